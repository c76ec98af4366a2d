//! Runs the anchor profile on a `.ply` with given settings and prints the file's parts and its
//! PSNR against the input (`eval --orbit 8`'s measure), checking that the bytes decode to the
//! scene the encoder reports. `cargo run --release --example anchor_probe -- SCENE.ply
//! [PER_ANCHOR F H DEGREE DISTILL ITERS POSITION_BITS]` (position bits 0: the default choice).
use gscodec::anchor::{encode, AnchorConfig};
use std::time::Instant;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let scene = gscodec::io::read_scene(std::path::Path::new(&args[1])).expect("scene");
    let d = AnchorConfig::default();
    let arg = |i: usize, def: f64| args.get(i).map_or(def, |s| s.parse().expect("number"));
    let bits = arg(8, 0.0) as u8;
    let cfg = AnchorConfig {
        per_anchor: arg(2, d.per_anchor as f64) as f32,
        features: arg(3, d.features as f64) as usize,
        hidden: arg(4, d.hidden as f64) as usize,
        max_sh_degree: arg(5, d.max_sh_degree as f64) as u8,
        distill_iters: arg(6, d.distill_iters as f64) as usize,
        iters: arg(7, d.iters as f64) as usize,
        position_bits: (bits > 0).then_some(bits),
        ..d
    };
    let pruned = gscodec::rate::quantise::prune(&scene, 1.0 / 255.0);
    let sig = gscodec::rate::importance::significance(&pruned);
    let t = Instant::now();
    let e = encode(&pruned, &sig, &cfg, (scene.len(), scene.sh_degree), None);
    let secs = t.elapsed().as_secs_f64();
    let decoded = gscodec_decoder::decode(&e.bytes).expect("decodes");
    assert_eq!(decoded, e.decoded, "the file decodes to the encoder's scene");
    let psnr = gscodec::encoder::orbit_psnr(&scene, &decoded);
    println!("{cfg:?}");
    println!("{}", serde_json::to_string(&e.report).unwrap());
    println!("bytes {} psnr {psnr:.2} gaussians {} time {secs:.1}s", e.bytes.len(), decoded.len());
}

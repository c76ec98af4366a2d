//! Size and rendered quality of our `.gsc` against SPZ on the shared scenes (docs/codec.md).
//!
//! `RD=1 cargo run --release --example spz_compare -- [DATA_DIR] [λ,λ,...] [SCENE]`
//! Renders the original, the SPZ-decoded scene and our decoded scene from the same 8 orbit
//! cameras (256×256, `views::orbit_cameras` of the original, up −y: the cameras of `gscodec eval --reference X --orbit 8`) and prints PSNR vs the original and bytes.

use gscodec::io::read_ply;
use gscodec::metrics::psnr;
use gscodec::rate::{self, EncodeConfig};
use gscodec::views::{orbit_cameras, UpAxis};
use gscodec_decoder::render::render;
use gscodec_decoder::{decode, RenderOptions};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let data = args.get(1).cloned().unwrap_or_else(|| "../shared/data".into());
    let lambdas: Vec<rate::Lambda> = args.get(2).map_or(vec!["0", "1", "3", "10"].into_iter().map(|x| x.parse().unwrap()).collect(), |s| s.split(',').map(|x| x.parse().expect("λ")).collect());
    let only = args.get(3).cloned();
    let opts = RenderOptions::default();
    for (name, spz) in [("k7000", "k7000"), ("fruit-drops", "fruit"), ("playbot-lod3", "playbot_lod3")] {
        if only.as_deref().is_some_and(|o| o != name) {
            continue;
        }
        let orig = read_ply(format!("{data}/scenes/{name}.ply").as_ref()).expect("scene");
        let spz_scene = read_ply(format!("{data}/spz-baseline/{spz}_spz_decoded.ply").as_ref()).expect("spz");
        let spz_bytes = std::fs::metadata(format!("{data}/spz-baseline/{spz}.spz")).expect("spz").len();
        let cams = orbit_cameras(&orig, 8, 256, 256, UpAxis::NegY.vector());
        let refs: Vec<_> = cams.iter().map(|c| render(&orig, c, &opts)).collect();
        let score = |s: &gscodec_decoder::Splats| {
            cams.iter().zip(&refs).map(|(c, r)| psnr(r, &render(s, c, &opts))).sum::<f64>() / cams.len() as f64
        };
        let spz_psnr = score(&spz_scene);
        println!("{name}: spz {spz_bytes} bytes, PSNR {spz_psnr:.2} dB");
        for &l in &lambdas {
            let config = if std::env::var("RD").is_ok() {
                rate::rd::search(&orig, l, |p| {
                    if std::env::var("RD").as_deref() == Ok("v") {
                        eprintln!("    {:?}", p)
                    }
                })
                .expect("rd")
                .0
            } else {
                EncodeConfig::for_lambda(l)
            };
            let (bytes, report, _) = rate::encode(&orig, &config).expect("encode");
            let dec = decode(&bytes).expect("decode");
            let p = score(&dec);
            let groups: Vec<String> = report
                .groups
                .iter()
                .map(|g| format!("{}={:.1}", g.group, 8.0 * (g.stream_bytes + g.table_bytes) as f64 / report.gaussians.max(1) as f64))
                .collect();
            let learned: Vec<String> = report
                .groups
                .iter()
                .map(|g| format!("{}: hist {:.0} B learned {:.0} B", g.group, g.histogram_bits / 8.0, g.learned_bits / 8.0))
                .collect();
            println!("    static histogram vs learned density per group: {}", learned.join("; "));
            println!(
                "  λ={l:<6} {:>8} bytes ({:.2}x smaller than spz) PSNR {p:.2} dB  est/actual {:.4}  N={} d={}  bits/G: {}",
                bytes.len(),
                spz_bytes as f64 / bytes.len() as f64,
                report.estimated_bits() / 8.0 / bytes.len() as f64,
                report.gaussians,
                report.sh_degree,
                groups.join(" ")
            );
        }
    }
}

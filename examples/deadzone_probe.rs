//! What the SH rest dead zone, and each group's quantisation, cost a trained scene (probe,
//! docs/wd.md §13).
//!
//! `cargo run --release --example deadzone_probe -- SCENE.ply DATASET STEPS`
//!
//! STEPS: `scale,rotation,opacity,sh_dc,sh1,sh2,sh3,position_rel` (e.g. an encode report's
//! `steps`). Prints the held-out PSNR of SCENE uncoded; quantised with one group at a time at its
//! step (the others 1000× finer); with the learned groups only (positions and rotations 1000×
//! finer: what training renders); and with every group at the SH rest dead zones 0–0.4, with
//! the file's bytes. No pruning, band dropping, codebooks or importance classes.

use gscodec::io::{load_dataset, read_scene, LoadOptions, Split};
use gscodec::rate::group::Group;
use gscodec::rate::quantise::dequantise;
use gscodec::rate::{self, EncodeConfig};
use gscodec_decoder::Splats;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    assert_eq!(args.len(), 4, "usage: deadzone_probe SCENE.ply DATASET STEPS");
    let scene = read_scene(args[1].as_ref()).expect("scene");
    let ds = load_dataset(args[2].as_ref(), &LoadOptions::default()).expect("dataset");
    let v: Vec<f32> = args[3].split(',').map(|x| x.parse().expect("a step")).collect();
    assert_eq!(v.len(), 8, "eight steps");
    let test = ds.split(Split::Test);
    let psnr = |s: &Splats| gscodec::metrics::view::mean_psnr_ssim(s, &test, ds.background).expect("render").expect("held-out views").0;
    let coded = |c: &EncodeConfig| {
        let (bytes, _, q) = rate::encode(&scene, c).expect("encode");
        (bytes.len(), psnr(&dequantise(&q)))
    };
    let mut c = EncodeConfig::default();
    c.steps.scale = v[0];
    c.steps.rotation = v[1];
    c.steps.opacity = v[2];
    c.steps.sh_dc = v[3];
    c.steps.sh_rest = [v[4], v[5], v[6]];
    c.steps.position_rel = v[7];
    let finer = |keep: &dyn Fn(Group) -> bool| {
        let mut f = c;
        for g in Group::ALL.into_iter().filter(|&g| !keep(g)) {
            *f.steps.of_mut(g) *= 1e-3;
        }
        f
    };
    println!("{}: {} Gaussians, uncoded {:.3} dB", args[1], scene.len(), psnr(&scene));
    for g in Group::ALL {
        let (b, p) = coded(&finer(&|h| h == g));
        println!("only {g:?} quantised: {p:.3} dB ({b} B)");
    }
    let (b, p) = coded(&finer(&|h| !matches!(h, Group::Position | Group::Rotation)));
    println!("learned groups quantised: {p:.3} dB ({b} B)");
    for dz in [0.0, 0.1, 0.2, 0.3, 0.4] {
        c.steps.rest_deadzone = dz;
        let (b, p) = coded(&c);
        println!("every group, SH rest dead zone {dz}: {p:.3} dB, {b} B");
    }
}

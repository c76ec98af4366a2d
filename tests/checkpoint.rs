//! Checkpoint and resume: a run stopped half way and resumed ends bit-identical to an
//! uninterrupted run; mismatched or corrupt checkpoints are refused; the live report is valid.

use gscodec::io::{write_ply, Dataset};
use gscodec::loss::L1Ssim;
use gscodec::train::targets::{orbit_cameras, render_targets, toy_scene};
use gscodec::train::{train_with, RunOptions, TrainConfig};
use gscodec::Error;
use gscodec_decoder::Splats;
use std::path::Path;

fn dataset() -> Dataset {
    render_targets(&toy_scene(80, 11), &orbit_cameras(10, 3.5, 24, 24), [1.0; 3])
}

fn cfg() -> TrainConfig {
    // 240 iterations: densification at 50, 100, 150, SH degree raised every 8.
    TrainConfig { iters: 240, seed: 7, init_points: 300, eval_interval: 60, ..Default::default() }
}

fn run(ds: &Dataset, c: &TrainConfig, opts: &RunOptions) -> gscodec::Result<(Splats, gscodec::train::TrainReport)> {
    train_with(ds, None, c, Box::new(L1Ssim::default()), None, &mut |_| {}, opts)
}

fn ply_bytes(s: &Splats, dir: &Path) -> Vec<u8> {
    let p = dir.join("s.ply");
    write_ply(&p, s).unwrap();
    std::fs::read(p).unwrap()
}

#[test]
fn resumed_run_is_bit_identical_to_an_uninterrupted_one() {
    let ds = dataset();
    let c = cfg();
    let tmp = tempfile::tempdir().unwrap();
    let (whole, whole_report) = run(&ds, &c, &RunOptions::default()).unwrap();
    let ckpt = tmp.path().join("ckpt");
    let report = tmp.path().join("report.json");
    let stopped = RunOptions { checkpoint: Some(ckpt.clone()), stop_after: Some(120), report: Some(report.clone()), ..Default::default() };
    let err = run(&ds, &c, &stopped).unwrap_err().to_string();
    assert!(err.contains("interrupted after iteration 120") && err.contains("--resume"), "{err}");
    // The live report of the stopped run is valid JSON up to iteration 120.
    let live: serde_json::Value = serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
    assert_eq!(live["points"].as_array().unwrap().last().unwrap()["iteration"], 120);
    let resumed = RunOptions { checkpoint: Some(ckpt.clone()), resume: Some(ckpt.clone()), ..Default::default() };
    let (again, again_report) = run(&ds, &c, &resumed).unwrap();
    assert!(whole.len() > 300, "densification ran ({} Gaussians)", whole.len());
    assert_eq!(ply_bytes(&whole, tmp.path()), ply_bytes(&again, tmp.path()));
    assert_eq!(whole_report.test_psnr, again_report.test_psnr);
    let losses =
        |r: &gscodec::train::TrainReport| r.points.iter().map(|p| (p.iteration, p.loss.to_bits(), p.gaussians)).collect::<Vec<_>>();
    assert_eq!(losses(&whole_report), losses(&again_report));
}

#[test]
fn periodic_checkpoints_and_refused_resumes() {
    let ds = dataset();
    let c = TrainConfig { iters: 60, ..cfg() };
    let tmp = tempfile::tempdir().unwrap();
    let ckpt = tmp.path().join("ckpt");
    let opts = RunOptions { checkpoint: Some(ckpt.clone()), checkpoint_every: Some(25), ..Default::default() };
    run(&ds, &c, &opts).unwrap();
    let state = gscodec::train::checkpoint::load(&ckpt).unwrap();
    assert_eq!(state.iteration, 50, "the last periodic checkpoint before the end");
    // Another run's settings: refused, naming the checkpoint.
    let other = TrainConfig { seed: 8, ..c.clone() };
    let resume = RunOptions { resume: Some(ckpt.clone()), ..Default::default() };
    match run(&ds, &other, &resume) {
        Err(Error::Input(m)) => assert!(m.contains("checkpoint.bin") && m.contains("another run"), "{m}"),
        r => panic!("{:?}", r.map(|_| ())),
    }
    // A corrupt or truncated file: an input error, no panic.
    let file = gscodec::train::checkpoint::file(&ckpt);
    let bytes = std::fs::read(&file).unwrap();
    for bad in [bytes[..bytes.len() / 2].to_vec(), b"nonsense".to_vec(), [&bytes[..8], &[9, 0, 0, 0], &bytes[12..]].concat()] {
        std::fs::write(&file, &bad).unwrap();
        assert!(matches!(run(&ds, &c, &resume), Err(Error::Input(_))));
    }
}

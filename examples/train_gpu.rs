//! Trains a dataset with the GPU trainer or the CPU trainer (same defaults as `gscodec train`) and
//! prints the report as JSON: the measurement behind docs/train.md's GPU table, until the CLI's
//! `--backend` is wired.
//!
//! `cargo run --release --features gpu --example train_gpu -- DATA [gpu|cpu] [ITERS] [OUT.ply]`

use gscodec::io::{load_dataset, LoadOptions};
use gscodec::loss::L1Ssim;
use gscodec::train::gpu::{self, GpuLoss};
use gscodec::train::TrainConfig;
use std::path::Path;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let data = args.get(1).expect("usage: train_gpu DATA [gpu|cpu] [ITERS] [OUT.ply]");
    let backend = args.get(2).map(String::as_str).unwrap_or("gpu");
    let iters: usize = args.get(3).and_then(|a| a.parse().ok()).unwrap_or(5000);
    let ds = load_dataset(Path::new(data), &LoadOptions::default()).unwrap_or_else(|e| panic!("{data}: {e}"));
    let cfg = TrainConfig { iters, ..Default::default() };
    let mut every = |p: &gscodec::train::Progress| {
        if let Some(psnr) = p.test_psnr {
            eprintln!("iteration {}: loss {:.4}, {} Gaussians, held-out {psnr:.2} dB", p.iteration, p.loss, p.gaussians);
        }
    };
    let result = match backend {
        "gpu" => gpu::train(&ds, None, &cfg, &GpuLoss::default(), &mut every),
        _ => gscodec::train::train(&ds, None, &cfg, Box::new(L1Ssim::default()), None, &mut every),
    };
    let (splats, report) = result.unwrap_or_else(|e| panic!("training failed: {e}"));
    if let Some(out) = args.get(4) {
        std::fs::write(out, splats.to_ply()).unwrap();
    }
    eprintln!(
        "{backend}: {} iterations in {:.2} s, {} Gaussians, held-out PSNR {:.2} dB, stages {:?}",
        iters,
        report.train_seconds,
        report.gaussians,
        report.test_psnr.unwrap_or(f64::NAN),
        report.stages
    );
    println!("{}", serde_json::to_string(&report).unwrap());
}

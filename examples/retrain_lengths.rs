//! One training from a dataset's images, coded with `l1ssim` and `wdr` at several retraining
//! lengths (docs/wd.md §25): what `encode DATASET --loss L --retrain-iters R` writes for each
//! (L, R), with the training from the images done once (`Encoder::train_dataset`, then
//! `Encoder::code_dataset` per file; `wdr` trains WD-R only in retraining, so both losses share it).
//!
//! `cargo run --release --example retrain_lengths -- DATASET OUT_DIR LAMBDA SEED ITERS R1,R2,…`
//!
//! Writes `OUT_DIR/{l1,w1}_r{R}_l{LAMBDA}_s{SEED}.gsc` and `.json` (the encode report), one pair
//! per loss and length; measure them with `gscodec eval FILE DATASET`. The CPU trainer, WD-R at
//! σ = 2 (`--wd-sigma 2`, the setting for ~200 px images).

use gscodec::encoder::{Backend, Encoder, EncoderConfig, Lambda, LossSpec};
use gscodec::loss::LossKind;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() != 6 {
        eprintln!("usage: retrain_lengths DATASET OUT_DIR LAMBDA SEED ITERS R1,R2,…");
        std::process::exit(2);
    }
    let number = |i: usize| -> f64 { args[i].parse().unwrap_or_else(|_| panic!("{}: not a number", args[i])) };
    let dataset = gscodec::io::load_dataset(args[0].as_ref(), &Default::default()).expect("dataset");
    let out = std::path::Path::new(&args[1]);
    std::fs::create_dir_all(out).expect("output directory");
    let (lambda, seed, iters) = (number(2), number(3) as u64, number(4) as usize);
    let lengths: Vec<usize> = args[5].split(',').map(|r| r.parse().expect("retraining length")).collect();
    let base = EncoderConfig::default()
        .with_iters(Some(iters))
        .with_lambda(Lambda::new(lambda).expect("λ >= 0"))
        .with_backend(Backend::Cpu)
        .with_seed(seed);
    let encoder = |kind, retrain| {
        let loss = LossSpec { kind, wd_sigma: Some(2.0), ..LossSpec::default() };
        Encoder::new(base.clone().with_loss(loss).with_retrain_iters(retrain)).expect("valid settings")
    };
    let t = std::time::Instant::now();
    let trained = encoder(LossKind::L1ssim, None).train_dataset(&dataset, &mut |_| {}).expect("training");
    eprintln!("trained {iters} iterations in {:.0} s", t.elapsed().as_secs_f64());
    for &r in &lengths {
        for (name, kind) in [("l1", LossKind::L1ssim), ("w1", LossKind::Wdr)] {
            let t = std::time::Instant::now();
            let coded = encoder(kind, Some(r)).code_dataset(&dataset, &trained, &mut |_| {}).expect("coding");
            let stem = format!("{name}_r{r}_l{lambda}_s{seed}");
            std::fs::write(out.join(format!("{stem}.gsc")), &coded.bytes).expect("write .gsc");
            let report = serde_json::to_string_pretty(&coded.report).expect("report");
            std::fs::write(out.join(format!("{stem}.json")), report).expect("write report");
            eprintln!("{stem}: {} B, searched, retrained and coded in {:.0} s", coded.bytes.len(), t.elapsed().as_secs_f64());
        }
    }
}

//! `gscodec train DATA -o OUT.ply`: train Gaussians on a posed-image dataset.

use crate::encoder::{Backend, LossSpec, TrainJob};
use crate::io;
use crate::loss::LossArgs;
use crate::train::TrainConfig;
use crate::{Error, Result};
use std::path::{Path, PathBuf};

/// Train 3D Gaussians on posed images (NeRF transforms*.json or COLMAP).
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Dataset directory (transforms*.json with images, or COLMAP sparse/0 + images).
    pub data: PathBuf,
    /// Output scene (.ply, INRIA layout).
    #[arg(short, long)]
    pub output: PathBuf,
    /// Training iterations; the reference 30k schedule is scaled to this.
    #[arg(long, default_value_t = 5000)]
    pub iters: usize,
    /// Random seed (initialisation, view order, densification).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Training loss (`--loss`, `--features`, `--wd-gamma`, `--wd-sigma`).
    #[command(flatten)]
    pub loss: LossArgs,
    /// Start from this scene (.ply) instead of the dataset's points / random points.
    #[arg(long)]
    pub init: Option<PathBuf>,
    /// Highest SH degree.
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u8).range(0..=3))]
    pub sh_degree: u8,
    /// Random initial Gaussians when the dataset has no point cloud.
    #[arg(long, default_value_t = 10_000)]
    pub init_points: usize,
    /// Upper bound on the number of Gaussians densification may reach.
    #[arg(long, default_value_t = 100_000)]
    pub max_gaussians: usize,
    /// Densification clones or splits the Gaussians whose mean view-space positional gradient
    /// (NDC units) reaches G; lower grows more.
    #[arg(long, value_name = "G", default_value_t = 2e-4)]
    pub densify_grad_threshold: f32,
    /// Turn off densification and pruning (fine-tuning).
    #[arg(long)]
    pub no_densify: bool,
    /// Evaluate held-out PSNR every N iterations (0 = only at the end).
    #[arg(long, default_value_t = 500)]
    pub eval_every: usize,
    /// Training backend: cpu, gpu (feature `gpu` and a GPU), or auto (a hardware GPU if there
    /// is one, else cpu).
    #[arg(long, value_enum, default_value_t = Backend::Auto)]
    pub backend: Backend,
    /// Write the training record (JSON: time series of loss, Gaussians, held-out PSNR).
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Dataset image options.
    #[command(flatten)]
    pub dataset: super::dataset_args::DatasetArgs,
    #[command(flatten)]
    pub checkpoint: super::dataset_args::CheckpointArgs,
    /// No progress bar or summary.
    #[arg(long)]
    pub quiet: bool,
}

pub fn run(args: Args) -> Result<()> {
    if args.iters == 0 {
        return Err(Error::Input("--iters must be at least 1".into()));
    }
    crate::encoder::check_densify_grad_threshold(args.densify_grad_threshold).map_err(|e| Error::Input(e.to_string()))?;
    check_output(&args.output, "ply")?;
    if let Some(report) = &args.report {
        io::atomic::check_output_file(report)?;
    }
    // Before the dataset, so a bad --features file fails fast.
    let loss = LossSpec::from_args(&args.loss, crate::loss::LossKind::L1ssim);
    loss.build(args.iters)?;
    let ds = io::load_dataset(&args.data, &args.dataset.load_options())?;
    let init = args.init.as_deref().map(io::read_ply).transpose()?;
    // After the inputs are checked: probing GPU adapters can print driver warnings (Mesa's
    // lavapipe prints two lines when XDG_RUNTIME_DIR is unset), which must not precede a
    // bad-input error's one line.
    let mut backend = args.backend.resolve()?;
    let cfg = TrainConfig {
        iters: args.iters,
        seed: args.seed,
        sh_degree_max: args.sh_degree,
        densify: !args.no_densify,
        eval_interval: args.eval_every,
        init_points: args.init_points,
        max_gaussians: args.max_gaussians,
        densify_grad_threshold: args.densify_grad_threshold,
        ..Default::default()
    };
    let pb = super::progress::bar(args.iters as u64, "train", args.quiet);
    // Without a terminal (logs), a line per evaluation instead of the bar.
    let log_lines = !args.quiet && pb.is_hidden();
    let mut last_psnr = None;
    let run = args.checkpoint.run_options(args.report.clone());
    let job = TrainJob { dataset: &ds, init, config: &cfg, loss: &loss, rate: None, run: &run };
    let (splats, report) = backend
        .train(job, &mut |p| {
            if p.test_psnr.is_some() {
                last_psnr = p.test_psnr;
                if log_lines {
                    eprintln!(
                        "iteration {}/{}: loss {:.4}, {} Gaussians, held-out PSNR {:.2} dB",
                        p.iteration,
                        p.iters,
                        p.loss,
                        p.gaussians,
                        p.test_psnr.unwrap_or(0.0)
                    );
                }
            }
            pb.set_position(p.iteration as u64);
            if p.iteration % 10 == 0 || p.test_psnr.is_some() {
                let psnr = last_psnr.map(|v| format!(" test {v:.2} dB")).unwrap_or_default();
                // The GPU trainer reads its loss back every few iterations: NaN until the first read.
                let loss = if p.loss.is_finite() { format!("loss {:.4} ", p.loss) } else { String::new() };
                pb.set_message(format!("{loss}n {}{psnr}", p.gaussians));
            }
        })
        .map_err(|e| match e {
            Error::Input(m) => Error::input(&args.data, m),
            other => other,
        })?;
    pb.finish_and_clear();
    io::write_ply(&args.output, &splats)?;
    if let Some(r) = &args.report {
        let json = serde_json::to_string_pretty(&report).map_err(|e| Error::failure(r, e))?;
        io::atomic::write_bytes_atomic(r, json.as_bytes())?;
    }
    if !args.quiet {
        match (report.test_psnr, report.test_ssim) {
            (Some(p), Some(s)) => println!("held-out ({} views): PSNR {p:.2} dB, SSIM {s:.4}", report.test_views),
            _ => println!("no held-out views"),
        }
        println!("{} Gaussians, {:.1} s training", report.gaussians, report.train_seconds);
        super::warn_truncated(report.truncated_frames);
    }
    Ok(())
}

fn check_output(path: &Path, ext: &str) -> Result<()> {
    match path.extension().and_then(|e| e.to_str()) {
        Some(e) if e.eq_ignore_ascii_case(ext) => io::atomic::check_output_file(path),
        _ => Err(Error::input(path, format!("output must be a .{ext} file"))),
    }
}

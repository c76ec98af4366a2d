//! `gscodec encode`: a trained `.ply` (or a dataset, once training is available) to a `.gsc` file.

use std::path::{Path, PathBuf};
use std::time::Instant;

use serde_json::json;

use crate::views::{orbit_cameras, UpAxis};
use crate::rate;
use crate::Error;
use gscodec_decoder::render::render;
use gscodec_decoder::{RenderOptions, Splats};

/// Compress a scene into a .gsc bitstream.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// A trained .ply scene, or a dataset directory.
    pub input: PathBuf,
    /// Output .gsc file.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Rate–distortion trade-off λ in J = D + λ·R, D = 255²·MSE of orbit renders, R = megabits.
    /// Larger gives smaller files; 0 = finest.
    #[arg(long, default_value_t = 20.0)]
    pub lambda: f64,
    /// Distortion for training (l1ssim, wd, wdr).
    #[arg(long, default_value = "l1ssim")]
    pub loss: String,
    /// Training iterations (0 = quantise and code the input as is).
    #[arg(long, default_value_t = 0)]
    pub iters: usize,
    /// Write a JSON report (sizes per attribute group, estimated vs actual, time series).
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// No progress output.
    #[arg(long)]
    pub quiet: bool,
}

/// Mean PSNR of `b` against `a` over the standard 8 orbit views of `a` at 256×256.
pub fn orbit_psnr(a: &Splats, b: &Splats) -> f64 {
    let opts = RenderOptions::default();
    let cams = orbit_cameras(a, 8, 256, 256, UpAxis::NegY.vector());
    cams.iter().map(|c| crate::metrics::psnr(&render(a, c, &opts), &render(b, c, &opts))).sum::<f64>() / cams.len() as f64
}

pub fn run(args: Args) -> crate::Result<()> {
    let start = Instant::now();
    if !(args.lambda >= 0.0 && args.lambda.is_finite()) {
        return Err(Error::Input(format!("--lambda {}: must be a finite number >= 0", args.lambda)));
    }
    if !["l1ssim", "wd", "wdr"].contains(&args.loss.as_str()) {
        return Err(Error::Input(format!("--loss {}: expected l1ssim, wd or wdr", args.loss)));
    }
    let scene = load_input(&args.input)?;
    if args.iters > 0 && !args.quiet {
        eprintln!("note: fine-tuning is not available in this build; coding the input as is");
    }
    let mut series = Vec::new();
    let (config, _) = rate::rd::search(&scene, args.lambda, |p| {
        series.push(json!({"iteration": p.step, "trial": p.change, "wall_s": start.elapsed().as_secs_f64(), "estimated_bits": 8.0 * p.bytes as f64, "d": p.d, "heldout_psnr": p.psnr}));
    })
    .map_err(|e| Error::input(&args.input, e))?;
    let (bytes, report, q) = rate::encode(&scene, &config).map_err(|e| Error::input(&args.input, e))?;
    crate::io::atomic::write_bytes_atomic(&args.output, &bytes)?;
    if !args.quiet {
        eprintln!(
            "{}: {} Gaussians (of {}), SH degree {}, {} bytes ({:.2} bytes/Gaussian)",
            args.output.display(),
            report.gaussians,
            scene.len(),
            report.sh_degree,
            bytes.len(),
            bytes.len() as f64 / report.gaussians.max(1) as f64
        );
    }
    if let Some(path) = &args.report {
        let decoded = rate::quantise::dequantise(&q);
        let psnr = orbit_psnr(&scene, &decoded);
        let estimated = report.estimated_bits();
        let v = json!({
            "input": args.input.display().to_string(),
            "lambda": args.lambda,
            "loss": args.loss,
            "file_bytes": bytes.len(),
            "estimated_bytes": estimated / 8.0,
            "gaussians": report.gaussians,
            "input_gaussians": scene.len(),
            "sh_degree": report.sh_degree,
            "position_bits": report.position_bits,
            "groups": report.groups,
            "orbit_psnr": psnr,
            "wall_s": start.elapsed().as_secs_f64(),
            "series": series,
        });
        let text = serde_json::to_string_pretty(&v).expect("json");
        crate::io::atomic::write_bytes_atomic(path, text.as_bytes())?;
    }
    Ok(())
}

fn load_input(path: &Path) -> crate::Result<Splats> {
    if path.is_dir() {
        return Err(Error::input(path, "encoding from a dataset needs training, which this build does not include yet; pass a trained .ply"));
    }
    crate::io::read_ply(path)
}

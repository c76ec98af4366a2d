//! `gscodec encode`: a trained `.ply` (or a dataset, once training is available) to a `.gsc` file.

use std::path::PathBuf;
use std::time::Instant;

use serde_json::json;

use crate::rate;
use crate::views::{orbit_cameras, training_cameras, UpAxis};
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
    #[arg(long, default_value_t = rate::Lambda::DEFAULT)]
    pub lambda: rate::Lambda,
    /// Training distortion and its options.
    #[command(flatten)]
    pub loss: crate::loss::LossArgs,
    /// Fine-tuning (a .ply: against 24 orbit renders of itself, densification off) or training
    /// (a dataset) iterations under D + λ·R with straight-through quantisation; 0 = code as is.
    /// Default: 0 for a .ply, 3000 for a dataset.
    #[arg(long)]
    pub iters: Option<usize>,
    /// Keep the quantisation steps fixed during training instead of learning them (per group:
    /// scale, opacity, SH DC, each SH band) under D + λ·R.
    #[arg(long)]
    pub fixed_steps: bool,
    /// Write a JSON report (sizes per attribute group, estimated vs actual, time series).
    #[arg(long)]
    pub report: Option<PathBuf>,
    /// Dataset image options.
    #[command(flatten)]
    pub dataset: super::dataset_args::DatasetArgs,
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

/// Training iterations when encoding a dataset without `--iters`.
pub const DEFAULT_DATASET_ITERS: usize = 3000;

pub fn run(args: Args) -> crate::Result<()> {
    let start = Instant::now();
    let input_is_dir = args.input.is_dir();
    let iters = args.iters.unwrap_or(if input_is_dir { DEFAULT_DATASET_ITERS } else { 0 });
    if input_is_dir && iters == 0 {
        return Err(Error::input(&args.input, "encoding a dataset needs training: pass --iters N"));
    }
    let mut scene = if input_is_dir { Splats::new(3) } else { crate::io::read_scene(&args.input)? };
    scene.validate().map_err(|e| Error::input(&args.input, e))?;
    let mut series = Vec::new();
    // A .ply: the RD search's PSNR is against the input scene's own renders, the error the user
    // cares about, so its trials go into the time series. A dataset: there is nothing to search
    // before training; training starts from the fixed ladder for λ.
    let mut config = if input_is_dir {
        rate::EncodeConfig::for_lambda(args.lambda)
    } else {
        rate::rd::search(&scene, args.lambda, |p| {
            series.push(json!({"iteration": p.step, "trial": p.change, "wall_s": start.elapsed().as_secs_f64(), "estimated_bits": 8.0 * p.bytes as f64, "d": p.d, "heldout_psnr": p.psnr}));
        })
        .map_err(|e| Error::input(&args.input, e))?
        .0
    };
    let original = scene.clone();
    let mut heldout = None;
    if iters > 0 {
        let (trained, steps, dataset) = fine_tune(&args, iters, &scene, &config, &start, &mut series)?;
        scene = trained;
        if input_is_dir {
            // RD choices on the trained scene (their PSNR is against the trained scene, not the
            // images, so they stay out of the held-out series).
            config = rate::rd::search_from(&scene, args.lambda, steps, |_| {}).map_err(|e| Error::input(&args.input, e))?.0;
            heldout = Some(dataset);
        } else {
            config.steps = steps;
        }
    }
    let (bytes, report, q) = rate::encode(&scene, &config).map_err(|e| Error::input(&args.input, e))?;
    crate::io::atomic::write_bytes_atomic(&args.output, &bytes)?;
    if !args.quiet {
        let per_gaussian = match report.gaussians {
            0 => String::new(),
            n => format!(" ({:.2} bytes/Gaussian)", bytes.len() as f64 / n as f64),
        };
        eprintln!(
            "{}: {} Gaussians (of {}), SH degree {}, {} bytes{per_gaussian}",
            args.output.display(),
            report.gaussians,
            scene.len(),
            report.sh_degree,
            bytes.len(),
        );
    }
    if let Some(path) = &args.report {
        let decoded = rate::quantise::dequantise(&q);
        if let Some(ds) = &heldout {
            // The final point of the series: the coded scene on the held-out images.
            let test = ds.split(crate::io::Split::Test);
            if let Some((psnr, _)) = crate::metrics::view::mean_psnr_ssim(&decoded, &test, ds.background) {
                series.push(json!({"iteration": iters, "trial": "coded", "wall_s": start.elapsed().as_secs_f64(), "estimated_bits": 8.0 * bytes.len() as f64, "d": null, "heldout_psnr": psnr}));
            }
        }
        // Against the input scene (for a dataset: against the trained scene before coding).
        let psnr = orbit_psnr(if input_is_dir { &scene } else { &original }, &decoded);
        let estimated = report.estimated_bits();
        let v = json!({
            "input": args.input.display().to_string(),
            "lambda": args.lambda,
            "loss": format!("{:?}", args.loss.loss.unwrap_or(crate::loss::LossKind::Wdr)).to_lowercase(),
            "iters": iters,
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

/// Fine-tunes `scene` (or trains from the dataset at `args.input`) with the rate term.
fn fine_tune(
    args: &Args,
    iters: usize,
    scene: &Splats,
    config: &rate::EncodeConfig,
    start: &Instant,
    series: &mut Vec<serde_json::Value>,
) -> crate::Result<(Splats, rate::Steps, crate::io::Dataset)> {
    use crate::rate::term::Shared;
    use crate::train::{train, TrainConfig};
    let (dataset, init) = if args.input.is_dir() {
        (crate::io::load_dataset(&args.input, &args.dataset.load_options())?, None)
    } else {
        // Training views avoid the 8 orbit views `orbit_psnr` evaluates on (held out).
        let cams = training_cameras(scene, 8, 256, 256, UpAxis::NegY.vector());
        (crate::train::targets::render_targets(scene, &cams, [0.0; 3]), Some(scene.clone()))
    };
    let cfg = TrainConfig {
        iters,
        densify: init.is_none(),
        sh_degree_max: if init.is_some() { scene.sh_degree } else { 3 },
        eval_interval: (iters / 10).max(1),
        ..Default::default()
    };
    let mut term = rate::term::RateTerm::new(args.lambda, config.steps, config.min_opacity);
    // From images, the rate term starts when densification ends (half way): with it from the
    // start, lego-200 at λ = 4 stalled at 23.7 dB held-out with 9k Gaussians; with the warm-up it
    // reaches 30.6 dB (docs/codec.md). A .ply already has its structure: the term runs throughout.
    term.start_iter = if init.is_none() { iters / 2 } else { 0 };
    term.learn_steps = !args.fixed_steps;
    let shared = term.shared();
    let pb = super::progress::bar(iters as u64, "train", args.quiet);
    let (trained, _) = train(&dataset, init, &cfg, crate::loss::build_loss(&args.loss, iters, crate::loss::LossKind::Wdr)?, Some(Box::new(term)), &mut |p| {
        pb.set_position(p.iteration as u64);
        if let Some(psnr) = p.test_psnr {
            let bits = shared.lock().expect("term lock").bits;
            series.push(json!({"iteration": p.iteration, "trial": "train", "wall_s": start.elapsed().as_secs_f64(), "estimated_bits": bits, "d": p.loss, "heldout_psnr": psnr}));
        }
    })
    .map_err(|e| match e {
        Error::Input(m) => Error::input(&args.input, m),
        other => other,
    })?;
    pb.finish_and_clear();
    let Shared { steps, bits } = *shared.lock().expect("term lock");
    // The rate term's own estimate at the end of training: for a .ply (coded at these steps) it
    // is to be compared with the file size.
    series.push(
        json!({"iteration": iters, "trial": "learned steps", "wall_s": start.elapsed().as_secs_f64(), "estimated_bits": bits, "steps": {
            "scale": steps.scale, "opacity": steps.opacity, "sh_dc": steps.sh_dc, "sh_rest": steps.sh_rest,
        }}),
    );
    Ok((trained, steps, dataset))
}

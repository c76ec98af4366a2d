//! `gscodec eval`: quality of a scene against a dataset split or a reference scene.

use super::progress;
use super::render::{dataset_views, orbit_views, View};
use super::sample::parse_size;
use crate::io::{read_scene, Split};
use crate::metrics::view::ViewMetrics;
use crate::views::UpAxis;
use crate::{metrics, Error, Result};
use gscodec_decoder::render::render;
use gscodec_decoder::{RenderOptions, Splats};
use std::path::PathBuf;
use std::time::Instant;

/// Measure a scene's rendering quality: against a dataset's photos, or against a reference scene
/// rendered from the same orbit.
#[derive(Debug, clap::Args)]
#[command(group = clap::ArgGroup::new("against").required(true).args(["data", "reference"]))]
pub struct Args {
    /// Scene file (.gsc, .ply, .spz, .splat).
    pub scene: PathBuf,
    /// Dataset directory (transforms*.json or COLMAP).
    pub data: Option<PathBuf>,
    /// Which frames of the dataset.
    #[arg(long, value_enum, default_value = "test", requires = "data")]
    pub split: Split,
    /// Reference scene to compare with.
    #[arg(long)]
    pub reference: Option<PathBuf>,
    /// Number of orbit views around the reference scene.
    #[arg(long, value_name = "N", default_value_t = 8, requires = "reference")]
    pub orbit: usize,
    /// World up axis of the orbit.
    #[arg(long, value_enum, default_value = "-y", allow_hyphen_values = true, requires = "reference")]
    pub up: UpAxis,
    /// Orbit image size WxH.
    #[arg(long, value_parser = parse_size, requires = "reference")]
    pub size: Option<(u32, u32)>,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
    /// Also report every view's metrics (JSON: a `per_view` array).
    #[arg(long)]
    pub per_view: bool,
    /// Dataset image options.
    #[command(flatten)]
    pub dataset: super::dataset_args::DatasetArgs,
    /// No progress output.
    #[arg(long)]
    pub quiet: bool,
}

/// Renders `scene` from every view (on `background`) and measures it against the view's target;
/// returns the per-view metrics and the total render time in milliseconds. `tick` runs after
/// each view.
///
/// # Errors
/// A target image that cannot be read (streamed datasets read them here).
///
/// # Panics
/// If a view has no target or a target's size differs from its camera's.
pub fn measure(scene: &Splats, views: &[View], background: [f32; 3], tick: &mut dyn FnMut()) -> Result<(Vec<ViewMetrics>, f64)> {
    let opts = RenderOptions { background, max_sh_degree: 3 };
    let mut ms = 0.0;
    let mut per_view = Vec::with_capacity(views.len());
    for v in views {
        let t = Instant::now();
        let img = render(scene, &v.camera, &opts);
        ms += t.elapsed().as_secs_f64() * 1e3;
        let target = v.target.as_ref().expect("every eval view has a target").get()?;
        per_view.push(metrics::view::evaluate(&target, &img));
        tick();
    }
    Ok((per_view, ms))
}

/// The orbit views of `eval --reference`: `n` views of `reference` (at `size`, default 256²),
/// each with the reference's render as its target, on a black background.
pub fn reference_views(reference: &Splats, n: usize, size: Option<(u32, u32)>, up: UpAxis) -> (Vec<View>, [f32; 3]) {
    let bg = [0.0; 3];
    let opts = RenderOptions { background: bg, max_sh_degree: 3 };
    let mut views = orbit_views(reference, n, size, up);
    views.iter_mut().for_each(|v| v.target = Some(render(reference, &v.camera, &opts).into()));
    (views, bg)
}

pub fn run(args: Args) -> Result<()> {
    let scene = read_scene(&args.scene)?;
    let bytes = std::fs::metadata(&args.scene).map_err(|e| Error::input(&args.scene, e))?.len();
    let (views, background): (Vec<View>, [f32; 3]) = if let Some(data) = &args.data {
        dataset_views(data, args.split, None, &args.dataset.load_options())?
    } else {
        let path = args.reference.as_ref().expect("clap group");
        if args.orbit == 0 {
            return Err(Error::input(path, "--orbit needs at least one view"));
        }
        let reference = read_scene(path)?;
        reference_views(&reference, args.orbit, args.size, args.up)
    };
    let pb = progress::bar(views.len() as u64, "eval", args.quiet);
    let (per_view, ms) = measure(&scene, &views, background, &mut || pb.inc(1))?;
    pb.finish_and_clear();
    let n = views.len() as f64;
    let Some(mean) = metrics::view::mean(&per_view) else {
        let what = args.data.as_ref().or(args.reference.as_ref()).unwrap_or(&args.scene);
        return Err(Error::input(what, "no views to evaluate"));
    };
    let mut report = serde_json::json!({
        "psnr": mean.psnr,
        "ssim": mean.ssim,
        "ms_ssim": mean.ms_ssim,
        "flip": mean.flip,
        "wd": mean.wd,
        "bytes": bytes,
        "gaussians": scene.len(),
        "render_ms": ms / n,
        "views": views.len(),
    });
    if args.per_view {
        report["per_view"] = views
            .iter()
            .zip(&per_view)
            .map(|(v, m)| {
                let mut o = serde_json::to_value(m).unwrap_or_default();
                o["index"] = v.index.into();
                o
            })
            .collect();
    }
    let opt = |v: Option<f64>, digits: usize| v.map_or("n/a".to_string(), |v| format!("{v:.digits$}"));
    if args.json {
        println!("{report}");
    } else {
        if args.per_view {
            println!("{:>6} {:>8} {:>7} {:>7} {:>7} {:>7}", "view", "psnr", "ssim", "ms_ssim", "flip", "wd");
            for (v, m) in views.iter().zip(&per_view) {
                println!("{:>6} {:>8.3} {:>7.4} {:>7} {:>7.4} {:>7}", v.index, m.psnr, m.ssim, opt(m.ms_ssim, 4), m.flip, opt(m.wd, 4));
            }
        }
        println!("psnr       {:.3} dB", mean.psnr);
        println!("ssim       {:.4}", mean.ssim);
        println!("ms_ssim    {}", opt(mean.ms_ssim, 4));
        println!("flip       {:.4}", mean.flip);
        println!("wd         {}", opt(mean.wd, 4));
        println!("bytes      {bytes}");
        println!("gaussians  {}", scene.len());
        println!("render_ms  {:.2}", ms / n);
        println!("views      {}", views.len());
    }
    Ok(())
}

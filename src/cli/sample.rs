//! `gscodec sample`: write the deterministic procedural dataset, or one rendered from a scene.

use crate::io::read_scene;
use crate::sample::{write_sample, write_scene_sample, SampleOptions};
use crate::views::UpAxis;
use std::path::PathBuf;

/// Write a procedural scene and its rendered views as a NeRF-style dataset
/// (transforms_train.json, train/r_<i>.png on white, truth.ply); with --scene, views of that scene.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Output directory (created; existing files of the same names are replaced).
    pub out_dir: PathBuf,
    /// Number of Gaussians of the procedural scene.
    #[arg(long, default_value_t = 2000, conflicts_with = "scene")]
    pub gaussians: usize,
    /// Render this scene (.ply, .spz, .splat, .gsc, …) instead of the procedural one: cameras on a
    /// sphere around its robust centre at the orbit's distance (2.5 × the 90th-percentile
    /// distance) and field of view (0.8 rad), elevations 15°–65°.
    #[arg(long, value_name = "SCENE")]
    pub scene: Option<PathBuf>,
    /// World up axis of --scene (the reference 3DGS / COLMAP convention is -y).
    #[arg(long, value_enum, default_value = "-y", allow_hyphen_values = true, requires = "scene")]
    pub up: UpAxis,
    /// Number of views.
    #[arg(long, default_value_t = 32)]
    pub views: usize,
    /// Image size WxH.
    #[arg(long, default_value = "128x128", value_parser = parse_size)]
    pub size: (u32, u32),
    /// Random seed.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// No progress output.
    #[arg(long)]
    pub quiet: bool,
}

/// Parses `WxH` with both positive.
pub fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let bad = || format!("`{s}` is not a size WxH (e.g. 256x256)");
    let (w, h) = s.split_once(['x', 'X']).ok_or_else(bad)?;
    let (w, h): (u32, u32) = (w.trim().parse().map_err(|_| bad())?, h.trim().parse().map_err(|_| bad())?);
    if w == 0 || h == 0 || w > 16384 || h > 16384 {
        return Err(format!("size {w}x{h} must be between 1x1 and 16384x16384"));
    }
    Ok((w, h))
}

pub fn run(args: Args) -> crate::Result<()> {
    let opts = SampleOptions { gaussians: args.gaussians, views: args.views, width: args.size.0, height: args.size.1, seed: args.seed };
    let pb = super::progress::bar(args.views as u64, "render", args.quiet);
    match &args.scene {
        Some(path) => write_scene_sample(&args.out_dir, path, &read_scene(path)?, args.up.vector(), &opts, &pb)?,
        None => write_sample(&args.out_dir, &opts, &pb)?,
    }
    pb.finish_and_clear();
    Ok(())
}

//! Dataset loading options shared by every command that reads a dataset (`train`, `encode`,
//! `eval`, `render`, `sweep`).

use super::render::parse_rgb;
use crate::io::LoadOptions;

/// How to read a dataset's images.
#[derive(Debug, Clone, Default, PartialEq, clap::Args)]
pub struct DatasetArgs {
    /// Downscale dataset images by this integer factor: from `images_N/` when the dataset has it
    /// (the 3DGS convention), else an exact N×N box filter; intrinsics scaled to match.
    #[arg(long, value_name = "N", default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..))]
    pub downscale: u32,
    /// Longest image side in pixels, after --downscale (Lanczos-3 resize when larger).
    #[arg(long, value_name = "PX", value_parser = clap::value_parser!(u32).range(1..))]
    pub max_size: Option<u32>,
    /// Background colour r,g,b in [0,1]: what RGBA images are composited on and what training and
    /// renders show behind the Gaussians (default: white for NeRF data, black for COLMAP photos).
    #[arg(long, value_parser = parse_rgb)]
    pub background: Option<[f32; 3]>,
    /// Do not read or write resized/undistorted images in `<dataset>/.gscodec-cache/`.
    #[arg(long)]
    pub no_cache: bool,
}

impl DatasetArgs {
    pub fn load_options(&self) -> LoadOptions {
        LoadOptions { downscale: self.downscale.max(1), max_size: self.max_size, cache: !self.no_cache, background: self.background }
    }

    /// The same options as command-line words (for child processes, e.g. `sweep`'s encodes).
    pub fn to_args(&self) -> Vec<String> {
        let mut v = Vec::new();
        if self.downscale > 1 {
            v.extend(["--downscale".into(), self.downscale.to_string()]);
        }
        if let Some(m) = self.max_size {
            v.extend(["--max-size".into(), m.to_string()]);
        }
        if let Some([r, g, b]) = self.background {
            v.extend(["--background".into(), format!("{r},{g},{b}")]);
        }
        if self.no_cache {
            v.push("--no-cache".into());
        }
        v
    }
}

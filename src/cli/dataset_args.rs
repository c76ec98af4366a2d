//! Dataset loading options shared by every command that reads a dataset (`train`, `encode`,
//! `eval`, `render`, `sweep`).

use super::render::parse_rgb;
use crate::io::LoadOptions;

/// How to read a dataset's images.
#[derive(Debug, Clone, PartialEq, clap::Args)]
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
    /// Memory for the decoded images in MiB (f32 RGB, 12 bytes a pixel, all frames): when they
    /// need more, they are read on demand from disk or the cache through an image cache of this
    /// size instead of all up front (results are the same).
    #[arg(long, value_name = "MB", default_value_t = DEFAULT_IMAGE_MEMORY_MB)]
    pub image_memory: u64,
}

/// `--image-memory`'s default, MiB.
pub const DEFAULT_IMAGE_MEMORY_MB: u64 = crate::io::DEFAULT_IMAGE_MEMORY >> 20;

impl Default for DatasetArgs {
    fn default() -> Self {
        DatasetArgs { downscale: 1, max_size: None, background: None, no_cache: false, image_memory: DEFAULT_IMAGE_MEMORY_MB }
    }
}

impl DatasetArgs {
    pub fn load_options(&self) -> LoadOptions {
        LoadOptions {
            downscale: self.downscale.max(1),
            max_size: self.max_size,
            cache: !self.no_cache,
            background: self.background,
            image_memory: Some(self.image_memory.saturating_mul(1 << 20)),
        }
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
        if self.image_memory != DEFAULT_IMAGE_MEMORY_MB {
            v.extend(["--image-memory".into(), self.image_memory.to_string()]);
        }
        v
    }
}

/// Checkpoints of long training runs (`train`).
#[derive(Debug, Clone, Default, PartialEq, clap::Args)]
pub struct CheckpointArgs {
    /// Write checkpoints (scene, optimiser, RNG, schedule position) into DIR: every
    /// --checkpoint-every iterations (default: every 10 minutes) and at Ctrl-C.
    #[arg(long, value_name = "DIR")]
    pub checkpoint: Option<std::path::PathBuf>,
    /// Checkpoint every N iterations instead of every 10 minutes.
    #[arg(long, value_name = "N", requires = "checkpoint", value_parser = clap::value_parser!(u64).range(1..))]
    pub checkpoint_every: Option<u64>,
    /// Continue the run checkpointed in DIR (same dataset and settings); gives the same result as
    /// an uninterrupted run. Usually DIR is also the --checkpoint folder.
    #[arg(long, value_name = "DIR")]
    pub resume: Option<std::path::PathBuf>,
}

impl CheckpointArgs {
    /// The trainer's run options, with `report` rewritten as training goes.
    pub fn run_options(&self, report: Option<std::path::PathBuf>) -> crate::train::RunOptions {
        crate::train::RunOptions {
            checkpoint: self.checkpoint.clone(),
            checkpoint_every: self.checkpoint_every.map(|n| n as usize),
            resume: self.resume.clone(),
            report,
            catch_interrupt: self.checkpoint.is_some(),
            ..Default::default()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Debug, Parser)]
    struct Cli {
        #[command(flatten)]
        d: DatasetArgs,
    }

    #[test]
    fn to_args_parses_back_to_the_same_options() {
        for words in
            [&[][..], &["--downscale", "4", "--max-size", "1600", "--background", "0.5,0,1", "--no-cache", "--image-memory", "0"][..]]
        {
            let a = Cli::try_parse_from(std::iter::once("x").chain(words.iter().copied())).unwrap().d;
            let b = Cli::try_parse_from(std::iter::once("x".to_string()).chain(a.to_args())).unwrap().d;
            assert_eq!(a, b);
        }
        assert!(Cli::try_parse_from(["x", "--downscale", "0"]).is_err());
        assert!(Cli::try_parse_from(["x", "--max-size", "0"]).is_err());
        assert_eq!(Cli::try_parse_from(["x"]).unwrap().d, DatasetArgs::default());
        assert_eq!(Cli::try_parse_from(["x", "--image-memory", "3"]).unwrap().d.load_options().image_memory, Some(3 << 20));
    }
}

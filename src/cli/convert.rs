//! `gscodec convert`: scene format conversion by extension.

use crate::io::{read_scene, write_scene};
use std::path::PathBuf;

/// Convert a scene between formats, chosen by the files' extensions: .ply, .compressed.ply,
/// .gsc, .spz, .splat, .sog (SOG bundle), meta.json (unbundled SOG), .glb, .gltf.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Input scene.
    pub input: PathBuf,
    /// Output scene (written atomically).
    pub output: PathBuf,
    /// No progress output.
    #[arg(long)]
    pub quiet: bool,
}

pub fn run(args: Args) -> crate::Result<()> {
    let scene = read_scene(&args.input)?;
    write_scene(&args.output, &scene)
}

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
    // An unbundled SOG scene (`DIR/meta.json`) is written as a folder, created with its parents.
    if !crate::io::sog::is_sog_meta(&args.output) {
        crate::io::atomic::check_output_file(&args.output)?;
    }
    let scene = read_scene(&args.input)?;
    if args.output.extension().is_some_and(|e| e.eq_ignore_ascii_case("gsc")) {
        // Fine default quantisation, no rendering-based RD search (that is `gscodec encode`).
        let (bytes, _, _) =
            crate::rate::encode(&scene, &crate::rate::EncodeConfig::default()).map_err(|e| crate::Error::input(&args.input, e))?;
        return crate::io::atomic::write_bytes_atomic(&args.output, &bytes);
    }
    write_scene(&args.output, &scene)
}

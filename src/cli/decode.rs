//! `gscodec decode`: a `.gsc` bitstream to an INRIA `.ply`.

use std::path::PathBuf;

use gscodec_decoder::Limits;

/// Decode a .gsc file to a .ply scene.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Input .gsc file.
    pub input: PathBuf,
    /// Output .ply file.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Skip SH bands above this degree.
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u8).range(0..=3))]
    pub max_sh_degree: u8,
    /// No progress output.
    #[arg(long)]
    pub quiet: bool,
}

pub fn run(args: Args) -> crate::Result<()> {
    crate::io::atomic::check_output_file(&args.output)?;
    let limits = Limits { max_sh_degree: args.max_sh_degree, ..Limits::default() };
    let scene = crate::io::read_scene_with(&args.input, &limits)?;
    crate::io::write_ply(&args.output, &scene)
}

//! The `gscodec` command line (DESIGN §10). One file per subcommand; each exposes `Args` and `run`.

use clap::{Parser, Subcommand};

pub mod convert;
pub mod dataset_args;
pub mod decode;
pub mod encode;
pub mod eval;
pub mod info;
pub mod progress;
pub mod render;
pub mod sample;
pub mod sweep;
pub mod train;

/// gscodec: rate-distortion trained compression of 3D Gaussian Splatting scenes.
#[derive(Debug, Parser)]
#[command(name = "gscodec", version, about)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    Sample(sample::Args),
    Train(train::Args),
    Encode(encode::Args),
    Decode(decode::Args),
    Info(info::Args),
    Render(render::Args),
    Convert(convert::Args),
    Eval(eval::Args),
    /// Encode at several λ and losses, evaluate, and write RD tables, plots and BD-rates.
    Sweep(sweep::Args),
}

/// Runs a parsed command line.
pub fn run(cli: Cli) -> crate::Result<()> {
    match cli.command {
        Command::Sample(a) => sample::run(a),
        Command::Train(a) => train::run(a),
        Command::Encode(a) => encode::run(a),
        Command::Decode(a) => decode::run(a),
        Command::Info(a) => info::run(a),
        Command::Render(a) => render::run(a),
        Command::Convert(a) => convert::run(a),
        Command::Eval(a) => eval::run(a),
        Command::Sweep(a) => sweep::run(a),
    }
}

/// Says on stderr when the GPU trainer rendered frames with only the tile/Gaussian pairs that fit
/// its sort buffers ([`crate::train::TrainReport::truncated_frames`]).
fn warn_truncated(frames: usize) {
    if frames > 0 {
        eprintln!("warning: {frames} training iteration(s) rendered only the tile/Gaussian pairs that fit the GPU sort buffers");
    }
}

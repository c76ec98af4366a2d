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

/// Lets glibc's allocator reuse freed memory instead of giving it back to the kernel.
///
/// Training, the WD loss and the RD search allocate and free images, gradients and feature
/// arrays of a few MB at every step. By default glibc serves such blocks with `mmap` or trims
/// them off the heap when freed, so every step faults their pages in again: a 300-iteration WD-R
/// training of lego-200 took 870,000–930,000 page faults and 4.3–5.1 s of kernel time. With
/// blocks up to 32 MiB kept on the heap and up to 512 MiB of free heap kept, it takes 91,000 and
/// 1.9–2.2 s, and one WD-R loss evaluation half the time (docs/train.md, "Allocator"). Peak
/// memory grows by 0–11 %; what is freed stays with the process until it exits.
pub fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only sets the allocator's parameters; call it before any thread starts
    // (the CLI's `main` and the benchmarks do).
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 32 << 20);
        libc::mallopt(libc::M_TRIM_THRESHOLD, 512 << 20);
    }
}

/// Says on stderr when the GPU trainer rendered frames with only the tile/Gaussian pairs that fit
/// its sort buffers ([`crate::train::TrainReport::truncated_frames`]).
fn warn_truncated(frames: usize) {
    if frames > 0 {
        eprintln!("warning: {frames} training iteration(s) rendered only the tile/Gaussian pairs that fit the GPU sort buffers");
    }
}

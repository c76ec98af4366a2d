//! `gscodec`: the encoder side — scene I/O, trainer, metrics and the CLI.
//!
//! | module | one job |
//! |---|---|
//! | [`encoder`] | the front door: [`Encoder`], [`EncoderConfig`], [`Lambda`], the training-backend seam |
//! | [`rate`] | quantisation, the RD search, the rate term of training, the attribute groups |
//! | [`train`] | the CPU trainer (Adam, densification, schedule) |
//! | [`loss`] | image losses with gradients (L1+SSIM, WD, WD-R) |
//! | [`io`] | scenes (`.ply`, `.spz`, `.splat`, `.gsc` reading) and posed-image datasets |
//! | [`metrics`] | PSNR, SSIM, MS-SSIM, FLIP, WD, BD-rate, plots |
//! | [`sweep`] | λ sweeps: encode, measure, tabulate |
//! | [`decoder`] | the `gscodec-decoder` crate |
//!
//! Dependencies flow one way: `cli` → `sweep` → `encoder` → `train` → `rate` → `decoder` (one
//! exception: `sweep` measures points with `cli::eval::measure`, the one implementation of `eval`).

pub use gscodec_decoder as decoder;

#[doc(hidden)]
pub mod anchor;
pub mod cli;
pub mod encoder;
pub mod error;
pub mod io;
pub mod loss;
pub mod metrics;
pub(crate) mod optim;
#[doc(hidden)]
pub mod raster;
pub mod rate;
#[doc(hidden)]
pub mod rng;
pub mod sample;
pub mod sweep;
#[doc(hidden)]
pub mod testkit;
pub mod train;
pub mod views;

pub use encoder::{Encoder, EncoderConfig, Lambda};
pub use error::{Error, Result};

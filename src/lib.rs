//! `gscodec`: the encoder side — scene I/O, trainer, metrics and the CLI.

pub use gscodec_decoder as decoder;

pub mod cli;
pub mod encoder;
pub mod error;
pub mod io;
pub mod loss;
pub mod metrics;
pub mod optim;
pub mod raster;
pub mod rate;
pub mod rng;
pub mod sample;
pub mod sweep;
pub mod train;
pub mod views;

pub use error::{Error, Result};

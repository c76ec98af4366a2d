//! Image quality metrics, Bjøntegaard deltas and plots.
//!
//! | module | one job |
//! |---|---|
//! | [`ms_ssim`] | multi-scale SSIM (5 scales, Wang et al. 2003 weights) |
//! | [`flip`] | ꟻLIP (LDR) mean error through NVIDIA's implementation |
//! | [`bdrate`] | Bjøntegaard delta rate / delta quality between two RD curves |
//! | [`plot`] | dependency-free SVG line plots |
//! | [`view`] | every metric of a rendered view, and means over views (what `eval` reports) |
//!
//! SSIM itself lives in [`crate::loss::ssim`] (one definition shared with training), PSNR and MSE
//! beside the decoder's `Image` (`gscodec_decoder::render`, so that the decoder's GPU tests use
//! the same PSNR); all three are re-exported here.

pub mod bdrate;
pub mod flip;
pub mod ms_ssim;
pub mod plot;
pub mod view;

pub use crate::loss::ssim::ssim;
pub use flip::flip;
pub use gscodec_decoder::render::{mse, psnr};
pub use ms_ssim::ms_ssim;

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
//! SSIM itself lives in [`crate::loss::ssim`] (one definition shared with training).

pub mod bdrate;
pub mod flip;
pub mod ms_ssim;
pub mod plot;
pub mod view;

use gscodec_decoder::Image;

pub use crate::loss::ssim::ssim;
pub use flip::flip;
pub use ms_ssim::ms_ssim;

/// Mean squared error over all channels and pixels.
pub fn mse(a: &Image, b: &Image) -> f64 {
    assert_eq!((a.width, a.height), (b.width, b.height), "MSE of images of different sizes");
    let s: f64 = a.data.iter().zip(&b.data).map(|(x, y)| (*x as f64 - *y as f64).powi(2)).sum();
    s / a.data.len().max(1) as f64
}

/// PSNR in dB for a peak of 1.0 (capped at 100 dB for identical images).
pub fn psnr(a: &Image, b: &Image) -> f64 {
    let m = mse(a, b);
    if m <= 1e-10 {
        100.0
    } else {
        -10.0 * m.log10()
    }
}

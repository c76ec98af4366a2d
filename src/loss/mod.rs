//! Image losses with analytic gradients: L1, SSIM, WD, WD-R.

pub mod ssim;

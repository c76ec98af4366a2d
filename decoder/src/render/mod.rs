//! Rendering: per-Gaussian preprocessing, tile binning and the CPU rasterizer (f32), plus an f64
//! brute-force reference with the same semantics for testing.

mod cpu;
/// The f64 brute-force renderer: the test oracle of the f32 renderers, not an API.
#[doc(hidden)]
pub mod reference;

/// The CPU renderer's stages, shared with the encoder's differentiable rasterizer; not an API.
#[doc(hidden)]
pub use cpu::{
    bin_tiles, block_reaches, composite, composite_lanes, composite_with, cull_thresholds, gather_tile, preprocess, Projected, TileBins,
    TileBlocks, TileGaussian, LANES,
};
pub use cpu::{contributions, contributions_and_removal_errors, record, removal_errors, render, replay, Recording};

/// A linear-in-file RGB float image, row-major, channels interleaved (`data[(y*w + x)*3 + c]`).
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `width × height × 3` values, row-major, RGB interleaved.
    pub data: Vec<f32>,
}

impl Image {
    /// An image filled with one colour.
    pub fn filled(width: u32, height: u32, rgb: [f32; 3]) -> Image {
        Image { width, height, data: rgb.repeat((width * height) as usize) }
    }

    /// The RGB value of pixel `(x, y)`.
    pub fn pixel(&self, x: u32, y: u32) -> [f32; 3] {
        let i = ((y * self.width + x) * 3) as usize;
        [self.data[i], self.data[i + 1], self.data[i + 2]]
    }
}

/// Mean squared error over all channels and pixels.
///
/// # Panics
/// If the images differ in size.
pub fn mse(a: &Image, b: &Image) -> f64 {
    assert_eq!((a.width, a.height), (b.width, b.height), "MSE of images of different sizes");
    let s: f64 = a.data.iter().zip(&b.data).map(|(x, y)| (*x as f64 - *y as f64).powi(2)).sum();
    s / a.data.len().max(1) as f64
}

/// PSNR in dB for a peak of 1.0, capped at 100 dB (identical images): the one PSNR of the
/// project (`gscodec::metrics::psnr` is this function).
///
/// # Panics
/// If the images differ in size.
pub fn psnr(a: &Image, b: &Image) -> f64 {
    psnr_of_mse(mse(a, b))
}

/// PSNR in dB of a mean squared error `m` for a peak of 1.0, capped at 100 dB (`m` ≤ 1e-10).
pub fn psnr_of_mse(m: f64) -> f64 {
    if m <= 1e-10 {
        100.0
    } else {
        -10.0 * m.log10()
    }
}

/// Options of a render.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RenderOptions {
    /// Colour behind the Gaussians (added with the final transmittance).
    pub background: [f32; 3],
    /// Use SH up to this degree (clamped to the scene's degree).
    pub max_sh_degree: u8,
}

impl Default for RenderOptions {
    fn default() -> Self {
        RenderOptions { background: [0.0; 3], max_sh_degree: 3 }
    }
}

#[cfg(feature = "gpu")]
pub mod gpu;

//! Multi-scale SSIM (Wang, Simoncelli & Bovik 2003), computed as the widely used
//! `pytorch_msssim` package does, so our figures are comparable with published ones:
//!
//! - 5 scales with weights [`WEIGHTS`]; between scales each image is 2×2 average-pooled (an odd
//!   side is zero-padded by one pixel on both ends first, the padding counting in the average, as
//!   `F.avg_pool2d(x, 2, padding=s % 2)` does);
//! - at each scale the 11×11 Gaussian window (σ = 1.5) statistics of [`crate::loss::ssim`] are
//!   averaged over the *valid* region only (pixels whose window lies inside the image);
//! - the contrast-structure means of scales 1–4 and the SSIM mean of scale 5 are clamped at 0,
//!   raised to their weights and multiplied, per channel; the channels are averaged.
//!
//! The coarsest scale needs a valid region of at least one pixel, so both image sides must be at
//! least [`MIN_SIDE`] = 161 pixels; smaller images give [`TooSmall`] rather than a made-up value.

use gscodec_decoder::Image;

use crate::loss::ssim::{channel, luminance_cs_maps, WINDOW};

/// Scale weights of Wang et al. 2003 (finest first).
pub const WEIGHTS: [f64; 5] = [0.0448, 0.2856, 0.3001, 0.2363, 0.1333];

/// Smallest image side MS-SSIM accepts: `(WINDOW - 1) · 2⁴ + 1`.
pub const MIN_SIDE: u32 = ((WINDOW - 1) * 16 + 1) as u32;

/// The images are too small for the 5 scales of MS-SSIM.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("MS-SSIM needs both image sides >= {MIN_SIDE} pixels for its 5 scales, got {width}x{height}")]
pub struct TooSmall {
    /// Width of the images given.
    pub width: u32,
    /// Height of the images given.
    pub height: u32,
}

/// Mean MS-SSIM over the RGB channels of two images of values in [0, 1].
///
/// # Errors
/// [`TooSmall`] when a side is shorter than [`MIN_SIDE`].
///
/// # Panics
/// If the two images differ in size.
pub fn ms_ssim(a: &Image, b: &Image) -> Result<f64, TooSmall> {
    assert_eq!((a.width, a.height), (b.width, b.height), "MS-SSIM of images of different sizes");
    if a.width < MIN_SIDE || a.height < MIN_SIDE {
        return Err(TooSmall { width: a.width, height: a.height });
    }
    let (w, h) = (a.width as usize, a.height as usize);
    let total: f64 = (0..3).map(|c| ms_ssim_plane(channel(a, c), channel(b, c), w, h)).sum();
    Ok(total / 3.0)
}

/// MS-SSIM of one channel pair (sides already checked).
fn ms_ssim_plane(mut x: Vec<f64>, mut y: Vec<f64>, mut w: usize, mut h: usize) -> f64 {
    let mut value = 1.0;
    for (scale, weight) in WEIGHTS.iter().enumerate() {
        let (l, cs) = luminance_cs_maps(&x, &y, w, h);
        let last = scale + 1 == WEIGHTS.len();
        let term = if last { valid_mean(l.iter().zip(&cs).map(|(l, cs)| l * cs), w, h) } else { valid_mean(cs.into_iter(), w, h) };
        value *= term.max(0.0).powf(*weight);
        if !last {
            let (nw, nh);
            (x, nw, nh) = avg_pool2(&x, w, h);
            (y, _, _) = avg_pool2(&y, w, h);
            (w, h) = (nw, nh);
        }
    }
    value
}

/// Mean of a `w x h` map over the pixels whose whole window lies inside the image: there the
/// zero-padded "same" filtering of [`crate::loss::ssim::blur`] equals a "valid" convolution.
fn valid_mean(map: impl Iterator<Item = f64>, w: usize, h: usize) -> f64 {
    let r = WINDOW / 2;
    let (mut sum, mut n) = (0.0, 0usize);
    for (i, v) in map.enumerate() {
        let (px, py) = (i % w, i / w);
        if px >= r && px + r < w && py >= r && py + r < h {
            sum += v;
            n += 1;
        }
    }
    sum / n as f64
}

/// 2×2 average pooling with stride 2; an odd side is zero-padded by one pixel on both ends and
/// the padding counts in the average (PyTorch `avg_pool2d(x, 2, padding=s % 2)`).
fn avg_pool2(plane: &[f64], w: usize, h: usize) -> (Vec<f64>, usize, usize) {
    let (pw, ph) = (w % 2, h % 2);
    let (ow, oh) = ((w + 2 * pw) / 2, (h + 2 * ph) / 2);
    let at = |x: isize, y: isize| {
        if x < 0 || y < 0 || x >= w as isize || y >= h as isize {
            0.0
        } else {
            plane[y as usize * w + x as usize]
        }
    };
    let mut out = Vec::with_capacity(ow * oh);
    for oy in 0..oh {
        for ox in 0..ow {
            let (x0, y0) = ((2 * ox) as isize - pw as isize, (2 * oy) as isize - ph as isize);
            out.push((at(x0, y0) + at(x0 + 1, y0) + at(x0, y0 + 1) + at(x0 + 1, y0 + 1)) / 4.0);
        }
    }
    (out, ow, oh)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pooling_matches_torch_on_odd_sides() {
        // avg_pool2d([[1,2,3],[4,5,6],[7,8,9]], 2, padding=1) = [[1/4, 5/4], [11/4, 28/4]]
        let (out, w, h) = avg_pool2(&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0], 3, 3);
        assert_eq!((w, h), (2, 2));
        assert_eq!(out, vec![0.25, 1.25, 2.75, 7.0]);
        let (out, w, h) = avg_pool2(&[1.0, 2.0, 3.0, 4.0], 4, 1);
        assert_eq!((w, h), (2, 1));
        assert_eq!(out, vec![0.75, 1.75]);
    }
}

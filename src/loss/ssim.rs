//! SSIM with the 11x11 Gaussian window (σ = 1.5) of the reference 3DGS code: zero-padded "same"
//! filtering per channel, constants C1 = 0.01², C2 = 0.03², mean over channels and pixels; and its
//! analytic gradient with respect to the first image.
//!
//! Computed in f64 with a separable filter (5 blurs forward, 3 more for the gradient per channel);
//! the zero-padded filter with a symmetric kernel is self-adjoint, so the backward pass reuses it.

use gscodec_decoder::Image;
use rayon::prelude::*;

pub const WINDOW: usize = 11;
pub const SIGMA: f64 = 1.5;
pub const C1: f64 = 0.01 * 0.01;
pub const C2: f64 = 0.03 * 0.03;

/// Normalised 1-D Gaussian taps of the SSIM window.
pub fn gaussian_taps() -> [f64; WINDOW] {
    let half = (WINDOW / 2) as f64;
    let mut t: [f64; WINDOW] = std::array::from_fn(|i| (-((i as f64 - half).powi(2)) / (2.0 * SIGMA * SIGMA)).exp());
    let s: f64 = t.iter().sum();
    t.iter_mut().for_each(|v| *v /= s);
    t
}

/// Rows per parallel work item: enough that small images stay on one thread.
const ROWS_PER_TASK: usize = 16;

/// Separable "same" blur with zero padding into `out`, using `tmp` (both `w*h`). Rows are
/// computed in parallel; every output value is the same sum in the same order whatever the
/// thread count, so results are bit-identical across thread counts.
fn blur_into(plane: &[f64], w: usize, h: usize, taps: &[f64; WINDOW], tmp: &mut [f64], out: &mut [f64]) {
    let r = WINDOW / 2;
    // Horizontal pass, a tap at a time over the row (vectorises): each sample still gets its
    // taps inside the row added in ascending order from 0, so the sums are the same.
    plane.par_chunks_exact(w).zip(tmp.par_chunks_exact_mut(w)).with_min_len(ROWS_PER_TASK).for_each(|(src, dst)| {
        dst.fill(0.0);
        for (k, &t) in taps.iter().enumerate() {
            // Samples x whose tap k reads inside the row: 0 ≤ x + k − r < w.
            let (lo, hi) = (r.saturating_sub(k), (w + r).saturating_sub(k).min(w));
            if lo < hi {
                let from = lo + k - r;
                for (d, s) in dst[lo..hi].iter_mut().zip(&src[from..from + (hi - lo)]) {
                    *d += t * s;
                }
            }
        }
    });
    // Vertical pass: whole rows at a time (vectorises).
    let tmp = &*tmp;
    out[..w * h].par_chunks_exact_mut(w).enumerate().with_min_len(ROWS_PER_TASK).for_each(|(y, dst)| {
        dst.fill(0.0);
        let k0 = r.saturating_sub(y);
        let k1 = (h + r - y).min(WINDOW);
        for k in k0..k1 {
            let yy = y + k - r;
            let t = taps[k];
            for (d, s) in dst.iter_mut().zip(&tmp[yy * w..(yy + 1) * w]) {
                *d += t * s;
            }
        }
    });
}

/// Separable "same" convolution of a single-channel `w x h` plane with zero padding.
pub fn blur(plane: &[f64], w: usize, h: usize) -> Vec<f64> {
    let (mut tmp, mut out) = (vec![0.0; w * h], vec![0.0; w * h]);
    blur_into(plane, w, h, &gaussian_taps(), &mut tmp, &mut out);
    out
}

/// Channel `c` of an interleaved RGB image as an f64 plane.
pub fn channel(img: &Image, c: usize) -> Vec<f64> {
    img.data.chunks_exact(3).map(|p| p[c] as f64).collect()
}

/// SSIM of one channel pair: the per-pixel map's sum and, when `grad` is given, the gradient of
/// that sum w.r.t. `x` written into it.
fn channel_ssim(x: &[f64], y: &[f64], w: usize, h: usize, grad: Option<&mut [f64]>) -> (f64, Vec<f64>) {
    let n = w * h;
    let taps = gaussian_taps();
    let mut tmp = vec![0.0; n];
    let mut bl = |src: &[f64]| {
        let mut out = vec![0.0; n];
        blur_into(src, w, h, &taps, &mut tmp, &mut out);
        out
    };
    let prod = |a: &[f64], b: &[f64]| a.par_iter().zip(b).with_min_len(ROWS_PER_TASK * w).map(|(p, q)| p * q).collect::<Vec<_>>();
    let (mx, my) = (bl(x), bl(y));
    let (sxx, syy, sxy) = (bl(&prod(x, x)), bl(&prod(y, y)), bl(&prod(x, y)));
    // Per pixel (in parallel, each value computed alone): the map and d(map)/d(statistics).
    let stats: Vec<[f64; 4]> = (0..n)
        .into_par_iter()
        .with_min_len(ROWS_PER_TASK * w)
        .map(|i| {
            let (vx, vy, cxy) = (sxx[i] - mx[i] * mx[i], syy[i] - my[i] * my[i], sxy[i] - mx[i] * my[i]);
            let (a1, a2) = (2.0 * mx[i] * my[i] + C1, 2.0 * cxy + C2);
            let (b1, b2) = (mx[i] * mx[i] + my[i] * my[i] + C1, vx + vy + C2);
            let s = (a1 * a2) / (b1 * b2);
            let ds_dm = 2.0 * my[i] * a2 / (b1 * b2) - s * 2.0 * mx[i] / b1;
            let ds_dv = -s / b2;
            let ds_dc = 2.0 * a1 / (b1 * b2);
            [s, ds_dm - 2.0 * mx[i] * ds_dv - my[i] * ds_dc, ds_dv, ds_dc]
        })
        .collect();
    let map: Vec<f64> = stats.par_iter().with_min_len(ROWS_PER_TASK * w).map(|v| v[0]).collect();
    // Summed in pixel order (a fixed order, whatever the thread count).
    let total = map.iter().sum();
    if let Some(grad) = grad {
        let pick = |k: usize| stats.par_iter().with_min_len(ROWS_PER_TASK * w).map(|v| v[k]).collect::<Vec<f64>>();
        let (bm, bxx, bxy) = (bl(&pick(1)), bl(&pick(2)), bl(&pick(3)));
        grad.par_iter_mut().enumerate().with_min_len(ROWS_PER_TASK * w).for_each(|(i, g)| {
            *g = bm[i] + 2.0 * x[i] * bxx[i] + y[i] * bxy[i];
        });
    }
    (total, map)
}

/// Per-pixel SSIM map of one channel pair.
pub fn ssim_map(x: &[f64], y: &[f64], w: usize, h: usize) -> Vec<f64> {
    channel_ssim(x, y, w, h, None).1
}

/// Mean SSIM over channels and pixels. Panics if the sizes differ.
pub fn ssim(a: &Image, b: &Image) -> f64 {
    assert_eq!((a.width, a.height), (b.width, b.height), "SSIM of images of different sizes");
    let (w, h) = (a.width as usize, a.height as usize);
    let per: Vec<f64> = (0..3usize).into_par_iter().map(|c| channel_ssim(&channel(a, c), &channel(b, c), w, h, None).0).collect();
    per.iter().sum::<f64>() / (3 * w * h) as f64
}

/// Mean SSIM and its gradient with respect to `a` (interleaved RGB like the image).
pub fn ssim_and_grad(a: &Image, b: &Image) -> (f64, Vec<f32>) {
    assert_eq!((a.width, a.height), (b.width, b.height), "SSIM of images of different sizes");
    let (w, h) = (a.width as usize, a.height as usize);
    let n = (3 * w * h) as f64;
    let per: Vec<(f64, Vec<f64>)> = (0..3usize)
        .into_par_iter()
        .map(|c| {
            let mut g = vec![0.0; w * h];
            let (s, _) = channel_ssim(&channel(a, c), &channel(b, c), w, h, Some(&mut g));
            (s, g)
        })
        .collect();
    let mut grad = vec![0.0f32; 3 * w * h];
    grad.par_chunks_exact_mut(3).enumerate().with_min_len(ROWS_PER_TASK * w).for_each(|(i, px)| {
        for (c, (_, g)) in per.iter().enumerate() {
            px[c] = (g[i] / n) as f32;
        }
    });
    (per.iter().map(|p| p.0).sum::<f64>() / n, grad)
}

/// Per-pixel luminance term `l = (2μxμy + C1)/(μx² + μy² + C1)` and contrast-structure term
/// `cs = (2σxy + C2)/(σx² + σy² + C2)` of one channel pair, from the same window statistics as
/// [`ssim_map`] (whose value is `l·cs`). MS-SSIM uses `cs` alone at its finer scales.
pub fn luminance_cs_maps(x: &[f64], y: &[f64], w: usize, h: usize) -> (Vec<f64>, Vec<f64>) {
    let sq = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(p, q)| p * q).collect::<Vec<_>>();
    let (mx, my) = (blur(x, w, h), blur(y, w, h));
    let (sxx, syy, sxy) = (blur(&sq(x, x), w, h), blur(&sq(y, y), w, h), blur(&sq(x, y), w, h));
    (0..w * h)
        .map(|i| {
            let (vx, vy, cxy) = (sxx[i] - mx[i] * mx[i], syy[i] - my[i] * my[i], sxy[i] - mx[i] * my[i]);
            let l = (2.0 * mx[i] * my[i] + C1) / (mx[i] * mx[i] + my[i] * my[i] + C1);
            (l, (2.0 * cxy + C2) / (vx + vy + C2))
        })
        .unzip()
}

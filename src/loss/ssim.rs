//! SSIM with the 11x11 Gaussian window (σ = 1.5) of the reference 3DGS code: zero-padded "same"
//! filtering per channel, constants C1 = 0.01², C2 = 0.03², mean over channels and pixels.

use gscodec_decoder::Image;

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

/// Separable "same" convolution of a single-channel `w x h` plane with zero padding.
pub fn blur(plane: &[f64], w: usize, h: usize) -> Vec<f64> {
    let taps = gaussian_taps();
    let r = (WINDOW / 2) as isize;
    let mut tmp = vec![0.0; w * h];
    for y in 0..h {
        for x in 0..w {
            let mut s = 0.0;
            for (k, t) in taps.iter().enumerate() {
                let xx = x as isize + k as isize - r;
                if xx >= 0 && (xx as usize) < w {
                    s += t * plane[y * w + xx as usize];
                }
            }
            tmp[y * w + x] = s;
        }
    }
    let mut out = vec![0.0; w * h];
    for y in 0..h {
        for x in 0..w {
            let mut s = 0.0;
            for (k, t) in taps.iter().enumerate() {
                let yy = y as isize + k as isize - r;
                if yy >= 0 && (yy as usize) < h {
                    s += t * tmp[yy as usize * w + x];
                }
            }
            out[y * w + x] = s;
        }
    }
    out
}

/// Channel `c` of an interleaved RGB image as an f64 plane.
pub fn channel(img: &Image, c: usize) -> Vec<f64> {
    img.data.chunks_exact(3).map(|p| p[c] as f64).collect()
}

/// Per-pixel SSIM map of one channel pair.
pub fn ssim_map(x: &[f64], y: &[f64], w: usize, h: usize) -> Vec<f64> {
    let sq = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(p, q)| p * q).collect::<Vec<_>>();
    let (mx, my) = (blur(x, w, h), blur(y, w, h));
    let (sxx, syy, sxy) = (blur(&sq(x, x), w, h), blur(&sq(y, y), w, h), blur(&sq(x, y), w, h));
    (0..w * h)
        .map(|i| {
            let (vx, vy, cxy) = (sxx[i] - mx[i] * mx[i], syy[i] - my[i] * my[i], sxy[i] - mx[i] * my[i]);
            ((2.0 * mx[i] * my[i] + C1) * (2.0 * cxy + C2)) / ((mx[i] * mx[i] + my[i] * my[i] + C1) * (vx + vy + C2))
        })
        .collect()
}

/// Mean SSIM over channels and pixels. Panics if the sizes differ.
pub fn ssim(a: &Image, b: &Image) -> f64 {
    assert_eq!((a.width, a.height), (b.width, b.height), "SSIM of images of different sizes");
    let (w, h) = (a.width as usize, a.height as usize);
    let total: f64 = (0..3).map(|c| ssim_map(&channel(a, c), &channel(b, c), w, h).iter().sum::<f64>()).sum();
    total / (3 * w * h) as f64
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

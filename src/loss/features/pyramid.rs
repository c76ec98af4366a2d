//! `pyramid`: a fixed, weight-free texture feature space (see `docs/wd.md`).
//!
//! Arrays: the ImageNet-normalised image (3 channels, full resolution), then for each of
//! [`STAGES`] stages (full, ½, ¼, ⅛ resolution; the luminance is low-passed and subsampled by 2
//! between stages like VGG's pooling) 16 rectified, oriented responses of the stage's luminance:
//! first (odd phase) and second (even phase) derivatives of a Gaussian, steered to 0°, 45°, 90°
//! and 135° (Freeman & Adelson's steerable G1/G2 basis), each split into its positive and
//! negative half-wave (`relu(r)`, `relu(−r)`), scaled by [`GAIN`].
//!
//! `pyramid-colour` ([`Pyramid::COLOUR`]) adds the same 16 responses of two opponent colour
//! signals (red–green, yellow–blue) at the ½, ¼ and ⅛ stages, after the luminance's arrays.

use rayon::prelude::*;

use super::{normalize, normalize_adjoint, Backward, Extracted, FeatureSpace};
use crate::loss::tensor::{half, Real, Tensor};

/// Number of filter-bank stages.
pub const STAGES: usize = 4;
/// Standard deviation of the derivative-of-Gaussian filters, in stage pixels.
pub const FILTER_SIGMA: f64 = 1.0;
/// Filter radius in stage pixels (7 taps).
pub const RADIUS: usize = 3;
/// Scale of the oriented responses (derivatives in normalised intensity per stage pixel).
/// Calibrated on lego-200 (`examples/wd_calibrate.rs`) so that, as the paper reports for VGG,
/// ‖∇d_WD‖ / ‖∇(β·L_orig)‖ ≈ 1.6 for a moderately blurred rendering (1.06 / 1.58 / 2.24 for
/// light / moderate / strong blur), which keeps the paper's γ meaningful.
pub const GAIN: f64 = 16.0;
/// Orientations of the steered filters, in degrees.
pub const ORIENTATIONS: [f64; 4] = [0.0, 45.0, 90.0, 135.0];
/// Channels per stage array: 4 orientations × (odd, even) × (positive, negative).
pub const STAGE_CHANNELS: usize = 16;

/// The weight-free feature space: the luminance bank (`pyramid`), or with the opponent colour
/// signals too (`pyramid-colour`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Pyramid {
    pub colour: bool,
}

impl Pyramid {
    /// `pyramid`: oriented responses of the luminance only.
    pub const LUMA: Pyramid = Pyramid { colour: false };
    /// `pyramid-colour`: also of the two opponent colour signals.
    pub const COLOUR: Pyramid = Pyramid { colour: true };

    /// The signals the bank analyses, in the order of their arrays.
    pub fn signals(&self) -> &'static [Signal] {
        if self.colour {
            &SIGNALS
        } else {
            &SIGNALS[..1]
        }
    }
}

/// 1-D taps of g, g′ and g″ (Gaussian, σ = [`FILTER_SIGMA`]), normalised so that the
/// derivative filters measure slope and curvature: Σ t·g′(t) = 1 (correlation) gives
/// response 1 to a unit ramp, Σ ½t²·g″(t) = 1 response 1 to ½t². (Also the GPU trainer's taps.)
pub fn taps() -> ([f64; 2 * RADIUS + 1], [f64; 2 * RADIUS + 1], [f64; 2 * RADIUS + 1]) {
    let s2 = FILTER_SIGMA * FILTER_SIGMA;
    let t = |i: usize| i as f64 - RADIUS as f64;
    let mut g: [f64; 2 * RADIUS + 1] = std::array::from_fn(|i| (-t(i) * t(i) / (2.0 * s2)).exp());
    let sum: f64 = g.iter().sum();
    g.iter_mut().for_each(|v| *v /= sum);
    let mut d1: [f64; 2 * RADIUS + 1] = std::array::from_fn(|i| t(i) * g[i]);
    let n1: f64 = d1.iter().enumerate().map(|(i, v)| t(i) * v).sum();
    d1.iter_mut().for_each(|v| *v /= n1);
    let mut d2: [f64; 2 * RADIUS + 1] = std::array::from_fn(|i| (t(i) * t(i) - s2) * g[i]);
    let mean: f64 = d2.iter().sum::<f64>() / d2.len() as f64;
    d2.iter_mut().for_each(|v| *v -= mean); // zero DC exactly
    let n2: f64 = d2.iter().enumerate().map(|(i, v)| 0.5 * t(i) * t(i) * v).sum();
    d2.iter_mut().for_each(|v| *v /= n2);
    (g, d1, d2)
}

/// Separable correlation with zero padding: `out[y][x] = Σ ky[j] kx[i] in[y+j−r][x+i−r]`.
fn correlate<T: Real>(x: &[T], h: usize, w: usize, kx: &[T], ky: &[T]) -> Vec<T> {
    correlate_columns(&correlate_rows(x, h, w, kx), h, w, ky)
}

/// The horizontal pass of [`correlate`]: each row on a zero-padded copy, a tap at a time over the
/// row (no bounds checks, vectorises; each sample's taps are still summed in order from 0).
fn correlate_rows<T: Real>(x: &[T], h: usize, w: usize, kx: &[T]) -> Vec<T> {
    let r = kx.len() / 2;
    let mut tmp = vec![T::zero(); h * w];
    let mut padded = vec![T::zero(); w + 2 * r];
    for y in 0..h {
        padded[r..r + w].copy_from_slice(&x[y * w..(y + 1) * w]);
        let row = &mut tmp[y * w..(y + 1) * w];
        for (k, &t) in kx.iter().enumerate() {
            for (o, &v) in row.iter_mut().zip(&padded[k..k + w]) {
                *o = *o + t * v;
            }
        }
    }
    tmp
}

/// The vertical pass of [`correlate`] over whole rows of the horizontal pass's output.
fn correlate_columns<T: Real>(tmp: &[T], h: usize, w: usize, ky: &[T]) -> Vec<T> {
    let r = ky.len() / 2;
    let mut out = vec![T::zero(); h * w];
    for y in 0..h {
        for (k, &t) in ky.iter().enumerate() {
            let yy = y as isize + k as isize - r as isize;
            if yy < 0 || yy as usize >= h {
                continue;
            }
            let src = &tmp[yy as usize * w..(yy as usize + 1) * w];
            for (o, &v) in out[y * w..(y + 1) * w].iter_mut().zip(src) {
                *o = *o + t * v;
            }
        }
    }
    out
}

/// The 1-D kernels g, g′, g″ of [`taps`] in `T`.
fn kernels<T: Real>() -> [Vec<T>; 3] {
    let (g, d1, d2) = taps();
    let v = |a: &[f64]| a.iter().map(|&x| T::c(x)).collect::<Vec<T>>();
    [v(&g), v(&d1), v(&d2)]
}

/// The five basis filters Gx, Gy, Gxx, Gxy, Gyy as (horizontal, vertical) indices into
/// [`kernels`].
const BASIS: [(usize, usize); 5] = [(1, 0), (0, 1), (2, 0), (1, 1), (0, 2)];

/// The five basis responses of one stage: [`correlate`] with each [`BASIS`] filter, the
/// horizontal pass done once per kernel (three instead of five, the same values).
fn basis_responses<T: Real>(y: &[T], h: usize, w: usize) -> [Vec<T>; 5] {
    let kernels = kernels::<T>();
    let rows: Vec<Vec<T>> = kernels.par_iter().map(|k| correlate_rows(y, h, w, k)).collect();
    let resp: Vec<Vec<T>> = BASIS.par_iter().map(|&(kx, ky)| correlate_columns(&rows[kx], h, w, &kernels[ky])).collect();
    resp.try_into().unwrap_or_else(|_| unreachable!("five basis filters"))
}

/// Steering coefficients: odd θ = (cos θ, sin θ) over (Gx, Gy); even θ = (cos²θ, 2 cosθ sinθ,
/// sin²θ) over (Gxx, Gxy, Gyy), one pair per [`ORIENTATIONS`] entry.
pub fn steering() -> Vec<([f64; 2], [f64; 3])> {
    ORIENTATIONS
        .iter()
        .map(|deg| {
            let (s, c) = deg.to_radians().sin_cos();
            ([c, s], [c * c, 2.0 * c * s, s * s])
        })
        .collect()
}

/// Basis responses → 16 rectified channels.
fn rectify<T: Real>(resp: &[Vec<T>; 5], h: usize, w: usize) -> Tensor<T> {
    let n = h * w;
    let st = steering();
    let gain = T::c(GAIN);
    let mut out = Tensor::zeros(STAGE_CHANNELS, h, w);
    // Channels 2j and 2j + 1 are the two half-waves of one steered response: steer once.
    out.data.par_chunks_mut((2 * n).max(1)).enumerate().for_each(|(pair, o)| {
        let (orient, phase) = (pair / 2, pair % 2);
        let (odd, even) = st[orient];
        let r: Vec<T> = if phase == 0 {
            let (a, b) = (T::c(odd[0]), T::c(odd[1]));
            resp[0].iter().zip(&resp[1]).map(|(&x, &y)| a * x + b * y).collect()
        } else {
            let (a, b, c) = (T::c(even[0]), T::c(even[1]), T::c(even[2]));
            resp[2].iter().zip(&resp[3]).zip(&resp[4]).map(|((&x, &y), &z)| a * x + b * y + c * z).collect()
        };
        let (pos, neg) = o.split_at_mut(n);
        for (sgn, o) in [(gain, pos), (-gain, neg)] {
            o.iter_mut().zip(&r).for_each(|(o, &r)| *o = (sgn * r).max(T::zero()));
        }
    });
    out
}

/// Gradient of [`rectify`] w.r.t. the five basis responses (one basis filter per task).
fn rectify_adjoint<T: Real>(out: &Tensor<T>, grad: &Tensor<T>) -> [Vec<T>; 5] {
    let n = out.plane_len();
    let st = steering();
    let gain = T::c(GAIN);
    let parts: Vec<Vec<T>> = (0..5)
        .into_par_iter()
        .map(|b| {
            let mut g = vec![T::zero(); n];
            // basis b ∈ {Gx, Gy} feeds the odd channels, {Gxx, Gxy, Gyy} the even ones
            let phase = if b < 2 { 0 } else { 1 };
            for ch in (0..STAGE_CHANNELS).filter(|ch| (ch / 2) % 2 == phase) {
                let (orient, sign) = (ch / 4, ch % 2);
                let (odd, even) = st[orient];
                let coef = if phase == 0 { odd[b] } else { even[b - 2] };
                let k = if sign == 0 { gain } else { -gain } * T::c(coef);
                let (o, gr) = (&out.data[ch * n..(ch + 1) * n], &grad.data[ch * n..(ch + 1) * n]);
                for i in 0..n {
                    if o[i] > T::zero() {
                        g[i] = g[i] + k * gr[i];
                    }
                }
            }
            g
        })
        .collect();
    parts.try_into().unwrap_or_else(|_| unreachable!("five basis filters"))
}

/// A grey-level signal the bank analyses: a linear combination of the normalised image's
/// channels, and the first stage whose oriented responses are features (finer stages only
/// low-pass it on the way).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Signal {
    pub coef: [f64; 3],
    pub first: usize,
}

/// The luminance (the mean of the normalised channels, at every stage), then the opponent colour
/// signals red–green and yellow–blue from the ½-resolution stage on: human sensitivity to
/// chromatic contrast falls off at lower spatial frequencies than to luminance contrast
/// (Mullen 1985), which colour difference measures model with wider chroma filters (S-CIELAB).
pub const SIGNALS: [Signal; 3] = [
    Signal { coef: [1.0 / 3.0, 1.0 / 3.0, 1.0 / 3.0], first: 0 },
    Signal { coef: [0.5, -0.5, 0.0], first: 1 },
    Signal { coef: [0.25, 0.25, -0.5], first: 1 },
];

struct Tape<T> {
    /// Every signal's shape at each stage.
    shapes: Vec<(usize, usize)>,
    /// Per signal: its stage arrays from `first` on (their signs give the relu masks).
    signals: Vec<(Signal, Vec<Tensor<T>>)>,
}

impl<T: Real> Tape<T> {
    /// Gradient w.r.t. one signal at full resolution from its stage arrays' gradients.
    fn signal_adjoint(&self, first: usize, stages: &[Tensor<T>], grads: &[Tensor<T>]) -> Tensor<T> {
        let kernels = kernels::<T>();
        let mut coarser: Option<Tensor<T>> = None;
        for s in (0..STAGES).rev() {
            let (h, w) = self.shapes[s];
            let mut gy = match coarser.take() {
                Some(g) => g.lowpass2_adjoint(h, w),
                None => Tensor::zeros(1, h, w),
            };
            if s >= first {
                let gb = rectify_adjoint(&stages[s - first], &grads[s - first]);
                // Adjoint of correlation = correlation with the reversed kernels.
                let parts: Vec<Vec<T>> = BASIS
                    .par_iter()
                    .zip(gb.par_iter())
                    .map(|(&(kx, ky), g)| {
                        let rx: Vec<T> = kernels[kx].iter().rev().cloned().collect();
                        let ry: Vec<T> = kernels[ky].iter().rev().cloned().collect();
                        correlate(g, h, w, &rx, &ry)
                    })
                    .collect();
                for p in parts {
                    gy.data.iter_mut().zip(p).for_each(|(a, b)| *a = *a + b);
                }
            }
            coarser = Some(gy);
        }
        coarser.expect("at least one stage")
    }
}

impl<T: Real> Backward<T> for Tape<T> {
    fn backward(self: Box<Self>, grads: &[Tensor<T>]) -> Tensor<T> {
        let mut grad = grads[0].clone();
        let n = grad.plane_len();
        let mut at = 1;
        for (signal, stages) in &self.signals {
            let gy = self.signal_adjoint(signal.first, stages, &grads[at..at + stages.len()]);
            at += stages.len();
            for c in 0..3 {
                let k = T::c(signal.coef[c]);
                grad.data[c * n..(c + 1) * n].iter_mut().zip(&gy.data).for_each(|(a, &b)| *a = *a + k * b);
            }
        }
        normalize_adjoint(&mut grad);
        grad
    }
}

impl<T: Real> FeatureSpace<T> for Pyramid {
    fn name(&self) -> &'static str {
        if self.colour {
            "pyramid-colour"
        } else {
            "pyramid"
        }
    }

    fn extract(&self, image: &Tensor<T>) -> Extracted<T> {
        let norm = normalize(image);
        let n = norm.plane_len();
        let shapes: Vec<(usize, usize)> =
            std::iter::successors(Some((norm.h, norm.w)), |&(h, w)| Some((half(h), half(w)))).take(STAGES).collect();
        let mut signals = Vec::new();
        for &signal in self.signals() {
            let k = signal.coef.map(T::c);
            let (r, g, b) = (&norm.data[..n], &norm.data[n..2 * n], &norm.data[2 * n..]);
            let y: Vec<T> = if k[0] == k[1] && k[1] == k[2] {
                (0..n).map(|i| k[0] * (r[i] + g[i] + b[i])).collect() // the luminance's own rounding
            } else {
                (0..n).map(|i| k[0] * r[i] + k[1] * g[i] + k[2] * b[i]).collect()
            };
            let mut y = Tensor::from_vec(1, norm.h, norm.w, y);
            let mut stages = Vec::with_capacity(STAGES);
            for s in 0..STAGES {
                if s > 0 {
                    y = y.lowpass2();
                }
                if s >= signal.first {
                    stages.push(rectify(&basis_responses(&y.data, y.h, y.w), y.h, y.w));
                }
            }
            signals.push((signal, stages));
        }
        let mut arrays = vec![norm];
        for (_, stages) in &signals {
            arrays.extend(stages.iter().cloned());
        }
        Extracted { arrays, tape: Box::new(Tape { shapes, signals }) }
    }
}

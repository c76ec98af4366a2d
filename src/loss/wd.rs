//! Wasserstein Distortion (WD) between two lists of feature arrays, with its analytic gradient.
//!
//! This follows the WD authors' public reference (`codex`, `wasserstein.py`) formula by formula:
//!
//! * statistics: on the running arrays `x` and `q = x²`, for k = 1..=5: `m_k = K*x`, `p_k = K*q`,
//!   `v_k = p_k − m_k²` with K = [¼,½,¼]⊗[¼,½,¼] (zero padding); then `x ← m_k[::2, ::2]`,
//!   `q ← p_k[::2, ::2]`;
//! * maps: level 0 is `(f − f̂)²`; level k is `(m_k − m̂_k)² + (√v_k⁺ − √v̂_k⁺)²`;
//! * weights: `w_i = relu(1 − |ℓ_i − i|)` with `ℓ_0 = ℓ_1 = ℓ` and `ℓ_{i+1} = lowpass2(ℓ_i)`
//!   (stride-2 "SAME" low-pass, so the border is attenuated by the zero padding), where `ℓ` is
//!   log2 σ resized to the array (linear, antialiased), minus the array's mean log2 downscale
//!   factor, then relu'd;
//! * value: Σ_arrays Σ_levels mean over (channels, pixels) of `w_i · map_i`.
//!
//! Gradient rules as in the reference: `√` has derivative `min(½/√x, 1e6)`, and the clamp
//! `max(v, 0)` passes the gradient where `v ≥ 0` or where the gradient is negative.
//!
//! Speed-ups (the paper's, exact): levels whose weight is zero everywhere are never computed (the
//! cascade stops at the highest needed level), and the reference side's statistics are computed
//! once into a [`Reference`] that callers may cache.

use rayon::prelude::*;

use super::tensor::{blur_into, Real, Tensor};

/// Number of low-pass levels above the pointwise level 0.
pub const NUM_LEVELS: usize = 5;
/// Bound on the derivative of `√` applied to variances.
pub const SQRT_GRAD_LIMIT: f64 = 1e6;
/// Default pooling scale σ (paper: 4, so log2 σ = 2).
pub const DEFAULT_SIGMA: f64 = 4.0;

/// The pooling scale σ, given at image resolution.
#[derive(Clone, Debug, PartialEq)]
pub enum Sigma {
    /// The same σ everywhere (σ ≤ 0 means pointwise: log2 σ is clamped at 0).
    Constant(f64),
    /// A per-pixel map of log2 σ, row-major `height × width` (any size; resized to each array).
    Log2Map { height: usize, width: usize, log2: Vec<f64> },
}

impl Default for Sigma {
    fn default() -> Self {
        Sigma::Constant(DEFAULT_SIGMA)
    }
}

impl Sigma {
    /// A per-pixel σ map (`height × width`, row-major), values σ > 0.
    pub fn map(height: usize, width: usize, sigma: &[f64]) -> Self {
        assert_eq!(sigma.len(), height * width, "σ map length does not match its size");
        Sigma::Log2Map { height, width, log2: sigma.iter().map(|s| s.log2()).collect() }
    }

    /// Largest log2 σ; WD needs it ≤ [`NUM_LEVELS`].
    pub fn max_log2(&self) -> f64 {
        match self {
            Sigma::Constant(s) => s.log2(),
            Sigma::Log2Map { log2, .. } => log2.iter().cloned().fold(f64::NEG_INFINITY, f64::max),
        }
    }

    /// `ℓ` for an `h × w` array of an image of `img_h × img_w` pixels (before the level cascade).
    fn log2_for<T: Real>(&self, img_h: usize, img_w: usize, h: usize, w: usize) -> Tensor<T> {
        let ratio = ((img_h as f64 / h as f64).log2() + (img_w as f64 / w as f64).log2()) / 2.0;
        let relu = |v: f64| T::c((v - ratio).max(0.0));
        match self {
            Sigma::Constant(s) => Tensor::from_vec(1, h, w, vec![relu(s.log2()); h * w]),
            Sigma::Log2Map { height, width, log2 } => {
                let resized = resize_linear_antialias(log2, *height, *width, h, w);
                Tensor::from_vec(1, h, w, resized.into_iter().map(relu).collect())
            }
        }
    }
}

/// Per-level weight maps of one feature array; `None` where the weight is zero everywhere.
#[derive(Clone, Debug, PartialEq)]
pub struct Plan<T> {
    /// `weights[i]`, i = 0..=NUM_LEVELS, one channel at that level's resolution.
    pub weights: Vec<Option<Tensor<T>>>,
}

impl<T: Real> Plan<T> {
    pub fn new(sigma: &Sigma, img_h: usize, img_w: usize, h: usize, w: usize) -> Self {
        let mut ls = sigma.log2_for::<T>(img_h, img_w, h, w);
        let mut weights = Vec::with_capacity(NUM_LEVELS + 1);
        for i in 0..=NUM_LEVELS {
            let ti = T::c(i as f64);
            let wmap: Vec<T> = ls.data.iter().map(|&l| (T::one() - (l - ti).abs()).max(T::zero())).collect();
            let any = wmap.iter().any(|&v| v > T::zero());
            weights.push(any.then(|| Tensor::from_vec(1, ls.h, ls.w, wmap)));
            if i > 0 && i < NUM_LEVELS {
                ls = ls.lowpass2();
            }
        }
        Plan { weights }
    }

    /// Highest level with a non-zero weight (0 when only the pointwise level counts).
    pub fn max_level(&self) -> usize {
        (0..=NUM_LEVELS).rev().find(|&i| self.weights[i].is_some()).unwrap_or(0)
    }

    /// Number of levels that contribute.
    pub fn active_levels(&self) -> usize {
        self.weights.iter().filter(|w| w.is_some()).count()
    }
}

/// Local means and (raw, unclamped) variances of one array at the levels its plan needs.
struct Moments<T> {
    mean: Vec<Option<Tensor<T>>>,
    var: Vec<Option<Tensor<T>>>,
}

fn squares<T: Real>(x: &[T]) -> Vec<T> {
    x.iter().map(|&v| v * v).collect()
}

/// One level's statistics of every plane: `(K * x, K * q, K * q − (K * x)²)`, with `q = x²` squared
/// plane by plane when `q` is `None` (level 1, whose running arrays are the array itself).
fn level_stats<T: Real>(x: &Tensor<T>, q: Option<&Tensor<T>>) -> (Tensor<T>, Tensor<T>, Tensor<T>) {
    let (mut m, mut p, mut v) = (Tensor::zeros(x.c, x.h, x.w), Tensor::zeros(x.c, x.h, x.w), Tensor::zeros(x.c, x.h, x.w));
    let n = x.plane_len();
    if n > 0 {
        m.data.par_chunks_mut(n).zip(p.data.par_chunks_mut(n)).zip(v.data.par_chunks_mut(n)).enumerate().for_each(|(c, ((m, p), v))| {
            let xs = x.plane(c);
            blur_into(xs, x.h, x.w, m);
            match q {
                Some(q) => blur_into(q.plane(c), x.h, x.w, p),
                None => blur_into(&squares(xs), x.h, x.w, p),
            }
            for ((v, &p), &m) in v.iter_mut().zip(p.iter()).zip(m.iter()) {
                *v = p - m * m;
            }
        });
    }
    (m, p, v)
}

/// [`Tensor::blur_subsample`] of the running arrays `x` and `q` (`q = x²` when `None`).
fn blur_subsample_pair<T: Real>(x: &Tensor<T>, q: Option<&Tensor<T>>) -> (Tensor<T>, Tensor<T>) {
    let q = match q {
        Some(q) => q.blur_subsample(),
        None => Tensor { data: squares(&x.data), ..*x }.blur_subsample(),
    };
    (x.blur_subsample(), q)
}

fn moments<T: Real>(x: &Tensor<T>, plan: &Plan<T>) -> Moments<T> {
    let top = plan.max_level();
    let mut mean = vec![None; NUM_LEVELS + 1];
    let mut var = vec![None; NUM_LEVELS + 1];
    // The running arrays entering the level; None before level 1 (x itself and its square).
    let mut run: Option<(Tensor<T>, Tensor<T>)> = None;
    for k in 1..=top {
        let (rx, rq) = match &run {
            Some((a, b)) => (a, Some(b)),
            None => (x, None),
        };
        if plan.weights[k].is_none() {
            // Only the subsampled running arrays are needed from this level.
            run = Some(blur_subsample_pair(rx, rq));
            continue;
        }
        let (m, p, v) = level_stats(rx, rq);
        if k < top {
            run = Some((m.subsample(0, 0), p.subsample(0, 0)));
        }
        var[k] = Some(v);
        mean[k] = Some(m);
    }
    Moments { mean, var }
}

fn clamped_sqrt<T: Real>(v: &Tensor<T>) -> Tensor<T> {
    Tensor { data: v.data.iter().map(|&v| v.max(T::zero()).sqrt()).collect(), ..*v }
}

/// The reference side of one array: its plan and the statistics WD compares against.
#[derive(Clone, Debug, PartialEq)]
pub struct ArrayReference<T> {
    /// (channels, height, width) of the array.
    pub shape: (usize, usize, usize),
    pub plan: Plan<T>,
    /// The features themselves, kept only when level 0 counts.
    pub level0: Option<Tensor<T>>,
    pub mean: Vec<Option<Tensor<T>>>,
    /// `√max(v, 0)` per needed level.
    pub sd: Vec<Option<Tensor<T>>>,
}

/// Everything WD needs from the reference image: cache it per view.
#[derive(Clone, Debug, PartialEq)]
pub struct Reference<T> {
    pub arrays: Vec<ArrayReference<T>>,
}

impl<T: Real> Reference<T> {
    /// Statistics of the reference feature arrays of an `img_h × img_w` image.
    pub fn new(features: &[Tensor<T>], sigma: &Sigma, img_h: usize, img_w: usize) -> Self {
        let arrays = features
            .iter()
            .map(|f| {
                let plan = Plan::new(sigma, img_h, img_w, f.h, f.w);
                let mo = moments(f, &plan);
                ArrayReference {
                    shape: (f.c, f.h, f.w),
                    level0: plan.weights[0].is_some().then(|| f.clone()),
                    mean: mo.mean,
                    sd: mo.var.iter().map(|v| v.as_ref().map(clamped_sqrt)).collect(),
                    plan,
                }
            })
            .collect();
        Reference { arrays }
    }

    /// Total number of contributing (array, level) pairs.
    pub fn active_levels(&self) -> usize {
        self.arrays.iter().map(|a| a.plan.active_levels()).sum()
    }

    /// Approximate heap size in bytes (for cache budgets).
    pub fn bytes(&self) -> usize {
        let t = |x: &Option<Tensor<T>>| x.as_ref().map_or(0, |t| t.data.len());
        let n: usize = self
            .arrays
            .iter()
            .map(|a| {
                t(&a.level0)
                    + a.mean.iter().map(t).sum::<usize>()
                    + a.sd.iter().map(t).sum::<usize>()
                    + a.plan.weights.iter().map(t).sum::<usize>()
            })
            .sum();
        n * std::mem::size_of::<T>()
    }
}

/// WD between rendered feature arrays and a reference.
pub fn distortion<T: Real>(reference: &Reference<T>, rendered: &[Tensor<T>]) -> f64 {
    check(reference, rendered);
    reference.arrays.iter().zip(rendered).map(|(r, x)| array_value(r, x, &moments(x, &r.plan))).sum()
}

/// WD and its gradient with respect to every rendered feature array.
pub fn distortion_and_grad<T: Real>(reference: &Reference<T>, rendered: &[Tensor<T>]) -> (f64, Vec<Tensor<T>>) {
    check(reference, rendered);
    let parts: Vec<(f64, Tensor<T>)> = reference.arrays.iter().zip(rendered).map(|(r, x)| array_value_and_grad(r, x)).collect();
    let value = parts.iter().map(|p| p.0).sum();
    (value, parts.into_iter().map(|p| p.1).collect())
}

/// WD between two lists of feature arrays of an `img_h × img_w` image (no caching).
pub fn wd<T: Real>(reference: &[Tensor<T>], rendered: &[Tensor<T>], sigma: &Sigma, img_h: usize, img_w: usize) -> f64 {
    distortion(&Reference::new(reference, sigma, img_h, img_w), rendered)
}

fn check<T: Real>(reference: &Reference<T>, rendered: &[Tensor<T>]) {
    assert_eq!(reference.arrays.len(), rendered.len(), "WD: different numbers of feature arrays");
    for (r, x) in reference.arrays.iter().zip(rendered) {
        assert_eq!(r.shape, (x.c, x.h, x.w), "WD: feature array shapes differ");
    }
}

/// `Σ_c Σ_p w(p) f(c, p)` summed in f64, divided by the element count.
fn weighted_mean<T: Real>(w: &Tensor<T>, c: usize, f: impl Fn(usize) -> T + Sync) -> f64 {
    let n = w.data.len();
    let total: f64 = (0..c)
        .into_par_iter()
        .map(|ch| w.data.iter().enumerate().map(|(i, &wi)| if wi > T::zero() { (wi * f(ch * n + i)).f64() } else { 0.0 }).sum::<f64>())
        .sum();
    total / (c * n) as f64
}

fn array_value<T: Real>(r: &ArrayReference<T>, x: &Tensor<T>, mo: &Moments<T>) -> f64 {
    let mut value = 0.0;
    if let (Some(w), Some(f)) = (&r.plan.weights[0], &r.level0) {
        value += weighted_mean(w, x.c, |i| {
            let d = x.data[i] - f.data[i];
            d * d
        });
    }
    for k in 1..=NUM_LEVELS {
        let Some(w) = &r.plan.weights[k] else { continue };
        let (m, v) = (mo.mean[k].as_ref().unwrap(), mo.var[k].as_ref().unwrap());
        let (mr, sr) = (r.mean[k].as_ref().unwrap(), r.sd[k].as_ref().unwrap());
        value += weighted_mean(w, x.c, |i| {
            let dm = m.data[i] - mr.data[i];
            let ds = v.data[i].max(T::zero()).sqrt() - sr.data[i];
            dm * dm + ds * ds
        });
    }
    value
}

fn array_value_and_grad<T: Real>(r: &ArrayReference<T>, x: &Tensor<T>) -> (f64, Tensor<T>) {
    let mo = moments(x, &r.plan);
    let value = array_value(r, x, &mo);
    let top = r.plan.max_level();
    let two = T::c(2.0);
    let limit = T::c(SQRT_GRAD_LIMIT);

    // Gradients w.r.t. the running arrays x_k, q_k entering level k + 1 (k = top - 1 .. 0).
    let mut gx: Option<Tensor<T>> = None;
    let mut gq: Option<Tensor<T>> = None;
    // Shapes of the level inputs: level k's maps live at the resolution of x_{k-1}.
    let mut shapes = vec![(x.h, x.w)];
    for _ in 1..top {
        let (h, w) = *shapes.last().unwrap();
        shapes.push((h.div_ceil(2), w.div_ceil(2)));
    }
    for k in (1..=top).rev() {
        let (h, w) = shapes[k - 1];
        let Some(wk) = &r.plan.weights[k] else {
            // Level k only fed the next level: fused adjoint of blur + subsample.
            let (a, b) = (gx.take().expect("a higher level"), gq.take().expect("a higher level"));
            gx = Some(a.blur_subsample_adjoint(h, w));
            gq = Some(b.blur_subsample_adjoint(h, w));
            continue;
        };
        let (mut gm, mut gp) = match (gx.take(), gq.take()) {
            (Some(a), Some(b)) => (a.subsample_adjoint(h, w, 0, 0), b.subsample_adjoint(h, w, 0, 0)),
            _ => (Tensor::zeros(x.c, h, w), Tensor::zeros(x.c, h, w)),
        };
        {
            let (m, v) = (mo.mean[k].as_ref().unwrap(), mo.var[k].as_ref().unwrap());
            let (mr, sr) = (r.mean[k].as_ref().unwrap(), r.sd[k].as_ref().unwrap());
            let n = h * w;
            let scale = two / T::c((x.c * n) as f64);
            gm.data.par_chunks_mut(n).zip(gp.data.par_chunks_mut(n)).enumerate().for_each(|(c, (gm, gp))| {
                for i in 0..n {
                    let wi = wk.data[i];
                    if wi <= T::zero() {
                        continue;
                    }
                    let j = c * n + i;
                    let (mj, vj) = (m.data[j], v.data[j]);
                    let vc = vj.max(T::zero());
                    let s = vc.sqrt();
                    let g_s = scale * wi * (s - sr.data[j]);
                    let g_vc = g_s * (T::c(0.5) / s).min(limit);
                    // Clamp at 0: pass the gradient where inactive, or where it is negative.
                    let g_v = if vj >= T::zero() || g_vc < T::zero() { g_vc } else { T::zero() };
                    gm[i] = gm[i] + scale * wi * (mj - mr.data[j]) - two * mj * g_v;
                    gp[i] = gp[i] + g_v;
                }
            });
        }
        gx = Some(gm.blur());
        gq = Some(gp.blur());
    }

    let mut grad = Tensor::zeros(x.c, x.h, x.w);
    let n = x.h * x.w;
    let w0 = r.plan.weights[0].as_ref().zip(r.level0.as_ref());
    let scale0 = two / T::c((x.c * n).max(1) as f64);
    grad.data.par_chunks_mut(n.max(1)).enumerate().for_each(|(c, g)| {
        for i in 0..g.len() {
            let j = c * n + i;
            let xj = x.data[j];
            let mut v = T::zero();
            if let (Some(gx), Some(gq)) = (&gx, &gq) {
                v = gx.data[j] + two * xj * gq.data[j];
            }
            if let Some((w, f)) = w0 {
                v = v + scale0 * w.data[i] * (xj - f.data[j]);
            }
            g[i] = v;
        }
    });
    (value, grad)
}

/// `jax.image.resize(x, (oh, ow), "linear", antialias=True)` of one row-major plane: a
/// triangle kernel widened by the downscale factor, normalised per output sample.
pub fn resize_linear_antialias(x: &[f64], h: usize, w: usize, oh: usize, ow: usize) -> Vec<f64> {
    let rows = resize_weights(h, oh);
    let cols = resize_weights(w, ow);
    let mut tmp = vec![0.0; h * ow];
    for y in 0..h {
        for (j, cw) in cols.iter().enumerate() {
            tmp[y * ow + j] = cw.iter().map(|&(i, wt)| wt * x[y * w + i]).sum();
        }
    }
    let mut out = vec![0.0; oh * ow];
    for (j, rw) in rows.iter().enumerate() {
        for i in 0..ow {
            out[j * ow + i] = rw.iter().map(|&(y, wt)| wt * tmp[y * ow + i]).sum();
        }
    }
    out
}

fn resize_weights(n_in: usize, n_out: usize) -> Vec<Vec<(usize, f64)>> {
    let scale = n_out as f64 / n_in as f64;
    let kscale = (1.0 / scale).max(1.0);
    (0..n_out)
        .map(|j| {
            let sample = (j as f64 + 0.5) / scale - 0.5;
            let mut ws: Vec<(usize, f64)> = (0..n_in)
                .filter_map(|i| {
                    let t = 1.0 - ((sample - i as f64).abs() / kscale);
                    (t > 0.0).then_some((i, t))
                })
                .collect();
            let total: f64 = ws.iter().map(|p| p.1).sum();
            if total > 0.0 {
                ws.iter_mut().for_each(|p| p.1 /= total);
            }
            ws
        })
        .collect()
}

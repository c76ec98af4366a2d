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
//! once into a [`Reference`] that callers may cache. Every plane (channel) of every array is
//! computed on its own, start to finish, as one parallel task: the statistics never mix channels,
//! so a plane's cascade, value and gradient stay in cache (the same arithmetic in the same order).

use rayon::prelude::*;

use super::tensor::{
    blur_into, blur_subsample_adjoint_into, blur_subsample_into, half, subsample_adjoint_into, subsample_into, Real, Tensor,
};

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

/// Height and width of the maps of level `k` of an `h × w` array (levels 0 and 1 at full
/// resolution, each further level at half the one before, rounded up).
fn level_dims(h: usize, w: usize, k: usize) -> (usize, usize) {
    (1..k).fold((h, w), |(h, w), _| (half(h), half(w)))
}

fn squares<T: Real>(x: &[T]) -> Vec<T> {
    x.iter().map(|&v| v * v).collect()
}

/// Local means and (raw, unclamped) variances of one plane at the levels its plan needs.
///
/// WD's statistics never mix channels, so everything runs plane by plane: a plane's whole
/// cascade, value and gradient stay in cache, and the planes of every array are the parallel tasks.
struct PlaneMoments<T> {
    mean: Vec<Option<Vec<T>>>,
    var: Vec<Option<Vec<T>>>,
}

fn plane_moments<T: Real>(x: &[T], h: usize, w: usize, plan: &Plan<T>) -> PlaneMoments<T> {
    let top = plan.max_level();
    let mut mean = vec![None; NUM_LEVELS + 1];
    let mut var = vec![None; NUM_LEVELS + 1];
    let zero = T::zero();
    // The running arrays entering level k (x itself and its square before level 1), h × w.
    let x2 = if top > 0 { squares(x) } else { Vec::new() };
    let mut run: Option<(Vec<T>, Vec<T>)> = None;
    let (mut h, mut w) = (h, w);
    for k in 1..=top {
        let (rx, rq) = match &run {
            Some((a, b)) => (a.as_slice(), b.as_slice()),
            None => (x, x2.as_slice()),
        };
        let (h2, w2) = (half(h), half(w));
        if plan.weights[k].is_none() {
            // Only the blurred and subsampled running arrays are needed from this level.
            let (mut a, mut b) = (vec![zero; h2 * w2], vec![zero; h2 * w2]);
            blur_subsample_into(rx, h, w, &mut a);
            blur_subsample_into(rq, h, w, &mut b);
            run = Some((a, b));
        } else {
            let (mut m, mut p) = (vec![zero; h * w], vec![zero; h * w]);
            blur_into(rx, h, w, &mut m);
            blur_into(rq, h, w, &mut p);
            let v: Vec<T> = p.iter().zip(&m).map(|(&p, &m)| p - m * m).collect();
            if k < top {
                let (mut a, mut b) = (vec![zero; h2 * w2], vec![zero; h2 * w2]);
                subsample_into(&m, h, w, 0, 0, &mut a);
                subsample_into(&p, h, w, 0, 0, &mut b);
                run = Some((a, b));
            }
            mean[k] = Some(m);
            var[k] = Some(v);
        }
        (h, w) = (h2, w2);
    }
    PlaneMoments { mean, var }
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

/// `(array, plane)` for every plane of every array, the unit of parallel work.
fn planes_of<T: Real>(arrays: &[Tensor<T>]) -> Vec<(usize, usize)> {
    arrays.iter().enumerate().flat_map(|(a, t)| (0..t.c).map(move |c| (a, c))).collect()
}

impl<T: Real> Reference<T> {
    /// Statistics of the reference feature arrays of an `img_h × img_w` image.
    pub fn new(features: &[Tensor<T>], sigma: &Sigma, img_h: usize, img_w: usize) -> Self {
        let plans: Vec<Plan<T>> = features.iter().map(|f| Plan::new(sigma, img_h, img_w, f.h, f.w)).collect();
        let moments: Vec<PlaneMoments<T>> = planes_of(features)
            .into_par_iter()
            .map(|(a, c)| plane_moments(features[a].plane(c), features[a].h, features[a].w, &plans[a]))
            .collect();
        let mut moments = moments.into_iter();
        let arrays = features
            .iter()
            .zip(plans)
            .map(|(f, plan)| {
                let planes: Vec<PlaneMoments<T>> = moments.by_ref().take(f.c).collect();
                // One level of every plane, stacked into the array's tensor at that level.
                let stack = |k: usize, level: &dyn Fn(&PlaneMoments<T>) -> &Option<Vec<T>>| {
                    let (h, w) = level_dims(f.h, f.w, k);
                    Tensor::from_vec(
                        f.c,
                        h,
                        w,
                        planes.iter().flat_map(|p| level(p).as_ref().expect("a needed level").iter().copied()).collect(),
                    )
                };
                let mut mean = vec![None; NUM_LEVELS + 1];
                let mut sd = vec![None; NUM_LEVELS + 1];
                for k in (1..=NUM_LEVELS).filter(|&k| plan.weights[k].is_some()) {
                    mean[k] = Some(stack(k, &|p| &p.mean[k]));
                    let mut s = stack(k, &|p| &p.var[k]);
                    s.data.iter_mut().for_each(|v| *v = v.max(T::zero()).sqrt());
                    sd[k] = Some(s);
                }
                ArrayReference { shape: (f.c, f.h, f.w), level0: plan.weights[0].is_some().then(|| f.clone()), mean, sd, plan }
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
    let sums: Vec<LevelSums> = planes_of(rendered)
        .into_par_iter()
        .map(|(a, c)| {
            let (r, x) = (&reference.arrays[a], &rendered[a]);
            plane_value(r, c, x.plane(c), &plane_moments(x.plane(c), x.h, x.w, &r.plan))
        })
        .collect();
    value_of(reference, &sums)
}

/// WD and its gradient with respect to every rendered feature array.
pub fn distortion_and_grad<T: Real>(reference: &Reference<T>, rendered: &[Tensor<T>]) -> (f64, Vec<Tensor<T>>) {
    check(reference, rendered);
    let mut grads: Vec<Tensor<T>> = rendered.iter().map(|x| Tensor::zeros(x.c, x.h, x.w)).collect();
    let mut tasks: Vec<(usize, usize, &mut [T])> = Vec::new();
    for (a, g) in grads.iter_mut().enumerate() {
        match g.plane_len() {
            // One task per plane, as in `planes_of`, even for planes without pixels.
            0 => tasks.extend((0..g.c).map(|c| (a, c, &mut [][..]))),
            n => tasks.extend(g.data.chunks_mut(n).enumerate().map(|(c, out)| (a, c, out))),
        }
    }
    let sums: Vec<LevelSums> = tasks
        .into_par_iter()
        .map(|(a, c, out)| {
            let (r, x) = (&reference.arrays[a], &rendered[a]);
            let mo = plane_moments(x.plane(c), x.h, x.w, &r.plan);
            plane_grad(r, c, x, &mo, out);
            plane_value(r, c, x.plane(c), &mo)
        })
        .collect();
    (value_of(reference, &sums), grads)
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

/// One plane's `Σ_p w(p) map(p)` per level, summed in f64.
type LevelSums = [f64; NUM_LEVELS + 1];

/// `Σ_p w(p)·t(p)` in f64 over the positively weighted samples, each product in `T`: eight
/// interleaved partial sums (so that it vectorises), added in a fixed order.
fn weighted_sum<T: Real>(w: &[T], mut terms: impl Iterator<Item = T>) -> f64 {
    let mut lanes = [0.0f64; 8];
    for ws in w.chunks(8) {
        for (lane, (&wi, t)) in lanes.iter_mut().zip(ws.iter().zip(terms.by_ref())) {
            *lane += if wi > T::zero() { (wi * t).f64() } else { 0.0 };
        }
    }
    lanes.iter().sum()
}

fn plane_value<T: Real>(r: &ArrayReference<T>, c: usize, x: &[T], mo: &PlaneMoments<T>) -> LevelSums {
    let mut sums = [0.0; NUM_LEVELS + 1];
    if let (Some(w), Some(f)) = (&r.plan.weights[0], &r.level0) {
        sums[0] = weighted_sum(
            &w.data,
            x.iter().zip(f.plane(c)).map(|(&a, &b)| {
                let d = a - b;
                d * d
            }),
        );
    }
    for k in 1..=NUM_LEVELS {
        let Some(w) = &r.plan.weights[k] else { continue };
        let (m, v) = (mo.mean[k].as_ref().unwrap(), mo.var[k].as_ref().unwrap());
        let (mr, sr) = (r.mean[k].as_ref().unwrap().plane(c), r.sd[k].as_ref().unwrap().plane(c));
        sums[k] = weighted_sum(
            &w.data,
            m.iter().zip(v).zip(mr.iter().zip(sr)).map(|((&m, &v), (&mr, &sr))| {
                let dm = m - mr;
                let ds = v.max(T::zero()).sqrt() - sr;
                dm * dm + ds * ds
            }),
        );
    }
    sums
}

/// Σ over levels of the mean over (channels, pixels) of the weighted maps; the planes' sums in
/// plane order, so the value does not depend on the thread count.
fn value_of<T: Real>(reference: &Reference<T>, sums: &[LevelSums]) -> f64 {
    let mut planes = sums.iter();
    let mut value = 0.0;
    for r in &reference.arrays {
        let mine: Vec<&LevelSums> = planes.by_ref().take(r.shape.0).collect();
        for (k, w) in r.plan.weights.iter().enumerate() {
            if let Some(w) = w {
                value += mine.iter().map(|s| s[k]).sum::<f64>() / (r.shape.0 * w.data.len()) as f64;
            }
        }
    }
    value
}

/// Gradient of WD with respect to plane `c` of the rendered array `x`, into `out`.
fn plane_grad<T: Real>(r: &ArrayReference<T>, c: usize, x: &Tensor<T>, mo: &PlaneMoments<T>, out: &mut [T]) {
    let top = r.plan.max_level();
    let (two, zero) = (T::c(2.0), T::zero());
    let limit = T::c(SQRT_GRAD_LIMIT);
    // Gradients w.r.t. the running arrays x_k, q_k entering level k + 1 (k = top - 1 .. 0);
    // level k's maps live at the resolution of x_{k-1}.
    let mut g: Option<(Vec<T>, Vec<T>)> = None;
    for k in (1..=top).rev() {
        let (h, w) = level_dims(x.h, x.w, k);
        let (h2, w2) = (half(h), half(w));
        let Some(wk) = &r.plan.weights[k] else {
            // Level k only fed the next level: fused adjoint of blur + subsample.
            let (a, b) = g.take().expect("a higher level");
            let (mut ga, mut gb) = (vec![zero; h * w], vec![zero; h * w]);
            blur_subsample_adjoint_into(&a, h2, w2, h, w, &mut ga);
            blur_subsample_adjoint_into(&b, h2, w2, h, w, &mut gb);
            g = Some((ga, gb));
            continue;
        };
        let (mut gm, mut gp) = (vec![zero; h * w], vec![zero; h * w]);
        if let Some((a, b)) = g.take() {
            subsample_adjoint_into(&a, w2, 0, 0, w, &mut gm);
            subsample_adjoint_into(&b, w2, 0, 0, w, &mut gp);
        }
        let (m, v) = (mo.mean[k].as_ref().unwrap(), mo.var[k].as_ref().unwrap());
        let (mr, sr) = (r.mean[k].as_ref().unwrap().plane(c), r.sd[k].as_ref().unwrap().plane(c));
        let scale = two / T::c((x.c * h * w) as f64);
        let half_ = T::c(0.5);
        for (((gm, gp), &wi), (((&mj, &vj), &mrj), &srj)) in
            gm.iter_mut().zip(gp.iter_mut()).zip(&wk.data).zip(m.iter().zip(v).zip(mr).zip(sr))
        {
            if wi <= zero {
                continue;
            }
            let vc = vj.max(zero);
            let s = vc.sqrt();
            let g_s = scale * wi * (s - srj);
            let g_vc = g_s * (half_ / s).min(limit);
            // Clamp at 0: pass the gradient where inactive, or where it is negative.
            let g_v = if vj >= zero || g_vc < zero { g_vc } else { zero };
            *gm = *gm + scale * wi * (mj - mrj) - two * mj * g_v;
            *gp = *gp + g_v;
        }
        let (mut a, mut b) = (vec![zero; h * w], vec![zero; h * w]);
        blur_into(&gm, h, w, &mut a);
        blur_into(&gp, h, w, &mut b);
        g = Some((a, b));
    }

    let xs = x.plane(c);
    match &g {
        Some((gx, gq)) => out.iter_mut().zip(xs).zip(gx.iter().zip(gq)).for_each(|((o, &xj), (&a, &b))| *o = a + two * xj * b),
        None => out.fill(zero),
    }
    if let (Some(w), Some(f)) = (&r.plan.weights[0], &r.level0) {
        let scale0 = two / T::c((x.c * xs.len()).max(1) as f64);
        out.iter_mut().zip(xs).zip(w.data.iter().zip(f.plane(c))).for_each(|((o, &xj), (&wi, &fj))| *o = *o + scale0 * wi * (xj - fj));
    }
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

//! The WD-based training losses: `wd` (γ·d_WD) and `wdr` (γ·(d_WD + β·L_orig)), both warmed up
//! with the original 3DGS loss `L_orig = 0.8·L1 + 0.2·(1 − SSIM)` for a share of the run
//! (`--wd-warmup`, by default three tenths: WD-R takes over while densification still runs).
//!
//! Reference statistics are cached per training view (`view` of [`ImageLoss`]), keyed also by a
//! fingerprint of the target so a changed target is never compared against stale statistics.

use std::collections::{HashMap, VecDeque};
use std::sync::Arc;

use gscodec_decoder::Image;

use super::features::FeatureSpace;
use super::tensor::Tensor;
use super::wd::{self, Reference, Sigma};
use super::{ImageLoss, L1Ssim};

/// WD-R's weight of the original loss, β = 1/0.09 (paper).
pub const BETA: f64 = 1.0 / 0.09;
/// Default global scale γ of `wdr` (paper: 0.025–0.032 depending on the dataset).
pub const DEFAULT_GAMMA_WDR: f64 = 0.025;
/// Default global scale γ of `wd` (paper: 0.028–0.038).
pub const DEFAULT_GAMMA_WD: f64 = 0.03;
/// Fraction of the run trained with `L_orig` alone before WD / WD-R take over. At 0.3 they take
/// over while densification still runs (it ends at [`crate::train::DENSIFY_UNTIL_SHARE`]), so
/// the Gaussians they add are grown under the perceptual loss. Measured on lego-200 against 0.5
/// (docs/wd.md §16–§17: GPU, two seeds, five λ: ꟻLIP BD-rate against L1-SSIM −16.4 % at 0.3,
/// where 0.5 measured −7.4 % with the search before sessions 18–19); the paper warms up for 3k
/// of 30k ([`PAPER_WARMUP_FRACTION`]) and tunes γ per scene to keep the splat count (docs/wd.md
/// §8).
pub const WARMUP_FRACTION: f64 = 0.3;
/// Default warm-up share of an `encode` of a dataset that retrains (`--wd-warmup 1`): the run
/// from the images trains with `L_orig` alone, and WD / WD-R train only the retraining of the
/// Gaussians the RD search keeps (docs/wd.md §23). On three scenes (GPU trainer, two seeds) its
/// ꟻLIP BD-rates against L1-SSIM are −12.4 % (lego-200), +1.1 % and −1.7 % (a ray-cast textured
/// scene, playbot-lod3's renders; CPU trainer: +5.2 % and −14.7 %), where [`WARMUP_FRACTION`]
/// gives −16.4 % on lego and lost 11–22 % on the two others (CPU trainer, §20–§21): WD-R growing
/// the scene paid on lego only.
pub const ENCODE_WARMUP_FRACTION: f64 = 1.0;
/// The paper's warm-up share (3k of 30k iterations), this crate's default before `--wd-warmup`
/// (what results that record no share were trained with).
pub const PAPER_WARMUP_FRACTION: f64 = 0.1;
/// Default memory budget of the per-view reference cache.
pub const DEFAULT_CACHE_BYTES: usize = 2 << 30;

/// Warm-up length for a run of `total_iters` iterations whose first `fraction` trains with
/// `L_orig` alone (`--wd-warmup`; [`WARMUP_FRACTION`] by default): iterations 1 to this number
/// (1-based) are the warm-up, so a share of 1 never trains with WD.
pub fn warmup_iters(total_iters: usize, fraction: f64) -> usize {
    (total_iters as f64 * fraction).round() as usize
}

/// Whether iteration `iter` (1-based) of a run with the warm-up `warmup` ([`warmup_iters`])
/// trains with `L_orig` alone; the CPU losses and the GPU WD stage both ask this.
pub fn in_warmup(iter: usize, warmup: usize) -> bool {
    iter <= warmup
}

/// d_WD of rendered images against targets in a feature space, with per-view caching.
pub struct WdDistortion {
    space: Box<dyn FeatureSpace<f32>>,
    sigma: Sigma,
    cache: HashMap<usize, (u64, Arc<Reference<f32>>)>,
    order: VecDeque<usize>,
    cache_bytes: usize,
    budget: usize,
}

impl WdDistortion {
    pub fn new(space: Box<dyn FeatureSpace<f32>>) -> Self {
        WdDistortion {
            space,
            sigma: Sigma::default(),
            cache: HashMap::new(),
            order: VecDeque::new(),
            cache_bytes: 0,
            budget: DEFAULT_CACHE_BYTES,
        }
    }

    /// Uses another σ (constant or per-pixel map); clears the cache.
    pub fn with_sigma(mut self, sigma: Sigma) -> Self {
        assert!(sigma.max_log2() <= wd::NUM_LEVELS as f64, "WD needs log2 σ ≤ {}", wd::NUM_LEVELS);
        self.sigma = sigma;
        self.clear_cache();
        self
    }

    /// Memory budget of the reference cache in bytes (0 disables caching).
    pub fn with_cache_budget(mut self, bytes: usize) -> Self {
        self.budget = bytes;
        self.clear_cache();
        self
    }

    pub fn feature_space(&self) -> &dyn FeatureSpace<f32> {
        self.space.as_ref()
    }

    pub fn clear_cache(&mut self) {
        self.cache.clear();
        self.order.clear();
        self.cache_bytes = 0;
    }

    /// Number of views whose reference statistics are cached.
    pub fn cached_views(&self) -> usize {
        self.cache.len()
    }

    fn reference(&mut self, target: &Image, view: Option<usize>) -> Arc<Reference<f32>> {
        let key = fingerprint(target);
        if let Some(v) = view {
            if let Some((k, r)) = self.cache.get(&v) {
                if *k == key {
                    return r.clone();
                }
            }
        }
        let feats = self.space.features(&Tensor::from_image(target));
        let r = Arc::new(Reference::new(&feats, &self.sigma, target.height as usize, target.width as usize));
        if let Some(v) = view {
            self.insert(v, key, r.clone());
        }
        r
    }

    fn insert(&mut self, view: usize, key: u64, r: Arc<Reference<f32>>) {
        let bytes = r.bytes();
        if bytes > self.budget {
            return;
        }
        if let Some((_, old)) = self.cache.remove(&view) {
            self.cache_bytes -= old.bytes();
            self.order.retain(|&v| v != view);
        }
        while self.cache_bytes + bytes > self.budget {
            let Some(v) = self.order.pop_front() else { break };
            if let Some((_, old)) = self.cache.remove(&v) {
                self.cache_bytes -= old.bytes();
            }
        }
        self.cache_bytes += bytes;
        self.order.push_back(view);
        self.cache.insert(view, (key, r));
    }

    /// d_WD(rendered, target); `view` = Some(id) uses and fills the cache.
    pub fn value(&mut self, rendered: &Image, target: &Image, view: Option<usize>) -> f64 {
        check_sizes(rendered, target);
        let r = self.reference(target, view);
        let feats = self.space.features(&Tensor::from_image(rendered));
        wd::distortion(&r, &feats)
    }

    /// d_WD and its gradient w.r.t. the rendered image (interleaved RGB).
    pub fn value_and_grad(&mut self, rendered: &Image, target: &Image, view: Option<usize>) -> (f64, Vec<f32>) {
        check_sizes(rendered, target);
        let r = self.reference(target, view);
        let ex = self.space.extract(&Tensor::from_image(rendered));
        let (value, grads) = wd::distortion_and_grad(&r, &ex.arrays);
        let g = ex.tape.backward(&grads);
        (value, g.to_interleaved_f32())
    }
}

fn check_sizes(a: &Image, b: &Image) {
    assert_eq!((a.width, a.height), (b.width, b.height), "WD of images of different sizes");
}

/// A 64-bit key of the target's sizes and pixel bits (it is compared, never stored): four
/// independent multiply–rotate lanes, each eating two samples at a time, then mixed. A byte-wise
/// FNV-1a is one serial multiply per byte, about 1 ms per 200×200 target and training iteration.
fn fingerprint(img: &Image) -> u64 {
    const K: u64 = 0x9e37_79b9_7f4a_7c15;
    let eat = |lane: u64, v: u64| (lane ^ v).wrapping_mul(K).rotate_left(29);
    let pair = |a: f32, b: f32| u64::from(a.to_bits()) | (u64::from(b.to_bits()) << 32);
    let mut lanes = [K ^ u64::from(img.width), K ^ (u64::from(img.height) << 32), K.rotate_left(17), K.rotate_left(41)];
    let chunks = img.data.chunks_exact(8);
    let rest = chunks.remainder();
    for c in chunks {
        for (l, lane) in lanes.iter_mut().enumerate() {
            *lane = eat(*lane, pair(c[2 * l], c[2 * l + 1]));
        }
    }
    for (i, &v) in rest.iter().enumerate() {
        lanes[i % 4] = eat(lanes[i % 4], u64::from(v.to_bits()) | 1 << 63);
    }
    lanes.iter().fold(img.data.len() as u64, |h, &l| eat(h, l))
}

/// `wd`: γ·d_WD after a warm-up with `L_orig`.
pub struct WdLoss {
    pub distortion: WdDistortion,
    pub gamma: f64,
    pub warmup: usize,
}

impl WdLoss {
    pub fn new(space: Box<dyn FeatureSpace<f32>>, total_iters: usize) -> Self {
        WdLoss { distortion: WdDistortion::new(space), gamma: DEFAULT_GAMMA_WD, warmup: warmup_iters(total_iters, WARMUP_FRACTION) }
    }

    /// The same loss with pooling scale `sigma` (see [`WdDistortion::with_sigma`]).
    pub fn with_sigma(self, sigma: Sigma) -> Self {
        WdLoss { distortion: self.distortion.with_sigma(sigma), ..self }
    }
}

impl ImageLoss for WdLoss {
    fn loss_and_grad(&mut self, rendered: &Image, target: &Image, view: usize, iter: usize) -> (f64, Vec<f32>) {
        if in_warmup(iter, self.warmup) {
            return l_orig(rendered, target);
        }
        let (v, mut g) = self.distortion.value_and_grad(rendered, target, Some(view));
        g.iter_mut().for_each(|x| *x *= self.gamma as f32);
        (self.gamma * v, g)
    }

    fn name(&self) -> &'static str {
        "wd"
    }
}

/// Training views over which [`WdrLoss`]'s normalised γ is measured after the warm-up.
pub const NORMALISE_VIEWS: usize = 16;

/// `wdr`: γ·(d_WD + β·L_orig) after a warm-up with `L_orig`.
///
/// γ is either fixed (`normalise = false`: the paper's per-dataset constant, `--wd-gamma`) or
/// normalised (the default): over the first [`NORMALISE_VIEWS`] iterations after the warm-up,
/// γ = Σ‖∇L_orig‖ / Σ‖∇(d_WD + β·L_orig)‖ (image gradients, summed over those views), then
/// frozen. The objective's gradient then has the scale of the L1-SSIM loss it replaces, so the
/// rate term's λ (calibrated in L1-SSIM units, `rate::lambda`) and the densification threshold
/// mean the same for both losses; γ stays a single scene-wide constant, as in the paper.
pub struct WdrLoss {
    pub distortion: WdDistortion,
    pub gamma: f64,
    pub beta: f64,
    pub warmup: usize,
    pub normalise: bool,
    /// Σ‖∇L_orig‖, Σ‖∇(d_WD + β·L_orig)‖ and the number of views measured so far.
    sums: (f64, f64, usize),
}

impl WdrLoss {
    pub fn new(space: Box<dyn FeatureSpace<f32>>, total_iters: usize) -> Self {
        WdrLoss {
            distortion: WdDistortion::new(space),
            gamma: DEFAULT_GAMMA_WDR,
            beta: BETA,
            warmup: warmup_iters(total_iters, WARMUP_FRACTION),
            normalise: true,
            sums: (0.0, 0.0, 0),
        }
    }

    /// The same loss with the fixed γ `gamma` (no normalisation).
    pub fn with_fixed_gamma(self, gamma: f64) -> Self {
        WdrLoss { gamma, normalise: false, ..self }
    }

    /// The same loss with pooling scale `sigma` (see [`WdDistortion::with_sigma`]).
    pub fn with_sigma(self, sigma: Sigma) -> Self {
        WdrLoss { distortion: self.distortion.with_sigma(sigma), ..self }
    }

    /// Whether γ is final (fixed, or normalised over [`NORMALISE_VIEWS`] views).
    pub fn gamma_settled(&self) -> bool {
        !self.normalise || self.sums.2 >= NORMALISE_VIEWS
    }
}

fn l2(v: &[f32]) -> f64 {
    v.iter().map(|x| f64::from(*x).powi(2)).sum::<f64>().sqrt()
}

impl ImageLoss for WdrLoss {
    fn loss_and_grad(&mut self, rendered: &Image, target: &Image, view: usize, iter: usize) -> (f64, Vec<f32>) {
        let (lo, go) = l_orig(rendered, target);
        if in_warmup(iter, self.warmup) {
            return (lo, go);
        }
        let (v, gw) = self.distortion.value_and_grad(rendered, target, Some(view));
        let b = self.beta as f32;
        let mut grad: Vec<f32> = gw.iter().zip(&go).map(|(w, o)| w + b * o).collect();
        if !self.gamma_settled() {
            let (no, nc) = (l2(&go), l2(&grad));
            if nc > 0.0 && no.is_finite() && nc.is_finite() {
                self.sums = (self.sums.0 + no, self.sums.1 + nc, self.sums.2 + 1);
                self.gamma = self.sums.0 / self.sums.1;
            }
        }
        let g = self.gamma as f32;
        grad.iter_mut().for_each(|x| *x *= g);
        (self.gamma * (v + self.beta * lo), grad)
    }

    fn name(&self) -> &'static str {
        "wdr"
    }
}

/// `L_orig = 0.8·L1 + 0.2·(1 − SSIM)` and its gradient (the trainer's [`L1Ssim`]).
pub fn l_orig(rendered: &Image, target: &Image) -> (f64, Vec<f32>) {
    L1Ssim::default().eval(rendered, target)
}

/// d_WD in `pyramid` (the luminance bank) at σ = 4 between two images, for metrics: the same
/// measure whatever features a run trained with.
pub fn wd_metric(rendered: &Image, target: &Image) -> f64 {
    WdDistortion::new(Box::new(super::features::pyramid::Pyramid::LUMA)).value(rendered, target, None)
}

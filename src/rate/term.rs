//! The rate term of training: the [`RdTerm`] seam the trainer calls, and [`RateTerm`], which
//! renders with straight-through quantised parameters and adds `w·R` with its gradient, where
//! `R` is the learned entropy model's bit estimate of everything the file will hold and
//! `w` = [`Lambda::training_weight_per_bit`].

use std::sync::{Arc, Mutex};

use gscodec_decoder::math::sigmoid;
use gscodec_decoder::Splats;

use rayon::prelude::*;
use serde::Serialize;

use super::group::{self, Group, GroupMap};
use super::lambda::Lambda;
use super::model::LearnedChannel;
use super::quantise::{q_dz, round_group, Steps};
use crate::optim::AdamRule;

/// A rate (or any regulariser) term added to the image loss; the codec plugs quantisation and
/// `λ·R` into training through this. Lives with the rate term (the trainer depends on `rate`,
/// never the reverse).
pub trait RdTerm: Send {
    /// Parameters to render with at this iteration (e.g. quantised, straight-through); None = as is.
    fn render_params(&mut self, _params: &Splats, _iter: usize) -> Option<Splats> {
        None
    }
    /// Adds the term (in loss units) and its gradient w.r.t. the raw params into `grad`
    /// (a Splats of the same shape used as a gradient buffer); returns the value.
    fn rate_and_grad(&mut self, params: &Splats, grad: &mut Splats, iter: usize) -> f64;
    /// What the term learned and estimated, when training ends (see [`RateOutcome`]).
    fn outcome(&self) -> Option<RateOutcome> {
        None
    }
}

/// What a rate term hands back at the end of training (in the `TrainReport`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct RateOutcome {
    /// The steps the file should be coded with (learned, or the starting ones when fixed).
    pub steps: GroupMap<f32>,
    /// Estimated bits of the scene at the last evaluation.
    pub estimated_bits: Option<f64>,
}
/// Bits per Gaussian charged for what the learned channels do not model (position, rotation,
/// escapes, table share); measured on the shared scenes at default steps (docs/codec.md).
pub const FIXED_BITS_PER_GAUSSIAN: f64 = 30.0;

/// Groups quantised (and their steps learned) in training: scale, opacity, SH DC and the SH
/// bands (positions and rotations are not quantised in training: their quantisation error is
/// far below a pixel).
pub const LEARNED_GROUPS: [Group; 6] = [Group::Scale, Group::Opacity, Group::ShDc, Group::Sh1, Group::Sh2, Group::Sh3];
/// Adam learning rate of the log steps (per iteration).
pub(crate) const STEP_LR: f32 = 2e-3;
/// A learned step stays within this factor of its starting value.
pub(crate) const STEP_RANGE: f32 = 8.0;

/// Gaussians per block of [`RateTerm::rate_and_grad`]'s parallel part (a fixed size, so the
/// results do not depend on the thread count).
const RATE_BLOCK: usize = 4096;

/// One Gaussian's share of [`RateTerm::rate_and_grad`], before it is summed in.
#[derive(Debug, Clone, Copy, Default)]
struct PerGaussian {
    /// Its bits (with [`FIXED_BITS_PER_GAUSSIAN`]).
    bits: f64,
    /// How much it counts: a soft step of its opacity at the pruning threshold, and its slope.
    keep: f64,
    d_keep: f64,
    /// `Σ ∂bits/∂ln step` per group.
    d_step: GroupMap<f64>,
}

/// One value's derivatives in [`RateTerm::rate_and_grad`]: by the value and by its channel
/// model's mean and log scale.
#[derive(Debug, Clone, Copy, Default)]
struct PerChannel {
    d_value: f64,
    d_mu: f64,
    d_log_b: f64,
}

/// What a [`RateTerm`] shares with its owner during training.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Shared {
    /// The current (learned) steps.
    pub steps: Steps,
    /// Estimated bits of the scene at the last evaluation; `None` before the term starts.
    pub bits: Option<f64>,
}

/// Rate term with a learned factorized model per channel (scale 3, opacity 1, DC 3, rest K·3)
/// and, when `learn_steps`, quantisation steps learned per group.
///
/// Step learning: the rendered parameters are `q = s·Q(v/s)`, `Q` rounding (with the file's dead
/// zone for the SH rest bands, [`RateTerm::deadzone`]); with the straight-through estimator
/// `∂q/∂ln s = s·(Q(v/s) − v/s)`, so `∂D/∂ln s = Σ ∂D/∂q · s·(Q(v/s) − v/s)`
/// over the group's values, and `∂R/∂ln s` comes from the bin width of the learned density. The
/// log steps take one Adam step per iteration on `D + w·R`.
#[derive(Debug, Clone)]
pub struct RateTerm {
    pub lambda: Lambda,
    pub steps: Steps,
    pub learn_steps: bool,
    /// Iterations before this one train without the term (plain renders, no rate): the scene's
    /// structure (densification) forms first.
    pub start_iter: usize,
    start_steps: Steps,
    /// Adam on the log steps: the rule and its two moments per group.
    adam: (AdamRule, GroupMap<f32>, GroupMap<f32>),
    shared: Arc<Mutex<Shared>>,
    /// Opacity at which Gaussians are pruned; the term charges each Gaussian its bits times a
    /// soft "kept" factor σ((logit − logit(min_opacity)) / 0.5), so pruning pays.
    pub min_opacity: f32,
    models: Vec<LearnedChannel>,
    /// Bits of the last evaluation (for reports).
    pub last_bits: f64,
    /// ∂(D + w·R)/∂ln s per group at the last evaluation ([`LEARNED_GROUPS`]; zero for
    /// the others, and unless `learn_steps`).
    pub last_step_gradient: GroupMap<f64>,
}

impl RateTerm {
    pub fn new(lambda: Lambda, steps: Steps, min_opacity: f32) -> Self {
        RateTerm {
            lambda,
            steps,
            learn_steps: false,
            start_iter: 0,
            start_steps: steps,
            adam: (AdamRule::default(), GroupMap::default(), GroupMap::default()),
            shared: Arc::new(Mutex::new(Shared { steps, bits: None })),
            min_opacity,
            models: Vec::new(),
            last_bits: 0.0,
            last_step_gradient: GroupMap::default(),
        }
    }

    /// The same term with step learning on.
    pub fn learning_steps(self) -> Self {
        RateTerm { learn_steps: true, ..self }
    }

    /// The steps and the latest rate estimate, readable while and after the term is used by
    /// `train` (which owns it).
    pub fn shared(&self) -> Arc<Mutex<Shared>> {
        self.shared.clone()
    }

    /// One Adam step on the log steps from `d_log_step` (∂objective/∂ln s per group).
    fn update_steps(&mut self, d_log_step: &GroupMap<f64>) {
        let (rule, m, v) = &mut self.adam;
        let c = rule.begin_step();
        for g in LEARNED_GROUPS {
            let start = self.start_steps.of(g).ln();
            let mut log_s = [self.steps.of(g).ln()];
            rule.update(c, STEP_LR, &mut log_s, &[d_log_step[g] as f32], std::slice::from_mut(&mut m[g]), std::slice::from_mut(&mut v[g]));
            *self.steps.of_mut(g) = log_s[0].clamp(start - STEP_RANGE.ln(), start + STEP_RANGE.ln()).exp();
        }
        self.shared.lock().expect("term lock").steps = self.steps;
    }

    /// The steps the term started from (a learned step stays within [`STEP_RANGE`] of them).
    #[cfg_attr(not(feature = "gpu"), allow(dead_code))] // the GPU trainer's uniform
    pub(crate) fn start_steps(&self) -> Steps {
        self.start_steps
    }

    /// The channels the term models for a scene of SH degree `degree`: (group, value within it).
    pub(crate) fn channels(degree: u8) -> Vec<(Group, usize)> {
        LEARNED_GROUPS
            .into_iter()
            .filter(|g| g.sh_band() <= degree)
            .flat_map(|g| (0..group::layout(g, degree).1.len()).map(move |c| (g, c)))
            .collect()
    }

    /// The starting density of every channel of [`Self::channels`], fitted to `params`.
    pub(crate) fn fit_models(params: &Splats) -> Vec<LearnedChannel> {
        let degree = params.sh_degree;
        Self::channels(degree)
            .into_iter()
            .map(|(g, c)| {
                let vals = group::values(params, g);
                LearnedChannel::fit_init(&(0..params.len()).map(|i| vals[group::index(g, degree, i, c)]).collect::<Vec<_>>())
            })
            .collect()
    }

    /// Straight-through quantised parameters: what the decoder will see (rounded per step, the
    /// SH rest bands with the file's dead zone; positions and rotations are left as they are,
    /// their quantisation error is far below a pixel).
    pub fn render_params(&mut self, params: &Splats, iter: usize) -> Option<Splats> {
        if iter < self.start_iter {
            return None;
        }
        let mut out = params.clone();
        let degree = out.sh_degree;
        for g in LEARNED_GROUPS.into_iter().filter(|g| g.sh_band() <= degree) {
            round_group(&mut out, g, self.steps.of(g), self.deadzone(g));
        }
        Some(out)
    }

    /// The dead zone group `g` is quantised with: the file's ([`Steps::rest_deadzone`]) for the
    /// SH rest bands, none for the others. Training renders through it, so that a scene
    /// retrained after the RD search chose a dead zone is trained for it: rendered with plain
    /// rounding, coefficients the dead zone zeroes cost 0.3–0.5 dB held-out on lego-200
    /// (docs/wd.md §13). The bit estimate ignores it (bins of one width).
    pub(crate) fn deadzone(&self, g: Group) -> f32 {
        if g.sh_band() > 0 {
            self.steps.rest_deadzone
        } else {
            0.0
        }
    }

    /// Adds `w·R` and its gradient into `grad`; trains the entropy model one step.
    pub fn rate_and_grad(&mut self, params: &Splats, grad: &mut Splats, iter: usize) -> f64 {
        if iter < self.start_iter {
            return 0.0;
        }
        let n = params.len();
        let degree = params.sh_degree;
        let channels = Self::channels(degree);
        let nc = channels.len();
        let at = |i: usize, (g, c): (Group, usize)| group::index(g, degree, i, c);
        if self.models.len() != nc {
            self.models = Self::fit_models(params);
        }
        // ∂D/∂ln s from the distortion gradient w.r.t. the rendered (quantised) values, which
        // `grad` holds before the rate gradient is added.
        let mut d_log_step = GroupMap::<f64>::default();
        if self.learn_steps {
            for &(g, c) in &channels {
                let (vals, grads, step, dz) = (group::values(params, g), group::values(grad, g), self.steps.of(g), self.deadzone(g));
                for i in 0..n {
                    let v = vals[at(i, (g, c))];
                    let x = v / step;
                    d_log_step[g] += f64::from(grads[at(i, (g, c))]) * f64::from((q_dz(v, step, dz) as f32 - x) * step);
                }
            }
        }
        let logit_min = (self.min_opacity / (1.0 - self.min_opacity).max(1e-6)).max(1e-9).ln();
        let scale = self.lambda.training_weight_per_bit();
        let mut total = 0.0;
        let mut model_grads = vec![(0.0f64, 0.0f64); nc];
        // Each block's Gaussians are measured in parallel (the models' bits and derivatives,
        // the part that costs), then summed and applied one Gaussian after another in index
        // order, so every sum is the same on any number of threads.
        let mut per = vec![PerGaussian::default(); RATE_BLOCK.min(n)];
        let mut per_channel = vec![PerChannel::default(); RATE_BLOCK.min(n) * nc];
        for start in (0..n).step_by(RATE_BLOCK) {
            let len = RATE_BLOCK.min(n - start);
            per[..len].par_iter_mut().zip(per_channel[..len * nc].par_chunks_mut(nc)).enumerate().for_each(|(j, (pg, pc))| {
                let i = start + j;
                let mut bits_i = FIXED_BITS_PER_GAUSSIAN;
                let mut d_step_i = GroupMap::<f64>::default();
                for ((k, &(g, c)), out) in channels.iter().enumerate().zip(pc.iter_mut()) {
                    let step = self.steps.of(g);
                    let b = self.models[k].bits(f64::from(group::values(params, g)[at(i, (g, c))]), f64::from(step));
                    bits_i += b.bits;
                    d_step_i[g] += b.d_step * f64::from(step);
                    *out = PerChannel { d_value: b.d_value, d_mu: b.d_mu, d_log_b: b.d_log_b };
                }
                let t = (params.opacity_logits[i] - logit_min) / 0.5;
                let keep = f64::from(sigmoid(t));
                *pg = PerGaussian { bits: bits_i, keep, d_keep: keep * (1.0 - keep) / 0.5, d_step: d_step_i };
            });
            for (j, (pg, pc)) in per[..len].iter().zip(per_channel.chunks_exact(nc)).enumerate() {
                let i = start + j;
                total += pg.keep * pg.bits;
                for g in LEARNED_GROUPS {
                    d_log_step[g] += scale * pg.keep * pg.d_step[g];
                }
                for (k, (&(g, c), b)) in channels.iter().zip(pc).enumerate() {
                    model_grads[k].0 += b.d_mu;
                    model_grads[k].1 += b.d_log_b;
                    group::values_mut(grad, g)[at(i, (g, c))] += (scale * pg.keep * b.d_value) as f32;
                }
                grad.opacity_logits[i] += (scale * pg.bits * pg.d_keep) as f32;
            }
        }
        // One normalised gradient step on the entropy model (it minimises the same bits).
        for (m, (gm, gb)) in self.models.iter_mut().zip(model_grads) {
            let nn = n.max(1) as f64;
            m.mu -= 0.1 * m.log_b.exp() * gm / nn;
            m.log_b -= 0.1 * gb / nn;
        }
        self.last_step_gradient = d_log_step;
        self.shared.lock().expect("term lock").bits = Some(total);
        if self.learn_steps {
            self.update_steps(&d_log_step);
        }
        self.last_bits = total;
        self.lambda.training_weight_per_bit() * total
    }

    /// `w·R` with frozen models and steps (no gradient, no learning): for tests and reports.
    pub fn rate(&self, params: &Splats) -> f64 {
        let mut t = self.clone();
        t.learn_steps = false;
        let mut scratch = params.clone();
        t.rate_and_grad(params, &mut scratch, 0)
    }
}

impl RdTerm for RateTerm {
    fn render_params(&mut self, params: &Splats, iter: usize) -> Option<Splats> {
        RateTerm::render_params(self, params, iter)
    }

    fn rate_and_grad(&mut self, params: &Splats, grad: &mut Splats, iter: usize) -> f64 {
        RateTerm::rate_and_grad(self, params, grad, iter)
    }

    fn outcome(&self) -> Option<RateOutcome> {
        Some(RateOutcome { steps: self.steps.map(), estimated_bits: (self.last_bits > 0.0).then_some(self.last_bits) })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// λ whose training weight is 1 per bit: the rate dominates.
    fn big() -> Lambda {
        Lambda::new(1e9).unwrap()
    }

    fn scene() -> Splats {
        let mut s = Splats::new(1);
        for i in 0..50 {
            let x = i as f32 * 0.37;
            s.push(
                [x.sin(), x.cos(), 0.0],
                [-3.0 + x.sin(), -3.2, -2.9 + 0.1 * x.cos()],
                [1.0, 0.0, 0.0, 0.0],
                1.0 + x.sin(),
                [0.2 * x.cos(), 0.1, -0.1],
                &[0.05 * x.sin(); 9],
            );
        }
        s
    }

    #[test]
    fn gradient_matches_finite_differences() {
        let s = scene();
        let mut term = RateTerm::new(big(), Steps::default(), 0.02);
        let mut g = s.clone();
        let zero = |g: &mut Splats| {
            g.log_scales.iter_mut().flatten().for_each(|v| *v = 0.0);
            g.opacity_logits.iter_mut().for_each(|v| *v = 0.0);
            g.sh_dc.iter_mut().flatten().for_each(|v| *v = 0.0);
            g.sh_rest.iter_mut().for_each(|v| *v = 0.0);
        };
        zero(&mut g);
        term.rate_and_grad(&s, &mut g, 0); // fits the model
        let frozen = term.clone();
        zero(&mut g);
        let mut t = frozen.clone();
        t.rate_and_grad(&s, &mut g, 0);
        let eval = |s: &Splats| {
            let mut t = frozen.clone();
            let mut scratch = s.clone();
            t.rate_and_grad(s, &mut scratch, 0)
        };
        let h = 1e-3;
        for (name, get) in [("opacity", 0usize), ("scale", 1), ("dc", 2), ("rest", 3)] {
            let mut p = s.clone();
            let mut m = s.clone();
            let analytic = match get {
                0 => {
                    p.opacity_logits[7] += h;
                    m.opacity_logits[7] -= h;
                    g.opacity_logits[7]
                }
                1 => {
                    p.log_scales[7][0] += h;
                    m.log_scales[7][0] -= h;
                    g.log_scales[7][0]
                }
                2 => {
                    p.sh_dc[7][0] += h;
                    m.sh_dc[7][0] -= h;
                    g.sh_dc[7][0]
                }
                _ => {
                    p.sh_rest[7 * 9 + 4] += h;
                    m.sh_rest[7 * 9 + 4] -= h;
                    g.sh_rest[7 * 9 + 4]
                }
            };
            let fd = (eval(&p) - eval(&m)) / (2.0 * f64::from(h));
            assert!((f64::from(analytic) - fd).abs() <= 0.02 * fd.abs() + 1e-3, "{name}: analytic {analytic} fd {fd}");
        }
    }

    fn zeroed(s: &Splats) -> Splats {
        let mut g = s.clone();
        g.log_scales.iter_mut().flatten().for_each(|v| *v = 0.0);
        g.opacity_logits.iter_mut().for_each(|v| *v = 0.0);
        g.sh_dc.iter_mut().flatten().for_each(|v| *v = 0.0);
        g.sh_rest.iter_mut().for_each(|v| *v = 0.0);
        g
    }

    #[test]
    fn step_gradient_of_the_rate_matches_finite_differences() {
        let s = scene();
        let mut fitted = RateTerm::new(big(), Steps::default(), 0.02);
        fitted.rate_and_grad(&s, &mut zeroed(&s), 0); // fits the models
        let mut t = fitted.clone().learning_steps();
        t.rate_and_grad(&s, &mut zeroed(&s), 0); // no distortion gradient: the rate part alone
        let h = 1e-4f64;
        for k in &LEARNED_GROUPS[..4] {
            let k = *k;
            let at = |e: f64| {
                let mut f = fitted.clone();
                let v = f.steps.of_mut(k);
                *v = (f64::from(*v) * e.exp()) as f32;
                f.rate(&s)
            };
            let fd = (at(h) - at(-h)) / (2.0 * h);
            let analytic = t.last_step_gradient[k];
            assert_eq!(t.last_step_gradient[Group::Sh2], 0.0, "a degree-1 scene has no band 2");
            assert!((analytic - fd).abs() <= 0.02 * fd.abs() + 1e-6, "group {k:?}: analytic {analytic} fd {fd}");
            assert!(analytic < 0.0, "coarser steps must cost fewer bits (group {k:?}: {analytic})");
        }
    }

    #[test]
    fn learned_steps_grow_under_rate_and_shrink_under_distortion() {
        let s = scene();
        let start = Steps::default();
        // Rate only (a huge λ, no distortion gradient): every step grows.
        let mut t = RateTerm::new(big(), start, 0.02).learning_steps();
        let handle = t.shared();
        for it in 0..200 {
            t.rate_and_grad(&s, &mut zeroed(&s), it);
        }
        let grown = handle.lock().unwrap().steps;
        for k in &LEARNED_GROUPS[..4] {
            assert!(grown.of(*k) > 1.2 * start.of(*k), "group {k:?}: {grown:?}");
        }
        // Distortion only (λ = 0, D = Σ (q − v)² so ∂D/∂q = 2(q − v)): every step shrinks.
        let mut t = RateTerm::new(Lambda::ZERO, start, 0.02).learning_steps();
        for it in 0..200 {
            let q = t.render_params(&s, it).unwrap();
            let mut g = zeroed(&s);
            let d_grad = |g: &mut [f32], q: &[f32], v: &[f32]| g.iter_mut().zip(q.iter().zip(v)).for_each(|(g, (q, v))| *g = 2.0 * (q - v));
            d_grad(g.log_scales.as_flattened_mut(), q.log_scales.as_flattened(), s.log_scales.as_flattened());
            d_grad(&mut g.opacity_logits, &q.opacity_logits, &s.opacity_logits);
            d_grad(g.sh_dc.as_flattened_mut(), q.sh_dc.as_flattened(), s.sh_dc.as_flattened());
            d_grad(&mut g.sh_rest, &q.sh_rest, &s.sh_rest);
            t.rate_and_grad(&s, &mut g, it);
        }
        for k in &LEARNED_GROUPS[..4] {
            assert!(t.steps.of(*k) < 0.8 * start.of(*k), "group {k:?}: {:?}", t.steps);
        }
    }

    #[test]
    fn the_term_is_off_before_its_start_iteration() {
        let s = scene();
        let mut t = RateTerm::new(big(), Steps::default(), 0.02).learning_steps();
        t.start_iter = 10;
        let mut g = zeroed(&s);
        assert!(t.render_params(&s, 9).is_none());
        assert_eq!(t.rate_and_grad(&s, &mut g, 9), 0.0);
        assert_eq!(g, zeroed(&s), "no gradient before the start");
        assert_eq!(t.steps, Steps::default(), "no step learning before the start");
        assert!(t.render_params(&s, 10).is_some());
        assert!(t.rate_and_grad(&s, &mut g, 10) > 0.0);
    }

    /// Training renders the learned groups as the file decodes them, the SH rest bands with the
    /// file's dead zone included: rendered and decoded values agree Gaussian by Gaussian.
    #[test]
    fn renders_the_learned_groups_as_the_file_decodes_them() {
        use crate::rate::quantise::{dequantise, quantise_ordered};
        let mut s = scene();
        // SH rest values spanning the dead zone: some within it, some beyond.
        s.sh_rest.iter_mut().enumerate().for_each(|(i, v)| *v = 0.09 * ((i as f32 * 0.71).sin()));
        for deadzone in [0.0, 0.3] {
            let steps = Steps { rest_deadzone: deadzone, sh_rest: [0.03; 3], ..Steps::default() };
            let rendered = RateTerm::new(big(), steps, 0.02).render_params(&s, 0).unwrap();
            let (q, order) = quantise_ordered(&s, &steps, &[]);
            let decoded = dequantise(&q);
            let k = s.rest_coeffs() * 3;
            let mut zeros = 0;
            for (j, &i) in order.iter().enumerate() {
                let close = |a: f32, b: f32| (a - b).abs() <= 1e-5 * (1.0 + b.abs());
                assert!(close(rendered.opacity_logits[i], decoded.opacity_logits[j]), "opacity of {i}");
                for c in 0..3 {
                    assert!(close(rendered.log_scales[i][c], decoded.log_scales[j][c]), "scale of {i}");
                    assert!(close(rendered.sh_dc[i][c], decoded.sh_dc[j][c]), "DC of {i}");
                }
                for c in 0..k {
                    let (r, d) = (rendered.sh_rest[i * k + c], decoded.sh_rest[j * k + c]);
                    assert!(close(r, d), "dead zone {deadzone}: SH rest {c} of {i}: rendered {r}, decoded {d}");
                    zeros += usize::from(d == 0.0);
                }
            }
            // The dead zone zeroes more coefficients than rounding: the case is exercised.
            let plain = s.sh_rest.iter().filter(|v| (*v / 0.03).round() == 0.0).count();
            assert_eq!(zeros > plain, deadzone > 0.0, "dead zone {deadzone}: {zeros} zeros, {plain} by rounding");
        }
    }

    /// The term's value, gradient, step gradient and model update are those of the plain loop
    /// over the Gaussians in order (written out here), on 1 and 3 threads, over several of its
    /// parallel blocks.
    #[test]
    fn the_blocked_term_is_the_plain_loop_on_any_thread_count() {
        let s = gscodec_decoder::testkit::random_splats(2 * RATE_BLOCK + 123, 3, 31);
        let grad0 = gscodec_decoder::testkit::random_splats(s.len(), 3, 32);
        let mut fitted = RateTerm::new(Lambda::new(4.0).unwrap(), Steps::default(), 0.02).learning_steps();
        fitted.rate_and_grad(&s, &mut grad0.clone(), 0); // fits the models
        let run = |threads: usize| {
            let (mut t, mut g) = (fitted.clone(), grad0.clone());
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            let v = pool.install(|| t.rate_and_grad(&s, &mut g, 1));
            (v, g, t.last_step_gradient, t.models.iter().map(|m| (m.mu, m.log_b)).collect::<Vec<_>>())
        };
        // The plain loop.
        let (t, mut g) = (fitted.clone(), grad0.clone());
        let degree = s.sh_degree;
        let channels = RateTerm::channels(degree);
        let at = |i: usize, (g, c): (Group, usize)| group::index(g, degree, i, c);
        let mut d_log_step = GroupMap::<f64>::default();
        for &(gr, c) in &channels {
            let (step, dz) = (t.steps.of(gr), t.deadzone(gr));
            for i in 0..s.len() {
                let v = group::values(&s, gr)[at(i, (gr, c))];
                d_log_step[gr] +=
                    f64::from(group::values(&grad0, gr)[at(i, (gr, c))]) * f64::from((q_dz(v, step, dz) as f32 - v / step) * step);
            }
        }
        let logit_min = (t.min_opacity / (1.0 - t.min_opacity).max(1e-6)).max(1e-9).ln();
        let scale = t.lambda.training_weight_per_bit();
        let (mut total, mut model_grads) = (0.0, vec![(0.0f64, 0.0f64); channels.len()]);
        for i in 0..s.len() {
            let (mut bits, mut d_step, mut d_values) = (FIXED_BITS_PER_GAUSSIAN, GroupMap::<f64>::default(), vec![]);
            for (k, &(gr, c)) in channels.iter().enumerate() {
                let step = t.steps.of(gr);
                let b = t.models[k].bits(f64::from(group::values(&s, gr)[at(i, (gr, c))]), f64::from(step));
                bits += b.bits;
                d_values.push(b.d_value);
                d_step[gr] += b.d_step * f64::from(step);
                model_grads[k].0 += b.d_mu;
                model_grads[k].1 += b.d_log_b;
            }
            let keep = f64::from(sigmoid((s.opacity_logits[i] - logit_min) / 0.5));
            total += keep * bits;
            for gr in LEARNED_GROUPS {
                d_log_step[gr] += scale * keep * d_step[gr];
            }
            for (k, &(gr, c)) in channels.iter().enumerate() {
                group::values_mut(&mut g, gr)[at(i, (gr, c))] += (scale * keep * d_values[k]) as f32;
            }
            g.opacity_logits[i] += (scale * bits * keep * (1.0 - keep) / 0.5) as f32;
        }
        let models: Vec<(f64, f64)> = t
            .models
            .iter()
            .zip(&model_grads)
            .map(|(m, (gm, gb))| (m.mu - 0.1 * m.log_b.exp() * gm / s.len() as f64, m.log_b - 0.1 * gb / s.len() as f64))
            .collect();
        let one = run(1);
        assert_eq!(one.0.to_bits(), (scale * total).to_bits());
        assert_eq!(one.1, g);
        assert_eq!(one.2 .0.map(f64::to_bits), d_log_step.0.map(f64::to_bits));
        assert_eq!(one.3, models);
        let three = run(3);
        assert_eq!(
            (three.0.to_bits(), &three.1, three.2 .0.map(f64::to_bits), &three.3),
            (one.0.to_bits(), &one.1, one.2 .0.map(f64::to_bits), &one.3)
        );
    }
}

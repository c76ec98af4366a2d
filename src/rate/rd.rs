//! Rate–distortion search over the encoder's choices by rendering: per-group step sizes, the
//! significance pruning threshold, the SH degree, per-Gaussian SH band dropping, per-band SH
//! vector quantisation and the importance classes, greedily chosen while `J = D + λ·R` falls;
//! the trials of each stage run in parallel.
//!
//! * `D` = 255² × mean squared error (RGB, all pixels) of the scene's views against the same
//!   views of the input scene: by default its standard orbit views ([`crate::views::orbit_cameras`],
//!   up −y as `eval --orbit`, 8 views at 96×96); for a scene trained from a dataset, views from its
//!   training cameras ([`RdViews::of_dataset`], what the encoder passes).
//! * `R` = file size in megabits (bits / 10⁶): λ is a [`Lambda`], whose docs hold the unit.

use gscodec_decoder::render::{record, render, replay, Recording};
use gscodec_decoder::{Image, RenderOptions, SceneError, Splats};
use rayon::prelude::*;
use serde::Serialize;

use super::encode::GroupCache;
use super::group::Group;
use super::lambda::Lambda;
use super::quantise::{dequantise, Steps};
use super::{encode_cached, opaque_enough, pruned, CoarseTail, EncodeConfig, Importance};
use crate::loss::features::{pyramid::Pyramid, FeatureSpace};
use crate::loss::tensor::Tensor;
use crate::loss::wd::{self, Reference, Sigma};
use crate::loss::L1Ssim;
use crate::views::{orbit_cameras, UpAxis};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

/// Views and resolution the search renders.
pub const VIEWS: usize = 8;
pub const SIZE: u32 = 96;
/// The side of the orbit views on which the pruning stage measures `D` for a scene without
/// cameras: the evaluation's own (`encoder::ORBIT_SIZE`, what `eval --reference --orbit 8` and
/// `--target-psnr` measure), where every later stage renders at [`SIZE`]. Pruning decides which
/// Gaussians exist, and at 96² small ones look cheaper to drop than the 256² views find them
/// (docs/codec.md §16); the later stages trade steps, which the coarser views rank alike. The
/// importance measures that rank the Gaussians (significance, removal errors:
/// [`super::importance::views`]) are taken at this side too (§19).
pub const PRUNING_SIZE: u32 = 256;

/// The views `D` is measured on: cameras, the background they are drawn over, and what `D`
/// measures on them ([`RdDistortion`]).
#[derive(Debug, Clone)]
pub struct RdViews {
    cams: Vec<gscodec_decoder::Camera>,
    background: [f32; 3],
    /// Per view, its pixels per pixel of the image it stands for (1, or less for a dataset
    /// camera scaled down to [`MAX_CAMERA_SIDE`]): WD's pooling scale σ, given in image
    /// pixels, is scaled by it.
    pixel_scale: Vec<f64>,
    distortion: RdDistortion,
    /// The cameras the significance is summed over ([`RdViews::significance`]); `None`: the
    /// scene's own ([`super::importance::views`]).
    significance_cams: Option<Vec<gscodec_decoder::Camera>>,
}

/// What `D` measures on the views.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum RdDistortion {
    /// 255² × mean squared error (RGB, all pixels): the search's default.
    #[default]
    Mse,
    /// A training loss's distortion of the decoded views against the input's, mean over views:
    /// d_WD in the built-in `pyramid` feature space with pooling scale `wd_sigma` (image pixels;
    /// no WD term when `None`) plus `l_orig` × (0.8·L1 + 0.2·(1 − SSIM)). So `l1ssim` is
    /// `{ None, 1 }`, `wd` is `{ Some(σ), 0 }` and `wdr` is `{ Some(σ), β }`, γ left out (a scale).
    /// It is brought into `D`'s unit (255²·MSE) by one factor per search, fixed on the search's
    /// first configuration ([`Trials::calibrate`]), so that λ trades the same bits for both.
    Loss { wd_sigma: Option<f64>, l_orig: f64 },
}

impl RdViews {
    /// The scene's [`VIEWS`] standard orbit views at [`SIZE`]², over black (a scene without cameras).
    pub fn orbit(scene: &Splats) -> Self {
        Self::cameras(orbit_cameras(scene, VIEWS, SIZE, SIZE, UpAxis::NegY.vector()), [0.0; 3])
    }

    /// Given cameras over `background`, `D` the squared error ([`RdDistortion::Mse`]).
    ///
    /// # Panics
    /// If `cams` is empty.
    pub fn cameras(cams: Vec<gscodec_decoder::Camera>, background: [f32; 3]) -> Self {
        assert!(!cams.is_empty(), "D needs at least one view");
        let pixel_scale = vec![1.0; cams.len()];
        RdViews { cams, background, pixel_scale, distortion: RdDistortion::Mse, significance_cams: None }
    }

    /// The same views with `D` measuring `distortion`.
    pub fn measuring(self, distortion: RdDistortion) -> Self {
        RdViews { distortion, ..self }
    }

    /// The significance of each Gaussian of `scene` (which ones pruning and the importance
    /// classes take first): summed over the dataset's training cameras for views from
    /// [`RdViews::of_dataset`] ([`super::importance::dataset_views`]), else over the scene's own
    /// views ([`super::importance::significance`]). An encode prunes with the significance of
    /// the views its search measured on, so that the search's trials and the file agree.
    pub fn significance(&self, scene: &Splats) -> Vec<f32> {
        super::importance::significance_on(scene, &self.importance_cams(scene))
    }

    /// [`RdViews::significance`] and the removal errors (what pruning ranks by) from the same
    /// cameras, rendered on the views' background.
    pub fn importance(&self, scene: &Splats) -> Importance {
        Importance::on(scene, &self.importance_cams(scene), self.background)
    }

    /// The cameras [`RdViews::significance`] and [`RdViews::importance`] sum over.
    fn importance_cams(&self, scene: &Splats) -> Vec<gscodec_decoder::Camera> {
        self.significance_cams.clone().unwrap_or_else(|| super::importance::views(scene))
    }

    /// [`VIEWS`] of `dataset`'s training cameras, evenly spread through its training frames
    /// (never a held-out one), over its background, each at its own size or scaled down to at
    /// most [`MAX_CAMERA_SIDE`] pixels on its longer side: the views a scene trained from the
    /// dataset is made to be seen from; the significance is summed over all its training
    /// cameras. `None` when the dataset has no training frames.
    pub fn of_dataset(dataset: &crate::io::Dataset) -> Option<Self> {
        let train = dataset.split(crate::io::Split::Train);
        let n = VIEWS.min(train.len());
        let (cams, pixel_scale): (Vec<_>, Vec<_>) = (0..n)
            .map(|i| {
                let c = &train[(2 * i + 1) * train.len() / (2 * n)].camera;
                let view = crate::views::fit_within(c, MAX_CAMERA_SIDE);
                let pixels = f64::from(view.width) / f64::from(c.width);
                (view, pixels)
            })
            .unzip();
        let significance_cams = Some(super::importance::dataset_views(dataset));
        (!cams.is_empty()).then(|| RdViews { pixel_scale, significance_cams, ..RdViews::cameras(cams, dataset.background) })
    }
}

/// The longest side of a dataset camera's view in `D` ([`RdViews::of_dataset`]).
pub const MAX_CAMERA_SIDE: u32 = 256;

/// One trial of the search (a configuration it encoded and measured).
#[derive(Debug, Clone, Serialize)]
pub struct Trial {
    pub step: usize,
    pub change: String,
    pub bytes: usize,
    pub d: f64,
    pub psnr: f64,
    pub j: f64,
}

/// The D/R evaluation of a configuration.
pub struct Evaluator<'a> {
    scene: &'a Splats,
    cams: Vec<gscodec_decoder::Camera>,
    refs: Vec<Image>,
    opts: RenderOptions,
    /// `D` as a loss measures it ([`RdDistortion::Loss`]); `None` for the squared error.
    loss: Option<LossD>,
    /// The scene's importance from the views' cameras ([`RdViews::importance`]), measured once.
    importance: Importance,
    /// CPU time spent encoding and rendering trials (nanoseconds, summed over threads), for
    /// [`Clock`].
    encode_ns: AtomicU64,
    render_ns: AtomicU64,
    /// The decoded scene of the current stage's start and its frames' [`Recording`]s: a trial
    /// whose decoded geometry is the same (it changes only SH coefficients or the SH degree) is
    /// drawn by replaying them with its colours ([`replay`], bit-identical to a render).
    base: Option<(Splats, Vec<Recording>)>,
    /// The groups the trials have coded ([`GroupCache`]): a trial changing one group's step
    /// codes only that group.
    cache: GroupCache,
}

/// [`RdDistortion::Loss`] on the evaluator's views.
struct LossD {
    /// Per view, the WD statistics of its reference render (empty without a WD term).
    wd: Vec<Reference<f32>>,
    l_orig: f64,
    /// `D` units (255²·MSE) per unit of the loss, fixed by [`Trials::calibrate`].
    scale: Option<f64>,
}

/// The measures of one configuration's decoded views, means over the views: 255²·MSE and the
/// loss's distortion (0 for [`RdDistortion::Mse`]). (Per view, [`Evaluator::view_measure`]
/// gives the plain MSE, and [`Evaluator::mean`] scales the mean.)
#[derive(Debug, Clone, Copy)]
struct Measured {
    mse: f64,
    loss: f64,
}

/// Whether `a` and `b` have the same geometry (positions, scales, rotations, opacities), bit for bit.
fn same_geometry(a: &Splats, b: &Splats) -> bool {
    let same = |x: &[f32], y: &[f32]| x.len() == y.len() && x.iter().zip(y).all(|(p, q)| p.to_bits() == q.to_bits());
    same(a.positions.as_flattened(), b.positions.as_flattened())
        && same(a.log_scales.as_flattened(), b.log_scales.as_flattened())
        && same(a.rotations.as_flattened(), b.rotations.as_flattened())
        && same(&a.opacity_logits, &b.opacity_logits)
}

impl<'a> Evaluator<'a> {
    /// `D` on the scene's orbit views ([`RdViews::orbit`]).
    pub fn new(scene: &'a Splats) -> Self {
        Self::with_views(scene, RdViews::orbit(scene))
    }

    /// `D` on `views`, pruning and the importance classes taking the Gaussians in the order of
    /// their [`RdViews::importance`] (removal error and significance).
    pub fn with_views(scene: &'a Splats, views: RdViews) -> Self {
        let t = Instant::now();
        let importance = views.importance(scene);
        let sig_s = t.elapsed().as_secs_f64();
        let sig_views = match (timing(), &views.significance_cams) {
            (false, _) => 0,
            (true, Some(cams)) => cams.len(),
            (true, None) => super::importance::views(scene).len(),
        };
        let ev = Self::with_importance(scene, views, importance);
        if timing() {
            eprintln!(
                "timing: significance and removal errors ({sig_views} views) {sig_s:.3} s wall; reference renders {:.3} s wall",
                t.elapsed().as_secs_f64() - sig_s
            );
        }
        ev
    }

    /// `D` on `views`, pruning and the importance classes taking the Gaussians in the order of
    /// `importance` (measured elsewhere).
    fn with_importance(scene: &'a Splats, views: RdViews, importance: Importance) -> Self {
        let RdViews { cams, background, pixel_scale, distortion, .. } = views;
        let opts = RenderOptions { background, ..RenderOptions::default() };
        let refs: Vec<Image> = cams.par_iter().map(|c| render(scene, c, &opts)).collect();
        let loss = match distortion {
            RdDistortion::Mse => None,
            RdDistortion::Loss { wd_sigma, l_orig } => {
                let wd = wd_sigma.map_or_else(Vec::new, |sigma| {
                    refs.par_iter()
                        .zip(&pixel_scale)
                        .map(|(r, s)| {
                            let feats = Pyramid::LUMA.features(&Tensor::from_image(r));
                            Reference::new(&feats, &Sigma::Constant(sigma * s), r.height as usize, r.width as usize)
                        })
                        .collect()
                });
                Some(LossD { wd, l_orig, scale: None })
            }
        };
        Evaluator {
            scene,
            cams,
            refs,
            opts,
            loss,
            importance,
            encode_ns: AtomicU64::new(0),
            render_ns: AtomicU64::new(0),
            base: None,
            cache: GroupCache::default(),
        }
    }

    /// (bytes, D) of `config`.
    pub fn eval(&self, config: &EncodeConfig) -> Result<(usize, f64), SceneError> {
        self.eval_report(config).map(|(b, d, _)| (b, d))
    }

    /// (bytes, D, encoder report) of `config`.
    pub fn eval_report(&self, config: &EncodeConfig) -> Result<(usize, f64, super::EncodeReport), SceneError> {
        self.outcome(config).map(|o| (o.bytes, o.d, o.report))
    }

    fn outcome(&self, config: &EncodeConfig) -> Result<Outcome, SceneError> {
        let (bytes, report, dec) = self.code(config)?;
        let t = Instant::now();
        let m = self.measure(&dec);
        self.render_ns.fetch_add(t.elapsed().as_nanos() as u64, Ordering::Relaxed);
        Ok(self.outcome_of(bytes, m, report))
    }

    /// (bytes, encoder report, decoded scene) of `config`, its encode time counted for [`Clock`].
    fn code(&self, config: &EncodeConfig) -> Result<(usize, super::EncodeReport, Splats), SceneError> {
        let t = Instant::now();
        let (bytes, report, q) = encode_cached(self.scene, config, Some(&self.importance), Some(&self.cache))?;
        let dec = dequantise(&q);
        self.encode_ns.fetch_add(t.elapsed().as_nanos() as u64, Ordering::Relaxed);
        Ok((bytes.len(), report, dec))
    }

    /// The SH codebooks `config` codes with (its groups and codebooks from the cache).
    fn codebooks(&self, config: &EncodeConfig) -> Result<Vec<(Group, super::vq::Codebook)>, SceneError> {
        Ok(encode_cached(self.scene, config, Some(&self.importance), Some(&self.cache))?.2.codebooks)
    }

    /// `D` of a decoded scene on these views (see [`RdDistortion`]). A scene with the base's
    /// geometry is drawn by replaying the base's frames.
    ///
    /// # Panics
    /// For [`RdDistortion::Loss`] before [`Trials::calibrate`] has fixed its scale.
    pub fn distortion(&self, dec: &Splats) -> f64 {
        self.d(self.measure(dec))
    }

    fn measure(&self, dec: &Splats) -> Measured {
        let base = self.base.as_ref().filter(|(b, _)| same_geometry(b, dec));
        // Views in parallel (a frame at 96² has only 6 rows of tiles to share out), summed in order.
        let per_view: Vec<Measured> = (0..self.cams.len())
            .into_par_iter()
            .map(|v| {
                let frame = match base {
                    Some((_, recordings)) => replay(&recordings[v], dec, &self.cams[v], &self.opts),
                    None => render(dec, &self.cams[v], &self.opts),
                };
                self.view_measure(v, &frame)
            })
            .collect();
        Self::mean(&per_view)
    }

    /// The measures of view `v`'s `frame`.
    fn view_measure(&self, v: usize, frame: &Image) -> Measured {
        let r = &self.refs[v];
        let mse = crate::metrics::mse(r, frame);
        let loss = self.loss.as_ref().map_or(0.0, |l| {
            let wd = l.wd.get(v).map_or(0.0, |reference| wd::distortion(reference, &Pyramid::LUMA.features(&Tensor::from_image(frame))));
            wd + if l.l_orig > 0.0 { l.l_orig * L1Ssim::default().value(frame, r) } else { 0.0 }
        });
        Measured { mse, loss }
    }

    fn mean(per_view: &[Measured]) -> Measured {
        let n = per_view.len() as f64;
        Measured {
            mse: per_view.iter().map(|m| m.mse).sum::<f64>() / n * 255.0 * 255.0,
            loss: per_view.iter().map(|m| m.loss).sum::<f64>() / n,
        }
    }

    /// `D` of measures: the squared error, or the loss in `D`'s unit.
    fn d(&self, m: Measured) -> f64 {
        match &self.loss {
            None => m.mse,
            Some(l) => m.loss * l.scale.expect("the loss's scale is fixed (Trials::calibrate) before D is measured"),
        }
    }

    fn outcome_of(&self, bytes: usize, m: Measured, report: super::EncodeReport) -> Outcome {
        Outcome { bytes, d: self.d(m), mse: m.mse, report }
    }

    /// [`Evaluator::outcome`] of `config`, recording its frames as the base that later trials
    /// changing only colours replay (the same outcome: [`record`] draws what [`render`] draws).
    fn eval_as_base(&mut self, config: &EncodeConfig) -> Result<Outcome, SceneError> {
        let (bytes, report, dec) = self.code(config)?;
        let t = Instant::now();
        let (frames, recordings): (Vec<Image>, Vec<Recording>) = self.cams.par_iter().map(|c| record(&dec, c, &self.opts)).unzip();
        let per_view: Vec<Measured> = frames.par_iter().enumerate().map(|(v, f)| self.view_measure(v, f)).collect();
        let m = Self::mean(&per_view);
        self.base = Some((dec, recordings));
        self.render_ns.fetch_add(t.elapsed().as_nanos() as u64, Ordering::Relaxed);
        Ok(self.outcome_of(bytes, m, report))
    }
}

/// Whether the search prints its timing (`GSCODEC_TIMING` set in the environment): per stage,
/// its wall time, the trials it evaluated and their encode and render time (summed over threads).
fn timing() -> bool {
    std::env::var_os("GSCODEC_TIMING").is_some()
}

/// The search's stage timer for `GSCODEC_TIMING`.
struct Clock {
    on: bool,
    lap: Instant,
    evaluated: usize,
}

impl Clock {
    fn new(trials: &Trials) -> Clock {
        Clock { on: timing(), lap: Instant::now(), evaluated: trials.len() }
    }

    /// Prints the stage that ends now (see [`timing`]) and starts the next.
    fn lap(&mut self, trials: &Trials, stage: &str) {
        if self.on {
            let secs = |a: &AtomicU64| a.swap(0, Ordering::Relaxed) as f64 * 1e-9;
            let evs = std::iter::once(&trials.ev).chain(trials.pruning.as_ref().map(|p| &p.0));
            let (e, r) = evs.fold((0.0, 0.0), |(e, r), ev| (e + secs(&ev.encode_ns), r + secs(&ev.render_ns)));
            let n = trials.len() - self.evaluated;
            eprintln!(
                "timing: {stage}: {n} trials, {:.3} s wall; trial encode {e:.3} s, render {r:.3} s (summed over threads)",
                self.lap.elapsed().as_secs_f64()
            );
        }
        self.lap = Instant::now();
        self.evaluated = trials.len();
    }
}

const MULTIPLIERS: [f32; 6] = [1.0, 2.0, 4.0, 8.0, 16.0, 32.0];
/// Fractions of the Gaussians (least significant first) the significance pruning tries.
const PRUNE_QUANTILES: [f32; 19] =
    [0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.35, 0.4, 0.45, 0.5, 0.55, 0.6, 0.65, 0.7, 0.75, 0.8, 0.85, 0.9, 0.95];
/// Fractions of the kept Gaussians (weakest first) whose band is zeroed by SH band dropping.
const SH_DROP_QUANTILES: [f32; 7] = [0.1, 0.25, 0.4, 0.55, 0.7, 0.85, 0.95];
/// Codebook sizes tried per SH band for vector quantisation (`EncodeConfig::sh_vq`), each at the
/// band's chosen step and half an octave finer.
const VQ_ROWS: [u32; 4] = [64, 256, 1024, 4096];
const VQ_STEPS: [f32; 2] = [1.0, std::f32::consts::FRAC_1_SQRT_2];
/// SH rest dead zones tried after the steps are chosen (see `Steps::rest_deadzone`).
const DEADZONES: [f32; 4] = [0.1, 0.2, 0.3, 0.4];
/// Importance classes ([`CoarseTail`]) the search tries: the least significant share of the
/// kept Gaussians, and the factor of its steps (docs/codec.md, "Importance classes").
const TAIL_SHARES: [f32; 3] = [0.25, 0.5, 0.75];
const TAIL_FACTORS: [f32; 5] = [1.5, 2.0, 3.0, 4.0, 6.0];
/// Multipliers of one group's tail factor ([`CoarseTail::groups`]) tried after the tail is
/// chosen ([`tail_stage`]; docs/codec.md §36).
const TAIL_GROUP_MULTIPLIERS: [f32; 2] = [0.5, 2.0];
const REFINE: [f32; 3] = [std::f32::consts::FRAC_1_SQRT_2, 1.0, std::f32::consts::SQRT_2];
/// Quarter-octave moves of the last pass.
const REFINE_FINE: [f32; 3] = [0.840_896_4, 1.0, 1.189_207_1];
/// An eighth of an octave: [`step_nudges`].
const NUDGE: f32 = 1.090_507_7;

fn sorted(mut v: Vec<f32>) -> Vec<f32> {
    v.sort_by(f32::total_cmp);
    v
}

/// `c` with group `g`'s step multiplied by `m` (the knobs of the search: one per group).
fn with_knob(c: &EncodeConfig, g: Group, m: f32) -> EncodeConfig {
    let mut c = *c;
    *c.steps.of_mut(g) *= m;
    c
}

/// The trials of a search: each configuration is evaluated once (a configuration tried again
/// reuses its result), and a batch of configurations is evaluated in parallel (rayon). Results
/// come back in the batch's order, and every evaluation is itself deterministic, so the search's
/// choices and the chosen file do not depend on the thread count. An outcome does not depend on
/// λ either, so searches of one scene at several λ (`encode --target-psnr`'s probes) share one
/// `Trials` ([`search_with`]) and each configuration is coded and rendered once for all (each
/// search starts a new cache of coded groups, so memory stays that of one search).
pub struct Trials<'a> {
    ev: Evaluator<'a>,
    seen: Vec<(EncodeConfig, Outcome)>,
    /// The pruning stage's evaluator and outcomes, on the orbit views at [`PRUNING_SIZE`]² (a
    /// scene without cameras, [`Trials::new`]); `None`: pruning measures on `ev`'s views.
    pruning: Option<(Evaluator<'a>, Vec<(EncodeConfig, Outcome)>)>,
}

/// What a configuration gives: its bytes, `D`, 255²·MSE (= `D` for [`RdDistortion::Mse`]) and
/// encoder report.
#[derive(Debug, Clone)]
struct Outcome {
    bytes: usize,
    d: f64,
    mse: f64,
    report: super::EncodeReport,
}

impl<'a> Trials<'a> {
    /// No trials yet for `scene` (renders its reference views and computes its significance).
    ///
    /// # Errors
    /// An invalid scene (NaN/Inf, inconsistent arrays).
    pub fn new(scene: &'a Splats) -> Result<Self, SceneError> {
        let mut trials = Self::with_views(scene, RdViews::orbit(scene))?;
        let views = RdViews::cameras(orbit_cameras(scene, VIEWS, PRUNING_SIZE, PRUNING_SIZE, UpAxis::NegY.vector()), [0.0; 3]);
        let importance = trials.ev.importance.clone();
        trials.pruning = Some((Evaluator::with_importance(scene, views, importance), Vec::new()));
        Ok(trials)
    }

    /// [`Trials::new`] with `D` measured on `views`.
    ///
    /// # Errors
    /// An invalid scene (NaN/Inf, inconsistent arrays).
    pub fn with_views(scene: &'a Splats, views: RdViews) -> Result<Self, SceneError> {
        scene.validate()?;
        Ok(Trials { ev: Evaluator::with_views(scene, views), seen: Vec::new(), pruning: None })
    }

    /// The scene the trials code.
    pub fn scene(&self) -> &'a Splats {
        self.ev.scene
    }

    /// The scene's importance from the search's views ([`RdViews::importance`]).
    pub fn importance(&self) -> &Importance {
        &self.ev.importance
    }

    /// `config`'s file size and decoded scene, coded as the trials are: the groups and SH
    /// codebooks they have coded are taken from their cache, so a configuration close to one
    /// tried costs only what differs ([`encode_cached`]: the same bytes as [`super::encode_with`]).
    ///
    /// # Errors
    /// `config`'s encode.
    pub fn code(&self, config: &EncodeConfig) -> Result<(usize, Splats), SceneError> {
        let (bytes, _, dec) = self.ev.code(config)?;
        Ok((bytes, dec))
    }

    /// Configurations evaluated so far (those of the pruning views included).
    pub fn len(&self) -> usize {
        self.seen.len() + self.pruning.as_ref().map_or(0, |p| p.1.len())
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Fixes the factor that brings [`RdDistortion::Loss`] into `D`'s unit: 255²·MSE over the
    /// loss's distortion of `config`, so that `config`'s `D` is its squared error and λ trades
    /// the same bits there whichever `D` is measured. The first call fixes it (the searches
    /// sharing these trials compare outcomes in one unit); where `config` is lossless (no error
    /// to compare), `D` stays the squared error. Nothing for [`RdDistortion::Mse`].
    ///
    /// # Errors
    /// `config`'s encode.
    pub fn calibrate(&mut self, config: &EncodeConfig) -> Result<(), SceneError> {
        if self.ev.loss.as_ref().is_none_or(|l| l.scale.is_some()) {
            return Ok(());
        }
        let (_, _, dec) = self.ev.code(config)?;
        let m = self.ev.measure(&dec);
        let scale = m.mse / m.loss;
        match (m.mse > 0.0 && scale.is_finite() && scale > 0.0, self.ev.loss.as_mut()) {
            (true, Some(l)) => l.scale = Some(scale),
            _ => self.ev.loss = None,
        }
        Ok(())
    }
}

impl Trials<'_> {
    /// The outcomes of `configs`, in order.
    fn run(&mut self, configs: &[EncodeConfig]) -> Result<Vec<Outcome>, SceneError> {
        run_on(&self.ev, &mut self.seen, configs)
    }

    /// [`Trials::run`] for the pruning stage: on the pruning views where there are some.
    fn run_pruning(&mut self, configs: &[EncodeConfig]) -> Result<Vec<Outcome>, SceneError> {
        match &mut self.pruning {
            Some((ev, seen)) => run_on(ev, seen, configs),
            None => self.run(configs),
        }
    }

    fn one(&mut self, config: &EncodeConfig) -> Result<Outcome, SceneError> {
        Ok(self.run(std::slice::from_ref(config))?.remove(0))
    }

    /// The outcome of `config`, the start of a stage, whose frames become the base that the
    /// stage's trials changing only colours replay ([`Evaluator::eval_as_base`]).
    fn base(&mut self, config: &EncodeConfig) -> Result<Outcome, SceneError> {
        let outcome = self.ev.eval_as_base(config)?;
        if !self.seen.iter().any(|(k, _)| k == config) {
            self.seen.push((*config, outcome.clone()));
        }
        Ok(outcome)
    }
}

/// The outcomes of `configs` on `ev`, in order, each evaluated once: those in `seen` reused, the
/// others evaluated in parallel and added to it.
fn run_on(ev: &Evaluator, seen: &mut Vec<(EncodeConfig, Outcome)>, configs: &[EncodeConfig]) -> Result<Vec<Outcome>, SceneError> {
    let mut todo: Vec<EncodeConfig> = Vec::new();
    for c in configs {
        if !seen.iter().any(|(k, _)| k == c) && !todo.contains(c) {
            todo.push(*c);
        }
    }
    let done: Vec<Result<Outcome, SceneError>> = todo.par_iter().map(|c| ev.outcome(c)).collect();
    for (c, r) in todo.into_iter().zip(done) {
        seen.push((c, r?));
    }
    Ok(configs.iter().map(|c| seen.iter().find(|(k, _)| k == c).expect("evaluated above").1.clone()).collect())
}

/// The trials a search has recorded, reported to `on_step` as they come.
struct Log<'f, F> {
    path: Vec<Trial>,
    on_step: &'f mut F,
    lambda: Lambda,
}

impl<F: FnMut(&Trial)> Log<'_, F> {
    fn j(&self, bytes: usize, d: f64) -> f64 {
        d + self.lambda.rate_cost(bytes)
    }

    fn record(&mut self, change: String, o: &Outcome) {
        let psnr = gscodec_decoder::render::psnr_of_mse(o.mse / (255.0 * 255.0));
        let p = Trial { step: self.path.len(), change, bytes: o.bytes, d: o.d, psnr, j: self.j(o.bytes, o.d) };
        (self.on_step)(&p);
        self.path.push(p);
    }

    /// One stage of whole-file choices: evaluates the candidates (one parallel batch), records
    /// each, and returns the (J, config) of lowest J, the first of equals, or `keep` when none
    /// is below `keep`'s J.
    fn stage(
        &mut self,
        trials: &mut Trials,
        keep: (f64, EncodeConfig),
        cands: Vec<(String, EncodeConfig)>,
    ) -> Result<(f64, EncodeConfig), SceneError> {
        let configs: Vec<EncodeConfig> = cands.iter().map(|c| c.1).collect();
        let outcomes = trials.run(&configs)?;
        Ok(self.pick(keep, cands, outcomes))
    }

    /// Records each candidate's outcome and returns the (J, config) of lowest J, the first of
    /// equals, or `keep` when none is below `keep`'s J.
    fn pick(&mut self, keep: (f64, EncodeConfig), cands: Vec<(String, EncodeConfig)>, outcomes: Vec<Outcome>) -> (f64, EncodeConfig) {
        let mut best = keep;
        for ((name, c), o) in cands.into_iter().zip(outcomes) {
            self.record(name, &o);
            if self.j(o.bytes, o.d) < best.0 {
                best = (self.j(o.bytes, o.d), c);
            }
        }
        best
    }
}

/// Pruning candidates from `from`: none, those whose removal changes no view, the
/// [`PRUNE_QUANTILES`] of `errs` (sorted removal errors of the Gaussians above the opacity
/// threshold), and everything (an empty file).
fn prune_candidates(errs: &[f32], from: &EncodeConfig) -> Vec<(String, EncodeConfig)> {
    let with = |t: f32| EncodeConfig { min_removal_error: t, ..*from };
    let mut cands = vec![("prune none".to_string(), with(0.0)), ("prune no-change".to_string(), with(f32::MIN_POSITIVE))];
    let mut last = f32::MIN_POSITIVE;
    for &f in &PRUNE_QUANTILES {
        let t = errs.get((errs.len() as f64 * f64::from(f)) as usize).copied().unwrap_or(f32::INFINITY);
        if t > last {
            last = t;
            cands.push((format!("prune removal error<q{f}"), with(t)));
        }
    }
    cands.push(("prune all".to_string(), with(f32::INFINITY)));
    cands
}

/// One pass of per-group step multipliers from `start`: per group, the multiplier of `mults`
/// minimising `ΔD + λ·R_group` (the group's own bytes). Every trial of a pass starts from
/// `start`, so a pass is one parallel batch.
fn step_pass<F: FnMut(&Trial)>(
    trials: &mut Trials,
    log: &mut Log<F>,
    start: &EncodeConfig,
    pass: usize,
    mults: &[f32],
) -> Result<EncodeConfig, SceneError> {
    let group_bytes =
        |r: &super::EncodeReport, k: Group| r.groups.iter().find(|g| g.group == k.name()).map_or(0, |g| g.stream_bytes + g.table_bytes);
    let Outcome { d: d0, report: r0, .. } = trials.base(start)?;
    let knobs: Vec<(Group, f32)> =
        Group::ALL.into_iter().filter(|&k| group_bytes(&r0, k) > 0).flat_map(|k| mults.iter().map(move |&m| (k, m))).collect();
    let configs: Vec<EncodeConfig> = knobs.iter().map(|&(k, m)| with_knob(start, k, m)).collect();
    let outcomes = trials.run(&configs)?;
    let mut best: Vec<(Group, f64, f32)> = Vec::new();
    for (&(k, m), o) in knobs.iter().zip(&outcomes) {
        log.record(format!("pass{pass} {}x{m}", k.name()), o);
        let cost = (o.d - d0) + log.lambda.rate_cost(group_bytes(&o.report, k));
        match best.last_mut() {
            Some(x) if x.0 == k => {
                if cost < x.1 {
                    *x = (k, cost, m);
                }
            }
            _ => best.push((k, cost, m)),
        }
    }
    Ok(best.into_iter().fold(*start, |c, (k, _, m)| with_knob(&c, k, m)))
}

/// Per SH band up to `degree`, in order: a codebook of each of [`VQ_ROWS`] rows at each of
/// [`VQ_STEPS`] × the band's step, or per-coefficient coding as in `start`; then, for two bands
/// or more, one joint codebook for all of them (`sh_joint`) of each of [`VQ_ROWS`] rows at each
/// of [`VQ_STEPS`] × `start`'s steps, or the bands as chosen (whole-file J; the start stays a
/// candidate, so the result's J is never above the start's).
fn vq_stage<F: FnMut(&Trial)>(trials: &mut Trials, log: &mut Log<F>, start: EncodeConfig, degree: u8) -> Result<EncodeConfig, SceneError> {
    let mut chosen = start;
    for b in 1..=chosen.max_sh_degree.min(degree).min(3) {
        let bi = usize::from(b) - 1;
        let Outcome { bytes, d, .. } = trials.one(&chosen)?;
        let cands = VQ_ROWS
            .iter()
            .flat_map(|&k| VQ_STEPS.iter().map(move |&m| (k, m)))
            .map(|(k, m)| {
                let mut c = chosen;
                c.sh_vq[bi] = k;
                c.steps.sh_rest[bi] *= m;
                (format!("sh_vq band{b} K={k} step×{m:.3}"), c)
            })
            .collect();
        let keep = (log.j(bytes, d), chosen);
        chosen = log.stage(trials, keep, cands)?.1;
    }
    if chosen.max_sh_degree.min(degree) >= 2 {
        let Outcome { bytes, d, .. } = trials.one(&chosen)?;
        let cands = VQ_ROWS
            .iter()
            .flat_map(|&k| VQ_STEPS.iter().map(move |&m| (k, m)))
            .map(|(k, m)| {
                let mut c = EncodeConfig { sh_vq: [k, 0, 0], sh_joint: true, ..start };
                c.steps.sh_rest = c.steps.sh_rest.map(|s| s * m);
                (format!("sh_vq joint K={k} step×{m:.3}"), c)
            })
            .collect();
        let keep = (log.j(bytes, d), chosen);
        chosen = log.stage(trials, keep, cands)?.1;
    }
    Ok(chosen)
}

/// `from` with one group's step an eighth of an octave ([`NUDGE`]) coarser (or finer), for
/// every group a scene of SH degree `sh_degree` coded with `from` has: moves smaller than the
/// search's quarter-octave steps, named by the group and the direction. A target spends what
/// its best probe has to spare with them: a PSNR above the target on fewer bytes (coarser), or
/// bytes below it on more PSNR (finer).
pub fn step_nudges(from: &EncodeConfig, coarser: bool, sh_degree: u8) -> Vec<(String, EncodeConfig)> {
    let (dir, m) = if coarser { ("coarser", NUDGE) } else { ("finer", 1.0 / NUDGE) };
    Group::present(sh_degree.min(from.max_sh_degree))
        .map(|g| {
            let mut c = *from;
            *c.steps.of_mut(g) *= m;
            (format!("{} step {dir}", g.name()), c)
        })
        .collect()
}

/// `from` with each importance class choice the search tries ([`TAIL_SHARES`] ×
/// [`TAIL_FACTORS`]) but its own, named by it.
pub fn tail_variants(from: &EncodeConfig) -> Vec<(String, EncodeConfig)> {
    TAIL_SHARES
        .iter()
        .flat_map(|&share| TAIL_FACTORS.iter().map(move |&factor| CoarseTail::new(share, factor)))
        .filter(|&tail| tail != from.tail)
        .map(|tail| (format!("tail {}x{}", tail.share, tail.factor), EncodeConfig { tail, ..*from }))
        .collect()
}

/// `from` with one group's multiplier of its tail's factor ([`CoarseTail::groups`]) times each
/// of [`TAIL_GROUP_MULTIPLIERS`], for every group that a scene of SH degree `sh_degree` coded
/// with `from` has, but the SH bands coded by codebooks (their rows are shared by every level);
/// none without a tail.
fn tail_group_variants(from: &EncodeConfig, sh_degree: u8) -> Vec<(String, EncodeConfig)> {
    if from.tail.is_off() {
        return Vec::new();
    }
    Group::present(sh_degree.min(from.max_sh_degree))
        .filter(|&g| !super::quantise::coded_by_codebook(g, from.sh_vq, from.sh_joint))
        .flat_map(|g| {
            TAIL_GROUP_MULTIPLIERS.iter().map(move |&m| {
                let mut c = *from;
                c.tail.groups[g as usize] *= m;
                (format!("tail {} ×{m}", g.name()), c)
            })
        })
        .collect()
}

/// Importance classes ([`CoarseTail`]): each of [`tail_variants`], or none as in `start`; then,
/// with a tail, each of [`tail_group_variants`], and where one lowers J, the same group's move
/// once more (whole-file J; each step's start stays a candidate, so the result's J is never
/// above `start`'s).
fn tail_stage<F: FnMut(&Trial)>(trials: &mut Trials, log: &mut Log<F>, start: EncodeConfig) -> Result<EncodeConfig, SceneError> {
    let Outcome { bytes: b, d, .. } = trials.one(&start)?;
    let (j, chosen) = log.stage(trials, (log.j(b, d), start), tail_variants(&start))?;
    let (j_group, moved) = log.stage(trials, (j, chosen), tail_group_variants(&chosen, trials.ev.scene.sh_degree))?;
    let Some(g) = (0..8).find(|&g| moved.tail.groups[g] != chosen.tail.groups[g]) else {
        return Ok(chosen);
    };
    let mut again = moved;
    again.tail.groups[g] *= moved.tail.groups[g] / chosen.tail.groups[g];
    let name = format!("tail {} ×{} again", Group::ALL[g].name(), again.tail.groups[g]);
    Ok(log.stage(trials, (j_group, moved), vec![(name, again)])?.1)
}

/// The search's last stage: [`EncodeConfig::dc_fit`] turned off where that lowers `J` (the
/// search chooses everything else with it on, for a scene with SH rest bands).
fn dc_fit_stage<F: FnMut(&Trial)>(trials: &mut Trials, log: &mut Log<F>, start: EncodeConfig) -> Result<EncodeConfig, SceneError> {
    if !start.dc_fit {
        return Ok(start);
    }
    let Outcome { bytes: b, d, .. } = trials.one(&start)?;
    Ok(log.stage(trials, (log.j(b, d), start), vec![("dc_fit off".into(), EncodeConfig { dc_fit: false, ..start })])?.1)
}

/// The importance classes of `config` chosen again for `trials`' scene, as the search's last
/// stage ([`tail_stage`]) chooses them, from `config` without classes, with `D` on the trials'
/// views; every other choice of `config` stays. For a scene that changed after the search (the
/// encoder's retraining): which Gaussians matter, and so what coarser steps for the least
/// significant cost, is no longer what the search measured.
///
/// # Errors
/// A scene the coder refuses.
pub fn retune_tail(trials: &mut Trials, lambda: Lambda, config: EncodeConfig) -> Result<EncodeConfig, SceneError> {
    let mut on_step = |_: &Trial| {};
    let mut log = Log { path: Vec::new(), on_step: &mut on_step, lambda };
    // As in the search: trial encodes without the learned tables.
    let start = EncodeConfig { tail: CoarseTail::OFF, learned_tables: false, ..config };
    trials.calibrate(&start)?;
    let chosen = tail_stage(trials, &mut log, start)?;
    Ok(EncodeConfig { tail: chosen.tail, ..config })
}

/// Rate–distortion allocation by rendering. Distortion is treated as additive over groups
/// (each group's coarsening is measured alone) and group rates as independent, so each group's
/// step is chosen separately: first the significance pruning threshold, then the SH degree and
/// the per-Gaussian SH band dropping (whole-file J), then per group the multiplier of the fine
/// step minimising `ΔD_g + λ·R_g` (where the degree left a band out at fine steps, the scene's
/// own degree also goes through the band dropping and the first of these passes, choosing the
/// degree again, and the lower J goes on), then the SH rest dead zone, then per SH band a codebook
/// (vector quantisation) or none, then the importance classes ([`CoarseTail`]) or none, all
/// with the DC fit ([`EncodeConfig::dc_fit`]) on, and last whether it stays on.
/// `on_step` sees each trial.
///
/// The trials of each stage are independent and run in parallel; the result (and the trial
/// list) is the same for any number of threads.
pub fn search(scene: &Splats, lambda: Lambda, on_step: impl FnMut(&Trial)) -> Result<(EncodeConfig, Vec<Trial>), SceneError> {
    search_with(&mut Trials::new(scene)?, lambda, fine_steps(), true, on_step)
}

/// The fine steps [`search`] starts from.
pub fn fine_steps() -> Steps {
    Steps::default().scaled(0.7)
}

/// [`search`] on `trials`' scene and views, with the per-group step multipliers applied to
/// `fine` (e.g. steps learned in training) instead of [`fine_steps`] (multiplier 1 keeps a step
/// as it is), reusing (and adding to) the evaluated configurations of `trials`: the same choice
/// and trial list as a fresh search, with fewer encodes and renders. `dc_fit` false searches
/// without the DC fit ([`EncodeConfig::dc_fit`]), for a scene that training will fit.
///
/// # Errors
/// A trial's encode (none for a scene [`Trials::new`] took).
pub fn search_with(
    trials: &mut Trials,
    lambda: Lambda,
    fine: Steps,
    dc_fit: bool,
    mut on_step: impl FnMut(&Trial),
) -> Result<(EncodeConfig, Vec<Trial>), SceneError> {
    let scene = trials.ev.scene;
    // Keep one search's coded groups at a time (memory grows with the scene); the outcomes of
    // the configurations, which are small, stay for the next search.
    trials.ev.cache = GroupCache::default();
    if let Some((ev, _)) = &mut trials.pruning {
        ev.cache = GroupCache::default();
    }
    let mut clock = Clock::new(trials);
    let mut log = Log { path: Vec::new(), on_step: &mut on_step, lambda };
    // The DC fit from the start: with it, leaving SH bands out and coarser SH steps cost less,
    // which every choice below weighs (docs/codec.md §29).
    // Rate-aware rounding weighs a bit at the exchange rate of steps chosen for a λ > 0; at
    // λ = 0 bits are free and every value is rounded to nearest (docs/codec.md §35).
    let fine = EncodeConfig {
        steps: fine,
        learned_tables: false,
        dc_fit: dc_fit && scene.sh_degree > 0,
        rate_rounding: lambda.get() > 0.0,
        ..EncodeConfig::default()
    };
    trials.calibrate(&fine)?;
    // 1. Pruning by removal error (at fine steps): the colour error that dropping the Gaussian
    //    alone causes in the views. It subsumes opacity, footprint and coverage thresholds,
    //    which it beat on every scene measured (docs/codec.md). Candidates: none, those whose
    //    removal changes nothing, quantiles of the rest, and everything (an empty file).
    let m = &trials.ev.importance;
    let errs = sorted((0..scene.len()).filter(|&i| opaque_enough(scene, i, &fine)).map(|i| m.removal[i]).collect());
    //    `D` on the pruning views ([`PRUNING_SIZE`]) where the trials have them.
    //    Its trials round every value to nearest: rate-aware rounding fits each group's tables
    //    once more, and a pruning trial changes every group (with it the stage took 1.5× as
    //    long on the 124k proxy); the later stages round with it (docs/codec.md §35).
    let nearest = EncodeConfig { rate_rounding: false, ..fine };
    let cands = prune_candidates(&errs, &nearest);
    let outcomes = trials.run_pruning(&cands.iter().map(|c| c.1).collect::<Vec<_>>())?;
    let base = EncodeConfig { rate_rounding: fine.rate_rounding, ..log.pick((f64::INFINITY, nearest), cands, outcomes).1 };
    let b0 = trials.base(&base)?.bytes;
    clock.lap(trials, "pruning");
    if b0 < 200 {
        return Ok((EncodeConfig { learned_tables: true, ..base }, log.path)); // nothing (or almost nothing) left to allocate
    }
    // 2. SH degree (at fine steps): the degree of lowest J. At fine steps a band costs the
    //    most it will, so this can leave out a band that the coarser steps chosen next make
    //    worth its bits: where it does, the scene's own degree also goes through stages 3 and 4's
    //    first pass and the degree is chosen again there, and the search goes on from the lower
    //    J of the two (docs/codec.md §31).
    let top = scene.sh_degree.min(3);
    let cands = (0..=top).rev().map(|deg| (format!("sh_degree={deg}"), with_degree(&base, deg, &fine.steps))).collect();
    let early = log.stage(trials, (f64::INFINITY, base), cands)?.1;
    clock.lap(trials, "SH degree");
    let mut chosen = coarse_steps(trials, &mut log, &mut clock, early, early.max_sh_degree == top, &fine.steps)?;
    if early.max_sh_degree < top {
        let full = coarse_steps(trials, &mut log, &mut clock, with_degree(&base, top, &fine.steps), true, &fine.steps)?;
        let mut j = |c: &EncodeConfig| trials.base(c).map(|o| log.j(o.bytes, o.d));
        if j(&full)? < j(&chosen)? {
            chosen = full;
        }
    }
    let chosen = finish(trials, &mut log, &mut clock, chosen)?;
    Ok((EncodeConfig { learned_tables: true, ..chosen }, log.path))
}

/// `c` with SH degree `deg`: the bands above it left out, their drop thresholds cleared and
/// their steps `fine`'s, so that one choice has one configuration whichever path reached it.
fn with_degree(c: &EncodeConfig, deg: u8, fine: &Steps) -> EncodeConfig {
    let mut c = EncodeConfig { max_sh_degree: deg, ..*c };
    for b in usize::from(deg)..3 {
        c.sh_drop[b] = 0.0;
        c.steps.sh_rest[b] = fine.sh_rest[b];
    }
    c
}

/// The search's stages after the SH degree up to the first step pass, from `base` (pruned, at
/// fine steps): per-Gaussian band dropping and the coarse step pass. `late_degree`: the SH
/// degree is then chosen again (among `base`'s and those below it), at steps near the final
/// ones.
fn coarse_steps<F: FnMut(&Trial)>(
    trials: &mut Trials,
    log: &mut Log<F>,
    clock: &mut Clock,
    mut base: EncodeConfig,
    late_degree: bool,
    fine: &Steps,
) -> Result<EncodeConfig, SceneError> {
    let scene = trials.ev.scene;
    // 3. Per-Gaussian SH band dropping (whole-file J, at fine steps so the steps adapt to it),
    //    band by band: thresholds at quantiles of the kept Gaussians' band contributions
    //    weighted by significance.
    if base.max_sh_degree > 0 && scene.sh_degree > 0 {
        let (kept, weights) = pruned(scene, &base, Some(&trials.ev.importance));
        let weights = weights.expect("given");
        for b in 1..=base.max_sh_degree.min(kept.sh_degree) {
            let c = sorted((0..kept.len()).map(|i| super::quantise::band_contribution(&kept, i, b, weights[i])).collect());
            let cands = SH_DROP_QUANTILES
                .iter()
                .filter_map(|&f| {
                    let t = *c.get((c.len() as f64 * f64::from(f)) as usize)?;
                    let mut cfg = base;
                    cfg.sh_drop[usize::from(b) - 1] = t;
                    (t > 0.0).then(|| (format!("sh_drop band{b}<q{f}"), cfg))
                })
                .collect();
            let Outcome { bytes, d, .. } = trials.base(&base)?;
            let keep = (log.j(bytes, d), base);
            base = log.stage(trials, keep, cands)?.1;
            clock.lap(trials, &format!("SH band {b} dropping"));
        }
    }
    // 4. Per group step multipliers: a coarse pass from the fine steps (here), then a refining
    //    pass (half-octave moves around the first choice), then quarter-octave moves ([`finish`]).
    let mut chosen = step_pass(trials, log, &base, 0, &MULTIPLIERS)?;
    clock.lap(trials, "step pass 0");
    if late_degree && chosen.max_sh_degree > 0 {
        let Outcome { bytes, d, .. } = trials.base(&chosen)?;
        let keep = (log.j(bytes, d), chosen);
        let cands =
            (0..chosen.max_sh_degree).rev().map(|deg| (format!("sh_degree={deg} after pass 0"), with_degree(&chosen, deg, fine))).collect();
        chosen = log.stage(trials, keep, cands)?.1;
        clock.lap(trials, "SH degree after pass 0");
    }
    Ok(chosen)
}

/// The search's stages after [`coarse_steps`]: the finer step passes, the dead zone,
/// codebooks, importance classes and the DC fit.
fn finish<F: FnMut(&Trial)>(
    trials: &mut Trials,
    log: &mut Log<F>,
    clock: &mut Clock,
    mut chosen: EncodeConfig,
) -> Result<EncodeConfig, SceneError> {
    let scene = trials.ev.scene;
    for (pass, mults) in [(1, &REFINE[..]), (2, &REFINE_FINE[..])] {
        chosen = step_pass(trials, log, &chosen, pass, mults)?;
        clock.lap(trials, &format!("step pass {pass}"));
    }
    // 5. SH rest dead zone (whole-file J: it changes only the SH band groups).
    if chosen.max_sh_degree > 0 && scene.sh_degree > 0 {
        let Outcome { bytes: b, d, .. } = trials.base(&chosen)?;
        let cands = DEADZONES
            .iter()
            .map(|&dz| {
                let mut c = chosen;
                c.steps.rest_deadzone = dz;
                (format!("rest_deadzone={dz}"), c)
            })
            .collect();
        let keep = (log.j(b, d), chosen);
        chosen = log.stage(trials, keep, cands)?.1;
        clock.lap(trials, "SH dead zone");
    }
    // 6. SH vector quantisation, band by band.
    let chosen = vq_stage(trials, log, chosen, scene.sh_degree)?;
    clock.lap(trials, "SH codebooks");
    // 7. Importance classes: the least significant Gaussians with coarser steps.
    let chosen = tail_stage(trials, log, chosen)?;
    clock.lap(trials, "importance classes");
    // 8. The DC fit (each DC takes back the mean colour its coded SH rest lost) off, tried last.
    let chosen = dc_fit_stage(trials, log, chosen)?;
    clock.lap(trials, "DC fit");
    Ok(chosen)
}

/// Configurations between two search results, `from` and `to` (e.g. the choices at two
/// neighbouring λ, where the search's discrete choices leave a step in the RD curve): `from`
/// with one knob set as in `to`, for each knob in which they differ — the pruning thresholds
/// (and the geometric mean of two significance thresholds), the SH degree, the SH rest dead
/// zone, the step of each group but the SH bands, and each SH band's step, drop threshold and
/// codebook size together (the search chooses them together). Named by the knob.
pub fn between(from: &EncodeConfig, to: &EncodeConfig) -> Vec<(String, EncodeConfig)> {
    let mut out: Vec<(String, EncodeConfig)> = Vec::new();
    let mut push = |name: String, c: EncodeConfig| {
        if c != *from && out.iter().all(|(_, o)| *o != c) {
            out.push((name, c));
        }
    };
    push("pruning".into(), EncodeConfig { min_opacity: to.min_opacity, min_removal_error: to.min_removal_error, ..*from });
    let (a, b) = (from.min_removal_error, to.min_removal_error);
    if a > 0.0 && b > 0.0 && a.is_finite() && b.is_finite() {
        push("pruning midway".into(), EncodeConfig { min_removal_error: (a * b).sqrt(), ..*from });
    }
    push("SH degree".into(), EncodeConfig { max_sh_degree: to.max_sh_degree, ..*from });
    let mut c = *from;
    c.steps.rest_deadzone = to.steps.rest_deadzone;
    push("SH dead zone".into(), c);
    for g in [Group::Position, Group::Scale, Group::Rotation, Group::Opacity, Group::ShDc] {
        let mut c = *from;
        *c.steps.of_mut(g) = to.steps.of(g);
        push(format!("{} step", g.name()), c);
    }
    push("importance classes".into(), EncodeConfig { tail: to.tail, ..*from });
    push("DC fit".into(), EncodeConfig { dc_fit: to.dc_fit, ..*from });
    for band in 0..3 {
        let mut c = *from;
        c.steps.sh_rest[band] = to.steps.sh_rest[band];
        c.sh_drop[band] = to.sh_drop[band];
        c.sh_vq[band] = to.sh_vq[band];
        push(format!("SH band {}", band + 1), c);
    }
    // One codebook for all bands or one per band: every band's choice together.
    if from.sh_joint != to.sh_joint {
        let mut c = EncodeConfig { sh_vq: to.sh_vq, sh_drop: to.sh_drop, sh_joint: to.sh_joint, ..*from };
        c.steps.sh_rest = to.steps.sh_rest;
        push("SH joint codebook".into(), c);
    }
    out
}

/// Opacity thresholds (× 1/255) [`pruning_opacity`] tries.
const PRUNE_OPACITIES: [f32; 11] = [2.0, 3.0, 4.0, 6.0, 8.0, 12.0, 16.0, 24.0, 32.0, 48.0, 64.0];

/// The opacity below which pruning pays at `lambda` without retraining: of `config` (a
/// search's choice) with its significance pruning replaced by an opacity threshold, the
/// threshold of lowest `J` (1/255, lossless, when none is lower). Fine-tuning charges the rate
/// of every Gaussian above it and prunes those it leaves below, so the rate term pushes
/// Gaussians that do not pay for their bits under it while the others learn to cover for them
/// (`encoder::Encoder::encode_scene`; docs/codec.md).
///
/// `trials` are those of the search that chose `config` (or new ones for its scene).
///
/// # Errors
/// A trial's encode (none for a scene [`Trials::new`] took).
pub fn pruning_opacity(trials: &mut Trials, lambda: Lambda, config: &EncodeConfig) -> Result<f32, SceneError> {
    let mut log = Log { path: Vec::new(), on_step: &mut |_: &Trial| {}, lambda };
    let base = EncodeConfig { min_removal_error: 0.0, min_opacity: 1.0 / 255.0, learned_tables: false, ..*config };
    let Outcome { bytes: b, d, .. } = trials.one(&base)?;
    // Every candidate keeps a subset of `base`'s Gaussians: its SH bands are coded with `base`'s
    // codebooks (each row by its nearest), not with a k-means of their own, which would cost
    // each candidate about ten times the rest of its encode. (No other stage tries opacity
    // thresholds without removal errors, so the outcomes recorded under these configurations
    // are never wanted with codebooks of their own.)
    let memo = &trials.ev.cache.codebooks;
    let books = trials.ev.codebooks(&base)?;
    if base.sh_joint && !books.is_empty() {
        // One codebook of all bands: "band 1"'s (`quantise::apply_codebooks`).
        let parts: Vec<&super::vq::Codebook> = books.iter().map(|b| &b.1).collect();
        memo.pin(1, Some(&super::vq::Codebook::beside(&parts)));
    } else {
        for (g, cb) in books {
            memo.pin(usize::from(g.sh_band()), Some(&cb));
        }
    }
    let cands =
        PRUNE_OPACITIES.iter().map(|&m| (format!("prune opacity<{m}/255"), EncodeConfig { min_opacity: m / 255.0, ..base })).collect();
    let chosen = log.stage(trials, (log.j(b, d), base), cands);
    (1..=3).for_each(|band| trials.ev.cache.codebooks.pin(band, None));
    Ok(chosen?.1.min_opacity)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A dataset's D views: training cameras only, spread through the training frames, scaled
    /// down to the size cap with their aspect ratio, over the dataset's background.
    #[test]
    fn dataset_views_are_spread_training_cameras_at_most_the_size_cap() {
        let scene = crate::sample::scene(100, 3);
        // 24 frames at 600×300; frames 0, 8 and 16 are held out (index % 8).
        let cams = crate::views::training_cameras(&scene, 8, 600, 300, glam::Vec3::NEG_Y);
        let mut dataset = crate::train::targets::render_targets(&scene, &cams, [1.0, 0.5, 0.0]);
        dataset.frames.iter_mut().enumerate().for_each(|(i, f)| f.index = i);
        let views = RdViews::of_dataset(&dataset).unwrap();
        assert_eq!((views.cams.len(), views.background), (VIEWS, [1.0, 0.5, 0.0]));
        let mut picked = Vec::new();
        assert_eq!(views.pixel_scale, vec![f64::from(MAX_CAMERA_SIDE) / 600.0; VIEWS], "WD's σ follows the scaling");
        for v in &views.cams {
            assert_eq!((v.width, v.height), (MAX_CAMERA_SIDE, MAX_CAMERA_SIDE / 2));
            let i = cams.iter().position(|c| c.translation == v.translation && c.rotation == v.rotation).unwrap();
            assert_ne!(i % 8, 0, "frame {i} is held out");
            assert_eq!(*v, cams[i].resized(v.width, v.height));
            picked.push(i);
        }
        // Evenly spread: the 21 training frames in 8 buckets, the middle of each (training
        // frames 1, 3, 6, 9, 11, 14, 17, 19 of 0..21, i.e. these frame indices).
        assert_eq!(picked, [2, 4, 7, 11, 13, 17, 20, 22]);
        // The significance is summed over every training camera, at most SIZE on a side.
        let sig_cams = super::super::importance::dataset_views(&dataset);
        let training: Vec<_> = cams.iter().enumerate().filter(|(i, _)| i % 8 != 0).map(|(_, c)| c.resized(SIZE, SIZE / 2)).collect();
        assert_eq!(sig_cams, training);
        assert_eq!(views.significance_cams.as_ref(), Some(&sig_cams));
        let sig = views.significance(&scene);
        assert_eq!(sig, super::super::importance::significance_on(&scene, &sig_cams));
        assert_ne!(sig, super::super::importance::significance(&scene), "not the orbit views' significance");
        // A small camera keeps its size; no training frame, no views.
        let mut small =
            crate::train::targets::render_targets(&scene, &cams[1..2].iter().map(|c| c.resized(40, 30)).collect::<Vec<_>>(), [0.0; 3]);
        small.frames[0].index = 1;
        assert_eq!(RdViews::of_dataset(&small).unwrap().cams, vec![cams[1].resized(40, 30)]);
        small.frames[0].index = 8;
        assert!(RdViews::of_dataset(&small).is_none());
    }

    /// D is measured on the views the trials were given, over their background: 255² × the
    /// mean squared error of the decoded scene's renders against the input's.
    #[test]
    fn distortion_is_measured_on_the_given_views() {
        let scene = crate::sample::scene(300, 4);
        let cams = crate::views::training_cameras(&scene, 2, 50, 40, glam::Vec3::NEG_Y);
        let background = [0.2, 0.9, 0.4];
        let mut trials = Trials::with_views(&scene, RdViews::cameras(cams.clone(), background)).unwrap();
        let config = EncodeConfig { steps: Steps::default().scaled(4.0), ..EncodeConfig::default() };
        let d = trials.one(&config).unwrap().d;
        let (_, _, q) = super::super::encode(&scene, &config).unwrap();
        let opts = RenderOptions { background, ..RenderOptions::default() };
        let decoded = dequantise(&q);
        let mse: f64 = cams.iter().map(|c| crate::metrics::mse(&render(&scene, c, &opts), &render(&decoded, c, &opts))).sum::<f64>()
            / cams.len() as f64;
        assert!(d > 0.0);
        assert!((d - 255.0 * 255.0 * mse).abs() <= 1e-9 * d, "D {d} against {}", 255.0 * 255.0 * mse);
        // The orbit views measure something else.
        let d_orbit = Trials::new(&scene).unwrap().one(&config).unwrap().d;
        assert_ne!(d, d_orbit);
    }

    /// A scene's pruning stage measures `D` on the orbit views at [`PRUNING_SIZE`]² (the
    /// evaluation's), the later stages on the search's views at [`SIZE`]²; a dataset's views
    /// serve every stage.
    #[test]
    fn pruning_measures_on_the_evaluation_views() {
        let scene = crate::sample::scene(300, 4);
        let (_, path) = search(&scene, Lambda::new(20.0).unwrap(), |_| {}).unwrap();
        let orbit = |size| RdViews::cameras(orbit_cameras(&scene, VIEWS, size, size, UpAxis::NegY.vector()), [0.0; 3]);
        let (fine, coarse) = (Evaluator::with_views(&scene, orbit(PRUNING_SIZE)), Evaluator::new(&scene));
        let fine_config =
            EncodeConfig { steps: fine_steps(), learned_tables: false, dc_fit: scene.sh_degree > 0, ..EncodeConfig::default() };
        // The pruning trials round to nearest; the stages after them round with the tables.
        let nearest = EncodeConfig { rate_rounding: false, ..fine_config };
        for (name, t) in [("prune none", 0.0), ("prune all", f32::INFINITY)] {
            let config = EncodeConfig { min_removal_error: t, ..nearest };
            let trial = path.iter().find(|p| p.change == name).unwrap();
            let (bytes, d) = fine.eval(&config).unwrap();
            assert_eq!((trial.bytes, trial.d), (bytes, d), "{name}");
            assert_ne!(coarse.eval(&config).unwrap().1, d, "{name}: the 96² views measure something else");
        }
        // The SH degree stage (the next) measures on the search's views, from the pruning of
        // lowest J (the first of equals).
        let trials = Trials::new(&scene).unwrap();
        let errs =
            sorted((0..scene.len()).filter(|&i| opaque_enough(&scene, i, &fine_config)).map(|i| trials.importance().removal[i]).collect());
        let pruned = path.iter().take_while(|p| p.change.starts_with("prune")).collect::<Vec<_>>();
        let best = pruned.iter().fold(pruned[0], |b, p| if p.j < b.j { p } else { b });
        let (_, chosen) = prune_candidates(&errs, &nearest).into_iter().find(|(n, _)| *n == best.change).unwrap();
        let deg = scene.sh_degree.min(3);
        let sh = path.iter().find(|p| p.change == format!("sh_degree={deg}")).unwrap();
        assert_eq!((sh.bytes, sh.d), coarse.eval(&EncodeConfig { max_sh_degree: deg, rate_rounding: true, ..chosen }).unwrap());
        // A dataset's trials have no separate pruning views.
        let cams = crate::views::training_cameras(&scene, 2, 50, 40, glam::Vec3::NEG_Y);
        assert!(Trials::with_views(&scene, RdViews::cameras(cams, [0.0; 3])).unwrap().pruning.is_none());
        assert!(Trials::new(&scene).unwrap().pruning.is_some());
    }

    /// A loss's `D` is the loss (WD in the `pyramid` space at σ × the views' pixel scale, plus
    /// the weighted L1-SSIM) of the decoded views against the input's, mean over views, times
    /// one factor: the calibrating configuration's squared error over its loss, so that there
    /// it equals the squared error.
    #[test]
    fn a_losss_distortion_is_the_loss_in_the_squared_errors_unit() {
        use crate::loss::wdr::{l_orig, WdDistortion, BETA};
        let scene = crate::sample::scene(300, 4);
        let cams = crate::views::training_cameras(&scene, 2, 64, 48, glam::Vec3::NEG_Y);
        let background = [0.2, 0.9, 0.4];
        let opts = RenderOptions { background, ..RenderOptions::default() };
        let coarse = |m: f32| EncodeConfig { steps: Steps::default().scaled(m), learned_tables: false, ..EncodeConfig::default() };
        let frames = |c: &EncodeConfig| {
            let decoded = dequantise(&super::super::encode(&scene, c).unwrap().2);
            cams.iter().map(|cam| (render(&scene, cam, &opts), render(&decoded, cam, &opts))).collect::<Vec<_>>()
        };
        for (loss, sigma, weight) in [("wdr", Some(2.0), BETA), ("wd", Some(2.0), 0.0), ("l1ssim", None, 1.0)] {
            let mut views = RdViews::cameras(cams.clone(), background).measuring(RdDistortion::Loss { wd_sigma: sigma, l_orig: weight });
            views.pixel_scale = vec![0.5; cams.len()];
            let mut trials = Trials::with_views(&scene, views).unwrap();
            let by_hand = |c: &EncodeConfig| {
                let f = frames(c);
                let mse = f.iter().map(|(r, d)| crate::metrics::mse(r, d)).sum::<f64>() / f.len() as f64 * 255.0 * 255.0;
                let l = f
                    .iter()
                    .map(|(r, d)| {
                        let wd = sigma.map_or(0.0, |s| {
                            WdDistortion::new(Box::new(Pyramid::LUMA)).with_sigma(Sigma::Constant(s * 0.5)).value(d, r, None)
                        });
                        wd + weight * l_orig(d, r).0
                    })
                    .sum::<f64>()
                    / f.len() as f64;
                (mse, l)
            };
            let (first, second) = (coarse(2.0), coarse(8.0));
            trials.calibrate(&first).unwrap();
            let ((mse1, l1), (mse2, l2)) = (by_hand(&first), by_hand(&second));
            let (o1, o2) = (trials.one(&first).unwrap(), trials.one(&second).unwrap());
            assert!((o1.d - mse1).abs() <= 1e-6 * mse1, "{loss}: D {} against its squared error {mse1}", o1.d);
            let d2 = l2 * mse1 / l1;
            assert!((o2.d - d2).abs() <= 1e-6 * d2, "{loss}: D {} against {d2}", o2.d);
            assert!((o2.mse - mse2).abs() <= 1e-9 * mse2 && (l2 / l1 - mse2 / mse1).abs() > 1e-3, "{loss}: the loss is not the MSE");
            // A second calibration changes nothing: outcomes stay in one unit.
            trials.calibrate(&second).unwrap();
            assert_eq!(trials.ev.distortion(&dequantise(&super::super::encode(&scene, &second).unwrap().2)).to_bits(), o2.d.to_bits());
        }
    }

    /// Where the SH degree stage leaves a band out at fine steps, the scene's own degree also
    /// goes through band dropping and the first step pass, the degree is chosen again there, and
    /// the search goes on from the lower J of the two.
    #[test]
    fn a_band_left_out_at_fine_steps_is_tried_again_at_coarser_steps() {
        // Bands 1 and 2 weak, band 3 strong: dear at fine steps, worth its bits at coarser ones.
        let mut scene = crate::sample::scene(300, 5);
        let k = scene.sh_rest.len() / scene.len();
        scene.sh_rest.iter_mut().enumerate().for_each(|(i, v)| *v *= if i % k < 24 { 0.3 } else { 4.0 });
        let top = scene.sh_degree.min(3);
        let fine = EncodeConfig { steps: fine_steps(), learned_tables: false, dc_fit: true, ..EncodeConfig::default() };
        let (mut both, mut full_won, mut early_won) = (0, false, false);
        for l in [100.0, 400.0, 1000.0] {
            let lambda = Lambda::new(l).unwrap();
            let (chosen, path) = search(&scene, lambda, |_| {}).unwrap();
            let lowest = |stage: &dyn Fn(&str) -> bool| {
                let t: Vec<&Trial> = path.iter().filter(|p| stage(&p.change)).collect();
                t.iter().fold(t[0], |b, p| if p.j < b.j { p } else { b }).change.clone()
            };
            let early = lowest(&|c| c.starts_with("sh_degree=") && !c.ends_with("after pass 0"));
            let early: u8 = early["sh_degree=".len()..].parse().unwrap();
            // Band `top`'s dropping runs on the scene's own degree only, which is always searched.
            assert!(path.iter().any(|p| p.change.starts_with(&format!("sh_drop band{top}<"))), "λ {l}");
            assert!(path.iter().any(|p| p.change.ends_with("after pass 0")), "λ {l}: the degree is chosen again");
            if early == top {
                continue;
            }
            both += 1;
            // Both starts through the first step pass, from the same pruning, then the rest.
            let mut trials = Trials::new(&scene).unwrap();
            let errs =
                sorted((0..scene.len()).filter(|&i| opaque_enough(&scene, i, &fine)).map(|i| trials.importance().removal[i]).collect());
            let pruning = lowest(&|c| c.starts_with("prune"));
            let (_, pruned) = prune_candidates(&errs, &fine).into_iter().find(|(n, _)| *n == pruning).unwrap();
            let mut on_step = |_: &Trial| {};
            let mut log = Log { path: Vec::new(), on_step: &mut on_step, lambda };
            let mut clock = Clock::new(&trials);
            let mut coarse = |deg, late| {
                coarse_steps(&mut trials, &mut log, &mut clock, with_degree(&pruned, deg, &fine.steps), late, &fine.steps).unwrap()
            };
            let (alone, full) = (coarse(early, false), coarse(top, true));
            let mut j = |c: &EncodeConfig| trials.one(c).map(|o| lambda.rate_cost(o.bytes) + o.d).unwrap();
            let (j_alone, j_full) = (j(&alone), j(&full));
            let start = if j_full < j_alone { full } else { alone };
            let expected = finish(&mut trials, &mut log, &mut clock, start).unwrap();
            assert_eq!(EncodeConfig { learned_tables: false, ..chosen }, expected, "λ {l}: from the lower J of the two");
            full_won |= j_full < j_alone;
            early_won |= j_alone < j_full;
        }
        assert!(
            both > 0 && full_won && early_won,
            "{both} λ left a band out at fine steps; each start won somewhere: {full_won}, {early_won}"
        );
    }

    /// λ measured end to end: the search's chosen file shrinks and its distortion grows as λ
    /// grows (replaces a test that only checked the final multiply by λ).
    #[test]
    fn larger_lambda_gives_smaller_files_and_more_distortion() {
        let scene = crate::sample::scene(300, 1);
        let ev = Evaluator::new(&scene);
        let mut last: Option<(usize, f64)> = None;
        for l in [0.0, 20.0, 2000.0] {
            let (cfg, path) = search(&scene, Lambda::new(l).unwrap(), |_| {}).unwrap();
            let (bytes, d) = ev.eval(&cfg).unwrap();
            assert!(path.iter().all(|p| (p.j - (p.d + Lambda::new(l).unwrap().rate_cost(p.bytes))).abs() < 1e-9));
            if let Some((b0, d0)) = last {
                assert!(bytes < b0, "λ {l}: {bytes} bytes, not fewer than {b0}");
                assert!(d >= d0, "λ {l}: D {d} below {d0}");
            }
            last = Some((bytes, d));
        }
    }

    /// Trials coded through the search's [`GroupCache`] and drawn from a recorded base give the
    /// bytes, reports and D of trials coded and drawn from scratch, and the cache serves the groups
    /// a trial does not change.
    #[test]
    fn cached_and_replayed_trials_are_the_uncached_ones() {
        let scene = crate::sample::scene(300, 3);
        assert!(scene.sh_degree > 0);
        let start = EncodeConfig { steps: Steps::default().scaled(0.7), learned_tables: false, ..EncodeConfig::default() };
        let mut configs: Vec<(Option<Group>, EncodeConfig)> =
            Group::ALL.into_iter().map(|g| (Some(g), with_knob(&start, g, 2.0))).collect();
        configs.push((None, EncodeConfig { max_sh_degree: 1, ..start }));
        configs.push((None, EncodeConfig { steps: Steps { rest_deadzone: 0.3, ..start.steps }, ..start }));
        configs.push((None, EncodeConfig { sh_vq: [16, 0, 0], ..start }));
        configs.push((None, EncodeConfig { sh_vq: [16, 8, 0], ..start }));
        configs.push((None, EncodeConfig { sh_vq: [16, 8, 0], max_sh_degree: 2, dc_fit: true, ..start }));
        let mut cached = Evaluator::new(&scene);
        cached.eval_as_base(&start).unwrap();
        assert!(cached.cache.len() >= 5, "{} groups", cached.cache.len());
        let fresh = Evaluator::new(&scene); // no base: every trial rendered
        let mut replayed = 0;
        for (knob, c) in &configs {
            let before = cached.cache.len();
            let (b, d, r) = cached.eval_report(c).unwrap();
            let (bytes, r0, _) = super::super::encode_with(&scene, c, Some(&cached.importance)).unwrap();
            assert_eq!(b, bytes.len(), "{c:?}");
            assert_eq!(format!("{r:?}"), format!("{r0:?}"));
            assert_eq!(d.to_bits(), fresh.eval(c).unwrap().1.to_bits(), "{c:?}");
            let (again, ..) = super::super::encode_cached(&scene, c, Some(&cached.importance), Some(&cached.cache)).unwrap();
            assert_eq!(again, bytes);
            if knob.is_some_and(|g| g != Group::Position) {
                assert_eq!(cached.cache.len(), before + 1, "{knob:?} codes only its own group");
            }
            let dec = dequantise(&super::super::encode_with(&scene, c, Some(&cached.importance)).unwrap().2);
            replayed += usize::from(same_geometry(&cached.base.as_ref().unwrap().0, &dec));
        }
        assert!(replayed >= 8, "{replayed} trials replayed"); // SH DC, 3 bands, degree, dead zone, 2 codebooks, DC fit
    }

    /// Runs `stage` from the default configuration at each of `lambdas` on `scene`: it tries
    /// `candidates` configurations, its choice's J is the lowest of the start's and every
    /// candidate's, and it leaves the start (`changed` false) unless that lowers J. Returns
    /// whether some λ changed it.
    fn stage_lowers_j(
        scene: &Splats,
        lambdas: [f64; 3],
        candidates: impl Fn(&EncodeConfig) -> usize,
        changed: impl Fn(&EncodeConfig) -> bool,
        stage: impl Fn(&mut Trials, &mut Log<fn(&Trial)>, EncodeConfig) -> Result<EncodeConfig, SceneError>,
    ) -> bool {
        let mut picked = false;
        for l in lambdas {
            let lambda = Lambda::new(l).unwrap();
            let mut trials = Trials::new(scene).unwrap();
            let mut on_step: fn(&Trial) = |_| {};
            let mut log = Log { path: Vec::new(), on_step: &mut on_step, lambda };
            let start = EncodeConfig { learned_tables: false, ..EncodeConfig::default() };
            let Outcome { bytes: b0, d: d0, .. } = trials.one(&start).unwrap();
            let out = stage(&mut trials, &mut log, start).unwrap();
            let Outcome { bytes: b, d, .. } = trials.one(&out).unwrap();
            let j = log.j(b, d);
            assert!(j <= log.j(b0, d0));
            assert!(log.path.iter().all(|t| t.j >= j - 1e-9), "λ {l}: a candidate had a lower J than the choice");
            assert!(!changed(&out) || j < log.j(b0, d0), "λ {l}: changed without lowering J");
            assert_eq!(log.path.len(), candidates(&out), "λ {l}: candidates tried");
            picked |= changed(&out);
        }
        picked
    }

    /// The codebook stage keeps per-coefficient coding unless a codebook lowers J, and chooses a
    /// codebook for some λ. Its candidates: every K and step per band, then every K and step for
    /// one joint codebook of the bands.
    #[test]
    fn the_search_picks_codebooks_only_when_j_is_lower() {
        let scene = crate::sample::scene(600, 3);
        assert!(scene.sh_degree >= 2);
        let candidates = (usize::from(scene.sh_degree) + 1) * VQ_ROWS.len() * VQ_STEPS.len();
        let vq = |c: &EncodeConfig| c.sh_vq != [0; 3];
        let picked =
            stage_lowers_j(&scene, [0.0, 50.0, 2000.0], |_| candidates, vq, |t, log, start| vq_stage(t, log, start, scene.sh_degree));
        assert!(picked, "no λ chose a codebook");
    }

    /// The tail stage picks importance classes only when they lower J (then the candidate of
    /// lowest J), and picks them for some λ. Its candidates: every share and factor, then with a
    /// tail every group's multiplier ([`tail_group_variants`]), then, where one was taken, that
    /// group's move once more.
    #[test]
    fn the_search_picks_a_tail_only_when_j_is_lower() {
        let scene = crate::sample::scene(600, 4);
        let tail = |c: &EncodeConfig| !c.tail.is_off();
        let candidates = |out: &EncodeConfig| {
            let common = EncodeConfig { tail: CoarseTail::new(out.tail.share, out.tail.factor), ..*out };
            let moved = out.tail.groups.iter().any(|&m| m != 1.0);
            TAIL_SHARES.len() * TAIL_FACTORS.len() + tail_group_variants(&common, scene.sh_degree).len() + usize::from(moved)
        };
        let picked = stage_lowers_j(&scene, [0.0, 50.0, 500.0], candidates, tail, tail_stage);
        assert!(picked, "no λ chose a tail");
    }

    /// Choosing the classes again keeps every other choice, and the result's J on the scene's
    /// own views is no higher than with the given classes or with none.
    #[test]
    fn retuned_tail_keeps_the_rest_and_lowers_j() {
        let scene = crate::sample::scene(600, 4);
        let given = EncodeConfig {
            tail: CoarseTail::new(TAIL_SHARES[0], TAIL_FACTORS[TAIL_FACTORS.len() - 1]),
            max_sh_degree: 2,
            ..EncodeConfig::default()
        };
        for l in [0.0, 50.0, 500.0] {
            let lambda = Lambda::new(l).unwrap();
            let out = retune_tail(&mut Trials::new(&scene).unwrap(), lambda, given).unwrap();
            assert_eq!(EncodeConfig { tail: given.tail, ..out }, given, "λ {l}: only the classes change");
            let mut trials = Trials::new(&scene).unwrap();
            let mut j = |c: &EncodeConfig| {
                let Outcome { bytes: b, d, .. } = trials.one(&EncodeConfig { learned_tables: false, ..*c }).unwrap();
                d + lambda.rate_cost(b)
            };
            let j_out = j(&out);
            assert!(j_out <= j(&given) && j_out <= j(&EncodeConfig { tail: CoarseTail::OFF, ..given }), "λ {l}");
        }
    }

    /// The parallel search chooses the same configuration, records the same trials and writes
    /// the same bytes on 1 and 2 threads.
    #[test]
    fn the_search_is_the_same_on_one_and_two_threads() {
        let scene = crate::sample::scene(300, 2);
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            pool.install(|| {
                let (cfg, path) = search(&scene, Lambda::new(20.0).unwrap(), |_| {}).unwrap();
                let trials: Vec<(String, usize, u64)> = path.into_iter().map(|t| (t.change, t.bytes, t.d.to_bits())).collect();
                (cfg, trials, super::super::encode(&scene, &cfg).unwrap().0)
            })
        };
        let (one, two) = (run(1), run(2));
        assert!(one.1.len() > 40, "{} trials", one.1.len());
        assert_eq!(one.0, two.0);
        assert_eq!(one.1, two.1);
        assert_eq!(one.2, two.2, "the chosen file differs between 1 and 2 threads");
    }

    /// The fine-tuning's pruning opacity: lossless at λ = 0 (pruning never lowers D), higher
    /// under a huge λ, and the file it gives never grows with λ (it minimises D + λ·R).
    #[test]
    fn pruning_opacity_follows_lambda() {
        let mut scene = crate::sample::scene(300, 4);
        // Opacities from 0.25/255 to 0.9, so every threshold tried prunes some.
        let n = scene.len() as f32;
        scene.opacity_logits.iter_mut().enumerate().for_each(|(i, o)| *o = -7.0 + 9.2 * i as f32 / n);
        let (config, _) = search(&scene, Lambda::new(20.0).unwrap(), |_| {}).unwrap();
        let ev = Evaluator::new(&scene);
        let mut trials = Trials::new(&scene).unwrap();
        let mut last = usize::MAX;
        for l in [0.0, 20.0, 2000.0, 1e6] {
            let m = pruning_opacity(&mut trials, Lambda::new(l).unwrap(), &config).unwrap();
            if l == 0.0 {
                assert_eq!(m, 1.0 / 255.0);
            }
            if l == 1e6 {
                assert!(m > 1.0 / 255.0, "{m}");
            }
            let (bytes, _) = ev.eval(&EncodeConfig { min_removal_error: 0.0, min_opacity: m, learned_tables: false, ..config }).unwrap();
            assert!(bytes <= last, "λ {l}: {bytes} bytes after {last}");
            last = bytes;
        }
    }

    /// Searches sharing their trials (as `--target-psnr`'s probes do) choose, record and code
    /// exactly what fresh searches do, and the later ones evaluate fewer new configurations than
    /// a fresh search does.
    #[test]
    fn shared_trials_change_no_choice() {
        let scene = crate::sample::scene(300, 6);
        let mut shared = Trials::new(&scene).unwrap();
        let fine = fine_steps();
        for (i, l) in [20.0, 200.0, 60.0].into_iter().enumerate() {
            let lambda = Lambda::new(l).unwrap();
            let before = shared.len();
            let (a, pa) = search_with(&mut shared, lambda, fine, true, |_| {}).unwrap();
            let mut fresh = Trials::new(&scene).unwrap();
            let (b, pb) = search_with(&mut fresh, lambda, fine, true, |_| {}).unwrap();
            assert_eq!(a, b, "λ {l}");
            let key = |p: &[Trial]| p.iter().map(|t| (t.change.clone(), t.bytes, t.d.to_bits())).collect::<Vec<_>>();
            assert_eq!(key(&pa), key(&pb), "λ {l}");
            assert_eq!(super::super::encode(&scene, &a).unwrap().0, super::super::encode(&scene, &b).unwrap().0);
            let added = shared.len() - before;
            assert!(i == 0 && added == fresh.len() || i > 0 && added < fresh.len(), "λ {l}: {added} new of {}", fresh.len());
        }
    }

    #[test]
    fn step_nudges_move_one_groups_step_an_eighth_of_an_octave() {
        let from = EncodeConfig::default();
        let nudges = [step_nudges(&from, true, 3), step_nudges(&from, false, 3)].concat();
        assert_eq!(nudges.len(), 16);
        // Only the groups the file has: no SH band above the scene's degree or the config's.
        assert_eq!(step_nudges(&from, true, 1).len(), 6);
        assert_eq!(step_nudges(&EncodeConfig { max_sh_degree: 0, ..from }, true, 3).len(), 5);
        for (name, c) in &nudges {
            let moved: Vec<Group> = Group::ALL.into_iter().filter(|&g| c.steps.of(g) != from.steps.of(g)).collect();
            assert_eq!(moved.len(), 1, "{name}: one group's step moves");
            let ratio = c.steps.of(moved[0]) / from.steps.of(moved[0]);
            let expected = if name.ends_with("coarser") { 2f32.powf(0.125) } else { 2f32.powf(-0.125) };
            assert!((ratio / expected - 1.0).abs() < 1e-6, "{name}: × {ratio}");
            assert!(name.starts_with(moved[0].name()), "{name} names {}", moved[0].name());
            assert_eq!(EncodeConfig { steps: from.steps, ..*c }, from, "{name}: nothing but the step");
        }
    }

    #[test]
    fn between_changes_one_knob_at_a_time_towards_the_other_choice() {
        let from = EncodeConfig { min_removal_error: 0.5, ..EncodeConfig::default() };
        let mut to = EncodeConfig { min_removal_error: 2.0, max_sh_degree: 2, ..from };
        to.steps.opacity *= 2.0;
        to.steps.sh_rest[1] *= 0.5;
        to.sh_vq[1] = 256;
        let cands = between(&from, &to);
        let names: Vec<&str> = cands.iter().map(|c| c.0.as_str()).collect();
        assert_eq!(names, ["pruning", "pruning midway", "SH degree", "opacity step", "SH band 2"]);
        let get = |n: &str| cands.iter().find(|c| c.0 == n).unwrap().1;
        assert_eq!(get("pruning"), EncodeConfig { min_removal_error: 2.0, ..from });
        assert_eq!(get("pruning midway").min_removal_error, 1.0);
        assert_eq!(get("SH degree"), EncodeConfig { max_sh_degree: 2, ..from });
        assert_eq!(get("opacity step").steps.opacity, to.steps.opacity);
        let band = get("SH band 2");
        assert_eq!((band.steps.sh_rest, band.sh_vq), (to.steps.sh_rest, to.sh_vq));
        // Every knob of `to` applied in turn gives `to`; equal choices give nothing between.
        let all = ["pruning", "SH degree", "opacity step", "SH band 2"]
            .iter()
            .fold(from, |c, n| between(&c, &to).into_iter().find(|x| x.0 == *n).unwrap().1);
        assert_eq!(all, to);
        assert!(between(&to, &to).is_empty());
    }
}

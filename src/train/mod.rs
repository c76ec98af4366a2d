//! The trainer: Adam over the Gaussian parameters with the reference 3DGS schedule (scaled to the
//! run length), adaptive density control, pluggable image loss ([`ImageLoss`]) and rate term
//! ([`RdTerm`]).

pub mod adam;
pub mod checkpoint;
pub mod densify;
/// The GPU trainer (wgpu), feature `gpu`.
#[cfg(feature = "gpu")]
pub mod gpu;
pub mod init;

pub mod targets;

use crate::io::{Dataset, Frame, Split};
use crate::loss::ImageLoss;
use crate::metrics::view::mean_psnr_ssim;
use crate::raster;
use crate::rate::group::Group;
use crate::rng::Rng;
use crate::{Error, Result};
use adam::{first_non_finite, Adam};
use densify::{DensifyParams, DensifyStats};
use gscodec_decoder::{RenderOptions, Splats};
use serde::{Deserialize, Serialize};
use std::path::PathBuf;
use std::time::Instant;

pub use crate::rate::term::{RateOutcome, RdTerm};

/// Training settings. Schedules are the reference 30k-iteration recipe scaled to `iters`.
#[derive(Debug, Clone, Serialize)]
pub struct TrainConfig {
    pub iters: usize,
    pub seed: u64,
    /// Highest SH degree (raised step by step during training).
    pub sh_degree_max: u8,
    /// Clone/split/prune/opacity reset (off to fine-tune an existing scene).
    pub densify: bool,
    /// Multiplies every learning rate.
    pub lr_scale: f32,
    /// The learning rates of every group but the positions (constant in the reference recipe)
    /// fall log-linearly over the second half of the run to this share of themselves (1: they
    /// stay constant). Fine-tuning a scene uses [`FINE_TUNE_ANNEAL`].
    pub anneal_to: f32,
    /// Held-out PSNR every this many iterations (0 = only at the end).
    pub eval_interval: usize,
    /// Random initial Gaussians when the dataset has no points and no initial scene is given.
    pub init_points: usize,
    /// Densification never grows the scene beyond this.
    pub max_gaussians: usize,
    /// Densification gradient threshold (NDC units, as the reference's 2e-4).
    pub densify_grad_threshold: f32,
}

impl Default for TrainConfig {
    fn default() -> Self {
        TrainConfig {
            iters: 5000,
            seed: 0,
            sh_degree_max: 3,
            densify: true,
            lr_scale: 1.0,
            anneal_to: 1.0,
            eval_interval: 500,
            init_points: 10_000,
            max_gaussians: 100_000,
            densify_grad_threshold: 2e-4,
        }
    }
}

/// [`TrainConfig::anneal_to`] of fine-tuning (`encoder::Encoder`'s `--iters` on a scene): with
/// constant rates the last iterations' single views leave the scene noisy. At `--iters 400` the
/// fall to 0.3 gave files smaller at equal PSNR by 10 % on fruit-drops, 6 % on k7000 and 1.9 %
/// on playbot trained here, 1.0 % larger on lego trained here (docs/codec.md §27).
pub const FINE_TUNE_ANNEAL: f32 = 0.3;

/// Learning rates of the reference recipe (position relative to the scene extent).
pub const LR_POSITION_INIT: f32 = 1.6e-4;
pub const LR_POSITION_FINAL: f32 = 1.6e-6;
pub const LR_SCALE: f32 = 5e-3;
pub const LR_ROTATION: f32 = 1e-3;
pub const LR_OPACITY: f32 = 5e-2;
pub const LR_SH_DC: f32 = 2.5e-3;
pub const LR_SH_REST: f32 = LR_SH_DC / 20.0;

/// Iteration schedule derived from the reference 30k recipe.
///
/// The reference (30,000 iterations): SH degree up every 1,000, densify every 100 from 500 to
/// 15,000, opacity reset every 3,000 while densifying. Scaled to `iters` linearly, with floors so
/// that short runs do not collapse: densification at most every [`MIN_DENSIFY_EVERY`] iterations
/// (new Gaussians need time to settle) and opacity resets at most every
/// [`MIN_OPACITY_RESET_EVERY`] (after a reset to 0.01 the opacities need hundreds of Adam steps to
/// come back before the next prune; at 300 iterations the plain scaling reset every 30). A run too
/// short for one reset at that interval before densification ends has none:
/// `opacity_reset_every` is then `usize::MAX` (`null` in reports), so `it % opacity_reset_every
/// == 0` and `it > opacity_reset_every` stay false.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct Schedule {
    pub sh_up_every: usize,
    pub densify_from: usize,
    pub densify_until: usize,
    pub densify_every: usize,
    #[serde(serialize_with = "never_as_null")]
    pub opacity_reset_every: usize,
}

/// Share of a run during which it densifies (15,000 of the reference 30,000 iterations).
pub const DENSIFY_UNTIL_SHARE: f64 = 0.5;
/// Fewest iterations between two densification steps.
pub const MIN_DENSIFY_EVERY: usize = 50;
/// Fewest iterations between two opacity resets (and before the first).
pub const MIN_OPACITY_RESET_EVERY: usize = 1000;
/// Pruning never leaves fewer Gaussians than this fraction of the most the run has had.
pub const MIN_KEEP_FRACTION: f64 = 0.01;

fn never_as_null<S: serde::Serializer>(v: &usize, s: S) -> std::result::Result<S::Ok, S::Error> {
    if *v == usize::MAX {
        s.serialize_none()
    } else {
        s.serialize_u64(*v as u64)
    }
}

impl Schedule {
    pub fn for_iters(iters: usize) -> Self {
        let s = iters as f64 / 30_000.0;
        let at = |v: f64| ((v * s).round() as usize).max(1);
        let densify_until = at(30_000.0 * DENSIFY_UNTIL_SHARE);
        let reset = at(3000.0).max(MIN_OPACITY_RESET_EVERY);
        Schedule {
            sh_up_every: at(1000.0),
            densify_from: at(500.0),
            densify_until,
            densify_every: at(100.0).clamp(MIN_DENSIFY_EVERY.min(iters.max(1)), 100),
            opacity_reset_every: if reset < densify_until { reset } else { usize::MAX },
        }
    }

    /// Whether iteration `it` (1-based) ends with a densify-and-prune step.
    pub fn densifies(&self, it: usize) -> bool {
        it < self.densify_until && it > self.densify_from && it % self.densify_every == 0
    }

    /// Whether iteration `it` ends with an opacity reset (`white_background`: the reference's
    /// extra reset at `densify_from` for white-background datasets).
    pub fn resets_opacity(&self, it: usize, white_background: bool) -> bool {
        it < self.densify_until && (it % self.opacity_reset_every == 0 || (white_background && it == self.densify_from))
    }

    /// Whether screen-size pruning is on at iteration `it` (after the first opacity reset).
    pub fn prunes_screen_size(&self, it: usize) -> bool {
        it > self.opacity_reset_every
    }
}

/// A progress update (once per iteration).
#[derive(Debug, Clone, Copy)]
pub struct Progress {
    pub iteration: usize,
    pub iters: usize,
    pub loss: f64,
    pub gaussians: usize,
    /// Held-out PSNR when it was evaluated at this iteration: of the scene as training renders
    /// it (the learned groups quantised once a rate term is on).
    pub test_psnr: Option<f64>,
    /// The rate term's bit estimate at this iteration (None without a rate term, or before it starts).
    pub rate_bits: Option<f64>,
}

/// One point of the error-against-run-time record.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ReportPoint {
    pub iteration: usize,
    /// Training wall time so far (evaluation excluded).
    pub seconds: f64,
    /// Mean training loss since the previous point.
    pub loss: f64,
    pub gaussians: usize,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub test_psnr: Option<f64>,
}

/// Accumulated wall time per training stage, seconds.
#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize)]
pub struct StageTimes {
    pub project: f64,
    pub sort: f64,
    pub rasterize: f64,
    pub loss: f64,
    pub backward: f64,
    pub optimiser: f64,
    pub densify: f64,
}

/// What a training run did.
#[derive(Debug, Clone, Serialize)]
pub struct TrainReport {
    /// The training backend that ran (`cpu`, `gpu`).
    pub backend: &'static str,
    pub loss: String,
    pub config: TrainConfig,
    pub schedule: Schedule,
    pub extent: f32,
    pub points: Vec<ReportPoint>,
    pub gaussians: usize,
    /// Training wall time (evaluation excluded).
    pub train_seconds: f64,
    pub test_views: usize,
    /// Held-out PSNR and SSIM at the end, of the scene as training renders it (the learned
    /// groups quantised when it trained with a rate term).
    pub test_psnr: Option<f64>,
    pub test_ssim: Option<f64>,
    pub stages: StageTimes,
    /// What the rate term learned (steps) and estimated (bits); None without one.
    pub rate: Option<RateOutcome>,
    /// GPU trainer: iterations whose tile/Gaussian pairs outgrew the sort buffers between two
    /// read-backs, rendered (forward and backward alike) with the pairs that fit; 0 on the CPU.
    pub truncated_frames: usize,
}

/// The learning rate of group `g` at iteration `it` (1-based): the reference recipe, the position
/// rate decaying log-linearly over `cfg.iters` and relative to the scene `extent`, the others
/// falling to `cfg.anneal_to` of themselves over the second half, all times `cfg.lr_scale`.
/// Shared by the CPU and GPU trainers.
pub fn learning_rate(g: Group, it: usize, cfg: &TrainConfig, extent: f32) -> f32 {
    let base = match g {
        Group::Position => {
            let t = (it as f64 / cfg.iters.max(1) as f64).clamp(0.0, 1.0);
            let l = ((LR_POSITION_INIT as f64).ln() * (1.0 - t) + (LR_POSITION_FINAL as f64).ln() * t).exp();
            (l * extent as f64) as f32
        }
        Group::Scale => LR_SCALE,
        Group::Rotation => LR_ROTATION,
        Group::Opacity => LR_OPACITY,
        Group::ShDc => LR_SH_DC,
        Group::Sh1 | Group::Sh2 | Group::Sh3 => LR_SH_REST,
    };
    let anneal = match g {
        Group::Position => 1.0,
        _ => {
            // 0 until half way, 1 at the end.
            let u = (2.0 * it as f64 / cfg.iters.max(1) as f64 - 1.0).clamp(0.0, 1.0);
            f64::from(cfg.anneal_to).powf(u)
        }
    };
    (f64::from(base) * anneal) as f32 * cfg.lr_scale
}

/// One densify/prune step of the reference recipe at iteration `it`, shared by both trainers:
/// clone/split/prune with the reference thresholds, never below [`MIN_KEEP_FRACTION`] of the
/// run's `peak` Gaussians.
///
/// # Errors
/// [`Error::Failure`] when every Gaussian was pruned.
#[allow(clippy::too_many_arguments)]
pub(crate) fn densify_step(
    params: &mut Splats,
    adam: &mut Adam,
    stats: &DensifyStats,
    cfg: &TrainConfig,
    sched: &Schedule,
    it: usize,
    extent: f32,
    peak: usize,
    rng: &mut Rng,
) -> Result<()> {
    let dp = DensifyParams {
        grad_threshold: cfg.densify_grad_threshold,
        percent_dense: 0.01,
        extent,
        min_opacity: 0.005,
        max_screen_radius: sched.prunes_screen_size(it).then_some(20.0),
        max_world_fraction: 0.1,
        max_gaussians: cfg.max_gaussians,
    };
    let floor = (peak as f64 * MIN_KEEP_FRACTION).ceil() as usize;
    densify::densify_and_prune_keeping(params, adam, stats, &dp, rng, floor);
    if params.is_empty() {
        return Err(Error::Failure(format!("training collapsed at iteration {it}: every Gaussian was pruned")));
    }
    Ok(())
}

pub(crate) fn non_finite_error(what: &str, iter: usize, i: usize, g: Group) -> Error {
    Error::Failure(format!("training diverged at iteration {iter}: non-finite {what} in parameter group `{}` (Gaussian {i})", g.name()))
}

/// Mean held-out PSNR and SSIM of what training renders: `rendered`, the parameters as the rate
/// term renders them (the learned groups quantised, as the file will hold them; `None` before
/// the term starts or without one), else `params`. A scene trained through the quantiser can be
/// 0.7 dB better or worse raw than quantised (docs/wd.md §13), so the raw scene's PSNR would
/// misreport what gets coded. Both trainers evaluate through this.
pub(crate) fn held_out(rendered: Option<Splats>, params: &Splats, frames: &[&Frame], background: [f32; 3]) -> Result<Option<(f64, f64)>> {
    mean_psnr_ssim(rendered.as_ref().unwrap_or(params), frames, background)
}

/// Trains Gaussians on `dataset`'s training split.
///
/// `init` is the starting scene (fine-tuning); without it the dataset's points or random points
/// are used. The loss is `loss` on each rendered training view plus `rd`'s term.
///
/// # Errors
/// No training views, an empty or invalid start scene, or a non-finite value reaching a
/// parameter (the message names the group and iteration).
pub fn train(
    dataset: &Dataset,
    init: Option<Splats>,
    cfg: &TrainConfig,
    loss: Box<dyn ImageLoss>,
    rd: Option<Box<dyn RdTerm>>,
    progress: &mut dyn FnMut(&Progress),
) -> Result<(Splats, TrainReport)> {
    train_with(dataset, init, cfg, loss, rd, progress, &RunOptions::default())
}

/// Checkpoints and the live report of a long run (all off by default).
#[derive(Debug, Clone)]
pub struct RunOptions {
    /// Folder to write checkpoints into.
    pub checkpoint: Option<PathBuf>,
    /// Checkpoint every this many iterations; `None`: every `checkpoint_seconds` of wall time.
    pub checkpoint_every: Option<usize>,
    pub checkpoint_seconds: f64,
    /// Continue the run checkpointed in this folder (same settings and dataset).
    pub resume: Option<PathBuf>,
    /// Rewrite this JSON report (a [`TrainReport`] so far) atomically as training goes: at each
    /// evaluation, each checkpoint, and at most every [`LIVE_REPORT_SECONDS`] otherwise.
    pub report: Option<PathBuf>,
    /// Stop after this iteration as if interrupted (checkpoint written); for tests.
    pub stop_after: Option<usize>,
    /// Stop at Ctrl-C (SIGINT) after the current iteration, writing a checkpoint.
    pub catch_interrupt: bool,
}

impl Default for RunOptions {
    fn default() -> Self {
        RunOptions {
            checkpoint: None,
            checkpoint_every: None,
            checkpoint_seconds: 600.0,
            resume: None,
            report: None,
            stop_after: None,
            catch_interrupt: false,
        }
    }
}

/// Seconds between two rewrites of the live report (besides evaluations and checkpoints).
pub const LIVE_REPORT_SECONDS: f64 = 10.0;

/// The run's identity for checkpoints: its settings and its dataset's frames.
pub(crate) fn fingerprint(cfg: &TrainConfig, dataset: &Dataset, loss: &str) -> String {
    let names: Vec<&str> = dataset.frames.iter().map(|f| f.name.as_str()).collect();
    serde_json::json!({ "config": cfg, "loss": loss, "frames": names }).to_string()
}

/// The checkpoint in `dir`, checked to be of this run: its fingerprint `print`, consistent sizes,
/// an iteration inside a run of `iters` and a view order over `train_views` views (both trainers).
pub(crate) fn resume_state(dir: &std::path::Path, print: &str, iters: usize, train_views: usize) -> Result<checkpoint::State> {
    let path = checkpoint::file(dir);
    let st = checkpoint::load(dir)?;
    if st.fingerprint != print {
        return Err(Error::input(&path, "the checkpoint is of another run (settings, loss or dataset differ)"));
    }
    st.check(&path)?;
    if st.iteration as usize >= iters || st.order.iter().any(|&o| o as usize >= train_views) {
        return Err(Error::input(&path, format!("iteration {} is not inside this {iters}-iteration run", st.iteration)));
    }
    Ok(st)
}

/// After iteration `it` of `iters`: `(write a checkpoint, stop the run)` — periodic (every
/// `checkpoint_every` iterations, else `checkpoint_seconds` since `last`) or stopping (`stop_after`,
/// Ctrl-C); never after the last iteration.
pub(crate) fn checkpoint_now(run: &RunOptions, it: usize, iters: usize, last: Instant) -> (bool, bool) {
    let stop = it < iters && (run.stop_after == Some(it) || (run.catch_interrupt && checkpoint::interrupted()));
    let due = match run.checkpoint_every {
        Some(n) => n > 0 && it % n == 0,
        None => last.elapsed().as_secs_f64() >= run.checkpoint_seconds,
    };
    ((due || stop) && it < iters, stop)
}

/// The error of a run stopped after iteration `it` (naming the checkpoint to resume from).
pub(crate) fn interrupted_error(run: &RunOptions, it: usize, iters: usize) -> Error {
    let resume = match &run.checkpoint {
        Some(dir) => format!("; resume with --resume {}", dir.display()),
        None => String::new(),
    };
    Error::Failure(format!("interrupted after iteration {it} of {iters}{resume}"))
}

/// [`train`] with checkpoints, resume and a live report.
///
/// # Errors
/// As [`train`]; also a checkpoint that does not match the run (input error), and an interrupted
/// run (failure: the message names the checkpoint to resume from).
/// What both trainers set up before their first iteration: the splits, the RNG, the scene extent,
/// the initial scene (given, or from the dataset's points / random points) with the SH degree
/// it starts at, and the schedule. Refuses what neither trainer can run.
pub(crate) struct RunStart<'a> {
    pub train_frames: Vec<&'a Frame>,
    pub test_frames: Vec<&'a Frame>,
    pub rng: Rng,
    pub extent: f32,
    pub params: Splats,
    pub degree: u8,
    pub sched: Schedule,
}

impl<'a> RunStart<'a> {
    pub(crate) fn new(dataset: &'a Dataset, init: Option<Splats>, cfg: &TrainConfig, rate: bool, run: &RunOptions) -> Result<Self> {
        if rate && (run.checkpoint.is_some() || run.resume.is_some()) {
            return Err(Error::Input("checkpoints do not cover the rate term yet: train without --checkpoint/--resume".into()));
        }
        let train_frames = dataset.split(Split::Train);
        let test_frames = dataset.split(Split::Test);
        if train_frames.is_empty() {
            return Err(Error::Input("dataset has no training views".into()));
        }
        let mut rng = Rng::new(cfg.seed);
        let extent = init::camera_extent(dataset);
        let max_degree = cfg.sh_degree_max.min(3);
        let (params, degree) = match init {
            Some(s) => {
                let d = s.sh_degree.min(max_degree);
                (if s.sh_degree < max_degree { s.with_sh_degree(max_degree) } else { s }, d)
            }
            None => (init::initial_splats(dataset, cfg.init_points, max_degree, &mut rng), 0),
        };
        params.validate().map_err(|e| Error::Input(format!("initial scene: {e}")))?;
        if params.is_empty() {
            return Err(Error::Input("initial scene has no Gaussians".into()));
        }
        Ok(RunStart { train_frames, test_frames, rng, extent, params, degree, sched: Schedule::for_iters(cfg.iters) })
    }
}

#[allow(clippy::too_many_arguments)]
pub fn train_with(
    dataset: &Dataset,
    init: Option<Splats>,
    cfg: &TrainConfig,
    mut loss: Box<dyn ImageLoss>,
    mut rd: Option<Box<dyn RdTerm>>,
    progress: &mut dyn FnMut(&Progress),
    run: &RunOptions,
) -> Result<(Splats, TrainReport)> {
    let RunStart { train_frames, test_frames, mut rng, extent, mut params, mut degree, sched } =
        RunStart::new(dataset, init, cfg, rd.is_some(), run)?;
    let max_degree = cfg.sh_degree_max.min(3);
    let view_of = |f: &Frame| dataset.frames.iter().position(|g| std::ptr::eq(g, f)).unwrap_or(f.index);
    let mut adam = Adam::new(&params);
    let mut stats = DensifyStats::new(params.len());
    let mut peak = params.len();
    let mut order: Vec<usize> = Vec::new();
    let mut points = Vec::new();
    let mut stages = StageTimes::default();
    let (mut loss_sum, mut loss_n) = (0.0f64, 0usize);
    let mut train_seconds = 0.0;
    let print = fingerprint(cfg, dataset, loss.name());
    let mut first = 1;
    if let Some(dir) = &run.resume {
        let st = resume_state(dir, &print, cfg.iters, train_frames.len())?;
        first = st.iteration as usize + 1;
        params = st.params.into_splats();
        adam.m = st.adam_m.into_splats();
        adam.v = st.adam_v.into_splats();
        adam.rule.step = st.adam_step;
        rng = Rng::from_state(st.rng);
        order = st.order.iter().map(|&o| o as usize).collect();
        degree = st.degree.min(max_degree);
        peak = st.peak as usize;
        stats = DensifyStats { grad_accum: st.grad_accum, count: st.count, max_radius: st.max_radius };
        points = st.points.into_iter().map(ReportPoint::from).collect();
        stages = st.stages;
        (loss_sum, loss_n) = (st.loss_sum, st.loss_n as usize);
        train_seconds = st.train_seconds;
    }
    if run.catch_interrupt && run.checkpoint.is_some() {
        checkpoint::catch_interrupt();
    }
    let mut last_checkpoint = Instant::now();
    let mut last_report = Instant::now();
    let loss_name = loss.name().to_string();
    let partial = |points: &Vec<ReportPoint>, n: usize, train_seconds: f64, stages: StageTimes| TrainReport {
        backend: "cpu",
        loss: loss_name.clone(),
        config: cfg.clone(),
        schedule: sched,
        extent,
        points: points.clone(),
        gaussians: n,
        train_seconds,
        test_views: test_frames.len(),
        test_psnr: None,
        test_ssim: None,
        stages,
        rate: None,
        truncated_frames: 0,
    };
    let log_every = (cfg.iters / 500).max(1);
    let lr = |g: Group, it: usize| learning_rate(g, it, cfg, extent);

    for it in first..=cfg.iters {
        let t_iter = Instant::now();
        if it % sched.sh_up_every == 0 && degree < max_degree {
            degree += 1;
        }
        if order.is_empty() {
            order = (0..train_frames.len()).collect();
            rng.shuffle(&mut order);
        }
        let frame = train_frames[order.pop().unwrap()];
        let opts = RenderOptions { background: dataset.background, max_sh_degree: degree };

        let rendered = rd.as_mut().and_then(|r| r.render_params(&params, it));
        let render_from = rendered.as_ref().unwrap_or(&params);
        let (img, state, ft) = raster::forward_timed(render_from, &frame.camera, &opts);
        stages.project += ft.project;
        stages.sort += ft.sort;
        stages.rasterize += ft.rasterize;

        let t0 = Instant::now();
        let target = frame.image.get()?;
        let (mut l, dl) = loss.loss_and_grad(&img, &target, view_of(frame), it);
        drop(target);
        let t1 = Instant::now();
        let grads = raster::backward(render_from, &state, &dl);
        let raster::Gradients { params: mut grad, mean2d_ndc_norm } = grads;
        let mut rate_bits = None;
        if let Some(r) = rd.as_mut() {
            l += r.rate_and_grad(&params, &mut grad, it);
            rate_bits = r.outcome().and_then(|o| o.estimated_bits);
        }
        let t2 = Instant::now();
        stages.loss += (t1 - t0).as_secs_f64();
        stages.backward += (t2 - t1).as_secs_f64();
        if let Some((i, g)) = first_non_finite(&grad) {
            return Err(non_finite_error("gradient", it, i, g));
        }
        if !l.is_finite() {
            return Err(Error::Failure(format!("training diverged at iteration {it}: loss is {l}")));
        }

        // Densification statistics.
        if cfg.densify && it < sched.densify_until {
            let r_scale = 800.0 / frame.camera.width.max(frame.camera.height) as f32;
            for (i, p) in state.projected.iter().enumerate() {
                if p.radius > 0.0 {
                    stats.grad_accum[i] += mean2d_ndc_norm[i];
                    stats.count[i] += 1;
                    stats.max_radius[i] = stats.max_radius[i].max(p.radius * r_scale);
                }
            }
        }

        adam.step(&mut params, &grad, |g| lr(g, it));
        if let Some((i, g)) = first_non_finite(&params) {
            return Err(non_finite_error("value", it, i, g));
        }
        let t3 = Instant::now();
        stages.optimiser += (t3 - t2).as_secs_f64();

        // Held-out evaluation before densification: an opacity reset at this iteration would
        // otherwise make the scene read as nearly empty. Its time is not training time.
        let eval_now = cfg.eval_interval > 0 && it % cfg.eval_interval == 0 && it != cfg.iters;
        let t_eval = Instant::now();
        let test_psnr = if eval_now {
            held_out(rd.as_mut().and_then(|r| r.render_params(&params, it)), &params, &test_frames, dataset.background)?.map(|e| e.0)
        } else {
            None
        };
        let eval_seconds = t_eval.elapsed().as_secs_f64();
        if cfg.densify {
            if sched.densifies(it) {
                densify_step(&mut params, &mut adam, &stats, cfg, &sched, it, extent, peak, &mut rng)?;
                stats = DensifyStats::new(params.len());
            }
            if sched.resets_opacity(it, dataset.background == [1.0; 3]) {
                densify::reset_opacity(&mut params, &mut adam, 0.01);
            }
        }
        peak = peak.max(params.len());
        stages.densify += t3.elapsed().as_secs_f64() - eval_seconds;
        train_seconds += t_iter.elapsed().as_secs_f64() - eval_seconds;

        loss_sum += l;
        loss_n += 1;
        if it % log_every == 0 || eval_now || it == cfg.iters {
            points.push(ReportPoint {
                iteration: it,
                seconds: train_seconds,
                loss: loss_sum / loss_n as f64,
                gaussians: params.len(),
                test_psnr,
            });
            (loss_sum, loss_n) = (0.0, 0);
        }
        progress(&Progress { iteration: it, iters: cfg.iters, loss: l, gaussians: params.len(), test_psnr, rate_bits });

        // Checkpoint (periodic, or stopping), then the live report.
        let (write, stop) = checkpoint_now(run, it, cfg.iters, last_checkpoint);
        let mut wrote = false;
        if let Some(dir) = run.checkpoint.as_ref().filter(|_| write) {
            let st = checkpoint::State {
                fingerprint: print.clone(),
                iteration: it as u64,
                params: (&params).into(),
                adam_m: (&adam.m).into(),
                adam_v: (&adam.v).into(),
                adam_step: adam.rule.step,
                rng: rng.state(),
                order: order.iter().map(|&o| o as u64).collect(),
                degree,
                peak: peak as u64,
                grad_accum: stats.grad_accum.clone(),
                count: stats.count.clone(),
                max_radius: stats.max_radius.clone(),
                points: points.iter().map(checkpoint::PointData::from).collect(),
                stages,
                loss_sum,
                loss_n: loss_n as u64,
                train_seconds,
            };
            checkpoint::save(dir, &st)?;
            last_checkpoint = Instant::now();
            wrote = true;
        }
        if let Some(r) = &run.report {
            if wrote || stop || test_psnr.is_some() || last_report.elapsed().as_secs_f64() >= LIVE_REPORT_SECONDS {
                write_report(r, &partial(&points, params.len(), train_seconds, stages))?;
                last_report = Instant::now();
            }
        }
        if stop {
            return Err(interrupted_error(run, it, cfg.iters));
        }
    }
    let final_eval = held_out(rd.as_mut().and_then(|r| r.render_params(&params, cfg.iters)), &params, &test_frames, dataset.background)?;
    if let (Some(last), Some((p, _))) = (points.last_mut(), final_eval) {
        last.test_psnr = Some(p);
    }
    let report = TrainReport {
        backend: "cpu",
        loss: loss_name.clone(),
        config: cfg.clone(),
        schedule: sched,
        extent,
        points,
        gaussians: params.len(),
        train_seconds,
        test_views: test_frames.len(),
        test_psnr: final_eval.map(|e| e.0),
        test_ssim: final_eval.map(|e| e.1),
        stages,
        rate: rd.as_ref().and_then(|r| r.outcome()),
        truncated_frames: 0,
    };
    Ok((params, report))
}

/// Writes a report as pretty JSON, atomically.
pub fn write_report(path: &std::path::Path, report: &TrainReport) -> Result<()> {
    let json = serde_json::to_string_pretty(report).map_err(|e| Error::failure(path, e))?;
    crate::io::atomic::write_bytes_atomic(path, json.as_bytes())
}

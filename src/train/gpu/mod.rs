//! GPU trainer (wgpu): the whole training iteration on the GPU, with the CPU trainer
//! ([`crate::train::train`]) as its oracle: same renderer conventions, schedule, learning rates,
//! Adam, densification rules, rate term and report.
//!
//! Per iteration, recorded into one submission that nothing waits for: (with the rate term: the
//! quantised render records,) projection + SH colour, tile-count scan (the decoder's kernels), the
//! pair count for the sort (kept on the GPU: `train_count.wgsl`), keys, radix sort and tile ranges
//! (decoder; sized by indirect dispatch), the rasterizer saving final transmittance and list end
//! per pixel, L1 + SSIM loss forward and backward, rasterizer backward, projection / covariance /
//! SH backward with the densification statistics, (the rate term's sums, gradient and updates,
//! [`rate`],) and Adam (shaders/train_*.wgsl). Each iteration's scalars (loss, pair count, bits,
//! stage timestamps) stay in a ring on the GPU that the host reads every [`READ_EVERY`]
//! iterations. Training images are uploaded once. Densification reads the scene, moments and
//! statistics back once per densify step and runs the CPU trainer's [`densify::densify_and_prune`]
//! on them (the same rules, the same random numbers).
//!
//! With `--loss wd|wdr` (built-in features), the WD stage ([`wd`]) follows the L1+SSIM loss after
//! the warm-up and replaces its gradient and value by the WD / WD-R ones.
//!
//! Not bit-exact with the CPU trainer: gradients are summed with float atomics in whatever order
//! the GPU runs them. Not supported yet (refused with an input error): WD with VGG-16 features.

mod context;
pub mod rate;
pub mod session;
pub mod wd;

pub use context::{hardware_adapter_available, Gpu};
pub use rate::RateState;
pub use session::Session;

use super::adam::Adam;
use super::densify::DensifyStats;
use super::held_out;
use super::{checkpoint, learning_rate, non_finite_error, Progress, ReportPoint, RunOptions, StageTimes, TrainConfig, TrainReport};
use crate::io::{Dataset, Frame};
use crate::loss::{wdr, FeatureSpec, LossKind};
use crate::optim::AdamRule;
use crate::rate::group::Group;
use crate::rate::term::{RateTerm, RdTerm};
use crate::rng::Rng;
use crate::{Error, Result};
use gscodec_decoder::{Camera, Image, RenderOptions, Splats};
use std::time::Instant;

/// The image loss of a GPU run (a description: the GPU builds its own kernels).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GpuLoss {
    pub kind: LossKind,
    /// Weight λ of `(1 − SSIM)` in `(1 − λ)·L1 + λ·(1 − SSIM)`.
    pub ssim_weight: f32,
    /// γ of `wd` / `wdr` (None: `wd`'s default, `wdr`'s normalised γ; see docs/wd.md).
    pub wd_gamma: Option<f64>,
    /// Uniform σ of `wd` / `wdr` (None: [`crate::loss::wd::DEFAULT_SIGMA`]).
    pub wd_sigma: Option<f64>,
    /// Share of the iterations trained with L1-SSIM before `wd` / `wdr` (None:
    /// [`crate::loss::wdr::WARMUP_FRACTION`]).
    pub wd_warmup: Option<f64>,
    /// WD in VGG-16 features (refused: the GPU has only the built-in `pyramid` banks).
    pub vgg_features: bool,
    /// WD in `pyramid-colour` (else `pyramid`).
    pub colour: bool,
}

impl Default for GpuLoss {
    fn default() -> Self {
        GpuLoss {
            kind: LossKind::L1ssim,
            ssim_weight: 0.2,
            wd_gamma: None,
            wd_sigma: None,
            wd_warmup: None,
            vgg_features: false,
            colour: FeatureSpec::default().colour(),
        }
    }
}

impl From<LossKind> for GpuLoss {
    fn from(kind: LossKind) -> Self {
        GpuLoss { kind, ..Default::default() }
    }
}

impl GpuLoss {
    /// The loss `--loss`, `--features`, `--wd-gamma` and `--wd-sigma` describe.
    pub fn new(kind: LossKind, features: &FeatureSpec, wd_gamma: Option<f64>, wd_sigma: Option<f64>) -> Self {
        GpuLoss {
            kind,
            wd_gamma,
            wd_sigma,
            vgg_features: matches!(features, FeatureSpec::Vgg16(_)),
            colour: features.colour(),
            ..Default::default()
        }
    }

    /// The same loss with the warm-up share `--wd-warmup` (None: the default).
    pub fn with_warmup(self, wd_warmup: Option<f64>) -> Self {
        GpuLoss { wd_warmup, ..self }
    }

    /// The input error for a loss the GPU trainer does not have (WD in VGG-16 features), a γ
    /// that is not a positive number, or a σ or warm-up share out of range.
    pub fn check(&self) -> Result<()> {
        if self.kind == LossKind::L1ssim {
            return Ok(());
        }
        if self.vgg_features {
            return Err(Error::Input(
                "GPU training computes WD only in the built-in `pyramid` and `pyramid-colour` features; --features vgg16=… runs on the CPU backend (--backend cpu)".into(),
            ));
        }
        if let Some(s) = self.wd_sigma {
            crate::loss::check_wd_sigma(s)?;
        }
        if let Some(f) = self.wd_warmup {
            crate::loss::check_wd_warmup(f)?;
        }
        match self.wd_gamma {
            Some(g) if !(g.is_finite() && g > 0.0) => Err(Error::Input(format!("--wd-gamma must be a positive number, got {g}"))),
            _ => Ok(()),
        }
    }

    /// The WD stage's configuration of a `kind` run of `iters` iterations.
    fn wd_config(&self, kind: LossKind, iters: usize) -> wd::WdConfig {
        wd::WdConfig { colour: self.colour, ..wd::WdConfig::new(kind, self.wd_gamma, self.wd_sigma, self.wd_warmup, iters) }
    }

    /// Short name for the report (`l1ssim`, `wd`, `wdr`).
    pub fn name(&self) -> &'static str {
        self.kind.name()
    }
}

/// The process's shared training device ([`Gpu::shared`]), or the input error saying there is none.
pub fn gpu_or_error() -> Result<std::sync::Arc<Gpu>> {
    Gpu::shared()?
        .ok_or_else(|| Error::Input("GPU training: no GPU adapter available (install a Vulkan driver, or use --backend cpu)".into()))
}

/// Renders `splats` on the GPU, backpropagates the host-given image gradient `dl_dimg` and
/// returns `(image, parameter gradients, |dL/dmean2d| in NDC units)` like
/// [`crate::raster::forward`] + [`crate::raster::backward`] (the test oracle).
#[doc(hidden)]
pub fn render_backward(
    gpu: &Gpu,
    splats: &Splats,
    cam: &Camera,
    opts: &RenderOptions,
    dl_dimg: &[f32],
) -> Result<(Image, Splats, Vec<f32>)> {
    let mut s = Session::new(gpu, splats)?;
    let mut enc = gpu.device.create_command_encoder(&Default::default());
    s.project(&mut enc, cam, opts.background, opts.max_sh_degree)?;
    s.rasterize(&mut enc, cam)?;
    gpu.queue.submit([enc.finish()]);
    let img = s.read_image()?;
    s.write_dl(dl_dimg);
    let mut enc = gpu.device.create_command_encoder(&Default::default());
    s.backward(&mut enc, cam, false);
    gpu.queue.submit([enc.finish()]);
    let (grads, g2) = s.read_grads()?;
    gpu.check()?;
    let (hw, hh) = (cam.width as f32 / 2.0, cam.height as f32 / 2.0);
    let norm = g2.chunks_exact(context::G2).map(|g| ((g[0] * hw).powi(2) + (g[1] * hh).powi(2)).sqrt()).collect();
    Ok((img, grads, norm))
}

/// The GPU L1+SSIM loss of `rendered` against `target` and its gradient w.r.t. `rendered`
/// (the test oracle is [`crate::loss::L1Ssim`]).
#[doc(hidden)]
pub fn loss_and_grad(gpu: &Gpu, rendered: &Image, target: &Image, ssim_weight: f32) -> Result<(f64, Vec<f32>)> {
    training_loss_and_grad(gpu, rendered, target, &GpuLoss { ssim_weight, ..Default::default() }, 1, 1)
}

/// The GPU training loss `loss` (L1+SSIM, then the WD stage when `iter` is past the warm-up of a
/// run of `iters` iterations) of `rendered` against `target` and its gradient w.r.t. `rendered`,
/// for one view (the test oracle is the CPU's [`crate::loss::ImageLoss`] of the same loss).
#[doc(hidden)]
pub fn training_loss_and_grad(
    gpu: &Gpu,
    rendered: &Image,
    target: &Image,
    loss: &GpuLoss,
    iters: usize,
    iter: usize,
) -> Result<(f64, Vec<f32>)> {
    loss.check()?;
    let (w, h) = (rendered.width, rendered.height);
    // A one-Gaussian session only to own the image buffers.
    let mut one = Splats::new(0);
    one.push([0.0; 3], [0.0; 3], [1.0, 0.0, 0.0, 0.0], 0.0, [0.0; 3], &[]);
    let mut s = Session::new(gpu, &one)?;
    s.ensure_image(w, h)?;
    let img = s.img.as_ref().unwrap();
    gpu.queue.write_buffer(&img.image, 0, bytemuck::cast_slice(&rendered.data));
    let tgt = gpu.storage_init("target", bytemuck::cast_slice(&target.data));
    let mut stage = match loss.kind {
        LossKind::L1ssim => None,
        kind => Some(wd::WdStage::new(gpu, loss.wd_config(kind, iters), w, h)?),
    };
    let mut enc = gpu.device.create_command_encoder(&Default::default());
    s.loss(&mut enc, &tgt, loss.ssim_weight);
    if let Some(st) = stage.as_mut() {
        st.record(&s, &mut enc, 0, &tgt, !wdr::in_warmup(iter, st.config.warmup))?;
    }
    gpu.queue.submit([enc.finish()]);
    let dl = s.read_dl()?;
    let l = s.read_loss()?;
    gpu.check()?;
    Ok((l as f64, dl))
}

/// The GPU rate term on `params` with the distortion gradient `dist_grad` (w.r.t. the rendered
/// values), for `calls` iterations of the term (the term starting at the first): returns, after
/// the last, `w·R`, the gradient (distortion + rate), the term's state and the quantised scene the
/// iteration rendered, like `calls` calls of [`RateTerm::rate_and_grad`] and
/// [`RateTerm::render_params`] (the test oracle).
#[doc(hidden)]
pub fn rate_and_grad(
    gpu: &Gpu,
    params: &Splats,
    dist_grad: &Splats,
    term: RateTerm,
    calls: usize,
) -> Result<(f64, Splats, RateState, Splats)> {
    let mut s = Session::new(gpu, params)?;
    let mut term = term;
    term.start_iter = 0;
    s.set_rate(term);
    let mut out = None;
    for it in 0..calls {
        s.begin_rate(it)?;
        gpu.queue.write_buffer(&s.scene.grads, 0, bytemuck::cast_slice(&session::to_records(dist_grad)));
        gpu.queue.write_buffer(&s.ring, 0, &[0; 256]);
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        s.record_rate(&mut enc);
        gpu.queue.submit([enc.finish()]);
        let (grads, _) = s.read_grads()?;
        let value = f64::from(s.read_loss()?);
        let r = s.rate.as_mut().expect("rate term");
        let rendered = session::from_records(&gpu.read_f32(&r.render, params.len() * s.scene.stride)?, params.sh_degree);
        let state = r.read(gpu)?;
        out = Some((value, grads, state, rendered));
    }
    gpu.check()?;
    out.ok_or_else(|| Error::Input("rate_and_grad: no call".into()))
}

/// The parameter group of offset `k` in a parameter record.
fn group_of_offset(k: usize) -> Group {
    match k {
        0..3 => Group::Position,
        3..6 => Group::Scale,
        6..10 => Group::Rotation,
        10 => Group::Opacity,
        11..14 => Group::ShDc,
        _ => match (k - 14) / 3 {
            0..3 => Group::Sh1,
            3..8 => Group::Sh2,
            _ => Group::Sh3,
        },
    }
}

/// Trains Gaussians on `dataset`'s training split on the GPU; the same contract, schedule and
/// report as [`crate::train::train`] (the report's `loss` is the loss's name, its stage times are GPU
/// times from timestamp queries when the adapter has them, else wall times around submissions).
///
/// # Errors
/// As the CPU trainer, plus: no GPU adapter, an unsupported loss (see [`GpuLoss::check`]), or a
/// scene or image larger than the adapter can bind.
pub fn train(
    dataset: &Dataset,
    init: Option<Splats>,
    cfg: &TrainConfig,
    loss: &GpuLoss,
    progress: &mut dyn FnMut(&Progress),
) -> Result<(Splats, TrainReport)> {
    loss.check()?;
    let gpu = gpu_or_error()?;
    train_on(&gpu, dataset, init, cfg, loss, progress)
}

/// [`train`] on a given device.
pub fn train_on(
    gpu: &Gpu,
    dataset: &Dataset,
    init: Option<Splats>,
    cfg: &TrainConfig,
    loss: &GpuLoss,
    progress: &mut dyn FnMut(&Progress),
) -> Result<(Splats, TrainReport)> {
    train_with(gpu, dataset, init, cfg, loss, None, progress, &RunOptions::default())
}

/// [`train_on`] under `D + λ·R` when `rate` is given — the GPU twin of the CPU trainer with a
/// [`RateTerm`] (straight-through quantised renders, `w·R` and its gradient, learned steps from
/// the term's start iteration on; the report's `rate` says what it learned) — and with `run`'s
/// checkpoints, resume and live report ([`crate::train::train_with`]'s, in the same checkpoint
/// format; a GPU resume continues the run but is not bit-exact, as GPU training is not).
///
/// # Errors
/// As [`train`]; also a checkpoint that does not match the run, checkpoints with a rate term
/// (input errors), and an interrupted run (failure naming the checkpoint to resume from).
#[allow(clippy::too_many_arguments)]
pub fn train_with(
    gpu: &Gpu,
    dataset: &Dataset,
    init: Option<Splats>,
    cfg: &TrainConfig,
    loss: &GpuLoss,
    rate: Option<RateTerm>,
    progress: &mut dyn FnMut(&Progress),
    run: &RunOptions,
) -> Result<(Splats, TrainReport)> {
    loss.check()?;
    let super::RunStart { train_frames, test_frames, mut rng, extent, mut params, mut degree, sched } =
        super::RunStart::new(dataset, init, cfg, rate.is_some(), run)?;
    let max_degree = cfg.sh_degree_max.min(3);
    // The same run identity as the CPU trainer's (`ImageLoss::name`), so either resumes the other.
    let print = super::fingerprint(cfg, dataset, loss.name());
    let mut order: Vec<usize> = Vec::new();
    let mut first = 1;
    let mut train_seconds = 0.0;
    let mut resumed = None;
    if let Some(dir) = &run.resume {
        let st = super::resume_state(dir, &print, cfg.iters, train_frames.len())?;
        first = st.iteration as usize + 1;
        params = st.params.clone().into_splats();
        rng = Rng::from_state(st.rng);
        order = st.order.iter().map(|&o| o as usize).collect();
        degree = st.degree.min(max_degree);
        train_seconds = st.train_seconds;
        resumed = Some(st);
    }
    let mut session = Session::new(gpu, &params)?;
    if let Some(term) = rate {
        session.set_rate(term);
    }
    let mut tally = Tally::new(session.scene.stride, first);
    let mut peak = params.len();
    if let Some(st) = resumed {
        session.replace_scene(&params, &st.adam_m.into_splats(), &st.adam_v.into_splats())?;
        session.step = st.adam_step;
        let stats: Vec<f32> = (0..params.len()).flat_map(|i| [st.grad_accum[i], st.count[i] as f32, st.max_radius[i]]).collect();
        session.upload_stats(&stats);
        peak = st.peak as usize;
        tally.points = st.points.into_iter().map(ReportPoint::from).collect();
        tally.stages = st.stages;
        (tally.loss_sum, tally.loss_n) = (st.loss_sum, st.loss_n as usize);
    }
    drop(params);
    if run.catch_interrupt && run.checkpoint.is_some() {
        checkpoint::catch_interrupt();
    }
    let (mut last_checkpoint, mut last_report) = (Instant::now(), Instant::now());
    // Training images: uploaded once when the dataset holds them in memory; when they exceed its
    // image budget (read on demand), one buffer is rewritten with each iteration's view.
    let streamed = train_frames.iter().any(|f| f.image.is_streamed());
    let targets: Vec<wgpu::Buffer> = if streamed {
        vec![gpu.storage("target", train_frames.iter().map(|f| f.image.bytes()).max().unwrap_or(0))]
    } else {
        train_frames
            .iter()
            .map(|f: &&Frame| Ok(gpu.storage_init("target", bytemuck::cast_slice(&f.image.get()?.data))))
            .collect::<Result<_>>()?
    };
    // The WD stage, one per image size (laid out on first use); reference statistics are cached
    // by training-view index, so a streamed target works as well.
    let wd_config = (loss.kind != LossKind::L1ssim).then(|| loss.wd_config(loss.kind, cfg.iters));
    let mut wd_stages: Vec<wd::WdStage> = Vec::new();
    let log_every = (cfg.iters / 500).max(1);
    let mut n = session.scene.n;
    let report = |points: Vec<ReportPoint>, n: usize, train_seconds: f64, stages: StageTimes| TrainReport {
        backend: "gpu",
        loss: loss.name().to_string(),
        config: cfg.clone(),
        schedule: sched,
        extent,
        points,
        gaussians: n,
        train_seconds,
        test_views: test_frames.len(),
        test_psnr: None,
        test_ssim: None,
        stages,
        rate: None,
        truncated_frames: 0,
    };

    for it in first..=cfg.iters {
        let t_iter = Instant::now();
        if it % sched.sh_up_every == 0 && degree < max_degree {
            degree += 1;
        }
        if order.is_empty() {
            order = (0..train_frames.len()).collect();
            rng.shuffle(&mut order);
        }
        let fi = order.pop().unwrap();
        let frame = train_frames[fi];
        // The whole iteration is one submission; nothing waits for the GPU.
        session.begin_rate(it)?;
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        session.project(&mut enc, &frame.camera, dataset.background, degree)?;
        session.rasterize(&mut enc, &frame.camera)?;
        let target = if streamed {
            gpu.queue.write_buffer(&targets[0], 0, bytemuck::cast_slice(&frame.image.get()?.data));
            &targets[0]
        } else {
            &targets[fi]
        };
        session.loss(&mut enc, target, loss.ssim_weight);
        if let Some(wc) = wd_config {
            let (w, h) = (frame.camera.width, frame.camera.height);
            let k = match wd_stages.iter().position(|st| (st.width, st.height) == (w, h)) {
                Some(k) => k,
                None => {
                    wd_stages.push(wd::WdStage::new(gpu, wc, w, h)?);
                    wd_stages.len() - 1
                }
            };
            wd_stages[k].record(&session, &mut enc, fi, target, !wdr::in_warmup(it, wc.warmup))?;
        }
        let stats_on = cfg.densify && it < sched.densify_until;
        session.backward(&mut enc, &frame.camera, stats_on);
        // One rate per record section; the three SH rest bands share theirs.
        let lr = [Group::Position, Group::Scale, Group::Rotation, Group::Opacity, Group::ShDc, Group::Sh1]
            .map(|g| learning_rate(g, it, cfg, extent));
        session.adam(&mut enc, lr);
        session.submit(enc);
        let t_dens = Instant::now();

        // The scalars (loss, pair counts, non-finite flags, stage times) every READ_EVERY
        // iterations, and before an evaluation or a densification step (which read the scene
        // back anyway). The wait is for the GPU's queued iterations: training time (in their
        // stage timestamps), neither evaluation nor densification time.
        let eval_now = cfg.eval_interval > 0 && it % cfg.eval_interval == 0 && it != cfg.iters;
        let densify_now = cfg.densify && sched.densifies(it);
        let t_read = Instant::now();
        if eval_now || densify_now || it % READ_EVERY == 0 {
            tally.absorb(session.read_scalars()?)?;
        }
        let read_seconds = t_read.elapsed().as_secs_f64();
        // Held-out evaluation before densification (as the CPU trainer); not training time.
        let t_eval = Instant::now();
        // The rate term's steps and estimate are read with the evaluations (the encoder's series).
        let rate_bits = match session.rate.as_mut() {
            Some(r) if eval_now && r.on_at(it) => Some(r.read(gpu)?.bits),
            _ => None,
        };
        let test_psnr = if eval_now && !test_frames.is_empty() {
            let params = session.download_params()?;
            held_out(session.rate.as_mut().and_then(|r| r.term.render_params(&params, it)), &params, &test_frames, dataset.background)?
                .map(|e| e.0)
        } else {
            None
        };
        let eval_seconds = t_eval.elapsed().as_secs_f64();
        if cfg.densify {
            if densify_now {
                let (mut p, m, v) = session.download()?;
                let raw = session.download_stats()?;
                let stats = DensifyStats {
                    grad_accum: raw.chunks_exact(3).map(|s| s[0]).collect(),
                    count: raw.chunks_exact(3).map(|s| s[1] as u32).collect(),
                    max_radius: raw.chunks_exact(3).map(|s| s[2]).collect(),
                };
                let mut adam = Adam { m, v, rule: AdamRule { step: session.step, ..AdamRule::default() } };
                super::densify_step(&mut p, &mut adam, &stats, cfg, &sched, it, extent, peak, &mut rng)?;
                session.replace_scene(&p, &adam.m, &adam.v)?;
                n = p.len();
            }
            if sched.resets_opacity(it, dataset.background == [1.0; 3]) {
                session.reset_opacity(0.01);
            }
        }
        peak = peak.max(n);
        tally.stages.densify += t_dens.elapsed().as_secs_f64() - eval_seconds - read_seconds;
        train_seconds += t_iter.elapsed().as_secs_f64() - eval_seconds;

        // The point's mean loss is filled in when its iteration's scalars arrive.
        if it % log_every == 0 || eval_now || it == cfg.iters {
            tally.waiting.push_back(ReportPoint { iteration: it, seconds: train_seconds, loss: f64::NAN, gaussians: n, test_psnr });
            tally.settle();
        }
        let rate_bits = rate_bits.or(tally.last_bits);
        progress(&Progress { iteration: it, iters: cfg.iters, loss: tally.last_loss, gaussians: n, test_psnr, rate_bits });

        // Checkpoint (periodic, or stopping), then the live report: both after reading the
        // scalars, so that the record is complete up to this iteration.
        let (write, stop) = super::checkpoint_now(run, it, cfg.iters, last_checkpoint);
        let write = write && run.checkpoint.is_some();
        let report_due = run.report.is_some()
            && (write || stop || test_psnr.is_some() || last_report.elapsed().as_secs_f64() >= super::LIVE_REPORT_SECONDS);
        if write || report_due {
            tally.absorb(session.read_scalars()?)?;
        }
        if let Some(dir) = run.checkpoint.as_ref().filter(|_| write) {
            let (p, m, v) = session.download()?;
            let raw = session.download_stats()?;
            let st = checkpoint::State {
                fingerprint: print.clone(),
                iteration: it as u64,
                params: (&p).into(),
                adam_m: (&m).into(),
                adam_v: (&v).into(),
                adam_step: session.step,
                rng: rng.state(),
                order: order.iter().map(|&o| o as u64).collect(),
                degree,
                peak: peak as u64,
                grad_accum: raw.chunks_exact(3).map(|s| s[0]).collect(),
                count: raw.chunks_exact(3).map(|s| s[1] as u32).collect(),
                max_radius: raw.chunks_exact(3).map(|s| s[2]).collect(),
                points: tally.points.iter().map(checkpoint::PointData::from).collect(),
                stages: tally.stages,
                loss_sum: tally.loss_sum + tally.arrived.iter().map(|a| a.1).sum::<f64>(),
                loss_n: (tally.loss_n + tally.arrived.len()) as u64,
                train_seconds,
            };
            checkpoint::save(dir, &st)?;
            last_checkpoint = Instant::now();
        }
        if let Some(r) = run.report.as_ref().filter(|_| report_due) {
            super::write_report(r, &report(tally.points.clone(), n, train_seconds, tally.stages))?;
            last_report = Instant::now();
        }
        if stop {
            return Err(super::interrupted_error(run, it, cfg.iters));
        }
    }
    // The last iterations' scalars.
    let t_end = Instant::now();
    tally.absorb(session.read_scalars()?)?;
    tally.settle();
    let params = session.download_params()?;
    let rate = match session.rate.as_mut() {
        Some(r) if r.started => {
            r.read(gpu)?;
            r.term.outcome()
        }
        Some(r) => r.term.outcome(),
        None => None,
    };
    train_seconds += t_end.elapsed().as_secs_f64();
    gpu.check()?;
    let mut points = tally.points;
    let final_eval =
        held_out(session.rate.as_mut().and_then(|r| r.term.render_params(&params, cfg.iters)), &params, &test_frames, dataset.background)?;
    if let (Some(last), Some((p, _))) = (points.last_mut(), final_eval) {
        last.test_psnr = Some(p);
    }
    let report = TrainReport {
        test_psnr: final_eval.map(|e| e.0),
        test_ssim: final_eval.map(|e| e.1),
        rate,
        truncated_frames: session.truncated,
        ..report(points, params.len(), train_seconds, tally.stages)
    };
    Ok((params, report))
}

/// Iterations between two reads of the per-iteration scalars (at most [`session::RING`]).
pub const READ_EVERY: usize = 32;

/// The host's account of the scalars that arrive every few iterations: the losses not yet
/// assigned to a report point, the points waiting for their losses, stage times.
struct Tally {
    stride: usize,
    /// The iteration the next arriving scalars belong to.
    next: usize,
    /// Losses of iterations since the last completed point.
    loss_sum: f64,
    loss_n: usize,
    /// Points whose iteration's scalars have not arrived yet (loss NaN).
    waiting: std::collections::VecDeque<ReportPoint>,
    /// Arrived (iteration, loss) not yet summed into a point.
    arrived: std::collections::VecDeque<(usize, f64)>,
    points: Vec<ReportPoint>,
    last_loss: f64,
    last_bits: Option<f64>,
    stages: StageTimes,
}

impl Tally {
    fn new(stride: usize, first: usize) -> Self {
        Tally {
            stride,
            next: first,
            loss_sum: 0.0,
            loss_n: 0,
            waiting: Default::default(),
            arrived: Default::default(),
            points: Vec::new(),
            last_loss: f64::NAN,
            last_bits: None,
            stages: StageTimes::default(),
        }
    }

    /// Takes the scalars of the next iterations: the first non-finite loss or flag is the
    /// divergence error of the CPU trainer (named at the iteration whose loss shows it, else at
    /// the last one read: the flags are read every [`READ_EVERY`] iterations).
    fn absorb(&mut self, sc: session::Scalars) -> Result<()> {
        let last = self.next + sc.iters.len().saturating_sub(1);
        let first_bad_loss = sc.iters.iter().position(|s| !s.loss.is_finite()).map(|j| self.next + j);
        if sc.bad_grad != u32::MAX || sc.bad_value != u32::MAX {
            let (what, idx) = if sc.bad_grad != u32::MAX { ("gradient", sc.bad_grad) } else { ("value", sc.bad_value) };
            let it = first_bad_loss.unwrap_or(last);
            return Err(non_finite_error(what, it, idx as usize / self.stride, group_of_offset(idx as usize % self.stride)));
        }
        if let Some(it) = first_bad_loss {
            let l = sc.iters[it - self.next].loss;
            return Err(Error::Failure(format!("training diverged at iteration {it}: loss is {l}")));
        }
        for s in sc.iters {
            if let Some(t) = s.stage_seconds {
                let st = &mut self.stages;
                st.project += t[0];
                st.sort += t[1];
                st.rasterize += t[2];
                // The loss stage: L1+SSIM and, with a WD loss, the WD stage (0 without one).
                st.loss += t[3] + t[6];
                st.backward += t[4];
                st.optimiser += t[5];
            }
            self.last_loss = s.loss as f64;
            self.last_bits = s.bits.map(f64::from);
            self.arrived.push_back((self.next, s.loss as f64));
            self.next += 1;
        }
        self.settle();
        Ok(())
    }

    /// Completes the waiting points whose losses have all arrived.
    fn settle(&mut self) {
        while let Some(p) = self.waiting.front() {
            if self.next <= p.iteration {
                break;
            }
            while let Some(&(i, l)) = self.arrived.front() {
                if i > p.iteration {
                    break;
                }
                self.loss_sum += l;
                self.loss_n += 1;
                self.arrived.pop_front();
            }
            let mut p = self.waiting.pop_front().expect("a waiting point");
            p.loss = self.loss_sum / self.loss_n.max(1) as f64;
            (self.loss_sum, self.loss_n) = (0.0, 0);
            self.points.push(p);
        }
    }
}

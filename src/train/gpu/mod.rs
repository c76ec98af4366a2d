//! GPU trainer (wgpu): the whole training iteration on the GPU, with the CPU trainer
//! ([`crate::train::train`]) as its oracle: same renderer conventions, schedule, learning rates,
//! Adam, densification rules and report.
//!
//! Per iteration: projection + SH colour, tile-count scan (the decoder's kernels), then one
//! read-back of a few scalars (the number of tile/Gaussian pairs, which sizes the sort; the
//! previous iteration's loss, non-finite flags and stage timestamps); keys, radix sort, tile
//! ranges (decoder), the rasterizer saving final transmittance and list end per pixel, L1 + SSIM
//! loss forward and backward, rasterizer backward, projection / covariance / SH backward with the
//! densification statistics, and Adam (shaders/train_*.wgsl). Training images are uploaded once.
//! Densification reads the scene, moments and statistics back once per densify step and runs the
//! CPU trainer's [`densify::densify_and_prune`] on them (the same rules, the same random numbers).
//!
//! Not bit-exact with the CPU trainer: gradients are summed with float atomics in whatever order
//! the GPU runs them. Not supported yet (refused with an input error): the WD / WD-R losses and
//! the rate term.

mod context;
pub mod session;

pub use context::{hardware_adapter_available, Gpu};
pub use session::Session;

use super::adam::Adam;
use super::densify::DensifyStats;
use super::{init, learning_rate, non_finite_error, Progress, ReportPoint, Schedule, StageTimes, TrainConfig, TrainReport};
use crate::io::{Dataset, Frame, Split};
use crate::loss::LossKind;
use crate::metrics::view::mean_psnr_ssim;
use crate::optim::AdamRule;
use crate::rate::group::Group;
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
}

impl Default for GpuLoss {
    fn default() -> Self {
        GpuLoss { kind: LossKind::L1ssim, ssim_weight: 0.2 }
    }
}

impl From<LossKind> for GpuLoss {
    fn from(kind: LossKind) -> Self {
        GpuLoss { kind, ..Default::default() }
    }
}

impl GpuLoss {
    /// The input error for a loss the GPU trainer does not have.
    pub fn check(&self) -> Result<()> {
        match self.kind {
            LossKind::L1ssim => Ok(()),
            LossKind::Wd | LossKind::Wdr => Err(Error::Input(format!(
                "GPU training supports only --loss l1ssim; the Wasserstein-distortion losses (wd, wdr) run on the CPU backend (--backend cpu), got {:?}",
                self.kind
            ))),
        }
    }
}

/// The input error for a rate term (λ·R, learned quantisation steps), which the GPU trainer does
/// not have yet: `encode` with a rate objective must use the CPU backend.
pub fn rate_unsupported() -> Error {
    Error::Input("GPU training does not support the rate term (λ·R, learned quantisation steps) yet; use --backend cpu".into())
}

fn gpu_or_error() -> Result<Gpu> {
    Gpu::new()?.ok_or_else(|| Error::Input("GPU training: no GPU adapter available (install a Vulkan driver, or use --backend cpu)".into()))
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
    let sc = s.project(cam, opts.background, opts.max_sh_degree)?;
    let mut enc = gpu.device.create_command_encoder(&Default::default());
    s.rasterize(&mut enc, cam, sc.pairs)?;
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
    let (w, h) = (rendered.width, rendered.height);
    // A one-Gaussian session only to own the image buffers.
    let mut one = Splats::new(0);
    one.push([0.0; 3], [0.0; 3], [1.0, 0.0, 0.0, 0.0], 0.0, [0.0; 3], &[]);
    let mut s = Session::new(gpu, &one)?;
    let cam = Camera::new(w, h, w as f32, w as f32, glam::Mat3::IDENTITY, glam::Vec3::new(0.0, 0.0, -1e6));
    let mut enc = gpu.device.create_command_encoder(&Default::default());
    s.rasterize(&mut enc, &cam, 0)?;
    gpu.queue.submit([enc.finish()]);
    let img = s.img.as_ref().unwrap();
    gpu.queue.write_buffer(&img.image, 0, bytemuck::cast_slice(&rendered.data));
    let tgt = gpu.storage_init("target", bytemuck::cast_slice(&target.data));
    let mut enc = gpu.device.create_command_encoder(&Default::default());
    s.loss(&mut enc, &tgt, ssim_weight);
    gpu.queue.submit([enc.finish()]);
    let dl = s.read_dl()?;
    let l = s.read_loss(0)?;
    gpu.check()?;
    Ok((l as f64, dl))
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
/// report as [`crate::train::train`] (the report's `loss` is `"l1ssim"`, its stage times are GPU
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
    loss.check()?;
    let train_frames = dataset.split(Split::Train);
    let test_frames = dataset.split(Split::Test);
    if train_frames.is_empty() {
        return Err(Error::Input("dataset has no training views".into()));
    }
    let mut rng = Rng::new(cfg.seed);
    let extent = init::camera_extent(dataset);
    let max_degree = cfg.sh_degree_max.min(3);
    let (params, mut degree) = match init {
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
    let sched = Schedule::for_iters(cfg.iters);
    let mut session = Session::new(gpu, &params)?;
    drop(params);
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
    let mut order: Vec<usize> = Vec::new();
    let mut points = Vec::new();
    let mut stages = StageTimes::default();
    let (mut loss_sum, mut loss_n) = (0.0f64, 0usize);
    let mut train_seconds = 0.0;
    let log_every = (cfg.iters / 500).max(1);
    let mut last_loss = f64::NAN;
    let mut pending: Option<ReportPoint> = None;
    let mut n = session.scene.n;
    let mut peak = n;
    let stride = session.scene.stride;

    // Scalars of iteration `it - 1` arrive with iteration `it`'s projection.
    let account = |sc: &session::Scalars, it: usize, stages: &mut StageTimes| -> Result<f64> {
        if sc.bad_grad != u32::MAX || sc.bad_value != u32::MAX {
            let (what, idx) = if sc.bad_grad != u32::MAX { ("gradient", sc.bad_grad) } else { ("value", sc.bad_value) };
            return Err(non_finite_error(what, it, idx as usize / stride, group_of_offset(idx as usize % stride)));
        }
        if let Some(t) = sc.stage_seconds {
            stages.project += t[0];
            stages.sort += t[1];
            stages.rasterize += t[2];
            stages.loss += t[3];
            stages.backward += t[4];
            stages.optimiser += t[5];
        }
        let l = sc.loss as f64;
        if !l.is_finite() {
            return Err(Error::Failure(format!("training diverged at iteration {it}: loss is {l}")));
        }
        Ok(l)
    };

    for it in 1..=cfg.iters {
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
        let t0 = Instant::now();
        let sc = session.project(&frame.camera, dataset.background, degree)?;
        let t_a = t0.elapsed().as_secs_f64();
        if it > 1 {
            last_loss = account(&sc, it - 1, &mut stages)?;
            loss_sum += last_loss;
            loss_n += 1;
            if let Some(mut p) = pending.take() {
                p.loss = loss_sum / loss_n as f64;
                points.push(p);
                (loss_sum, loss_n) = (0.0, 0);
            }
        }
        let t1 = Instant::now();
        let mut enc = gpu.device.create_command_encoder(&Default::default());
        session.rasterize(&mut enc, &frame.camera, sc.pairs)?;
        let target = if streamed {
            gpu.queue.write_buffer(&targets[0], 0, bytemuck::cast_slice(&frame.image.get()?.data));
            &targets[0]
        } else {
            &targets[fi]
        };
        session.loss(&mut enc, target, loss.ssim_weight);
        let stats_on = cfg.densify && it < sched.densify_until;
        session.backward(&mut enc, &frame.camera, stats_on);
        // One rate per record section; the three SH rest bands share theirs.
        let lr = [Group::Position, Group::Scale, Group::Rotation, Group::Opacity, Group::ShDc, Group::Sh1]
            .map(|g| learning_rate(g, it, cfg, extent));
        session.adam(&mut enc, lr);
        session.submit(enc);
        if sc.stage_seconds.is_none() && !gpu.timestamps {
            // No timestamps: wall time around the submissions (the second includes the wait).
            gpu.device.poll(wgpu::PollType::wait_indefinitely()).map_err(|e| Error::Failure(format!("GPU error: {e}")))?;
            stages.project += t_a;
            stages.rasterize += t1.elapsed().as_secs_f64();
        }
        let t_dens = Instant::now();

        // Held-out evaluation before densification (as the CPU trainer); not training time.
        let eval_now = cfg.eval_interval > 0 && it % cfg.eval_interval == 0 && it != cfg.iters;
        let t_eval = Instant::now();
        let test_psnr = if eval_now && !test_frames.is_empty() {
            mean_psnr_ssim(&session.download_params()?, &test_frames, dataset.background)?.map(|e| e.0)
        } else {
            None
        };
        let eval_seconds = t_eval.elapsed().as_secs_f64();
        if cfg.densify {
            if sched.densifies(it) {
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
        stages.densify += t_dens.elapsed().as_secs_f64() - eval_seconds;
        train_seconds += t_iter.elapsed().as_secs_f64() - eval_seconds;

        // The point's mean loss is completed when this iteration's loss arrives (next iteration).
        if it % log_every == 0 || eval_now || it == cfg.iters {
            pending = Some(ReportPoint { iteration: it, seconds: train_seconds, loss: f64::NAN, gaussians: n, test_psnr });
        }
        progress(&Progress { iteration: it, iters: cfg.iters, loss: last_loss, gaussians: n, test_psnr, rate_bits: None });
    }
    // The last iteration's scalars.
    let t_end = Instant::now();
    let sc = session.project(&train_frames[0].camera, dataset.background, degree)?;
    let l = account(&sc, cfg.iters, &mut stages)?;
    if let Some(mut p) = pending.take() {
        p.loss = (loss_sum + l) / (loss_n + 1) as f64;
        points.push(p);
    }
    let params = session.download_params()?;
    train_seconds += t_end.elapsed().as_secs_f64();
    gpu.check()?;
    let final_eval = mean_psnr_ssim(&params, &test_frames, dataset.background)?;
    if let (Some(last), Some((p, _))) = (points.last_mut(), final_eval) {
        last.test_psnr = Some(p);
    }
    let report = TrainReport {
        backend: "gpu",
        loss: "l1ssim".to_string(),
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
        rate: None,
    };
    Ok((params, report))
}

//! The training-backend seam: [`Backend`] (what `--backend cpu|gpu|auto` picks), the
//! [`TrainBackend`] trait every trainer implements, the [`TrainJob`] it is handed and
//! [`CpuBackend`], today's CPU trainer (`crate::train::train`).
//!
//! The GPU trainer (`crate::train::gpu`, feature `gpu`) plugs in as `GpuBackend`, returned by
//! `gpu_backend` below; see docs/codec.md ("The training backend").

use gscodec_decoder::Splats;

use crate::io::Dataset;
use crate::loss::{FeatureSpec, ImageLoss, LossArgs, LossKind};
use crate::rate::term::RateTerm;
use crate::rate::{Lambda, Steps};
use crate::train::{Progress, RunOptions, TrainConfig, TrainReport};
use crate::{Error, Result};

/// Which trainer runs `train`, `encode` and `sweep`.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq, Default, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Backend {
    /// The CPU trainer (always available).
    Cpu,
    /// The wgpu trainer (feature `gpu`, and a GPU adapter); refused otherwise.
    Gpu,
    /// The GPU trainer when a hardware (not software) adapter exists, else the CPU trainer.
    #[default]
    Auto,
}

impl Backend {
    /// The trainer this choice stands for on this machine.
    ///
    /// # Errors
    /// [`Error::Input`] (exit 2) for `Gpu` when this build or machine has no GPU trainer.
    pub fn resolve(self) -> Result<Box<dyn TrainBackend>> {
        match self {
            Backend::Cpu => Ok(Box::new(CpuBackend)),
            Backend::Gpu => {
                gpu_backend(false).ok_or_else(|| Error::Input("--backend gpu: GPU training not available in this build".into()))
            }
            Backend::Auto => Ok(gpu_backend(true).unwrap_or_else(|| Box::new(CpuBackend))),
        }
    }
}

/// The GPU trainer, if this build has one and (with `auto`) a hardware adapter exists. `auto`
/// runs on the CPU the jobs the GPU trainer cannot (WD in VGG-16 features).
#[cfg(feature = "gpu")]
fn gpu_backend(auto: bool) -> Option<Box<dyn TrainBackend>> {
    // `auto` looks for a hardware adapter only when a job the GPU trainer can run arrives
    // (probing prints driver warnings on some machines, e.g. Mesa's lavapipe without
    // XDG_RUNTIME_DIR, and costs time).
    Some(Box::new(GpuBackend { fall_back_to_cpu: auto }))
}

/// Without the `gpu` feature there is no GPU trainer.
#[cfg(not(feature = "gpu"))]
fn gpu_backend(_auto: bool) -> Option<Box<dyn TrainBackend>> {
    None
}

/// The wgpu trainer, `crate::train::gpu::train`.
#[cfg(feature = "gpu")]
#[derive(Debug, Clone, Copy)]
struct GpuBackend {
    /// Run what the GPU trainer refuses on the CPU instead (`--backend auto`).
    fall_back_to_cpu: bool,
}

#[cfg(feature = "gpu")]
impl TrainBackend for GpuBackend {
    fn name(&self) -> &'static str {
        "gpu"
    }

    fn train(&mut self, job: TrainJob<'_>, progress: &mut dyn FnMut(&Progress)) -> Result<(Splats, TrainReport)> {
        let loss = crate::train::gpu::GpuLoss::new(job.loss.kind, &job.loss.features, job.loss.wd_gamma, job.loss.wd_sigma)
            .with_warmup(job.loss.wd_warmup);
        let refused = loss.check().err();
        match refused {
            Some(_) if self.fall_back_to_cpu => CpuBackend.train(job, progress),
            Some(e) => Err(e),
            None if self.fall_back_to_cpu && !crate::train::gpu::hardware_adapter_available() => CpuBackend.train(job, progress),
            None => {
                let gpu = crate::train::gpu::gpu_or_error()?;
                let rate = job.rate.map(RateObjective::term);
                crate::train::gpu::train_with(&gpu, job.dataset, job.init, job.config, &loss, rate, progress, job.run)
            }
        }
    }
}

/// The image loss a backend trains with, as a description (kind, features, γ, σ), so that a GPU
/// backend can build its own kernels; [`LossSpec::build`] makes the CPU implementation.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct LossSpec {
    /// l1ssim, wd or wdr.
    pub kind: LossKind,
    /// WD's feature space.
    pub features: FeatureSpec,
    /// γ of WD / WD-R (None: the loss's default).
    pub wd_gamma: Option<f64>,
    /// Uniform pooling scale σ of WD / WD-R (None: [`crate::loss::wd::DEFAULT_SIGMA`]).
    pub wd_sigma: Option<f64>,
    /// Share of the iterations trained with L1-SSIM before WD / WD-R (None:
    /// [`crate::loss::wdr::WARMUP_FRACTION`]).
    pub wd_warmup: Option<f64>,
}

impl LossSpec {
    /// The loss `--loss`/`--features`/`--wd-gamma`/`--wd-sigma`/`--wd-warmup` describe,
    /// `default` when `--loss` is absent.
    pub fn from_args(args: &LossArgs, default: LossKind) -> LossSpec {
        LossSpec {
            kind: args.loss.unwrap_or(default),
            features: args.features.clone(),
            wd_gamma: args.wd_gamma,
            wd_sigma: args.wd_sigma,
            wd_warmup: args.wd_warmup,
        }
    }

    /// WD's σ for reports: the value trained with for `wd` / `wdr`, None for `l1ssim`.
    pub fn reported_sigma(&self) -> Option<f64> {
        (self.kind != LossKind::L1ssim).then(|| self.wd_sigma.unwrap_or(crate::loss::wd::DEFAULT_SIGMA))
    }

    /// WD's feature space for reports (`pyramid`, …) for `wd` / `wdr`, None for `l1ssim`.
    pub fn reported_features(&self) -> Option<String> {
        (self.kind != LossKind::L1ssim).then(|| self.features.to_string())
    }

    /// The same loss with the warm-up share `share` where `--wd-warmup` was not given (`wd` /
    /// `wdr`; `l1ssim` has none).
    pub fn with_default_warmup(self, share: f64) -> LossSpec {
        let wd_warmup = self.wd_warmup.or((self.kind != LossKind::L1ssim).then_some(share));
        LossSpec { wd_warmup, ..self }
    }

    /// WD's warm-up share for reports: the value trained with for `wd` / `wdr`, None for `l1ssim`.
    pub fn reported_warmup(&self) -> Option<f64> {
        (self.kind != LossKind::L1ssim).then(|| self.wd_warmup.unwrap_or(crate::loss::wdr::WARMUP_FRACTION))
    }

    /// Short name (`l1ssim`, `wd`, `wdr`).
    pub fn name(&self) -> &'static str {
        self.kind.name()
    }

    /// The CPU loss for a run of `iters` iterations.
    ///
    /// # Errors
    /// Unreadable VGG weights, a γ that is not a positive number or a σ out of range (exit 2).
    pub fn build(&self, iters: usize) -> Result<Box<dyn ImageLoss>> {
        let args = LossArgs {
            loss: Some(self.kind),
            features: self.features.clone(),
            wd_gamma: self.wd_gamma,
            wd_sigma: self.wd_sigma,
            wd_warmup: self.wd_warmup,
        };
        crate::loss::build_loss(&args, iters, self.kind)
    }
}

/// The rate objective of a training run: `D + λ·R` with straight-through quantisation.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RateObjective {
    /// The trade-off.
    pub lambda: Lambda,
    /// Starting quantisation steps.
    pub steps: Steps,
    /// Pruning opacity the term charges against (see `RateTerm::min_opacity`).
    pub min_opacity: f32,
    /// Learn the steps (per group) under the objective instead of keeping them.
    pub learn_steps: bool,
    /// Iterations before this one train without the term.
    pub start_iter: usize,
}

impl RateObjective {
    /// The rate term that trains under this objective (both backends run its maths).
    pub fn term(self) -> RateTerm {
        let mut term = RateTerm::new(self.lambda, self.steps, self.min_opacity);
        term.learn_steps = self.learn_steps;
        term.start_iter = self.start_iter;
        term
    }
}

/// One training run, as handed to a [`TrainBackend`].
pub struct TrainJob<'a> {
    /// Training (and held-out) views.
    pub dataset: &'a Dataset,
    /// Starting scene (fine-tuning); None: the dataset's points or random points.
    pub init: Option<Splats>,
    /// Iterations, schedule switches, seed.
    pub config: &'a TrainConfig,
    /// The image loss.
    pub loss: &'a LossSpec,
    /// The rate term; None trains the image loss alone.
    pub rate: Option<RateObjective>,
    /// Checkpoints, resume and the live report (`RunOptions::default()`: none).
    pub run: &'a RunOptions,
}

/// A trainer. Both backends use the same [`TrainConfig`] and schedule and return the same
/// result types; the report names the backend ([`TrainReport::backend`]) and, with a rate
/// objective, what it learned ([`TrainReport::rate`]).
pub trait TrainBackend: Send {
    /// `cpu`, `gpu`.
    fn name(&self) -> &'static str;

    /// Trains `job`, calling `progress` once per iteration.
    ///
    /// # Errors
    /// [`Error::Input`] for what the job asks that the backend cannot do, or a bad dataset;
    /// [`Error::Failure`] when training diverges.
    fn train(&mut self, job: TrainJob<'_>, progress: &mut dyn FnMut(&Progress)) -> Result<(Splats, TrainReport)>;
}

/// The CPU trainer, `crate::train::train`.
#[derive(Debug, Clone, Copy, Default)]
pub struct CpuBackend;

impl TrainBackend for CpuBackend {
    fn name(&self) -> &'static str {
        "cpu"
    }

    fn train(&mut self, job: TrainJob<'_>, progress: &mut dyn FnMut(&Progress)) -> Result<(Splats, TrainReport)> {
        let loss = job.loss.build(job.config.iters)?;
        let rd = job.rate.map(|r| Box::new(r.term()) as Box<dyn crate::train::RdTerm>);
        crate::train::train_with(job.dataset, job.init, job.config, loss, rd, progress, job.run)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn backends_resolve_or_refuse_clearly() {
        assert_eq!(Backend::Cpu.resolve().unwrap().name(), "cpu");
    }

    /// Without the `gpu` feature, `gpu` is refused as bad input and `auto` falls back to the CPU.
    #[cfg(not(feature = "gpu"))]
    #[test]
    fn without_the_gpu_feature_gpu_is_refused_and_auto_is_cpu() {
        let e = Backend::Gpu.resolve().err().expect("no GPU trainer");
        assert_eq!(e.exit_code(), 2);
        assert!(e.to_string().contains("GPU training not available"), "{e}");
        assert_eq!(Backend::Auto.resolve().unwrap().name(), "cpu");
    }

    /// With the `gpu` feature, `gpu` trains a rate job on the GPU (any adapter, lavapipe too) and
    /// `auto` sends it there only when a hardware adapter exists.
    #[cfg(feature = "gpu")]
    #[test]
    fn with_the_gpu_feature_rate_jobs_run_on_the_gpu() {
        let scene = crate::sample::scene(40, 2);
        let cams = crate::views::orbit_cameras(&scene, 4, 32, 32, crate::views::UpAxis::NegY.vector());
        let dataset = crate::train::targets::render_targets(&scene, &cams, [0.0; 3]);
        let cfg = TrainConfig { iters: 2, densify: false, eval_interval: 0, ..Default::default() };
        let loss = LossSpec::default();
        let rate =
            RateObjective { lambda: Lambda::DEFAULT, steps: Steps::default(), min_opacity: 1.0 / 255.0, learn_steps: true, start_iter: 0 };
        let run = RunOptions::default();
        let job = || TrainJob { dataset: &dataset, init: Some(scene.clone()), config: &cfg, loss: &loss, rate: Some(rate), run: &run };
        if crate::train::gpu::Gpu::new().unwrap().is_some() {
            let (_, r) = gpu_backend(false).unwrap().train(job(), &mut |_| {}).unwrap();
            assert_eq!(r.backend, "gpu");
            assert!(r.rate.and_then(|o| o.estimated_bits).is_some_and(|b| b > 0.0), "{:?}", r.rate);
        } else {
            crate::testkit::skip("no GPU adapter: only auto's choice is tested");
        }
        let (_, r) = GpuBackend { fall_back_to_cpu: true }.train(job(), &mut |_| {}).unwrap();
        let want = if crate::train::gpu::hardware_adapter_available() { "gpu" } else { "cpu" };
        assert_eq!(r.backend, want);
        assert!(r.rate.is_some());
        // WD-R (built-in features) is a job the GPU trainer runs; WD in VGG-16 features is refused.
        let wdr = LossSpec { kind: LossKind::Wdr, ..LossSpec::default() };
        let vgg = LossSpec { features: FeatureSpec::Vgg16("vgg16.safetensors".into()), ..wdr.clone() };
        let e = gpu_backend(false).unwrap().train(TrainJob { loss: &vgg, rate: None, ..job() }, &mut |_| {}).expect_err("refused");
        assert!(e.exit_code() == 2 && e.to_string().contains("pyramid"), "{e}");
        if crate::train::gpu::Gpu::new().ok().flatten().is_some() {
            let (_, r) = gpu_backend(false).unwrap().train(TrainJob { loss: &wdr, rate: None, ..job() }, &mut |_| {}).unwrap();
            assert_eq!((r.backend, r.loss.as_str()), ("gpu", "wdr"));
        }
    }
}

//! The encoder's front door: [`Encoder`] turns a scene or a posed-image dataset into `.gsc`
//! bytes under `J = D + λ·R`.
//!
//! | item | one job |
//! |---|---|
//! | [`EncoderConfig`] | settings, `with_*` setters, `validate()` → [`InvalidConfig`] |
//! | [`Lambda`] | the trade-off λ, its one unit and every conversion |
//! | [`Encoder`] | RD search, training through a backend, coding, measuring |
//! | [`TrainedScene`], [`Encoder::train_dataset`], [`Encoder::code_dataset`] | a dataset encode in two halves, the training shared by encoders that [`Encoder::trains_like`] |
//! | [`Target`], [`Encoder::encode_scene_to`], [`TargetEvent`] | the smallest file at a PSNR, the best PSNR within a size; each probe as it finishes |
//! | [`EncodeReport`] | what an encode did, typed (`encode --report`, `sweep`) |
//! | [`Backend`], [`TrainBackend`], [`TrainJob`], [`CpuBackend`] | the training-backend seam |
//!
//! ```
//! use gscodec::encoder::{Encoder, EncoderConfig, Lambda};
//! let scene = gscodec::sample::scene(50, 1);
//! let encoder = Encoder::new(EncoderConfig::default().with_lambda(Lambda::new(20.0).unwrap())).unwrap();
//! let out = encoder.encode_scene(&scene, &mut |_| {}).unwrap();
//! assert_eq!(out.bytes.len(), out.report.file_bytes);
//! assert!(out.report.orbit_psnr > 20.0);
//! ```

mod backend;
mod breakdown;
mod config;
mod report;
mod target;

use std::time::Instant;

use rayon::prelude::*;

use gscodec_decoder::render::render;
use gscodec_decoder::{RenderOptions, Splats};

pub use crate::rate::Lambda;
pub use backend::{Backend, CpuBackend, LossSpec, RateObjective, TrainBackend, TrainJob};
pub use breakdown::CodingStage;
pub use config::{
    check_densify_grad_threshold, EncoderConfig, InvalidConfig, Profile, SearchDistortion, DEFAULT_DATASET_ITERS, INIT_RETRAIN_ITERS,
    MAX_ITERS, RETRAIN_DIVISOR, RETRAIN_RATE_WEIGHT,
};
pub use report::{EncodeReport, EncodeStages, SeriesPoint};
pub use target::{Between, Probe, Target, TargetEvent, TargetSearch, MAX_LAMBDA, MAX_TARGET_PSNR};

use crate::io::{Dataset, Split};
use crate::loss::{wdr, LossKind};
use crate::rate::group::Group;
use crate::rate::rd::{RdDistortion, RdViews};
use crate::rate::{self, EncodeConfig, Importance, Steps};
use crate::train::{Progress, RunOptions, TrainConfig, TrainReport};
use crate::views::{orbit_cameras, training_cameras, UpAxis};
use crate::{Error, Result};

/// Orbit views (and their size) [`EncodeReport::orbit_psnr`] is measured on: the views of
/// `eval --reference INPUT --orbit 8`.
pub const ORBIT_VIEWS: usize = 8;
/// Orbit view size, pixels (square).
pub const ORBIT_SIZE: u32 = 256;

/// The result of an encode.
#[derive(Debug, Clone)]
pub struct Encoded {
    /// The `.gsc` file.
    pub bytes: Vec<u8>,
    /// The scene a decoder restores from [`Encoded::bytes`].
    pub decoded: Splats,
    /// What the encode did.
    pub report: EncodeReport,
    /// The encoder's choices that [`Encoded::bytes`] codes with (the RD search's, with the
    /// steps fine-tuning learned).
    pub config: EncodeConfig,
    /// A fine-tuned file's scene as training left it, before coding: coded again with
    /// [`Encoded::config`] it gives the same file. `None` where the file codes the input scene
    /// (no fine-tuning, or the search's own file was kept) or a dataset's.
    pub trained: Option<Splats>,
}

/// A scene trained from a dataset's images, before the RD search ([`Encoder::train_dataset`]).
/// A sweep's points that train alike share one: at a λ and seed, `l1ssim` and `wdr` with WD-R
/// only in retraining differ only after it.
#[derive(Debug, Clone)]
pub struct TrainedScene {
    scene: Splats,
    /// The quantisation steps training learned, where the RD search starts.
    steps: Steps,
    report: TrainReport,
    series: Vec<SeriesPoint>,
    iters: usize,
    /// Wall time of the training, counted into every encode that codes the scene.
    elapsed: std::time::Duration,
    /// The settings that shaped the training (`Encoder::training_settings`).
    settings: EncoderConfig,
}

impl TrainedScene {
    /// The trained scene.
    pub fn scene(&self) -> &Splats {
        &self.scene
    }

    /// Wall time of the training.
    pub fn elapsed(&self) -> std::time::Duration {
        self.elapsed
    }
}

/// An encoder with validated settings.
#[derive(Debug, Clone)]
pub struct Encoder {
    config: EncoderConfig,
}

impl Encoder {
    /// An encoder for `config`.
    ///
    /// # Errors
    /// The config's first setting out of range ([`EncoderConfig::validate`]).
    pub fn new(config: EncoderConfig) -> std::result::Result<Encoder, InvalidConfig> {
        config.validate()?;
        Ok(Encoder { config })
    }

    /// The settings.
    pub fn config(&self) -> &EncoderConfig {
        &self.config
    }

    /// Encodes a trained scene: the RD search on orbit renders of the scene, then (with
    /// `iters` > 0) fine-tuning under `D + λ·R` against 24 renders of itself away from the
    /// orbit views, densification off. `progress` sees every training iteration.
    ///
    /// # Errors
    /// [`Error::Input`] for an invalid scene or a backend that cannot run the job;
    /// [`Error::Failure`] when training diverges.
    pub fn encode_scene(&self, scene: &Splats, progress: &mut dyn FnMut(&Progress)) -> Result<Encoded> {
        let mut trials = rate::rd::Trials::new(scene).map_err(|e| Error::Input(e.to_string()))?;
        self.encode_scene_with(&mut trials, &Orbit::new(scene), progress)
    }

    /// [`Encoder::encode_scene`] of `trials`' scene, reusing (and adding to) the RD search's
    /// evaluated configurations, which do not depend on λ (`--target-psnr`'s probes share them),
    /// and measuring against `orbit`, the orbit views of that scene.
    pub(crate) fn encode_scene_with(
        &self,
        trials: &mut rate::rd::Trials,
        orbit: &Orbit,
        progress: &mut dyn FnMut(&Progress),
    ) -> Result<Encoded> {
        if self.config.profile == Profile::Explicit {
            return self.encode_explicit(trials, orbit, progress);
        }
        // The anchor profile codes what the explicit profile's RD search keeps (pruned, SH
        // bands dropped) on its grid; its own fine-tuning takes `--anchor-iters`, else `--iters`.
        let explicit_iters = if self.config.profile == Profile::Anchor { Some(0) } else { self.config.iters };
        let explicit = Encoder { config: self.config.clone().with_iters(explicit_iters) };
        let e = explicit.encode_explicit(trials, orbit, progress)?;
        self.with_anchors(e, trials.scene(), orbit, None, None)
    }

    /// The explicit result `e` of `scene` replaced by the anchor profile's file where the profile
    /// asks for it: always for [`Profile::Anchor`], when its `J` is lower for [`Profile::Auto`].
    /// The anchors are fine-tuned to `dataset`'s training images, whose held-out views then
    /// measure the file (the series' `coded` point), else to renders of `scene`. For a dataset,
    /// `importance` holds the RD search's views and `scene`'s importance from them
    /// ([`RdViews::importance`]), which prunes; else the scene's own.
    fn with_anchors(
        &self,
        e: Encoded,
        scene: &Splats,
        orbit: &Orbit,
        dataset: Option<&Dataset>,
        importance: Option<(&RdViews, &Importance)>,
    ) -> Result<Encoded> {
        let start = Instant::now();
        let prepared = rate::prepared(scene, &e.config, importance.map(|s| s.1));
        if prepared.is_empty() {
            return Ok(e);
        }
        let sig = importance.map_or_else(|| rate::importance::significance(&prepared), |(v, _)| v.significance(&prepared));
        let d = crate::anchor::AnchorConfig::default();
        let cfg = crate::anchor::AnchorConfig {
            position_bits: Some(e.report.position_bits),
            features: self.config.anchor_features.unwrap_or(d.features),
            hidden: self.config.anchor_hidden.unwrap_or(d.hidden),
            iters: self.config.anchor_iters.or(self.config.iters).unwrap_or(d.iters),
            seed: self.config.seed,
            ..d
        };
        let fit = dataset.map(crate::anchor::FitViews::training_views).transpose()?;
        let a = crate::anchor::encode(&prepared, &sig, &cfg, (scene.len(), scene.sh_degree), fit.as_ref());
        let orbit_psnr = orbit.psnr(&a.decoded);
        let j = |d: &Splats, bytes: usize| orbit.distortion(d) + self.config.lambda.rate_cost(bytes);
        let alternative = (e.bytes.len(), e.report.orbit_psnr);
        // The anchors' fitting counts as training, whichever file is kept.
        let mut stages = e.report.stages;
        stages.train_s += start.elapsed().as_secs_f64();
        stages.total_s += start.elapsed().as_secs_f64();
        if self.config.profile == Profile::Auto && j(&e.decoded, e.bytes.len()) <= j(&a.decoded, a.bytes.len()) {
            let report = EncodeReport { profile: "explicit", anchor: Some(a.report), stages, ..e.report };
            return Ok(Encoded { report, ..e });
        }
        // The series ends with the file written: the anchor file on the held-out views.
        let mut series = e.report.series;
        if let (Some(ds), Some(coded)) = (dataset, series.iter_mut().rev().find(|p| p.trial == report::CODED)) {
            let psnr = crate::metrics::view::mean_psnr_ssim(&a.decoded, &ds.split(Split::Test), ds.background)?.map(|m| m.0);
            *coded = SeriesPoint {
                wall_s: coded.wall_s + start.elapsed().as_secs_f64(),
                estimated_bits: Some(8.0 * a.bytes.len() as f64),
                heldout_psnr: psnr,
                ..coded.clone()
            };
        }
        let report = EncodeReport {
            file_bytes: a.bytes.len(),
            estimated_bytes: a.bytes.len() as f64,
            gaussians: a.decoded.len(),
            sh_degree: a.decoded.sh_degree,
            orbit_psnr,
            stages,
            series,
            profile: "anchor",
            explicit_alternative: Some(alternative),
            anchor: Some(a.report),
            ..e.report
        };
        Ok(Encoded { bytes: a.bytes, decoded: a.decoded, report, config: e.config, trained: None })
    }

    /// [`Encoder::encode_scene_with`] in the explicit profile.
    fn encode_explicit(&self, trials: &mut rate::rd::Trials, orbit: &Orbit, progress: &mut dyn FnMut(&Progress)) -> Result<Encoded> {
        let start = Instant::now();
        let scene = trials.scene();
        let iters = self.config.iters_for(false);
        let mut stages = EncodeStages::default();
        let mut series = Vec::new();
        // The RD search's PSNR is against the input scene's own renders, the error the user
        // cares about, so its trials go into the time series.
        let record = |series: &mut Vec<SeriesPoint>, p: &rate::rd::Trial| {
            series.push(SeriesPoint {
                iteration: p.step,
                trial: p.change.clone(),
                wall_s: start.elapsed().as_secs_f64(),
                estimated_bits: Some(8.0 * p.bytes as f64),
                d: Some(p.d),
                heldout_psnr: Some(p.psnr),
            });
        };
        let search = |trials: &mut rate::rd::Trials, dc_fit: bool, series: &mut Vec<SeriesPoint>| {
            rate::rd::search_with(trials, self.config.lambda, rate::rd::fine_steps(), dc_fit, |p| record(series, p))
                .map(|r| r.0)
                .map_err(|e| Error::Input(e.to_string()))
        };
        let searched = search(trials, true, &mut series)?;
        // Fine-tuning starts from a search without the DC fit: training fits the DC itself, and
        // from the fit's choices (more SH left out) it ended worse (docs/codec.md §30).
        let mut config = if iters > 0 { search(trials, false, &mut series)? } else { searched };
        stages.rd_search_s = start.elapsed().as_secs_f64();
        let mut trained = None;
        let mut train_report = None;
        // Fine-tune what the search chose to code (pruned, SH bands dropped), so that the
        // Gaussians left learn to cover for those pruned. The rate term charges the Gaussians
        // above the opacity where pruning pays at this λ, and coding the result prunes at it
        // (and again by removal error), so training decides which low-opacity Gaussians earn
        // their bits.
        let init = if iters > 0 { rate::prepared(scene, &config, None) } else { Splats::default() };
        if !init.is_empty() {
            let m = rate::rd::pruning_opacity(trials, self.config.lambda, &config).map_err(|e| Error::Input(e.to_string()))?;
            config.min_opacity = config.min_opacity.max(m);
            // Training views avoid the orbit views `orbit_psnr` evaluates on (held out).
            let cams = training_cameras(scene, 8, ORBIT_SIZE, ORBIT_SIZE, UpAxis::NegY.vector());
            let dataset = crate::train::targets::render_targets(scene, &cams, [0.0; 3]);
            // The rates falling over the second half ([`crate::train::FINE_TUNE_ANNEAL`]).
            let cfg = TrainConfig { anneal_to: crate::train::FINE_TUNE_ANNEAL, ..self.fine_tune_config(iters, &init) };
            // A .ply already has its structure: the term runs from the start.
            let (s, r) = self.train(&dataset, Some(init), &cfg, &config, 0, start, &mut series, progress)?;
            config.steps = learned_steps(config.steps, &r);
            // The DC fit for what training did not see: bands the coding leaves out, codebook
            // rows, the importance classes' coarser steps (docs/codec.md §30).
            config.dc_fit = scene.sh_degree > 0;
            config.dc_fit_trained = true;
            stages.train_s = r.train_seconds;
            config = self.retune_tail(&s, RdViews::orbit(&s), config, &mut stages)?.0;
            trained = Some(s);
            train_report = Some(r);
        }
        let Some(trained) = trained else {
            return self.finish(orbit, scene, &searched, iters, start, stages, series, None, None, Some(trials.importance()));
        };
        let tuned = self.finish(orbit, &trained, &config, iters, start, stages, series, train_report, None, None)?;
        // Fine-tuning must pay: where the RD search's own file has the lower J on the orbit
        // views (D at 256², what the report's PSNR measures), that file is the output.
        let plain = self.finish(
            orbit,
            scene,
            &searched,
            0,
            Instant::now(),
            EncodeStages::default(),
            Vec::new(),
            None,
            None,
            Some(trials.importance()),
        )?;
        let j = |e: &Encoded| orbit.distortion(&e.decoded) + self.config.lambda.rate_cost(e.bytes.len());
        if j(&plain) < j(&tuned) {
            let r = tuned.report;
            let report = EncodeReport {
                loss: r.loss,
                iters,
                backend: r.backend,
                stages: r.stages,
                train: r.train,
                series: r.series,
                fine_tuning_kept: Some(false),
                ..plain.report
            };
            return Ok(Encoded { report, ..plain });
        }
        Ok(Encoded { report: EncodeReport { fine_tuning_kept: Some(true), ..tuned.report }, trained: Some(trained), ..tuned })
    }

    /// Trains a scene from a posed-image dataset under `D + λ·R` (the rate term from half way,
    /// after densification), then runs the RD search from the learned steps on the trained
    /// scene and codes it. `progress` sees every training iteration. `wd` / `wdr` with no
    /// warm-up share given train only the retraining ([`EncoderConfig::default_wd_warmup`]).
    ///
    /// # Errors
    /// As [`Encoder::encode_scene`], and [`InvalidConfig::DatasetWithoutTraining`] for `iters` 0.
    pub fn encode_dataset(&self, dataset: &Dataset, progress: &mut dyn FnMut(&Progress)) -> Result<Encoded> {
        let trained = self.train_dataset(dataset, progress)?;
        self.code_dataset(dataset, &trained, progress)
    }

    /// The first half of [`Encoder::encode_dataset`]: trains a scene from `dataset`'s images
    /// under `D + λ·R`, with the rate term from half way, and stops before the RD search.
    /// [`Encoder::code_dataset`] codes it, as often as wanted, with any encoder that
    /// [`Encoder::trains_like`] this one.
    ///
    /// # Errors
    /// As [`Encoder::encode_dataset`].
    pub fn train_dataset(&self, dataset: &Dataset, progress: &mut dyn FnMut(&Progress)) -> Result<TrainedScene> {
        let start = Instant::now();
        let resolved = self.resolved();
        resolved.config.validate_for_dataset()?;
        check_breakdown_views(&resolved.config, dataset)?;
        let run = Encoder { config: resolved.training_settings() };
        let iters = run.config.iters_for(true);
        if run.config.loss != resolved.config.loss {
            // First built for retraining: one that cannot be (VGG weights unreadable) fails now.
            resolved.config.loss.build(iters)?;
        }
        let mut series = Vec::new();
        // Nothing to search before training: training starts from the fixed ladder for λ.
        let ladder = EncodeConfig::for_lambda(run.config.lambda);
        let mut cfg = TrainConfig { iters, seed: run.config.seed, eval_interval: (iters / 10).max(1), ..Default::default() };
        cfg.max_gaussians = run.config.max_gaussians.unwrap_or(cfg.max_gaussians);
        cfg.densify_grad_threshold = run.config.densify_grad_threshold.unwrap_or(cfg.densify_grad_threshold);
        // The rate term starts when densification ends (half way): with it from the start,
        // lego-200 at λ = 4 stalled at 23.7 dB held-out with 9k Gaussians; with the warm-up it
        // reaches 30.6 dB (docs/codec.md).
        let (scene, report) = run.train(dataset, None, &cfg, &ladder, iters / 2, start, &mut series, progress)?;
        let steps = learned_steps(ladder.steps, &report);
        Ok(TrainedScene { scene, steps, report, series, iters, elapsed: start.elapsed(), settings: run.config })
    }

    /// The second half of [`Encoder::encode_dataset`]: the RD search, retraining, coding and
    /// measuring of `trained`. The encode's times count `trained`'s training, as if it had
    /// trained here.
    ///
    /// # Errors
    /// As [`Encoder::encode_dataset`]; [`Error::Failure`] when `trained` was trained with other
    /// settings than this encoder would train with ([`Encoder::trains_like`]).
    pub fn code_dataset(&self, dataset: &Dataset, trained: &TrainedScene, progress: &mut dyn FnMut(&Progress)) -> Result<Encoded> {
        let resolved = self.resolved();
        resolved.config.validate_for_dataset()?;
        check_breakdown_views(&resolved.config, dataset)?;
        if resolved.training_settings() != trained.settings {
            return Err(Error::Failure("code_dataset: the scene was trained with other settings than this encoder trains with".into()));
        }
        resolved.code_trained_scene(dataset, trained, progress)
    }

    /// [`Encoder::code_trained`] of a [`TrainedScene`], whose training time counts into the
    /// encode's, by this (resolved) encoder whatever λ it has: [`Encoder::code_dataset`] after
    /// its check, and each probe of a dataset's target ([`Encoder::encode_dataset_to`]).
    fn code_trained_scene(&self, dataset: &Dataset, trained: &TrainedScene, progress: &mut dyn FnMut(&Progress)) -> Result<Encoded> {
        let TrainedScene { scene, steps, report, series, iters, elapsed, .. } = trained;
        let start = Instant::now().checked_sub(*elapsed).unwrap_or_else(Instant::now);
        self.code_trained(dataset, scene, *steps, Some(report.clone()), *iters, start, series.clone(), progress)
    }

    /// Whether `other` trains the same scene from a dataset's images as this encoder
    /// ([`Encoder::train_dataset`]): the settings differ at most in what acts after that
    /// training (retraining, the search's distortion, the file's options), and in the loss
    /// only where both train the whole run from the images with L1-SSIM (`l1ssim`, or `wd` /
    /// `wdr` whose warm-up is the whole run, the default of a dataset encode that retrains).
    pub fn trains_like(&self, other: &Encoder) -> bool {
        self.resolved().training_settings() == other.resolved().training_settings()
    }

    /// This encoder with the dataset default of the warm-up share applied.
    fn resolved(&self) -> Encoder {
        let loss = self.config.loss.clone().with_default_warmup(self.config.default_wd_warmup(true));
        Encoder { config: self.config.clone().with_loss(loss) }
    }

    /// The settings that shape the training from the images (a resolved encoder's): λ, the
    /// iterations, seed, budget, densification threshold, backend, step learning and the loss,
    /// which is L1-SSIM's when WD never acts in the run. Everything else keeps its default.
    fn training_settings(&self) -> EncoderConfig {
        let c = &self.config;
        let iters = c.iters_for(true);
        // The last iteration decides: the warm-up is iterations 1 to its end.
        let wd_acts = c.loss.reported_warmup().is_some_and(|share| !wdr::in_warmup(iters, wdr::warmup_iters(iters, share)));
        let loss = if wd_acts { c.loss.clone() } else { LossSpec { kind: LossKind::L1ssim, ..LossSpec::default() } };
        EncoderConfig {
            lambda: c.lambda,
            iters: Some(iters),
            learn_steps: c.learn_steps,
            loss,
            backend: c.backend,
            seed: c.seed,
            max_gaussians: c.max_gaussians,
            densify_grad_threshold: c.densify_grad_threshold,
            ..EncoderConfig::default()
        }
    }

    /// Codes `scene`, a scene trained on `dataset` elsewhere (`encode DATASET --init SCENE`: by
    /// the reference 3DGS trainer, gsplat, Brush, or `gscodec train`), as [`Encoder::encode_dataset`]
    /// codes the scene it trains: the RD search measures on the dataset's training cameras,
    /// retraining (`retrain_iters`, default [`INIT_RETRAIN_ITERS`]: as long as a default training) fine-tunes the
    /// Gaussians it keeps to the training images under `D + λ·R`, and the report measures the
    /// held-out views. The scene must be in the dataset's world frame. `iters`, `max_gaussians`
    /// and `densify_grad_threshold`, which shape training from the images, are not used.
    ///
    /// # Errors
    /// As [`Encoder::encode_dataset`], but a scene needs no training.
    pub fn encode_trained(&self, dataset: &Dataset, scene: &Splats, progress: &mut dyn FnMut(&Progress)) -> Result<Encoded> {
        let start = Instant::now();
        self.config.validate()?;
        check_breakdown_views(&self.config, dataset)?;
        let retrain = Some(self.config.retrain_iters_for_init());
        let pinned = Encoder { config: self.config.clone().with_retrain_iters(retrain) };
        pinned.code_trained(dataset, scene, rate::rd::fine_steps(), None, 0, start, Vec::new(), progress)
    }

    /// The part of [`Encoder::encode_dataset`] after training: `trained` (trained `iters`
    /// iterations, reported by `train`, or given) searched from `steps` on the dataset's
    /// training cameras, retrained, coded and measured.
    #[allow(clippy::too_many_arguments)]
    fn code_trained(
        &self,
        dataset: &Dataset,
        trained: &Splats,
        steps: Steps,
        r: Option<TrainReport>,
        iters: usize,
        start: Instant,
        mut series: Vec<SeriesPoint>,
        progress: &mut dyn FnMut(&Progress),
    ) -> Result<Encoded> {
        let mut stages = EncodeStages { train_s: r.as_ref().map_or(0.0, |r| r.train_seconds), ..EncodeStages::default() };
        // RD choices on the trained scene, with D on views from the dataset's training cameras
        // (against the trained scene, not the images, so they stay out of the held-out series).
        let t = Instant::now();
        let views = RdViews::of_dataset(dataset)
            .ok_or_else(|| Error::Input("the dataset has no training views".into()))?
            .measuring(self.search_distortion());
        let mut trials = rate::rd::Trials::with_views(trained, views.clone()).map_err(|e| Error::Input(e.to_string()))?;
        // With the DC fit, unlike fine-tuning's search (retraining against the images from a
        // search without it: lego-200 `--init` λ 6 +7 % bytes for +0.06 dB, docs/codec.md §30).
        let (mut config, _) =
            rate::rd::search_with(&mut trials, self.config.lambda, steps, true, |_| {}).map_err(|e| Error::Input(e.to_string()))?;
        // Pruning and the importance classes take the Gaussians in the order of their removal
        // error and significance from the dataset's training cameras, in the search and in the
        // file.
        let trained_importance = trials.importance().clone();
        drop(trials); // its reference renders and coded groups, before retraining
        stages.rd_search_s = t.elapsed().as_secs_f64();
        let orbit = Orbit::new(trained);
        // Retraining: the Gaussians the search keeps learn to cover for those it pruned, against
        // the images (the .ply path's fine-tuning, with the images as targets).
        let retrain = self.config.retrain_iters_for(true);
        let retrain_lambda = Lambda::new(self.config.lambda.get() * RETRAIN_RATE_WEIGHT).expect("a share of a valid λ");
        let init = (retrain > 0).then(|| rate::prepared(trained, &config, Some(&trained_importance))).filter(|s| !s.is_empty());
        let mut retrain_report = None;
        let retrained = if let Some(init) = init {
            let cfg = self.fine_tune_config(retrain, &init);
            // The loss of the main run, with WD / WD-R from the first iteration, and the rate
            // term at its retraining weight.
            let loss = LossSpec { wd_warmup: Some(0.0), ..self.config.loss.clone() };
            let retrainer = Encoder { config: self.config.clone().with_loss(loss).with_lambda(retrain_lambda) };
            let mut progress = |p: &Progress| progress(&Progress { iteration: iters + p.iteration, iters: iters + retrain, ..*p });
            let first = series.len();
            let (s, r2) = retrainer.train(dataset, Some(init), &cfg, &config, 0, start, &mut series, &mut progress)?;
            // Its time series continues the main run's iterations.
            series[first..].iter_mut().for_each(|p| p.iteration += iters);
            config.steps = learned_steps(config.steps, &r2);
            config.dc_fit = false; // as for a fine-tuned scene (`encode_explicit`)
            stages.train_s += r2.train_seconds;
            let (c, sig) = self.retune_tail(&s, views.clone(), config, &mut stages)?;
            config = c;
            retrain_report = Some(r2);
            Some((s, sig))
        } else {
            None
        };
        let (coded, importance) = retrained.as_ref().map_or((trained, &trained_importance), |(s, m)| (s, m));
        // The report's run: the training from the images, else (a given scene) the retraining.
        let r = r.or(retrain_report);
        let mut e = self.finish(&orbit, coded, &config, iters, start, stages, series, r, Some(dataset), Some(importance))?;
        e.report.retrain_iters = if retrained.is_some() { retrain } else { 0 };
        e.report.retrain_lambda = retrained.is_some().then_some(retrain_lambda);
        if self.config.coding_breakdown {
            e.report.coding_breakdown = Some(breakdown::coding_breakdown(coded, importance, &self.file_config(&config), dataset)?);
        }
        match self.config.profile {
            Profile::Explicit => Ok(e),
            // The anchors are distilled from the trained scene, then fine-tuned to the images.
            _ => Encoder { config: self.config.clone().with_iters(None) }.with_anchors(
                e,
                trained,
                &orbit,
                Some(dataset),
                Some((&views, &trained_importance)),
            ),
        }
    }

    /// `config` with its importance classes chosen again on `trained`, the scene retraining or
    /// fine-tuning made of what the search chose: the least significant Gaussians are no longer
    /// those the search coarsened (docs/codec.md, "Retraining"); and `trained`'s importance
    /// from `views` ([`RdViews::importance`]). Its time counts as search time.
    fn retune_tail(
        &self,
        trained: &Splats,
        views: RdViews,
        config: EncodeConfig,
        stages: &mut EncodeStages,
    ) -> Result<(EncodeConfig, Importance)> {
        let t = Instant::now();
        let mut trials = rate::rd::Trials::with_views(trained, views).map_err(|e| Error::Input(e.to_string()))?;
        let config = rate::rd::retune_tail(&mut trials, self.config.lambda, config).map_err(|e| Error::Input(e.to_string()))?;
        stages.rd_search_s += t.elapsed().as_secs_f64();
        Ok((config, trials.importance().clone()))
    }

    /// What the RD search of a trained dataset scene measures `D` with
    /// ([`EncoderConfig::search_distortion`]).
    fn search_distortion(&self) -> RdDistortion {
        let sigma = Some(self.config.loss.wd_sigma.unwrap_or(crate::loss::wd::DEFAULT_SIGMA));
        match (self.config.search_distortion, self.config.loss.kind) {
            (SearchDistortion::Mse, _) => RdDistortion::Mse,
            (SearchDistortion::Loss, LossKind::L1ssim) => RdDistortion::Loss { wd_sigma: None, l_orig: 1.0 },
            (SearchDistortion::Loss, LossKind::Wd) => RdDistortion::Loss { wd_sigma: sigma, l_orig: 0.0 },
            (SearchDistortion::Loss, LossKind::Wdr) => RdDistortion::Loss { wd_sigma: sigma, l_orig: wdr::BETA },
        }
    }

    /// The settings a file is written with: the RD choices `config` and the caller's
    /// `--progressive`.
    fn file_config(&self, config: &EncodeConfig) -> EncodeConfig {
        EncodeConfig { progressive: self.config.progressive, ..*config }
    }

    /// Training settings that fine-tune `init` (a scene the RD search has pruned) for `iters`
    /// iterations: no densification, SH up to `init`'s degree.
    fn fine_tune_config(&self, iters: usize, init: &Splats) -> TrainConfig {
        TrainConfig {
            iters,
            seed: self.config.seed,
            densify: false,
            sh_degree_max: init.sh_degree,
            eval_interval: (iters / 10).max(1),
            ..Default::default()
        }
    }

    /// Runs the configured backend on one training job with the rate objective.
    #[allow(clippy::too_many_arguments)]
    fn train(
        &self,
        dataset: &Dataset,
        init: Option<Splats>,
        cfg: &TrainConfig,
        config: &EncodeConfig,
        start_iter: usize,
        start: Instant,
        series: &mut Vec<SeriesPoint>,
        progress: &mut dyn FnMut(&Progress),
    ) -> Result<(Splats, TrainReport)> {
        let mut backend = self.config.backend.resolve()?;
        let rate = RateObjective {
            lambda: self.config.lambda,
            steps: config.steps,
            min_opacity: config.min_opacity,
            learn_steps: self.config.learn_steps,
            start_iter,
        };
        let job = TrainJob { dataset, init, config: cfg, loss: &self.config.loss, rate: Some(rate), run: &RunOptions::default() };
        let (s, r) = backend.train(job, &mut |p| {
            if let Some(psnr) = p.test_psnr {
                series.push(SeriesPoint {
                    iteration: p.iteration,
                    trial: "train".into(),
                    wall_s: start.elapsed().as_secs_f64(),
                    estimated_bits: p.rate_bits,
                    d: Some(p.loss),
                    heldout_psnr: Some(psnr),
                });
            }
            progress(p);
        })?;
        // The rate term's own estimate at the end of training: for a scene (coded at these
        // steps) it is to be compared with the file size.
        series.push(SeriesPoint {
            iteration: cfg.iters,
            trial: "learned steps".into(),
            wall_s: start.elapsed().as_secs_f64(),
            estimated_bits: r.rate.and_then(|o| o.estimated_bits),
            d: None,
            heldout_psnr: None,
        });
        Ok((s, r))
    }

    /// Codes `coded` with `config`, measures the result against `reference`'s orbit views and
    /// builds the report. For a dataset input, `heldout` is the dataset (the coded scene is
    /// measured on its held-out views). `importance` is what `coded` is pruned with: the RD
    /// search's measure of it ([`RdViews::importance`]) where the search measured this scene,
    /// else `None` (`coded`'s own, measured here).
    #[allow(clippy::too_many_arguments)]
    fn finish(
        &self,
        reference: &Orbit,
        coded: &Splats,
        config: &EncodeConfig,
        iters: usize,
        start: Instant,
        mut stages: EncodeStages,
        mut series: Vec<SeriesPoint>,
        train: Option<TrainReport>,
        heldout: Option<&Dataset>,
        importance: Option<&Importance>,
    ) -> Result<Encoded> {
        let t = Instant::now();
        let config = &self.file_config(config);
        let (bytes, r, q) = rate::encode_with(coded, config, importance).map_err(|e| Error::Input(e.to_string()))?;
        stages.write_s = t.elapsed().as_secs_f64();
        let t = Instant::now();
        let decoded = rate::quantise::dequantise(&q);
        if let Some(ds) = heldout {
            // The final point of the series: the coded scene on the held-out images.
            if let Some((psnr, _)) = crate::metrics::view::mean_psnr_ssim(&decoded, &ds.split(Split::Test), ds.background)? {
                series.push(SeriesPoint {
                    iteration: iters,
                    trial: report::CODED.into(),
                    wall_s: start.elapsed().as_secs_f64(),
                    estimated_bits: Some(8.0 * bytes.len() as f64),
                    d: None,
                    heldout_psnr: Some(psnr),
                });
            }
        }
        let orbit_psnr = reference.psnr(&decoded);
        stages.evaluate_s = t.elapsed().as_secs_f64();
        stages.total_s = start.elapsed().as_secs_f64();
        let report = EncodeReport {
            input: String::new(),
            init: None,
            lambda: self.config.lambda,
            loss: train.as_ref().map(|_| self.config.loss.name()),
            wd_features: train.as_ref().and_then(|_| self.config.loss.reported_features()),
            wd_sigma: train.as_ref().and_then(|_| self.config.loss.reported_sigma()),
            wd_warmup: train.as_ref().and_then(|_| self.config.loss.reported_warmup()),
            iters,
            retrain_iters: 0,
            retrain_lambda: None,
            search_distortion: heldout.map(|_| self.config.search_distortion.name()),
            backend: train.as_ref().map(|t| t.backend),
            file_bytes: bytes.len(),
            estimated_bytes: r.estimated_bits() / 8.0,
            gaussians: r.gaussians,
            input_gaussians: reference.scene.len(),
            sh_degree: r.sh_degree,
            position_bits: r.position_bits,
            groups: r.groups,
            steps: config.steps.map(),
            rest_deadzone: config.steps.rest_deadzone,
            min_opacity: config.min_opacity,
            min_removal_error: config.min_removal_error,
            tail: config.tail,
            dc_fit: config.dc_fit,
            orbit_psnr,
            stages,
            train,
            series,
            target: None,
            fine_tuning_kept: None,
            coding_breakdown: None,
            profile: "explicit",
            anchor: None,
            explicit_alternative: None,
        };
        Ok(Encoded { bytes, decoded, report, config: *config, trained: None })
    }
}

/// `--coding-breakdown` measures on the held-out views: refused for a dataset without any.
fn check_breakdown_views(config: &EncoderConfig, dataset: &Dataset) -> Result<()> {
    match config.coding_breakdown && dataset.split(Split::Test).is_empty() {
        true => Err(Error::Input("--coding-breakdown: the dataset has no held-out views to measure on".into())),
        false => Ok(()),
    }
}

/// `base` with the steps a training run learned (positions, rotations and the dead zone stay).
fn learned_steps(base: Steps, r: &TrainReport) -> Steps {
    let mut steps = base;
    if let Some(o) = &r.rate {
        for g in crate::rate::term::LEARNED_GROUPS {
            *steps.of_mut(g) = o.steps[g];
        }
    }
    debug_assert!(Group::ALL.iter().all(|&g| steps.of(g) > 0.0));
    steps
}

/// Mean PSNR of `b` against `a` over [`ORBIT_VIEWS`] orbit views of `a` at [`ORBIT_SIZE`]²
/// (up −y, black background): what `eval --reference A --orbit 8` reports for `b`.
pub fn orbit_psnr(a: &Splats, b: &Splats) -> f64 {
    Orbit::new(a).psnr(b)
}

/// The orbit views of [`orbit_psnr`]'s reference scene, rendered once, for measuring many scenes
/// against it.
pub(crate) struct Orbit<'a> {
    scene: &'a Splats,
    cams: Vec<gscodec_decoder::Camera>,
    refs: Vec<gscodec_decoder::Image>,
}

impl<'a> Orbit<'a> {
    pub(crate) fn new(reference: &'a Splats) -> Orbit<'a> {
        let cams = orbit_cameras(reference, ORBIT_VIEWS, ORBIT_SIZE, ORBIT_SIZE, UpAxis::NegY.vector());
        let refs = cams.iter().map(|c| render(reference, c, &RenderOptions::default())).collect();
        Orbit { scene: reference, cams, refs }
    }

    /// `D` of `b` as the RD search defines it, on these views: 255² × the mean squared error.
    pub(crate) fn distortion(&self, b: &Splats) -> f64 {
        self.mean(b, crate::metrics::mse) * 255.0 * 255.0
    }

    /// [`orbit_psnr`] of `b`.
    pub(crate) fn psnr(&self, b: &Splats) -> f64 {
        self.mean(b, crate::metrics::psnr)
    }

    /// The mean over the views of `metric(reference, render of b)` (views rendered in parallel,
    /// summed in order).
    fn mean(&self, b: &Splats, metric: fn(&gscodec_decoder::Image, &gscodec_decoder::Image) -> f64) -> f64 {
        let opts = RenderOptions::default();
        let per_view: Vec<f64> = self.cams.par_iter().zip(&self.refs).map(|(c, r)| metric(r, &render(b, c, &opts))).collect();
        per_view.iter().sum::<f64>() / self.cams.len() as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Fine-tuning a `.ply` trains what the RD search (without the DC fit) chose to code (pruned,
    /// SH bands dropped), not the whole input, so the Gaussians left can cover for those pruned.
    #[test]
    fn fine_tuning_starts_from_what_the_search_codes() {
        let scene = crate::sample::scene(300, 5);
        let lambda = Lambda::new(200.0).unwrap();
        // The search without the DC fit: training fits the DC itself.
        let mut trials = rate::rd::Trials::new(&scene).unwrap();
        let (config, _) = rate::rd::search_with(&mut trials, lambda, rate::rd::fine_steps(), false, |_| {}).unwrap();
        assert!(!config.dc_fit);
        let searched = rate::prepared(&scene, &config, None).len();
        assert!(0 < searched && searched < scene.len(), "the search prunes at this λ: {searched} of {}", scene.len());
        let encoder = Encoder::new(EncoderConfig { lambda, iters: Some(2), backend: Backend::Cpu, ..EncoderConfig::default() }).unwrap();
        let e = encoder.encode_scene(&scene, &mut |_| {}).unwrap();
        let trained = e.report.train.as_ref().expect("fine-tuned").gaussians;
        assert_eq!(trained, searched);
        // A fine-tuned file is coded with the fit of what training did not see.
        assert!(e.report.fine_tuning_kept != Some(true) || e.report.dc_fit == (scene.sh_degree > 0), "{:?}", e.report.fine_tuning_kept);
        assert!(
            e.report.gaussians <= trained && e.report.input_gaussians == scene.len(),
            "{:?}",
            (e.report.gaussians, e.report.input_gaussians)
        );
    }

    /// Fine-tuning never gives a file whose `J` on the orbit views is above the RD search's own
    /// file; where it would, the search's file is the output, byte for byte.
    #[test]
    fn fine_tuning_is_kept_only_when_it_lowers_j() {
        let scene = crate::sample::scene(300, 7);
        let orbit = Orbit::new(&scene);
        for l in [5.0, 200.0] {
            let lambda = Lambda::new(l).unwrap();
            let config = EncoderConfig { lambda, iters: Some(0), backend: Backend::Cpu, ..EncoderConfig::default() };
            let plain = Encoder::new(config.clone()).unwrap().encode_scene(&scene, &mut |_| {}).unwrap();
            assert_eq!(plain.report.fine_tuning_kept, None);
            let tuned = Encoder::new(EncoderConfig { iters: Some(30), ..config }).unwrap().encode_scene(&scene, &mut |_| {}).unwrap();
            let j = |e: &Encoded| orbit.distortion(&e.decoded) + lambda.rate_cost(e.bytes.len());
            assert!(j(&tuned) <= j(&plain), "λ {l}: {} > {}", j(&tuned), j(&plain));
            assert!(tuned.report.train.is_some() && tuned.report.iters == 30);
            match tuned.report.fine_tuning_kept {
                Some(false) => assert_eq!(tuned.bytes, plain.bytes, "λ {l}"),
                Some(true) => assert_ne!(tuned.bytes, plain.bytes, "λ {l}"),
                None => panic!("λ {l}: fine-tuned without saying whether it was kept"),
            }
        }
    }
}

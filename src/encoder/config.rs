//! [`EncoderConfig`]: what the encoder is asked to do, built with `with_*` setters and checked by
//! [`EncoderConfig::validate`], which returns an [`InvalidConfig`] naming the bad value and its bound.

use super::backend::{Backend, LossSpec};
use crate::loss::{wdr, LossKind};
use crate::rate::Lambda;

/// Training iterations when encoding a dataset without [`EncoderConfig::iters`].
pub const DEFAULT_DATASET_ITERS: usize = 3000;
/// Retraining iterations of a dataset encode without [`EncoderConfig::retrain_iters`]: the
/// training iterations divided by this (a third since session 26; a tenth before, which left
/// 7–35 % of the rate at equal ꟻLIP unused: docs/wd.md §25).
pub const RETRAIN_DIVISOR: usize = 3;
/// Retraining iterations of a scene trained elsewhere (`encode DATASET --init SCENE`) without
/// [`EncoderConfig::retrain_iters`]: as many as a dataset's default training, which such an
/// encode does not run. On lego-200 (`--init`, λ 6–60) 3000 steps instead of 1000 saved 19–22 %
/// of the bytes at equal PSNR for L1-SSIM and WD-R alike (playbot-200: L1-SSIM 21 %), and WD-R's
/// ꟻLIP lead over L1-SSIM on lego grew from 10.7 % to 24.2 % (docs/wd.md §29).
pub const INIT_RETRAIN_ITERS: usize = DEFAULT_DATASET_ITERS;
/// The rate term's weight in a dataset's retraining, as a share of its weight in training
/// ([`crate::rate::Lambda::training_weight_per_bit`]). Retraining fits the images with what the
/// RD search chose; at the full weight the term's pull on top of that choice cost more quality
/// than it saved bytes (lego-200, `--init`, λ 6–60: at 0.3 the L1-SSIM curve saves 19 % on ꟻLIP
/// and 14 % on PSNR, WD-R's 28.5 % on ꟻLIP; at 0.1 about the same; playbot-200 −13.8 % on
/// ꟻLIP). From the images, where the scene grew under the term, it is neutral (docs/wd.md §27).
pub const RETRAIN_RATE_WEIGHT: f64 = 0.3;
/// Largest number of training iterations accepted.
pub const MAX_ITERS: usize = 10_000_000;

/// Encoder settings (plain data with `Default`; see the field docs).
#[derive(Debug, Clone, PartialEq)]
pub struct EncoderConfig {
    /// The rate–distortion trade-off (unit: see [`Lambda`]).
    pub lambda: Lambda,
    /// Training iterations under `D + λ·R`: fine-tuning for a scene (default 0: code as is),
    /// training for a dataset (default [`DEFAULT_DATASET_ITERS`]).
    pub iters: Option<usize>,
    /// Learn the quantisation steps (per group) in training instead of keeping them.
    pub learn_steps: bool,
    /// The training distortion (default WD-R).
    pub loss: LossSpec,
    /// Which trainer runs the training.
    pub backend: Backend,
    /// Training seed.
    pub seed: u64,
    /// Write importance levels (a progressive 4.0 file, [`crate::rate::EncodeConfig::progressive`]).
    pub progressive: bool,
    /// Which way to code the scene (SPEC §12: the anchor profile).
    pub profile: Profile,
    /// The anchor profile's features per anchor and hidden units (`None`: its defaults, 16 and 32).
    pub anchor_features: Option<usize>,
    pub anchor_hidden: Option<usize>,
    /// The anchor profile's fine-tuning steps (`None`: `iters` for a scene, else 300).
    pub anchor_iters: Option<usize>,
    /// Dataset input: iterations that train the Gaussians the RD search keeps (after it prunes
    /// the trained scene and drops SH bands) on the images again, under `D + λ·R` with the
    /// training loss (no warm-up) and no densification, before they are coded (`None`: a third
    /// of the training iterations, [`EncoderConfig::retrain_iters_for`], or for a scene given
    /// with `--init` [`EncoderConfig::retrain_iters_for_init`]; 0: code the search's choice of
    /// the trained scene as it is).
    pub retrain_iters: Option<usize>,
    /// Dataset input: also code the scene that is coded (retrained, or as trained) with the RD
    /// search's choices added one at a time and report each file's held-out PSNR
    /// ([`super::CodingStage`]; costs seven more encodes and eight held-out evaluations).
    pub coding_breakdown: bool,
    /// Dataset input: what the RD search measures `D` with on the training cameras' views.
    pub search_distortion: SearchDistortion,
    /// Dataset input: densification never grows the scene beyond this many Gaussians (`None`:
    /// [`crate::train::TrainConfig`]'s default, 100,000; the initial points are kept when there
    /// are more).
    pub max_gaussians: Option<usize>,
    /// Dataset input: densification clones or splits the Gaussians whose mean view-space
    /// positional gradient reaches this (NDC units; `None`: the reference's 2e-4). Lower grows
    /// more.
    pub densify_grad_threshold: Option<f32>,
}

/// What the RD search of a scene trained from a dataset measures `D` with, on views from the
/// training cameras against the trained scene (`rate::rd::RdDistortion`). A `.ply`'s search
/// measures the squared error on orbit views against the input, the PSNR `--target-psnr`
/// targets.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SearchDistortion {
    /// 255² × mean squared error.
    #[default]
    Mse,
    /// The training loss's distortion (`l1ssim`: 0.8·L1 + 0.2·(1 − SSIM); `wd`: d_WD; `wdr`:
    /// d_WD + β·(that), with `pyramid` features and the loss's σ), in the squared error's unit
    /// at the search's first configuration.
    Loss,
}

impl SearchDistortion {
    /// Its name on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            SearchDistortion::Mse => "mse",
            SearchDistortion::Loss => "loss",
        }
    }
}

/// How a scene is coded: the explicit profile (per-Gaussian attributes, formats 3.0–6.0, 8.0), the
/// anchor profile (anchors with features and a fixed-point MLP, format 7.0, SPEC §12), or
/// whichever of the two has the lower `J = D + λ·R`.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq, Default, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Profile {
    #[default]
    Explicit,
    Anchor,
    Auto,
}

impl Profile {
    /// Its name on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            Profile::Explicit => "explicit",
            Profile::Anchor => "anchor",
            Profile::Auto => "auto",
        }
    }
}

impl Default for EncoderConfig {
    fn default() -> Self {
        EncoderConfig {
            lambda: Lambda::DEFAULT,
            iters: None,
            learn_steps: true,
            loss: LossSpec { kind: LossKind::Wdr, ..LossSpec::default() },
            backend: Backend::default(),
            seed: 0,
            progressive: false,
            profile: Profile::Explicit,
            anchor_features: None,
            anchor_hidden: None,
            anchor_iters: None,
            retrain_iters: None,
            coding_breakdown: false,
            search_distortion: SearchDistortion::Mse,
            max_gaussians: None,
            densify_grad_threshold: None,
        }
    }
}

impl EncoderConfig {
    /// Sets λ.
    pub fn with_lambda(mut self, lambda: Lambda) -> Self {
        self.lambda = lambda;
        self
    }

    /// Sets the training iterations (`None`: the default for the input).
    pub fn with_iters(mut self, iters: Option<usize>) -> Self {
        self.iters = iters;
        self
    }

    /// Learns (true) or keeps (false) the quantisation steps in training.
    pub fn with_learned_steps(mut self, learn: bool) -> Self {
        self.learn_steps = learn;
        self
    }

    /// Sets the training distortion.
    pub fn with_loss(mut self, loss: LossSpec) -> Self {
        self.loss = loss;
        self
    }

    /// Sets the training backend.
    pub fn with_backend(mut self, backend: Backend) -> Self {
        self.backend = backend;
        self
    }

    /// Sets the training seed.
    pub fn with_seed(mut self, seed: u64) -> Self {
        self.seed = seed;
        self
    }

    /// Sets the profile.
    pub fn with_profile(mut self, profile: Profile) -> Self {
        self.profile = profile;
        self
    }

    /// Sets the anchor profile's features per anchor and hidden units (`None`: its defaults).
    pub fn with_anchor_shape(mut self, features: Option<usize>, hidden: Option<usize>) -> Self {
        self.anchor_features = features;
        self.anchor_hidden = hidden;
        self
    }

    /// Sets the anchor profile's fine-tuning steps (`None`: `iters` for a scene, else 300).
    pub fn with_anchor_iters(mut self, iters: Option<usize>) -> Self {
        self.anchor_iters = iters;
        self
    }

    /// Reports where coding a trained dataset scene loses its held-out PSNR
    /// ([`EncoderConfig::coding_breakdown`]).
    pub fn with_coding_breakdown(mut self, on: bool) -> Self {
        self.coding_breakdown = on;
        self
    }

    /// Sets the iterations that retrain what the RD search keeps of a trained dataset scene
    /// (`None`: the default, a third of the training iterations, [`RETRAIN_DIVISOR`], or
    /// [`INIT_RETRAIN_ITERS`] for a scene given with `--init`).
    pub fn with_retrain_iters(mut self, iters: Option<usize>) -> Self {
        self.retrain_iters = iters;
        self
    }

    /// Sets the most Gaussians densification may grow when training from a dataset.
    pub fn with_max_gaussians(mut self, n: Option<usize>) -> Self {
        self.max_gaussians = n;
        self
    }

    /// Sets the densification gradient threshold when training from a dataset.
    pub fn with_densify_grad_threshold(mut self, g: Option<f32>) -> Self {
        self.densify_grad_threshold = g;
        self
    }

    /// Sets what the RD search of a dataset's trained scene measures `D` with.
    pub fn with_search_distortion(mut self, d: SearchDistortion) -> Self {
        self.search_distortion = d;
        self
    }

    /// Writes importance levels (true) or one level (false).
    pub fn with_progressive(mut self, progressive: bool) -> Self {
        self.progressive = progressive;
        self
    }

    /// Iterations for a scene (`dataset` false) or a dataset.
    pub fn iters_for(&self, dataset: bool) -> usize {
        self.iters.unwrap_or(if dataset { DEFAULT_DATASET_ITERS } else { 0 })
    }

    /// The warm-up share `wd` / `wdr` train with when `--wd-warmup` is not given:
    /// [`wdr::ENCODE_WARMUP_FRACTION`] (WD / WD-R only in retraining) for a scene trained here
    /// from a dataset's images that is then retrained, else [`wdr::WARMUP_FRACTION`].
    pub fn default_wd_warmup(&self, from_images: bool) -> f64 {
        match from_images && self.retrain_iters_for(true) > 0 {
            true => wdr::ENCODE_WARMUP_FRACTION,
            false => wdr::WARMUP_FRACTION,
        }
    }

    /// Retraining iterations for a scene (`dataset` false: none) or a dataset.
    pub fn retrain_iters_for(&self, dataset: bool) -> usize {
        match dataset {
            false => 0,
            true => self.retrain_iters.unwrap_or(self.iters_for(true) / RETRAIN_DIVISOR),
        }
    }

    /// Retraining iterations for a scene given with `--init` ([`super::Encoder::encode_trained`]):
    /// [`EncoderConfig::retrain_iters`], else [`INIT_RETRAIN_ITERS`].
    pub fn retrain_iters_for_init(&self) -> usize {
        self.retrain_iters.unwrap_or(INIT_RETRAIN_ITERS)
    }

    /// Retraining iterations of a dataset encode: of a scene given with `--init` (`init`,
    /// [`EncoderConfig::retrain_iters_for_init`]) or of one trained here from the images.
    pub fn retrain_iters_of_dataset(&self, init: bool) -> usize {
        if init {
            self.retrain_iters_for_init()
        } else {
            self.retrain_iters_for(true)
        }
    }

    /// Checks the settings.
    ///
    /// # Errors
    /// The first setting out of its range, as an [`InvalidConfig`].
    pub fn validate(&self) -> Result<(), InvalidConfig> {
        if let Some(v) = self.iters.filter(|&n| n > MAX_ITERS) {
            return Err(InvalidConfig::Iters { value: v, max: MAX_ITERS });
        }
        if let Some(v) = self.retrain_iters.filter(|&n| n > MAX_ITERS) {
            return Err(InvalidConfig::RetrainIters { value: v, max: MAX_ITERS });
        }
        if self.max_gaussians == Some(0) {
            return Err(InvalidConfig::MaxGaussians);
        }
        if let Some(g) = self.densify_grad_threshold {
            check_densify_grad_threshold(g)?;
        }
        if let Some(g) = self.loss.wd_gamma.filter(|g| !(g.is_finite() && *g > 0.0)) {
            return Err(InvalidConfig::WdGamma { value: g });
        }
        if let Some(s) = self.loss.wd_sigma {
            crate::loss::check_wd_sigma(s)?;
        }
        if let Some(f) = self.loss.wd_warmup {
            crate::loss::check_wd_warmup(f)?;
        }
        Ok(())
    }

    /// [`Self::validate`] for a dataset input, which needs training.
    ///
    /// # Errors
    /// As [`Self::validate`], and [`InvalidConfig::DatasetWithoutTraining`] for `iters = Some(0)`.
    pub fn validate_for_dataset(&self) -> Result<(), InvalidConfig> {
        self.validate()?;
        if self.iters == Some(0) {
            return Err(InvalidConfig::DatasetWithoutTraining);
        }
        Ok(())
    }
}

/// Checks a densification gradient threshold (`--densify-grad-threshold`): finite and > 0.
///
/// # Errors
/// [`InvalidConfig::DensifyGradThreshold`] otherwise.
pub fn check_densify_grad_threshold(value: f32) -> Result<(), InvalidConfig> {
    match value.is_finite() && value > 0.0 {
        true => Ok(()),
        false => Err(InvalidConfig::DensifyGradThreshold { value }),
    }
}

/// A setting of [`EncoderConfig`] out of range; the message names the value and the bound.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum InvalidConfig {
    /// More training iterations than [`MAX_ITERS`].
    #[error("--iters {value}: at most {max}")]
    Iters {
        /// The value given.
        value: usize,
        /// The largest accepted.
        max: usize,
    },
    /// More retraining iterations than [`MAX_ITERS`].
    #[error("--retrain-iters {value}: at most {max}")]
    RetrainIters {
        /// The value given.
        value: usize,
        /// The largest accepted.
        max: usize,
    },
    /// A Gaussian budget of 0.
    #[error("--max-gaussians 0: must be at least 1")]
    MaxGaussians,
    /// The densification threshold must be a finite number > 0.
    #[error("--densify-grad-threshold {value}: must be a finite number > 0")]
    DensifyGradThreshold {
        /// The value given.
        value: f32,
    },
    /// γ of WD / WD-R must be a finite number > 0.
    #[error("--wd-gamma {value}: must be a finite number > 0")]
    WdGamma {
        /// The value given.
        value: f64,
    },
    /// σ of WD / WD-R must be in [1, 2^NUM_LEVELS] (ℓ = log2 σ in [0, NUM_LEVELS]).
    #[error("--wd-sigma {value}: must be in [1, {max}]")]
    WdSigma {
        /// The value given.
        value: f64,
        /// The largest accepted.
        max: f64,
    },
    /// The warm-up share of WD / WD-R must be in [0, 1].
    #[error("--wd-warmup {value}: must be in [0, 1]")]
    WdWarmup {
        /// The value given.
        value: f64,
    },
    /// A dataset is encoded by training: iterations must be ≥ 1.
    #[error("--iters 0: encoding a dataset needs training, at least 1 iteration")]
    DatasetWithoutTraining,
    /// `--target-psnr` must be a finite number of dB in (0, 200].
    #[error("--target-psnr {value}: must be in (0, {max}] dB")]
    TargetPsnr {
        /// The value given.
        value: f64,
        /// The largest accepted.
        max: f64,
    },
    /// `--target-bytes` must be at least the size of an empty file.
    #[error("--target-bytes {value}: must be at least {min} (an empty scene's file)")]
    TargetBytes {
        /// The value given.
        value: u64,
        /// The smallest accepted.
        min: u64,
    },
}

impl From<InvalidConfig> for crate::Error {
    fn from(e: InvalidConfig) -> Self {
        crate::Error::Input(e.to_string())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages_carry_the_value_and_the_bound() {
        assert_eq!(EncoderConfig::default().validate(), Ok(()));
        let e = EncoderConfig::default().with_iters(Some(MAX_ITERS + 1)).validate().unwrap_err();
        assert_eq!(e.to_string(), format!("--iters {}: at most {MAX_ITERS}", MAX_ITERS + 1));
        let loss = LossSpec { wd_gamma: Some(-0.5), ..LossSpec::default() };
        let e = EncoderConfig::default().with_loss(loss).validate().unwrap_err();
        assert_eq!(e, InvalidConfig::WdGamma { value: -0.5 });
        assert!(e.to_string().contains("-0.5") && e.to_string().contains("> 0"));
        for s in [0.5, 33.0, f64::NAN] {
            let loss = LossSpec { wd_sigma: Some(s), ..LossSpec::default() };
            let e = EncoderConfig::default().with_loss(loss).validate().unwrap_err();
            assert_eq!(e.to_string(), format!("--wd-sigma {s}: must be in [1, 32]"));
        }
        for s in [1.0, 2.0, 32.0] {
            let loss = LossSpec { wd_sigma: Some(s), ..LossSpec::default() };
            assert_eq!(EncoderConfig::default().with_loss(loss).validate(), Ok(()));
        }
        // retraining: a third of the dataset's training iterations unless set; never for a scene
        let c = EncoderConfig::default().with_iters(Some(5000));
        assert_eq!((c.retrain_iters_for(true), c.retrain_iters_for(false)), (1666, 0));
        assert_eq!(EncoderConfig::default().retrain_iters_for(true), 1000);
        assert_eq!(c.clone().with_retrain_iters(Some(7)).retrain_iters_for(true), 7);
        // a scene given with --init: as long as a default training, whatever --iters says
        assert_eq!((c.retrain_iters_for_init(), EncoderConfig::default().retrain_iters_for_init()), (3000, 3000));
        assert_eq!(c.clone().with_retrain_iters(Some(0)).retrain_iters_for_init(), 0);
        let e = c.with_retrain_iters(Some(MAX_ITERS + 1)).validate().unwrap_err();
        assert_eq!(e.to_string(), format!("--retrain-iters {}: at most {MAX_ITERS}", MAX_ITERS + 1));
        let e = EncoderConfig::default().with_max_gaussians(Some(0)).validate().unwrap_err();
        assert_eq!(e.to_string(), "--max-gaussians 0: must be at least 1");
        assert_eq!(EncoderConfig::default().with_max_gaussians(Some(1)).validate(), Ok(()));
        let e = EncoderConfig::default().with_densify_grad_threshold(Some(0.0)).validate().unwrap_err();
        assert_eq!(e.to_string(), "--densify-grad-threshold 0: must be a finite number > 0");
        assert!(EncoderConfig::default().with_densify_grad_threshold(Some(f32::NAN)).validate().is_err());
        assert_eq!(EncoderConfig::default().with_densify_grad_threshold(Some(1e-4)).validate(), Ok(()));
        let c = EncoderConfig::default().with_iters(Some(0));
        assert_eq!(c.validate(), Ok(()), "a scene may be coded as is");
        assert_eq!(c.validate_for_dataset(), Err(InvalidConfig::DatasetWithoutTraining));
        assert_eq!(crate::Error::from(InvalidConfig::DatasetWithoutTraining).exit_code(), 2);
    }
}

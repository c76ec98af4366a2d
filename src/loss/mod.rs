//! Image losses with analytic gradients: L1, SSIM, WD, WD-R.

pub mod features;
pub mod l1;
pub mod ssim;
pub mod tensor;
pub mod wd;
pub mod wdr;

pub use l1::{l1_and_grad, L1Ssim};

use gscodec_decoder::Image;

/// A distortion between a rendered image and its target, with its gradient.
///
/// The trainer calls this once per iteration per rendered view. `view` identifies the training
/// view (stable across iterations) so implementations may cache per-target data (e.g. reference
/// features); `iter` lets a loss follow a schedule (e.g. WD-R's warm-up).
pub trait ImageLoss: Send {
    /// Returns the loss and `dL/d(rendered)` in the image's interleaved RGB layout.
    fn loss_and_grad(&mut self, rendered: &Image, target: &Image, view: usize, iter: usize) -> (f64, Vec<f32>);

    /// Short name for reports (`l1ssim`, `wd`, `wdr`).
    fn name(&self) -> &'static str;
}

pub use features::FeatureSpec;

/// Which training distortion to use.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum LossKind {
    /// The original 3DGS loss 0.8·L1 + 0.2·(1 − SSIM).
    #[default]
    L1ssim,
    /// Wasserstein Distortion γ·d_WD (after an L1+SSIM warm-up).
    Wd,
    /// WD regularised with the original loss: γ·(d_WD + β·L_orig) (after the warm-up).
    Wdr,
}

impl LossKind {
    /// Short name for reports and checkpoints (`l1ssim`, `wd`, `wdr`).
    pub fn name(self) -> &'static str {
        match self {
            LossKind::L1ssim => "l1ssim",
            LossKind::Wd => "wd",
            LossKind::Wdr => "wdr",
        }
    }
}

/// The loss options shared by `train` and `encode`.
#[derive(clap::Args, Clone, Debug, PartialEq, Default)]
pub struct LossArgs {
    /// Training distortion (default: `l1ssim` for `train`, `wdr` for `encode`).
    #[arg(long, value_enum)]
    pub loss: Option<LossKind>,
    /// Feature space of WD: `pyramid-colour` (built in: oriented responses of the luminance and
    /// of two opponent colour signals, see docs/wd.md), `pyramid` (built in: of the luminance
    /// only) or `vgg16=PATH` (VGG-16 weights as safetensors, see scripts/export_vgg16.py; CPU
    /// only).
    #[arg(long, default_value = "pyramid-colour", value_name = "pyramid-colour|pyramid|vgg16=PATH")]
    pub features: FeatureSpec,
    /// Global scale γ of `wd` / `wdr` (default: 0.03 / normalised to L1-SSIM's gradient scale,
    /// see docs/wd.md).
    #[arg(long = "wd-gamma", value_name = "G")]
    pub wd_gamma: Option<f64>,
    /// Pooling scale σ of `wd` / `wdr` in pixels, the same everywhere: 1 ≤ S ≤ 32 (default: 4,
    /// DESIGN §4; see docs/wd.md).
    #[arg(long = "wd-sigma", value_name = "S")]
    pub wd_sigma: Option<f64>,
    /// Share of the iterations trained with L1-SSIM alone before `wd` / `wdr` take over:
    /// 0 ≤ F ≤ 1 (default: 0.3, before densification ends at 0.5; the paper's is 0.1; see
    /// docs/wd.md §17). 1: the run from the images is L1-SSIM's, and `wd` / `wdr` train only in
    /// the retraining after the RD search: the default of `encode` of a dataset that retrains
    /// (docs/wd.md §23).
    #[arg(long = "wd-warmup", value_name = "F")]
    pub wd_warmup: Option<f64>,
}

/// Largest uniform σ WD accepts: 2^[`wd::NUM_LEVELS`] (ℓ = log2 σ ≤ NUM_LEVELS).
pub const MAX_WD_SIGMA: f64 = (1u32 << wd::NUM_LEVELS) as f64;

/// Checks a `--wd-sigma`: in [1, [`MAX_WD_SIGMA`]] (NaN is not).
///
/// # Errors
/// [`InvalidConfig::WdSigma`](crate::encoder::InvalidConfig::WdSigma), naming the value and the bound.
pub fn check_wd_sigma(sigma: f64) -> Result<(), crate::encoder::InvalidConfig> {
    match (1.0..=MAX_WD_SIGMA).contains(&sigma) {
        true => Ok(()),
        false => Err(crate::encoder::InvalidConfig::WdSigma { value: sigma, max: MAX_WD_SIGMA }),
    }
}

/// Checks a `--wd-warmup`: in [0, 1] (NaN is not; 1: WD / WD-R only in retraining).
///
/// # Errors
/// [`InvalidConfig::WdWarmup`](crate::encoder::InvalidConfig::WdWarmup), naming the value.
pub fn check_wd_warmup(fraction: f64) -> Result<(), crate::encoder::InvalidConfig> {
    match (0.0..=1.0).contains(&fraction) {
        true => Ok(()),
        false => Err(crate::encoder::InvalidConfig::WdWarmup { value: fraction }),
    }
}

/// Builds the loss for a run of `total_iters` iterations (the WD warm-up is `--wd-warmup` of
/// it, [`wdr::WARMUP_FRACTION`] by default);
/// `default` is used when `--loss` was not given.
///
/// # Errors
/// Bad input (exit 2) for an unreadable VGG weights file, a γ that is not a positive number or a
/// σ out of [1, [`MAX_WD_SIGMA`]] or a warm-up share out of [0, 1).
pub fn build_loss(args: &LossArgs, total_iters: usize, default: LossKind) -> crate::Result<Box<dyn ImageLoss>> {
    if let Some(g) = args.wd_gamma {
        if !(g.is_finite() && g > 0.0) {
            return Err(crate::Error::Input(format!("--wd-gamma must be a positive number, got {g}")));
        }
    }
    if let Some(s) = args.wd_sigma {
        check_wd_sigma(s)?;
    }
    if let Some(f) = args.wd_warmup {
        check_wd_warmup(f)?;
    }
    let warmup = wdr::warmup_iters(total_iters, args.wd_warmup.unwrap_or(wdr::WARMUP_FRACTION));
    let sigma = wd::Sigma::Constant(args.wd_sigma.unwrap_or(wd::DEFAULT_SIGMA));
    Ok(match args.loss.unwrap_or(default) {
        LossKind::L1ssim => Box::new(L1Ssim::default()),
        LossKind::Wd => {
            let mut l = wdr::WdLoss::new(args.features.build()?, total_iters).with_sigma(sigma);
            l.gamma = args.wd_gamma.unwrap_or(l.gamma);
            l.warmup = warmup;
            Box::new(l)
        }
        LossKind::Wdr => {
            let mut l = wdr::WdrLoss::new(args.features.build()?, total_iters).with_sigma(sigma);
            l.warmup = warmup;
            Box::new(match args.wd_gamma {
                Some(g) => l.with_fixed_gamma(g),
                None => l,
            })
        }
    })
}

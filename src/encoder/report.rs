//! [`EncodeReport`]: what an encode did, typed (what `encode --report` writes and `sweep` reads).

use serde::Serialize;

use crate::rate::group::GroupMap;
use crate::rate::{GroupReport, Lambda};
use crate::train::TrainReport;

use super::TargetSearch;

/// Wall time per encoder stage, seconds.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct EncodeStages {
    /// The rendering RD search (per-group steps, pruning, SH degree).
    pub rd_search_s: f64,
    /// Training or fine-tuning under `D + λ·R` (the backend's own stages are in [`EncodeReport::train`]).
    pub train_s: f64,
    /// Quantisation and entropy coding of the final file.
    pub write_s: f64,
    /// Decoding the coded scene back and measuring [`EncodeReport::orbit_psnr`].
    pub evaluate_s: f64,
    /// The whole encode.
    pub total_s: f64,
}

/// The [`SeriesPoint::trial`] of the series' last point: the file written (a dataset: on its
/// held-out images).
pub const CODED: &str = "coded";

/// One point of the encode's time series: an RD-search trial, a training evaluation, the
/// learned steps or the coded result.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SeriesPoint {
    /// RD-search trial number or training iteration.
    pub iteration: usize,
    /// What this point is: the trial's change, `train`, `learned steps` or `coded`.
    pub trial: String,
    /// Wall time since the encode started, seconds.
    pub wall_s: f64,
    /// Size (trials, coded) or the rate term's estimate (training), bits.
    pub estimated_bits: Option<f64>,
    /// The trial's distortion (255²·MSE) or the training loss.
    pub d: Option<f64>,
    /// PSNR (dB): of the trial against the input scene (a `.ply`), or on held-out images
    /// (training from a dataset).
    pub heldout_psnr: Option<f64>,
}

/// What an encode did.
#[derive(Debug, Clone, Serialize)]
pub struct EncodeReport {
    /// The input, as the caller named it (empty when it did not).
    pub input: String,
    /// The trained scene a dataset encode coded instead of training one (`encode DATASET
    /// --init SCENE`, [`super::Encoder::encode_trained`]), as the caller named it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub init: Option<String>,
    /// λ (unit: see [`Lambda`]).
    pub lambda: Lambda,
    /// Training distortion, when the encode trained.
    pub loss: Option<&'static str>,
    /// WD's feature space (`--features`), when the encode trained with `wd` / `wdr`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub wd_features: Option<String>,
    /// WD's uniform pooling scale σ (`--wd-sigma`), when the encode trained with `wd` / `wdr`.
    pub wd_sigma: Option<f64>,
    /// WD's warm-up share (`--wd-warmup`), when the encode trained with `wd` / `wdr`.
    pub wd_warmup: Option<f64>,
    /// Training iterations (0: coded as is).
    pub iters: usize,
    /// Iterations that retrained what the RD search kept of a trained dataset scene
    /// ([`super::EncoderConfig::retrain_iters`]; 0: none).
    pub retrain_iters: usize,
    /// The λ the retraining's rate term trained at, when it ran: λ × `RETRAIN_RATE_WEIGHT`
    /// (docs/wd.md §27).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub retrain_lambda: Option<Lambda>,
    /// What the RD search measured `D` with (`mse`, `loss`: `encode --search-distortion`),
    /// for a dataset input.
    pub search_distortion: Option<&'static str>,
    /// The training backend that ran (`cpu`, `gpu`), when the encode trained.
    pub backend: Option<&'static str>,
    /// Size of the file.
    pub file_bytes: usize,
    /// The entropy model's estimate of the size, bytes.
    pub estimated_bytes: f64,
    /// Gaussians in the file.
    pub gaussians: usize,
    /// Gaussians before pruning: the input scene's (a `.ply`), or the trained scene's (a dataset).
    pub input_gaussians: usize,
    /// SH degree of the file.
    pub sh_degree: u8,
    /// Position grid bits per axis.
    pub position_bits: u8,
    /// Bytes and bits per attribute group.
    pub groups: Vec<GroupReport>,
    /// Quantisation steps per group (Position: relative to the Gaussians' size).
    pub steps: GroupMap<f32>,
    /// Dead zone of the SH rest quantiser, in steps (0: plain rounding; an encoder-only choice
    /// the RD search makes, not in the file).
    pub rest_deadzone: f32,
    /// Pruning thresholds of the file: opacity, and removal error (0: none).
    pub min_opacity: f32,
    pub min_removal_error: f32,
    /// Importance classes of the file (format 6.0): the least significant `share` of the
    /// Gaussians with every step × `factor` (share 0: none).
    pub tail: crate::rate::CoarseTail,
    /// Whether each DC took back the mean colour its coded SH rest bands lost over the views
    /// (`EncodeConfig::dc_fit`, an encoder-only choice: the RD search's, and on for a
    /// fine-tuned file, where it takes back only what training did not see).
    pub dc_fit: bool,
    /// Mean PSNR of the decoded scene against the input scene (for a dataset: against the trained
    /// scene before coding) over the 8 orbit views at 256×256, as `eval --reference --orbit 8`.
    pub orbit_psnr: f64,
    /// Wall time per stage.
    pub stages: EncodeStages,
    /// The training run's report (backend, per-stage times, held-out PSNR), when it trained.
    pub train: Option<TrainReport>,
    /// RD-search trials and training evaluations against wall time.
    pub series: Vec<SeriesPoint>,
    /// With a target (`--target-psnr`, `--target-bytes`): the target and every λ tried.
    pub target: Option<TargetSearch>,
    /// Fine-tuning a scene (`iters` > 0): whether the fine-tuned file is the output (`false`:
    /// the RD search's own file had the lower `J = D + λ·R`, D on the orbit views at 256², and
    /// is the output; `train` still reports the run). `None` without fine-tuning.
    pub fine_tuning_kept: Option<bool>,
    /// With `--coding-breakdown` (dataset input): the held-out PSNR of the scene before coding
    /// and as each of the RD search's choices is added ([`super::CodingStage`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub coding_breakdown: Option<Vec<super::CodingStage>>,
    /// The profile of the file: `explicit` (formats 3.0–6.0 and 8.0) or `anchor` (7.0, SPEC §12).
    pub profile: &'static str,
    /// The anchor profile's encode (with `--profile anchor` or `auto`), whether or not its file
    /// is the output; `groups`, `steps` and the pruning fields then describe the explicit
    /// profile's choice, whose pruned scene the anchors code.
    pub anchor: Option<crate::anchor::AnchorReport>,
    /// With `--profile auto`: the explicit file's size and PSNR, the other candidate.
    pub explicit_alternative: Option<(usize, f64)>,
}

impl EncodeReport {
    /// The written file's PSNR on a dataset's held-out images (what `eval OUT DATASET` reads):
    /// the [`CODED`] point's; `None` for a scene.
    pub fn heldout_psnr(&self) -> Option<f64> {
        self.series.iter().rev().find(|p| p.trial == CODED).and_then(|p| p.heldout_psnr)
    }
}

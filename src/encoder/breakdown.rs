//! Where the coding of a trained dataset scene loses its held-out PSNR (`encode
//! --coding-breakdown`): the scene uncoded, then coded with the RD search's choices added one
//! at a time, in the order the search makes them, up to the file itself; and two partial
//! quantisations that split the steps' share between the groups training quantises and those it
//! does not.

use serde::Serialize;

use gscodec_decoder::Splats;

use crate::io::{Dataset, Split};
use crate::rate::group::Group;
use crate::rate::term::LEARNED_GROUPS;
use crate::rate::{self, CoarseTail, EncodeConfig, Importance, Steps};
use crate::{Error, Result};

/// One row of the breakdown.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CodingStage {
    /// What is coded: `uncoded`, `quantised`, `+ pruning`, `+ SH band dropping`, `+ SH
    /// codebooks`, `+ importance classes` (cumulative; the last is the file), then
    /// `only untrained groups quantised` and `only trained groups quantised`.
    pub stage: &'static str,
    /// Bytes of that file (`None` for the uncoded scene).
    pub bytes: Option<usize>,
    /// Mean PSNR on the dataset's held-out views (dB).
    pub heldout_psnr: f64,
}

/// Steps this much finer than the chosen ones stand for "not quantised" in the partial rows.
const UNQUANTISED: f32 = 1e-3;

/// The breakdown of coding `scene` with `config` (the file's settings) and the `importance`
/// the file prunes with, measured on `dataset`'s held-out views.
///
/// # Errors
/// A dataset without held-out views, or a scene the coder refuses.
pub fn coding_breakdown(scene: &Splats, importance: &Importance, config: &EncodeConfig, dataset: &Dataset) -> Result<Vec<CodingStage>> {
    let test = dataset.split(Split::Test);
    let psnr = |s: &Splats| -> Result<f64> {
        let m = crate::metrics::view::mean_psnr_ssim(s, &test, dataset.background)?;
        Ok(m.ok_or_else(|| Error::Input("--coding-breakdown: the dataset has no held-out views".into()))?.0)
    };
    let coded = |stage: &'static str, c: EncodeConfig| -> Result<CodingStage> {
        let (bytes, _, q) = rate::encode_with(scene, &c, Some(importance)).map_err(|e| Error::Input(e.to_string()))?;
        Ok(CodingStage { stage, bytes: Some(bytes.len()), heldout_psnr: psnr(&rate::quantise::dequantise(&q))? })
    };
    // Opacity below 1/255 never draws: that pruning is in every row.
    let quantised = EncodeConfig { min_removal_error: 0.0, sh_drop: [0.0; 3], sh_vq: [0; 3], tail: CoarseTail::OFF, ..*config };
    let pruned = EncodeConfig { min_removal_error: config.min_removal_error, ..quantised };
    let dropped = EncodeConfig { sh_drop: config.sh_drop, ..pruned };
    let codebooks = EncodeConfig { sh_vq: config.sh_vq, ..dropped };
    // Only the groups training quantises (`trained`) or only the others (position, rotation) at
    // the chosen steps; the rest at steps UNQUANTISED times finer (positions: as fine as the
    // format's grid allows).
    let only = |trained: bool| {
        let mut steps: Steps = config.steps;
        for g in Group::ALL.into_iter().filter(|g| LEARNED_GROUPS.contains(g) != trained) {
            *steps.of_mut(g) *= UNQUANTISED;
        }
        EncodeConfig { steps, ..quantised }
    };
    Ok(vec![
        CodingStage { stage: "uncoded", bytes: None, heldout_psnr: psnr(scene)? },
        coded("quantised", quantised)?,
        coded("+ pruning", pruned)?,
        coded("+ SH band dropping", dropped)?,
        coded("+ SH codebooks", codebooks)?,
        coded("+ importance classes", *config)?,
        coded("only untrained groups quantised", only(false))?,
        coded("only trained groups quantised", only(true))?,
    ])
}

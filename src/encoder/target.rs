//! Encoding to a target instead of a λ: the smallest file that reaches a PSNR, or the best PSNR
//! within a size, found by a bracketing search on λ ([`Encoder::encode_scene_to`]).

use serde::Serialize;

use gscodec_decoder::Splats;

use super::{Encoded, Encoder, InvalidConfig, Lambda};
use crate::train::Progress;
use crate::Result;

/// What to aim for.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Target {
    /// The smallest file whose [`super::EncodeReport::orbit_psnr`] is at least this many dB.
    Psnr(f64),
    /// The best orbit PSNR among files of at most this many bytes.
    Bytes(u64),
}

/// Largest `--target-psnr` accepted, dB.
pub const MAX_TARGET_PSNR: f64 = 200.0;
/// The largest λ the search tries (every scene's file is nearly empty there).
pub const MAX_LAMBDA: f64 = 1e9;
/// Probes between the ends at most (bisection would resolve λ to within ≈8 % in 8).
const MAX_INNER_PROBES: usize = 8;
/// The search stops when the bracket is narrower than this in `ln(1+λ)` (λ within ≈8 %) ...
const RESOLUTION: f64 = 0.08;
/// ... or when a probe meets the target by less than this margin (dB of PSNR; for a size,
/// `ln` of the budget over the bytes: 0.5 %).
const CLOSE_PSNR: f64 = 0.05;
const CLOSE_BYTES: f64 = 0.005;

/// One encode of the search.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Probe {
    /// λ tried.
    pub lambda: Lambda,
    /// File size.
    pub bytes: usize,
    /// Orbit PSNR, dB.
    pub psnr: f64,
}

/// How a target was met: the target and every encode tried, in order.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TargetSearch {
    /// The target.
    pub target: Target,
    /// Every encode of the search.
    pub probes: Vec<Probe>,
}

impl Target {
    /// Checks the target's value.
    ///
    /// # Errors
    /// A PSNR outside (0, [`MAX_TARGET_PSNR`]] or a size below an empty scene's file.
    pub fn validate(self) -> std::result::Result<(), InvalidConfig> {
        match self {
            Target::Psnr(v) if !(v > 0.0 && v <= MAX_TARGET_PSNR) => Err(InvalidConfig::TargetPsnr { value: v, max: MAX_TARGET_PSNR }),
            Target::Bytes(v) => {
                let min = empty_file_bytes();
                if v < min {
                    return Err(InvalidConfig::TargetBytes { value: v, min });
                }
                Ok(())
            }
            _ => Ok(()),
        }
    }

    fn met(self, e: &Encoded) -> bool {
        match self {
            Target::Psnr(p) => e.report.orbit_psnr >= p,
            Target::Bytes(b) => e.bytes.len() as u64 <= b,
        }
    }

    /// By how much `e` meets the target (negative: misses it), in the unit the search
    /// interpolates: dB for a PSNR, `ln(budget / bytes)` for a size.
    fn margin(self, e: &Encoded) -> f64 {
        match self {
            Target::Psnr(p) => e.report.orbit_psnr - p,
            Target::Bytes(b) => (b as f64).ln() - (e.bytes.len() as f64).ln(),
        }
    }

    /// A margin close enough to the target to stop searching.
    fn close(self) -> f64 {
        match self {
            Target::Psnr(_) => CLOSE_PSNR,
            Target::Bytes(_) => CLOSE_BYTES,
        }
    }

    /// Whether `a` is better than `b`, both meeting the target.
    fn better(self, a: &Encoded, b: &Encoded) -> bool {
        match self {
            Target::Psnr(_) => a.bytes.len() < b.bytes.len(),
            Target::Bytes(_) => a.report.orbit_psnr > b.report.orbit_psnr,
        }
    }
}

/// Size of the file of an empty scene (the smallest `.gsc`).
fn empty_file_bytes() -> u64 {
    crate::rate::encode(&Splats::new(0), &crate::rate::EncodeConfig::default()).map_or(0, |(b, _, _)| b.len() as u64)
}

impl Encoder {
    /// Encodes `scene` to `target` by a bracketing search ([`bracket`]: regula falsi, Illinois)
    /// on λ in `ln(1+λ)` over [0, [`MAX_LAMBDA`]]: the PSNR falls and the size shrinks as λ
    /// grows, so the search keeps the boundary between λs that meet the target and λs that do
    /// not, and returns the best encode that met it (the
    /// smallest file for a PSNR, the best PSNR for a size); its report's `target` lists every
    /// encode tried. Each probe is a full [`Encoder::encode_scene`] with this encoder's settings.
    ///
    /// # Errors
    /// An invalid target, a PSNR that even λ = 0 does not reach, or an encode's error.
    pub fn encode_scene_to(&self, scene: &Splats, target: Target, progress: &mut dyn FnMut(&Progress)) -> Result<Encoded> {
        target.validate()?;
        // The probes share the RD search's trials: a configuration's size and distortion do not
        // depend on λ, so each is coded and rendered once for all probes.
        let mut trials = crate::rate::rd::Trials::new(scene).map_err(|e| crate::Error::Input(e.to_string()))?;
        let mut probes = Vec::new();
        let mut best: Option<Encoded> = None;
        let mut probe = |t: f64, best: &mut Option<Encoded>| -> Result<f64> {
            let lambda = Lambda::new(t.exp_m1().max(0.0)).unwrap_or(Lambda::ZERO);
            let enc = Encoder { config: self.config.clone().with_lambda(lambda) };
            let e = enc.encode_scene_with(&mut trials, progress)?;
            probes.push(Probe { lambda, bytes: e.bytes.len(), psnr: e.report.orbit_psnr });
            let met = target.met(&e);
            let margin = target.margin(&e);
            if met && best.as_ref().is_none_or(|b| target.better(&e, b)) {
                *best = Some(e);
            }
            // `met` decides the side even where the margin rounds to 0.
            Ok(if met { margin.max(0.0) } else { margin.min(-f64::MIN_POSITIVE) })
        };
        // Ends: t = 0 (finest) and t = ln(1 + MAX_LAMBDA) (coarsest).
        let ends = [0.0f64, MAX_LAMBDA.ln_1p()];
        let (m0, m1) = (probe(ends[0], &mut best)?, probe(ends[1], &mut best)?);
        if (m0 >= 0.0) != (m1 >= 0.0) {
            bracket(ends[0], m0, ends[1], m1, target.close(), |t| probe(t, &mut best))?;
        }
        let search = TargetSearch { target, probes };
        match best {
            Some(mut e) => {
                e.report.target = Some(search);
                Ok(e)
            }
            None => {
                let finest = search.probes[0];
                Err(crate::Error::Input(match target {
                    Target::Psnr(p) => format!("--target-psnr {p}: not reachable, the finest setting (λ = 0) gives {:.2} dB", finest.psnr),
                    Target::Bytes(b) => format!(
                        "--target-bytes {b}: not reachable, the smallest file found has {} bytes",
                        search.probes.iter().map(|p| p.bytes).min().unwrap_or(0)
                    ),
                }))
            }
        }
    }
}

/// Narrows the bracket between `t0` and `t1`, whose margins `m0` and `m1` have opposite signs
/// (≥ 0: meets the target), by the Illinois variant of regula falsi: the next probe is where the
/// straight line between the ends' margins crosses 0, kept within the middle 80 % of the bracket
/// (bisection where a margin is not finite); an end kept twice in a row has its margin halved,
/// so both ends move. Stops when the bracket is narrower than [`RESOLUTION`], when a probe meets
/// the target by less than `close`, or after [`MAX_INNER_PROBES`] probes. The margin falls as
/// `t` grows for a PSNR target and rises for a size target; either way works.
fn bracket(t0: f64, m0: f64, t1: f64, m1: f64, close: f64, mut probe: impl FnMut(f64) -> Result<f64>) -> Result<()> {
    let (mut good, mut bad) = if m0 >= 0.0 { ((t0, m0), (t1, m1)) } else { ((t1, m1), (t0, m0)) };
    let mut last_met = None;
    for _ in 0..MAX_INNER_PROBES {
        if (good.0 - bad.0).abs() <= RESOLUTION {
            break;
        }
        let f = good.1 / (good.1 - bad.1);
        let f = if f.is_finite() { f.clamp(0.1, 0.9) } else { 0.5 };
        let t = good.0 + f * (bad.0 - good.0);
        let m = probe(t)?;
        let met = m >= 0.0;
        if met {
            good = (t, m);
            if last_met == Some(true) {
                bad.1 *= 0.5;
            }
            if m < close {
                break;
            }
        } else {
            bad = (t, m);
            if last_met == Some(false) {
                good.1 *= 0.5;
            }
        }
        last_met = Some(met);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::encoder::EncoderConfig;

    #[test]
    fn targets_out_of_range_are_refused_with_their_bound() {
        let e = Target::Psnr(-3.0).validate().unwrap_err();
        assert_eq!(e.to_string(), "--target-psnr -3: must be in (0, 200] dB");
        assert!(Target::Psnr(f64::NAN).validate().is_err());
        let min = empty_file_bytes();
        assert!(min > 0);
        assert_eq!(Target::Bytes(min - 1).validate(), Err(InvalidConfig::TargetBytes { value: min - 1, min }));
        assert_eq!(Target::Bytes(min).validate(), Ok(()));
    }

    #[test]
    fn psnr_and_size_targets_are_met_by_the_best_probe() {
        let scene = crate::sample::scene(200, 3);
        let enc = Encoder::new(EncoderConfig::default()).unwrap();
        // A PSNR between the finest and the default setting's.
        let fine = enc.encode_scene(&scene, &mut |_| {}).unwrap().report.orbit_psnr;
        let want = fine - 3.0;
        let e = enc.encode_scene_to(&scene, Target::Psnr(want), &mut |_| {}).unwrap();
        let s = e.report.target.clone().unwrap();
        assert!(e.report.orbit_psnr >= want, "{} < {want}", e.report.orbit_psnr);
        // The smallest file that met it, and no probe that met it is smaller.
        assert!(s.probes.iter().filter(|p| p.psnr >= want).all(|p| p.bytes >= e.bytes.len()), "{s:?}");
        assert!(s.probes.iter().any(|p| p.psnr < want), "the search brackets the target: {s:?}");
        assert!(s.probes.len() <= 2 + MAX_INNER_PROBES, "{s:?}");
        // A size target: half the file the PSNR target gave.
        let budget = e.bytes.len() as u64 / 2;
        let f = enc.encode_scene_to(&scene, Target::Bytes(budget), &mut |_| {}).unwrap();
        let s = f.report.target.clone().unwrap();
        assert!(f.bytes.len() as u64 <= budget);
        assert!(s.probes.iter().filter(|p| p.bytes as u64 <= budget).all(|p| p.psnr <= f.report.orbit_psnr), "{s:?}");
        // Unreachable: more than the finest setting gives.
        let e = enc.encode_scene_to(&scene, Target::Psnr(199.0), &mut |_| {}).unwrap_err();
        assert!(e.to_string().contains("not reachable") && e.exit_code() == 2, "{e}");
    }

    /// Runs [`bracket`] on `margin` over the ends' bracket; returns the probes (t, margin).
    fn probes_of(margin: impl Fn(f64) -> f64, close: f64) -> Vec<(f64, f64)> {
        let t1 = MAX_LAMBDA.ln_1p();
        let mut seen = Vec::new();
        bracket(0.0, margin(0.0), t1, margin(t1), close, |t| {
            seen.push((t, margin(t)));
            Ok(margin(t))
        })
        .unwrap();
        seen
    }

    /// The best probe meeting the target (the largest t for a falling margin) and the closest
    /// one missing it.
    fn bracket_of(probes: &[(f64, f64)]) -> (f64, f64) {
        let good = probes.iter().filter(|p| p.1 >= 0.0).map(|p| p.0).fold(0.0, f64::max);
        let bad = probes.iter().filter(|p| p.1 < 0.0).map(|p| p.0).fold(MAX_LAMBDA.ln_1p(), f64::min);
        (good, bad)
    }

    #[test]
    fn a_smooth_curve_is_resolved_in_fewer_probes_than_bisection() {
        // A PSNR-like margin: 52 dB at λ = 0 falling to 10 dB, crossing the target at t = 3.2.
        let psnr = |t: f64| 10.0 + 42.0 / (1.0 + (t / 2.0).powi(2));
        let target = psnr(3.2);
        let probes = probes_of(|t| psnr(t) - target, CLOSE_PSNR);
        let (good, bad) = bracket_of(&probes);
        assert!(good <= 3.2 && 3.2 < bad, "{probes:?}");
        let met_closely = probes.iter().any(|p| (0.0..CLOSE_PSNR).contains(&p.1));
        assert!(met_closely || bad - good <= RESOLUTION, "{probes:?}");
        assert!(probes.len() < MAX_INNER_PROBES, "{} probes: {probes:?}", probes.len());
    }

    #[test]
    fn a_step_curve_keeps_the_bracket_and_the_probe_budget() {
        // A stepped curve (the RD search's choices are discrete): met below t = 5.3, by 1 dB.
        let probes = probes_of(|t| if t < 5.3 { 1.0 } else { -1.0 }, CLOSE_PSNR);
        let (good, bad) = bracket_of(&probes);
        assert!(good < 5.3 && 5.3 <= bad, "{probes:?}");
        assert_eq!(probes.len(), MAX_INNER_PROBES, "a step is never met closely: {probes:?}");
        // Bisection's 8 halvings would give 20.7 / 256; the clamped steps give at most 2x that.
        assert!(bad - good <= 2.0 * MAX_LAMBDA.ln_1p() / 256.0, "{probes:?}");
    }

    #[test]
    fn a_rising_margin_is_bracketed_from_the_other_end() {
        // A size target: the margin ln(budget / bytes) rises with t; met above t = 7.
        let bytes = |t: f64| 1e6 * (-0.4 * t).exp() + 100.0;
        let budget = bytes(7.0);
        let probes = probes_of(|t| budget.ln() - bytes(t).ln(), CLOSE_BYTES);
        let lowest_met = probes.iter().filter(|p| p.1 >= 0.0).map(|p| p.0).fold(f64::INFINITY, f64::min);
        let highest_missed = probes.iter().filter(|p| p.1 < 0.0).map(|p| p.0).fold(0.0, f64::max);
        assert!(highest_missed < 7.0 && 7.0 <= lowest_met, "{probes:?}");
        assert!(probes.len() < MAX_INNER_PROBES, "{probes:?}");
    }
}

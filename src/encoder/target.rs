//! Encoding to a target instead of a λ: the smallest file that reaches a PSNR, or the best PSNR
//! within a size, found by bisection on λ ([`Encoder::encode_scene_to`]).

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
/// Bisection steps between the ends (in `ln(1+λ)`; 8 steps resolve λ to within ≈8 %).
const BISECTION_STEPS: usize = 8;

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
    /// Encodes `scene` to `target` by bisection on λ in `ln(1+λ)` over [0, [`MAX_LAMBDA`]]: the
    /// PSNR falls and the size shrinks as λ grows, so the search keeps the boundary between λs
    /// that meet the target and λs that do not, and returns the best encode that met it (the
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
        let mut probe = |t: f64, best: &mut Option<Encoded>| -> Result<bool> {
            let lambda = Lambda::new(t.exp_m1().max(0.0)).unwrap_or(Lambda::ZERO);
            let enc = Encoder { config: self.config.clone().with_lambda(lambda) };
            let e = enc.encode_scene_with(&mut trials, progress)?;
            probes.push(Probe { lambda, bytes: e.bytes.len(), psnr: e.report.orbit_psnr });
            let met = target.met(&e);
            if met && best.as_ref().is_none_or(|b| target.better(&e, b)) {
                *best = Some(e);
            }
            Ok(met)
        };
        // Ends: t = 0 (finest) and t = ln(1 + MAX_LAMBDA) (coarsest).
        let (mut lo, mut hi) = (0.0f64, MAX_LAMBDA.ln_1p());
        let (met_lo, met_hi) = (probe(lo, &mut best)?, probe(hi, &mut best)?);
        if !(met_lo && met_hi) && (met_lo || met_hi) {
            // `good` is the end that meets the target; bisect towards the other.
            let psnr_side = met_lo; // a PSNR target is met at small λ, a size target at large λ
            for _ in 0..BISECTION_STEPS {
                let mid = 0.5 * (lo + hi);
                let met = probe(mid, &mut best)?;
                if met == psnr_side {
                    lo = mid;
                } else {
                    hi = mid;
                }
            }
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
        assert!(s.probes.iter().any(|p| p.psnr < want), "the bisection brackets the target: {s:?}");
        assert_eq!(s.probes.len(), 2 + BISECTION_STEPS);
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
}

//! λ, the rate–distortion trade-off: one unit, and every conversion the encoder makes from it.
//!
//! **Unit.** λ is the weight of the rate in `J = D + λ·R`, where
//! * `D` = 255² × mean squared error (RGB, all pixels) of the scene's orbit renders against the
//!   input's, i.e. distortion in 8-bit grey levels squared, and
//! * `R` = the file size in megabits (10⁶ bits).
//!
//! So λ is "distortion units per megabit": λ = 20 (the default) accepts 20 units of 255²·MSE to
//! save one megabit. λ = 0 is the finest setting; larger λ gives smaller files. `encode --lambda`,
//! `sweep --lambdas`, the RD search, the rate term in training and every report use this unit.
//!
//! **Conversions** (all here, nowhere else):
//! * [`Lambda::rate_cost`] — `λ·R` of a file of `bytes` bytes, in `D` units (the RD search).
//! * [`Lambda::training_weight_per_bit`] — the rate term's weight per bit in the trainer's loss
//!   units. The trainer minimises an image loss (L1 + SSIM, WD, WD-R) whose values are ~10³
//!   times smaller per unit of `255²·MSE` than `D` (measured at the default λ: with this scale
//!   a fine-tune moves the file size and PSNR the way the RD search does; docs/codec.md), so the
//!   term adds `λ · 10⁻³ · bits / 10⁶`.
//! * [`Lambda::ladder_step_multiplier`] / [`Lambda::ladder_min_opacity`] — the fixed ladder used
//!   before training from images, when there is no scene to search on: steps × `√(1+λ)` and the
//!   pruning threshold `(1+λ)/255`.

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

/// Bits per megabit: `R` is measured in megabits.
const BITS_PER_MEGABIT: f64 = 1e6;
/// Trainer loss units per unit of `D` (see the module docs).
const TRAIN_LOSS_PER_D: f64 = 1e-3;

/// The rate–distortion trade-off λ ≥ 0 in `J = D + λ·R` (D = 255²·MSE, R = megabits; see the
/// [module docs](self)). Serialised as a plain number.
#[derive(Debug, Clone, Copy, PartialEq, PartialOrd, Serialize, Deserialize)]
#[serde(try_from = "f64", into = "f64")]
pub struct Lambda(f64);

impl Lambda {
    /// The encoder's default, λ = 20.
    pub const DEFAULT: Lambda = Lambda(20.0);
    /// The finest setting, λ = 0.
    pub const ZERO: Lambda = Lambda(0.0);

    /// λ = `v`, or `None` unless `v` is finite and ≥ 0.
    pub fn new(v: f64) -> Option<Lambda> {
        (v.is_finite() && v >= 0.0).then_some(Lambda(v))
    }

    /// The value in the unit of the module docs.
    pub fn get(self) -> f64 {
        self.0
    }

    /// `λ·R` of a file of `bytes` bytes, in `D` units (255²·MSE).
    pub fn rate_cost(self, bytes: usize) -> f64 {
        self.0 * bytes as f64 * 8.0 / BITS_PER_MEGABIT
    }

    /// The rate term's weight per (estimated) bit in the trainer's loss units:
    /// `λ · 10⁻³ / 10⁶` (see the module docs).
    pub fn training_weight_per_bit(self) -> f64 {
        self.0 * TRAIN_LOSS_PER_D / BITS_PER_MEGABIT
    }

    /// Step multiplier of the fixed ladder (training from images): `√(1+λ)`.
    pub fn ladder_step_multiplier(self) -> f32 {
        (1.0 + self.0).sqrt() as f32
    }

    /// Pruning opacity of the fixed ladder: `(1+λ)/255`, at most 2 (everything pruned).
    pub fn ladder_min_opacity(self) -> f32 {
        ((1.0 + self.0) / 255.0).min(2.0) as f32
    }
}

impl Default for Lambda {
    fn default() -> Self {
        Lambda::DEFAULT
    }
}

impl fmt::Display for Lambda {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        fmt::Display::fmt(&self.0, f)
    }
}

impl From<Lambda> for f64 {
    fn from(l: Lambda) -> f64 {
        l.0
    }
}

impl TryFrom<f64> for Lambda {
    type Error = String;
    fn try_from(v: f64) -> Result<Lambda, String> {
        Lambda::new(v).ok_or_else(|| format!("λ {v} is not a finite number >= 0"))
    }
}

/// Parses a number (what `--lambda` takes).
impl FromStr for Lambda {
    type Err = String;
    fn from_str(s: &str) -> Result<Lambda, String> {
        let v: f64 = s.trim().parse().map_err(|_| format!("`{s}` is not a number"))?;
        Lambda::try_from(v)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_finite_non_negative_values_are_lambdas() {
        assert_eq!("24".parse::<Lambda>().unwrap().get(), 24.0);
        assert_eq!("0".parse::<Lambda>(), Ok(Lambda::ZERO));
        for bad in ["-1", "nan", "inf", "x", ""] {
            assert!(bad.parse::<Lambda>().is_err(), "{bad}");
        }
        assert_eq!(serde_json::to_string(&Lambda::DEFAULT).unwrap(), "20.0");
        assert!(serde_json::from_str::<Lambda>("-3").is_err());
    }

    #[test]
    fn conversions_follow_the_documented_unit() {
        let l = Lambda::new(20.0).unwrap();
        assert_eq!(l.rate_cost(125_000), 20.0); // one megabit costs λ units of D
        assert!((l.training_weight_per_bit() - 20e-9).abs() < 1e-20);
        assert_eq!(Lambda::new(3.0).unwrap().ladder_step_multiplier(), 2.0);
        assert_eq!(Lambda::new(1e9).unwrap().ladder_min_opacity(), 2.0);
    }
}

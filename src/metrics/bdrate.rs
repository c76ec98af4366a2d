//! Bjøntegaard deltas between two rate–quality curves.
//!
//! BD-rate is the average rate difference, in percent, between a *test* curve and an *anchor*
//! curve at equal quality: log₁₀(rate) is interpolated as a function of quality on each curve,
//! both are integrated over the quality interval the curves share, and the mean difference `Δ`
//! becomes `(10^Δ − 1)·100`. Negative means the test needs fewer bytes for the same quality.
//! BD-quality (BD-PSNR when the metric is PSNR) swaps the axes: the mean quality difference at
//! equal log-rate.
//!
//! Two interpolations ([`Interpolation`]):
//! - [`Interpolation::Pchip`] (default): piecewise cubic Hermite interpolation with
//!   Fritsch–Carlson slopes (as `scipy.interpolate.PchipInterpolator`), the variant of the JCT-VC /
//!   JVET common-test-conditions sheets (JCTVC-L1100, JVET-T2010). Needs ≥ 2 points per curve.
//! - [`Interpolation::Cubic`]: the original VCEG-M33 least-squares cubic polynomial. Needs ≥ 4.
//!
//! The quality axis may be higher-is-better (PSNR, SSIM) or lower-is-better (ꟻLIP, WD): points are
//! sorted by the interpolation's x-axis, so only the shared interval matters. Tested against the
//! `bjontegaard` Python package (`scripts/bdrate_reference.py`).

/// How each curve is interpolated.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Interpolation {
    /// Piecewise cubic Hermite (Fritsch–Carlson), the modern JCT-VC/JVET choice.
    #[default]
    Pchip,
    /// Classic VCEG-M33 third-order polynomial least-squares fit.
    Cubic,
}

/// A point of a rate–quality curve.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RdPoint {
    /// Rate, any positive unit (bytes here).
    pub rate: f64,
    /// Quality or distortion value of a metric.
    pub quality: f64,
}

/// Why a Bjøntegaard delta cannot be computed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BdError {
    /// Too few points on a curve for the interpolation.
    #[error("a curve has {got} points; {method:?} interpolation needs at least {need}")]
    TooFewPoints { got: usize, need: usize, method: Interpolation },
    /// A rate is not positive or a value is not finite.
    #[error("invalid RD point (rate {rate}, quality {quality}): rates must be positive and values finite")]
    InvalidPoint { rate: f64, quality: f64 },
    /// Two points of a curve share the same x-axis value.
    #[error("two points of a curve have the same {axis} {value}; the curve is not a function of it")]
    DuplicateX { axis: &'static str, value: f64 },
    /// The curves do not overlap on the integration axis.
    #[error("the curves do not overlap in {axis}")]
    NoOverlap { axis: &'static str },
}

/// BD-rate in percent of `test` against `anchor` (negative: `test` is smaller at equal quality).
///
/// # Errors
/// See [`BdError`].
pub fn bd_rate(anchor: &[RdPoint], test: &[RdPoint], method: Interpolation) -> Result<f64, BdError> {
    let curve = |c: &[RdPoint]| c.iter().map(|p| (p.quality, p.rate.log10())).collect::<Vec<_>>();
    let avg = bd_delta(&curve(check(anchor)?), &curve(check(test)?), method, "quality")?;
    Ok((10f64.powf(avg) - 1.0) * 100.0)
}

/// BD-quality (BD-PSNR for PSNR): mean quality difference `test − anchor` at equal log-rate.
///
/// # Errors
/// See [`BdError`].
pub fn bd_quality(anchor: &[RdPoint], test: &[RdPoint], method: Interpolation) -> Result<f64, BdError> {
    let curve = |c: &[RdPoint]| c.iter().map(|p| (p.rate.log10(), p.quality)).collect::<Vec<_>>();
    bd_delta(&curve(check(anchor)?), &curve(check(test)?), method, "rate")
}

fn check(curve: &[RdPoint]) -> Result<&[RdPoint], BdError> {
    match curve.iter().find(|p| !(p.rate > 0.0 && p.rate.is_finite() && p.quality.is_finite())) {
        Some(p) => Err(BdError::InvalidPoint { rate: p.rate, quality: p.quality }),
        None => Ok(curve),
    }
}

/// Mean of `f_test − f_anchor` over the shared x-interval, each curve given as (x, y) points.
fn bd_delta(anchor: &[(f64, f64)], test: &[(f64, f64)], method: Interpolation, axis: &'static str) -> Result<f64, BdError> {
    let (fa, fb) = (Curve::fit(anchor, method, axis)?, Curve::fit(test, method, axis)?);
    let (lo, hi) = (fa.x_min().max(fb.x_min()), fa.x_max().min(fb.x_max()));
    if !(hi > lo) {
        return Err(BdError::NoOverlap { axis });
    }
    Ok((fb.integrate(lo, hi) - fa.integrate(lo, hi)) / (hi - lo))
}

/// An interpolated curve y(x).
enum Curve {
    /// Knots `x`, values `y`, slopes `d` of a piecewise cubic Hermite interpolant.
    Hermite { x: Vec<f64>, y: Vec<f64>, d: Vec<f64> },
    /// Polynomial in `t = (x − shift)/scale`, coefficients lowest order first, on [x_min, x_max].
    Poly { c: [f64; 4], shift: f64, scale: f64, x_min: f64, x_max: f64 },
}

impl Curve {
    fn fit(points: &[(f64, f64)], method: Interpolation, axis: &'static str) -> Result<Self, BdError> {
        let need = match method {
            Interpolation::Pchip => 2,
            Interpolation::Cubic => 4,
        };
        if points.len() < need {
            return Err(BdError::TooFewPoints { got: points.len(), need, method });
        }
        let mut p = points.to_vec();
        p.sort_by(|a, b| a.0.total_cmp(&b.0));
        if let Some(w) = p.windows(2).find(|w| w[0].0 == w[1].0) {
            return Err(BdError::DuplicateX { axis, value: w[0].0 });
        }
        let (x, y): (Vec<f64>, Vec<f64>) = p.into_iter().unzip();
        Ok(match method {
            Interpolation::Pchip => {
                let d = pchip_slopes(&x, &y);
                Curve::Hermite { x, y, d }
            }
            Interpolation::Cubic => {
                let n = x.len() as f64;
                let shift = x.iter().sum::<f64>() / n;
                let scale = (x.iter().map(|v| (v - shift).powi(2)).sum::<f64>() / n).sqrt();
                let t: Vec<f64> = x.iter().map(|v| (v - shift) / scale).collect();
                Curve::Poly { c: cubic_least_squares(&t, &y), shift, scale, x_min: x[0], x_max: x[x.len() - 1] }
            }
        })
    }

    fn x_min(&self) -> f64 {
        match self {
            Curve::Hermite { x, .. } => x[0],
            Curve::Poly { x_min, .. } => *x_min,
        }
    }

    fn x_max(&self) -> f64 {
        match self {
            Curve::Hermite { x, .. } => x[x.len() - 1],
            Curve::Poly { x_max, .. } => *x_max,
        }
    }

    /// ∫ y(x) dx over [lo, hi] (inside the knot range).
    fn integrate(&self, lo: f64, hi: f64) -> f64 {
        match self {
            Curve::Hermite { x, y, d } => {
                let mut total = 0.0;
                for k in 0..x.len() - 1 {
                    let (a, b) = (lo.max(x[k]), hi.min(x[k + 1]));
                    if b <= a {
                        continue;
                    }
                    // In u = x − x_k: y = y_k + d_k u + c2 u² + c3 u³.
                    let h = x[k + 1] - x[k];
                    let delta = (y[k + 1] - y[k]) / h;
                    let c2 = (3.0 * delta - 2.0 * d[k] - d[k + 1]) / h;
                    let c3 = (d[k] + d[k + 1] - 2.0 * delta) / (h * h);
                    let prim = |u: f64| u * (y[k] + u * (d[k] / 2.0 + u * (c2 / 3.0 + u * c3 / 4.0)));
                    total += prim(b - x[k]) - prim(a - x[k]);
                }
                total
            }
            Curve::Poly { c, shift, scale, .. } => {
                let prim = |x: f64| {
                    let t = (x - shift) / scale;
                    t * (c[0] + t * (c[1] / 2.0 + t * (c[2] / 3.0 + t * c[3] / 4.0)))
                };
                scale * (prim(hi) - prim(lo))
            }
        }
    }
}

/// Fritsch–Carlson PCHIP slopes at the knots, as `scipy.interpolate.PchipInterpolator`:
/// weighted harmonic means of the neighbouring secants inside (0 where they change sign), and a
/// shape-preserving one-sided three-point estimate at both ends. Two points give a straight line.
fn pchip_slopes(x: &[f64], y: &[f64]) -> Vec<f64> {
    let n = x.len();
    let h: Vec<f64> = x.windows(2).map(|w| w[1] - w[0]).collect();
    let m: Vec<f64> = (0..n - 1).map(|k| (y[k + 1] - y[k]) / h[k]).collect();
    if n == 2 {
        return vec![m[0]; 2];
    }
    let mut d = vec![0.0; n];
    for k in 1..n - 1 {
        if m[k - 1] * m[k] > 0.0 {
            let (w1, w2) = (2.0 * h[k] + h[k - 1], h[k] + 2.0 * h[k - 1]);
            d[k] = (w1 + w2) / (w1 / m[k - 1] + w2 / m[k]);
        }
    }
    let end = |h0: f64, h1: f64, m0: f64, m1: f64| {
        let d = ((2.0 * h0 + h1) * m0 - h0 * m1) / (h0 + h1);
        if d.signum() != m0.signum() || m0 == 0.0 || d == 0.0 {
            0.0
        } else if m0.signum() != m1.signum() && d.abs() > 3.0 * m0.abs() {
            3.0 * m0
        } else {
            d
        }
    };
    d[0] = end(h[0], h[1], m[0], m[1]);
    d[n - 1] = end(h[n - 2], h[n - 3], m[n - 2], m[n - 3]);
    d
}

/// Least-squares cubic `c0 + c1 t + c2 t² + c3 t³` through (t, y), by the normal equations
/// (t is standardised, so they are well conditioned) and Gaussian elimination with pivoting.
fn cubic_least_squares(t: &[f64], y: &[f64]) -> [f64; 4] {
    let mut a = [[0.0f64; 5]; 4];
    for (ti, yi) in t.iter().zip(y) {
        let pw = [1.0, *ti, ti * ti, ti * ti * ti];
        for r in 0..4 {
            for c in 0..4 {
                a[r][c] += pw[r] * pw[c];
            }
            a[r][4] += pw[r] * yi;
        }
    }
    for col in 0..4 {
        let piv = (col..4).max_by(|&i, &j| a[i][col].abs().total_cmp(&a[j][col].abs())).unwrap_or(col);
        a.swap(col, piv);
        for r in 0..4 {
            if r != col && a[col][col] != 0.0 {
                let f = a[r][col] / a[col][col];
                for c in col..5 {
                    a[r][c] -= f * a[col][c];
                }
            }
        }
    }
    std::array::from_fn(|i| a[i][4] / a[i][i])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pts(rate: &[f64], q: &[f64]) -> Vec<RdPoint> {
        rate.iter().zip(q).map(|(&rate, &quality)| RdPoint { rate, quality }).collect()
    }

    // Reference values: scripts/bdrate_reference.py (bjontegaard 1.3.0). Data set "x265" is the
    // libx265 example of that package's README; "six" has six points per curve.
    const X265: ([f64; 4], [f64; 4], [f64; 4], [f64; 4]) = (
        [9487.76, 4593.60, 2486.44, 1358.24],
        [40.037, 38.615, 36.845, 34.851],
        [9787.80, 4469.00, 2451.52, 1356.24],
        [40.121, 38.651, 36.970, 34.987],
    );
    const SIX: ([f64; 6], [f64; 6], [f64; 6], [f64; 6]) = (
        [120.0, 250.0, 510.0, 1000.0, 2100.0, 4000.0],
        [0.61, 0.70, 0.78, 0.83, 0.88, 0.905],
        [90.0, 200.0, 380.0, 900.0, 1500.0, 3900.0],
        [0.60, 0.71, 0.775, 0.85, 0.87, 0.91],
    );

    #[test]
    fn matches_the_bjontegaard_package() {
        let cases: [(&[f64], &[f64], &[f64], &[f64], Interpolation, f64, f64); 4] = [
            (&X265.0, &X265.1, &X265.2, &X265.3, Interpolation::Pchip, -4.417485350589, 0.119692785425),
            (&X265.0, &X265.1, &X265.2, &X265.3, Interpolation::Cubic, -4.420462706125, 0.120409419115),
            (&SIX.0, &SIX.1, &SIX.2, &SIX.3, Interpolation::Pchip, -23.771053139250, 0.021658719810),
            (&SIX.0, &SIX.1, &SIX.2, &SIX.3, Interpolation::Cubic, -23.155803605690, 0.022026018048),
        ];
        for (ra, qa, rt, qt, method, want_rate, want_q) in cases {
            let (a, t) = (pts(ra, qa), pts(rt, qt));
            let r = bd_rate(&a, &t, method).unwrap();
            let q = bd_quality(&a, &t, method).unwrap();
            assert!((r - want_rate).abs() < 1e-8, "{method:?} rate {r} vs {want_rate}");
            assert!((q - want_q).abs() < 1e-10, "{method:?} quality {q} vs {want_q}");
        }
    }

    #[test]
    fn a_curve_scaled_in_rate_has_the_scale_as_bd_rate() {
        // Test = anchor with every rate × 0.8: exactly −20 % at every quality, for both methods.
        let a = pts(&X265.0, &X265.1);
        let t: Vec<RdPoint> = a.iter().map(|p| RdPoint { rate: p.rate * 0.8, ..*p }).collect();
        for m in [Interpolation::Pchip, Interpolation::Cubic] {
            assert!((bd_rate(&a, &t, m).unwrap() + 20.0).abs() < 1e-9);
            assert!(bd_rate(&a, &a, m).unwrap().abs() < 1e-12);
        }
    }

    #[test]
    fn direction_and_order_of_the_quality_axis_do_not_matter() {
        // A lower-is-better metric (negated) and shuffled points give the same BD-rate.
        let (a, t) = (pts(&SIX.0, &SIX.1), pts(&SIX.2, &SIX.3));
        let neg = |c: &[RdPoint]| c.iter().rev().map(|p| RdPoint { quality: -p.quality, ..*p }).collect::<Vec<_>>();
        let want = bd_rate(&a, &t, Interpolation::Pchip).unwrap();
        let got = bd_rate(&neg(&a), &neg(&t), Interpolation::Pchip).unwrap();
        assert!((want - got).abs() < 1e-9);
    }

    #[test]
    fn two_points_interpolate_linearly() {
        // log10 rate linear in quality: anchor 100→1000 over q 0→1, test 50→500: −50 %.
        let a = pts(&[100.0, 1000.0], &[0.0, 1.0]);
        let t = pts(&[50.0, 500.0], &[0.0, 1.0]);
        assert!((bd_rate(&a, &t, Interpolation::Pchip).unwrap() + 50.0).abs() < 1e-9);
    }

    #[test]
    fn bad_curves_are_reported() {
        let a = pts(&X265.0, &X265.1);
        assert!(matches!(bd_rate(&a[..3], &a, Interpolation::Cubic), Err(BdError::TooFewPoints { got: 3, need: 4, .. })));
        let zero = pts(&[0.0, 10.0], &[1.0, 2.0]);
        assert!(matches!(bd_rate(&zero, &a, Interpolation::Pchip), Err(BdError::InvalidPoint { .. })));
        let dup = pts(&[1.0, 10.0, 20.0], &[1.0, 2.0, 2.0]);
        assert!(matches!(bd_rate(&dup, &a, Interpolation::Pchip), Err(BdError::DuplicateX { .. })));
        let far = pts(&[1.0, 10.0], &[100.0, 200.0]);
        assert!(matches!(bd_rate(&far, &a, Interpolation::Pchip), Err(BdError::NoOverlap { .. })));
    }
}

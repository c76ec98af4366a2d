//! The learned entropy model used as the rate term in training: a factorized density per
//! channel (a Laplace whose location and scale are trained to minimise the coded bits, evaluated
//! on quantisation bins), with gradients of the bits w.r.t. the Gaussians' raw parameters.
//!
//! At encode time the trained density is rendered to integer weights over the table range
//! ([`LearnedChannel::weights`]) — a candidate for the stored table next to the static histogram.

/// Likelihood floor (DESIGN §5): no log of zero.
pub const LIKELIHOOD_FLOOR: f64 = 1e-9;

/// A discretised Laplace density over one channel's values, with trainable parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LearnedChannel {
    pub mu: f64,
    pub log_b: f64,
}

/// Bits of one value and their derivatives.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BitsGrad {
    pub bits: f64,
    /// d bits / d value.
    pub d_value: f64,
    pub d_mu: f64,
    pub d_log_b: f64,
    /// d bits / d step (the bin width).
    pub d_step: f64,
}

impl LearnedChannel {
    /// A density fitted to `values` by moments (median, mean absolute deviation).
    pub fn fit_init(values: &[f32]) -> LearnedChannel {
        if values.is_empty() {
            return LearnedChannel { mu: 0.0, log_b: 0.0 };
        }
        let mut v: Vec<f64> = values.iter().map(|&x| f64::from(x)).collect();
        v.sort_by(f64::total_cmp);
        let mu = v[v.len() / 2];
        let mad = v.iter().map(|x| (x - mu).abs()).sum::<f64>() / v.len() as f64;
        LearnedChannel { mu, log_b: mad.max(1e-6).ln() }
    }

    fn cdf_and_pdf(&self, x: f64) -> (f64, f64) {
        let b = self.log_b.exp();
        let z = (x - self.mu) / b;
        let e = (-z.abs()).exp();
        let pdf = 0.5 * e / b;
        let cdf = if z < 0.0 { 0.5 * e } else { 1.0 - 0.5 * e };
        (cdf, pdf)
    }

    /// Bits of the bin `[y − step/2, y + step/2]` and gradients (continuous relaxation of
    /// quantisation: at a bin centre this is the exact ideal code length of that bin).
    pub fn bits(&self, y: f64, step: f64) -> BitsGrad {
        let (hi, lo) = (y + 0.5 * step, y - 0.5 * step);
        let (fh, ph) = self.cdf_and_pdf(hi);
        let (fl, pl) = self.cdf_and_pdf(lo);
        let p = fh - fl;
        if p <= LIKELIHOOD_FLOOR {
            return BitsGrad { bits: -LIKELIHOOD_FLOOR.log2(), d_value: 0.0, d_mu: 0.0, d_log_b: 0.0, d_step: 0.0 };
        }
        let k = -1.0 / (p * std::f64::consts::LN_2);
        let dp_dy = ph - pl;
        let dp_dlogb = -ph * (hi - self.mu) + pl * (lo - self.mu);
        BitsGrad { bits: -p.log2(), d_value: k * dp_dy, d_mu: -k * dp_dy, d_log_b: k * dp_dlogb, d_step: k * 0.5 * (ph + pl) }
    }

    /// Trains the density on quantised `values` (bin centres) by `iters` steps of gradient
    /// descent on the mean bits; returns the final mean bits per value.
    pub fn train(&mut self, values: &[f32], step: f64, iters: usize) -> f64 {
        let mut lr = 0.5;
        let mut last = f64::INFINITY;
        for _ in 0..iters {
            let (mut bits, mut gm, mut gb) = (0.0, 0.0, 0.0);
            for &v in values {
                let g = self.bits(f64::from(v), step);
                bits += g.bits;
                gm += g.d_mu;
                gb += g.d_log_b;
            }
            let n = values.len().max(1) as f64;
            let bits = bits / n;
            if bits > last {
                lr *= 0.5;
            }
            last = bits;
            let b = self.log_b.exp();
            self.mu -= lr * b * gm / n;
            self.log_b -= lr * gb / n;
        }
        last
    }

    /// The density as table weights over integer values `lo .. lo + n` (values × `step`) plus
    /// the escape (the remaining tail mass), scaled to at most `scale`.
    pub fn weights(&self, lo: i32, n: usize, step: f64) -> Vec<f64> {
        let mut w: Vec<f64> = (0..n).map(|s| self.bits((lo as f64 + s as f64) * step, step).bits).map(|b| (-b).exp2()).collect();
        let inside: f64 = w.iter().sum();
        w.push((1.0 - inside).max(0.0));
        w
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gradients_match_finite_differences() {
        let m = LearnedChannel { mu: 0.3, log_b: -1.2 };
        for y in [-1.0, 0.0, 0.25, 0.31, 2.0] {
            let g = m.bits(y, 0.1);
            let h = 1e-6;
            let fd = |f: &dyn Fn(f64) -> f64| (f(h) - f(-h)) / (2.0 * h);
            let dy = fd(&|e| m.bits(y + e, 0.1).bits);
            let dmu = fd(&|e| LearnedChannel { mu: m.mu + e, ..m }.bits(y, 0.1).bits);
            let db = fd(&|e| LearnedChannel { log_b: m.log_b + e, ..m }.bits(y, 0.1).bits);
            let ds = fd(&|e| m.bits(y, 0.1 + e).bits);
            assert!((g.d_step - ds).abs() < 1e-4 * (1.0 + ds.abs()), "y={y}: {} vs {ds}", g.d_step);
            assert!((g.d_value - dy).abs() < 1e-4 * (1.0 + dy.abs()), "y={y}: {} vs {dy}", g.d_value);
            assert!((g.d_mu - dmu).abs() < 1e-4 * (1.0 + dmu.abs()));
            assert!((g.d_log_b - db).abs() < 1e-4 * (1.0 + db.abs()));
        }
    }

    #[test]
    fn training_lowers_bits_towards_the_entropy() {
        // Laplace-like integers with scale ≈ 2.
        let values: Vec<f32> = (0..4000)
            .map(|i| {
                let u = ((i * 7919) % 4000) as f64 / 4000.0 + 1.0 / 8000.0;
                let x = if u < 0.5 { 2.0 * (2.0 * u).ln() } else { -2.0 * (2.0 - 2.0 * u).ln() };
                x.round() as f32
            })
            .collect();
        let mut m = LearnedChannel { mu: 3.0, log_b: 2.0 };
        let before = m.train(&values, 1.0, 1);
        let after = m.train(&values, 1.0, 200);
        assert!(after < before - 0.3, "{before} -> {after}");
        assert!((m.mu).abs() < 0.3 && (m.log_b.exp() - 2.0).abs() < 0.4, "{m:?}");
    }
}

//! The one optimiser update rule, Adam, for any flat list of `f32` values: the trainer's
//! Gaussian parameters (`crate::train::adam::Adam`) and the rate term's learned log steps
//! (`crate::rate::term`). A leaf module, so both can use it without depending on each other.

/// Adam's hyper-parameters and step count; [`AdamRule::update`] is the update rule.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AdamRule {
    pub beta1: f32,
    pub beta2: f32,
    pub eps: f32,
    /// Steps taken so far (the bias corrections depend on it).
    pub step: u64,
}

impl Default for AdamRule {
    /// The reference 3DGS hyper-parameters (β₁ 0.9, β₂ 0.999, ε 10⁻¹⁵).
    fn default() -> Self {
        AdamRule { beta1: 0.9, beta2: 0.999, eps: 1e-15, step: 0 }
    }
}

/// The bias corrections of one step (see [`AdamRule::begin_step`]).
#[derive(Debug, Clone, Copy)]
pub struct Correction {
    /// `1 − β₁ᵗ`.
    bc1: f64,
    /// `√(1 − β₂ᵗ)`.
    sqrt_bc2: f32,
}

impl AdamRule {
    /// Counts a step and returns its bias corrections.
    pub fn begin_step(&mut self) -> Correction {
        self.step += 1;
        let bc1 = 1.0 - f64::from(self.beta1).powf(self.step as f64);
        let bc2 = 1.0 - f64::from(self.beta2).powf(self.step as f64);
        Correction { bc1, sqrt_bc2: bc2.sqrt() as f32 }
    }

    /// Updates values `p` with gradients `g` and moments `m`, `v` (all the same length) at
    /// learning rate `lr`: `p −= lr·m̂ / (√v̂ + ε)` with bias-corrected moments.
    pub fn update(&self, c: Correction, lr: f32, p: &mut [f32], g: &[f32], m: &mut [f32], v: &mut [f32]) {
        let step_size = (f64::from(lr) / c.bc1) as f32;
        let (b1, b2, eps) = (self.beta1, self.beta2, self.eps);
        for (((p, &g), m), v) in p.iter_mut().zip(g).zip(m.iter_mut()).zip(v.iter_mut()) {
            *m = b1 * *m + (1.0 - b1) * g;
            *v = b2 * *v + (1.0 - b2) * g * g;
            *p -= step_size * *m / (v.sqrt() / c.sqrt_bc2 + eps);
        }
    }
}

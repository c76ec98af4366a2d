//! Adam over the Gaussian parameters, one learning rate per attribute [`Group`], with the one
//! update rule [`AdamRule`] (which the rate term's learned log steps use too).

use gscodec_decoder::Splats;
use rayon::prelude::*;

pub use crate::optim::AdamRule;
use crate::rate::group::{self, Group};

/// A zero-filled scene of the same shape as `s` (a gradient or moment buffer).
pub fn zeros_like(s: &Splats) -> Splats {
    let n = s.len();
    Splats {
        sh_degree: s.sh_degree,
        positions: vec![[0.0; 3]; n],
        log_scales: vec![[0.0; 3]; n],
        rotations: vec![[0.0; 4]; n],
        opacity_logits: vec![0.0; n],
        sh_dc: vec![[0.0; 3]; n],
        sh_rest: vec![0.0; s.sh_rest.len()],
    }
}

/// First non-finite value, as `(gaussian, group)`.
pub fn first_non_finite(s: &Splats) -> Option<(usize, Group)> {
    for g in group::present(s.sh_degree) {
        let bad = group::per_gaussian(s, g).position(|v| v.iter().any(|x| !x.is_finite()));
        if let Some(i) = bad {
            return Some((i, g));
        }
    }
    None
}

/// Values per parallel work item of [`Adam::step`].
const ADAM_CHUNK: usize = 1 << 14;

/// Adam state for the Gaussian parameters (moments shaped like the scene).
#[derive(Debug, Clone)]
pub struct Adam {
    pub m: Splats,
    pub v: Splats,
    pub rule: AdamRule,
}

impl Adam {
    pub fn new(params: &Splats) -> Self {
        Adam { m: zeros_like(params), v: zeros_like(params), rule: AdamRule::default() }
    }

    /// One step: `lr(group)` gives each attribute group's learning rate.
    pub fn step(&mut self, params: &mut Splats, grad: &Splats, lr: impl Fn(Group) -> f32) {
        let c = self.rule.begin_step();
        let degree = params.sh_degree;
        for g in group::present(degree) {
            let (stride, r) = group::layout(g, degree);
            let lr = lr(g);
            let (p, gr) = (group::values_mut(params, g), group::values(grad, g));
            let (m, v) = (group::values_mut(&mut self.m, g), group::values_mut(&mut self.v, g));
            // Element-wise, so parallel chunks give bit-identical results for any thread count.
            let rule = &self.rule;
            if r.len() == stride {
                // The whole field: chunks of values.
                p.par_chunks_mut(ADAM_CHUNK)
                    .zip(gr.par_chunks(ADAM_CHUNK))
                    .zip(m.par_chunks_mut(ADAM_CHUNK))
                    .zip(v.par_chunks_mut(ADAM_CHUNK))
                    .for_each(|(((p, gr), m), v)| rule.update(c, lr, p, gr, m, v));
                continue;
            }
            p.par_chunks_exact_mut(stride)
                .zip(gr.par_chunks_exact(stride))
                .zip(m.par_chunks_exact_mut(stride))
                .zip(v.par_chunks_exact_mut(stride))
                .with_min_len(ADAM_CHUNK / stride.max(1))
                .for_each(|(((p, gr), m), v)| {
                    let r = r.clone();
                    rule.update(c, lr, &mut p[r.clone()], &gr[r.clone()], &mut m[r.clone()], &mut v[r]);
                });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn first_steps_move_by_the_learning_rate_against_the_gradient_sign() {
        // Adam's first step is lr·sign(g) (m̂ = g, v̂ = g²), whatever the gradient's size.
        let mut s = Splats::new(2);
        s.push([0.0; 3], [0.0; 3], [1.0, 0.0, 0.0, 0.0], 0.0, [0.0; 3], &[0.0; 24]);
        let mut g = zeros_like(&s);
        g.positions[0] = [3.0, -1e-3, 0.0];
        g.sh_rest[0] = 5.0; // band 1
        g.sh_rest[9] = -7.0; // band 2
        let mut adam = Adam::new(&s);
        let lr = |g: Group| match g {
            Group::Position => 0.1,
            Group::Sh1 => 0.01,
            Group::Sh2 => 0.02,
            _ => 1.0,
        };
        adam.step(&mut s, &g, lr);
        let close = |a: f32, b: f32| (a - b).abs() < 1e-6;
        assert!(close(s.positions[0][0], -0.1) && close(s.positions[0][1], 0.1) && s.positions[0][2] == 0.0, "{:?}", s.positions);
        assert!(close(s.sh_rest[0], -0.01) && close(s.sh_rest[9], 0.02), "{:?}", &s.sh_rest[..12]);
        assert_eq!(s.log_scales[0], [0.0; 3]);
        assert_eq!(first_non_finite(&s), None);
        s.sh_rest[20] = f32::NAN; // coefficient 6: band 2
        assert_eq!(first_non_finite(&s), Some((0, Group::Sh2)));
    }
}

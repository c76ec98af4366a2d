//! Adam with one learning rate per parameter group, over `Splats`-shaped moment buffers.

use gscodec_decoder::Splats;
use rayon::prelude::*;

/// The parameter groups of a scene, in `Splats` field order.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Group {
    Position,
    LogScale,
    Rotation,
    Opacity,
    ShDc,
    ShRest,
}

impl Group {
    pub const ALL: [Group; 6] = [Group::Position, Group::LogScale, Group::Rotation, Group::Opacity, Group::ShDc, Group::ShRest];

    /// Name used in messages (matches the `.ply` property families).
    pub fn name(self) -> &'static str {
        match self {
            Group::Position => "position",
            Group::LogScale => "scale",
            Group::Rotation => "rotation",
            Group::Opacity => "opacity",
            Group::ShDc => "f_dc",
            Group::ShRest => "f_rest",
        }
    }

    /// Values per Gaussian in this group for a scene of `s`'s SH degree.
    pub fn width(self, s: &Splats) -> usize {
        match self {
            Group::Position | Group::LogScale | Group::ShDc => 3,
            Group::Rotation => 4,
            Group::Opacity => 1,
            Group::ShRest => s.rest_coeffs() * 3,
        }
    }
}

/// The flat values of one group.
pub fn group(s: &Splats, g: Group) -> &[f32] {
    match g {
        Group::Position => s.positions.as_flattened(),
        Group::LogScale => s.log_scales.as_flattened(),
        Group::Rotation => s.rotations.as_flattened(),
        Group::Opacity => &s.opacity_logits,
        Group::ShDc => s.sh_dc.as_flattened(),
        Group::ShRest => &s.sh_rest,
    }
}

/// The flat values of one group, mutable.
pub fn group_mut(s: &mut Splats, g: Group) -> &mut [f32] {
    match g {
        Group::Position => s.positions.as_flattened_mut(),
        Group::LogScale => s.log_scales.as_flattened_mut(),
        Group::Rotation => s.rotations.as_flattened_mut(),
        Group::Opacity => &mut s.opacity_logits,
        Group::ShDc => s.sh_dc.as_flattened_mut(),
        Group::ShRest => &mut s.sh_rest,
    }
}

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

/// First index of a non-finite value in a group, as `(gaussian, group)`.
pub fn first_non_finite(s: &Splats) -> Option<(usize, Group)> {
    for g in Group::ALL {
        let w = g.width(s).max(1);
        if let Some(i) = group(s, g).iter().position(|v| !v.is_finite()) {
            return Some((i / w, g));
        }
    }
    None
}

/// Values per parallel work item of [`Adam::step`].
const ADAM_CHUNK: usize = 1 << 14;

/// Adam state (moments shaped like the scene) with the reference hyper-parameters.
#[derive(Debug, Clone)]
pub struct Adam {
    pub m: Splats,
    pub v: Splats,
    pub step: u64,
    pub beta1: f32,
    pub beta2: f32,
    pub eps: f32,
}

impl Adam {
    pub fn new(params: &Splats) -> Self {
        Adam { m: zeros_like(params), v: zeros_like(params), step: 0, beta1: 0.9, beta2: 0.999, eps: 1e-15 }
    }

    /// One step: `lr(group)` gives each group's learning rate.
    pub fn step(&mut self, params: &mut Splats, grad: &Splats, lr: impl Fn(Group) -> f32) {
        self.step += 1;
        let bc1 = 1.0 - (self.beta1 as f64).powf(self.step as f64);
        let bc2 = 1.0 - (self.beta2 as f64).powf(self.step as f64);
        let (b1, b2, eps) = (self.beta1, self.beta2, self.eps);
        for g in Group::ALL {
            let step_size = (lr(g) as f64 / bc1) as f32;
            let sqrt_bc2 = bc2.sqrt() as f32;
            let p = group_mut(params, g);
            let gr = group(grad, g);
            let m = group_mut(&mut self.m, g);
            let v = group_mut(&mut self.v, g);
            // Element-wise, so parallel chunks give bit-identical results for any thread count.
            p.par_chunks_mut(ADAM_CHUNK)
                .zip(gr.par_chunks(ADAM_CHUNK))
                .zip(m.par_chunks_mut(ADAM_CHUNK))
                .zip(v.par_chunks_mut(ADAM_CHUNK))
                .for_each(|(((p, gr), m), v)| {
                    for i in 0..p.len() {
                        let gi = gr[i];
                        m[i] = b1 * m[i] + (1.0 - b1) * gi;
                        v[i] = b2 * v[i] + (1.0 - b2) * gi * gi;
                        p[i] -= step_size * m[i] / (v[i].sqrt() / sqrt_bc2 + eps);
                    }
                });
        }
    }
}

//! Adaptive density control of the reference 3DGS trainer: clone small and split large Gaussians
//! whose accumulated view-space positional gradient is large, prune transparent and oversized
//! ones, and reset opacities periodically.

use super::adam::{zeros_like, Adam};
use crate::rng::Rng;
use glam::Vec3;
use gscodec_decoder::{math, Splats};

/// Per-Gaussian statistics gathered between densification steps.
#[derive(Debug, Clone, Default)]
pub struct DensifyStats {
    /// Sum of `|dL/d mean2d|` (NDC units) over the views where the Gaussian was drawn.
    pub grad_accum: Vec<f32>,
    pub count: Vec<u32>,
    /// Largest screen radius (pixels, rescaled to an 800-pixel image) since the last step.
    pub max_radius: Vec<f32>,
}

impl DensifyStats {
    pub fn new(n: usize) -> Self {
        DensifyStats { grad_accum: vec![0.0; n], count: vec![0; n], max_radius: vec![0.0; n] }
    }
}

/// Thresholds of one densification step (all scene-relative).
#[derive(Debug, Clone, Copy)]
pub struct DensifyParams {
    pub grad_threshold: f32,
    /// Clone when the largest scale is at most `percent_dense * extent`, split otherwise.
    pub percent_dense: f32,
    pub extent: f32,
    pub min_opacity: f32,
    /// Prune Gaussians whose screen radius (800-pixel equivalent) exceeded this; `None` = off.
    pub max_screen_radius: Option<f32>,
    /// Prune Gaussians larger than this fraction of the extent (with `max_screen_radius`).
    pub max_world_fraction: f32,
    /// Do not grow beyond this many Gaussians.
    pub max_gaussians: usize,
}

fn copy_one(dst: &mut Splats, src: &Splats, i: usize) {
    dst.push(src.positions[i], src.log_scales[i], src.rotations[i], src.opacity_logits[i], src.sh_dc[i], src.rest_of(i));
}

fn max_scale(s: &Splats, i: usize) -> f32 {
    s.log_scales[i].iter().fold(f32::MIN, |a, &b| a.max(b)).exp()
}

/// Appends `extra` to the parameters and zero moments to Adam.
fn append(params: &mut Splats, adam: &mut Adam, extra: &Splats) {
    for i in 0..extra.len() {
        copy_one(params, extra, i);
    }
    let z = zeros_like(extra);
    for i in 0..z.len() {
        copy_one(&mut adam.m, &z, i);
        copy_one(&mut adam.v, &z, i);
    }
}

/// Keeps the Gaussians with `keep[i]` in the parameters and the Adam moments.
pub fn retain(params: &mut Splats, adam: &mut Adam, keep: &[bool]) {
    params.retain_indices(|i| keep[i]);
    adam.m.retain_indices(|i| keep[i]);
    adam.v.retain_indices(|i| keep[i]);
}

/// One densify-and-prune step; returns `(cloned, split, pruned)`.
pub fn densify_and_prune(
    params: &mut Splats,
    adam: &mut Adam,
    stats: &DensifyStats,
    p: &DensifyParams,
    rng: &mut Rng,
) -> (usize, usize, usize) {
    densify_and_prune_keeping(params, adam, stats, p, rng, 0)
}

/// [`densify_and_prune`] that never leaves fewer than `floor` Gaussians: when pruning would, the
/// most opaque of the pruned ones (ties by index) are kept.
pub fn densify_and_prune_keeping(
    params: &mut Splats,
    adam: &mut Adam,
    stats: &DensifyStats,
    p: &DensifyParams,
    rng: &mut Rng,
    floor: usize,
) -> (usize, usize, usize) {
    let n = params.len();
    let grads: Vec<f32> = (0..n).map(|i| if stats.count[i] > 0 { stats.grad_accum[i] / stats.count[i] as f32 } else { 0.0 }).collect();
    let room = p.max_gaussians.saturating_sub(n);
    let mut cloned = Splats::new(params.sh_degree);
    let mut split = Splats::new(params.sh_degree);
    let mut remove = vec![false; n];
    let mut n_split = 0;
    let limit = p.percent_dense * p.extent;
    // Largest gradients first when the budget is short.
    let mut order: Vec<usize> = (0..n).filter(|&i| grads[i] >= p.grad_threshold).collect();
    order.sort_by(|&a, &b| grads[b].total_cmp(&grads[a]).then(a.cmp(&b)));
    let mut added = 0;
    for &i in &order {
        if max_scale(params, i) <= limit {
            if added + 1 > room {
                continue;
            }
            copy_one(&mut cloned, params, i);
            added += 1;
        } else {
            if added + 1 > room {
                continue;
            }
            // Two samples from the Gaussian itself, each with scale / 1.6.
            let r = math::quat_to_mat3(params.rotations[i]);
            let s = Vec3::from_array(params.log_scales[i].map(f32::exp));
            let new_ls = params.log_scales[i].map(|l| l - (1.6f32).ln());
            for _ in 0..2 {
                let off = r * (Vec3::new(rng.normal(), rng.normal(), rng.normal()) * s);
                let pos = (Vec3::from_array(params.positions[i]) + off).to_array();
                split.push(pos, new_ls, params.rotations[i], params.opacity_logits[i], params.sh_dc[i], params.rest_of(i));
            }
            remove[i] = true;
            n_split += 1;
            added += 1;
        }
    }
    let n_cloned = cloned.len();
    append(params, adam, &cloned);
    append(params, adam, &split);
    // Prune: split originals, transparent, and (optionally) oversized Gaussians. The statistics
    // describe the original Gaussians; new ones are never pruned for size in this step.
    let mut keep = vec![true; params.len()];
    let mut pruned = 0;
    for i in 0..params.len() {
        let op = math::sigmoid(params.opacity_logits[i]);
        let mut drop = (i < n && remove[i]) || op < p.min_opacity;
        if let Some(max_r) = p.max_screen_radius {
            let big_screen = i < n && stats.max_radius[i] > max_r;
            drop |= big_screen || max_scale(params, i) > p.max_world_fraction * p.extent;
        }
        if drop {
            keep[i] = false;
            if !(i < n && remove[i]) {
                pruned += 1;
            }
        }
    }
    let kept = keep.iter().filter(|&&k| k).count();
    if kept < floor {
        // Split originals stay removed (their two halves are kept); rescue the most opaque.
        let mut rescue: Vec<usize> = (0..params.len()).filter(|&i| !keep[i] && (i >= n || !remove[i])).collect();
        rescue.sort_by(|&a, &b| params.opacity_logits[b].total_cmp(&params.opacity_logits[a]).then(a.cmp(&b)));
        for &i in rescue.iter().take(floor - kept) {
            keep[i] = true;
            pruned -= 1;
        }
    }
    retain(params, adam, &keep);
    (n_cloned, n_split, pruned)
}

/// Sets every opacity to at most `max_opacity` (and zeroes the opacity moments, as the reference
/// replaces that optimiser state).
pub fn reset_opacity(params: &mut Splats, adam: &mut Adam, max_opacity: f32) {
    let cap = (max_opacity / (1.0 - max_opacity)).ln();
    for (l, (m, v)) in params.opacity_logits.iter_mut().zip(adam.m.opacity_logits.iter_mut().zip(adam.v.opacity_logits.iter_mut())) {
        *l = l.min(cap);
        *m = 0.0;
        *v = 0.0;
    }
}

//! The anchor profile's trainable model in `f32` (what [`super::fixed`] turns into the integers of
//! SPEC §12): Gaussians at fixed grid positions, grouped into anchor cells, each anchor with F
//! features and a base log scale, and one MLP `F + 3 → H (ReLU) → P` shared by all, evaluated per
//! Gaussian on its anchor's features and its cell inside the anchor. Forward and backward by
//! hand: the MLP is two dense layers.

use gscodec_decoder::bitstream::anchors::{outputs_per_gaussian, POSITION_INPUTS, VALUE_BOUND};
use gscodec_decoder::Splats;
use rayon::prelude::*;

/// The float model. Features are in integer units (the file stores `round(feature)`), outputs in
/// value units (log σ relative to the anchor's base).
#[derive(Debug, Clone)]
pub struct Model {
    /// Features F, hidden units H, output SH degree.
    pub f: usize,
    pub h: usize,
    pub degree: u8,
    /// Anchor cells are `2^shift` grid cells wide.
    pub shift: u8,
    /// Per Gaussian (file order): position (dequantised), anchor, cell inside the anchor.
    pub positions: Vec<[f32; 3]>,
    pub anchor_of: Vec<u32>,
    pub local: Vec<[i32; 3]>,
    /// `A × F`.
    pub feat: Vec<f32>,
    /// `A × 3`, log σ.
    pub base: Vec<f32>,
    /// `H × (F + 3 + 1)`: weights, then bias, per hidden unit.
    pub w1: Vec<f32>,
    /// `P × (H + 1)`.
    pub w2: Vec<f32>,
}

/// Gaussians per run of the backward pass's deterministic sum.
const RUN: usize = 512;

/// Per-Gaussian MLP activations kept for the backward pass.
pub struct Activations {
    /// `N × H` pre-activations of the hidden layer.
    pub pre: Vec<f32>,
    /// `N × P` outputs.
    pub out: Vec<f32>,
}

impl Model {
    /// Output channels per Gaussian, P.
    pub fn p(&self) -> usize {
        outputs_per_gaussian(self.degree)
    }

    /// MLP inputs, F + 3.
    pub fn inputs(&self) -> usize {
        self.f + POSITION_INPUTS
    }

    /// Number of anchors.
    pub fn anchors(&self) -> usize {
        self.base.len() / 3
    }

    /// The features as the file stores them: rounded, within ±(2^24 − 1) (SPEC §12.1).
    pub fn integer_features(&self) -> Vec<i32> {
        let bound = (VALUE_BOUND - 1) as f32;
        self.feat.iter().map(|v| v.round().clamp(-bound, bound) as i32).collect()
    }

    /// Gaussian `i`'s MLP input: its anchor's rounded features (the straight-through estimator
    /// passes the gradient as if they were not rounded), then its cell inside the anchor scaled
    /// to `(−½, ½)` ([`Model::local_input`]).
    fn input(&self, i: usize, x: &mut Vec<f32>) {
        let a = self.anchor_of[i] as usize;
        x.clear();
        x.extend(self.feat[a * self.f..][..self.f].iter().map(|v| v.round()));
        x.extend(self.local[i].iter().map(|&v| self.local_input(v)));
    }

    /// The float MLP's input for a cell `l` inside the anchor: `(l + ½) / 2^shift − ½`, affine
    /// in `l`, so the fixed-point MLP takes `l` itself (SPEC §12.2) with the scale and offset
    /// folded into its first layer ([`super::fixed::fixed_mlp`]).
    pub fn local_input(&self, l: i32) -> f32 {
        (l as f32 + 0.5) * self.cell_scale() - 0.5
    }

    /// `2^-shift`.
    pub fn cell_scale(&self) -> f32 {
        (-(self.shift as f32)).exp2()
    }

    /// The MLP on every Gaussian.
    pub fn forward(&self) -> Activations {
        let (h, p, m) = (self.h, self.p(), self.inputs());
        let n = self.positions.len();
        let mut pre = vec![0f32; n * h];
        let mut out = vec![0f32; n * p];
        pre.par_chunks_mut(h).zip(out.par_chunks_mut(p)).enumerate().for_each_init(Vec::new, |x, (i, (pre, out))| {
            self.input(i, x);
            for (j, row) in self.w1.chunks_exact(m + 1).enumerate() {
                pre[j] = row[m] + row[..m].iter().zip(x.iter()).map(|(w, x)| w * x).sum::<f32>();
            }
            for (c, row) in self.w2.chunks_exact(h + 1).enumerate() {
                out[c] = row[h] + row[..h].iter().zip(pre.iter()).map(|(w, p)| w * p.max(0.0)).sum::<f32>();
            }
        });
        Activations { pre, out }
    }

    /// Gradients of the MLP's parameters and of the features from `d_out` (`N × P`).
    pub fn backward(&self, act: &Activations, d_out: &[f32]) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
        let (f, h, p, m) = (self.f, self.h, self.p(), self.inputs());
        let n = self.positions.len();
        // Per Gaussian, the gradient of its features (summed per anchor afterwards). The weight
        // gradients are summed per fixed run of Gaussians, then the runs in order: the result
        // does not depend on the thread count.
        let mut d_x = vec![0f32; n * f];
        let partial: Vec<(Vec<f32>, Vec<f32>)> = d_x
            .par_chunks_mut(f * RUN)
            .enumerate()
            .map(|(r, d_xs)| {
                let (mut g1, mut g2, mut x) = (vec![0f32; self.w1.len()], vec![0f32; self.w2.len()], Vec::new());
                let mut d_h = vec![0f32; h];
                for (k, d_x) in d_xs.chunks_exact_mut(f).enumerate() {
                    let i = r * RUN + k;
                    let d_o = &d_out[i * p..][..p];
                    if d_o.iter().all(|&v| v == 0.0) {
                        continue;
                    }
                    self.input(i, &mut x);
                    let pre = &act.pre[i * h..][..h];
                    d_h.iter_mut().for_each(|v| *v = 0.0);
                    for (c, (row, g)) in self.w2.chunks_exact(h + 1).zip(g2.chunks_exact_mut(h + 1)).enumerate() {
                        let d = d_o[c];
                        if d == 0.0 {
                            continue;
                        }
                        for j in 0..h {
                            g[j] += d * pre[j].max(0.0);
                            d_h[j] += d * row[j];
                        }
                        g[h] += d;
                    }
                    for j in 0..h {
                        if pre[j] <= 0.0 {
                            continue;
                        }
                        let d = d_h[j];
                        let row = &self.w1[j * (m + 1)..][..m + 1];
                        let g = &mut g1[j * (m + 1)..][..m + 1];
                        for q in 0..m {
                            g[q] += d * x[q];
                        }
                        for q in 0..f {
                            d_x[q] += d * row[q];
                        }
                        g[m] += d;
                    }
                }
                (g1, g2)
            })
            .collect();
        let (mut g1, mut g2) = (vec![0f32; self.w1.len()], vec![0f32; self.w2.len()]);
        for (a1, a2) in partial {
            g1.iter_mut().zip(a1).for_each(|(x, y)| *x += y);
            g2.iter_mut().zip(a2).for_each(|(x, y)| *x += y);
        }
        let mut d_feat = vec![0f32; self.feat.len()];
        for (i, d) in d_x.chunks_exact(f).enumerate() {
            let a = self.anchor_of[i] as usize;
            d_feat[a * f..][..f].iter_mut().zip(d).for_each(|(x, y)| *x += y);
        }
        (g1, g2, d_feat)
    }

    /// The Gaussians the outputs describe, with base log scales `base` (the caller rounds them).
    pub fn gaussians(&self, out: &[f32], base: &[f32]) -> Splats {
        let p = self.p();
        let rest = 3 * gscodec_decoder::math::sh_rest_coeffs(self.degree);
        let mut s = Splats::new(self.degree);
        for (i, o) in out.chunks_exact(p).enumerate() {
            let a = self.anchor_of[i] as usize;
            let ls = std::array::from_fn(|j| o[1 + j] + base[3 * a + j]);
            let mut rot = [o[4], o[5], o[6], o[7]];
            if rot.iter().all(|&c| c == 0.0) {
                rot = [1.0, 0.0, 0.0, 0.0];
            }
            s.push(self.positions[i], ls, rot, o[0], [o[8], o[9], o[10]], &o[11..11 + rest]);
        }
        s
    }
}

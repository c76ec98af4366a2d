//! Fitting the anchor model to a scene: the Gaussians on a grid ([`place`]), anchors from its
//! coarser cells ([`choose_shift`], [`init`]), the MLP and the features distilled from the
//! Gaussians' attributes ([`distill`]), then fine-tuned against renders of the input
//! ([`fine_tune`]).

use gscodec_decoder::bitstream::params::Grid;
use gscodec_decoder::bitstream::positions::{morton_decode, morton_encode};
use gscodec_decoder::math::sh_rest_coeffs;
use gscodec_decoder::{RenderOptions, Splats};

use super::model::Model;
use crate::optim::AdamRule;
use crate::raster;
use crate::rng::Rng;

/// Adam over one flat parameter vector: the project's update rule ([`AdamRule`]) with this
/// vector's moments.
pub struct Adam {
    rule: AdamRule,
    m: Vec<f32>,
    v: Vec<f32>,
}

impl Adam {
    pub fn new(n: usize) -> Adam {
        Adam { rule: AdamRule { eps: 1e-8, ..AdamRule::default() }, m: vec![0.0; n], v: vec![0.0; n] }
    }

    pub fn step(&mut self, x: &mut [f32], g: &[f32], lr: f32) {
        let c = self.rule.begin_step();
        self.rule.update(c, lr, x, g, &mut self.m, &mut self.v);
    }
}

/// The scene on the grid: Gaussians in Morton order (`order[i]` is the input Gaussian that file
/// Gaussian `i` stands for), their Morton codes, and the grid.
pub struct Placed {
    pub grid: Grid,
    pub morton: Vec<u64>,
    pub order: Vec<usize>,
}

/// Puts the Gaussians on a grid of `bits` bits per axis over the scene's bounds (the explicit
/// profile's grid), in Morton order.
pub fn place(scene: &Splats, bits: u8) -> Placed {
    let (lo, hi) = scene.bounds().expect("a non-empty scene");
    let grid = crate::rate::quantise::grid(lo, hi, bits);
    let (origin, step, _) = grid;
    let max_q = (1u64 << bits) - 1;
    let mut keyed: Vec<(u64, usize)> = (0..scene.len())
        .map(|i| {
            let q: [u32; 3] = std::array::from_fn(|a| {
                let t = (f64::from(scene.positions[i][a]) - f64::from(origin[a])) / f64::from(step[a]);
                t.round().clamp(0.0, max_q as f64) as u32
            });
            (morton_encode(q, bits), i)
        })
        .collect();
    keyed.sort_unstable();
    Placed { grid, morton: keyed.iter().map(|k| k.0).collect(), order: keyed.iter().map(|k| k.1).collect() }
}

/// The anchor shift whose anchors hold closest to `per_anchor` Gaussians on average (in log
/// terms), among 0..=bits (SPEC §12.1: at most the grid's bits).
pub fn choose_shift(morton: &[u64], bits: u8, per_anchor: f32) -> u8 {
    let anchors = |s: u8| 1 + morton.windows(2).filter(|w| w[0] >> (3 * u32::from(s)) != w[1] >> (3 * u32::from(s))).count();
    (0..=bits)
        .min_by(|&a, &b| {
            let err = |s: u8| ((morton.len() as f32 / anchors(s) as f32) / per_anchor).ln().abs();
            err(a).total_cmp(&err(b))
        })
        .unwrap_or(0)
}

/// The model for `placed` with anchors of `2^shift` cells: base log scales the mean of each
/// anchor's Gaussians, features and MLP random.
pub fn init(scene: &Splats, placed: &Placed, shift: u8, f: usize, h: usize, degree: u8, seed: u64) -> Model {
    let (grid, bits) = (&placed.grid, placed.grid.2);
    let mask = (1u32 << shift) - 1;
    let n = placed.order.len();
    let mut anchor_of = Vec::with_capacity(n);
    let mut count: Vec<usize> = Vec::new();
    let mut base: Vec<f32> = Vec::new();
    for (i, &m) in placed.morton.iter().enumerate() {
        if i == 0 || placed.morton[i - 1] >> (3 * u32::from(shift)) != m >> (3 * u32::from(shift)) {
            count.push(0);
            base.extend([0.0; 3]);
        }
        let a = count.len() - 1;
        count[a] += 1;
        (0..3).for_each(|ax| base[3 * a + ax] += scene.log_scales[placed.order[i]][ax]);
        anchor_of.push(a as u32);
    }
    base.chunks_exact_mut(3).zip(&count).for_each(|(b, &c)| b.iter_mut().for_each(|v| *v /= c as f32));
    let positions = placed.morton.iter().map(|&m| gscodec_decoder::bitstream::positions::position_of(m, grid)).collect();
    let local = placed.morton.iter().map(|&m| morton_decode(m, bits).map(|q| (q & mask) as i32)).collect();
    let mut rng = Rng::new(seed);
    let p = gscodec_decoder::bitstream::anchors::outputs_per_gaussian(degree);
    let m = f + gscodec_decoder::bitstream::anchors::POSITION_INPUTS;
    let mut init_w = |rows: usize, cols: usize, scale: f32| -> Vec<f32> {
        (0..rows * (cols + 1)).map(|i| if i % (cols + 1) == cols { 0.0 } else { rng.normal() * scale / (cols as f32).sqrt() }).collect()
    };
    let w1 = init_w(h, m, 1.0);
    let w2 = init_w(p, h, 0.5);
    let feat = (0..count.len() * f).map(|_| rng.normal() * 2.0).collect();
    Model { f, h, degree, shift, positions, anchor_of, local, feat, base, w1, w2 }
}

/// A Gaussian's targets in the model's output units: opacity logit, log σ over the anchor's
/// base, the unit quaternion with w ≥ 0, colours (DC, then the rest up to `degree`).
fn targets(scene: &Splats, i: usize, base: &[f32], degree: u8) -> Vec<f32> {
    let mut t = vec![scene.opacity_logits[i]];
    t.extend((0..3).map(|ax| scene.log_scales[i][ax] - base[ax]));
    let r = scene.rotations[i];
    let norm = r.iter().map(|v| v * v).sum::<f32>().sqrt().max(1e-12);
    let sign = if r[0] < 0.0 { -1.0 } else { 1.0 };
    t.extend(r.iter().map(|v| sign * v / norm));
    t.extend(scene.sh_dc[i]);
    let rest = sh_rest_coeffs(degree) * 3;
    let have = scene.rest_coeffs() * 3;
    t.extend((0..rest).map(|c| if c < have { scene.sh_rest[i * have + c] } else { 0.0 }));
    t
}

/// Fits features and MLP to the Gaussians' attributes (squared error of the outputs, each
/// Gaussian weighted by `weight`), `iters` full-batch Adam steps. Returns the final mean loss.
pub fn distill(model: &mut Model, scene: &Splats, order: &[usize], weight: &[f32], iters: usize) -> f64 {
    let p = model.p();
    let tg: Vec<Vec<f32>> = order
        .iter()
        .enumerate()
        .map(|(i, &g)| targets(scene, g, &model.base[3 * model.anchor_of[i] as usize..][..3], model.degree))
        .collect();
    let (mut o1, mut o2, mut of) = (Adam::new(model.w1.len()), Adam::new(model.w2.len()), Adam::new(model.feat.len()));
    let n = order.len();
    let mut last = 0.0;
    for it in 0..iters {
        let act = model.forward();
        let mut d = vec![0f32; act.out.len()];
        let mut loss = 0.0f64;
        for i in 0..n {
            let (o, t, w) = (&act.out[i * p..][..p], &tg[i], weight[i]);
            for c in 0..p {
                let e = o[c] - t[c];
                loss += f64::from(w * e * e);
                d[i * p + c] = 2.0 * w * e / n as f32;
            }
        }
        let (g1, g2, gf) = model.backward(&act, &d);
        let lr = 3e-3 * (1.0 - 0.9 * it as f32 / iters as f32);
        o1.step(&mut model.w1, &g1, lr);
        o2.step(&mut model.w2, &g2, lr);
        of.step(&mut model.feat, &gf, 30.0 * lr);
        last = loss / n as f64;
    }
    last
}

/// Straight-through rounding of `v` to multiples of `step`.
pub(crate) fn rounded(v: &[f32], step: f32) -> Vec<f32> {
    v.iter().map(|x| (x / step).round() * step).collect()
}

/// Fine-tunes the model against `views` under L1 + SSIM, `iters` steps of one view each; base
/// scales are rounded to their step in the forward pass (straight through). Returns the last loss.
pub fn fine_tune(model: &mut Model, views: &super::FitViews, iters: usize, base_step: f32, seed: u64) -> f64 {
    let (cameras, targets) = (&views.cameras, &views.images);
    let p = model.p();
    let rest = 3 * sh_rest_coeffs(model.degree);
    let loss_fn = crate::loss::l1::L1Ssim::default();
    let opts = RenderOptions { background: views.background, max_sh_degree: 3 };
    let mut rng = Rng::new(seed ^ 0xA4C4);
    let (mut o1, mut o2, mut of) = (Adam::new(model.w1.len()), Adam::new(model.w2.len()), Adam::new(model.feat.len()));
    let mut ob = Adam::new(model.base.len());
    let mut last = 0.0;
    for it in 0..iters {
        let act = model.forward();
        let splats = model.gaussians(&act.out, &rounded(&model.base, base_step));
        let v = rng.below(cameras.len());
        let (img, state) = raster::forward(&splats, &cameras[v], &opts);
        let (loss, g_img) = loss_fn.eval(&img, &targets[v]);
        let g = raster::backward(&splats, &state, &g_img).params;
        let mut d_out = vec![0f32; act.out.len()];
        let mut d_base = vec![0f32; model.base.len()];
        for (i, d) in d_out.chunks_exact_mut(p).enumerate() {
            let a = model.anchor_of[i] as usize;
            d[0] = g.opacity_logits[i];
            d[1..4].copy_from_slice(&g.log_scales[i]);
            d_base[3 * a..][..3].iter_mut().zip(&g.log_scales[i]).for_each(|(b, v)| *b += v);
            d[4..8].copy_from_slice(&g.rotations[i]);
            d[8..11].copy_from_slice(&g.sh_dc[i]);
            d[11..11 + rest].copy_from_slice(&g.sh_rest[i * rest..][..rest]);
        }
        let (g1, g2, gf) = model.backward(&act, &d_out);
        let decay = 1.0 - 0.9 * it as f32 / iters.max(1) as f32;
        o1.step(&mut model.w1, &g1, 1e-3 * decay);
        o2.step(&mut model.w2, &g2, 1e-3 * decay);
        of.step(&mut model.feat, &gf, 0.03 * decay);
        ob.step(&mut model.base, &d_base, 0.005 * decay);
        last = loss;
    }
    last
}

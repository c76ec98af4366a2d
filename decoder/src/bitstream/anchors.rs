//! The anchor profile (SPEC §12, format 7.0). The Gaussians' positions are coded as in the
//! explicit profile (a grid and one Morton stream, SPEC §4, §6.1); the grid's cells of
//! `2^s × 2^s × 2^s` are the **anchors**, each with a feature vector and a base log scale, and a
//! small fixed-point MLP turns an anchor's features and a Gaussian's position inside the anchor
//! cell into that Gaussian's opacity, scale, rotation and colour. Everything the MLP computes is
//! integer arithmetic, so the decoded scene is bit-identical on every machine; the only float
//! operations are the products and sums of SPEC §8.
//!
//! The section (kind [`ANCHORS_KIND`], chunk 0) reuses the explicit profile's elements: the
//! position grid and stream, the same length + raw bits code for the MLP's zigzagged weights,
//! and "blocks" — a channel count, per channel a step and a table (SPEC §4, §4.1), then the
//! channels' streams (SPEC §6) — for the anchors' features and base scales.

use rayon::prelude::*;

use super::assemble::dequantise_position;
use super::bytes::unzigzag;
use super::params::{read_channel_tables, read_position_params, GroupParams};
use super::positions::{decode_lengths, decode_morton, morton_decode};
use super::stream::decode_channels;
use super::tables::ChannelTable;
use super::{ByteReader, ByteWriter};
use crate::error::{self, DecodeError, Limit};
use crate::math::sh_rest_coeffs;
use crate::Splats;

/// Section kind of the anchor section (SPEC §12).
pub const ANCHORS_KIND: u16 = 0x03;
/// Most MLP layers.
pub const MAX_LAYERS: usize = 4;
/// Most inputs or outputs of one MLP layer.
pub const MAX_WIDTH: usize = 4096;
/// Most MLP weights and biases in all, Σ outputs × (inputs + 1).
pub const MAX_WEIGHTS: usize = 1 << 18;
/// Most multiply-adds of a decode, Gaussians × weights (a `limits` error above).
pub const MAX_WORK: u64 = 1 << 34;
/// Every feature, weight, bias and activation lies strictly inside ±2^24: features and weights
/// outside are a `format` error, activations are clamped to ±(2^24 − 1).
pub const VALUE_BOUND: i32 = 1 << 24;
/// Longest coded length of a zigzagged weight: `z < 2^25`.
pub const WEIGHT_LENGTH_BITS: u32 = 25;
/// Output channels per Gaussian before the colours: opacity, log σ × 3, quaternion × 4.
const GEOMETRY_OUTPUTS: usize = 8;
/// MLP inputs besides the features: the Gaussian's cell inside its anchor, x y z.
pub const POSITION_INPUTS: usize = 3;

/// Output channels of one Gaussian for SH degree `d`: opacity, 3 log σ, 4 quaternion
/// components, then `3·(d+1)²` colour values (DC r g b, then the rest coefficient-major).
pub fn outputs_per_gaussian(d: u8) -> usize {
    GEOMETRY_OUTPUTS + 3 * (sh_rest_coeffs(d) + 1)
}

/// One layer's shape and its right shift.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Layer {
    pub inputs: usize,
    pub outputs: usize,
    pub shift: u8,
}

/// The fixed-point MLP: per layer, `outputs` rows of `inputs` weights followed by the bias.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Mlp {
    pub layers: Vec<Layer>,
    pub weights: Vec<i32>,
}

impl Mlp {
    /// Total weights and biases.
    pub fn weight_count(layers: &[Layer]) -> usize {
        layers.iter().map(|l| l.outputs * (l.inputs + 1)).sum()
    }

    /// The MLP of SPEC §12.2 on `x` (every |value| < 2^24): per layer, each output is
    /// `(bias + Σ w·x) >> shift` in 64-bit arithmetic, clamped to ±(2^24 − 1), and ReLU on every
    /// layer but the last. `tmp` is scratch; the result is left in `out`.
    pub fn forward(&self, x: &[i32], tmp: &mut Vec<i32>, out: &mut Vec<i32>) {
        out.clear();
        out.extend_from_slice(x);
        let mut w = &self.weights[..];
        for (li, l) in self.layers.iter().enumerate() {
            std::mem::swap(tmp, out);
            out.clear();
            let last = li + 1 == self.layers.len();
            for row in w[..l.outputs * (l.inputs + 1)].chunks_exact(l.inputs + 1) {
                let acc =
                    row[..l.inputs].iter().zip(tmp.iter()).fold(i64::from(row[l.inputs]), |a, (&w, &x)| a + i64::from(w) * i64::from(x));
                out.push(activate(acc, l.shift, last));
            }
            w = &w[l.outputs * (l.inputs + 1)..];
        }
    }
}

/// [`Mlp::forward`] arranged for many Gaussians (what [`expand`] runs), with the same integer
/// results:
/// * the first layer's feature part `b_j + Σ_(k<F) w_jk·x_k` is computed once per anchor
///   ([`Evaluator::anchor`]); each Gaussian adds its 3 cell terms;
/// * every later layer keeps its weights input-major, so a layer is `acc[·] += w[k][·]·x_k` over
///   the outputs, which the compiler vectorises. The accumulation is in `f64` when it is exact:
///   every product `|w|·|x| < 2^48` is, and when `|b_j| + Σ_k |w_jk|·(2^24 − 1) < 2^51` for every
///   row so is every partial sum (integers below 2^51), so the result equals the `i64` sum of
///   SPEC §12.2 ([`activate_f64`] needs the 2^51). A layer outside that bound accumulates in
///   `i64`.
pub struct Evaluator {
    features: usize,
    /// First layer: per output, the feature weights then the bias (rows of [`Mlp`]), and the
    /// cell weights input-major.
    first: Layer,
    first_rows: Vec<i32>,
    first_cell: Vec<[i64; POSITION_INPUTS]>,
    rest: Vec<FastLayer>,
}

/// Outputs accumulated together by an `f64` layer (kept in registers).
const BLOCK: usize = 8;

struct FastLayer {
    layer: Layer,
    bias: Vec<i64>,
    /// `f64`: blocks of [`BLOCK`] outputs, each `w[k · BLOCK + j]`; `i64`: `w[k · outputs + j]`.
    weights: FastWeights,
}

enum FastWeights {
    F64(Vec<f64>),
    I64(Vec<i64>),
}

/// Per-thread scratch of an [`Evaluator`]: the current anchor's first-layer sums and the
/// activations.
#[derive(Default)]
pub struct Scratch {
    anchor: Option<usize>,
    first: Vec<i64>,
    acc_i: Vec<i64>,
    x: Vec<i32>,
    y: Vec<i32>,
}

/// `y = clamp(acc >> shift, ±(2^24 − 1))`, rectified unless `last` (SPEC §12.2).
#[inline(always)]
fn activate(acc: i64, shift: u8, last: bool) -> i32 {
    let bound = i64::from(VALUE_BOUND - 1);
    let y = (acc >> shift).clamp(-bound, bound) as i32;
    if last {
        y
    } else {
        y.max(0)
    }
}

/// [`activate`] of an accumulator held exactly in an `f64` (an integer, `|acc| < 2^51`), in
/// `f64` operations the compiler can vectorise: `acc · 2^−shift` is exact, adding and removing
/// 1.5·2^52 rounds it to the nearest integer, and one comparison turns that into the floor.
#[inline(always)]
fn activate_f64(acc: f64, scale: f64, last: bool) -> i32 {
    const ROUND: f64 = 6_755_399_441_055_744.0; // 1.5 · 2^52
    let y = acc * scale;
    let r = (y + ROUND) - ROUND;
    let floor = if r > y { r - 1.0 } else { r };
    let bound = f64::from(VALUE_BOUND - 1);
    floor.clamp(if last { -bound } else { 0.0 }, bound) as i32
}

impl Evaluator {
    /// The evaluator of `mlp`, whose first layer takes `features` features and the 3 cell
    /// coordinates (`inputs = features + 3`, as [`read_anchors`] checks).
    pub fn new(mlp: &Mlp, features: usize) -> Evaluator {
        let first = mlp.layers[0];
        debug_assert_eq!(first.inputs, features + POSITION_INPUTS);
        let (head, mut w) = mlp.weights.split_at(first.outputs * (first.inputs + 1));
        let mut first_rows = Vec::with_capacity(first.outputs * (features + 1));
        let mut first_cell = Vec::with_capacity(first.outputs);
        for row in head.chunks_exact(first.inputs + 1) {
            first_rows.extend_from_slice(&row[..features]);
            first_rows.push(row[first.inputs]);
            first_cell.push(std::array::from_fn(|k| i64::from(row[features + k])));
        }
        let mut rest = Vec::new();
        for l in &mlp.layers[1..] {
            let (rows, tail) = w.split_at(l.outputs * (l.inputs + 1));
            w = tail;
            let bias: Vec<i64> = rows.chunks_exact(l.inputs + 1).map(|r| i64::from(r[l.inputs])).collect();
            let bound = i64::from(VALUE_BOUND - 1);
            let exact = rows.chunks_exact(l.inputs + 1).all(|r| {
                let sum: i128 = r[..l.inputs].iter().map(|&w| i128::from(w.unsigned_abs()) * i128::from(bound)).sum();
                sum + i128::from(r[l.inputs].unsigned_abs()) < 1i128 << 51
            });
            let at = |k: usize, j: usize| rows[j * (l.inputs + 1) + k];
            let weights = match exact {
                true => {
                    // Blocks of BLOCK outputs (the last padded with zero weights), input-major.
                    let blocks = l.outputs.div_ceil(BLOCK);
                    let order =
                        (0..blocks).flat_map(|b| (0..l.inputs).flat_map(move |k| (b * BLOCK..(b + 1) * BLOCK).map(move |j| (k, j))));
                    FastWeights::F64(order.map(|(k, j)| if j < l.outputs { f64::from(at(k, j)) } else { 0.0 }).collect())
                }
                false => FastWeights::I64((0..l.inputs).flat_map(|k| (0..l.outputs).map(move |j| i64::from(at(k, j)))).collect()),
            };
            rest.push(FastLayer { layer: *l, bias, weights });
        }
        Evaluator { features, first, first_rows, first_cell, rest }
    }

    /// Makes `scratch` hold anchor `a`'s first-layer feature sums (`features`: its F values).
    fn anchor(&self, a: usize, features: &[i32], scratch: &mut Scratch) {
        if scratch.anchor == Some(a) {
            return;
        }
        scratch.anchor = Some(a);
        scratch.first.clear();
        scratch.first.extend(self.first_rows.chunks_exact(self.features + 1).map(|row| {
            row[..self.features].iter().zip(features).fold(i64::from(row[self.features]), |s, (&w, &x)| s + i64::from(w) * i64::from(x))
        }));
    }

    /// The outputs of the Gaussian of anchor `a` (features `features`) at cell `cell`, left in
    /// the returned slice (equal to [`Mlp::forward`] on the features followed by `cell`).
    pub fn eval<'s>(&self, a: usize, features: &[i32], cell: [i32; 3], s: &'s mut Scratch) -> &'s [i32] {
        self.anchor(a, features, s);
        let c = cell.map(i64::from);
        let last = self.rest.is_empty();
        s.y.clear();
        s.y.extend(
            s.first
                .iter()
                .zip(&self.first_cell)
                .map(|(&p, w)| activate(p + w[0] * c[0] + w[1] * c[1] + w[2] * c[2], self.first.shift, last)),
        );
        for (li, l) in self.rest.iter().enumerate() {
            std::mem::swap(&mut s.x, &mut s.y);
            let last = li + 1 == self.rest.len();
            let (n, shift) = (l.layer.outputs, l.layer.shift);
            s.y.clear();
            match &l.weights {
                FastWeights::F64(w) => {
                    let scale = f64::from_bits(u64::from(1023 - u16::from(shift)) << 52); // 2^−shift, shift ≤ 62
                    for (b, block) in w.chunks_exact(BLOCK * l.layer.inputs).enumerate() {
                        let outputs = b * BLOCK..n.min((b + 1) * BLOCK);
                        let mut acc = [0.0f64; BLOCK];
                        acc.iter_mut().zip(&l.bias[outputs.clone()]).for_each(|(a, &b)| *a = b as f64);
                        for (row, &x) in block.chunks_exact(BLOCK).zip(&s.x) {
                            let x = f64::from(x);
                            acc.iter_mut().zip(row).for_each(|(a, &w)| *a += w * x);
                        }
                        s.y.extend(acc[..outputs.len()].iter().map(|&a| activate_f64(a, scale, last)));
                    }
                }
                FastWeights::I64(w) => {
                    s.acc_i.clone_from(&l.bias);
                    for (row, &x) in w.chunks_exact(n).zip(&s.x) {
                        let x = i64::from(x);
                        s.acc_i.iter_mut().zip(row).for_each(|(a, &w)| *a += w * x);
                    }
                    s.y.extend(s.acc_i.iter().map(|&a| activate(a, shift, last)));
                }
            }
        }
        &s.y
    }
}

/// The decoded anchor section (SPEC §12.1).
#[derive(Debug, Clone, PartialEq)]
pub struct AnchorSet {
    /// Features per anchor, F.
    pub features: usize,
    /// Anchor cells are `2^shift` grid cells wide.
    pub shift: u8,
    pub mlp: Mlp,
    /// Step of each output channel of a Gaussian ([`outputs_per_gaussian`] of them).
    pub out_steps: Vec<f32>,
    /// The Gaussians' positions, dequantised (SPEC §8).
    pub positions: Vec<[f32; 3]>,
    /// Each Gaussian's anchor and its cell inside the anchor (`q AND (2^shift − 1)` per axis).
    pub anchor_of: Vec<u32>,
    pub local: Vec<[i32; 3]>,
    /// `A × F` integer features.
    pub feature_values: Vec<i32>,
    /// `A × 3` dequantised base log scales.
    pub base: Vec<f32>,
}

impl AnchorSet {
    /// Number of anchors.
    pub fn anchors(&self) -> usize {
        self.base.len() / 3
    }
}

/// Reads a block of `channels` channels for `rows` records (SPEC §12.1): `u8 C`, C × (step,
/// table), then the coded channels' streams. Values are dequantised with the steps, or returned
/// as integers (`f32`, exact) with `integer`.
fn read_block(r: &mut ByteReader<'_>, channels: usize, rows: usize, integer: bool) -> Result<Vec<f32>, DecodeError> {
    let mut p = GroupParams { steps: Vec::new(), tables: Vec::new(), grid: None, codebook: None };
    read_channel_tables(r, channels, &mut p, false)?; // mode 3 is explicit-profile only (8.0)
    let scale = if integer { vec![1.0; channels] } else { p.steps.clone() };
    let mut vals = vec![0f32; rows * channels];
    decode_channels(&p, r, &scale, 0..channels, &mut vals)?;
    Ok(vals)
}

/// Integer values of a block read with `integer`: each must lie strictly inside ±2^24 (a value
/// escaped beyond converts to an `f32` of at least 2^24 in magnitude, so the test is exact).
fn bounded_integers(vals: &[f32], r: &ByteReader<'_>, what: &'static str) -> Result<Vec<i32>, DecodeError> {
    if vals.iter().any(|v| v.abs() >= VALUE_BOUND as f32) {
        return Err(r.corrupt(what));
    }
    Ok(vals.iter().map(|&v| v as i32).collect())
}

/// Reads and checks the anchor section of a file with `n` (≥ 1) Gaussians of SH degree `d`; it
/// must be consumed exactly.
pub fn read_anchors(r: &mut ByteReader<'_>, n: usize, d: u8) -> Result<AnchorSet, DecodeError> {
    let at = r.place();
    let features = r.u8("feature count")? as usize;
    let shift = r.u8("anchor shift")?;
    let depth = r.u8("layer count")? as usize;
    if features == 0 || !(1..=MAX_LAYERS).contains(&depth) {
        return Err(at.corrupt("no features, or MLP layers outside 1..=4"));
    }
    let p = outputs_per_gaussian(d);
    let mut layers: Vec<Layer> = Vec::with_capacity(depth);
    for i in 0..depth {
        let at = r.place();
        let inputs = r.varint("layer inputs")? as usize;
        let outputs = r.varint("layer outputs")? as usize;
        let shift = r.u8("layer shift")?;
        let expect_in = layers.last().map_or(features + POSITION_INPUTS, |l| l.outputs);
        let last_ok = i + 1 < depth || outputs == p;
        if inputs != expect_in || !(1..=MAX_WIDTH).contains(&outputs) || !last_ok || shift > 62 {
            return Err(at.corrupt("MLP layer shape or shift out of place"));
        }
        layers.push(Layer { inputs, outputs, shift });
    }
    let total = Mlp::weight_count(&layers);
    if total > MAX_WEIGHTS {
        return Err(error::limit(Limit::AnchorWork, total as u64, MAX_WEIGHTS as u64, false));
    }
    let work = n as u64 * total as u64;
    if work > MAX_WORK {
        return Err(error::limit(Limit::AnchorWork, work, MAX_WORK, false));
    }
    let mut out_steps = Vec::with_capacity(p);
    for _ in 0..p {
        out_steps.push(r.f32("output step")?);
    }
    // Per layer: a length table and one stream of its rows (each `inputs` weights, then the
    // bias), every value zigzagged and coded as a length and raw bits (SPEC §12.1).
    let mut weights = Vec::with_capacity(total);
    for l in &layers {
        let at = r.place();
        let table = ChannelTable::read(r)?;
        if !matches!(table, ChannelTable::Constant(_) | ChannelTable::Coded { .. }) {
            return Err(at.corrupt("context-coded weight lengths"));
        }
        decode_lengths(&table, r, l.outputs * (l.inputs + 1), WEIGHT_LENGTH_BITS, |z, at| {
            let w = unzigzag(z as u32);
            if w.unsigned_abs() >= VALUE_BOUND as u32 {
                return Err(at.corrupt("MLP weight outside ±2^24"));
            }
            weights.push(w);
            Ok(())
        })?;
    }
    let grid = read_position_params(r)?;
    let (origin, step, bits) = grid.grid.expect("position parameters have a grid");
    if shift > bits {
        return Err(at.corrupt("anchor shift above the grid's bits"));
    }
    let mask = (1u32 << shift) - 1;
    let (mut positions, mut anchor_of, mut local) = (Vec::with_capacity(n), Vec::with_capacity(n), Vec::with_capacity(n));
    let mut last_cell = None;
    let mut anchors = 0u32;
    decode_morton(&grid, r, n, |m, at| {
        let cell = m >> (3 * u32::from(shift));
        if last_cell != Some(cell) {
            last_cell = Some(cell);
            anchors += 1;
        }
        let q = morton_decode(m, bits);
        let xyz: [f32; 3] = std::array::from_fn(|a| dequantise_position(origin[a], step[a], q[a]));
        if !xyz.iter().all(|x| x.is_finite()) {
            return Err(at.corrupt("dequantised value is not finite"));
        }
        positions.push(xyz);
        anchor_of.push(anchors - 1);
        local.push(q.map(|q| (q & mask) as i32));
        Ok(())
    })?;
    let a = anchors as usize;
    let feature_values = read_block(r, features, a, true)?;
    let feature_values = bounded_integers(&feature_values, r, "feature outside ±2^24")?;
    let base = read_block(r, 3, a, false)?;
    if r.remaining() != 0 {
        return Err(r.corrupt("trailing bytes in the anchor section"));
    }
    Ok(AnchorSet { features, shift, mlp: Mlp { layers, weights }, out_steps, positions, anchor_of, local, feature_values, base })
}

/// The Gaussians of `set` (SPEC §12.3) for a file of SH degree `d`, output at degree `degree`
/// (≤ d) into `out`, in file order. Every value must be finite.
pub fn expand(set: &AnchorSet, d: u8, degree: u8, out: &mut Splats) -> Result<(), &'static str> {
    let f = set.features;
    let rest = 3 * sh_rest_coeffs(degree);
    debug_assert!(degree <= d && set.out_steps.len() == outputs_per_gaussian(d));
    let n = set.positions.len();
    let eval = Evaluator::new(&set.mlp, f);
    let mut s = Splats::new(degree);
    s.positions.clone_from(&set.positions);
    s.log_scales = vec![[0.0; 3]; n];
    s.rotations = vec![[0.0; 4]; n];
    s.opacity_logits = vec![0.0; n];
    s.sh_dc = vec![[0.0; 3]; n];
    s.sh_rest = vec![0.0; n * rest];
    let rest_rows: Vec<&mut [f32]> =
        if rest == 0 { (0..n).map(|_| &mut [][..]).collect() } else { s.sh_rest.chunks_exact_mut(rest).collect() };
    // Gaussian i from its anchor's MLP; true where a value is not finite.
    type Row<'r> = (&'r mut [f32; 3], &'r mut [f32; 4], &'r mut f32, &'r mut [f32; 3], &'r mut [f32]);
    let gaussian = |scratch: &mut Scratch, i: usize, (ls, rot, op, dc, rs): Row| {
        let a = set.anchor_of[i] as usize;
        let o = eval.eval(a, &set.feature_values[a * f..][..f], set.local[i], scratch);
        let v = |c: usize| o[c] as f32 * set.out_steps[c];
        *op = v(0);
        *ls = std::array::from_fn(|j| v(1 + j) + set.base[3 * a + j]);
        *rot = std::array::from_fn(|j| v(4 + j));
        if rot.iter().all(|&c| c == 0.0) {
            *rot = [1.0, 0.0, 0.0, 0.0];
        }
        *dc = std::array::from_fn(|c| v(8 + c));
        rs.iter_mut().enumerate().for_each(|(c, r)| *r = v(11 + c));
        !(op.is_finite() && ls.iter().chain(rot.iter()).chain(dc.iter()).chain(rs.iter()).all(|x| x.is_finite()))
    };
    let bad = if crate::par::sequential() {
        let mut scratch = Scratch::default();
        let rows = s.log_scales.iter_mut().zip(&mut s.rotations).zip(&mut s.opacity_logits).zip(&mut s.sh_dc).zip(rest_rows);
        rows.enumerate().fold(false, |bad, (i, ((((ls, rot), op), dc), rs))| gaussian(&mut scratch, i, (ls, rot, op, dc, rs)) || bad)
    } else {
        (s.log_scales.par_iter_mut(), s.rotations.par_iter_mut(), s.opacity_logits.par_iter_mut(), s.sh_dc.par_iter_mut(), rest_rows)
            .into_par_iter()
            .enumerate()
            .map_init(Scratch::default, |scratch, (i, row)| gaussian(scratch, i, row))
            .any(|bad| bad)
    };
    if bad {
        return Err("decoded Gaussian value is not finite");
    }
    *out = s;
    Ok(())
}

/// The pieces of an anchor section, each already serialised by the explicit profile's writers.
#[derive(Debug, Clone)]
pub struct AnchorSection<'a> {
    pub features: usize,
    pub shift: u8,
    pub layers: &'a [Layer],
    pub out_steps: &'a [f32],
    /// Per layer, the serialised length table of its zigzagged weights, then their stream
    /// (`write_position_stream` of the zigzagged values).
    pub weights: &'a [u8],
    /// `write_position_params` of the grid, then `write_position_stream` of every Gaussian.
    pub positions: &'a [u8],
    /// Blocks of features (F channels) and base log scales (3).
    pub feature_block: &'a [u8],
    pub base_block: &'a [u8],
}

/// Serialises an anchor section (SPEC §12.1).
pub fn write_anchors(s: &AnchorSection<'_>) -> Vec<u8> {
    let mut w = ByteWriter::new();
    w.u8(s.features as u8);
    w.u8(s.shift);
    w.u8(s.layers.len() as u8);
    for l in s.layers {
        w.varint(l.inputs as u32);
        w.varint(l.outputs as u32);
        w.u8(l.shift);
    }
    s.out_steps.iter().for_each(|&v| w.f32(v));
    w.bytes(s.weights);
    w.bytes(s.positions);
    w.bytes(s.feature_block);
    w.bytes(s.base_block);
    w.buf
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_mlp_shifts_clamps_and_rectifies() {
        // 2 → 2 (ReLU) → 1: hidden = relu((3x0 − x1 + 4) >> 1, (−x0) >> 1); out = h0 + 2·h1 − 1.
        let mlp = Mlp {
            layers: vec![Layer { inputs: 2, outputs: 2, shift: 1 }, Layer { inputs: 2, outputs: 1, shift: 0 }],
            weights: vec![3, -1, 4, -1, 0, 0, 1, 2, -1],
        };
        let (mut tmp, mut out) = (Vec::new(), Vec::new());
        mlp.forward(&[5, 2], &mut tmp, &mut out);
        assert_eq!(out, vec![8 - 1]); // h = (17 >> 1, relu(−5 >> 1)) = (8, 0)
        mlp.forward(&[-3, 0], &mut tmp, &mut out);
        assert_eq!(out, vec![2 - 1]); // h = (relu(−5 >> 1), 3 >> 1) = (0, 1)
                                      // The shift floors: −7 >> 1 = −4.
        let one = Mlp { layers: vec![Layer { inputs: 1, outputs: 1, shift: 1 }], weights: vec![1, 0] };
        one.forward(&[-7], &mut tmp, &mut out);
        assert_eq!(out, vec![-4]);
        // The accumulator saturates at ±(2^24 − 1).
        let big = Mlp { layers: vec![Layer { inputs: 1, outputs: 1, shift: 0 }], weights: vec![VALUE_BOUND - 1, 0] };
        big.forward(&[-(VALUE_BOUND - 1)], &mut tmp, &mut out);
        assert_eq!(out, vec![-(VALUE_BOUND - 1)]);
    }

    /// The evaluator [`expand`] runs gives [`Mlp::forward`]'s integers: one to four layers,
    /// widths around the `f64` block size, small weights (the `f64` path), weights up to 2^24
    /// (the `i64` path), activations that saturate, and anchors revisited in any order.
    #[test]
    fn the_evaluator_equals_the_reference_mlp() {
        let mut rng = crate::rng::Rng::new(7);
        let mut paths = [0; 2];
        for case in 0..60 {
            let features = 1 + rng.below(20);
            let depth = 1 + case % 4;
            let mut inputs = features + POSITION_INPUTS;
            let (mut layers, mut weights) = (Vec::new(), Vec::new());
            for l in 0..depth {
                let outputs = 1 + rng.below(if l + 1 == depth { 30 } else { 40 });
                let bits = if case % 3 == 0 { 24 } else { 11 };
                let shift = rng.below(20) as u8;
                layers.push(Layer { inputs, outputs, shift });
                for _ in 0..outputs * (inputs + 1) {
                    let w = (rng.next_u64() % (1u64 << bits)) as i32 - (1 << (bits - 1));
                    weights.push(w.clamp(-(VALUE_BOUND - 1), VALUE_BOUND - 1));
                }
                inputs = outputs;
            }
            let mlp = Mlp { layers, weights };
            let eval = Evaluator::new(&mlp, features);
            eval.rest.iter().for_each(|l| paths[usize::from(matches!(l.weights, FastWeights::I64(_)))] += 1);
            let anchors: Vec<Vec<i32>> =
                (0..4).map(|_| (0..features).map(|_| (rng.next_u64() % (1 << 25)) as i32 - (1 << 24) + 1).collect()).collect();
            let (mut scratch, mut tmp, mut out) = (Scratch::default(), Vec::new(), Vec::new());
            for _ in 0..20 {
                let a = rng.below(anchors.len());
                let cell = [0; 3].map(|_| rng.below(1 << 10) as i32);
                let x: Vec<i32> = anchors[a].iter().copied().chain(cell).collect();
                mlp.forward(&x, &mut tmp, &mut out);
                assert_eq!(eval.eval(a, &anchors[a], cell, &mut scratch), &out[..], "case {case}");
            }
        }
        assert!(paths[0] > 5 && paths[1] > 5, "both accumulations are tested: {paths:?}");
    }
}

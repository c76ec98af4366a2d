//! From the float [`Model`] to the integers of SPEC §12 and the file: features and base scales
//! rounded to their steps, the MLP turned into integer weights with one right shift per layer,
//! and every block coded with the explicit profile's table chooser. The decoded scene is
//! computed by the decoder's own [`expand`], so what the encoder reports is what a decoder gets.

use gscodec_decoder::bitstream::anchors::{
    expand, outputs_per_gaussian, write_anchors, AnchorSection, AnchorSet, Layer, Mlp, ANCHORS_KIND, VALUE_BOUND,
};
use gscodec_decoder::bitstream::bytes::zigzag;
use gscodec_decoder::bitstream::info::{write_info, EncoderInfo};
use gscodec_decoder::bitstream::layout::INFO_KIND;
use gscodec_decoder::bitstream::params::{write_channel_params, write_position_params, Grid};
use gscodec_decoder::bitstream::positions::{delta_length, morton_deltas, write_position_stream};
use gscodec_decoder::bitstream::sections::write_padded;
use gscodec_decoder::bitstream::stream::write_channel_streams;
use gscodec_decoder::bitstream::{Header, Section, SECTION_OPTIONAL, VERSION_MAJOR_ANCHORS, VERSION_MINOR};
use gscodec_decoder::entropy::ChannelTable;
use gscodec_decoder::Splats;
use rayon::prelude::*;

use super::model::{Activations, Model};
use crate::rate::tables;

/// Steps of a Gaussian's output channels (SPEC §12.3): they cost no bits (the MLP computes the
/// values), so they are fine: opacity logit 2^-8, log σ 2^-10, quaternion 2^-12, colour 2^-11.
pub fn output_steps(degree: u8) -> Vec<f32> {
    let p = outputs_per_gaussian(degree);
    (0..p)
        .map(|c| match c {
            0 => 1.0 / 256.0,
            1..=3 => 1.0 / 1024.0,
            4..=7 => 1.0 / 4096.0,
            _ => 1.0 / 2048.0,
        })
        .collect()
}

/// Bits of precision the hidden layer keeps (its largest activation ≈ 2^HIDDEN_BITS).
const HIDDEN_BITS: i32 = 12;
/// The first layer's largest weight is about 2^FIRST_WEIGHT_BITS.
const FIRST_WEIGHT_BITS: i32 = 11;
/// The output layer's largest weight is about 2^OUTPUT_WEIGHT_BITS.
const OUTPUT_WEIGHT_BITS: i32 = 10;

/// The MLP of `model` in fixed point (SPEC §12.2), from its activations `act` and the anchors'
/// integer features `features` ([`Model::integer_features`]).
pub fn fixed_mlp(model: &Model, act: &Activations, features: &[i32]) -> Mlp {
    let (m, h) = (model.inputs(), model.h);
    let steps = output_steps(model.degree);
    let p = steps.len();
    let max_pre = act.pre.iter().fold(1e-6f32, |m, &v| m.max(v.abs()));
    // Hidden units are integers of `sh`: the largest activation is about 2^HIDDEN_BITS.
    let sh = max_pre / (1 << HIDDEN_BITS) as f32;
    let bound = (VALUE_BOUND - 1) as f32;
    let int = |v: f32| v.round().clamp(-bound, bound) as i32;
    // The float first layer sees the cell inside the anchor as `l·c + (c/2 − ½)` (c = 2^-shift,
    // Model::local_input); the fixed one sees `l`: scale those weights, fold the rest into the
    // bias. The layer's shift gives its largest weight about 2^FIRST_WEIGHT_BITS (the cell
    // weights are 2^shift times smaller), and half a unit added to the bias makes the shift round.
    let (c, f) = (model.cell_scale(), model.f);
    let rows1: Vec<Vec<f32>> = model
        .w1
        .chunks_exact(m + 1)
        .map(|row| {
            let mut r: Vec<f32> = row[..f].iter().map(|&w| w / sh).collect();
            r.extend(row[f..m].iter().map(|&w| w * c / sh));
            r.push((row[m] + row[f..m].iter().map(|&w| w * (0.5 * c - 0.5)).sum::<f32>()) / sh);
            r
        })
        .collect();
    let max1 = rows1.iter().flat_map(|r| r[..m].iter()).fold(1e-12f32, |a, &v| a.max(v.abs()));
    let max_b1 = rows1.iter().map(|r| r[m].abs()).fold(1e-12f32, f32::max);
    let shift1 = (FIRST_WEIGHT_BITS as f32 - max1.log2()).min(23.0 - max_b1.log2()).floor().clamp(0.0, 40.0) as u8;
    let mult1 = (shift1 as f32).exp2();
    let mut weights = Vec::with_capacity(model.w1.len() + model.w2.len());
    for r in &rows1 {
        weights.extend(r[..m].iter().map(|&w| int(w * mult1)));
        weights.push(int(r[m] * mult1 + if shift1 > 0 { 0.5 * mult1 } else { 0.0 }));
    }
    // Output row c (channel c mod P): value / step_c = (Σ w2·h_int·sh + b2) / step_c.
    let scaled = |c: usize, j: usize| {
        let w = model.w2[c * (h + 1) + j];
        if j < h {
            w * sh / steps[c % p]
        } else {
            w / steps[c % p]
        }
    };
    let rows = model.w2.len() / (h + 1);
    let (mut max_w, mut max_b) = (1e-12f32, 1e-12f32);
    for c in 0..rows {
        (0..h).for_each(|j| max_w = max_w.max(scaled(c, j).abs()));
        max_b = max_b.max(scaled(c, h).abs());
    }
    let by_weights = OUTPUT_WEIGHT_BITS as f32 - max_w.log2();
    let by_bias = 23.0 - max_b.log2();
    let shift = by_weights.min(by_bias).floor().clamp(0.0, 40.0) as u8;
    let mult = (shift as f32).exp2();
    for c in 0..rows {
        (0..h).for_each(|j| weights.push(int(scaled(c, j) * mult)));
        weights.push(int(scaled(c, h) * mult + if shift > 0 { 0.5 * mult } else { 0.0 }));
    }
    let mut mlp = Mlp { layers: vec![Layer { inputs: m, outputs: h, shift: shift1 }, Layer { inputs: h, outputs: p, shift }], weights };
    // Bias correction: the rounded weights shift each output on average; move the last layer's
    // biases by the mean difference between the integer outputs and the float ones.
    let f = model.f;
    let diffs: Vec<Vec<f64>> = (0..model.positions.len())
        .into_par_iter()
        .map_init(
            || (Vec::new(), Vec::new(), Vec::new()),
            |(x, tmp, o), i| {
                let a = model.anchor_of[i] as usize;
                x.clear();
                x.extend_from_slice(&features[a * f..][..f]);
                x.extend_from_slice(&model.local[i]);
                mlp.forward(x, tmp, o);
                (0..p).map(|c| f64::from(o[c]) - f64::from(act.out[i * p + c] / steps[c])).collect()
            },
        )
        .collect();
    let n = diffs.len().max(1) as f64;
    let biases = mlp.weights.len() - p * (h + 1);
    for c in 0..p {
        let mean = diffs.iter().map(|d| d[c]).sum::<f64>() / n;
        let b = &mut mlp.weights[biases + c * (h + 1) + h];
        *b = int(*b as f32 - (mean * f64::from(mult)) as f32);
    }
    mlp
}

/// The quantised model: what the file holds.
#[derive(Debug, Clone)]
pub struct Fixed {
    pub set: AnchorSet,
    pub grid: Grid,
    pub morton: Vec<u64>,
    pub base: Vec<i32>,
    pub base_step: f32,
    /// The decoded scene (SPEC §12.3).
    pub decoded: Splats,
}

/// Rounds `model` (whose activations are `act`) to the file's integers.
pub fn quantise(model: &Model, act: &Activations, grid: Grid, morton: &[u64], shift: u8, base_step: f32) -> Fixed {
    let base: Vec<i32> = model.base.iter().map(|v| (v / base_step).round() as i32).collect();
    let feature_values = model.integer_features();
    let set = AnchorSet {
        features: model.f,
        shift,
        mlp: fixed_mlp(model, act, &feature_values),
        out_steps: output_steps(model.degree),
        positions: model.positions.clone(),
        anchor_of: model.anchor_of.clone(),
        local: model.local.clone(),
        feature_values,
        base: base.iter().map(|&v| v as f32 * base_step).collect(),
    };
    let mut decoded = Splats::new(model.degree);
    expand(&set, model.degree, model.degree, &mut decoded).expect("the encoder's own anchors expand");
    Fixed { set, grid, morton: morton.to_vec(), base, base_step, decoded }
}

/// Bytes of the parts of an anchor file.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct AnchorBytes {
    pub mlp: usize,
    pub positions: usize,
    pub features: usize,
    pub base: usize,
    pub file: usize,
}

/// A block (SPEC §12.1): `channels` columns of `rows` values, each with its step and the
/// cheapest table (context tables allowed: the rows are one stream).
fn block(columns: &[Vec<i32>], steps: &[f32]) -> Vec<u8> {
    let rows = columns.first().map_or(0, Vec::len);
    let all = 0..rows; // each column is one stream (one context run)
    let chosen: Vec<tables::ChosenTable> =
        columns.par_iter().map(|c| tables::compare(c, Some(std::slice::from_ref(&all)), None).best).collect();
    let mut out = write_channel_params(steps, chosen.iter().map(|t| &t.bytes[..]));
    let refs: Vec<&ChannelTable> = chosen.iter().map(|t| &t.table).collect();
    let cols: Vec<&[i32]> = columns.iter().map(Vec::as_slice).collect();
    out.extend(write_channel_streams(&refs, &cols));
    out
}

fn columns(values: &[i32], width: usize) -> Vec<Vec<i32>> {
    (0..width).map(|j| values.iter().skip(j).step_by(width).copied().collect()).collect()
}

/// Writes a 7.0 file (SPEC §12) of `fixed`; `input` is the encoder's input (Gaussians, SH degree)
/// for the info section.
pub fn write(fixed: &Fixed, input: (usize, u8)) -> (Vec<u8>, AnchorBytes) {
    let set = &fixed.set;
    // Per layer: the length table of its zigzagged weights, then their stream (SPEC §12.1).
    let mut weights = Vec::new();
    let mut rest = &set.mlp.weights[..];
    for l in &set.mlp.layers {
        let (layer, tail) = rest.split_at(l.outputs * (l.inputs + 1));
        let z: Vec<u64> = layer.iter().map(|&w| u64::from(zigzag(w))).collect();
        let lens: Vec<i32> = z.iter().map(|&v| delta_length(v) as i32).collect();
        let t = tables::compare(&lens, None, None).best; // lengths are never context-coded (SPEC §12.1)
        weights.extend_from_slice(&t.bytes);
        weights.extend(write_position_stream(&t.table, &z));
        rest = tail;
    }
    // The positions are one stream (SPEC §12.1).
    let deltas = morton_deltas(&fixed.morton, std::slice::from_ref(&(0..fixed.morton.len())));
    let lens: Vec<i32> = deltas.iter().map(|&d| delta_length(d) as i32).collect();
    let t = tables::compare(&lens, None, None).best; // position lengths are never context-coded (SPEC §4)
    let mut positions = write_position_params(&fixed.grid, &t.bytes);
    positions.extend(write_position_stream(&t.table, &deltas));
    let feature_block = block(&columns(&set.feature_values, set.features), &vec![1.0; set.features]);
    let base_block = block(&columns(&fixed.base, 3), &[fixed.base_step; 3]);
    let section = write_anchors(&AnchorSection {
        features: set.features,
        shift: set.shift,
        layers: &set.mlp.layers,
        out_steps: &set.out_steps,
        weights: &weights,
        positions: &positions,
        feature_block: &feature_block,
        base_block: &base_block,
    });
    let info = write_info(&EncoderInfo { input_gaussians: input.0 as u32, input_sh_degree: input.1 });
    let header = Header {
        version_major: VERSION_MAJOR_ANCHORS,
        version_minor: VERSION_MINOR,
        gaussians: fixed.decoded.len() as u32,
        sh_degree: fixed.decoded.sh_degree,
    };
    let sections = [
        Section { kind: ANCHORS_KIND, chunk: 0, flags: 0, data: &section },
        Section { kind: INFO_KIND, chunk: 0, flags: SECTION_OPTIONAL, data: &info },
    ];
    let bytes = write_padded(&header, &sections);
    let sizes = AnchorBytes {
        mlp: weights.len(),
        positions: positions.len(),
        features: feature_block.len(),
        base: base_block.len(),
        file: bytes.len(),
    };
    (bytes, sizes)
}

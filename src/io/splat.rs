//! antimatter15's `.splat` format (the WebGL splat viewer's): 32 bytes per Gaussian, no header.
//!
//! Per Gaussian: position `3 × f32`, linear scale `3 × f32` (`exp(log_scale)`), colour `4 × u8`
//! (`RGB = clamp((0.5 + SH_C0·dc)·255)`, `A = sigmoid(opacity)·255`), rotation `4 × u8`
//! (normalised `w, x, y, z`, each `v·128 + 128` clamped). View-dependent SH is dropped (the format
//! has no place for it). Gaussians are written in the order of the reference converter: by
//! `exp(Σ log_scale) · sigmoid(opacity)` descending, so viewers that stream the file draw the
//! largest, most opaque Gaussians first.

use crate::io::atomic::write_bytes_atomic;
use crate::{Error, Result};
use gscodec_decoder::math::{normalize_quat, sigmoid, SH_C0};
use gscodec_decoder::Splats;
use std::path::Path;

/// Bytes per Gaussian.
pub const SPLAT_STRIDE: usize = 32;

fn to_u8(x: f32) -> u8 {
    x.round().clamp(0.0, 255.0) as u8
}

/// Encodes a scene as `.splat` bytes (SH beyond the DC term is dropped).
pub fn encode_splat(splats: &Splats) -> Vec<u8> {
    let importance = |i: usize| -> f32 {
        let s = splats.log_scales[i];
        (s[0] + s[1] + s[2]).exp() * sigmoid(splats.opacity_logits[i])
    };
    let mut order: Vec<usize> = (0..splats.len()).collect();
    order.sort_by(|&a, &b| importance(b).total_cmp(&importance(a)));
    let mut out = Vec::with_capacity(splats.len() * SPLAT_STRIDE);
    for i in order {
        splats.positions[i].iter().for_each(|v| out.extend_from_slice(&v.to_le_bytes()));
        splats.log_scales[i].iter().for_each(|v| out.extend_from_slice(&v.exp().to_le_bytes()));
        out.extend(splats.sh_dc[i].map(|c| to_u8((0.5 + SH_C0 * c) * 255.0)));
        out.push(to_u8(sigmoid(splats.opacity_logits[i]) * 255.0));
        out.extend(normalize_quat(splats.rotations[i]).map(|v| to_u8(v * 128.0 + 128.0)));
    }
    out
}

/// Decodes `.splat` bytes to an SH-degree-0 scene (the inverse of [`encode_splat`] up to its bytes).
pub fn decode_splat(bytes: &[u8]) -> Result<Splats, String> {
    if bytes.len() % SPLAT_STRIDE != 0 {
        return Err(format!("{} bytes is not a multiple of {SPLAT_STRIDE}", bytes.len()));
    }
    let f = |r: &[u8], at: usize| f32::from_le_bytes(r[at..at + 4].try_into().unwrap());
    let mut s = Splats::new(0);
    for r in bytes.chunks_exact(SPLAT_STRIDE) {
        let pos = [f(r, 0), f(r, 4), f(r, 8)];
        let scale = [f(r, 12), f(r, 16), f(r, 20)];
        if !pos.iter().chain(&scale).all(|v| v.is_finite()) || scale.iter().any(|&v| v <= 0.0) {
            return Err(format!("Gaussian {}: non-finite position or non-positive scale", s.len()));
        }
        let a = (r[27] as f32 / 255.0).clamp(0.25 / 255.0, 1.0 - 0.25 / 255.0);
        let rot = [r[28], r[29], r[30], r[31]].map(|b| (b as f32 - 128.0) / 128.0);
        let rot = if rot.iter().all(|&v| v == 0.0) { [1.0, 0.0, 0.0, 0.0] } else { rot };
        s.push(pos, scale.map(f32::ln), rot, (a / (1.0 - a)).ln(), [r[24], r[25], r[26]].map(|b| (b as f32 / 255.0 - 0.5) / SH_C0), &[]);
    }
    Ok(s)
}

/// Writes `splats` as `.splat` atomically.
pub fn write_splat(path: &Path, splats: &Splats) -> Result<()> {
    splats.validate().map_err(|e| Error::input(path, format!("cannot encode as .splat: {e}")))?;
    write_bytes_atomic(path, &encode_splat(splats))
}

/// Reads a `.splat` file.
pub fn read_splat(path: &Path) -> Result<Splats> {
    let bytes = std::fs::read(path).map_err(|e| Error::input(path, format!("cannot read: {e}")))?;
    decode_splat(&bytes).map_err(|m| Error::input(path, format!("not a valid .splat file: {m}")))
}

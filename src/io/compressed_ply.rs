//! PlayCanvas's compressed PLY (`.compressed.ply`): read and write.
//!
//! Layout, per splat-transform's reader and writer (facts, not code): a binary little-endian PLY
//! with an element `chunk` (one per 256 Gaussians: float `min_x min_y min_z max_x max_y max_z
//! min_scale_{x,y,z} max_scale_{x,y,z}`, optionally `min_r min_g min_b max_r max_g max_b`), an
//! element `vertex` (uint `packed_position packed_rotation packed_scale packed_color`) and, for SH
//! degree ≥ 1, an element `sh` (uchar `f_rest_0..3K-1`, channel-major as in `.ply`).
//!
//! * position and log-scale: 11-10-11 bits (x in the top 11 bits), each a fraction of the chunk's
//!   `[min, max]` (scale bounds clamped to ±20);
//! * rotation: 2-10-10-10 smallest three of `(rot_0..rot_3) = (w, x, y, z)`: the top 2 bits index
//!   the largest component (made positive), then the other three in order, each `v·√½ + ½` in 10
//!   bits;
//! * colour: 8-8-8-8, RGB = `0.5 + SH_C0·f_dc` as a fraction of the chunk's colour range (or of
//!   [0, 1] when the chunk has no colour bounds), A = `sigmoid(opacity)`;
//! * SH: `b = trunc((v/8 + ½)·256)` clamped to a byte, read back as `((b + ½)/256 − ½)·8`
//!   (bytes 0 and 255 as −4 and +4).
//!
//! Unorm fields are written `floor(f·(2^bits − 1) + ½)`. Gaussians are written in Morton order.
//! Coordinates are the `.ply`'s, unchanged.

use crate::io::atomic::write_bytes_atomic;
use crate::io::ply::{parse_header, Format, ScalarType};
use crate::io::sog::morton_order;
use crate::io::spz::alpha_to_logit;
use crate::{Error, Result};
use gscodec_decoder::math::{normalize_quat, sh_rest_coeffs, sigmoid, SH_C0};
use gscodec_decoder::Splats;
use std::path::Path;

/// Gaussians per chunk.
pub const CHUNK_SIZE: usize = 256;

const CHUNK_PROPS: [&str; 18] = [
    "min_x",
    "min_y",
    "min_z",
    "max_x",
    "max_y",
    "max_z",
    "min_scale_x",
    "min_scale_y",
    "min_scale_z",
    "max_scale_x",
    "max_scale_y",
    "max_scale_z",
    "min_r",
    "min_g",
    "min_b",
    "max_r",
    "max_g",
    "max_b",
];
const VERTEX_PROPS: [&str; 4] = ["packed_position", "packed_rotation", "packed_scale", "packed_color"];

/// True when a PLY file name ends in `.compressed.ply` (the name writers choose the format by).
pub fn is_compressed_ply_name(path: &Path) -> bool {
    path.file_name().is_some_and(|n| n.to_string_lossy().to_ascii_lowercase().ends_with(".compressed.ply"))
}

/// True when `bytes` is a PLY whose header has PlayCanvas's `chunk` element and packed vertices.
pub fn is_compressed_ply(bytes: &[u8]) -> bool {
    parse_header(bytes).is_ok_and(|h| {
        h.elements.iter().any(|e| e.name == "chunk")
            && h.elements[h.vertex].props.as_ref().is_some_and(|p| p.iter().any(|(n, _)| n == "packed_position"))
    })
}

/// Reads a compressed PLY file.
pub fn read_compressed_ply(path: &Path) -> Result<Splats> {
    let bytes = std::fs::read(path).map_err(|e| Error::input(path, format!("cannot read: {e}")))?;
    decode_compressed_ply(&bytes).map_err(|m| Error::input(path, format!("not a valid compressed PLY: {m}")))
}

/// Writes `splats` as a compressed PLY atomically.
pub fn write_compressed_ply(path: &Path, splats: &Splats) -> Result<()> {
    let bytes = encode_compressed_ply(splats).map_err(|m| Error::input(path, format!("cannot encode as compressed PLY: {m}")))?;
    write_bytes_atomic(path, &bytes)
}

/// Byte offsets of `names` within one record of `props`, each required with type `ty`.
fn offsets(props: &[(String, ScalarType)], names: &[&str], ty: ScalarType, element: &str) -> Result<Vec<usize>, String> {
    names
        .iter()
        .map(|want| {
            let mut at = 0;
            for (name, t) in props {
                if name == want {
                    return if *t == ty { Ok(at) } else { Err(format!("`{element}` property `{want}` has type {t:?}, {ty:?} expected")) };
                }
                at += t.size();
            }
            Err(format!("`{element}` has no property `{want}`"))
        })
        .collect()
}

fn f32_at(b: &[u8], at: usize) -> f32 {
    f32::from_le_bytes(b[at..at + 4].try_into().unwrap())
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(b[at..at + 4].try_into().unwrap())
}

fn unorm(v: u32, bits: u32) -> f32 {
    let t = (1u32 << bits) - 1;
    (v & t) as f32 / t as f32
}

fn lerp(a: f32, b: f32, t: f32) -> f32 {
    a * (1.0 - t) + b * t
}

/// Decodes compressed PLY bytes.
pub fn decode_compressed_ply(bytes: &[u8]) -> Result<Splats, String> {
    let h = parse_header(bytes)?;
    if h.format != Format::BinaryLe {
        return Err("compressed PLY must be binary_little_endian".into());
    }
    let find = |name: &str| h.elements.iter().position(|e| e.name == name);
    let (ci, vi) = (find("chunk").ok_or("no `chunk` element")?, h.vertex);
    let si = find("sh");
    if let Some(e) = h.elements.iter().find(|e| !["chunk", "vertex", "sh"].contains(&e.name.as_str())) {
        return Err(format!("unexpected element `{}`", e.name));
    }
    let props = |i: usize| h.elements[i].props.as_deref().ok_or_else(|| format!("`{}` has a list property", h.elements[i].name));
    let (cprops, vprops) = (props(ci)?, props(vi)?);
    let with_color = cprops.len() == 18;
    if cprops.len() != 12 && !with_color {
        return Err(format!("`chunk` has {} properties, 12 or 18 expected", cprops.len()));
    }
    let coff = offsets(cprops, &CHUNK_PROPS[..cprops.len()], ScalarType::F32, "chunk")?;
    let voff = offsets(vprops, &VERTEX_PROPS, ScalarType::U32, "vertex")?;
    let n = h.elements[vi].count;
    let n_chunks = h.elements[ci].count;
    if n.div_ceil(CHUNK_SIZE) != n_chunks {
        return Err(format!("{n_chunks} chunks for {n} vertices, {} expected", n.div_ceil(CHUNK_SIZE)));
    }
    let (degree, soff) = match si {
        None => (0, Vec::new()),
        Some(si) => {
            if h.elements[si].count != n {
                return Err(format!("`sh` has {} rows for {n} vertices", h.elements[si].count));
            }
            let sprops = props(si)?;
            let degree = match sprops.len() {
                9 => 1,
                24 => 2,
                45 => 3,
                m => return Err(format!("`sh` has {m} properties, 9, 24 or 45 expected")),
            };
            let names: Vec<String> = (0..sprops.len()).map(|i| format!("f_rest_{i}")).collect();
            let names: Vec<&str> = names.iter().map(String::as_str).collect();
            (degree, offsets(sprops, &names, ScalarType::U8, "sh")?)
        }
    };
    // Element extents in file order, checked against the body before anything is allocated.
    let body = &bytes[h.body_start..];
    let mut at = 0usize;
    let mut start = vec![0usize; h.elements.len()];
    for (i, e) in h.elements.iter().enumerate() {
        let stride: usize = e.props.as_ref().map_or(0, |p| p.iter().map(|(_, t)| t.size()).sum());
        start[i] = at;
        at =
            e.count.checked_mul(stride).and_then(|s| s.checked_add(at)).filter(|&end| end <= body.len()).ok_or_else(|| {
                format!("truncated: element `{}` ({} rows of {stride} bytes) runs past the end of the file", e.name, e.count)
            })?;
    }
    if at != body.len() {
        return Err(format!("{} bytes after the last element", body.len() - at));
    }
    let stride = |i: usize| -> usize { h.elements[i].props.as_ref().map_or(0, |p| p.iter().map(|(_, t)| t.size()).sum()) };
    let (cstride, vstride) = (stride(ci), stride(vi));
    let k = sh_rest_coeffs(degree);
    let mut s = Splats::new(degree);
    let mut rest = vec![0.0f32; 3 * k];
    for i in 0..n {
        let c = &body[start[ci] + (i / CHUNK_SIZE) * cstride..][..cstride];
        let v = &body[start[vi] + i * vstride..][..vstride];
        let ch = |j: usize| f32_at(c, coff[j]);
        let unpack_111011 = |w: u32| [unorm(w >> 21, 11), unorm(w >> 11, 10), unorm(w, 11)];
        let p = unpack_111011(u32_at(v, voff[0]));
        let sc = unpack_111011(u32_at(v, voff[2]));
        let col = u32_at(v, voff[3]);
        let rgb = [unorm(col >> 24, 8), unorm(col >> 16, 8), unorm(col >> 8, 8)];
        let dc = std::array::from_fn(|a| {
            let c = if with_color { lerp(ch(12 + a), ch(15 + a), rgb[a]) } else { rgb[a] };
            (c - 0.5) / SH_C0
        });
        if let Some(si) = si {
            let row = &body[start[si] + i * stride(si)..][..stride(si)];
            // File: channel-major f_rest_{c*K+k}; Splats: [k][c].
            for (j, &o) in soff.iter().enumerate() {
                let b = row[o];
                let unit = match b {
                    0 => 0.0,
                    255 => 1.0,
                    _ => (b as f32 + 0.5) / 256.0,
                };
                rest[(j % k) * 3 + j / k] = (unit - 0.5) * 8.0;
            }
        }
        s.push(
            std::array::from_fn(|a| lerp(ch(a), ch(3 + a), p[a])),
            std::array::from_fn(|a| lerp(ch(6 + a), ch(9 + a), sc[a])),
            unpack_rotation(u32_at(v, voff[1])),
            alpha_to_logit(col as u8),
            dc,
            &rest,
        );
    }
    s.validate().map_err(|e| format!("invalid scene: {e}"))?;
    Ok(s)
}

/// 2-10-10-10 smallest three to `(w, x, y, z)`.
fn unpack_rotation(w: u32) -> [f32; 4] {
    let norm = std::f32::consts::SQRT_2;
    let small = [(unorm(w >> 20, 10) - 0.5) * norm, (unorm(w >> 10, 10) - 0.5) * norm, (unorm(w, 10) - 0.5) * norm];
    let m = (1.0 - small.iter().map(|v| v * v).sum::<f32>()).max(0.0).sqrt();
    let largest = (w >> 30) as usize;
    let mut q = [0.0; 4];
    let mut j = 0;
    for (i, v) in q.iter_mut().enumerate() {
        if i == largest {
            *v = m;
        } else {
            *v = small[j];
            j += 1;
        }
    }
    q
}

fn pack_unorm(v: f32, bits: u32) -> u32 {
    let t = ((1u32 << bits) - 1) as f32;
    (v * t + 0.5).floor().clamp(0.0, t) as u32
}

fn pack_rotation(rot: [f32; 4]) -> u32 {
    let mut q = normalize_quat(rot);
    let largest = (1..4).fold(0, |m, i| if q[i].abs() > q[m].abs() { i } else { m });
    if q[largest] < 0.0 {
        q = q.map(|v| -v);
    }
    let mut w = largest as u32;
    for (i, &v) in q.iter().enumerate() {
        if i != largest {
            w = (w << 10) | pack_unorm(v * std::f32::consts::FRAC_1_SQRT_2 + 0.5, 10);
        }
    }
    w
}

/// `(x − min)/(max − min)` clamped to [0, 1]; 0 for a range below 1e-5 (the reference's rule).
fn normalize(x: f32, min: f32, max: f32) -> f32 {
    if x <= min {
        0.0
    } else if x >= max {
        1.0
    } else if max - min < 1e-5 {
        0.0
    } else {
        (x - min) / (max - min)
    }
}

/// Encodes a scene as compressed PLY bytes (Morton order, 256 Gaussians per chunk).
pub fn encode_compressed_ply(splats: &Splats) -> Result<Vec<u8>, String> {
    splats.validate().map_err(|e| e.to_string())?;
    let n = splats.len();
    let k = splats.rest_coeffs();
    let order = morton_order(&splats.positions);
    let n_chunks = n.div_ceil(CHUNK_SIZE);
    let mut head = format!(
        "ply\nformat binary_little_endian 1.0\ncomment Generated by gscodec {}\nelement chunk {n_chunks}\n",
        env!("CARGO_PKG_VERSION")
    );
    CHUNK_PROPS.iter().for_each(|p| head.push_str(&format!("property float {p}\n")));
    head.push_str(&format!("element vertex {n}\n"));
    VERTEX_PROPS.iter().for_each(|p| head.push_str(&format!("property uint {p}\n")));
    if k > 0 {
        head.push_str(&format!("element sh {n}\n"));
        (0..3 * k).for_each(|i| head.push_str(&format!("property uchar f_rest_{i}\n")));
    }
    head.push_str("end_header\n");
    let mut chunks = Vec::with_capacity(n_chunks * 18 * 4);
    let mut verts = Vec::with_capacity(n * 16);
    let mut sh = Vec::with_capacity(n * 3 * k);
    for members in order.chunks(CHUNK_SIZE) {
        let color = |g: usize| splats.sh_dc[g].map(|c| c * SH_C0 + 0.5);
        let bounds = |f: &dyn Fn(usize) -> [f32; 3]| -> ([f32; 3], [f32; 3]) {
            members.iter().fold(([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]), |(lo, hi), &g| {
                let v = f(g);
                (std::array::from_fn(|a| lo[a].min(v[a])), std::array::from_fn(|a| hi[a].max(v[a])))
            })
        };
        let (plo, phi) = bounds(&|g| splats.positions[g]);
        let (slo, shi) = bounds(&|g| splats.log_scales[g]);
        let (slo, shi) = (slo.map(|v| v.clamp(-20.0, 20.0)), shi.map(|v| v.clamp(-20.0, 20.0)));
        let (clo, chi) = bounds(&color);
        for v in plo.iter().chain(&phi).chain(&slo).chain(&shi).chain(&clo).chain(&chi) {
            chunks.extend_from_slice(&v.to_le_bytes());
        }
        for &g in members {
            let pack = |v: [f32; 3], lo: [f32; 3], hi: [f32; 3]| {
                let t: [f32; 3] = std::array::from_fn(|a| normalize(v[a], lo[a], hi[a]));
                pack_unorm(t[0], 11) << 21 | pack_unorm(t[1], 10) << 11 | pack_unorm(t[2], 11)
            };
            let c = color(g);
            let ct: [f32; 3] = std::array::from_fn(|a| normalize(c[a], clo[a], chi[a]));
            let packed_color = pack_unorm(ct[0], 8) << 24
                | pack_unorm(ct[1], 8) << 16
                | pack_unorm(ct[2], 8) << 8
                | pack_unorm(sigmoid(splats.opacity_logits[g]), 8);
            for w in [
                pack(splats.positions[g], plo, phi),
                pack_rotation(splats.rotations[g]),
                pack(splats.log_scales[g], slo, shi),
                packed_color,
            ] {
                verts.extend_from_slice(&w.to_le_bytes());
            }
            let rest = splats.rest_of(g);
            for c in 0..3 {
                for kk in 0..k {
                    sh.push(((rest[kk * 3 + c] / 8.0 + 0.5) * 256.0).trunc().clamp(0.0, 255.0) as u8);
                }
            }
        }
    }
    let mut out = head.into_bytes();
    out.extend_from_slice(&chunks);
    out.extend_from_slice(&verts);
    out.extend_from_slice(&sh);
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rotation_packing_round_trips_within_ten_bits() {
        for q in [[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, -1.0], [0.3, -0.5, 0.7, 0.1], [-0.5, 0.5, -0.5, 0.5]] {
            let n = normalize_quat(q);
            let d = unpack_rotation(pack_rotation(q));
            let dot: f32 = (0..4).map(|i| n[i] * d[i]).sum();
            assert!(dot.abs() > 1.0 - 2e-6, "{q:?} -> {d:?}");
        }
    }

    #[test]
    fn rejects_garbage_without_panicking() {
        let header = "ply\nformat binary_little_endian 1.0\nelement chunk 1\nproperty float min_x\nelement vertex 1\nproperty uint packed_position\nend_header\n";
        for bytes in [&b""[..], b"ply\n", header.as_bytes()] {
            assert!(decode_compressed_ply(bytes).is_err());
        }
    }
}

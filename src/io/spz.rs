//! Niantic's SPZ format (read versions 2–4, write 3 or 4).
//!
//! Layout (all little-endian), per the public reference implementation (nianticlabs/spz):
//!
//! * **v2 / v3**: the whole file is one gzip stream holding a 16-byte header
//!   (`magic "NGSP"`, `version u32`, `num_points u32`, `sh_degree u8`, `fractional_bits u8`,
//!   `flags u8`, `reserved u8`) followed by the attribute arrays in this order: positions,
//!   alphas, colours, scales, rotations, SH.
//! * **v4**: an uncompressed 32-byte header (the 16 bytes above with `reserved` holding the number
//!   of streams, then `toc_offset u32` and 12 reserved bytes), a table of contents of
//!   `(compressed u64, uncompressed u64)` per stream, then one zstd frame per attribute array in
//!   the same order (the SH stream is absent for degree 0).
//!
//! Attribute coding: positions are 24-bit signed fixed point with `fractional_bits`; log-scales
//! are bytes `(s + 10) * 16`; rotations are three bytes `x,y,z * 127.5 + 127.5` with `w ≥ 0` in
//! v2, and "smallest three" in v3+ (a `u32`: top 2 bits = index of the largest |component| in
//! `x,y,z,w` order, then three 10-bit fields of sign bit + 9-bit magnitude scaled by `√½`, most
//! significant first); alpha is the sigmoid in a byte; colour is `dc * 0.15 * 255 + 127.5`;
//! SH coefficients are bytes `v * 128 + 128`, coefficient-major with channels interleaved
//! (the same order as [`Splats::sh_rest`]).
//!
//! Coordinates: the SPZ specification names RUB as its frame, but Niantic's `ply_to_spz` /
//! `spz_to_ply` tools at default settings store the `.ply` coordinates unchanged (checked against
//! `spz-baseline/k7000_spz_decoded.ply`: identical positions, rotations and SH signs). We do the
//! same: no axis flip on read or write, so `.ply → .spz → .ply` keeps the scene in place.

use crate::io::atomic::write_bytes_atomic;
use crate::{Error, Result};
use gscodec_decoder::math::{normalize_quat, sh_rest_coeffs, sigmoid};
use gscodec_decoder::Splats;
use std::io::Read;
use std::path::Path;

/// `"NGSP"` read as a little-endian `u32`.
pub const MAGIC: u32 = 0x5053_474e;
/// Scale of the DC colour bytes (the reference's `colorScale`).
pub const COLOR_SCALE: f32 = 0.15;
/// Fractional bits the writer uses when the scene fits (the reference's choice, ~0.25 mm).
pub const DEFAULT_FRACTIONAL_BITS: u8 = 12;
/// Antialiased (mip-splatting) flag bit.
pub const FLAG_ANTIALIASED: u8 = 0x1;

/// Which SPZ version to write.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SpzVersion {
    /// Gzip container, smallest-three rotations (readable by every reader since 2025).
    V3,
    /// Per-attribute zstd streams (the current reference tool's output).
    #[default]
    V4,
}

/// The fixed fields of an SPZ header.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SpzHeader {
    pub version: u32,
    pub num_points: u32,
    pub sh_degree: u8,
    pub fractional_bits: u8,
    pub flags: u8,
}

/// Reads an `.spz` file. Bad content is an input error naming the file.
pub fn read_spz(path: &Path) -> Result<Splats> {
    let bytes = std::fs::read(path).map_err(|e| Error::input(path, format!("cannot read: {e}")))?;
    decode_spz(&bytes).map_err(|m| Error::input(path, format!("not a valid SPZ file: {m}")))
}

/// Writes `splats` as SPZ (`version`) atomically.
pub fn write_spz(path: &Path, splats: &Splats, version: SpzVersion) -> Result<()> {
    let bytes = encode_spz(splats, version).map_err(|m| Error::input(path, format!("cannot encode as SPZ: {m}")))?;
    write_bytes_atomic(path, &bytes)
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(b[at..at + 4].try_into().unwrap())
}

fn u64_at(b: &[u8], at: usize) -> u64 {
    u64::from_le_bytes(b[at..at + 8].try_into().unwrap())
}

/// Byte sizes of the six attribute arrays for `h`.
fn stream_sizes(h: &SpzHeader) -> [u64; 6] {
    let n = h.num_points as u64;
    let rot = if h.version >= 3 { 4 } else { 3 };
    [n * 9, n, n * 3, n * 3, n * rot, n * 3 * sh_rest_coeffs(h.sh_degree) as u64]
}

fn parse_fixed_header(b: &[u8]) -> Result<SpzHeader, String> {
    if b.len() < 16 {
        return Err("file is shorter than the 16-byte header".into());
    }
    if u32_at(b, 0) != MAGIC {
        return Err("bad magic (expected \"NGSP\")".into());
    }
    let h = SpzHeader { version: u32_at(b, 4), num_points: u32_at(b, 8), sh_degree: b[12], fractional_bits: b[13], flags: b[14] };
    if !(2..=4).contains(&h.version) {
        return Err(format!("version {} is not supported (2, 3 and 4 are)", h.version));
    }
    if h.sh_degree > 3 {
        return Err(format!("SH degree {} is out of range (0..=3)", h.sh_degree));
    }
    if h.fractional_bits > 24 {
        return Err(format!("{} fractional bits is out of range (0..=24)", h.fractional_bits));
    }
    Ok(h)
}

/// Reads the header of an SPZ file (decompressing only the first bytes of a gzip container).
pub fn peek_spz_header(bytes: &[u8]) -> Result<SpzHeader, String> {
    if bytes.starts_with(&[0x1f, 0x8b]) {
        let mut head = Vec::with_capacity(16);
        flate2::read::GzDecoder::new(bytes).take(16).read_to_end(&mut head).map_err(|e| format!("gzip: {e}"))?;
        parse_fixed_header(&head)
    } else {
        parse_fixed_header(bytes)
    }
}

/// Decompresses `src` through `reader`, refusing more than `limit` bytes (no allocation beyond
/// what the data really holds).
fn read_limited(reader: impl Read, limit: u64, what: &str) -> Result<Vec<u8>, String> {
    let mut out = Vec::new();
    reader.take(limit + 1).read_to_end(&mut out).map_err(|e| format!("{what}: {e}"))?;
    if out.len() as u64 > limit {
        return Err(format!("{what}: more data than the header announces"));
    }
    Ok(out)
}

/// Decodes SPZ bytes (v2/v3 gzip or v4 zstd) into a scene.
pub fn decode_spz(bytes: &[u8]) -> Result<Splats, String> {
    let (h, streams) = if bytes.starts_with(&[0x1f, 0x8b]) {
        let h = peek_spz_header(bytes)?;
        if h.version >= 4 {
            return Err(format!("version {} inside a gzip container", h.version));
        }
        let sizes = stream_sizes(&h);
        let total: u64 = 16 + sizes.iter().sum::<u64>();
        let raw = read_limited(flate2::read::GzDecoder::new(bytes), total, "gzip")?;
        if (raw.len() as u64) < total {
            return Err(format!("truncated: {} bytes of data, the header announces {total}", raw.len()));
        }
        let mut at = 16usize;
        let streams: Vec<Vec<u8>> = sizes
            .iter()
            .map(|&s| {
                let v = raw[at..at + s as usize].to_vec();
                at += s as usize;
                v
            })
            .collect();
        (h, streams)
    } else {
        let h = parse_fixed_header(bytes)?;
        if h.version < 4 {
            return Err(format!("version {} must be gzip-compressed", h.version));
        }
        if bytes.len() < 32 {
            return Err("file is shorter than the 32-byte v4 header".into());
        }
        let num_streams = bytes[15] as usize;
        let toc = u32_at(bytes, 16) as usize;
        let sizes = stream_sizes(&h);
        let expected_streams = if h.sh_degree == 0 { 5 } else { 6 };
        if num_streams != expected_streams && num_streams != 6 {
            return Err(format!("{num_streams} streams, expected {expected_streams}"));
        }
        let toc_end = toc
            .checked_add(num_streams * 16)
            .filter(|&e| e <= bytes.len() && toc >= 32)
            .ok_or("table of contents lies outside the file")?;
        let mut at = toc_end as u64;
        let mut streams = Vec::with_capacity(6);
        for (s, &want) in sizes.iter().enumerate().take(num_streams) {
            let (comp, uncomp) = (u64_at(bytes, toc + 16 * s), u64_at(bytes, toc + 16 * s + 8));
            if uncomp != want {
                return Err(format!("stream {s} holds {uncomp} bytes, {want} expected for {} Gaussians", h.num_points));
            }
            let end = at
                .checked_add(comp)
                .filter(|&e| e <= bytes.len() as u64)
                .ok_or_else(|| format!("stream {s} runs past the end of the file"))?;
            let src = &bytes[at as usize..end as usize];
            let data = if want == 0 && comp == 0 {
                Vec::new()
            } else {
                let dec = zstd::stream::read::Decoder::with_buffer(src).map_err(|e| format!("zstd: {e}"))?;
                read_limited(dec, want, "zstd")?
            };
            if data.len() as u64 != want {
                return Err(format!("stream {s} decompresses to {} bytes, {want} expected", data.len()));
            }
            streams.push(data);
            at = end;
        }
        if streams.len() == 5 {
            streams.push(Vec::new());
        }
        (h, streams)
    };
    Ok(unpack(&h, &streams))
}

/// Turns the six attribute arrays (already length-checked) into a scene.
fn unpack(h: &SpzHeader, s: &[Vec<u8>]) -> Splats {
    let n = h.num_points as usize;
    let k = sh_rest_coeffs(h.sh_degree);
    let (pos, alpha, color, scale, rot, sh) = (&s[0], &s[1], &s[2], &s[3], &s[4], &s[5]);
    let pscale = 1.0 / (1u32 << h.fractional_bits) as f32;
    let mut out = Splats::new(h.sh_degree);
    out.positions = pos
        .chunks_exact(9)
        .map(|p| {
            std::array::from_fn(|a| {
                let v = u32::from(p[3 * a]) | u32::from(p[3 * a + 1]) << 8 | u32::from(p[3 * a + 2]) << 16;
                ((v << 8) as i32 >> 8) as f32 * pscale
            })
        })
        .collect();
    out.log_scales = scale.chunks_exact(3).map(|c| std::array::from_fn(|a| c[a] as f32 / 16.0 - 10.0)).collect();
    out.rotations = if h.version >= 3 {
        rot.chunks_exact(4).map(|r| unpack_smallest_three(u32::from_le_bytes([r[0], r[1], r[2], r[3]]))).collect()
    } else {
        rot.chunks_exact(3)
            .map(|r| {
                let [x, y, z] = [r[0], r[1], r[2]].map(|b| b as f32 / 127.5 - 1.0);
                [(1.0 - (x * x + y * y + z * z)).max(0.0).sqrt(), x, y, z]
            })
            .collect()
    };
    out.opacity_logits = alpha.iter().map(|&a| alpha_to_logit(a)).collect();
    out.sh_dc = color.chunks_exact(3).map(|c| std::array::from_fn(|a| (c[a] as f32 / 255.0 - 0.5) / COLOR_SCALE)).collect();
    out.sh_rest = sh.iter().map(|&b| (b as f32 - 128.0) / 128.0).collect();
    debug_assert_eq!(out.sh_rest.len(), n * k * 3);
    out
}

/// Inverse sigmoid of `a / 255`. Bytes 0 and 255 (probability 0 or 1, ±∞ in the reference) are
/// moved a quarter step inside so the logit stays finite and re-encodes to the same byte.
pub(crate) fn alpha_to_logit(a: u8) -> f32 {
    let p = (a as f32 / 255.0).clamp(0.25 / 255.0, 1.0 - 0.25 / 255.0);
    (p / (1.0 - p)).ln()
}

/// Smallest-three quaternion (`x,y,z,w` component indices in the packed word) to `(w, x, y, z)`.
fn unpack_smallest_three(mut comp: u32) -> [f32; 4] {
    const MASK: u32 = (1 << 9) - 1;
    let largest = (comp >> 30) as usize;
    let mut q = [0.0f32; 4]; // x, y, z, w
    let mut sum = 0.0f32;
    for i in (0..4).rev() {
        if i != largest {
            let mag = comp & MASK;
            let neg = (comp >> 9) & 1 == 1;
            comp >>= 10;
            let v = std::f32::consts::FRAC_1_SQRT_2 * (mag as f32 / MASK as f32);
            q[i] = if neg { -v } else { v };
            sum += q[i] * q[i];
        }
    }
    q[largest] = (1.0 - sum).max(0.0).sqrt();
    [q[3], q[0], q[1], q[2]]
}

/// `(w, x, y, z)` to the smallest-three word (the reference's `packQuaternionSmallestThree`).
fn pack_smallest_three(rot: [f32; 4]) -> u32 {
    let [w, x, y, z] = normalize_quat(rot);
    let q = [x, y, z, w];
    let mut largest = 0;
    for i in 1..4 {
        if q[i].abs() > q[largest].abs() {
            largest = i;
        }
    }
    let negate = q[largest] < 0.0;
    let mut comp = largest as u32;
    for (i, &v) in q.iter().enumerate() {
        if i != largest {
            let neg = ((v < 0.0) ^ negate) as u32;
            let mag = ((511.0 * (v.abs() / std::f32::consts::FRAC_1_SQRT_2) + 0.5) as u32).min(511);
            comp = (comp << 10) | (neg << 9) | mag;
        }
    }
    comp
}

/// The reference's `toUint8`: round half away from zero, clamp to a byte.
fn to_u8(x: f32) -> u8 {
    x.round().clamp(0.0, 255.0) as u8
}

/// The reference's SH quantiser: 8-bit value snapped to the centre of a `bucket`-wide bin
/// (5 bits for band 1, 4 bits for higher bands), 0 always representable.
fn quantize_sh(x: f32, bits: u32) -> u8 {
    let bucket = 1i32 << (8 - bits);
    let q = (x * 128.0).round() as i32 + 128;
    let q = (q + bucket / 2) / bucket * bucket;
    q.clamp(0, 255) as u8
}

/// The largest number of fractional bits (≤ 12) at which every coordinate fits 24-bit fixed point.
fn fractional_bits_for(splats: &Splats) -> Result<u8, String> {
    let max = splats.positions.iter().flatten().fold(0.0f32, |m, v| m.max(v.abs()));
    (0..=DEFAULT_FRACTIONAL_BITS)
        .rev()
        .find(|&fb| (max * (1u32 << fb) as f32).round() < (1 << 23) as f32)
        .ok_or_else(|| format!("a coordinate of magnitude {max} does not fit SPZ's 24-bit fixed point"))
}

/// The six attribute arrays of `splats`, in file order.
fn pack(splats: &Splats, fractional_bits: u8, version: u32) -> [Vec<u8>; 6] {
    let pscale = (1u32 << fractional_bits) as f32;
    let pos = splats
        .positions
        .iter()
        .flat_map(|p| p.map(|v| (v * pscale).round() as i32))
        .flat_map(|f| [f as u8, (f >> 8) as u8, (f >> 16) as u8])
        .collect();
    let alpha = splats.opacity_logits.iter().map(|&o| to_u8(sigmoid(o) * 255.0)).collect();
    let color = splats.sh_dc.iter().flatten().map(|&c| to_u8(c * (COLOR_SCALE * 255.0) + 0.5 * 255.0)).collect();
    let scale = splats.log_scales.iter().flatten().map(|&s| to_u8((s + 10.0) * 16.0)).collect();
    let rot = if version >= 3 {
        splats.rotations.iter().flat_map(|&r| pack_smallest_three(r).to_le_bytes()).collect()
    } else {
        splats
            .rotations
            .iter()
            .flat_map(|&r| {
                let [w, x, y, z] = normalize_quat(r);
                let s = if w < 0.0 { -127.5 } else { 127.5 };
                [x, y, z].map(|v| to_u8(v * s + 127.5))
            })
            .collect()
    };
    let k = splats.rest_coeffs();
    let sh = splats.sh_rest.iter().enumerate().map(|(j, &v)| quantize_sh(v, if (j / 3) % k.max(1) < 3 { 5 } else { 4 })).collect();
    [pos, alpha, color, scale, rot, sh]
}

/// Encodes a scene as SPZ. Fails for non-finite values or coordinates beyond 24-bit fixed point.
pub fn encode_spz(splats: &Splats, version: SpzVersion) -> Result<Vec<u8>, String> {
    splats.validate().map_err(|e| e.to_string())?;
    let n = u32::try_from(splats.len()).map_err(|_| "too many Gaussians for SPZ (max 2^32-1)".to_string())?;
    let fb = fractional_bits_for(splats)?;
    let v = match version {
        SpzVersion::V3 => 3,
        SpzVersion::V4 => 4,
    };
    let streams = pack(splats, fb, v);
    let mut head = Vec::with_capacity(32);
    head.extend_from_slice(&MAGIC.to_le_bytes());
    head.extend_from_slice(&v.to_le_bytes());
    head.extend_from_slice(&n.to_le_bytes());
    head.extend_from_slice(&[splats.sh_degree, fb, 0]);
    match version {
        SpzVersion::V3 => {
            use std::io::Write;
            head.push(0);
            let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
            let write = |gz: &mut flate2::write::GzEncoder<Vec<u8>>| -> std::io::Result<()> {
                gz.write_all(&head)?;
                streams.iter().try_for_each(|s| gz.write_all(s))
            };
            write(&mut gz).map_err(|e| e.to_string())?;
            gz.finish().map_err(|e| e.to_string())
        }
        SpzVersion::V4 => {
            let used: Vec<&Vec<u8>> = streams.iter().take(if splats.sh_degree == 0 { 5 } else { 6 }).collect();
            head.push(used.len() as u8);
            head.extend_from_slice(&32u32.to_le_bytes());
            head.resize(32, 0);
            let compressed: Vec<Vec<u8>> =
                used.iter().map(|s| zstd::bulk::compress(s, 12).map_err(|e| e.to_string())).collect::<Result<_, _>>()?;
            for (c, s) in compressed.iter().zip(&used) {
                head.extend_from_slice(&(c.len() as u64).to_le_bytes());
                head.extend_from_slice(&(s.len() as u64).to_le_bytes());
            }
            compressed.iter().for_each(|c| head.extend_from_slice(c));
            Ok(head)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn smallest_three_round_trip_is_within_quantisation() {
        let qs = [[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, -1.0], [0.3, -0.5, 0.7, 0.1], [-0.5, 0.5, -0.5, 0.5], [0.01, -0.9, 0.2, 0.3]];
        for q in qs {
            let n = normalize_quat(q);
            let d = unpack_smallest_three(pack_smallest_three(q));
            // Same rotation up to sign; each small component within half a 9-bit step of √½.
            let dot: f32 = (0..4).map(|i| n[i] * d[i]).sum();
            assert!(dot.abs() > 1.0 - 1e-5, "{q:?} -> {d:?} (dot {dot})");
        }
    }

    #[test]
    fn sh_quantiser_matches_reference_buckets() {
        assert_eq!(quantize_sh(0.0, 5), 128);
        assert_eq!(quantize_sh(0.0, 4), 128);
        assert_eq!(quantize_sh(1.0, 4), 255);
        assert_eq!(quantize_sh(-1.0, 5), 0);
        assert_eq!(quantize_sh(0.05, 5), 136); // round(6.4)=6 -> 134 -> bucket 8 -> 136
    }

    #[test]
    fn fractional_bits_shrink_for_large_scenes() {
        let mut s = Splats::new(0);
        s.push([3000.0, 0.0, 0.0], [0.0; 3], [1.0, 0.0, 0.0, 0.0], 0.0, [0.0; 3], &[]);
        assert_eq!(fractional_bits_for(&s).unwrap(), 11);
        s.positions[0][0] = 1e9;
        assert!(fractional_bits_for(&s).is_err());
    }

    #[test]
    fn rejects_garbage_without_panicking() {
        for bytes in [
            &b""[..],
            b"NGSP",
            b"\x1f\x8b\x08\x00garbage",
            &[0x4e, 0x47, 0x53, 0x50, 4, 0, 0, 0, 255, 255, 255, 255, 3, 12, 0, 6, 32, 0, 0, 0],
        ] {
            assert!(decode_spz(bytes).is_err());
        }
        // A valid header announcing 2^32-1 points with a tiny body must fail cleanly, not allocate.
        let mut b = vec![0u8; 32 + 6 * 16];
        b[..4].copy_from_slice(&MAGIC.to_le_bytes());
        b[4] = 4;
        b[8..12].copy_from_slice(&u32::MAX.to_le_bytes());
        b[12] = 3;
        b[15] = 6;
        b[16] = 32;
        assert!(decode_spz(&b).is_err());
    }
}

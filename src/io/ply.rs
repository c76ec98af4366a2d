//! INRIA 3DGS `.ply` scenes: read (binary little/big endian and ascii) and write (binary little endian).
//!
//! Layout (DESIGN §3): `x y z [nx ny nz] f_dc_0..2 f_rest_* opacity scale_0..2 rot_0..3`, where
//! `opacity` is a logit, `scale_*` are log standard deviations, `rot_*` is a quaternion `(w, x, y, z)`
//! and `f_rest` is channel-major: coefficient `k` of channel `c` is `f_rest_{c*K+k}` with
//! `K = (d+1)^2 - 1`. The SH degree follows from the number of `f_rest` properties (0, 9, 24 or 45).
//!
//! Reading accepts properties in any order and of any scalar PLY type, ignores properties it does
//! not know (normals, `transform`, ...) and skips other elements with scalar properties. Every
//! count is checked against the file size before anything is allocated, and the scene is
//! validated (finite values, non-zero quaternions), so a bad file is an [`Error::input`].

use crate::io::atomic::write_bytes_atomic;
use crate::{Error, Result};
use gscodec_decoder::math::sh_rest_coeffs;
use gscodec_decoder::Splats;
use rayon::prelude::*;
use std::path::Path;

/// Reads an INRIA `.ply` scene.
///
/// # Errors
/// [`Error::input`] naming `path` when the file is missing, malformed, truncated, lies in its
/// header, or holds NaN/Inf values or zero quaternions.
pub fn read_ply(path: &Path) -> Result<Splats> {
    let bytes = std::fs::read(path).map_err(|e| Error::input(path, format!("cannot read: {e}")))?;
    read_ply_bytes(&bytes, path)
}

/// Reads an INRIA `.ply` scene from memory; `path` is only used in error messages.
pub fn read_ply_bytes(bytes: &[u8], path: &Path) -> Result<Splats> {
    let bad = |msg: String| Error::input(path, msg);
    let header = parse_header(bytes).map_err(bad)?;
    let layout = Layout::new(&header).map_err(bad)?;
    let body = &bytes[header.body_start..];
    let records = match header.format {
        Format::Ascii => read_ascii(body, &header, &layout),
        Format::BinaryLe | Format::BinaryBe => read_binary(body, &header, &layout),
    }
    .map_err(bad)?;
    let splats = layout.to_splats(&records);
    splats.validate().map_err(|e| Error::input(path, format!("invalid scene: {e}")))?;
    Ok(splats)
}

/// Writes `splats` as a binary little-endian INRIA `.ply` (normals written as zero, like the
/// reference trainer), atomically.
///
/// # Errors
/// [`Error::failure`] when the file cannot be written.
pub fn write_ply(path: &Path, splats: &Splats) -> Result<()> {
    write_bytes_atomic(path, &splats.to_ply())
}

// ---------------------------------------------------------------------------------------------
// Header

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Format {
    Ascii,
    BinaryLe,
    BinaryBe,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum ScalarType {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl ScalarType {
    fn parse(s: &str) -> Option<ScalarType> {
        Some(match s {
            "char" | "int8" => ScalarType::I8,
            "uchar" | "uint8" => ScalarType::U8,
            "short" | "int16" => ScalarType::I16,
            "ushort" | "uint16" => ScalarType::U16,
            "int" | "int32" => ScalarType::I32,
            "uint" | "uint32" => ScalarType::U32,
            "float" | "float32" => ScalarType::F32,
            "double" | "float64" => ScalarType::F64,
            _ => return None,
        })
    }

    pub(crate) fn size(self) -> usize {
        match self {
            ScalarType::I8 | ScalarType::U8 => 1,
            ScalarType::I16 | ScalarType::U16 => 2,
            ScalarType::I32 | ScalarType::U32 | ScalarType::F32 => 4,
            ScalarType::F64 => 8,
        }
    }

    /// Decodes one value from exactly `size()` bytes.
    #[inline]
    fn decode(self, b: &[u8], big: bool) -> f32 {
        macro_rules! num {
            ($t:ty, $n:expr) => {{
                let a: [u8; $n] = b[..$n].try_into().unwrap();
                if big {
                    <$t>::from_be_bytes(a)
                } else {
                    <$t>::from_le_bytes(a)
                }
            }};
        }
        match self {
            ScalarType::F32 => num!(f32, 4),
            ScalarType::F64 => num!(f64, 8) as f32,
            ScalarType::I8 => b[0] as i8 as f32,
            ScalarType::U8 => b[0] as f32,
            ScalarType::I16 => num!(i16, 2) as f32,
            ScalarType::U16 => num!(u16, 2) as f32,
            ScalarType::I32 => num!(i32, 4) as f32,
            ScalarType::U32 => num!(u32, 4) as f32,
        }
    }

    fn parse_ascii(self, tok: &str) -> Option<f32> {
        match self {
            ScalarType::F32 => tok.parse::<f32>().ok(),
            ScalarType::F64 => tok.parse::<f64>().ok().map(|v| v as f32),
            _ => tok.parse::<i64>().ok().map(|v| v as f32),
        }
    }
}

#[derive(Debug)]
pub(crate) struct Element {
    pub(crate) name: String,
    pub(crate) count: usize,
    /// Scalar properties; `None` when the element has a list property (only allowed after the vertices).
    pub(crate) props: Option<Vec<(String, ScalarType)>>,
}

#[derive(Debug)]
pub(crate) struct Header {
    pub(crate) format: Format,
    pub(crate) elements: Vec<Element>,
    pub(crate) vertex: usize,
    pub(crate) body_start: usize,
}

/// Headers longer than this are not PLY scenes.
const MAX_HEADER: usize = 1 << 20;

pub(crate) fn parse_header(bytes: &[u8]) -> std::result::Result<Header, String> {
    if !bytes.starts_with(b"ply\n") && !bytes.starts_with(b"ply\r\n") {
        return Err("not a PLY file (missing `ply` magic)".into());
    }
    let limit = bytes.len().min(MAX_HEADER);
    let end = find(&bytes[..limit], b"end_header").ok_or("PLY header has no `end_header`")?;
    let mut body_start = end + b"end_header".len();
    if bytes.get(body_start) == Some(&b'\r') {
        body_start += 1;
    }
    match bytes.get(body_start) {
        Some(b'\n') => body_start += 1,
        None => {}
        Some(_) => return Err("malformed `end_header` line".into()),
    }
    let text = std::str::from_utf8(&bytes[..end]).map_err(|_| "PLY header is not valid text")?;
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    for (lineno, line) in text.lines().enumerate().skip(1) {
        let words: Vec<&str> = line.split_whitespace().collect();
        let at = |msg: &str| format!("PLY header line {}: {msg}: `{}`", lineno + 1, line.trim());
        match words.as_slice() {
            [] | ["comment", ..] | ["obj_info", ..] => {}
            ["format", f, ver] => {
                if *ver != "1.0" {
                    return Err(at("unsupported PLY version"));
                }
                format = Some(match *f {
                    "ascii" => Format::Ascii,
                    "binary_little_endian" => Format::BinaryLe,
                    "binary_big_endian" => Format::BinaryBe,
                    _ => return Err(at("unknown format")),
                });
            }
            ["element", name, count] => {
                let count = count.parse::<usize>().map_err(|_| at("bad element count"))?;
                elements.push(Element { name: name.to_string(), count, props: Some(Vec::new()) });
            }
            ["property", "list", _, _, _] => {
                let el = elements.last_mut().ok_or_else(|| at("property before any element"))?;
                el.props = None;
            }
            ["property", ty, name] => {
                let el = elements.last_mut().ok_or_else(|| at("property before any element"))?;
                let ty = ScalarType::parse(ty).ok_or_else(|| at("unknown property type"))?;
                if let Some(props) = &mut el.props {
                    if props.iter().any(|(n, _)| n == name) {
                        return Err(at("duplicate property"));
                    }
                    props.push((name.to_string(), ty));
                }
            }
            _ => return Err(at("unrecognised header line")),
        }
    }
    let format = format.ok_or("PLY header has no `format` line")?;
    let vertex = elements.iter().position(|e| e.name == "vertex").ok_or("PLY header has no `vertex` element")?;
    if elements[..=vertex].iter().any(|e| e.props.is_none()) {
        return Err("list properties in or before the `vertex` element are not supported".into());
    }
    Ok(Header { format, elements, vertex, body_start })
}

fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).position(|w| w == needle)
}

// ---------------------------------------------------------------------------------------------
// Property layout: where each vertex property goes in a flat per-Gaussian record.

/// Record slots: 0..3 position, 3..6 f_dc, 6 opacity, 7..10 scale, 10..14 rot, 14.. f_rest (file order).
const FIXED: [&str; 14] =
    ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"];

struct Layout {
    degree: u8,
    /// Record length: 14 + 3K.
    rec: usize,
    /// Per vertex property, in file order: (type, record slot or None when ignored).
    props: Vec<(ScalarType, Option<usize>)>,
    /// Bytes per vertex in binary files.
    stride: usize,
}

impl Layout {
    fn new(h: &Header) -> std::result::Result<Layout, String> {
        let props = h.elements[h.vertex].props.as_ref().expect("checked in parse_header");
        let n_rest = props.iter().filter(|(n, _)| n.starts_with("f_rest_")).count();
        let degree = match n_rest {
            0 => 0,
            9 => 1,
            24 => 2,
            45 => 3,
            n => return Err(format!("{n} `f_rest_*` properties; expected 0, 9, 24 or 45 (SH degree 0-3)")),
        };
        let mut slots = Vec::with_capacity(props.len());
        let mut seen = vec![false; 14 + n_rest];
        for (name, ty) in props {
            let slot = if let Some(i) = FIXED.iter().position(|f| f == name) {
                Some(i)
            } else if let Some(idx) = name.strip_prefix("f_rest_") {
                match idx.parse::<usize>() {
                    Ok(i) if i < n_rest => Some(14 + i),
                    _ => return Err(format!("property `{name}` out of range for {n_rest} `f_rest_*` properties")),
                }
            } else {
                None
            };
            if let Some(s) = slot {
                seen[s] = true;
            }
            slots.push((*ty, slot));
        }
        if let Some(missing) = (0..14).find(|&i| !seen[i]) {
            return Err(format!("required vertex property `{}` is missing", FIXED[missing]));
        }
        let stride = props.iter().map(|(_, t)| t.size()).sum();
        Ok(Layout { degree, rec: 14 + n_rest, props: slots, stride })
    }

    fn to_splats(&self, records: &[f32]) -> Splats {
        let k = sh_rest_coeffs(self.degree);
        let n = records.len() / self.rec;
        let mut s = Splats::new(self.degree);
        s.positions.reserve_exact(n);
        s.sh_dc.reserve_exact(n);
        s.opacity_logits.reserve_exact(n);
        s.log_scales.reserve_exact(n);
        s.rotations.reserve_exact(n);
        s.sh_rest = vec![0.0; n * k * 3];
        for (i, r) in records.chunks_exact(self.rec).enumerate() {
            s.positions.push([r[0], r[1], r[2]]);
            s.sh_dc.push([r[3], r[4], r[5]]);
            s.opacity_logits.push(r[6]);
            s.log_scales.push([r[7], r[8], r[9]]);
            s.rotations.push([r[10], r[11], r[12], r[13]]);
            // File: channel-major f_rest_{c*K+k}; Splats: [k][c].
            let rest = &mut s.sh_rest[i * k * 3..(i + 1) * k * 3];
            for c in 0..3 {
                for kk in 0..k {
                    rest[kk * 3 + c] = r[14 + c * k + kk];
                }
            }
        }
        s
    }
}

// ---------------------------------------------------------------------------------------------
// Bodies

fn read_binary(body: &[u8], h: &Header, l: &Layout) -> std::result::Result<Vec<f32>, String> {
    // Skip elements before the vertices (scalar-only, so fixed size).
    let mut offset = 0usize;
    for e in &h.elements[..h.vertex] {
        let size: usize = e.props.as_ref().unwrap().iter().map(|(_, t)| t.size()).sum();
        offset = e
            .count
            .checked_mul(size)
            .and_then(|b| b.checked_add(offset))
            .filter(|&o| o <= body.len())
            .ok_or_else(|| format!("truncated: element `{}` needs more bytes than the file has", e.name))?;
    }
    let n = h.elements[h.vertex].count;
    let avail = body.len() - offset;
    let need = n.checked_mul(l.stride).filter(|&b| b <= avail).ok_or_else(|| {
        format!(
            "truncated: header declares {n} vertices of {} bytes ({} bytes) but the body has {avail}",
            l.stride,
            n as u128 * l.stride as u128
        )
    })?;
    let rest_after = avail - need;
    let later = &h.elements[h.vertex + 1..];
    if later.is_empty() && rest_after != 0 {
        return Err(format!("header declares {n} vertices but the body has {rest_after} extra bytes"));
    }
    let big = h.format == Format::BinaryBe;
    let data = &body[offset..offset + need];
    let mut records = vec![0.0f32; n * l.rec];
    if l.stride == 0 {
        return Ok(records);
    }
    records.par_chunks_mut(l.rec * 1024).zip(data.par_chunks(l.stride * 1024)).for_each(|(recs, bytes)| {
        for (rec, v) in recs.chunks_exact_mut(l.rec).zip(bytes.chunks_exact(l.stride)) {
            let mut at = 0;
            for &(ty, slot) in &l.props {
                let sz = ty.size();
                if let Some(s) = slot {
                    rec[s] = ty.decode(&v[at..at + sz], big);
                }
                at += sz;
            }
        }
    });
    Ok(records)
}

fn read_ascii(body: &[u8], h: &Header, l: &Layout) -> std::result::Result<Vec<f32>, String> {
    let text = std::str::from_utf8(body).map_err(|_| "ascii PLY body is not valid text")?;
    let mut lines = text.lines().filter(|s| !s.trim().is_empty());
    for e in &h.elements[..h.vertex] {
        for _ in 0..e.count {
            lines.next().ok_or_else(|| format!("truncated: element `{}` has fewer lines than declared", e.name))?;
        }
    }
    let n = h.elements[h.vertex].count;
    // Each vertex needs at least one line of 2 bytes per property: bound the allocation.
    if n.saturating_mul(l.props.len().max(1) * 2) > body.len() + l.props.len() {
        return Err(format!("truncated: header declares {n} vertices but the body has only {} bytes", body.len()));
    }
    let mut records = vec![0.0f32; n * l.rec];
    for (i, rec) in records.chunks_exact_mut(l.rec.max(1)).enumerate() {
        let line = lines.next().ok_or_else(|| format!("truncated: header declares {n} vertices but the body has {i}"))?;
        let mut toks = line.split_whitespace();
        for &(ty, slot) in &l.props {
            let tok = toks.next().ok_or_else(|| format!("vertex {i}: fewer values than properties"))?;
            let v = ty.parse_ascii(tok).ok_or_else(|| format!("vertex {i}: cannot parse `{tok}`"))?;
            if let Some(s) = slot {
                rec[s] = v;
            }
        }
        if toks.next().is_some() {
            return Err(format!("vertex {i}: more values than properties"));
        }
    }
    if h.elements.len() == h.vertex + 1 && lines.next().is_some() {
        return Err(format!("header declares {n} vertices but the body has more lines"));
    }
    Ok(records)
}

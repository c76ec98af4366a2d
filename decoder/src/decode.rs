//! `.gsc` bytes to a scene: parameter sections, then every (group, chunk) stream in parallel.

use rayon::prelude::*;

use crate::bitstream::layout::{self, chunk_count, Group, CHUNK, INFO_KIND, MAX_POSITION_BITS};
use crate::bitstream::{self, ByteReader, Container, DecodeError, Header};
use crate::entropy::{ChannelTable, SymbolDecoder};
use crate::Splats;

/// What to decode.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DecodeOptions {
    /// SH bands above this degree are skipped (their streams are not even read).
    pub max_sh_degree: u8,
    /// Worker threads (at most 256); 0 = rayon's global pool. The result is identical for every value.
    pub threads: usize,
}

impl Default for DecodeOptions {
    fn default() -> Self {
        DecodeOptions { max_sh_degree: 3, threads: 0 }
    }
}

/// One section as listed by [`inspect`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SectionInfo {
    pub kind: u16,
    pub chunk: u16,
    pub optional: bool,
    pub bytes: usize,
    /// Group name, or `info` / `padding` / `unknown`.
    pub name: &'static str,
}

/// A checked overview of a file (for `gscodec info`).
#[derive(Debug, Clone, PartialEq)]
pub struct FileInfo {
    pub header: Header,
    pub file_bytes: usize,
    pub sections: Vec<SectionInfo>,
    /// Gaussians in the encoder's input before pruning (from the optional info section).
    pub input_gaussians: Option<u32>,
    /// SH degree of the encoder's input (from the optional info section).
    pub input_sh_degree: Option<u8>,
    /// Channels stored once as constants, as `group/channel`.
    pub constant_channels: Vec<String>,
}

/// Reads the fixed header only (magic, version, counts); no checksums beyond the header checks.
pub fn peek_header(bytes: &[u8]) -> Result<Header, DecodeError> {
    bitstream::parse_header(bytes).map(|(h, _)| h)
}

/// Parses and checks a file without decoding its streams.
pub fn inspect(bytes: &[u8]) -> Result<FileInfo, DecodeError> {
    let c = bitstream::parse(bytes)?;
    let params = read_all_params(&c, c.header.sh_degree)?;
    let mut info = FileInfo {
        header: c.header,
        file_bytes: bytes.len(),
        sections: Vec::new(),
        input_gaussians: None,
        input_sh_degree: None,
        constant_channels: Vec::new(),
    };
    for s in &c.sections {
        let name = Group::ALL.into_iter().find(|g| g.params_kind() == s.kind || g.data_kind() == s.kind).map(|g| g.name()).unwrap_or(
            match s.kind {
                INFO_KIND => "info",
                layout::PADDING_KIND => "padding",
                _ => "unknown",
            },
        );
        info.sections.push(SectionInfo {
            kind: s.kind,
            chunk: s.chunk,
            optional: s.flags & bitstream::SECTION_OPTIONAL != 0,
            bytes: s.data.len(),
            name,
        });
        if s.kind == INFO_KIND && s.data.len() == 5 {
            let mut r = ByteReader::new(s.data);
            info.input_gaussians = r.u32("info").ok();
            info.input_sh_degree = r.u8("info").ok();
        }
    }
    for (g, p) in &params {
        for (i, t) in p.tables.iter().enumerate() {
            if matches!(t, ChannelTable::Constant(_)) {
                info.constant_channels.push(format!("{}/{}", g.name(), i));
            }
        }
    }
    Ok(info)
}

/// Decodes a `.gsc` file. Never panics; any malformed input gives a [`DecodeError`].
/// The result is bit-identical across runs and thread counts.
pub fn decode(bytes: &[u8], options: &DecodeOptions) -> Result<Splats, DecodeError> {
    if options.threads > 0 {
        if let Ok(pool) = rayon::ThreadPoolBuilder::new().num_threads(options.threads.min(256)).build() {
            return pool.install(|| decode_in_pool(bytes, options));
        }
    }
    decode_in_pool(bytes, options)
}

/// Parsed parameter section of one group.
#[derive(Debug)]
struct GroupParams {
    /// Per channel dequantisation step (Position: unused).
    steps: Vec<f32>,
    tables: Vec<ChannelTable>,
    /// Position only: grid origin, step and bits per axis.
    grid: Option<([f32; 3], [f32; 3], u8)>,
}

fn read_params(g: Group, data: &[u8]) -> Result<GroupParams, DecodeError> {
    let mut r = ByteReader::new(data);
    let mut p = GroupParams { steps: Vec::new(), tables: Vec::new(), grid: None };
    if g == Group::Position {
        let origin = [r.f32("grid origin")?, r.f32("grid origin")?, r.f32("grid origin")?];
        let step = [r.f32("grid step")?, r.f32("grid step")?, r.f32("grid step")?];
        let bits = r.u8("grid bits")?;
        if bits > MAX_POSITION_BITS {
            return Err(DecodeError::Corrupt("position grid above 21 bits per axis"));
        }
        p.grid = Some((origin, step, bits));
        p.tables.push(ChannelTable::read(&mut r)?);
    } else {
        let n = r.u8("channel count")? as usize;
        if n != g.channels() {
            return Err(DecodeError::Corrupt("wrong channel count"));
        }
        for _ in 0..n {
            p.steps.push(r.f32("channel step")?);
            p.tables.push(ChannelTable::read(&mut r)?);
        }
    }
    if r.remaining() != 0 {
        return Err(DecodeError::Corrupt("trailing bytes in a parameter section"));
    }
    Ok(p)
}

fn read_all_params(c: &Container<'_>, degree: u8) -> Result<Vec<(Group, GroupParams)>, DecodeError> {
    if c.header.gaussians == 0 {
        return Ok(Vec::new());
    }
    Group::present(degree)
        .map(|g| {
            let s = c.section(g.params_kind(), 0).ok_or_else(|| DecodeError::MissingSection(format!("{} parameters", g.name())))?;
            Ok((g, read_params(g, s.data)?))
        })
        .collect()
}

/// Values per Gaussian a group decodes to.
fn width(g: Group) -> usize {
    match g {
        Group::Rotation => 4,
        Group::Position => 3,
        _ => g.channels(),
    }
}

fn finite(v: f32) -> Result<f32, DecodeError> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(DecodeError::Corrupt("dequantised value is not finite"))
    }
}

fn decode_chunk(g: Group, p: &GroupParams, data: &[u8], count: usize) -> Result<Vec<f32>, DecodeError> {
    let mut d = SymbolDecoder::new(data)?;
    let mut out = Vec::with_capacity(count * width(g));
    match g {
        Group::Position => {
            let (origin, step, bits) = p.grid.expect("position has a grid");
            let max_len = 3 * u32::from(bits);
            let limit = 1u64 << max_len; // bits <= 21, so at most 2^63
            let mut m: u64 = 0;
            for _ in 0..count {
                let len = d.value(&p.tables[0])?;
                if len < 0 || len as u32 > max_len {
                    return Err(DecodeError::Corrupt("position delta too long"));
                }
                let len = len as u32;
                let delta = if len <= 1 {
                    u64::from(len)
                } else {
                    let mut rest = 0u64;
                    let mut left = len - 1;
                    while left > 0 {
                        let take = left.min(32);
                        rest = (rest << take) | u64::from(d.raw_bits(take)?);
                        left -= take;
                    }
                    (1u64 << (len - 1)) | rest
                };
                m = m.checked_add(delta).filter(|&m| m < limit).ok_or(DecodeError::Corrupt("position outside the grid"))?;
                let q = layout::morton_decode(m, bits);
                for a in 0..3 {
                    out.push(finite(layout::dequantise_position(origin[a], step[a], q[a]))?);
                }
            }
        }
        Group::Rotation => {
            for _ in 0..count {
                let largest = d.value(&p.tables[0])?;
                if !(0..4).contains(&largest) {
                    return Err(DecodeError::Corrupt("rotation index outside 0..4"));
                }
                let mut c = [0.0f32; 3];
                for (j, cj) in c.iter_mut().enumerate() {
                    *cj = finite(d.value(&p.tables[j + 1])? as f32 * p.steps[j + 1])?;
                }
                out.extend_from_slice(&layout::rotation_from_smallest_three(largest as usize, c));
            }
        }
        _ => {
            for _ in 0..count {
                for (t, &s) in p.tables.iter().zip(&p.steps) {
                    out.push(finite(d.value(t)? as f32 * s)?);
                }
            }
        }
    }
    Ok(out)
}

fn decode_in_pool(bytes: &[u8], options: &DecodeOptions) -> Result<Splats, DecodeError> {
    let c = bitstream::parse(bytes)?;
    let n = c.header.gaussians as usize;
    let degree = c.header.sh_degree.min(options.max_sh_degree);
    let mut splats = Splats::new(degree);
    if n == 0 {
        return Ok(splats);
    }
    let params = read_all_params(&c, degree)?;
    let chunks = chunk_count(n);
    if chunks > usize::from(u16::MAX) + 1 {
        return Err(DecodeError::Limit("too many chunks"));
    }
    let jobs: Vec<(usize, usize)> = (0..params.len()).flat_map(|gi| (0..chunks).map(move |ch| (gi, ch))).collect();
    let results: Vec<Vec<f32>> = jobs
        .par_iter()
        .map(|&(gi, ch)| {
            let (g, p) = &params[gi];
            let data = c.section(g.data_kind(), ch as u16).map_or(&[][..], |s| s.data);
            let count = CHUNK.min(n - ch * CHUNK);
            decode_chunk(*g, p, data, count)
        })
        .collect::<Result<_, _>>()?;

    let k = splats.rest_coeffs();
    splats.sh_rest = vec![0.0; n * k * 3];
    for (&(gi, ch), vals) in jobs.iter().zip(&results) {
        let g = params[gi].0;
        let base = ch * CHUNK;
        match g {
            Group::Position => splats.positions.extend(vals.chunks_exact(3).map(|v| [v[0], v[1], v[2]])),
            Group::Scale => splats.log_scales.extend(vals.chunks_exact(3).map(|v| [v[0], v[1], v[2]])),
            Group::Rotation => splats.rotations.extend(vals.chunks_exact(4).map(|v| [v[0], v[1], v[2], v[3]])),
            Group::Opacity => splats.opacity_logits.extend_from_slice(vals),
            Group::ShDc => splats.sh_dc.extend(vals.chunks_exact(3).map(|v| [v[0], v[1], v[2]])),
            Group::Sh1 | Group::Sh2 | Group::Sh3 => {
                let b = g.sh_band() as usize;
                let first = b * b - 1; // first rest coefficient of band b
                let w = (2 * b + 1) * 3;
                for (i, v) in vals.chunks_exact(w).enumerate() {
                    let at = ((base + i) * k + first) * 3;
                    splats.sh_rest[at..at + w].copy_from_slice(v);
                }
            }
        }
    }
    Ok(splats)
}

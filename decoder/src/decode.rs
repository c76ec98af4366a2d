//! `.gsc` bytes to a scene: parameter sections, then the (group, chunk, channel range) jobs in parallel.

use std::ops::Range;
use std::sync::{Arc, Mutex};

use rayon::prelude::*;

use crate::bitstream::layout::{self, chunk_count, Group, CHUNK, INFO_KIND, MAX_POSITION_BITS};
use crate::bitstream::{self, ByteReader, Container, DecodeError, Header};
use crate::entropy::{context, ChannelTable, Lookup, SymbolDecoder, CONTEXTS};
use crate::Splats;

/// SH bands are decoded in jobs of about this many channels (a band has 9, 15 or 21).
const JOB_CHANNELS: usize = 8;

/// What to decode.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DecodeOptions {
    /// SH bands above this degree are skipped (their streams are not even read).
    pub max_sh_degree: u8,
    /// Worker threads (at most 256); 0 = rayon's global pool. The result is identical for every
    /// value. The pool for a thread count is built on first use and reused.
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
    /// Channels coded with one table per context, as `group/channel`.
    pub context_channels: Vec<String>,
}

/// Reads the fixed header only (magic, version, counts): the first 16 bytes are enough. No
/// checksums and no check of the Gaussian count against the file size ([`decode`] does both).
pub fn peek_header(bytes: &[u8]) -> Result<Header, DecodeError> {
    bitstream::parse_header_fields(bytes).map(|(h, _)| h)
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
        context_channels: Vec::new(),
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
            match t {
                ChannelTable::Constant(_) => info.constant_channels.push(format!("{}/{}", g.name(), i)),
                ChannelTable::Context { .. } => info.context_channels.push(format!("{}/{}", g.name(), i)),
                ChannelTable::Coded { .. } => {}
            }
        }
    }
    Ok(info)
}

/// Decodes a `.gsc` file. Never panics; any malformed input gives a [`DecodeError`].
/// The result is bit-identical across runs and thread counts.
pub fn decode(bytes: &[u8], options: &DecodeOptions) -> Result<Splats, DecodeError> {
    let c = bitstream::parse(bytes)?;
    in_pool(options, || decode_container(&c, c.header.sh_degree.min(options.max_sh_degree)))
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
        let lengths = ChannelTable::read(&mut r)?;
        if matches!(lengths, ChannelTable::Context { .. }) {
            return Err(DecodeError::Corrupt("context-coded position lengths"));
        }
        p.tables.push(lengths);
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
    let groups: Vec<Group> = Group::present(degree).collect();
    groups
        .into_par_iter()
        .map(|g| {
            let s = c.section(g.params_kind(), 0).ok_or_else(|| DecodeError::MissingSection(format!("{} parameters", g.name())))?;
            Ok((g, read_params(g, s.data)?))
        })
        .collect()
}

fn finite(v: f32) -> Result<f32, DecodeError> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(DecodeError::Corrupt("dequantised value is not finite"))
    }
}

/// One coded channel being decoded: its stream, tables and the previous value (the context).
struct Lane<'a> {
    col: usize,
    lo: i32,
    centre: i32,
    prev: i32,
    tables: [Lookup<'a>; CONTEXTS],
    scale: f32,
    d: SymbolDecoder<'a>,
}

impl Lane<'_> {
    /// The lane's next value into `row` (`CONTEXT`: pick the table by the previous value).
    #[inline(always)]
    fn decode<const CONTEXT: bool>(&mut self, row: &mut [f32]) {
        let table = if CONTEXT { self.tables[context(self.prev, self.centre)] } else { self.tables[0] };
        let v = self.d.coded_value(self.lo, table);
        self.prev = v;
        row[self.col] = v as f32 * self.scale;
    }
}

/// The next stream of a data section: `varint length`, then `length` bytes.
fn next_stream_bytes<'a>(r: &mut ByteReader<'a>) -> Result<&'a [u8], DecodeError> {
    let len = r.varint("stream length")? as usize;
    r.take(len, "stream")
}

/// Channels `channels` of a (non-position) group chunk, Gaussian-major (`count × channels.len()`),
/// each value `f32(v) · scale[channel]`. Each coded channel has its own stream; decoding them side
/// by side lets the independent coder states overlap in the CPU.
fn decode_channels(
    p: &GroupParams,
    r: &mut ByteReader<'_>,
    count: usize,
    scale: &[f32],
    channels: Range<usize>,
) -> Result<Vec<f32>, DecodeError> {
    // Every channel's stream is located (so the section's layout is checked), the wanted ones decoded.
    let mut streams = Vec::with_capacity(p.tables.len());
    for t in &p.tables {
        streams.push(match t {
            ChannelTable::Constant(_) => &[][..],
            ChannelTable::Coded { .. } | ChannelTable::Context { .. } => next_stream_bytes(r)?,
        });
    }
    let w = channels.len();
    let mut vals = vec![0f32; count * w];
    // Channels with one table and context-coded ones decode in separate lanes, so that the former
    // skip the context computation.
    let (mut plain, mut contextual) = (Vec::with_capacity(w), Vec::new());
    for (col, j) in channels.enumerate() {
        match p.tables[j].contexts() {
            None => {
                let v = if let ChannelTable::Constant(v) = p.tables[j] { v } else { 0 };
                vals.iter_mut().skip(col).step_by(w).for_each(|x| *x = v as f32 * scale[j]);
            }
            Some((lo, centre, tables)) => {
                let lanes = if matches!(p.tables[j], ChannelTable::Context { .. }) { &mut contextual } else { &mut plain };
                lanes.push(Lane {
                    col,
                    lo,
                    centre,
                    prev: centre,
                    tables: tables.map(|t| t.lookup_table()),
                    scale: scale[j],
                    d: SymbolDecoder::new(streams[j])?,
                });
            }
        }
    }
    for row in vals.chunks_exact_mut(w) {
        plain.iter_mut().for_each(|l| l.decode::<false>(row));
        contextual.iter_mut().for_each(|l| l.decode::<true>(row));
    }
    plain.into_iter().chain(contextual).try_for_each(|l| l.d.finish())?;
    if !vals.iter().fold(true, |ok, x| ok & x.is_finite()) {
        return Err(DecodeError::Corrupt("dequantised value is not finite"));
    }
    Ok(vals)
}

fn decode_positions(p: &GroupParams, r: &mut ByteReader<'_>, count: usize) -> Result<Vec<f32>, DecodeError> {
    let (origin, step, bits) = p.grid.expect("position has a grid");
    let mut d = SymbolDecoder::new(next_stream_bytes(r)?)?;
    let mut out = Vec::with_capacity(count * 3);
    let max_len = 3 * u32::from(bits);
    let limit = 1u64 << max_len; // bits <= 21, so at most 2^63
    let mut m: u64 = 0;
    for _ in 0..count {
        let len = d.value(&p.tables[0], 0);
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
                rest = (rest << take) | u64::from(d.raw_bits(take));
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
    d.finish()?;
    Ok(out)
}

/// Decodes channels `channels` of one data section (position and rotation: always all of them).
fn decode_chunk(g: Group, p: &GroupParams, data: &[u8], count: usize, channels: Range<usize>) -> Result<Vec<f32>, DecodeError> {
    let mut r = ByteReader::new(data);
    let out = match g {
        Group::Position => decode_positions(p, &mut r, count)?,
        Group::Rotation => {
            // The index channel is read unscaled: f32 holds 0..=3 (and any escaped value) exactly enough.
            let vals = decode_channels(p, &mut r, count, &[1.0, p.steps[1], p.steps[2], p.steps[3]], 0..4)?;
            let mut out = Vec::with_capacity(count * 4);
            for v in vals.chunks_exact(4) {
                if !matches!(v[0], 0.0 | 1.0 | 2.0 | 3.0) {
                    return Err(DecodeError::Corrupt("rotation index outside 0..4"));
                }
                out.extend_from_slice(&layout::rotation_from_smallest_three(v[0] as usize, [v[1], v[2], v[3]]));
            }
            out
        }
        _ => decode_channels(p, &mut r, count, &p.steps, channels)?,
    };
    if r.remaining() != 0 {
        return Err(DecodeError::Corrupt("trailing bytes in a data section"));
    }
    Ok(out)
}

/// Decodes a `.gsc` file from any reader (a file, a socket, a decompressor), reading it to the end.
///
/// ```
/// # let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../bitstream-spec/vectors/hand.gsc");
/// let file = std::fs::File::open(path).unwrap();
/// let scene = gscodec_decoder::decode_reader(file, &Default::default()).unwrap();
/// assert_eq!(scene.len(), 3);
/// ```
pub fn decode_reader(mut reader: impl std::io::Read, options: &DecodeOptions) -> Result<Splats, DecodeError> {
    let mut bytes = Vec::new();
    reader.read_to_end(&mut bytes).map_err(|e| DecodeError::Io(e.to_string()))?;
    decode(&bytes, options)
}

/// Decodes what has arrived of a file written in the recommended section order (SPEC §3, §7.1):
/// `Ok(None)` until the base (positions, scales, rotations, opacities, DC colours) is complete,
/// then the scene with the highest SH degree (up to `options.max_sh_degree`) whose sections have
/// all arrived. Call it again as more bytes come in; given the whole file it equals [`decode`].
/// Every section used is CRC-checked; corrupt data is an error, not `None`.
///
/// ```
/// # let bytes = std::fs::read(concat!(env!("CARGO_MANIFEST_DIR"), "/../bitstream-spec/vectors/tiny.gsc")).unwrap();
/// use gscodec_decoder::{decode_prefix, DecodeOptions};
/// let options = DecodeOptions::default();
/// let mut shown = None;
/// for arrived in (0..=bytes.len()).step_by(4096).chain([bytes.len()]) {
///     if let Some(scene) = decode_prefix(&bytes[..arrived], &options).unwrap() {
///         shown = Some(scene.sh_degree); // hand the scene to the renderer
///     }
/// }
/// assert_eq!(shown, Some(3));
/// ```
pub fn decode_prefix(bytes: &[u8], options: &DecodeOptions) -> Result<Option<Splats>, DecodeError> {
    if bitstream::MAGIC.starts_with(bytes) {
        return Ok(None); // not even the magic has arrived
    }
    let c = match bitstream::parse_prefix(bytes) {
        Ok(c) => c,
        Err(DecodeError::Truncated(_)) => return Ok(None),
        Err(e) => return Err(e),
    };
    let arrived = |g: Group| !c.pending.iter().any(|&(kind, _)| kind == g.params_kind() || kind == g.data_kind());
    if !Group::present(0).all(arrived) {
        return Ok(None);
    }
    let wanted = c.header.sh_degree.min(options.max_sh_degree);
    let degree = (1..=wanted).take_while(|&b| arrived(Group::for_band(b))).last().unwrap_or(0);
    in_pool(options, || decode_container(&c, degree)).map(Some)
}

/// Runs `f` on a pool of `options.threads` threads (0 = rayon's global pool). A pool is built
/// the first time a thread count is asked for and kept for later decodes.
fn in_pool<T: Send>(options: &DecodeOptions, f: impl FnOnce() -> T + Send) -> T {
    static POOLS: Mutex<Vec<(usize, Arc<rayon::ThreadPool>)>> = Mutex::new(Vec::new());
    let threads = options.threads.min(256);
    if threads == 0 {
        return f();
    }
    let pool = {
        let mut pools = POOLS.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
        match pools.iter().find(|(t, _)| *t == threads) {
            Some((_, p)) => Some(p.clone()),
            None => rayon::ThreadPoolBuilder::new().num_threads(threads).build().ok().map(|p| {
                let p = Arc::new(p);
                pools.push((threads, p.clone()));
                p
            }),
        }
    };
    match pool {
        Some(p) => p.install(f),
        None => f(), // no threads could be started: decode on the global pool
    }
}

fn decode_container(c: &Container<'_>, degree: u8) -> Result<Splats, DecodeError> {
    let n = c.header.gaussians as usize;
    let mut splats = Splats::new(degree);
    if n == 0 {
        return Ok(splats);
    }
    let params = read_all_params(c, degree)?;
    let chunks = chunk_count(n);
    if chunks > usize::from(u16::MAX) + 1 {
        return Err(DecodeError::Limit("too many chunks"));
    }
    // One job per (group, chunk); SH bands are split further into channel ranges of about
    // JOB_CHANNELS so that the work balances over the threads even for a one-chunk scene.
    let mut jobs: Vec<(usize, usize, Range<usize>)> = Vec::new();
    for (gi, (g, _)) in params.iter().enumerate() {
        let c = g.channels();
        let pieces = if g.sh_band() > 0 { c.div_ceil(JOB_CHANNELS) } else { 1 };
        for ch in 0..chunks {
            jobs.extend((0..pieces).map(|i| (gi, ch, i * c / pieces..(i + 1) * c / pieces)));
        }
    }
    let results: Vec<Vec<f32>> = jobs
        .par_iter()
        .map(|(gi, ch, channels)| {
            let (g, p) = &params[*gi];
            let data = c.section(g.data_kind(), *ch as u16).map_or(&[][..], |s| s.data);
            let count = CHUNK.min(n - ch * CHUNK);
            decode_chunk(*g, p, data, count, channels.clone())
        })
        .collect::<Result<_, _>>()?;

    let row = splats.rest_coeffs() * 3;
    // The jobs' results, in (group, chunk) order, as the scene's arrays: the base groups are
    // concatenated, the SH jobs' columns scattered into the rest rows, all in parallel.
    let group_values = |group: Group| -> Vec<&[f32]> {
        jobs.iter().zip(&results).filter(|((gi, ..), _)| params[*gi].0 == group).map(|(_, v)| v.as_slice()).collect()
    };
    let concat = |group: Group| -> Vec<f32> { group_values(group).concat() };
    let triples = |group: Group| -> Vec<[f32; 3]> { concat(group).chunks_exact(3).map(|v| [v[0], v[1], v[2]]).collect() };
    let scatter_sh = || {
        let mut rest = vec![0.0f32; n * row];
        // SH channel j of band b is rest value (b²−1)·3 + j of its Gaussian.
        let mut pieces: Vec<Vec<(usize, &[f32])>> = vec![Vec::new(); chunks];
        for ((gi, ch, channels), vals) in jobs.iter().zip(&results) {
            let b = params[*gi].0.sh_band() as usize;
            if b > 0 {
                pieces[*ch].push(((b * b - 1) * 3 + channels.start, vals));
            }
        }
        rest.par_chunks_mut(CHUNK * row.max(1)).zip(&pieces).for_each(|(rows, pieces)| {
            let count = rows.len() / row.max(1);
            rows.par_chunks_mut(row.max(1)).enumerate().with_min_len(1024).for_each(|(i, dst)| {
                for &(first, vals) in pieces {
                    let w = vals.len() / count;
                    dst[first..first + w].copy_from_slice(&vals[i * w..(i + 1) * w]);
                }
            });
        });
        rest
    };
    let ((positions, log_scales), ((rotations, opacity_logits), (sh_dc, sh_rest))) = rayon::join(
        || rayon::join(|| triples(Group::Position), || triples(Group::Scale)),
        || {
            rayon::join(
                || {
                    rayon::join(
                        || concat(Group::Rotation).chunks_exact(4).map(|v| [v[0], v[1], v[2], v[3]]).collect(),
                        || concat(Group::Opacity),
                    )
                },
                || rayon::join(|| triples(Group::ShDc), scatter_sh),
            )
        },
    );
    splats.positions = positions;
    splats.log_scales = log_scales;
    splats.rotations = rotations;
    splats.opacity_logits = opacity_logits;
    splats.sh_dc = sh_dc;
    splats.sh_rest = sh_rest;
    Ok(splats)
}

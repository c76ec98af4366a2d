//! `.gsc` bytes to a scene: parameter sections, then the (group, chunk, channel range) jobs in parallel.

use std::ops::Range;
use std::sync::{Arc, Mutex};

use rayon::prelude::*;

use crate::bitstream::assemble::{assemble, Piece};
use crate::bitstream::layout::{self, chunk_count, Group, CHUNK, INFO_KIND};
use crate::bitstream::params::read_all_params;
use crate::bitstream::stream::decode_data_section;
use crate::bitstream::tables::ChannelTable;
use crate::bitstream::{self, header, info, Container, Header};
use crate::error::{self, DecodeError, FormatErrorKind, Limit};
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
    header::read_header(bytes).map(|(h, _)| h)
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
        if let Some(i) = (s.kind == INFO_KIND).then(|| info::read_info(s.data)).flatten() {
            info.input_gaussians = Some(i.input_gaussians);
            info.input_sh_degree = Some(i.input_sh_degree);
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
    reader.read_to_end(&mut bytes)?;
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
        Err(e) if e.format_error().is_some_and(|f| f.kind() == FormatErrorKind::Truncated) => return Ok(None),
        Err(e) => return Err(e),
    };
    let arrived = |g: Group| !c.pending.iter().any(|id| id.kind == g.params_kind() || id.kind == g.data_kind());
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
        return Err(error::limit(Limit::Gaussians, n as u64, (usize::from(u16::MAX) + 1) as u64 * CHUNK as u64, false));
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
            let count = CHUNK.min(n - ch * CHUNK);
            decode_data_section(*g, p, &mut c.reader(g.data_kind(), *ch as u16), count, channels.clone())
        })
        .collect::<Result<_, _>>()?;
    let pieces: Vec<Piece> = jobs
        .iter()
        .zip(&results)
        .map(|((gi, ch, channels), values)| {
            let group = params[*gi].0;
            let columns = match group {
                Group::Position => 0..3,
                Group::Rotation => 0..4,
                _ => channels.clone(),
            };
            Piece { group, first: ch * CHUNK, columns, values }
        })
        .collect();
    assemble(n, degree, &pieces, &mut splats);
    Ok(splats)
}

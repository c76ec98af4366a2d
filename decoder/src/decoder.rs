//! The decoder's front door: [`Decoder`] (configure) → [`Reader`] (header and section table
//! read, limits checked) → a [`Splats`] scene, plus one-call conveniences for bytes in memory.

use std::io::Read;

use crate::bitstream::anchors::{read_anchors, ANCHORS_KIND};
use crate::bitstream::header::{self, check_allocation_bound, Header, HEADER_BYTES};
use crate::bitstream::info::{read_info, EncoderInfo};
use crate::bitstream::layout::{Group, CODEBOOK_KIND, INFO_KIND, LEVELS_KIND};
use crate::bitstream::levels::Layout;
use crate::bitstream::params::read_all_params;
use crate::bitstream::sections::{self, read_table, table_bytes, Table};
use crate::bitstream::tables::ChannelTable;
use crate::bitstream::{self, SECTION_OPTIONAL};
use crate::decode::{decode_chunks, decode_container, in_pool};
use crate::error::{self, DecodeError, FormatErrorKind, Limit, Place, SectionId};
use crate::math::sh_rest_coeffs;
use crate::Splats;

/// Resource limits of a decode, checked right after the header and section table are read,
/// before anything they bound is allocated or read.
///
/// The defaults take any scene of up to 16.7 M Gaussians whose decode needs at most 4 GiB.
///
/// # Examples
///
/// A tiny byte budget refuses a file before its payloads are read:
///
/// ```
/// use gscodec_decoder::{Decoder, DecodeError, Limits};
/// # let bytes = std::fs::read(concat!(env!("CARGO_MANIFEST_DIR"), "/../bitstream-spec/vectors/tiny.gsc")).unwrap();
/// let limits = Limits { max_bytes: 1000, ..Limits::default() };
/// let err = Decoder::with_limits(&bytes[..], limits).read_info().unwrap_err();
/// assert!(matches!(err, DecodeError::LimitsExceeded(_)));
/// assert_eq!(err.class(), "limits");
/// ```
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Limits {
    /// Most Gaussians a file may hold (default 2^24; the format's own bound is 2^26).
    pub max_gaussians: u32,
    /// One byte budget: the bytes a decode holds at its peak — the file, the decoded values and
    /// the scene ([`Reader::required_bytes`]) — may not exceed it (default 4 GiB).
    pub max_bytes: u64,
    /// SH bands above this degree are not read, allocated or returned (default 3: all). Unlike
    /// the other limits it trims instead of failing: a scene of lower degree is still the scene.
    pub max_sh_degree: u8,
}

impl Default for Limits {
    fn default() -> Self {
        Limits { max_gaussians: 1 << 24, max_bytes: 4 << 30, max_sh_degree: 3 }
    }
}

impl Limits {
    /// No limits beyond the format's own (SPEC §9).
    pub fn none() -> Limits {
        Limits { max_gaussians: u32::MAX, max_bytes: u64::MAX, max_sh_degree: 3 }
    }
}

/// One section as listed in a file's table.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SectionInfo {
    /// Section kind (SPEC §3).
    pub kind: u16,
    /// Chunk index.
    pub chunk: u16,
    /// Whether the OPTIONAL flag is set.
    pub optional: bool,
    /// Payload bytes.
    pub bytes: usize,
    /// Group name, or `levels` / `sh_bandB codebook` / `info` / `padding` / `unknown`.
    pub name: &'static str,
}

impl SectionInfo {
    fn new(id: SectionId, flags: u32, bytes: usize) -> SectionInfo {
        let name = Group::of_kind(id.kind).map(|g| g.name()).unwrap_or(match id.kind {
            INFO_KIND => "info",
            bitstream::layout::PADDING_KIND => "padding",
            LEVELS_KIND => "levels",
            ANCHORS_KIND => "anchors",
            CODEBOOK_KIND => match id.chunk {
                1 => "sh_band1 codebook",
                2 => "sh_band2 codebook",
                3 => "sh_band3 codebook",
                _ => "unknown",
            },
            _ => "unknown",
        });
        SectionInfo { kind: id.kind, chunk: id.chunk, optional: flags & SECTION_OPTIONAL != 0, bytes, name }
    }
}

/// What the header and section table say about a file, available before its payloads are read.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Info {
    /// The fixed header: version, Gaussian count, SH degree.
    pub header: Header,
    /// Length of the whole file as the table declares it.
    pub file_bytes: u64,
    /// The sections in file order.
    pub sections: Vec<SectionInfo>,
}

/// A checked overview of a whole file without decoding its streams ([`inspect`]; `gscodec info`).
#[derive(Debug, Clone, PartialEq)]
pub struct FileInfo {
    /// Header and sections.
    pub info: Info,
    /// The optional info section: the encoder's input before pruning and SH truncation.
    pub encoder: Option<EncoderInfo>,
    /// Gaussians of each importance level, in file order (SPEC §3.1): several in a progressive
    /// 4.0 file, one (all N) in a 3.0 file, none when N = 0.
    pub levels: Vec<usize>,
    /// Gaussians of each chunk, in file order.
    pub chunks: Vec<usize>,
    /// Channels stored once as constants, as `group/channel`.
    pub constant_channels: Vec<String>,
    /// Channels coded with one table per context, as `group/channel`.
    pub context_channels: Vec<String>,
    /// Channels coded with neighbour contexts (SPEC §4.3, format 8.0), as `group/channel`.
    pub neighbour_channels: Vec<String>,
    /// SH bands coded by vector quantisation (SPEC §3.2): (band, codebook rows K).
    pub codebooks: Vec<(u8, usize)>,
    /// SH bands that share the row index of the band below (SPEC §3.2, format 9.0).
    pub shared_index: Vec<u8>,
    /// A 6.0 file's parameters per level (SPEC §4): per level, its scale step over level 0's
    /// (importance classes: how much coarser the level is coded). Empty before 6.0.
    pub level_step_factors: Vec<f32>,
    /// An anchor-profile file's model (SPEC §12); `None` for the explicit profile.
    pub anchors: Option<AnchorSummary>,
}

/// What an anchor-profile file (SPEC §12) holds besides its Gaussians.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct AnchorSummary {
    /// Anchors A.
    pub anchors: usize,
    /// Features per anchor F.
    pub features: usize,
    /// Anchor cells are 2^shift grid cells wide per axis.
    pub shift: u8,
    /// The MLP's layer widths, input first.
    pub widths: Vec<usize>,
}

/// Configures a decode of a `.gsc` file from any [`Read`] (a file, a socket, a decompressor, a
/// byte slice); [`read_info`](Decoder::read_info) then reads the header.
///
/// # Examples
///
/// ```
/// use gscodec_decoder::{Decoder, Limits};
/// # let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../bitstream-spec/vectors/tiny.gsc");
/// let file = std::fs::File::open(path)?;
/// let mut decoder = Decoder::new(std::io::BufReader::new(file));
/// decoder.set_limits(Limits { max_sh_degree: 1, ..Limits::default() });
/// let reader = decoder.read_info()?;
/// assert_eq!(reader.info().header.sh_degree, 3); // stored
/// assert_eq!(reader.output_sh_degree(), 1); // returned
/// let scene = reader.decode()?;
/// assert_eq!((scene.len(), scene.sh_degree), (1000, 1));
/// # Ok::<(), gscodec_decoder::DecodeError>(())
/// ```
#[derive(Debug)]
pub struct Decoder<R> {
    reader: R,
    limits: Limits,
    threads: usize,
}

impl<R: Read> Decoder<R> {
    /// A decoder with the default [`Limits`].
    pub fn new(reader: R) -> Self {
        Decoder { reader, limits: Limits::default(), threads: 0 }
    }

    /// A decoder with `limits`.
    pub fn with_limits(reader: R, limits: Limits) -> Self {
        Decoder { reader, limits, threads: 0 }
    }

    /// Replaces the limits.
    pub fn set_limits(&mut self, limits: Limits) -> &mut Self {
        self.limits = limits;
        self
    }

    /// Worker threads of the decode (at most 256); 0 (the default) = rayon's global pool, 1 = the
    /// calling thread alone (no pool, nothing handed to another thread). The result is identical
    /// for every value; the pool for a count of two or more is built on first use and kept.
    pub fn set_threads(&mut self, threads: usize) -> &mut Self {
        self.threads = threads;
        self
    }

    /// Reads the fixed header and the section table (16 + 16·S + 4 bytes, nothing more), checks
    /// the header CRC, the format's bounds and the limits.
    ///
    /// # Errors
    /// [`DecodeError::Io`] if the reader fails; `Format` (bad magic, truncation),
    /// `Unsupported` (another major version), `Checksum` (header CRC) or `LimitsExceeded`.
    pub fn read_info(mut self) -> Result<Reader<R>, DecodeError> {
        let mut bytes = vec![0u8; HEADER_BYTES];
        let got = read_up_to(&mut self.reader, &mut bytes)?;
        bytes.truncate(got);
        let (_, count) = header::read_header(&bytes)?;
        let end = table_bytes(count);
        bytes.resize(end, 0);
        let got = read_up_to(&mut self.reader, &mut bytes[HEADER_BYTES..])?;
        bytes.truncate(HEADER_BYTES + got);
        let table = read_table(&bytes)?;
        check_allocation_bound(&table.header, table.file_bytes())?;
        let degree = check_limits(&table, &self.limits)?;
        Ok(Reader { reader: self.reader, bytes, table, degree, threads: self.threads })
    }
}

/// A file whose header and section table have been read and checked against the limits; it
/// decodes the rest. Consumed by decoding, so options cannot change mid-decode.
#[derive(Debug)]
pub struct Reader<R> {
    reader: R,
    /// Header and section table, then (while decoding) the payloads.
    bytes: Vec<u8>,
    table: Table,
    degree: u8,
    threads: usize,
}

impl<R: Read> Reader<R> {
    /// Header and sections as the table lists them.
    pub fn info(&self) -> Info {
        let sections = self.table.entries.iter().map(|e| SectionInfo::new(e.id, e.flags, e.length as usize)).collect();
        Info { header: self.table.header, file_bytes: self.table.file_bytes(), sections }
    }

    /// Number of Gaussians the scene will have.
    pub fn gaussians(&self) -> usize {
        self.table.header.gaussians as usize
    }

    /// SH degree of the scene that will be returned: the stored one, at most
    /// [`Limits::max_sh_degree`].
    pub fn output_sh_degree(&self) -> u8 {
        self.degree
    }

    /// The bytes this decode holds at its peak, checked against [`Limits::max_bytes`]: the file,
    /// the decoded values and the scene.
    pub fn required_bytes(&self) -> u64 {
        required_bytes(&self.table, self.degree)
    }

    /// Reads the payloads and decodes them into `out` (the scene is decoded into new arrays that
    /// replace `out`'s). On error `out` is left as it was.
    ///
    /// # Errors
    /// [`DecodeError::Io`] if the reader fails; otherwise what the bytes break (see
    /// [`DecodeError`]): truncation, a section CRC, trailing bytes, corrupt content.
    pub fn decode_into(mut self, out: &mut Splats) -> Result<(), DecodeError> {
        let start = self.bytes.len();
        let body = self.table.file_bytes() - start as u64; // ≤ max_bytes, checked
                                                           // The buffer grows with what arrives, not with what the table claims: a short input
                                                           // that declares a huge section costs what it holds.
        self.bytes.reserve(body.min(16 << 20) as usize);
        (&mut self.reader).take(body).read_to_end(&mut self.bytes)?;
        if self.bytes.len() as u64 - start as u64 == body && read_up_to(&mut self.reader, &mut [0u8; 1])? != 0 {
            return Err(Place { section: None, offset: self.bytes.len() as u64 }.error(FormatErrorKind::TrailingData, "trailing data"));
        }
        let c = sections::parse(&self.bytes)?;
        in_pool(self.threads, || decode_container(&c, self.degree, out))
    }

    /// Reads the payloads and decodes them into a new scene.
    ///
    /// # Errors
    /// As [`decode_into`](Reader::decode_into).
    pub fn decode(self) -> Result<Splats, DecodeError> {
        let mut out = Splats::new(self.degree);
        self.decode_into(&mut out)?;
        Ok(out)
    }
}

/// Reads until `buf` is full or the reader ends; the number of bytes read.
fn read_up_to(r: &mut impl Read, buf: &mut [u8]) -> Result<usize, DecodeError> {
    let mut got = 0;
    while got < buf.len() {
        match r.read(&mut buf[got..]) {
            Ok(0) => break,
            Ok(n) => got += n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(DecodeError::Io(e)),
        }
    }
    Ok(got)
}

/// Bytes of a decoded scene of `n` Gaussians and SH degree `degree`.
fn scene_bytes(n: u64, degree: u8) -> u64 {
    n * (3 + 3 + 4 + 1 + 3 + 3 * sh_rest_coeffs(degree) as u64) * 4
}

fn required_bytes(table: &Table, degree: u8) -> u64 {
    table.file_bytes() + 2 * scene_bytes(table.header.gaussians.into(), degree)
}

/// Checks the caller's limits against a file's table; the SH degree to decode.
fn check_limits(table: &Table, limits: &Limits) -> Result<u8, DecodeError> {
    let n = table.header.gaussians;
    if n > limits.max_gaussians {
        return Err(error::limit(Limit::Gaussians, n.into(), limits.max_gaussians.into(), true));
    }
    let degree = table.header.sh_degree.min(limits.max_sh_degree);
    let need = required_bytes(table, degree);
    if need > limits.max_bytes {
        return Err(error::limit(Limit::Bytes, need, limits.max_bytes, true));
    }
    Ok(degree)
}

/// Decodes a whole `.gsc` file in memory with the default [`Limits`] (the same checks and result
/// as [`Decoder`], without copying the bytes). Never panics; the result is bit-identical across
/// runs and thread counts.
///
/// # Errors
/// Any [`DecodeError`] but `Io`.
///
/// # Examples
///
/// ```
/// # let bytes = std::fs::read(concat!(env!("CARGO_MANIFEST_DIR"), "/../bitstream-spec/vectors/hand.gsc")).unwrap();
/// let scene = gscodec_decoder::decode(&bytes)?;
/// assert_eq!(scene.len(), 3);
/// assert_eq!(gscodec_decoder::decode(b"PK\x03\x04").unwrap_err().class(), "format");
/// # Ok::<(), gscodec_decoder::DecodeError>(())
/// ```
pub fn decode(bytes: &[u8]) -> Result<Splats, DecodeError> {
    decode_with(bytes, &Limits::default())
}

/// As [`decode`], with `limits`.
///
/// # Errors
/// Any [`DecodeError`] but `Io`.
pub fn decode_with(bytes: &[u8], limits: &Limits) -> Result<Splats, DecodeError> {
    // The checks of Decoder::read_info, in its order, then those of Reader::decode.
    let table = read_table(bytes)?;
    check_allocation_bound(&table.header, table.file_bytes())?;
    let degree = check_limits(&table, limits)?;
    let c = sections::parse(bytes)?;
    let mut out = Splats::new(degree);
    decode_container(&c, degree, &mut out)?;
    Ok(out)
}

/// Reads the fixed header only (magic, version, counts): the first 16 bytes are enough. No
/// checksums and no check of the Gaussian count against the file size ([`decode`] does both).
///
/// # Errors
/// `Format` (bad magic, fewer than 16 bytes), `Unsupported` (another major version) or
/// `LimitsExceeded` (the format's bounds).
pub fn peek_header(bytes: &[u8]) -> Result<Header, DecodeError> {
    header::read_header(bytes).map(|(h, _)| h)
}

/// Parses and checks a whole file (every CRC, the levels and every parameter section) without
/// decoding its streams.
///
/// # Errors
/// Any [`DecodeError`] but `Io` and `LimitsExceeded` from caller limits.
pub fn inspect(bytes: &[u8]) -> Result<FileInfo, DecodeError> {
    let c = sections::parse(bytes)?;
    if c.header.is_anchor() {
        return inspect_anchors(&c, bytes.len() as u64);
    }
    let layout = c.layout()?;
    let params = read_all_params(&c, c.header.sh_degree, layout.level_chunks.len())?;
    let mut info = FileInfo {
        info: Info { header: c.header, file_bytes: bytes.len() as u64, sections: Vec::new() },
        encoder: None,
        levels: layout.level_sizes(),
        chunks: layout.chunk_sizes.iter().map(|&k| k as usize).collect(),
        constant_channels: Vec::new(),
        context_channels: Vec::new(),
        neighbour_channels: Vec::new(),
        codebooks: Vec::new(),
        shared_index: Vec::new(),
        level_step_factors: Vec::new(),
        anchors: None,
    };
    for s in &c.sections {
        info.info.sections.push(SectionInfo::new(s.id(), s.flags, s.data.len()));
        if s.kind == INFO_KIND {
            info.encoder = read_info(s.data);
        }
    }
    if c.header.has_level_params() {
        let scale =
            |set: &[(Group, crate::bitstream::params::GroupParams)]| set.iter().find(|g| g.0 == Group::Scale).map_or(1.0, |g| g.1.steps[0]);
        info.level_step_factors = params.sets.iter().map(|set| scale(set) / scale(&params.sets[0])).collect();
    }
    for (l, set) in params.sets.iter().enumerate() {
        for (g, p) in set {
            if let Some(cb) = p.codebook.as_ref().filter(|_| l == 0) {
                info.codebooks.push((g.sh_band(), cb.rows));
                if p.shares_index() {
                    info.shared_index.push(g.sh_band());
                }
            }
            // Channel names carry the level of a 6.0 file's later parameter sets.
            let name = |i: usize| if l == 0 { format!("{}/{}", g.name(), i) } else { format!("{}/{}@{}", g.name(), i, l) };
            for (i, t) in p.tables.iter().enumerate() {
                match t {
                    ChannelTable::Constant(_) => info.constant_channels.push(name(i)),
                    ChannelTable::Context { .. } => info.context_channels.push(name(i)),
                    ChannelTable::Neighbour(_) => info.neighbour_channels.push(name(i)),
                    ChannelTable::Coded { .. } => {}
                }
            }
        }
    }
    Ok(info)
}

/// [`inspect`] of an anchor-profile file: its sections and its anchor section's model (the
/// anchors' streams are decoded to check them).
fn inspect_anchors(c: &sections::Container<'_>, file_bytes: u64) -> Result<FileInfo, DecodeError> {
    let n = c.header.gaussians as usize;
    let anchors = if n == 0 {
        None
    } else {
        if c.section(ANCHORS_KIND, 0).is_none() {
            return Err(c.missing(SectionId { kind: ANCHORS_KIND, chunk: 0 }, "anchors"));
        }
        let set = read_anchors(&mut c.reader(ANCHORS_KIND, 0), n, c.header.sh_degree)?;
        let widths = std::iter::once(set.mlp.layers[0].inputs).chain(set.mlp.layers.iter().map(|l| l.outputs)).collect();
        Some(AnchorSummary { anchors: set.anchors(), features: set.features, shift: set.shift, widths })
    };
    let sections = c.sections.iter().map(|s| SectionInfo::new(s.id(), s.flags, s.data.len())).collect();
    let encoder = c.sections.iter().find(|s| s.kind == INFO_KIND).and_then(|s| read_info(s.data));
    Ok(FileInfo {
        info: Info { header: c.header, file_bytes, sections },
        encoder,
        levels: if n == 0 { Vec::new() } else { vec![n] },
        chunks: Vec::new(),
        constant_channels: Vec::new(),
        context_channels: Vec::new(),
        neighbour_channels: Vec::new(),
        codebooks: Vec::new(),
        shared_index: Vec::new(),
        level_step_factors: Vec::new(),
        anchors,
    })
}

/// Decodes what has arrived of a file written in the recommended section order (SPEC §3, §7.1):
/// `Ok(None)` until the first importance level is complete (levels, parameters and the base —
/// positions, scales, rotations, opacities, DC colours — of its chunks), then the Gaussians of
/// every complete level (a prefix of the file's Gaussians, in file order), with the highest SH
/// degree (up to `limits.max_sh_degree`) whose sections for those Gaussians have all arrived. A
/// 3.0 file, or a 4.0 file of one level, has one level: every Gaussian. Call it again as more
/// bytes come in; given the whole file it equals [`decode`]. Every section used is CRC-checked;
/// corrupt data is an error, not `None`.
///
/// # Errors
/// Any [`DecodeError`] but `Io`; a file that is merely incomplete is `Ok(None)`.
///
/// # Examples
///
/// ```
/// # let bytes = std::fs::read(concat!(env!("CARGO_MANIFEST_DIR"), "/../bitstream-spec/vectors/levels.gsc")).unwrap();
/// use gscodec_decoder::{decode_prefix, Limits};
/// let mut shown = Vec::new();
/// for arrived in (0..=bytes.len()).step_by(1024).chain([bytes.len()]) {
///     if let Some(scene) = decode_prefix(&bytes[..arrived], &Limits::default()).unwrap() {
///         shown.push((scene.len(), scene.sh_degree)); // hand the scene to the renderer
///     }
/// }
/// assert!(shown[0].0 < 100); // the first level: the most important ~1/16
/// assert_eq!(shown.last(), Some(&(1000, 3)));
/// ```
pub fn decode_prefix(bytes: &[u8], limits: &Limits) -> Result<Option<Splats>, DecodeError> {
    let Some(p) = arrived_prefix(bytes, limits)? else { return Ok(None) };
    let mut out = Splats::new(p.degree);
    if p.container.header.is_anchor() {
        decode_container(&p.container, p.degree, &mut out)?;
    } else {
        decode_chunks(&p.container, &p.layout, p.chunks, p.degree, &mut out)?;
    }
    Ok(Some(out))
}

/// What [`decode_prefix`] would return for these bytes, without decoding the streams: `None`,
/// or the number of Gaussians (whole levels) and the SH degree. Costs the parse and the CRCs of
/// the sections that have arrived.
///
/// # Errors
/// As [`decode_prefix`].
pub fn prefix_extent(bytes: &[u8], limits: &Limits) -> Result<Option<(usize, u8)>, DecodeError> {
    Ok(arrived_prefix(bytes, limits)?.map(|p| (p.layout.chunk_ranges()[..p.chunks].last().map_or(0, |r| r.end), p.degree)))
}

/// The part of a file [`decode_prefix`] decodes: its first `chunks` chunks (whole levels) with SH
/// up to `degree`.
struct Prefix<'a> {
    container: sections::Container<'a>,
    layout: Layout,
    chunks: usize,
    degree: u8,
}

/// The rule of [`decode_prefix`]: the levels whose base sections have all arrived, and the SH
/// bands whose sections for them have.
fn arrived_prefix<'a>(bytes: &'a [u8], limits: &Limits) -> Result<Option<Prefix<'a>>, DecodeError> {
    if bitstream::MAGIC.starts_with(bytes) {
        return Ok(None); // not even the magic has arrived
    }
    let c = match sections::parse_prefix(bytes) {
        Ok(c) => c,
        Err(e) if e.format_error().is_some_and(|f| f.kind() == FormatErrorKind::Truncated) => return Ok(None),
        Err(e) => return Err(e),
    };
    let table = read_table(bytes)?;
    let wanted = check_limits(&table, limits)?;
    if c.header.is_anchor() {
        // An anchor-profile file has one level: all of it (SPEC §12).
        let layout = Layout::uniform(c.header.gaussians as usize);
        let chunks = layout.chunks();
        return Ok(c.pending.is_empty().then_some(Prefix { container: c, layout, chunks, degree: wanted }));
    }
    let pending: std::collections::HashSet<SectionId> = c.pending.iter().copied().collect();
    let pending = |kind: u16, chunk: usize| u16::try_from(chunk).is_ok_and(|chunk| pending.contains(&SectionId { kind, chunk }));
    if pending(LEVELS_KIND, 0) || !Group::present(0).all(|g| !pending(g.params_kind(), 0)) {
        return Ok(None);
    }
    let layout = c.layout()?;
    // A level needs its parameter sections (SPEC §4: chunk 0 before 6.0), and an SH band's
    // codebook (SPEC §3.2) comes with its parameter section.
    let arrived = |g: Group, level: usize, chunks: std::ops::Range<usize>| {
        !pending(g.params_kind(), c.header.params_chunk(level))
            && !pending(CODEBOOK_KIND, usize::from(g.sh_band()))
            && chunks.into_iter().all(|ch| !pending(g.data_kind(), ch))
    };
    let levels = layout.level_ranges();
    let complete = levels.iter().enumerate().take_while(|(l, r)| Group::present(0).all(|g| arrived(g, *l, (*r).clone()))).count();
    if complete == 0 && !levels.is_empty() {
        return Ok(None);
    }
    let chunks = levels[..complete].last().map_or(0, |r| r.end);
    let degree = (1..=wanted)
        .take_while(|&b| levels[..complete].iter().enumerate().all(|(l, r)| arrived(Group::for_band(b), l, r.clone())))
        .last()
        .unwrap_or(0);
    Ok(Some(Prefix { container: c, layout, chunks, degree }))
}

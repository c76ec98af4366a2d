//! The `.gsc` container: header, section table, per-section CRC32 — the one definition of the
//! format, used by the decoder to read and by the encoder to write (`bitstream-spec/SPEC.md`).
//!
//! Layout (all integers little-endian):
//! ```text
//! 0   magic  8A 47 53 43 ("\x8AGSC")
//! 4   u8 version major, u8 version minor
//! 6   u16 section count S
//! 8   u32 Gaussian count N
//! 12  u8 SH degree, u8 flags (0), u16 reserved (0)
//! 16  S × { u16 kind, u16 chunk, u32 flags, u32 length, u32 crc32 }
//! 16+16S  u32 CRC32 of bytes 0 .. 16+16S
//! then the S section payloads, back to back, in table order; nothing after the last one.
//! ```

pub mod bytes;
pub mod layout;

pub use bytes::{ByteReader, ByteWriter};

/// First four bytes of every `.gsc` file.
pub const MAGIC: [u8; 4] = [0x8A, b'G', b'S', b'C'];
/// Format version written by this crate. A reader accepts any minor of its major.
pub const VERSION_MAJOR: u8 = 3;
pub const VERSION_MINOR: u8 = 0;
/// Section flag: a reader that does not know this section kind may skip it.
pub const SECTION_OPTIONAL: u32 = 1;
/// Hard limits (see SPEC §9).
pub const MAX_SECTIONS: usize = 4096;
pub const MAX_GAUSSIANS: u32 = 1 << 26;
/// A file may hold at most this many Gaussians per byte of file (1 bit per Gaussian).
pub const MAX_GAUSSIANS_PER_BYTE: u64 = 8;
const FIXED_HEADER: usize = 16;
const TABLE_ENTRY: usize = 16;

/// Why a byte string is not a valid `.gsc` file. Decoding never panics; it returns one of these.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum DecodeError {
    #[error("not a gscodec file (bad magic)")]
    BadMagic,
    #[error("unsupported format version {major}.{minor} (this decoder reads {VERSION_MAJOR}.x)")]
    UnsupportedVersion { major: u8, minor: u8 },
    #[error("file is truncated while reading {0}")]
    Truncated(&'static str),
    #[error("checksum mismatch in {0}")]
    Checksum(String),
    #[error("corrupt data: {0}")]
    Corrupt(&'static str),
    #[error("limit exceeded: {0}")]
    Limit(&'static str),
    #[error("unknown required section kind {0}")]
    UnknownSection(u16),
    #[error("missing section: {0}")]
    MissingSection(String),
    #[error("{0} bytes of trailing data after the last section")]
    TrailingData(usize),
    #[error("cannot read the input: {0}")]
    Io(String),
}

/// The fixed header fields.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Header {
    pub version_major: u8,
    pub version_minor: u8,
    pub gaussians: u32,
    pub sh_degree: u8,
}

/// One section: its table entry and its payload.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Section<'a> {
    pub kind: u16,
    pub chunk: u16,
    pub flags: u32,
    pub data: &'a [u8],
}

/// A parsed container: header and sections whose CRCs have been checked.
#[derive(Debug, Clone)]
pub struct Container<'a> {
    pub header: Header,
    pub sections: Vec<Section<'a>>,
    /// `(kind, chunk)` of the sections listed in the table whose payloads lie beyond the end of
    /// a prefix ([`parse_prefix`]); always empty for [`parse`].
    pub pending: Vec<(u16, u16)>,
}

impl<'a> Container<'a> {
    /// The section of `kind` and `chunk`, if present.
    pub fn section(&self, kind: u16, chunk: u16) -> Option<&Section<'a>> {
        self.sections.iter().find(|s| s.kind == kind && s.chunk == chunk)
    }
}

/// Parses only the fixed header (cheap; no CRC of sections) and checks the Gaussian count
/// against the length of `bytes`, the whole file (SPEC §2 allocation bound).
pub fn parse_header(bytes: &[u8]) -> Result<(Header, usize), DecodeError> {
    let (header, count) = parse_header_fields(bytes)?;
    check_allocation_bound(&header, bytes.len() as u64)?;
    Ok((header, count))
}

fn check_allocation_bound(header: &Header, file_bytes: u64) -> Result<(), DecodeError> {
    if u64::from(header.gaussians) > MAX_GAUSSIANS_PER_BYTE * file_bytes {
        return Err(DecodeError::Limit("Gaussian count too large for the file size"));
    }
    Ok(())
}

/// The fixed header's fields and checks, without the allocation bound (which needs the file length).
pub fn parse_header_fields(bytes: &[u8]) -> Result<(Header, usize), DecodeError> {
    let mut r = ByteReader::new(bytes);
    if r.take(4, "magic").map_err(|_| DecodeError::BadMagic)? != MAGIC {
        return Err(DecodeError::BadMagic);
    }
    let major = r.u8("version")?;
    let minor = r.u8("version")?;
    if major != VERSION_MAJOR {
        return Err(DecodeError::UnsupportedVersion { major, minor });
    }
    let count = r.u16("section count")? as usize;
    let gaussians = r.u32("Gaussian count")?;
    let sh_degree = r.u8("SH degree")?;
    let flags = r.u8("header flags")?;
    let reserved = r.u16("header reserved")?;
    if flags != 0 || reserved != 0 {
        return Err(DecodeError::Corrupt("non-zero reserved header bits"));
    }
    if sh_degree > 3 {
        return Err(DecodeError::Corrupt("SH degree above 3"));
    }
    if count > MAX_SECTIONS {
        return Err(DecodeError::Limit("more than 4096 sections"));
    }
    if gaussians > MAX_GAUSSIANS {
        return Err(DecodeError::Limit("more than 2^26 Gaussians"));
    }
    Ok((Header { version_major: major, version_minor: minor, gaussians, sh_degree }, count))
}

/// Parses and checks the whole container: header CRC, section bounds and every section's CRC.
pub fn parse(bytes: &[u8]) -> Result<Container<'_>, DecodeError> {
    parse_sections(bytes, false)
}

/// Parses the start of a file that is still arriving: the header and section table must be
/// complete (else `Truncated`); sections whose payloads are complete are checked and returned,
/// the others are listed in [`Container::pending`].
pub fn parse_prefix(bytes: &[u8]) -> Result<Container<'_>, DecodeError> {
    parse_sections(bytes, true)
}

fn parse_sections(bytes: &[u8], prefix: bool) -> Result<Container<'_>, DecodeError> {
    let (header, count) = if prefix { parse_header_fields(bytes)? } else { parse_header(bytes)? };
    let table_end = FIXED_HEADER + TABLE_ENTRY * count;
    if bytes.len() < table_end + 4 {
        return Err(DecodeError::Truncated("section table"));
    }
    let mut r = ByteReader::new(&bytes[FIXED_HEADER..table_end + 4]);
    let mut entries = Vec::with_capacity(count);
    for _ in 0..count {
        let kind = r.u16("section table")?;
        let chunk = r.u16("section table")?;
        let flags = r.u32("section table")?;
        let length = r.u32("section table")? as usize;
        let crc = r.u32("section table")?;
        entries.push((kind, chunk, flags, length, crc));
    }
    let header_crc = r.u32("header checksum")?;
    if crc32fast::hash(&bytes[..table_end]) != header_crc {
        return Err(DecodeError::Checksum("header".into()));
    }
    if prefix {
        // The bound holds for the whole file the table declares, and decoding waits until it
        // holds for what has arrived: output never outgrows the input actually read.
        let declared = (table_end + 4) as u64 + entries.iter().map(|e| e.3 as u64).sum::<u64>();
        check_allocation_bound(&header, declared)?;
        if check_allocation_bound(&header, bytes.len() as u64).is_err() {
            return Err(DecodeError::Truncated("file (allocation bound)"));
        }
    }
    let mut body = ByteReader::new(&bytes[table_end + 4..]);
    let mut sections = Vec::with_capacity(count);
    let mut pending = Vec::new();
    for (kind, chunk, flags, length, crc) in entries {
        if prefix && (!pending.is_empty() || body.remaining() < length) {
            pending.push((kind, chunk));
            continue;
        }
        let data = body.take(length, "section payload")?;
        if crc32fast::hash(data) != crc {
            return Err(DecodeError::Checksum(format!("section {kind}/{chunk}")));
        }
        if flags & !SECTION_OPTIONAL != 0 {
            return Err(DecodeError::Corrupt("unknown section flags"));
        }
        if sections.iter().any(|s: &Section| s.kind == kind && s.chunk == chunk) {
            return Err(DecodeError::Corrupt("duplicate section"));
        }
        if flags & SECTION_OPTIONAL == 0 && !is_known(&header, kind, chunk) {
            return Err(DecodeError::UnknownSection(kind));
        }
        sections.push(Section { kind, chunk, flags, data });
    }
    if body.remaining() != 0 && !prefix {
        return Err(DecodeError::TrailingData(body.remaining()));
    }
    Ok(Container { header, sections, pending })
}

/// Whether (kind, chunk) is a section this version defines for a file with `header`'s Gaussian
/// count and SH degree (SPEC §3): parameters (chunk 0) and data (chunk < chunk count) of a present
/// group, info and padding (chunk 0). Anything else is unknown: skipped when OPTIONAL, else an error.
pub fn is_known(header: &Header, kind: u16, chunk: u16) -> bool {
    if kind == layout::INFO_KIND || kind == layout::PADDING_KIND {
        return chunk == 0;
    }
    let n = header.gaussians as usize;
    n > 0
        && layout::Group::present(header.sh_degree)
            .any(|g| (kind == g.params_kind() && chunk == 0) || (kind == g.data_kind() && usize::from(chunk) < layout::chunk_count(n)))
}

/// Serialises a container. Sections are written in the given order.
pub fn write(header: &Header, sections: &[Section<'_>]) -> Vec<u8> {
    let mut w = ByteWriter::new();
    w.bytes(&MAGIC);
    w.u8(header.version_major);
    w.u8(header.version_minor);
    w.u16(sections.len() as u16);
    w.u32(header.gaussians);
    w.u8(header.sh_degree);
    w.u8(0);
    w.u16(0);
    for s in sections {
        w.u16(s.kind);
        w.u16(s.chunk);
        w.u32(s.flags);
        w.u32(s.data.len() as u32);
        w.u32(crc32fast::hash(s.data));
    }
    let crc = crc32fast::hash(&w.buf);
    w.u32(crc);
    for s in sections {
        w.bytes(s.data);
    }
    w.buf
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Vec<u8> {
        let h = Header { version_major: VERSION_MAJOR, version_minor: VERSION_MINOR, gaussians: 3, sh_degree: 1 };
        write(&h, &[Section { kind: 0x11, chunk: 0, flags: 0, data: b"abc" }, Section { kind: 9, chunk: 2, flags: 1, data: b"" }])
    }

    #[test]
    fn unknown_sections_are_skipped_only_when_optional() {
        let h = Header { version_major: VERSION_MAJOR, version_minor: VERSION_MINOR, gaussians: 3, sh_degree: 1 };
        let with = |kind: u16, chunk: u16, flags: u32| parse(&write(&h, &[Section { kind, chunk, flags, data: b"" }])).map(|_| ());
        // Known: parameters and data of present groups (one chunk here), info, padding.
        for (kind, chunk) in [(0x10, 0), (0x15, 0), (0x20, 0), (0x25, 0), (0x100, 0), (0x101, 0)] {
            assert_eq!(with(kind, chunk, 0), Ok(()), "{kind:#x}/{chunk}");
        }
        // Unknown: an absent SH band, a chunk past the last, parameters of chunk 1, a new kind.
        for (kind, chunk) in [(0x16, 0), (0x26, 0), (0x20, 1), (0x11, 1), (0x18, 0), (0x102, 0), (0x100, 1)] {
            assert_eq!(with(kind, chunk, 0), Err(DecodeError::UnknownSection(kind)), "{kind:#x}/{chunk}");
            assert_eq!(with(kind, chunk, SECTION_OPTIONAL), Ok(()), "{kind:#x}/{chunk} optional");
        }
        let empty = Header { gaussians: 0, ..h };
        assert_eq!(
            parse(&write(&empty, &[Section { kind: 0x10, chunk: 0, flags: 0, data: b"" }])).unwrap_err(),
            DecodeError::UnknownSection(0x10)
        );
    }

    #[test]
    fn round_trip() {
        let bytes = sample();
        let c = parse(&bytes).unwrap();
        assert_eq!(c.header.gaussians, 3);
        assert_eq!(c.sections.len(), 2);
        assert_eq!(c.section(0x11, 0).unwrap().data, b"abc");
        assert_eq!(c.section(9, 2).unwrap().flags, SECTION_OPTIONAL);
    }

    #[test]
    fn every_truncation_and_flip_is_an_error() {
        let bytes = sample();
        for n in 0..bytes.len() {
            assert!(parse(&bytes[..n]).is_err(), "truncated to {n}");
        }
        for i in 0..bytes.len() {
            let mut b = bytes.clone();
            b[i] ^= 0x10;
            assert!(parse(&b).is_err(), "flip at {i}");
        }
    }

    #[test]
    fn newer_major_is_refused() {
        let mut bytes = sample();
        bytes[4] = VERSION_MAJOR + 1;
        assert_eq!(parse(&bytes).unwrap_err(), DecodeError::UnsupportedVersion { major: VERSION_MAJOR + 1, minor: VERSION_MINOR });
    }

    #[test]
    fn hostile_section_count_is_refused_without_allocating() {
        let mut bytes = sample();
        bytes[6] = 0xff;
        bytes[7] = 0x0f; // 4095 sections, table far beyond the input
        assert_eq!(parse(&bytes).unwrap_err(), DecodeError::Truncated("section table"));
    }
}

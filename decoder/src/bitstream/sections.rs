//! The section table and payloads (SPEC §2, §3): reading and checking a whole file or a prefix
//! of one, and writing a file from its sections.

use super::header::{self, check_allocation_bound, Header, HEADER_BYTES};
use super::layout::{self, Group, CODEBOOK_KIND, INFO_KIND, LEVELS_KIND, PADDING_KIND};
use super::levels::Layout;
use super::{ByteReader, ByteWriter, SECTION_OPTIONAL};
use crate::error::{self, DecodeError, FormatErrorKind, Place, SectionId};

/// Bytes of one section table entry.
pub const TABLE_ENTRY: usize = 16;

/// One section: its table entry and its payload.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Section<'a> {
    /// Section kind (SPEC §3).
    pub kind: u16,
    /// Chunk index.
    pub chunk: u16,
    /// Section flags (bit 0: OPTIONAL).
    pub flags: u32,
    /// The payload.
    pub data: &'a [u8],
}

impl Section<'_> {
    /// Kind and chunk.
    pub fn id(&self) -> SectionId {
        SectionId { kind: self.kind, chunk: self.chunk }
    }
}

/// One entry of the section table (the payload not yet read).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TableEntry {
    /// Kind and chunk.
    pub id: SectionId,
    /// Section flags.
    pub flags: u32,
    /// Payload bytes.
    pub length: u32,
    /// CRC-32 of the payload.
    pub crc: u32,
}

/// A file's header and section table, checked up to the header CRC.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Table {
    /// The fixed header.
    pub header: Header,
    /// The table entries in file order.
    pub entries: Vec<TableEntry>,
}

impl Table {
    /// Bytes of header, table and header CRC: where the first payload starts.
    pub fn table_bytes(&self) -> usize {
        table_bytes(self.entries.len())
    }

    /// The length of the whole file the table declares.
    pub fn file_bytes(&self) -> u64 {
        self.table_bytes() as u64 + self.entries.iter().map(|e| u64::from(e.length)).sum::<u64>()
    }
}

/// Bytes of header, `sections` table entries and header CRC.
pub fn table_bytes(sections: usize) -> usize {
    HEADER_BYTES + TABLE_ENTRY * sections + 4
}

/// Reads the header and section table from the start of a file and checks the header CRC.
/// `bytes` must hold at least [`table_bytes`] of the section count (else a truncation error);
/// what follows is not looked at. The allocation bound is not checked here.
pub fn read_table(bytes: &[u8]) -> Result<Table, DecodeError> {
    let (header, count) = header::read_header(bytes)?;
    let end = table_bytes(count);
    if bytes.len() < end {
        return Err(Place { section: None, offset: HEADER_BYTES as u64 }.truncated("section table"));
    }
    let mut r = ByteReader::new(&bytes[..end]);
    r.take(HEADER_BYTES, "header")?;
    let mut entries = Vec::with_capacity(count);
    for _ in 0..count {
        let kind = r.u16("section table")?;
        let chunk = r.u16("section table")?;
        let flags = r.u32("section table")?;
        let length = r.u32("section table")?;
        let crc = r.u32("section table")?;
        entries.push(TableEntry { id: SectionId { kind, chunk }, flags, length, crc });
    }
    let stored = r.u32("header checksum")?;
    let computed = crc32fast::hash(&bytes[..end - 4]);
    if computed != stored {
        return Err(Place::default().checksum(stored, computed));
    }
    Ok(Table { header, entries })
}

/// A parsed container: header and sections whose CRCs have been checked.
#[derive(Debug, Clone)]
pub struct Container<'a> {
    /// The fixed header.
    pub header: Header,
    /// The sections whose payloads are present, in file order.
    pub sections: Vec<Section<'a>>,
    /// File offset of each section's payload (same order as `sections`).
    pub offsets: Vec<u64>,
    /// The sections listed in the table whose payloads lie beyond the end of a prefix
    /// ([`parse_prefix`]); always empty for [`parse`].
    pub pending: Vec<SectionId>,
    /// File offset just after the section table (where a missing section would be read).
    pub payloads_start: u64,
}

impl<'a> Container<'a> {
    /// The section of `kind` and `chunk` with its payload's file offset, if present.
    pub fn section(&self, kind: u16, chunk: u16) -> Option<(&Section<'a>, u64)> {
        let i = self.sections.iter().position(|s| s.kind == kind && s.chunk == chunk)?;
        Some((&self.sections[i], self.offsets[i]))
    }

    /// A reader over the payload of the section of `kind` and `chunk`: an absent section reads
    /// as zero bytes (SPEC §3).
    pub fn reader(&self, kind: u16, chunk: u16) -> ByteReader<'a> {
        let id = SectionId { kind, chunk };
        match self.section(kind, chunk) {
            Some((s, offset)) => ByteReader::at(s.data, Place { section: Some(id), offset }),
            None => ByteReader::at(&[], Place { section: Some(id), offset: self.payloads_start }),
        }
    }

    /// The file's chunks and levels: a 3.0 file's implicit layout, or a 4.0 file's levels
    /// section (SPEC §3.1), which must be present when N > 0 and list more chunks than the
    /// highest chunk index of a (known) data section (else a `format` error).
    pub fn layout(&self) -> Result<Layout, DecodeError> {
        let n = self.header.gaussians as usize;
        if !self.header.has_levels() || n == 0 {
            return Ok(Layout::uniform(n));
        }
        if self.section(LEVELS_KIND, 0).is_none() {
            return Err(self.missing(SectionId { kind: LEVELS_KIND, chunk: 0 }, "levels"));
        }
        let layout = Layout::read(&mut self.reader(LEVELS_KIND, 0), n)?;
        // Data sections are numbered by chunk, a 6.0 file's parameter sections by level.
        let beyond = |id: &SectionId| {
            Group::of_kind(id.kind).is_some_and(|g| {
                (g.data_kind() == id.kind && usize::from(id.chunk) >= layout.chunks())
                    || (g.params_kind() == id.kind && usize::from(id.chunk) >= layout.level_chunks.len())
            }) && is_known(&self.header, id.kind, id.chunk)
        };
        let listed = self
            .sections
            .iter()
            .map(Section::id)
            .zip(self.offsets.iter().copied())
            .chain(self.pending.iter().map(|&id| (id, self.payloads_start)));
        if let Some((id, offset)) = listed.into_iter().find(|(id, _)| beyond(id)) {
            let what = if Group::of_kind(id.kind).is_some_and(|g| g.data_kind() == id.kind) {
                "data section of a chunk the levels do not list"
            } else {
                "parameter section of a level the levels do not list"
            };
            return Err(Place { section: Some(id), offset }.corrupt(what));
        }
        Ok(layout)
    }

    /// The codebook section of SH group `g` (SPEC §3.2), if the file has one. A known codebook
    /// of a band above the file's degree D is corrupt (`format`).
    pub fn codebook(&self, g: Group) -> Result<Option<ByteReader<'a>>, DecodeError> {
        let band = u16::from(g.sh_band());
        let d = u16::from(self.header.sh_degree);
        if let Some(i) =
            self.sections.iter().position(|s| s.kind == CODEBOOK_KIND && s.chunk > d && is_known(&self.header, s.kind, s.chunk))
        {
            let s = &self.sections[i];
            return Err(Place { section: Some(s.id()), offset: self.offsets[i] }.corrupt("codebook of an SH band the file does not have"));
        }
        Ok((band > 0 && self.section(CODEBOOK_KIND, band).is_some()).then(|| self.reader(CODEBOOK_KIND, band)))
    }

    /// A missing required section.
    pub fn missing(&self, id: SectionId, what: &'static str) -> DecodeError {
        Place { section: Some(id), offset: self.payloads_start }.error(FormatErrorKind::MissingSection, what)
    }
}

/// Parses and checks a whole file: header, table, header CRC, every payload's CRC, flags and
/// known-ness, no trailing bytes (the order of SPEC §9).
pub fn parse(bytes: &[u8]) -> Result<Container<'_>, DecodeError> {
    parse_sections(bytes, false)
}

/// Parses the start of a file that is still arriving: the header and section table must be
/// complete (else a truncation error); sections whose payloads are complete are checked and
/// returned, the others are listed in [`Container::pending`].
pub fn parse_prefix(bytes: &[u8]) -> Result<Container<'_>, DecodeError> {
    parse_sections(bytes, true)
}

fn parse_sections(bytes: &[u8], prefix: bool) -> Result<Container<'_>, DecodeError> {
    if !prefix {
        // The allocation bound comes before the table (SPEC §9): a whole file's length is known.
        let (header, _) = header::read_header(bytes)?;
        check_allocation_bound(&header, bytes.len() as u64)?;
    }
    let table = read_table(bytes)?;
    let header = table.header;
    if prefix {
        // The bound holds for the whole file the table declares, and decoding waits until it
        // holds for what has arrived: output never outgrows the input actually read.
        check_allocation_bound(&header, table.file_bytes())?;
        if check_allocation_bound(&header, bytes.len() as u64).is_err() {
            return Err(Place::default().truncated("file (allocation bound)"));
        }
    }
    let start = table.table_bytes();
    let mut body = ByteReader::at(&bytes[start..], Place { section: None, offset: start as u64 });
    let mut c = Container {
        header,
        sections: Vec::with_capacity(table.entries.len()),
        offsets: Vec::with_capacity(table.entries.len()),
        pending: Vec::new(),
        payloads_start: start as u64,
    };
    for (i, e) in table.entries.iter().enumerate() {
        let length = e.length as usize;
        if prefix && (!c.pending.is_empty() || body.remaining() < length) {
            c.pending.push(e.id);
            continue;
        }
        let at = Place { section: Some(e.id), ..body.place() };
        let data = body.take(length, "section payload").map_err(|_| at.truncated("section payload"))?;
        check_entry(&c, e, data, at, (HEADER_BYTES + TABLE_ENTRY * i) as u64)?;
        c.sections.push(Section { kind: e.id.kind, chunk: e.id.chunk, flags: e.flags, data });
        c.offsets.push(at.offset);
    }
    if body.remaining() != 0 && !prefix {
        return Err(body.place().error(FormatErrorKind::TrailingData, "trailing data"));
    }
    Ok(c)
}

/// A section's CRC, flags, uniqueness and known-ness, in that order (SPEC §9); `entry_at` is
/// the file offset of its table entry.
fn check_entry(c: &Container<'_>, e: &TableEntry, data: &[u8], at: Place, entry_at: u64) -> Result<(), DecodeError> {
    let computed = crc32fast::hash(data);
    if computed != e.crc {
        return Err(at.checksum(e.crc, computed));
    }
    let entry = Place { section: Some(e.id), offset: entry_at };
    if e.flags & !SECTION_OPTIONAL != 0 {
        return Err(entry.plus(4).corrupt("unknown section flags"));
    }
    if c.sections.iter().any(|s| s.id() == e.id) {
        return Err(entry.corrupt("duplicate section"));
    }
    if e.flags & SECTION_OPTIONAL == 0 && !is_known(&c.header, e.id.kind, e.id.chunk) {
        return Err(error::unsupported_section(e.id, entry_at));
    }
    Ok(())
}

/// Whether (kind, chunk) is a section the file's version defines for a file with `header`'s
/// Gaussian count and SH degree (SPEC §3): parameters (chunk 0; in 6.0 any chunk, one per level)
/// and data of a present group, info and padding (chunk 0), from 4.0 on the levels section
/// (chunk 0, N > 0), from 5.0 on the codebooks (chunk 1..=3, N > 0; one of a band above D is
/// corrupt, [`Container::codebook`]). A 3.0 data section must have a chunk < ⌈N / 65536⌉; from
/// 4.0 on one may have any chunk here, and one beyond the levels' last chunk (a 6.0 parameter
/// section: beyond the last level) is corrupt ([`Container::layout`]). Anything else is unknown:
/// skipped when OPTIONAL, else an error.
pub fn is_known(header: &Header, kind: u16, chunk: u16) -> bool {
    if kind == INFO_KIND || kind == PADDING_KIND {
        return chunk == 0;
    }
    let n = header.gaussians as usize;
    if header.is_anchor() {
        return kind == super::anchors::ANCHORS_KIND && chunk == 0 && n > 0;
    }
    if kind == LEVELS_KIND {
        return header.has_levels() && n > 0 && chunk == 0;
    }
    if kind == CODEBOOK_KIND {
        return header.has_codebooks() && n > 0 && (1..=3).contains(&chunk);
    }
    let data_chunk = |c: u16| header.has_levels() || usize::from(c) < layout::chunk_count(n);
    n > 0
        && Group::present(header.sh_degree)
            .any(|g| (kind == g.params_kind() && (chunk == 0 || header.has_level_params())) || (kind == g.data_kind() && data_chunk(chunk)))
}

/// Serialises a file: header, section table with each payload's CRC, header CRC, then the
/// payloads in the given order.
pub fn write(header: &Header, sections: &[Section<'_>]) -> Vec<u8> {
    let mut w = ByteWriter::new();
    header::write_header(&mut w, header, sections.len());
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

/// As [`write`], adding an optional padding section when the file would be shorter than the
/// allocation bound allows (SPEC §2: at least one byte per 8 Gaussians).
pub fn write_padded(header: &Header, sections: &[Section<'_>]) -> Vec<u8> {
    let bytes = write(header, sections);
    let need = header::min_file_bytes(header.gaussians);
    if bytes.len() >= need {
        return bytes;
    }
    let padding = vec![0; need - bytes.len()];
    let mut padded = sections.to_vec();
    padded.push(Section { kind: PADDING_KIND, chunk: 0, flags: SECTION_OPTIONAL, data: &padding });
    write(header, &padded)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bitstream::{VERSION_MAJOR, VERSION_MAJOR_SHARED, VERSION_MAJOR_UNIFORM, VERSION_MINOR};

    /// A 3.0 header.
    fn header(gaussians: u32) -> Header {
        Header { version_major: VERSION_MAJOR_UNIFORM, version_minor: VERSION_MINOR, gaussians, sh_degree: 1 }
    }

    fn sample() -> Vec<u8> {
        write(&header(3), &[Section { kind: 0x11, chunk: 0, flags: 0, data: b"abc" }, Section { kind: 9, chunk: 2, flags: 1, data: b"" }])
    }

    #[test]
    fn unknown_sections_are_skipped_only_when_optional() {
        let h = header(3);
        let with = |kind: u16, chunk: u16, flags: u32| parse(&write(&h, &[Section { kind, chunk, flags, data: b"" }])).map(|_| ());
        // Known: parameters and data of present groups (one chunk here), info, padding.
        for (kind, chunk) in [(0x10, 0), (0x15, 0), (0x20, 0), (0x25, 0), (0x100, 0), (0x101, 0)] {
            assert!(with(kind, chunk, 0).is_ok(), "{kind:#x}/{chunk}");
        }
        // Unknown: an absent SH band, a chunk past the last, parameters of chunk 1, a new kind,
        // the levels section of 4.0.
        for (kind, chunk) in [(0x16, 0), (0x26, 0), (0x20, 1), (0x11, 1), (0x18, 0), (0x102, 0), (0x100, 1), (0x01, 0)] {
            let e = with(kind, chunk, 0).unwrap_err();
            let DecodeError::Unsupported(u) = e else { panic!("{kind:#x}/{chunk}: {e}") };
            assert_eq!(u.section(), Some(SectionId { kind, chunk }));
            assert!(with(kind, chunk, SECTION_OPTIONAL).is_ok(), "{kind:#x}/{chunk} optional");
        }
        let e = parse(&write(&header(0), &[Section { kind: 0x10, chunk: 0, flags: 0, data: b"" }])).unwrap_err();
        assert_eq!(e.class(), "unsupported");
        // 4.0: the levels section is known (N > 0), and any data chunk (the levels bound it).
        let v4 = |gaussians| Header { version_major: VERSION_MAJOR, ..header(gaussians) };
        for (kind, chunk, known) in [(0x01, 0, true), (0x01, 1, false), (0x20, 1, true), (0x25, 65_535, true), (0x26, 0, false)] {
            assert_eq!(is_known(&v4(3), kind, chunk), known, "{kind:#x}/{chunk}");
        }
        assert!(!is_known(&v4(0), 0x01, 0));
    }

    /// Codebooks (kind 0x02, SPEC §3.2): known in 5.0 for bands 1..=3 when N > 0, unknown in
    /// 4.0 and 3.0; one of a band above D is corrupt.
    #[test]
    fn codebook_sections_are_known_in_5_only() {
        let v = |major, gaussians| Header { version_major: major, ..header(gaussians) };
        for (major, n, chunk, known) in
            [(5, 3, 1, true), (5, 3, 3, true), (5, 3, 0, false), (5, 3, 4, false), (5, 0, 1, false), (4, 3, 1, false), (3, 3, 1, false)]
        {
            assert_eq!(is_known(&v(major, n), CODEBOOK_KIND, chunk), known, "{major}.0 N={n} chunk {chunk}");
        }
        // header(): D = 1, so a codebook of band 2 is corrupt, one of band 1 is not.
        let h = v(VERSION_MAJOR, 3);
        let c = |chunk| {
            let bytes = write(&h, &[Section { kind: CODEBOOK_KIND, chunk, flags: 0, data: b"" }]);
            let c = parse(&bytes).unwrap();
            c.codebook(Group::Sh1).map(|r| r.is_some()).map_err(|e| e.class())
        };
        assert_eq!(c(1), Ok(true));
        assert_eq!(c(2), Err("format"));
    }

    #[test]
    fn data_sections_beyond_the_levels_are_corrupt() {
        let h = Header { version_major: VERSION_MAJOR, ..header(5) };
        let levels = Layout::from_levels(&[2, 3]).write();
        let with = |chunk: u16| {
            let sections =
                [Section { kind: LEVELS_KIND, chunk: 0, flags: 0, data: &levels }, Section { kind: 0x21, chunk, flags: 0, data: b"" }];
            parse(&write(&h, &sections)).unwrap().layout().map(|l| l.chunk_sizes)
        };
        assert_eq!(with(1).unwrap(), vec![2, 3]);
        assert_eq!(with(2).unwrap_err().class(), "format");
        let e = parse(&write(&h, &[])).unwrap().layout().unwrap_err();
        assert_eq!(e.format_error().map(|f| f.kind()), Some(FormatErrorKind::MissingSection));
    }

    #[test]
    fn round_trip() {
        let bytes = sample();
        let c = parse(&bytes).unwrap();
        assert_eq!(c.header.gaussians, 3);
        assert_eq!(c.sections.len(), 2);
        assert_eq!(c.section(0x11, 0).unwrap().0.data, b"abc");
        assert_eq!(c.section(0x11, 0).unwrap().1, table_bytes(2) as u64);
        assert_eq!(c.section(9, 2).unwrap().0.flags, SECTION_OPTIONAL);
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
    fn errors_name_their_class_and_place() {
        let bytes = sample();
        let mut b = bytes.clone();
        b[4] = VERSION_MAJOR_SHARED + 1;
        let e = parse(&b).unwrap_err();
        let DecodeError::Unsupported(u) = &e else { panic!("{e}") };
        assert_eq!(u.version(), Some((VERSION_MAJOR_SHARED + 1, VERSION_MINOR)));
        // A flipped payload byte: the checksum of that section, at its payload's offset.
        let mut b = bytes.clone();
        let last = b.len() - 1;
        b[last] ^= 1;
        let DecodeError::Checksum(c) = parse(&b).unwrap_err() else { panic!() };
        assert_eq!((c.section(), c.offset()), (Some(SectionId { kind: 0x11, chunk: 0 }), table_bytes(2) as u64));
        // Trailing data and a truncated payload.
        let mut b = bytes.clone();
        b.push(0);
        let e = parse(&b).unwrap_err();
        assert_eq!(
            (e.format_error().unwrap().kind(), e.format_error().unwrap().offset()),
            (FormatErrorKind::TrailingData, bytes.len() as u64)
        );
        let e = parse(&bytes[..bytes.len() - 1]).unwrap_err();
        let f = e.format_error().unwrap();
        assert_eq!((f.kind(), f.section()), (FormatErrorKind::Truncated, Some(SectionId { kind: 0x11, chunk: 0 })));
    }

    #[test]
    fn hostile_section_count_is_refused_without_allocating() {
        let mut bytes = sample();
        bytes[6] = 0xff;
        bytes[7] = 0x0f; // 4095 sections, table far beyond the input
        let e = parse(&bytes).unwrap_err();
        assert_eq!(e.format_error().map(|f| (f.kind(), f.what())), Some((FormatErrorKind::Truncated, "section table")));
    }

    #[test]
    fn padding_meets_the_allocation_bound() {
        let h = header(4000);
        let bytes = write_padded(&h, &[]);
        assert_eq!(bytes.len(), 500 + 16);
        assert!(check_allocation_bound(&h, bytes.len() as u64).is_ok());
        assert_eq!(write_padded(&header(3), &[]), write(&header(3), &[]));
    }
}

//! Why decoding failed, sorted by cause: the input could not be read ([`DecodeError::Io`]), the
//! bytes break the format ([`DecodeError::Format`]), a CRC does not match
//! ([`DecodeError::Checksum`]), the file needs what this decoder does not implement
//! ([`DecodeError::Unsupported`]), or it is larger than a limit ([`DecodeError::LimitsExceeded`]).
//!
//! The detail types are opaque structs with accessors, so they can carry more without breaking
//! callers; every one says where in the file the problem is.

use std::fmt;

use crate::bitstream::layout::{Group, INFO_KIND, LEVELS_KIND, PADDING_KIND};

/// A section of a `.gsc` file: its kind and chunk (SPEC §3).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct SectionId {
    /// Section kind (`0x01` levels, `0x10 + g` parameters, `0x20 + g` data, `0x100` info, `0x101` padding).
    pub kind: u16,
    /// Chunk index (0 except for data sections).
    pub chunk: u16,
}

impl SectionId {
    /// What the section holds: a group name with `parameters` or `data`, `levels`, `codebook`,
    /// `anchors`, `info`, `padding` or `unknown`.
    pub fn name(self) -> String {
        if let Some(g) = Group::of_kind(self.kind) {
            return format!("{} {}", g.name(), if g.params_kind() == self.kind { "parameters" } else { "data" });
        }
        match self.kind {
            INFO_KIND => "info".into(),
            PADDING_KIND => "padding".into(),
            LEVELS_KIND => "levels".into(),
            crate::bitstream::layout::CODEBOOK_KIND => "codebook".into(),
            crate::bitstream::anchors::ANCHORS_KIND => "anchors".into(),
            _ => "unknown".into(),
        }
    }
}

impl fmt::Display for SectionId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "section {:#x}/{} ({})", self.kind, self.chunk, self.name())
    }
}

/// Why a byte string could not be decoded. Decoding never panics; it returns one of these.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum DecodeError {
    /// The reader failed (the file may be fine; retrying may help).
    #[error("cannot read the input: {0}")]
    Io(#[from] std::io::Error),
    /// The bytes are not a valid `.gsc` file: bad magic, truncation, corrupt content, a missing
    /// section or trailing data.
    #[error(transparent)]
    Format(#[from] FormatError),
    /// The header's or a section's CRC-32 does not match its bytes.
    #[error(transparent)]
    Checksum(#[from] ChecksumError),
    /// A valid file this decoder cannot read: another major version, or a required section kind
    /// it does not know.
    #[error(transparent)]
    Unsupported(#[from] UnsupportedError),
    /// The file is larger than a limit: one of the format's own (SPEC §9) or one of the
    /// caller's [`Limits`](crate::Limits).
    #[error(transparent)]
    LimitsExceeded(#[from] LimitError),
}

impl DecodeError {
    /// The error class: `"io"`, `"format"`, `"checksum"`, `"unsupported"` or `"limits"` (the
    /// names used by `bitstream-spec/vectors/bad/` and by the C ABI's error codes).
    pub fn class(&self) -> &'static str {
        match self {
            DecodeError::Io(_) => "io",
            DecodeError::Format(_) => "format",
            DecodeError::Checksum(_) => "checksum",
            DecodeError::Unsupported(_) => "unsupported",
            DecodeError::LimitsExceeded(_) => "limits",
        }
    }

    /// The format error's detail, if this is one.
    pub fn format_error(&self) -> Option<&FormatError> {
        match self {
            DecodeError::Format(e) => Some(e),
            _ => None,
        }
    }
}

/// What kind of format violation a [`FormatError`] is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum FormatErrorKind {
    /// The file does not start with the `.gsc` magic (or is shorter than 4 bytes).
    BadMagic,
    /// The file ends before a field or payload it declares.
    Truncated,
    /// A field holds a value the format forbids.
    Corrupt,
    /// A required section is not in the file.
    MissingSection,
    /// Bytes follow the last section's payload.
    TrailingData,
}

/// A format violation: what, of which kind, and where (section and byte offset in the file).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FormatError {
    kind: FormatErrorKind,
    what: &'static str,
    at: Place,
}

impl FormatError {
    /// The kind of violation.
    pub fn kind(&self) -> FormatErrorKind {
        self.kind
    }

    /// What was being read or which rule failed, e.g. `"stream length"`.
    pub fn what(&self) -> &'static str {
        self.what
    }

    /// The section the problem is in (`None` for the header and the section table).
    pub fn section(&self) -> Option<SectionId> {
        self.at.section
    }

    /// Byte offset in the file where the offending field starts (for a missing section: where
    /// its payload would be read, the end of the section table).
    pub fn offset(&self) -> u64 {
        self.at.offset
    }
}

impl fmt::Display for FormatError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.kind {
            FormatErrorKind::BadMagic => write!(f, "not a gscodec file (bad magic)")?,
            FormatErrorKind::Truncated => write!(f, "file is truncated while reading {}", self.what)?,
            FormatErrorKind::Corrupt => write!(f, "corrupt data: {}", self.what)?,
            FormatErrorKind::MissingSection => write!(f, "missing section: {}", self.what)?,
            FormatErrorKind::TrailingData => write!(f, "trailing data after the last section")?,
        }
        if self.kind != FormatErrorKind::BadMagic {
            write!(f, " at byte {}", self.at.offset)?;
            if let Some(s) = self.at.section {
                write!(f, " in {s}")?;
            }
        }
        Ok(())
    }
}

impl std::error::Error for FormatError {}

/// A CRC-32 mismatch: of the header (with the section table) or of one section's payload.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ChecksumError {
    at: Place,
    stored: u32,
    computed: u32,
}

impl ChecksumError {
    /// The section whose payload does not match (`None`: the header and section table).
    pub fn section(&self) -> Option<SectionId> {
        self.at.section
    }

    /// Byte offset of the checked bytes in the file.
    pub fn offset(&self) -> u64 {
        self.at.offset
    }

    /// The CRC stored in the file and the one computed from its bytes.
    pub fn crcs(&self) -> (u32, u32) {
        (self.stored, self.computed)
    }
}

impl fmt::Display for ChecksumError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.at.section {
            None => write!(f, "checksum mismatch in the header")?,
            Some(s) => write!(f, "checksum mismatch in {s} (payload at byte {})", self.at.offset)?,
        }
        write!(f, ": stored {:08x}, computed {:08x}", self.stored, self.computed)
    }
}

impl std::error::Error for ChecksumError {}

/// A valid file that needs what this decoder does not implement.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct UnsupportedError {
    what: Unsupported,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Unsupported {
    Version { major: u8, minor: u8 },
    Section { id: SectionId, offset: u64 },
}

impl UnsupportedError {
    /// The file's `(major, minor)` version, when that is what is unsupported.
    pub fn version(&self) -> Option<(u8, u8)> {
        match self.what {
            Unsupported::Version { major, minor } => Some((major, minor)),
            Unsupported::Section { .. } => None,
        }
    }

    /// The unknown required section, when that is what is unsupported.
    pub fn section(&self) -> Option<SectionId> {
        match self.what {
            Unsupported::Section { id, .. } => Some(id),
            Unsupported::Version { .. } => None,
        }
    }
}

impl fmt::Display for UnsupportedError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.what {
            Unsupported::Version { major, minor } => {
                write!(
                    f,
                    "unsupported format version {major}.{minor} (this decoder reads {}.x to {}.x)",
                    crate::bitstream::VERSION_MAJOR_UNIFORM,
                    crate::bitstream::VERSION_MAJOR_SHARED
                )
            }
            Unsupported::Section { id, offset } => {
                write!(f, "unknown required section kind {:#x} (chunk {}, table entry at byte {offset})", id.kind, id.chunk)
            }
        }
    }
}

impl std::error::Error for UnsupportedError {}

/// Which limit a [`LimitError`] hit.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum Limit {
    /// Gaussians in the file: the format's 2^26, or [`Limits::max_gaussians`](crate::Limits).
    Gaussians,
    /// Gaussians per byte of file: at most 8 (SPEC §2, the allocation bound).
    GaussiansPerByte,
    /// Bytes the decoder would hold (input and output): [`Limits::max_bytes`](crate::Limits).
    Bytes,
    /// Sections in the file: at most 4096.
    Sections,
    /// Symbols of a channel table: at most 4096.
    TableSymbols,
    /// The anchor profile's MLP (SPEC §12): at most 2^18 weights, and anchors × weights at most
    /// 2^34 multiply-adds.
    AnchorWork,
}

/// A file larger than a limit; says which, the value and the bound.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LimitError {
    limit: Limit,
    value: u64,
    max: u64,
    caller: bool,
}

impl LimitError {
    /// Which limit.
    pub fn limit(&self) -> Limit {
        self.limit
    }

    /// The file's value and the largest allowed.
    pub fn value_and_max(&self) -> (u64, u64) {
        (self.value, self.max)
    }

    /// Whether the bound is the caller's [`Limits`](crate::Limits) (which can be raised) rather
    /// than the format's own.
    pub fn is_caller_limit(&self) -> bool {
        self.caller
    }
}

impl fmt::Display for LimitError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let (v, m) = (self.value, self.max);
        match (self.limit, self.caller) {
            (Limit::Gaussians, true) => write!(f, "limit exceeded: {v} Gaussians > Limits::max_gaussians = {m}"),
            (Limit::Bytes, _) => write!(f, "limit exceeded: decoding needs {v} bytes > Limits::max_bytes = {m}"),
            (Limit::Gaussians, false) => write!(f, "limit exceeded: {v} Gaussians > 2^26"),
            (Limit::GaussiansPerByte, _) => {
                write!(f, "limit exceeded: {v} Gaussians in a file of {m} bytes (at most 8 per byte)")
            }
            (Limit::Sections, _) => write!(f, "limit exceeded: {v} sections > {m}"),
            (Limit::TableSymbols, _) => write!(f, "limit exceeded: table of {v} symbols > {m}"),
            (Limit::AnchorWork, _) => write!(f, "limit exceeded: anchor MLP work {v} > {m}"),
        }
    }
}

impl std::error::Error for LimitError {}

/// Where in the file something is: a section (or none: header and table) and a byte offset.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub(crate) struct Place {
    pub(crate) section: Option<SectionId>,
    pub(crate) offset: u64,
}

impl Place {
    /// `n` bytes further on.
    pub(crate) fn plus(self, n: usize) -> Place {
        Place { offset: self.offset + n as u64, ..self }
    }

    pub(crate) fn error(self, kind: FormatErrorKind, what: &'static str) -> DecodeError {
        DecodeError::Format(FormatError { kind, what, at: self })
    }

    pub(crate) fn corrupt(self, what: &'static str) -> DecodeError {
        self.error(FormatErrorKind::Corrupt, what)
    }

    pub(crate) fn truncated(self, what: &'static str) -> DecodeError {
        self.error(FormatErrorKind::Truncated, what)
    }

    pub(crate) fn checksum(self, stored: u32, computed: u32) -> DecodeError {
        DecodeError::Checksum(ChecksumError { at: self, stored, computed })
    }
}

pub(crate) fn unsupported_version(major: u8, minor: u8) -> DecodeError {
    DecodeError::Unsupported(UnsupportedError { what: Unsupported::Version { major, minor } })
}

pub(crate) fn unsupported_section(id: SectionId, offset: u64) -> DecodeError {
    DecodeError::Unsupported(UnsupportedError { what: Unsupported::Section { id, offset } })
}

/// The format's own bound (`caller = false`) or the caller's.
pub(crate) fn limit(limit: Limit, value: u64, max: u64, caller: bool) -> DecodeError {
    DecodeError::LimitsExceeded(LimitError { limit, value, max, caller })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages_name_the_place_and_the_bound() {
        let id = |kind, chunk| SectionId { kind, chunk };
        assert_eq!(id(0x11, 0).name(), "scale parameters");
        assert_eq!(id(0x27, 2).to_string(), "section 0x27/2 (sh_band3 data)");
        assert_eq!(id(0x102, 0).name(), "unknown");
        let at = Place { section: Some(id(0x23, 1)), offset: 1234 };
        let e = at.truncated("stream");
        assert_eq!(e.to_string(), "file is truncated while reading stream at byte 1234 in section 0x23/1 (opacity data)");
        assert_eq!((e.class(), e.format_error().unwrap().offset()), ("format", 1234));
        let e = Place::default().checksum(1, 2);
        assert_eq!((e.class(), e.to_string()), ("checksum", "checksum mismatch in the header: stored 00000001, computed 00000002".into()));
        let e = limit(Limit::Gaussians, 10, 5, true);
        assert_eq!((e.class(), e.to_string()), ("limits", "limit exceeded: 10 Gaussians > Limits::max_gaussians = 5".into()));
        assert_eq!(unsupported_version(4, 1).class(), "unsupported");
        assert_eq!(DecodeError::from(std::io::Error::other("x")).class(), "io");
    }
}

//! The fixed header (SPEC §2): magic, version, section count, Gaussian count, SH degree.

use super::{
    ByteReader, ByteWriter, MAGIC, MAX_GAUSSIANS, MAX_GAUSSIANS_PER_BYTE, MAX_SECTIONS, VERSION_MAJOR, VERSION_MAJOR_ANCHORS,
    VERSION_MAJOR_CODEBOOKS, VERSION_MAJOR_LEVELS, VERSION_MAJOR_NEIGHBOURS, VERSION_MAJOR_SHARED, VERSION_MAJOR_UNIFORM,
};
use crate::error::{self, DecodeError, FormatErrorKind, Limit, Place};

/// Bytes of the fixed header.
pub const HEADER_BYTES: usize = 16;

/// The fixed header's fields (the section count is the section table's length).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Header {
    /// Format major version (this crate reads 3 to 6, 8 and 9, the explicit profile, and 7,
    /// the anchor profile).
    pub version_major: u8,
    /// Format minor version (a reader accepts any).
    pub version_minor: u8,
    /// Number of Gaussians `N`.
    pub gaussians: u32,
    /// SH degree `D` of the stored scene (0..=3).
    pub sh_degree: u8,
}

impl Header {
    /// Whether the file has a levels section (formats 4 to 6, 8 and 9, SPEC §3.1); a 3.0 file's
    /// layout is one level of 65,536-Gaussian chunks.
    pub fn has_levels(&self) -> bool {
        (VERSION_MAJOR_LEVELS..=VERSION_MAJOR).contains(&self.version_major) || self.has_neighbours()
    }

    /// Whether the file is in the anchor profile (format 7, SPEC §12).
    pub fn is_anchor(&self) -> bool {
        self.version_major == VERSION_MAJOR_ANCHORS
    }

    /// Whether the file may hold SH codebooks (formats 5, 6, 8 and 9, SPEC §3.2).
    pub fn has_codebooks(&self) -> bool {
        (VERSION_MAJOR_CODEBOOKS..=VERSION_MAJOR).contains(&self.version_major) || self.has_neighbours()
    }

    /// Whether each level has its own parameter sections (formats 6, 8 and 9, SPEC §4): level
    /// `l`'s are the sections of chunk `l`; before 6.0 every level uses those of chunk 0.
    pub fn has_level_params(&self) -> bool {
        self.version_major == VERSION_MAJOR || self.has_neighbours()
    }

    /// Whether channel tables may be neighbour-context tables (mode 3, formats 8 and 9, SPEC
    /// §4.3).
    pub fn has_neighbours(&self) -> bool {
        matches!(self.version_major, VERSION_MAJOR_NEIGHBOURS | VERSION_MAJOR_SHARED)
    }

    /// Whether an SH band may share the row index of the band below (format 9, SPEC §3.2).
    pub fn has_shared_index(&self) -> bool {
        self.version_major == VERSION_MAJOR_SHARED
    }

    /// The chunk of the parameter sections that level `level`'s data sections use.
    pub fn params_chunk(&self, level: usize) -> usize {
        if self.has_level_params() {
            level
        } else {
            0
        }
    }
}

/// Reads and checks the fixed header: magic, major version, reserved bits, SH degree, section
/// and Gaussian counts (in that order, SPEC §9). Returns the header and the section count. The
/// allocation bound needs the file length: see [`check_allocation_bound`].
pub fn read_header(bytes: &[u8]) -> Result<(Header, usize), DecodeError> {
    let mut r = ByteReader::new(bytes);
    let bad_magic = || Place::default().error(FormatErrorKind::BadMagic, "magic");
    if r.take(4, "magic").map_err(|_| bad_magic())? != MAGIC {
        return Err(bad_magic());
    }
    let major = r.u8("version")?;
    let minor = r.u8("version")?;
    if !(VERSION_MAJOR_UNIFORM..=VERSION_MAJOR_SHARED).contains(&major) {
        return Err(error::unsupported_version(major, minor));
    }
    let count = r.u16("section count")? as usize;
    let gaussians = r.u32("Gaussian count")?;
    let degree_at = r.place();
    let sh_degree = r.u8("SH degree")?;
    let flags_at = r.place();
    let flags = r.u8("header flags")?;
    let reserved = r.u16("header reserved")?;
    if flags != 0 || reserved != 0 {
        return Err(flags_at.corrupt("non-zero reserved header bits"));
    }
    if sh_degree > 3 {
        return Err(degree_at.corrupt("SH degree above 3"));
    }
    if count > MAX_SECTIONS {
        return Err(error::limit(Limit::Sections, count as u64, MAX_SECTIONS as u64, false));
    }
    if gaussians > MAX_GAUSSIANS {
        return Err(error::limit(Limit::Gaussians, gaussians.into(), MAX_GAUSSIANS.into(), false));
    }
    Ok((Header { version_major: major, version_minor: minor, gaussians, sh_degree }, count))
}

/// Writes the fixed header of a file with `sections` sections.
pub fn write_header(w: &mut ByteWriter, header: &Header, sections: usize) {
    w.bytes(&MAGIC);
    w.u8(header.version_major);
    w.u8(header.version_minor);
    w.u16(sections as u16);
    w.u32(header.gaussians);
    w.u8(header.sh_degree);
    w.u8(0);
    w.u16(0);
}

/// The allocation bound (SPEC §2): at most 8 Gaussians per byte of the whole file.
pub fn check_allocation_bound(header: &Header, file_bytes: u64) -> Result<(), DecodeError> {
    if u64::from(header.gaussians) > MAX_GAUSSIANS_PER_BYTE * file_bytes {
        return Err(error::limit(Limit::GaussiansPerByte, header.gaussians.into(), file_bytes, false));
    }
    Ok(())
}

/// The least file length that satisfies the allocation bound for `gaussians` Gaussians.
pub fn min_file_bytes(gaussians: u32) -> usize {
    u64::from(gaussians).div_ceil(MAX_GAUSSIANS_PER_BYTE) as usize
}

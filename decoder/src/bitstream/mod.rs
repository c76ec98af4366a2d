//! The `.gsc` format, one module per element of `bitstream-spec/SPEC.md`, each with its reader
//! and its writer side by side. The decoder reads through them; the encoder (crate `gscodec`)
//! writes only through them, so a change to an element touches one file.
//!
//! | module | SPEC | reads | writes |
//! |---|---|---|---|
//! | [`bytes`] | §1 | `ByteReader` (placed errors) | `ByteWriter` |
//! | [`header`] | §2 | [`header::read_header`] | [`header::write_header`] |
//! | [`sections`] | §2, §3 | [`sections::read_table`], [`sections::parse`], [`sections::parse_prefix`] | [`sections::write`], [`sections::write_padded`] |
//! | [`layout`] | §3 | attribute groups, section kinds, chunks | |
//! | [`levels`] | §3.1 | [`levels::Layout::read`] | [`levels::Layout::write`] |
//! | [`params`] | §3.2 | [`params::read_codebook`] | [`params::write_codebook`] |
//! | [`params`] | §4 | [`params::read_params`] | [`params::write_position_params`], [`params::write_channel_params`] |
//! | [`tables`] | §4.1 | [`tables::ChannelTable::read`] | `ChannelTable::write_*` |
//! | [`stream`] | §6, §6.2 | channel streams of a data section | [`stream::write_channel_streams`], [`stream::push_stream`] |
//! | [`positions`] | §6.1 | the Morton position stream | [`positions::write_position_stream`] |
//! | [`info`] | §3 | [`info::read_info`] | [`info::write_info`] |
//! | [`anchors`] | §12 | [`anchors::read_anchors`], [`anchors::expand`] | [`anchors::write_anchors`] |
//! | [`assemble`] | §7, §8 | dequantisation and channel values → [`Splats`](crate::Splats) | |
//!
//! Probability tables and the ANS coder are in [`crate::entropy`].

pub mod anchors;
pub mod assemble;
pub mod bytes;
pub mod header;
pub mod info;
pub mod layout;
pub mod levels;
pub mod params;
pub mod positions;
pub mod sections;
pub mod stream;
pub mod tables;

pub use bytes::{ByteReader, ByteWriter};
pub use header::Header;
pub use sections::{parse, parse_prefix, write, Container, Section};

/// First four bytes of every `.gsc` file.
pub const MAGIC: [u8; 4] = [0x8A, b'G', b'S', b'C'];
/// Newest major version of the explicit profile: files whose levels have their own parameter
/// sections (SPEC §4, importance classes) are written as 6.0; files of [`VERSION_MAJOR_CODEBOOKS`],
/// [`VERSION_MAJOR_LEVELS`] and [`VERSION_MAJOR_UNIFORM`] are read too.
pub const VERSION_MAJOR: u8 = 6;
/// Format 7.0: the anchor profile (SPEC §12), an anchor section instead of the explicit
/// profile's levels, groups and codebooks.
pub const VERSION_MAJOR_ANCHORS: u8 = 7;
/// Format 8.0: the explicit profile of 6.0 with neighbour-context tables (table mode 3, SPEC
/// §4.3), written for files that use one.
pub const VERSION_MAJOR_NEIGHBOURS: u8 = 8;
/// Format 9.0: 8.0 with SH bands that share the row index of the band below (one codebook row
/// per Gaussian for several bands, SPEC §3.2), written for files that have one. The newest
/// major version this crate reads.
pub const VERSION_MAJOR_SHARED: u8 = 9;
/// Format 5.0: SH codebooks (SPEC §3.2), written for files with codebooks whose levels share one
/// set of parameter sections.
pub const VERSION_MAJOR_CODEBOOKS: u8 = 5;
/// Format 4.0: importance levels (SPEC §3.1), written for progressive files without codebooks.
pub const VERSION_MAJOR_LEVELS: u8 = 4;
/// The previous major version (3.0: no levels section, chunks of 65,536), read by this crate and
/// written for files of one level of such chunks, so that 3.0 readers can read them.
pub const VERSION_MAJOR_UNIFORM: u8 = 3;
/// Format minor version written by this crate (a reader accepts any minor of its majors).
pub const VERSION_MINOR: u8 = 0;
/// Section flag: a reader that does not know this section kind may skip it.
pub const SECTION_OPTIONAL: u32 = 1;
/// Most sections a file may have (SPEC §9).
pub const MAX_SECTIONS: usize = 4096;
/// Most Gaussians a file may hold (SPEC §9).
pub const MAX_GAUSSIANS: u32 = 1 << 26;
/// A file may hold at most this many Gaussians per byte of file (SPEC §2).
pub const MAX_GAUSSIANS_PER_BYTE: u64 = 8;

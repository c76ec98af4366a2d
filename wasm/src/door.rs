//! The only place this crate calls `gscodec-decoder`: every decoder call the WASM package makes
//! goes through these functions, so a change of the decoder's API is a change of this file.
//!
//! Calls used: [`gscodec_decoder::decode_with`], [`gscodec_decoder::decode_prefix`],
//! [`gscodec_decoder::peek_header`], [`gscodec_decoder::inspect`] (with [`Limits`], [`Splats`],
//! [`FileInfo`], [`Header`], [`DecodeError`] and its `class()`), `bitstream::sections::parse_prefix`
//! + [`Group`] (which SH bands of a prefix have arrived) and `math::sigmoid` /
//! `math::normalize_quat` (unit conversion).

use gscodec_decoder::bitstream::sections;
pub use gscodec_decoder::{math, DecodeError, FileInfo, Header, Splats};
use gscodec_decoder::{FormatErrorKind, Group, Limits};

/// The decoder's default limits, SH bands above `max_sh_degree` skipped. The browser has one
/// thread: the decode runs on the calling thread (rayon falls back to it on
/// `wasm32-unknown-unknown`).
fn limits(max_sh_degree: u8) -> Limits {
    Limits { max_sh_degree, ..Limits::default() }
}

/// A whole `.gsc` file to a scene.
pub fn decode(bytes: &[u8], max_sh_degree: u8) -> Result<Splats, DecodeError> {
    gscodec_decoder::decode_with(bytes, &limits(max_sh_degree))
}

/// What a file holds (header, sections, sizes), checked but not decoded.
pub fn info(bytes: &[u8]) -> Result<FileInfo, DecodeError> {
    gscodec_decoder::inspect(bytes)
}

/// The fixed header (version, Gaussian count, SH degree) from the first 16 bytes.
pub fn peek(bytes: &[u8]) -> Result<Header, DecodeError> {
    gscodec_decoder::peek_header(bytes)
}

/// The scene a prefix of a file can show: `None` until the base groups have arrived.
pub fn decode_prefix(bytes: &[u8], max_sh_degree: u8) -> Result<Option<Splats>, DecodeError> {
    gscodec_decoder::decode_prefix(bytes, &limits(max_sh_degree))
}

/// Whether an error says that bytes are missing (the file may be fine, only cut short).
pub fn is_truncation(e: &DecodeError) -> bool {
    e.format_error().is_some_and(|f| f.kind() == FormatErrorKind::Truncated)
}

/// The SH degree [`decode_prefix`] would give for this prefix, without decoding: `None` until the
/// base groups (position, scale, rotation, opacity, DC colour) have arrived. Costs a parse and the
/// CRCs of the arrived sections. This is `decode_prefix`'s own rule; a decoder call that reports
/// it would replace this function.
pub fn arrived_degree(bytes: &[u8], max_sh_degree: u8) -> Result<Option<u8>, DecodeError> {
    if gscodec_decoder::bitstream::MAGIC.starts_with(bytes) {
        return Ok(None);
    }
    let c = match sections::parse_prefix(bytes) {
        Ok(c) => c,
        Err(e) if is_truncation(&e) => return Ok(None),
        Err(e) => return Err(e),
    };
    let arrived = |g: Group| !c.pending.iter().any(|id| id.kind == g.params_kind() || id.kind == g.data_kind());
    if !Group::present(0).all(arrived) {
        return Ok(None);
    }
    let wanted = c.header.sh_degree.min(max_sh_degree);
    Ok(Some((1..=wanted).take_while(|&b| arrived(Group::for_band(b))).last().unwrap_or(0)))
}

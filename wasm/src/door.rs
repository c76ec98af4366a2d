//! The only place this crate calls `gscodec-decoder`: every decoder call the WASM package makes
//! goes through these functions, so a change of the decoder's API is a change of this file.
//!
//! Calls used: [`gscodec_decoder::decode_with`], [`gscodec_decoder::decode_prefix`],
//! [`gscodec_decoder::prefix_extent`], [`gscodec_decoder::peek_header`],
//! [`gscodec_decoder::inspect`] (with [`Limits`], [`Splats`], [`FileInfo`], [`Header`],
//! [`DecodeError`] and its `class()`) and `math::sigmoid` / `math::normalize_quat` (unit
//! conversion).

pub use gscodec_decoder::{math, DecodeError, FileInfo, Header, Splats};
use gscodec_decoder::{FormatErrorKind, Limits};

/// The decoder's default limits, SH bands above `max_sh_degree` skipped. The browser has one
/// thread: on `wasm32-unknown-unknown` the decoder runs its loops as plain loops on the calling
/// thread, as a one-thread decode does natively (rayon's job queues are not used).
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

/// The scene a prefix of a file can show: `None` until the first importance level (the base
/// groups of its chunks) has arrived, then every complete level with the SH bands that arrived.
pub fn decode_prefix(bytes: &[u8], max_sh_degree: u8) -> Result<Option<Splats>, DecodeError> {
    gscodec_decoder::decode_prefix(bytes, &limits(max_sh_degree))
}

/// Whether an error says that bytes are missing (the file may be fine, only cut short).
pub fn is_truncation(e: &DecodeError) -> bool {
    e.format_error().is_some_and(|f| f.kind() == FormatErrorKind::Truncated)
}

/// What [`decode_prefix`] would give for this prefix, without decoding: `None`, or the number of
/// Gaussians (whole importance levels) and the SH degree.
pub fn prefix_extent(bytes: &[u8], max_sh_degree: u8) -> Result<Option<(usize, u8)>, DecodeError> {
    gscodec_decoder::prefix_extent(bytes, &limits(max_sh_degree))
}

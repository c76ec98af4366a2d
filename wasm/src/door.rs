//! The only place this crate calls `gscodec-decoder`: every decoder call the WASM package makes
//! goes through these functions, so a change of the decoder's API is a change of this file.
//!
//! Calls used: [`gscodec_decoder::decode`], [`gscodec_decoder::decode_prefix`],
//! [`gscodec_decoder::peek_header`], [`gscodec_decoder::inspect`] (with [`DecodeOptions`],
//! [`Splats`], [`FileInfo`], [`DecodeError`]), `bitstream::parse_prefix` +
//! `bitstream::layout::Group` (which SH bands of a prefix have arrived) and `math::sigmoid` /
//! `math::normalize_quat` (unit conversion).

pub use gscodec_decoder::bitstream::Header;
use gscodec_decoder::bitstream::{self, layout::Group};
use gscodec_decoder::DecodeOptions;
pub use gscodec_decoder::{math, DecodeError, FileInfo, Splats};

/// Decoding options: SH bands above `max_sh_degree` are skipped. The browser has one thread, so
/// decoding runs on the calling thread (rayon falls back to it on `wasm32-unknown-unknown`).
fn options(max_sh_degree: u8) -> DecodeOptions {
    DecodeOptions { max_sh_degree, threads: 0 }
}

/// A whole `.gsc` file to a scene.
pub fn decode(bytes: &[u8], max_sh_degree: u8) -> Result<Splats, DecodeError> {
    gscodec_decoder::decode(bytes, &options(max_sh_degree))
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
    gscodec_decoder::decode_prefix(bytes, &options(max_sh_degree))
}

/// The SH degree [`decode_prefix`] would give for this prefix, without decoding: `None` until the
/// base groups (position, scale, rotation, opacity, DC colour) have arrived. Costs a parse and the
/// CRCs of the arrived sections. This is `decode_prefix`'s own rule; a decoder call that reports
/// it would replace this function.
pub fn arrived_degree(bytes: &[u8], max_sh_degree: u8) -> Result<Option<u8>, DecodeError> {
    if bitstream::MAGIC.starts_with(bytes) {
        return Ok(None);
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
    let wanted = c.header.sh_degree.min(max_sh_degree);
    Ok(Some((1..=wanted).take_while(|&b| arrived(Group::for_band(b))).last().unwrap_or(0)))
}

/// The class of an error, for callers that branch on it: `format` (not a valid file), `truncated`
/// (more bytes needed), `unsupported` (a newer format version), `limit` (over a decoder limit),
/// `io`.
pub fn error_kind(e: &DecodeError) -> &'static str {
    match e {
        DecodeError::Truncated(_) => "truncated",
        DecodeError::UnsupportedVersion { .. } => "unsupported",
        DecodeError::Limit(_) => "limit",
        DecodeError::Io(_) => "io",
        DecodeError::BadMagic
        | DecodeError::Checksum(_)
        | DecodeError::Corrupt(_)
        | DecodeError::UnknownSection(_)
        | DecodeError::MissingSection(_)
        | DecodeError::TrailingData(_) => "format",
    }
}

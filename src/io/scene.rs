//! Scene files by extension: the one place that maps a path to a reader or writer.
//!
//! `.ply` (INRIA layout) today; other formats (`.gsc`, `.spz`, `.splat`) plug in here.

use super::ply;
use crate::{Error, Result};
use gscodec_decoder::Splats;
use std::path::Path;

/// The lower-case extension of `path`, or "".
fn extension(path: &Path) -> String {
    path.extension().map(|e| e.to_string_lossy().to_ascii_lowercase()).unwrap_or_default()
}

/// Reads a scene, choosing the format by extension.
///
/// # Errors
/// [`Error::input`] for an unknown extension or a bad file.
pub fn read_scene(path: &Path) -> Result<Splats> {
    match extension(path).as_str() {
        "ply" => ply::read_ply(path),
        e => Err(Error::input(path, format!("unsupported scene format `.{e}` (supported: .ply)"))),
    }
}

/// Writes a scene, choosing the format by extension (atomically).
pub fn write_scene(path: &Path, splats: &Splats) -> Result<()> {
    match extension(path).as_str() {
        "ply" => ply::write_ply(path, splats),
        e => Err(Error::input(path, format!("unsupported output format `.{e}` (supported: .ply)"))),
    }
}

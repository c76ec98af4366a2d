//! Scene files by extension: the one place that maps a path to a reader or writer.
//!
//! `.ply` (INRIA layout), `.spz` (Niantic SPZ; read v2–v4, written as v4) and `.splat`
//! (antimatter15, 32 bytes per Gaussian, DC colour only); `.gsc` plugs in here too.

use super::spz::{self, SpzVersion};
use super::{ply, splat};
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
        "spz" => spz::read_spz(path),
        "splat" => splat::read_splat(path),
        e => Err(Error::input(path, format!("unsupported scene format `.{e}` (supported: .ply, .spz, .splat)"))),
    }
}

/// Writes a scene, choosing the format by extension (atomically).
pub fn write_scene(path: &Path, splats: &Splats) -> Result<()> {
    match extension(path).as_str() {
        "ply" => ply::write_ply(path, splats),
        "spz" => spz::write_spz(path, splats, SpzVersion::V4),
        "splat" => splat::write_splat(path, splats),
        e => Err(Error::input(path, format!("unsupported output format `.{e}` (supported: .ply, .spz, .splat)"))),
    }
}

//! Scene files by extension: the one place that maps a path to a reader or writer.
//!
//! `.ply` (INRIA layout), `.gsc` (gscodec bitstream), `.spz` (Niantic SPZ; read v2–v4, written as v4)
//! and `.splat` (antimatter15, 32 bytes per Gaussian, DC colour only).

use super::spz::{self, SpzVersion};
use super::{ply, splat};
use crate::{Error, Result};
use gscodec_decoder::{decode, DecodeOptions, Splats};
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
    read_scene_with(path, &DecodeOptions::default())
}

/// As [`read_scene`], with decode options for `.gsc` (e.g. a maximum SH degree; `.ply` scenes
/// are truncated to it too).
pub fn read_scene_with(path: &Path, opts: &DecodeOptions) -> Result<Splats> {
    let s = match extension(path).as_str() {
        "ply" => ply::read_ply(path)?,
        "spz" => spz::read_spz(path)?,
        "splat" => splat::read_splat(path)?,
        "gsc" => {
            let bytes = std::fs::read(path).map_err(|e| Error::input(path, e))?;
            decode(&bytes, opts).map_err(|e| Error::input(path, e))?
        }
        e => return Err(Error::input(path, format!("unsupported scene format `.{e}` (supported: .ply, .gsc, .spz, .splat)"))),
    };
    Ok(if s.sh_degree > opts.max_sh_degree { s.with_sh_degree(opts.max_sh_degree) } else { s })
}

/// Writes a scene, choosing the format by extension (atomically): `.ply`, `.spz`, `.splat`
/// (`.gsc` needs the encoder: `crate::rate::encode`).
pub fn write_scene(path: &Path, splats: &Splats) -> Result<()> {
    match extension(path).as_str() {
        "ply" => ply::write_ply(path, splats),
        "gsc" => Err(Error::input(path, "a .gsc file is written by the encoder (`gscodec encode`), not by scene I/O")),
        "spz" => spz::write_spz(path, splats, SpzVersion::V4),
        "splat" => splat::write_splat(path, splats),
        e => Err(Error::input(path, format!("unsupported output format `.{e}` (supported: .ply, .gsc, .spz, .splat)"))),
    }
}

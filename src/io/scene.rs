//! Scene files by extension: the one place that maps a path to a reader or writer.
//!
//! `.ply` (INRIA layout), `.gsc` (gscodec bitstream), `.spz` (Niantic SPZ; read v2–v4, written as v4)
//! and `.splat` (antimatter15, 32 bytes per Gaussian, DC colour only).

use super::spz::{self, SpzVersion};
use super::{ply, splat};
use crate::{Error, Result};
use gscodec_decoder::{Decoder, Limits, Splats};
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
    read_scene_with(path, &Limits::default())
}

/// As [`read_scene`], with decoder limits for `.gsc` (their maximum SH degree truncates the other
/// formats' scenes too).
pub fn read_scene_with(path: &Path, limits: &Limits) -> Result<Splats> {
    let s = match extension(path).as_str() {
        "ply" => ply::read_ply(path)?,
        "spz" => spz::read_spz(path)?,
        "splat" => splat::read_splat(path)?,
        "gsc" => {
            let file = std::fs::File::open(path).map_err(|e| Error::input(path, e))?;
            let decoder = Decoder::with_limits(std::io::BufReader::new(file), *limits);
            decoder.read_info().and_then(|r| r.decode()).map_err(|e| Error::input(path, e))?
        }
        e => return Err(Error::input(path, format!("unsupported scene format `.{e}` (supported: .ply, .gsc, .spz, .splat)"))),
    };
    Ok(if s.sh_degree > limits.max_sh_degree { s.with_sh_degree(limits.max_sh_degree) } else { s })
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

//! Scene files by extension: the one place that maps a path to a reader or writer.
//!
//! `.ply` (INRIA layout; PlayCanvas compressed PLY is recognised by its header, and written for
//! names ending in `.compressed.ply`), `.gsc` (gscodec bitstream), `.spz` (Niantic SPZ; read v2–v4,
//! written as v4), `.splat` (antimatter15, 32 bytes per Gaussian, DC colour only), `.sog` and
//! `meta.json` (PlayCanvas SOG v2, bundled or unbundled) and `.glb` / `.gltf` (glTF 2.0 with
//! `KHR_gaussian_splatting`).

use super::spz::{self, SpzVersion};
use super::{compressed_ply, gltf, ply, sog, splat};
use crate::{Error, Result};
use gscodec_decoder::{Decoder, Limits, Splats};
use std::path::Path;

/// The formats `read_scene` / `write_scene` know, for error messages.
const SUPPORTED: &str = ".ply, .compressed.ply, .gsc, .spz, .splat, .sog, meta.json (SOG), .glb, .gltf";

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
        "ply" => {
            let bytes = std::fs::read(path).map_err(|e| Error::input(path, format!("cannot read: {e}")))?;
            if compressed_ply::is_compressed_ply(&bytes) {
                compressed_ply::decode_compressed_ply(&bytes).map_err(|m| Error::input(path, format!("not a valid compressed PLY: {m}")))?
            } else {
                ply::read_ply_bytes(&bytes, path)?
            }
        }
        "spz" => spz::read_spz(path)?,
        "splat" => splat::read_splat(path)?,
        "sog" => sog::read_sog(path)?,
        "json" if sog::is_sog_meta(path) => sog::read_sog(path)?,
        "glb" | "gltf" => gltf::read_gltf(path)?,
        "gsc" => {
            let file = std::fs::File::open(path).map_err(|e| Error::input(path, e))?;
            let decoder = Decoder::with_limits(std::io::BufReader::new(file), *limits);
            decoder.read_info().and_then(|r| r.decode()).map_err(|e| Error::input(path, e))?
        }
        e => return Err(Error::input(path, format!("unsupported scene format `.{e}` (supported: {SUPPORTED})"))),
    };
    Ok(if s.sh_degree > limits.max_sh_degree { s.with_sh_degree(limits.max_sh_degree) } else { s })
}

/// Writes a scene, choosing the format by extension (atomically): `.ply`, `.spz`, `.splat`
/// (`.gsc` needs the encoder: `crate::rate::encode`).
pub fn write_scene(path: &Path, splats: &Splats) -> Result<()> {
    match extension(path).as_str() {
        "ply" if compressed_ply::is_compressed_ply_name(path) => compressed_ply::write_compressed_ply(path, splats),
        "ply" => ply::write_ply(path, splats),
        "gsc" => Err(Error::input(path, "a .gsc file is written by the encoder (`gscodec encode`), not by scene I/O")),
        "spz" => spz::write_spz(path, splats, SpzVersion::V4),
        "splat" => splat::write_splat(path, splats),
        "sog" => sog::write_sog(path, splats),
        "json" if sog::is_sog_meta(path) => sog::write_sog(path, splats),
        "glb" | "gltf" => gltf::write_gltf(path, splats),
        e => Err(Error::input(path, format!("unsupported output format `.{e}` (supported: {SUPPORTED})"))),
    }
}

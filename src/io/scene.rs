//! A scene file of either kind (`.gsc` bitstream or INRIA `.ply`), and the standard orbit
//! cameras around a scene used when no dataset cameras exist (encode of a `.ply`, eval, bench).

use std::path::Path;

use glam::Vec3;
use gscodec_decoder::{decode, Camera, DecodeOptions, Splats};

use crate::{Error, Result};

/// Loads `.gsc` (decoded with all SH bands) or `.ply` by extension.
pub fn load_scene(path: &Path) -> Result<Splats> {
    load_scene_with(path, &DecodeOptions::default())
}

/// As [`load_scene`], with decode options for `.gsc` files.
pub fn load_scene_with(path: &Path, opts: &DecodeOptions) -> Result<Splats> {
    let is_gsc = path.extension().is_some_and(|e| e.eq_ignore_ascii_case("gsc"));
    if is_gsc {
        let bytes = std::fs::read(path).map_err(|e| Error::input(path, e))?;
        decode(&bytes, opts).map_err(|e| Error::input(path, e))
    } else {
        let s = crate::io::read_ply(path)?;
        Ok(if s.sh_degree > opts.max_sh_degree { s.with_sh_degree(opts.max_sh_degree) } else { s })
    }
}

/// `n` cameras on a circle around the scene: centred on the per-axis median position, radius
/// 2× the median distance of Gaussians from that centre, 0.35 rad elevation, world up +y,
/// 60° horizontal field of view. Deterministic; an empty scene gets a unit orbit at the origin.
pub fn scene_orbit(splats: &Splats, n: usize, width: u32, height: u32) -> Vec<Camera> {
    let (center, radius) = if splats.is_empty() {
        (Vec3::ZERO, 1.0)
    } else {
        let median = |mut v: Vec<f32>| {
            v.sort_by(f32::total_cmp);
            v[v.len() / 2]
        };
        let c = Vec3::new(
            median(splats.positions.iter().map(|p| p[0]).collect()),
            median(splats.positions.iter().map(|p| p[1]).collect()),
            median(splats.positions.iter().map(|p| p[2]).collect()),
        );
        let r = median(splats.positions.iter().map(|p| (Vec3::from(*p) - c).length()).collect());
        (c, 2.0 * r.max(1e-6))
    };
    Camera::orbit(n, center, radius, 0.35, Vec3::Y, width, height, 60f32.to_radians())
}

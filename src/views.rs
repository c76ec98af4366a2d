//! Camera sets for looking at a scene without a dataset (orbits for `render`, `eval`, encoding from
//! a `.ply`).

use glam::Vec3;
use gscodec_decoder::{Camera, Splats};

/// Horizontal field of view of orbit cameras (radians, about 46°).
pub const ORBIT_FOV_X: f32 = 0.8;
/// Elevation of orbit cameras above the scene's horizontal plane (radians, 25°).
pub const ORBIT_ELEVATION: f32 = 25.0 * std::f32::consts::PI / 180.0;
/// Orbit radius in multiples of the 90th-percentile distance of the Gaussians to the centre.
pub const ORBIT_RADIUS_FACTOR: f32 = 2.5;

/// Robust centre (per-axis median of the positions) and extent (90th-percentile distance to it).
/// An empty scene gives the origin and 1.
pub fn robust_frame(splats: &Splats) -> (Vec3, f32) {
    if splats.is_empty() {
        return (Vec3::ZERO, 1.0);
    }
    let median = |a: usize| {
        let mut v: Vec<f32> = splats.positions.iter().map(|p| p[a]).collect();
        let mid = v.len() / 2;
        *v.select_nth_unstable_by(mid, f32::total_cmp).1
    };
    let c = Vec3::new(median(0), median(1), median(2));
    let mut d: Vec<f32> = splats.positions.iter().map(|p| Vec3::from(*p).distance(c)).collect();
    let k = (d.len() * 9 / 10).min(d.len() - 1);
    let ext = *d.select_nth_unstable_by(k, f32::total_cmp).1;
    (c, if ext.is_finite() && ext > 0.0 { ext } else { 1.0 })
}

/// Where orbit cameras look at `splats` from: its robust centre and the orbit radius,
/// [`ORBIT_RADIUS_FACTOR`] × its robust extent ([`robust_frame`]).
pub fn orbit_frame(splats: &Splats) -> (Vec3, f32) {
    let (centre, extent) = robust_frame(splats);
    (centre, ORBIT_RADIUS_FACTOR * extent)
}

/// `cam` at its own size, or scaled down so that its longer side is `max_side` pixels (each
/// side rounded, at least 1).
pub fn fit_within(cam: &Camera, max_side: u32) -> Camera {
    let scale = (max_side as f32 / cam.width.max(cam.height) as f32).min(1.0);
    let side = |v: u32| ((v as f32 * scale).round() as u32).max(1);
    cam.resized(side(cam.width), side(cam.height))
}

/// `n` cameras on a circle around the scene's robust centre, at [`ORBIT_ELEVATION`], radius
/// [`ORBIT_RADIUS_FACTOR`] × the robust extent, with `up` as the world up axis.
pub fn orbit_cameras(splats: &Splats, n: usize, width: u32, height: u32, up: Vec3) -> Vec<Camera> {
    let (centre, radius) = orbit_frame(splats);
    Camera::orbit(n, centre, radius, ORBIT_ELEVATION, up, width, height, ORBIT_FOV_X)
}

/// Cameras for fine-tuning a scene against renders of itself: three rings of `per_ring` views at
/// [`ORBIT_ELEVATION`] and 15° below and above it, with azimuths half a step off those of
/// [`orbit_cameras`]`(…, per_ring, …)`, so that no training view is one of the evaluation views.
pub fn training_cameras(splats: &Splats, per_ring: usize, width: u32, height: u32, up: Vec3) -> Vec<Camera> {
    let (centre, radius) = orbit_frame(splats);
    let ring = |elevation: f32| {
        let twice = Camera::orbit(2 * per_ring, centre, radius, elevation, up, width, height, ORBIT_FOV_X);
        twice.into_iter().skip(1).step_by(2) // azimuths (2i+1)·π/per_ring
    };
    let tilt = 15f32.to_radians();
    [ORBIT_ELEVATION - tilt, ORBIT_ELEVATION, ORBIT_ELEVATION + tilt].into_iter().flat_map(ring).collect()
}

/// World up axes by name, for `--up`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum UpAxis {
    #[value(name = "x")]
    PosX,
    #[value(name = "-x")]
    NegX,
    #[value(name = "y")]
    PosY,
    #[value(name = "-y")]
    NegY,
    #[value(name = "z")]
    PosZ,
    #[value(name = "-z")]
    NegZ,
}

impl UpAxis {
    pub fn vector(self) -> Vec3 {
        match self {
            UpAxis::PosX => Vec3::X,
            UpAxis::NegX => -Vec3::X,
            UpAxis::PosY => Vec3::Y,
            UpAxis::NegY => -Vec3::Y,
            UpAxis::PosZ => Vec3::Z,
            UpAxis::NegZ => -Vec3::Z,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn training_cameras_avoid_the_evaluation_views() {
        let mut s = Splats::new(0);
        for i in 0..50 {
            let x = i as f32 * 0.1;
            s.push([x.sin(), x.cos(), x], [-2.0; 3], [1.0, 0.0, 0.0, 0.0], 0.0, [0.0; 3], &[]);
        }
        let eval = orbit_cameras(&s, 8, 64, 64, Vec3::NEG_Y);
        let train = training_cameras(&s, 8, 64, 64, Vec3::NEG_Y);
        assert_eq!(train.len(), 24);
        let radius = (eval[0].center() - eval[4].center()).length() / 2.0;
        for t in &train {
            let nearest = eval.iter().map(|e| (e.center() - t.center()).length()).fold(f32::INFINITY, f32::min);
            assert!(nearest > 0.1 * radius, "a training camera sits on an evaluation camera");
        }
    }
}

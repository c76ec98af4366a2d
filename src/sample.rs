//! A deterministic procedural scene and its NeRF-style dataset (`gscodec sample`).
//!
//! The scene (world up = +z, like Blender) has a textured floor (a checkerboard of flat Gaussians
//! at z = −0.5), clusters of coloured blobs, thin anisotropic needles and some Gaussians with
//! view-dependent colour in SH bands 1–3 (the scene is SH degree 3). Views are rendered from
//! cameras on a sphere of radius 4 around the origin at elevations between 15° and 65°, with a
//! horizontal field of view of 0.6911 rad (the NeRF-synthetic one), on a white background, and
//! saved as 8-bit RGB PNGs. Everything comes from a seeded SplitMix64 generator and plain
//! arithmetic, so the same options give the same files on every machine.
//!
//! `gscodec sample --scene SCENE` writes the same kind of dataset from any scene instead: the
//! cameras on a sphere around its robust centre at the orbit's distance and field of view
//! ([`Rig::around`]), so that every scene can be trained from images (a second scene for studies
//! that must not rest on one data set).

use crate::io::atomic::write_dir_atomic;
use crate::io::image::write_png;
use crate::io::{camera_spread, nerf, ply};
use crate::rng::Rng;
use crate::views::{orbit_frame, ORBIT_FOV_X};
use crate::{Error, Result};
use glam::Vec3;
use gscodec_decoder::camera::DEFAULT_ZNEAR;
use gscodec_decoder::math::{sh_rest_coeffs, SH_C0};
use gscodec_decoder::render::render;
use gscodec_decoder::{Camera, RenderOptions, Splats};
use std::path::Path;

/// Horizontal field of view of the sample cameras (radians).
pub const FOV_X: f64 = 0.691_111_207_008_361_8;
/// Distance of the cameras from the origin.
pub const RADIUS: f32 = 4.0;
/// Background the views are rendered on.
pub const BACKGROUND: [f32; 3] = [1.0; 3];

/// What to generate. `gaussians` is the procedural scene's size; [`write_scene_sample`] takes
/// its scene instead.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SampleOptions {
    pub gaussians: usize,
    pub views: usize,
    pub width: u32,
    pub height: u32,
    pub seed: u64,
}

/// Where a sample's cameras stand: on a sphere of `radius` around `centre`, looking at it, with
/// `up` as the world up axis and `fov_x` as the horizontal field of view (radians).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rig {
    pub centre: Vec3,
    pub radius: f32,
    pub up: Vec3,
    pub fov_x: f64,
}

impl Rig {
    /// The procedural scene's cameras: radius [`RADIUS`] around the origin, +z up, [`FOV_X`].
    pub const PROCEDURAL: Rig = Rig { centre: Vec3::ZERO, radius: RADIUS, up: Vec3::Z, fov_x: FOV_X };

    /// Cameras framing `scene` as the evaluation orbit does: [`orbit_frame`]'s centre and
    /// radius, [`ORBIT_FOV_X`]; `up` normalised.
    pub fn around(scene: &Splats, up: Vec3) -> Rig {
        let (centre, radius) = orbit_frame(scene);
        Rig { centre, radius, up: up.normalize(), fov_x: f64::from(ORBIT_FOV_X) }
    }

    /// Camera-to-world matrices (OpenGL axes, like NeRF's `transform_matrix`) of `views` cameras
    /// on the rig's sphere: azimuths evenly spaced with a seeded jitter of ±0.3 of a step,
    /// elevations spread between 15° and 65° above the plane normal to `up`.
    pub fn poses(&self, views: usize, seed: u64) -> Vec<[[f32; 4]; 4]> {
        let mut rng = sample_rng(seed.wrapping_add(1));
        // A basis of the horizontal plane; for +z up it is exactly (x, y), so the procedural
        // sample's poses keep their bits.
        let a = if self.up.x.abs() < 0.9 { Vec3::X } else { Vec3::Y };
        let a = (a - self.up * self.up.dot(a)).normalize();
        let b = self.up.cross(a);
        (0..views)
            .map(|i| {
                let azim = std::f32::consts::TAU * (i as f32 + rng.range(-0.3, 0.3)) / views.max(1) as f32;
                // Low-discrepancy spread of elevations between 15 and 65 degrees.
                let elev = (15.0 + 50.0 * ((i as f32 * 0.618_034) % 1.0)).to_radians();
                let dir = a * (azim.cos() * elev.cos()) + b * (azim.sin() * elev.cos()) + self.up * elev.sin();
                let eye = dir * self.radius + self.centre;
                let cam = Camera::look_at(eye, self.centre, self.up, 64, 64, self.fov_x as f32);
                // OpenCV world-to-camera -> OpenGL camera-to-world: columns x, -y, -z of R^T.
                let rt = cam.rotation.transpose();
                let (x, y, z) = (rt.x_axis, -rt.y_axis, -rt.z_axis);
                [[x.x, y.x, z.x, eye.x], [x.y, y.y, z.y, eye.y], [x.z, y.z, z.z, eye.z], [0.0, 0.0, 0.0, 1.0]]
            })
            .collect()
    }
}

impl Default for SampleOptions {
    fn default() -> Self {
        SampleOptions { gaussians: 2000, views: 32, width: 128, height: 128, seed: 0 }
    }
}

/// The sample's random stream: the crate's SplitMix64 with the seed mixing the committed
/// `samples/tiny` was generated with.
fn sample_rng(seed: u64) -> Rng {
    Rng::from_state(seed ^ 0x5851_f42d_4c95_7f2d)
}

/// A random unit quaternion (w, x, y, z), not normalised exactly (the renderer normalises).
fn random_quat(rng: &mut Rng) -> [f32; 4] {
    let q = [rng.range(-1.0, 1.0), rng.range(-1.0, 1.0), rng.range(-1.0, 1.0), rng.range(-1.0, 1.0)];
    let n = q.iter().map(|v| v * v).sum::<f32>().sqrt().max(1e-3);
    q.map(|v| v / n)
}

fn dc(rgb: [f32; 3]) -> [f32; 3] {
    rgb.map(|c| (c - 0.5) / SH_C0)
}

/// The procedural scene: `n` Gaussians, SH degree 3.
pub fn scene(n: usize, seed: u64) -> Splats {
    let mut rng = sample_rng(seed);
    let mut s = Splats::new(3);
    let k3 = sh_rest_coeffs(3) * 3;
    let zero = vec![0.0f32; k3];
    // Floor: a g×g grid of flat Gaussians, checkerboard of two colours with a little noise.
    let n_floor = n * 2 / 5;
    let g = (n_floor as f32).sqrt().floor() as usize;
    let cell = 3.0 / g.max(1) as f32;
    for iy in 0..g {
        for ix in 0..g {
            let (x, y) = (-1.5 + (ix as f32 + 0.5) * cell, -1.5 + (iy as f32 + 0.5) * cell);
            let check = ((x + 1.5) / 0.75).floor() as i32 + ((y + 1.5) / 0.75).floor() as i32;
            let base = if check % 2 == 0 { [0.85, 0.8, 0.7] } else { [0.25, 0.3, 0.45] };
            let noise = rng.range(-0.05, 0.05);
            let ls = (cell * 0.6).ln();
            s.push(
                [x, y, -0.5],
                [ls, ls, (cell * 0.02).ln()],
                [1.0, 0.0, 0.0, rng.range(-0.05, 0.05)],
                4.0,
                dc(base.map(|c| c + noise)),
                &zero,
            );
        }
    }
    let left = n.saturating_sub(s.len());
    let n_needles = left / 8;
    let n_blobs = left - n_needles;
    // Blobs: clusters around a few coloured centres; every fifth one has view-dependent colour.
    let palette = [[0.9, 0.2, 0.15], [0.2, 0.75, 0.3], [0.2, 0.35, 0.95], [0.95, 0.8, 0.1], [0.7, 0.25, 0.8]];
    let centres: Vec<[f32; 3]> = (0..palette.len()).map(|_| [rng.range(-0.9, 0.9), rng.range(-0.9, 0.9), rng.range(-0.2, 0.6)]).collect();
    for i in 0..n_blobs {
        let c = i % palette.len();
        let r = rng.range(0.0, 0.35);
        let dir = Vec3::new(rng.range(-1.0, 1.0), rng.range(-1.0, 1.0), rng.range(-1.0, 1.0)).normalize_or(Vec3::Z);
        let p = Vec3::from(centres[c]) + dir * r;
        let col = palette[c].map(|v: f32| (v + rng.range(-0.1, 0.1)).clamp(0.0, 1.0));
        let ls = rng.range(0.03, 0.09).ln();
        let scales = [ls + rng.range(-0.3, 0.3), ls + rng.range(-0.3, 0.3), ls + rng.range(-0.3, 0.3)];
        let rest: Vec<f32> = if i % 5 == 0 {
            // Degree 1 strong, degrees 2-3 weaker: colour shifts with the viewing direction.
            (0..k3).map(|j| rng.range(-1.0, 1.0) * if j < 9 { 0.5 } else { 0.15 }).collect()
        } else {
            zero.clone()
        };
        s.push(p.into(), scales, random_quat(&mut rng), rng.range(0.5, 3.0), dc(col), &rest);
    }
    // Needles: long thin Gaussians standing up from the floor at random tilts.
    for _ in 0..n_needles {
        let base = [rng.range(-1.2, 1.2), rng.range(-1.2, 1.2), rng.range(-0.4, 0.4)];
        let col = [rng.range(0.05, 0.35), rng.range(0.3, 0.6), rng.range(0.5, 0.9)];
        let len = rng.range(0.08, 0.25);
        s.push(base, [len.ln(), rng.range(0.003, 0.008).ln(), rng.range(0.003, 0.008).ln()], random_quat(&mut rng), 2.0, dc(col), &zero);
    }
    s
}

/// Writes the procedural dataset: `transforms_train.json`, `train/r_<i>.png`, `truth.ply`, all or
/// nothing.
pub fn write_sample(dir: &Path, opts: &SampleOptions, progress: &indicatif::ProgressBar) -> Result<()> {
    if opts.gaussians == 0 {
        return Err(Error::input(dir, "--gaussians must be positive"));
    }
    write_dataset(dir, &scene(opts.gaussians, opts.seed), &Rig::PROCEDURAL, opts, progress)
}

/// Writes the dataset of `splats` (read from `source`, which errors name) as [`write_sample`]
/// writes the procedural one, with the cameras of [`Rig::around`]`(splats, up)`; `truth.ply` is
/// `splats`. `opts.gaussians` is not used.
pub fn write_scene_sample(
    dir: &Path,
    source: &Path,
    splats: &Splats,
    up: Vec3,
    opts: &SampleOptions,
    progress: &indicatif::ProgressBar,
) -> Result<()> {
    if splats.is_empty() {
        return Err(Error::input(source, "the scene has no Gaussians to render"));
    }
    write_dataset(dir, splats, &Rig::around(splats, up), opts, progress)
}

fn write_dataset(dir: &Path, splats: &Splats, rig: &Rig, opts: &SampleOptions, progress: &indicatif::ProgressBar) -> Result<()> {
    if opts.views == 0 || opts.width == 0 || opts.height == 0 {
        return Err(Error::input(dir, "--views and --size must be positive"));
    }
    let poses = rig.poses(opts.views, opts.seed);
    write_dir_atomic(dir, |tmp| {
        // f32 values are written as their exact f64 so that reading them back gives the same bits.
        let frames: Vec<serde_json::Value> = poses
            .iter()
            .enumerate()
            .map(|(i, m)| {
                let rows: Vec<Vec<f64>> = m.iter().map(|r| r.iter().map(|&v| v as f64).collect()).collect();
                serde_json::json!({ "file_path": format!("./train/r_{i}"), "transform_matrix": rows })
            })
            .collect();
        let json = serde_json::json!({ "camera_angle_x": rig.fov_x, "frames": frames });
        let json_path = tmp.join("transforms_train.json");
        let text = serde_json::to_string_pretty(&json).expect("JSON of numbers and strings");
        std::fs::write(&json_path, text).map_err(|e| Error::failure(&json_path, format!("cannot write: {e}")))?;
        ply::write_ply(&tmp.join("truth.ply"), splats)?;
        // Cameras exactly as `load_dataset` rebuilds them from the JSON just written.
        let specs = nerf::parse_transforms(&json_path)?;
        let mut cams: Vec<Camera> =
            specs.iter().map(|s| s.camera(opts.width, opts.height, 1).map_err(|m| Error::failure(&json_path, m))).collect::<Result<_>>()?;
        let znear = DEFAULT_ZNEAR * camera_spread(cams.iter().map(|c| c.center()));
        cams.iter_mut().for_each(|c| c.znear = znear);
        let train = tmp.join("train");
        std::fs::create_dir_all(&train).map_err(|e| Error::failure(&train, format!("cannot create: {e}")))?;
        progress.set_length(cams.len() as u64);
        let ropts = RenderOptions { background: BACKGROUND, max_sh_degree: 3 };
        for (i, cam) in cams.iter().enumerate() {
            write_png(&train.join(format!("r_{i}.png")), &render(splats, cam, &ropts))?;
            progress.inc(1);
        }
        Ok(())
    })
}

//! Datasets made by rendering a known scene: the targets when fine-tuning an existing `.ply`
//! (the codec's INPUT = trained scene case) and the synthetic scenes of tests and benches.

use crate::io::{Dataset, Frame};
use gscodec_decoder::render::render;
use gscodec_decoder::{Camera, RenderOptions, Splats};

/// Renders `scene` from each camera (full SH, on `background`); frame `i` is camera `i`.
pub fn render_targets(scene: &Splats, cameras: &[Camera], background: [f32; 3]) -> Dataset {
    let opts = RenderOptions { background, max_sh_degree: 3 };
    let frames = cameras
        .iter()
        .enumerate()
        .map(|(i, cam)| Frame { index: i, name: format!("{i:04}"), camera: *cam, image: render(scene, cam, &opts) })
        .collect();
    Dataset { frames, background, ..Default::default() }
}

/// A small deterministic test scene: `n` coloured Gaussians in the unit ball (SH degree 1).
pub fn toy_scene(n: usize, seed: u64) -> Splats {
    let mut rng = crate::rng::Rng::new(seed);
    let mut s = Splats::new(1);
    while s.len() < n {
        let p = [rng.uniform(), rng.uniform(), rng.uniform()].map(|v| 2.0 * v - 1.0);
        if p.iter().map(|v| v * v).sum::<f32>() > 1.0 {
            continue;
        }
        let ls = [0, 1, 2].map(|_| -2.6 + 0.8 * rng.uniform());
        let rot = [0, 1, 2, 3].map(|_| rng.normal());
        let dc = [0, 1, 2].map(|_| 1.6 * rng.uniform() - 0.8);
        let rest: Vec<f32> = (0..9).map(|_| 0.2 * rng.normal()).collect();
        s.push(p, ls, rot, 1.0 + 2.0 * rng.uniform(), dc, &rest);
    }
    s
}

/// `n` cameras on a sphere-ish orbit (two elevation rings) around the origin at `radius`.
pub fn orbit_cameras(n: usize, radius: f32, width: u32, height: u32) -> Vec<Camera> {
    let half = n / 2;
    let mut cams = Camera::orbit(half, glam::Vec3::ZERO, radius, 0.35, glam::Vec3::Z, width, height, 0.9);
    cams.extend(Camera::orbit(n - half, glam::Vec3::ZERO, radius, -0.25, glam::Vec3::Z, width, height, 0.9));
    cams
}

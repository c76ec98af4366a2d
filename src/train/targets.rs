//! Datasets made by rendering a known scene: the targets when fine-tuning an existing `.ply`
//! (the codec's INPUT = trained scene case) and the synthetic datasets of tests and benches
//! (their scenes and cameras come from [`crate::testkit`]).

use crate::io::{Dataset, Frame};
use gscodec_decoder::render::render;
use gscodec_decoder::{Camera, RenderOptions, Splats};

/// Renders `scene` from each camera (full SH, on `background`); frame `i` is camera `i`.
pub fn render_targets(scene: &Splats, cameras: &[Camera], background: [f32; 3]) -> Dataset {
    let opts = RenderOptions { background, max_sh_degree: 3 };
    let frames = cameras
        .iter()
        .enumerate()
        .map(|(i, cam)| Frame { index: i, name: format!("{i:04}"), camera: *cam, image: render(scene, cam, &opts).into() })
        .collect();
    Dataset { frames, background, ..Default::default() }
}

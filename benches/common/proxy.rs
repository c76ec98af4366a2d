//! The large proxy scene of docs/codec.md "Encode speed at scale": a scene tiled side by side,
//! shared by `examples/tile_scene.rs` and `benches/decode.rs` (no data committed).

use gscodec::decoder::Splats;

/// `nx × nz` copies of `scene` laid out along x and z (the orbit's up axis is −y), each shifted
/// by the scene's extent along that axis: a scene `nx·nz` times larger with the input's
/// attribute statistics. An empty scene stays empty.
pub fn tiled(scene: &Splats, nx: usize, nz: usize) -> Splats {
    let mut out = Splats::new(scene.sh_degree);
    let Some((lo, hi)) = scene.bounds() else { return out };
    for ix in 0..nx {
        for iz in 0..nz {
            let shift = [ix as f32 * (hi[0] - lo[0]), 0.0, iz as f32 * (hi[2] - lo[2])];
            for i in 0..scene.len() {
                let p = scene.positions[i];
                out.push(
                    [p[0] + shift[0], p[1], p[2] + shift[2]],
                    scene.log_scales[i],
                    scene.rotations[i],
                    scene.opacity_logits[i],
                    scene.sh_dc[i],
                    scene.rest_of(i),
                );
            }
        }
    }
    out
}

//! Differentiable rasterizer: the decoder's forward render with saved state, and its analytic
//! backward pass to every Gaussian parameter.
//!
//! The forward pass *is* the decoder's renderer (`preprocess`, `bin_tiles`, each pixel composited
//! over its 4×4 block's share of its tile's list, `TileBlocks`), so a trained scene renders
//! identically in any player. It additionally keeps, per pixel, the final transmittance and where
//! in its tile's list it stopped; the backward pass walks the pixel's block list back to front
//! from there (as the reference CUDA rasterizer walks the tile's list),
//! recovering each transmittance by division, so memory is bounded by the image size plus the
//! tile overlaps.
//!
//! Determinism: per-tile partial gradients are written into one slot per tile-list entry and then
//! summed per Gaussian in tile-list order, so the result does not depend on the thread count.

mod backward;

pub use backward::{backward, Gradients};

use gscodec_decoder::math::TILE;
use gscodec_decoder::render::{
    bin_tiles, block_reaches, composite_lanes, cull_thresholds, gather_tile, preprocess, Projected, TileBins, TileBlocks, LANES,
};
use gscodec_decoder::{Camera, Image, RenderOptions, Splats};
use rayon::prelude::*;
use std::time::Instant;

/// What the backward pass needs from a forward render.
#[derive(Debug, Clone)]
pub struct RasterState {
    pub camera: Camera,
    pub options: RenderOptions,
    /// SH degree actually used (`min(options.max_sh_degree, splats.sh_degree)`).
    pub degree: u8,
    pub projected: Vec<Projected>,
    pub bins: TileBins,
    /// Per Gaussian, the `power` below which it is skipped (`cull_thresholds`) and its 4×4-block
    /// reach (`block_reaches`), as the forward pass used them.
    pub cull: Vec<f32>,
    pub reach: Vec<Option<[f64; 2]>>,
    /// Final transmittance per pixel.
    pub final_t: Vec<f32>,
    /// Per pixel, the index in its tile's list of the entry its compositing stopped at
    /// (transmittance spent), or the list's length: the backward pass walks the entries of the
    /// pixel's block ([`TileBlocks`]) that come before it.
    pub n_visited: Vec<u32>,
}

/// Wall time of the forward stages, seconds.
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize)]
pub struct ForwardTimings {
    pub project: f64,
    pub sort: f64,
    pub rasterize: f64,
}

/// Renders like [`gscodec_decoder::render::render`] (bit-identical) and keeps the state for
/// [`backward`].
pub fn forward(splats: &Splats, cam: &Camera, opts: &RenderOptions) -> (Image, RasterState) {
    let (img, state, _) = forward_timed(splats, cam, opts);
    (img, state)
}

/// [`forward`] with per-stage wall times.
pub fn forward_timed(splats: &Splats, cam: &Camera, opts: &RenderOptions) -> (Image, RasterState, ForwardTimings) {
    let (w, h) = (cam.width, cam.height);
    let t0 = Instant::now();
    let projected = preprocess(splats, cam, opts.max_sh_degree);
    let t1 = Instant::now();
    let bins = bin_tiles(&projected, w, h);
    let t2 = Instant::now();
    let n_pix = (w * h) as usize;
    let mut img = Image::filled(w, h, [0.0; 3]);
    let mut final_t = vec![0.0f32; n_pix];
    let mut n_visited = vec![0u32; n_pix];
    let band_pix = (w * TILE) as usize;
    let (cull, reach) = (cull_thresholds(&projected), block_reaches(&projected));
    // Every tile composited in parallel (row-major within the tile, each pixel over its block's
    // list: TileBlocks), then copied into the image by bands of tile rows: the same per-pixel
    // arithmetic as the decoder's banded renderer.
    let n_tiles = (bins.tiles_x * bins.tiles_y) as usize;
    let tiles: Vec<Vec<([f32; 3], f32, u32)>> = (0..n_tiles)
        .into_par_iter()
        .map_init(
            || (Vec::new(), TileBlocks::default()),
            |(local, blocks), t| {
                let (tx, ty) = (t as u32 % bins.tiles_x, t as u32 / bins.tiles_x);
                gather_tile(&projected, &cull, bins.tile(t), local);
                blocks.cut(local, bins.tile(t), &reach, (tx, ty), (w, h));
                let (x0, x1, y0, y1) = (tx * TILE, ((tx + 1) * TILE).min(w), ty * TILE, ((ty + 1) * TILE).min(h));
                let mut out = Vec::with_capacity(((x1 - x0) * (y1 - y0)) as usize);
                for py in y0..y1 {
                    for xl in (x0..x1).step_by(LANES) {
                        let (list, index) = blocks.at(xl - x0, py - y0);
                        let lanes = (x1 - xl).min(LANES as u32) as usize;
                        let (c, t, n) =
                            composite_lanes(list, std::array::from_fn(|l| (xl + l as u32) as f32), py as f32, lanes, |_, _, _| ());
                        for l in 0..lanes {
                            // Entries visited, as an index into the tile's list: the one the
                            // pixel stopped at, or past the end.
                            let n = index.get(n[l] as usize).copied().unwrap_or(local.len() as u32);
                            out.push(([c[0][l], c[1][l], c[2][l]], t[l], n));
                        }
                    }
                }
                out
            },
        )
        .collect();
    img.data
        .par_chunks_mut(band_pix * 3)
        .zip(final_t.par_chunks_mut(band_pix))
        .zip(n_visited.par_chunks_mut(band_pix))
        .enumerate()
        .for_each(|(ty, ((band, band_t), band_n))| {
            for tx in 0..bins.tiles_x {
                let (x0, x1) = (tx * TILE, ((tx + 1) * TILE).min(w));
                let tile = &tiles[ty * bins.tiles_x as usize + tx as usize];
                for (i, &(c, t, n)) in tile.iter().enumerate() {
                    let (ly, x) = (i as u32 / (x1 - x0), x0 + i as u32 % (x1 - x0));
                    let p = (ly * w + x) as usize;
                    for k in 0..3 {
                        band[p * 3 + k] = c[k] + t * opts.background[k];
                    }
                    band_t[p] = t;
                    band_n[p] = n;
                }
            }
        });
    let t3 = Instant::now();
    let degree = opts.max_sh_degree.min(splats.sh_degree);
    let timings = ForwardTimings { project: (t1 - t0).as_secs_f64(), sort: (t2 - t1).as_secs_f64(), rasterize: (t3 - t2).as_secs_f64() };
    (img, RasterState { camera: *cam, options: *opts, degree, projected, bins, cull, reach, final_t, n_visited }, timings)
}

//! Tile-based CPU rasterizer (rayon): project every Gaussian, bin it into the 16x16 screen tiles its
//! 3σ rectangle touches, depth-sort each tile's list, then composite front to back per pixel.

use super::{Image, RenderOptions};
use crate::camera::Camera;
use crate::math::{self, MAX_ALPHA, MIN_ALPHA, MIN_TRANSMITTANCE, TILE};
use crate::splats::Splats;
use glam::Vec3;
use rayon::prelude::*;

/// A Gaussian after projection to the screen. Culled Gaussians have `radius == 0`.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Projected {
    /// Centre in continuous image coordinates (pixel `(i, j)` has its centre at `(i+0.5, j+0.5)`).
    pub mean: [f32; 2],
    /// Inverse 2D covariance `[A, B, C]`.
    pub conic: [f32; 3],
    /// Camera-space depth of the centre.
    pub depth: f32,
    /// 3σ radius in pixels (0 = culled).
    pub radius: f32,
    /// Opacity after the sigmoid.
    pub opacity: f32,
    /// RGB from the SH (+0.5, clamped at 0).
    pub color: [f32; 3],
}

/// Projects one Gaussian; culled (near plane, singular covariance, off-screen) gives `radius = 0`.
fn project_one(splats: &Splats, i: usize, cam: &Camera, center: Vec3, degree: u8) -> Projected {
    let pos = Vec3::from_array(splats.positions[i]);
    let t = cam.to_camera(pos);
    if !(t.z > cam.znear) {
        return Projected::default();
    }
    let cov3d = math::covariance_3d(splats.log_scales[i], splats.rotations[i]);
    let Some((conic, radius)) = math::conic_and_radius(math::project_cov2d(cam, t, &cov3d)) else {
        return Projected::default();
    };
    let mean = [cam.fx * t.x / t.z + cam.cx, cam.fy * t.y / t.z + cam.cy];
    if !(mean[0].is_finite() && mean[1].is_finite()) {
        return Projected::default();
    }
    let r = math::tile_rect(mean, radius, cam.width, cam.height);
    if r[2] <= r[0] || r[3] <= r[1] {
        return Projected::default();
    }
    Projected {
        mean,
        conic,
        depth: t.z,
        radius,
        opacity: math::sigmoid(splats.opacity_logits[i]),
        color: color_of(splats, i, center, degree),
    }
}

/// The colour of Gaussian `i` seen from a camera at `center` (SH up to `degree`).
fn color_of(splats: &Splats, i: usize, center: Vec3, degree: u8) -> [f32; 3] {
    let k = math::sh_rest_coeffs(degree);
    let k_all = splats.rest_coeffs();
    let rest = &splats.sh_rest[i * k_all * 3..(i * k_all + k) * 3];
    math::sh_color(degree, splats.sh_dc[i], rest, math::view_dir(center, Vec3::from_array(splats.positions[i])))
}

/// Projects all Gaussians (in parallel).
pub fn preprocess(splats: &Splats, cam: &Camera, max_sh_degree: u8) -> Vec<Projected> {
    let degree = max_sh_degree.min(splats.sh_degree);
    let center = cam.center();
    (0..splats.len()).into_par_iter().map(|i| project_one(splats, i, cam, center, degree)).collect()
}

/// Per-tile, depth-sorted Gaussian index lists.
#[derive(Debug, Clone, Default)]
pub struct TileBins {
    /// Tiles per row.
    pub tiles_x: u32,
    /// Tile rows.
    pub tiles_y: u32,
    /// `ranges[t]..ranges[t+1]` indexes `ids` for tile `t = ty * tiles_x + tx`.
    pub ranges: Vec<u32>,
    /// Gaussian indices, front to back within each tile (ties broken by index).
    pub ids: Vec<u32>,
}

impl TileBins {
    /// The Gaussians of tile `t`, front to back.
    pub fn tile(&self, t: usize) -> &[u32] {
        &self.ids[self.ranges[t] as usize..self.ranges[t + 1] as usize]
    }
}

/// Bins projected Gaussians into screen tiles, each list sorted by depth (stable on index).
pub fn bin_tiles(proj: &[Projected], width: u32, height: u32) -> TileBins {
    let (tiles_x, tiles_y) = (width.div_ceil(TILE), height.div_ceil(TILE));
    let n_tiles = (tiles_x * tiles_y) as usize;
    let rects: Vec<([u32; 4], f32)> = proj
        .par_iter()
        .map(|p| (if p.radius > 0.0 { math::tile_rect(p.mean, p.radius, width, height) } else { [0; 4] }, math::alpha_level(p.opacity)))
        .collect();
    // A Gaussian is listed in a tile only if it can reach alpha >= 1/255 at one of its pixels.
    let reaches = |p: &Projected, level: f32, tx: u32, ty: u32| {
        let (x0, y0) = (tx * TILE, ty * TILE);
        let bx = [x0 as f32, y0 as f32, ((x0 + TILE).min(width) - 1) as f32, ((y0 + TILE).min(height) - 1) as f32];
        math::reaches_box_with(p.mean, p.conic, p.opacity, level, bx)
    };
    // Bands of tile rows are binned in parallel, each scanning every rectangle in index order
    // (a list of (tile, id) pairs, then a counting sort by tile), so every tile's list holds its
    // Gaussians in ascending index order whatever the banding and the thread count.
    let n_bands = (rayon::current_num_threads() * 4).clamp(1, tiles_y.max(1) as usize) as u32;
    let bands: Vec<(Vec<u32>, Vec<u32>)> = (0..n_bands)
        .into_par_iter()
        .map(|b| {
            let (y0, y1) = (tiles_y * b / n_bands, tiles_y * (b + 1) / n_bands);
            let first = y0 * tiles_x;
            let mut pairs: Vec<(u32, u32)> = Vec::new();
            for (g, (p, (r, level))) in proj.iter().zip(&rects).enumerate() {
                for ty in r[1].max(y0)..r[3].min(y1) {
                    for tx in r[0]..r[2] {
                        if reaches(p, *level, tx, ty) {
                            pairs.push((ty * tiles_x + tx - first, g as u32));
                        }
                    }
                }
            }
            // Local ranges (counts, then their prefix sums) and ids of the band's tiles.
            let mut ranges = vec![0u32; ((y1 - y0) * tiles_x) as usize + 1];
            for &(t, _) in &pairs {
                ranges[t as usize + 1] += 1;
            }
            for t in 1..ranges.len() {
                ranges[t] += ranges[t - 1];
            }
            let mut cursor = ranges.clone();
            let mut ids = vec![0u32; pairs.len()];
            for (t, g) in pairs {
                ids[cursor[t as usize] as usize] = g;
                cursor[t as usize] += 1;
            }
            (ranges, ids)
        })
        .collect();
    let mut ranges = Vec::with_capacity(n_tiles + 1);
    ranges.push(0u32);
    let mut ids = Vec::with_capacity(bands.iter().map(|b| b.1.len()).sum());
    for (r, i) in bands {
        let base = ids.len() as u32;
        ranges.extend(r[1..].iter().map(|v| v + base));
        ids.extend_from_slice(&i);
    }
    // Ids are ascending within a tile, so a stable sort on depth breaks ties by index.
    let mut chunks: Vec<&mut [u32]> = Vec::with_capacity(n_tiles);
    let mut rest: &mut [u32] = &mut ids;
    for t in 0..n_tiles {
        let (head, tail) = rest.split_at_mut((ranges[t + 1] - ranges[t]) as usize);
        chunks.push(head);
        rest = tail;
    }
    chunks.into_par_iter().for_each(|c| c.sort_by(|&a, &b| proj[a as usize].depth.total_cmp(&proj[b as usize].depth)));
    TileBins { tiles_x, tiles_y, ranges, ids }
}

/// A projected Gaussian copied into a tile's contiguous working list.
#[derive(Debug, Clone, Copy, Default)]
pub struct TileGaussian {
    /// `mean - 0.5`: the centre in pixel-index coordinates.
    pub mx: f32,
    /// `mean - 0.5` along y.
    pub my: f32,
    /// Inverse 2D covariance `[A, B, C]`.
    pub conic: [f32; 3],
    /// Opacity after the sigmoid.
    pub opacity: f32,
    /// Below this `power` the alpha is certainly under [`MIN_ALPHA`]: skip without `exp`.
    pub cull: f32,
    /// RGB.
    pub color: [f32; 3],
}

/// Per Gaussian, a `power` below which `opacity · exp(power) < MIN_ALPHA` for sure. The 1e-3
/// margin dwarfs the rounding of `ln`/`exp`, so skipping there changes no decision: the image is
/// exactly the one that evaluating `exp` for every pair gives.
pub fn cull_thresholds(proj: &[Projected]) -> Vec<f32> {
    proj.iter().map(|p| if p.opacity > 0.0 { (MIN_ALPHA / p.opacity).ln() - 1e-3 } else { f32::INFINITY }).collect()
}

/// Copies a tile's depth-sorted Gaussians into `out` (contiguous, for cache-friendly reuse by
/// all pixels of the tile).
pub fn gather_tile(proj: &[Projected], cull: &[f32], ids: &[u32], out: &mut Vec<TileGaussian>) {
    out.clear();
    out.extend(ids.iter().map(|&g| {
        let p = &proj[g as usize];
        TileGaussian {
            mx: p.mean[0] - 0.5,
            my: p.mean[1] - 0.5,
            conic: p.conic,
            opacity: p.opacity,
            cull: cull[g as usize],
            color: p.color,
        }
    }));
}

/// Side, in pixels, of the blocks that [`shade`], [`record`] and the training passes cut a tile
/// into: a block's row is one [`composite_lanes`] call.
const BLOCK: u32 = LANES as u32;

/// A tile's gathered list cut per [`BLOCK`]×[`BLOCK`] block of pixels: each block keeps the
/// entries whose reach overlaps it, in the tile's order. An entry's reach is the bounding box of
/// the ellipse where `opacity·exp(power) ≥ 1/255` (`q ≤ 2·ln(255·opacity)`, half-widths
/// `√(2 ln(255·opacity)·Σ_xx)` and `√(… Σ_yy)` with `Σ` the inverse of the conic), widened
/// (level +2 % and +1e-5 of its terms' magnitude, half-widths +1 % and +0.01 px) far beyond what
/// f32 rounding in [`composite_with`] can move a blended pixel. An entry left out of a block is thus one that every pixel of the block skips anyway, so
/// compositing a pixel over its block's list blends exactly what compositing it over the tile's
/// list blends, in the same order: the same colour and weights, bit for bit, with fewer entries
/// to visit.
#[derive(Default)]
pub struct TileBlocks {
    /// Per block (row-major within the tile): the entries and their indices in the tile's list.
    lists: Vec<(Vec<TileGaussian>, Vec<u32>)>,
    /// Blocks per row of the tile.
    per_row: u32,
}

/// Per projected Gaussian, the half-widths along x and y of its reach as [`TileBlocks`] defines
/// it (`None`: below 1/255 everywhere, never blended). A Gaussian's reach is the same in every
/// tile, so it is computed once per frame rather than once per tile it is listed in.
pub fn block_reaches(proj: &[Projected]) -> Vec<Option<[f64; 2]>> {
    proj.par_iter()
        .map(|p| {
            let level = 2.0 * (f64::from(p.opacity) / f64::from(MIN_ALPHA)).ln();
            if !(level > 0.0) {
                return None;
            }
            let [a, b, c] = p.conic.map(f64::from);
            let det = a * c - b * b;
            // The f32 rounding of `power` is below 1e-7 of the magnitude of its terms, which
            // within the ellipse's box are at most `terms`: the level is raised by 1e-5 of that.
            let (hx, hy) = ((level * c / det).sqrt(), (level * a / det).sqrt());
            let terms = a * hx * hx + c * hy * hy + 2.0 * b.abs() * hx * hy;
            let level = level * 1.02 + 1e-5 * terms;
            let half =
                |s: f64| if det > 0.0 && s > 0.0 && level.is_finite() { (level * s / det).sqrt() * 1.01 + 0.01 } else { f64::INFINITY };
            Some([half(c), half(a)])
        })
        .collect()
}

impl TileBlocks {
    /// Cuts `local`, the gathered list of tile (`tx`, `ty`) of a `width`×`height` frame, whose
    /// entries are Gaussians `ids` with reaches `reach[id]` ([`block_reaches`]).
    pub fn cut(
        &mut self,
        local: &[TileGaussian],
        ids: &[u32],
        reach: &[Option<[f64; 2]>],
        (tx, ty): (u32, u32),
        (width, height): (u32, u32),
    ) {
        let (x0, y0) = (tx * TILE, ty * TILE);
        let (x1, y1) = ((x0 + TILE).min(width), (y0 + TILE).min(height));
        let (nx, ny) = ((x1 - x0).div_ceil(BLOCK), (y1 - y0).div_ceil(BLOCK));
        self.per_row = nx;
        self.lists.resize_with((nx * ny) as usize, Default::default);
        for (list, index) in &mut self.lists {
            list.clear();
            index.clear();
        }
        // The blocks (first, last) along one axis that [centre − half, centre + half] overlaps.
        let span = |centre: f64, half: f64, origin: u32, n: u32| -> Option<(u32, u32)> {
            let (lo, hi) = ((centre - half - f64::from(origin)) / f64::from(BLOCK), (centre + half - f64::from(origin)) / f64::from(BLOCK));
            if !(hi >= 0.0 && lo < f64::from(n)) {
                return if lo.is_nan() || hi.is_nan() { Some((0, n - 1)) } else { None };
            }
            // Both ends are ≥ 0 here, where truncation is the floor.
            Some((lo.max(0.0) as u32, hi.min(f64::from(n - 1)) as u32))
        };
        for (j, (g, &id)) in local.iter().zip(ids).enumerate() {
            let Some([half_x, half_y]) = reach[id as usize] else {
                continue; // below 1/255 everywhere: never blended
            };
            let (Some(bx), Some(by)) = (span(f64::from(g.mx), half_x, x0, nx), span(f64::from(g.my), half_y, y0, ny)) else {
                continue;
            };
            for yb in by.0..=by.1 {
                for xb in bx.0..=bx.1 {
                    let (list, index) = &mut self.lists[(yb * nx + xb) as usize];
                    list.push(*g);
                    index.push(j as u32);
                }
            }
        }
    }

    /// The list and tile-list indices of the block holding pixel (`lx`, `ly`) of the tile.
    pub fn at(&self, lx: u32, ly: u32) -> (&[TileGaussian], &[u32]) {
        let (list, index) = &self.lists[((ly / BLOCK) * self.per_row + lx / BLOCK) as usize];
        (list, index)
    }
}

/// Composites one pixel (pixel-index coordinates `px, py`) front to back over a gathered,
/// depth-sorted tile list. Returns the colour, the final transmittance and the number of list
/// entries visited (what a backward pass needs to walk the list back).
#[inline]
pub fn composite(list: &[TileGaussian], px: f32, py: f32) -> ([f32; 3], f32, u32) {
    composite_with(list, px, py, |_, _, _| ())
}

/// [`composite`], also calling `blend(j, α, T)` for every list entry `j` that is blended in, with
/// its alpha and the transmittance in front of it: its blending weight `α·T` is the share of the
/// pixel it covers. The weights of a pixel sum to `1 − T_final` up to rounding.
#[inline]
pub fn composite_with(list: &[TileGaussian], px: f32, py: f32, mut blend: impl FnMut(usize, f32, f32)) -> ([f32; 3], f32, u32) {
    let mut c = [0.0f32; 3];
    let mut t = 1.0f32;
    for (j, p) in list.iter().enumerate() {
        let (dx, dy) = (p.mx - px, p.my - py);
        let power = -0.5 * (p.conic[0] * dx * dx + p.conic[2] * dy * dy) - p.conic[1] * dx * dy;
        if power > 0.0 || power < p.cull {
            continue;
        }
        let alpha = MAX_ALPHA.min(p.opacity * power.exp());
        if alpha < MIN_ALPHA {
            continue;
        }
        let next_t = t * (1.0 - alpha);
        if next_t < MIN_TRANSMITTANCE {
            return (c, t, j as u32);
        }
        for k in 0..3 {
            c[k] += p.color[k] * alpha * t;
        }
        blend(j, alpha, t);
        t = next_t;
    }
    (c, t, list.len() as u32)
}

/// Pixels [`composite_lanes`] composites side by side.
pub const LANES: usize = 4;

/// [`composite_with`] for the first `lanes` (≤ [`LANES`]) of the pixels `px` of one row `py`:
/// each pixel's colour (per channel, per pixel), final transmittance and entries visited, bit
/// for bit what [`composite`] gives it, calling `blend(j, α, T)` for every entry `j` blended
/// into a pixel, the pixels of an entry in order. The pixels share the list's
/// loads and the arithmetic that the target can do in vectors.
#[inline]
pub fn composite_lanes(
    list: &[TileGaussian],
    px: [f32; LANES],
    py: f32,
    lanes: usize,
    mut blend: impl FnMut(usize, f32, f32),
) -> ([[f32; LANES]; 3], [f32; LANES], [u32; LANES]) {
    let mut c = [[0.0f32; LANES]; 3];
    let mut t = [1.0f32; LANES];
    let mut visited = [list.len() as u32; LANES];
    let mut live: [bool; LANES] = std::array::from_fn(|l| l < lanes);
    for (j, p) in list.iter().enumerate() {
        let mut power = [0.0f32; LANES];
        let mut pass = [false; LANES];
        for l in 0..LANES {
            let (dx, dy) = (p.mx - px[l], p.my - py);
            power[l] = -0.5 * (p.conic[0] * dx * dx + p.conic[2] * dy * dy) - p.conic[1] * dx * dy;
            pass[l] = live[l] & !(power[l] > 0.0 || power[l] < p.cull);
        }
        if pass == [false; LANES] {
            continue;
        }
        for l in 0..LANES {
            if !pass[l] {
                continue;
            }
            let alpha = MAX_ALPHA.min(p.opacity * power[l].exp());
            if alpha < MIN_ALPHA {
                continue;
            }
            let next_t = t[l] * (1.0 - alpha);
            if next_t < MIN_TRANSMITTANCE {
                (live[l], visited[l]) = (false, j as u32);
                continue;
            }
            for k in 0..3 {
                c[k][l] += p.color[k] * alpha * t[l];
            }
            blend(j, alpha, t[l]);
            t[l] = next_t;
        }
        if live == [false; LANES] {
            break;
        }
    }
    (c, t, visited)
}

/// Renders `splats` from `cam` with the reference 3DGS semantics (see DESIGN §3).
pub fn render(splats: &Splats, cam: &Camera, opts: &RenderOptions) -> Image {
    let proj = preprocess(splats, cam, opts.max_sh_degree);
    let bins = bin_tiles(&proj, cam.width, cam.height);
    shade::<NO_RECORD>(&proj, &bins, cam, opts, &mut [])
}

/// For every Gaussian of `splats`, the sum over the pixels of the frame [`render`] draws from
/// `cam` of its blending weight `α·T` there: the area (in pixels) it covers in the image, after
/// occlusion. The same culling, the same `α < 1/255` skip and the same early stop as the render;
/// summed over the Gaussians it equals `Σ_pixels (1 − T_final)` up to rounding. Deterministic:
/// weights are summed per tile-list entry, then per Gaussian in tile-list order (in f64).
pub fn contributions(splats: &Splats, cam: &Camera, opts: &RenderOptions) -> Vec<f32> {
    let [weights] = per_gaussian::<RECORD_WEIGHT, 1>(splats, cam, opts);
    weights
}

/// For every Gaussian of `splats`, the squared colour error that removing it alone would cause in
/// the frame [`render`] draws from `cam`: `Σ_pixels ‖T·α·(B − c)‖²`, with `T` the transmittance in
/// front of it, `α` its alpha and `c` its colour at the pixel, and `B` the colour behind it (what
/// is composited after it, the background included), which is exactly how much the pixel changes
/// without it (up to what the early stop hides). The same culling, skip and early stop as the
/// render; deterministic like [`contributions`].
pub fn removal_errors(splats: &Splats, cam: &Camera, opts: &RenderOptions) -> Vec<f32> {
    contributions_and_removal_errors(splats, cam, opts).1
}

/// [`contributions`] and [`removal_errors`] from one pass over the pixels (the same values as
/// the two calls: the weights do not depend on colour).
pub fn contributions_and_removal_errors(splats: &Splats, cam: &Camera, opts: &RenderOptions) -> (Vec<f32>, Vec<f32>) {
    let [weights, errors] = per_gaussian::<RECORD_REMOVAL, 2>(splats, cam, opts);
    (weights, errors)
}

/// What [`shade`] records in mode `MODE` for each tile-list entry (`SLOTS` values each), summed
/// per Gaussian in tile-list order (in f64): one vector per slot.
fn per_gaussian<const MODE: u8, const SLOTS: usize>(splats: &Splats, cam: &Camera, opts: &RenderOptions) -> [Vec<f32>; SLOTS] {
    let proj = preprocess(splats, cam, opts.max_sh_degree);
    let bins = bin_tiles(&proj, cam.width, cam.height);
    const { assert!(SLOTS == slots(MODE)) };
    let mut records = vec![0.0f32; SLOTS * bins.ids.len()];
    shade::<MODE>(&proj, &bins, cam, opts, &mut records);
    std::array::from_fn(|slot| {
        let mut sum = vec![0.0f64; splats.len()];
        for (&g, r) in bins.ids.iter().zip(records.chunks_exact(SLOTS)) {
            sum[g as usize] += r[slot] as f64;
        }
        sum.into_iter().map(|v| v as f32).collect()
    })
}

/// What [`shade`] records per tile-list entry: nothing (a plain render), the blending weight
/// `α·T` ([`contributions`]), or that weight and the squared colour error of removing the entry
/// ([`contributions_and_removal_errors`]).
const NO_RECORD: u8 = 0;
const RECORD_WEIGHT: u8 = 1;
const RECORD_REMOVAL: u8 = 2;

/// Values [`shade`] records per tile-list entry in mode `mode`.
const fn slots(mode: u8) -> usize {
    match mode {
        NO_RECORD => 0,
        RECORD_WEIGHT => 1,
        _ => 2,
    }
}

/// Composites every pixel, one task per row of tiles. In a recording `MODE`, also adds what it
/// records of each blended entry into `records[slots(MODE)·k ..]`, `k` indexing `bins.ids`
/// (`records` is then `slots(MODE) · bins.ids.len()` long, otherwise empty): its weight, then
/// (in `RECORD_REMOVAL`) its removal error.
fn shade<const MODE: u8>(proj: &[Projected], bins: &TileBins, cam: &Camera, opts: &RenderOptions, records: &mut [f32]) -> Image {
    let w = cam.width;
    let (cull, reach) = (cull_thresholds(proj), block_reaches(proj));
    let mut img = Image::filled(w, cam.height, [0.0; 3]);
    let row_len = (w * 3) as usize;
    let slots = slots(MODE);
    // The tile-list entries of each row of tiles: disjoint slices of `records`.
    let mut bands: Vec<&mut [f32]> = Vec::with_capacity(bins.tiles_y as usize);
    let mut rest = records;
    for ty in 0..bins.tiles_y {
        let row = |ty: u32| bins.ranges[(ty * bins.tiles_x) as usize] as usize;
        let len = slots * (row(ty + 1) - row(ty));
        let (head, tail) = std::mem::take(&mut rest).split_at_mut(len);
        bands.push(head);
        rest = tail;
    }
    // Rows of pixels are disjoint slices of the output.
    img.data.par_chunks_mut(row_len * TILE as usize).zip(bands).enumerate().for_each(|(ty, (band, band_w))| {
        let ty = ty as u32;
        let band_start = bins.ranges[(ty * bins.tiles_x) as usize];
        let mut local = Vec::new();
        let mut blocks = TileBlocks::default();
        for tx in 0..bins.tiles_x {
            let t = (ty * bins.tiles_x + tx) as usize;
            gather_tile(proj, &cull, bins.tile(t), &mut local);
            blocks.cut(&local, bins.tile(t), &reach, (tx, ty), (w, cam.height));
            let offset = (bins.ranges[t] - band_start) as usize;
            let x1 = ((tx + 1) * TILE).min(w);
            for (ly, row) in band.chunks_mut(row_len).enumerate() {
                let py = (ty * TILE + ly as u32) as f32;
                // A block's row is `LANES` pixels wide (or fewer at the frame's edge).
                for x0 in (tx * TILE..x1).step_by(LANES) {
                    let (list, index) = blocks.at(x0 - tx * TILE, ly as u32);
                    let lanes = (x1 - x0).min(LANES as u32) as usize;
                    let px = std::array::from_fn(|l| (x0 + l as u32) as f32);
                    let (c, t, _) = composite_lanes(list, px, py, lanes, |j, a, t| {
                        if MODE != NO_RECORD {
                            band_w[slots * (offset + index[j] as usize)] += a * t;
                        }
                    });
                    for l in 0..lanes {
                        let fin: [f32; 3] = std::array::from_fn(|k| c[k][l] + t[l] * opts.background[k]);
                        if MODE == RECORD_REMOVAL {
                            // ΔC of removing entry j: T·α·(B − c), B the colour behind it, from
                            // T·(1 − α)·B = C_final − (C in front of j, j included).
                            let mut front = [0.0f32; 3];
                            composite_with(list, px[l], py, |j, a, t| {
                                let col = list[j].color;
                                let mut e = 0.0;
                                for k in 0..3 {
                                    front[k] += col[k] * a * t;
                                    let d = a / (1.0 - a) * (fin[k] - front[k]) - t * a * col[k];
                                    e += d * d;
                                }
                                band_w[slots * (offset + index[j] as usize) + 1] += e;
                            });
                        }
                        row[(x0 as usize + l) * 3..][..3].copy_from_slice(&fin);
                    }
                }
            }
        }
    });
    img
}

/// What compositing a frame blended at every pixel, in order: enough to composite the frame
/// again with other colours while no Gaussian moves ([`replay`]). Made by [`record`].
#[derive(Debug, Clone)]
pub struct Recording {
    width: u32,
    height: u32,
    /// Per row of tiles (the bands [`render`] shades in parallel), per pixel in the band's order:
    /// the end of its entries in `entries` and its final transmittance.
    bands: Vec<(Vec<(u32, f32)>, Vec<Blend>)>,
}

/// One Gaussian blended into a pixel: its index, its alpha and the transmittance in front of it.
#[derive(Debug, Clone, Copy)]
struct Blend {
    id: u32,
    alpha: f32,
    t: f32,
}

impl Recording {
    /// Bytes held (for callers that bound their memory).
    pub fn bytes(&self) -> usize {
        self.bands.iter().map(|(p, e)| p.len() * 8 + e.len() * 12).sum()
    }
}

/// [`render`], also recording what every pixel blended ([`Recording`]).
pub fn record(splats: &Splats, cam: &Camera, opts: &RenderOptions) -> (Image, Recording) {
    let proj = preprocess(splats, cam, opts.max_sh_degree);
    let bins = bin_tiles(&proj, cam.width, cam.height);
    let w = cam.width;
    let (cull, reach) = (cull_thresholds(&proj), block_reaches(&proj));
    let mut img = Image::filled(w, cam.height, [0.0; 3]);
    let row_len = (w * 3) as usize;
    let bands = img
        .data
        .par_chunks_mut(row_len * TILE as usize)
        .enumerate()
        .map(|(ty, band)| {
            let ty = ty as u32;
            let (mut pixels, mut entries) = (Vec::new(), Vec::new());
            let mut local = Vec::new();
            let mut blocks = TileBlocks::default();
            for tx in 0..bins.tiles_x {
                let t = (ty * bins.tiles_x + tx) as usize;
                let ids = bins.tile(t);
                gather_tile(&proj, &cull, ids, &mut local);
                blocks.cut(&local, ids, &reach, (tx, ty), (w, cam.height));
                let x1 = ((tx + 1) * TILE).min(w);
                for (ly, row) in band.chunks_mut(row_len).enumerate() {
                    let py = (ty * TILE + ly as u32) as f32;
                    for x in tx * TILE..x1 {
                        let (list, index) = blocks.at(x - tx * TILE, ly as u32);
                        let (c, t, _) =
                            composite_with(list, x as f32, py, |j, alpha, t| entries.push(Blend { id: ids[index[j] as usize], alpha, t }));
                        pixels.push((entries.len() as u32, t));
                        for k in 0..3 {
                            row[x as usize * 3 + k] = c[k] + t * opts.background[k];
                        }
                    }
                }
            }
            (pixels, entries)
        })
        .collect();
    (img, Recording { width: w, height: cam.height, bands })
}

/// The frame [`render`] draws of `splats` from `cam`, given the [`Recording`] of a frame of a
/// scene with the same geometry (positions, scales, rotations, opacities: only colours, i.e. SH
/// coefficients or degree, may differ) from the same camera: bit-identical to [`render`], without
/// projecting, binning or evaluating a Gaussian again.
///
/// # Panics
/// If the recording is not of `cam`'s size.
pub fn replay(rec: &Recording, splats: &Splats, cam: &Camera, opts: &RenderOptions) -> Image {
    assert_eq!((rec.width, rec.height), (cam.width, cam.height), "a recording of this camera");
    let degree = opts.max_sh_degree.min(splats.sh_degree);
    let center = cam.center();
    let colors: Vec<[f32; 3]> = (0..splats.len()).into_par_iter().map(|i| color_of(splats, i, center, degree)).collect();
    let w = cam.width;
    let row_len = (w * 3) as usize;
    let mut img = Image::filled(w, cam.height, [0.0; 3]);
    img.data.par_chunks_mut(row_len * TILE as usize).zip(&rec.bands).for_each(|(band, (pixels, entries))| {
        let mut next = pixels.iter();
        let mut start = 0usize;
        // The pixels in the order `record` visited them: tile by tile, row by row within a tile.
        for tx in 0..w.div_ceil(TILE) {
            let x1 = ((tx + 1) * TILE).min(w);
            for row in band.chunks_mut(row_len) {
                for x in tx * TILE..x1 {
                    let &(end, t) = next.next().expect("one entry per pixel");
                    let mut c = [0.0f32; 3];
                    for b in &entries[start..end as usize] {
                        let color = colors[b.id as usize];
                        for k in 0..3 {
                            c[k] += color[k] * b.alpha * b.t;
                        }
                    }
                    start = end as usize;
                    for k in 0..3 {
                        row[x as usize * 3 + k] = c[k] + t * opts.background[k];
                    }
                }
            }
        }
    });
    img
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testkit::{extreme_splats, random_splats, rig_cameras};

    /// `n` random Gaussians of SH degree `degree`, then the extreme ones.
    fn random_and_extreme_splats(n: usize, degree: u8, seed: u64) -> Splats {
        let mut s = random_splats(n, degree, seed);
        let extreme = extreme_splats(degree);
        for i in 0..extreme.len() {
            s.push(
                extreme.positions[i],
                extreme.log_scales[i],
                extreme.rotations[i],
                extreme.opacity_logits[i],
                extreme.sh_dc[i],
                extreme.rest_of(i),
            );
        }
        s
    }

    /// Compositing over a tile's blocks ([`TileBlocks`]) gives, bit for bit, the image and the
    /// contributions that compositing every pixel over its whole tile list gives.
    #[test]
    fn blocks_change_no_pixel_and_no_contribution() {
        let s = random_and_extreme_splats(600, 2, 5);
        let opts = RenderOptions { background: [0.3, 0.1, 0.6], ..RenderOptions::default() };
        for cam in rig_cameras(4, 3.5, 53, 38) {
            let proj = preprocess(&s, &cam, opts.max_sh_degree);
            let bins = bin_tiles(&proj, cam.width, cam.height);
            let cull = cull_thresholds(&proj);
            let mut img = Image::filled(cam.width, cam.height, [0.0; 3]);
            let mut sum = vec![0.0f64; s.len()];
            let mut local = Vec::new();
            for ty in 0..bins.tiles_y {
                for tx in 0..bins.tiles_x {
                    let t = (ty * bins.tiles_x + tx) as usize;
                    gather_tile(&proj, &cull, bins.tile(t), &mut local);
                    let mut w = vec![0.0f32; local.len()];
                    for y in ty * TILE..((ty + 1) * TILE).min(cam.height) {
                        for x in tx * TILE..((tx + 1) * TILE).min(cam.width) {
                            let (c, t, _) = composite_with(&local, x as f32, y as f32, |j, a, t| w[j] += a * t);
                            let i = ((y * cam.width + x) * 3) as usize;
                            for k in 0..3 {
                                img.data[i + k] = c[k] + t * opts.background[k];
                            }
                        }
                    }
                    for (&g, &v) in bins.tile(t).iter().zip(&w) {
                        sum[g as usize] += v as f64;
                    }
                }
            }
            assert_eq!(render(&s, &cam, &opts).data, img.data);
            let want: Vec<f32> = sum.into_iter().map(|v| v as f32).collect();
            assert_eq!(contributions(&s, &cam, &opts), want);
            assert!(want.iter().filter(|&&v| v > 0.0).count() > 100);
        }
    }

    /// Compositing `LANES` pixels side by side gives each pixel what compositing it alone gives:
    /// colour, final transmittance and entries visited, bit for bit, whether a pixel stops
    /// early (transmittance spent) or walks its whole list.
    #[test]
    fn pixels_side_by_side_are_pixels_alone() {
        let s = random_and_extreme_splats(800, 2, 17);
        let (mut stopped, mut walked) = (0, 0);
        for cam in rig_cameras(3, 3.0, 50, 35) {
            let proj = preprocess(&s, &cam, 3);
            let bins = bin_tiles(&proj, cam.width, cam.height);
            let cull = cull_thresholds(&proj);
            let mut local = Vec::new();
            for t in 0..(bins.tiles_x * bins.tiles_y) as usize {
                gather_tile(&proj, &cull, bins.tile(t), &mut local);
                let (tx, ty) = (t as u32 % bins.tiles_x, t as u32 / bins.tiles_x);
                for y in ty * TILE..(ty + 1) * TILE {
                    for x0 in (tx * TILE..(tx + 1) * TILE).step_by(LANES) {
                        let px: [f32; LANES] = std::array::from_fn(|l| (x0 as usize + l) as f32);
                        let (c, tr, n) = composite_lanes(&local, px, y as f32, LANES, |_, _, _| ());
                        for l in 0..LANES {
                            let (c1, t1, n1) = composite(&local, px[l], y as f32);
                            assert_eq!(
                                (c1.map(f32::to_bits), t1.to_bits(), n1),
                                ([c[0][l], c[1][l], c[2][l]].map(f32::to_bits), tr[l].to_bits(), n[l])
                            );
                            if (n1 as usize) < local.len() {
                                stopped += 1;
                            } else if n1 > 0 {
                                walked += 1;
                            }
                        }
                    }
                }
            }
        }
        assert!(stopped > 100 && walked > 100, "{stopped} pixels stopped early, {walked} walked their list");
    }

    /// A Gaussian's removal error is the squared change of the frame when it alone is left out:
    /// each compared with a render of the scene without it.
    #[test]
    fn removal_errors_are_what_leaving_one_out_changes() {
        let s = random_splats(80, 1, 23);
        let opts = RenderOptions { background: [0.3, 0.5, 0.2], ..RenderOptions::default() };
        let cam = rig_cameras(1, 3.5, 45, 38)[0];
        let full = render(&s, &cam, &opts);
        let errors = removal_errors(&s, &cam, &opts);
        let mut seen = 0;
        for (i, &e) in errors.iter().enumerate() {
            let mut without = s.clone();
            without.retain_indices(|k| k != i);
            let change: f64 = full.data.iter().zip(&render(&without, &cam, &opts).data).map(|(a, b)| f64::from(a - b).powi(2)).sum();
            assert!(
                (f64::from(e) - change).abs() <= 1e-3 * change + 1e-7,
                "Gaussian {i}: removal error {e}, leaving it out changes {change}"
            );
            seen += usize::from(change > 1e-3);
        }
        assert!(seen > 20, "only {seen} Gaussians change the frame");
    }

    /// A recording's frame is `render`'s, and replaying it with other colours (SH coefficients
    /// and degree changed, geometry kept) gives exactly the frame `render` draws of that scene,
    /// at a size that is not a whole number of tiles.
    #[test]
    fn replay_is_render_with_new_colours() {
        let s = random_and_extreme_splats(400, 3, 11);
        let opts = RenderOptions { background: [0.2, 0.4, 0.1], ..RenderOptions::default() };
        for cam in rig_cameras(3, 3.8, 45, 37) {
            let (img, rec) = record(&s, &cam, &opts);
            assert_eq!(img.data, render(&s, &cam, &opts).data);
            assert!(rec.bytes() > 45 * 37 * 8);
            let mut recoloured = s.clone();
            recoloured.sh_dc.iter_mut().enumerate().for_each(|(i, c)| c[i % 3] = -c[i % 3] * 0.7 + 0.1);
            recoloured.sh_rest.iter_mut().step_by(5).for_each(|v| *v *= -1.5);
            let again = replay(&rec, &recoloured, &cam, &opts);
            assert_ne!(again.data, img.data);
            assert_eq!(again.data, render(&recoloured, &cam, &opts).data);
            let sh1 = recoloured.with_sh_degree(1);
            assert_eq!(replay(&rec, &sh1, &cam, &opts).data, render(&sh1, &cam, &opts).data);
        }
    }
}

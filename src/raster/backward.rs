//! Analytic backward pass of the rasterizer: image gradient -> per-Gaussian 2D gradients (per tile,
//! back to front) -> parameter gradients through the EWA projection, the 3D covariance, the
//! quaternion normalisation, the sigmoid and the SH colour (with its clamp at 0).

use super::RasterState;
use glam::{Mat3, Vec3};
use gscodec_decoder::math::{self, MAX_ALPHA, MIN_ALPHA, SH_C1, SH_C2, SH_C3, TILE};
use gscodec_decoder::render::{gather_tile, TileBlocks};
use gscodec_decoder::Splats;
use rayon::prelude::*;
use std::sync::atomic::{AtomicU32, Ordering::Relaxed};

/// Gradients of a scalar loss with respect to every Gaussian parameter.
#[derive(Debug, Clone, PartialEq)]
pub struct Gradients {
    /// Same shape and layout as the rendered [`Splats`]; SH coefficients above the rendered degree
    /// get zero.
    pub params: Splats,
    /// `|dL/d(mean2d)|` in the reference trainer's NDC units (pixel gradient times `(W/2, H/2)`),
    /// the statistic that drives densification; 0 for Gaussians that were not drawn.
    pub mean2d_ndc_norm: Vec<f32>,
}

/// Gradient w.r.t. the screen-space quantities of one Gaussian.
#[derive(Debug, Clone, Copy, Default)]
struct Grad2d {
    mean: [f32; 2],
    conic: [f32; 3],
    opacity: f32,
    color: [f32; 3],
}

impl Grad2d {
    fn add(&mut self, o: &Grad2d) {
        self.mean[0] += o.mean[0];
        self.mean[1] += o.mean[1];
        for k in 0..3 {
            self.conic[k] += o.conic[k];
            self.color[k] += o.color[k];
        }
        self.opacity += o.opacity;
    }
}

/// Backpropagates `dl_dimg` (`dL/d(pixel)`, interleaved RGB like [`gscodec_decoder::Image`]) through
/// the render that produced `state` from `splats`.
pub fn backward(splats: &Splats, state: &RasterState, dl_dimg: &[f32]) -> Gradients {
    let cam = &state.camera;
    let (w, h) = (cam.width, cam.height);
    assert_eq!(dl_dimg.len(), (w * h * 3) as usize, "image gradient has the wrong size");
    let bins = &state.bins;
    let proj = &state.projected;
    let bg = state.options.background;
    let n_tiles = (bins.tiles_x * bins.tiles_y) as usize;

    // 1. One gradient slot per tile-list entry; each tile fills its own slots.
    let mut entries = vec![Grad2d::default(); bins.ids.len()];
    let chunks = split_at_ranges(&mut entries, &bins.ranges[..=n_tiles]);
    let (cull, reach) = (&state.cull, &state.reach);
    chunks.into_par_iter().enumerate().for_each_init(
        || (Vec::new(), TileBlocks::default()),
        |(local, blocks), (t, out)| {
            let ids = bins.tile(t);
            if ids.is_empty() {
                return;
            }
            gather_tile(proj, cull, ids, local);
            let (tx, ty) = (t as u32 % bins.tiles_x, t as u32 / bins.tiles_x);
            // Each pixel walks its block's entries (those of its tile that can reach it, in the
            // tile's order) that the forward pass visited.
            blocks.cut(local, ids, reach, (tx, ty), (w, h));
            for y in ty * TILE..((ty + 1) * TILE).min(h) {
                for x in tx * TILE..((tx + 1) * TILE).min(w) {
                    let p = (y * w + x) as usize;
                    let (list, index) = blocks.at(x - tx * TILE, y - ty * TILE);
                    let n = index.partition_point(|&j| j < state.n_visited[p]);
                    if n == 0 {
                        continue;
                    }
                    let dl = [dl_dimg[p * 3], dl_dimg[p * 3 + 1], dl_dimg[p * 3 + 2]];
                    let t_final = state.final_t[p];
                    let bg_dot = bg[0] * dl[0] + bg[1] * dl[1] + bg[2] * dl[2];
                    let (px, py) = (x as f32, y as f32);
                    let mut tr = t_final;
                    let mut accum = [0.0f32; 3];
                    let (mut last_alpha, mut last_color) = (0.0f32, [0.0f32; 3]);
                    for j in (0..n).rev() {
                        let pr = &list[j];
                        // Same arithmetic as the forward pass, so the same entries are skipped.
                        let (dx, dy) = (pr.mx - px, pr.my - py);
                        let power = -0.5 * (pr.conic[0] * dx * dx + pr.conic[2] * dy * dy) - pr.conic[1] * dx * dy;
                        if power > 0.0 || power < pr.cull {
                            continue;
                        }
                        let gauss = power.exp();
                        let raw = pr.opacity * gauss;
                        let alpha = MAX_ALPHA.min(raw);
                        if alpha < MIN_ALPHA {
                            continue;
                        }
                        let one_minus = 1.0 - alpha;
                        tr /= one_minus; // transmittance in front of this Gaussian
                        let o = &mut out[index[j] as usize];
                        let weight = alpha * tr;
                        for k in 0..3 {
                            o.color[k] += weight * dl[k];
                            accum[k] = last_alpha * last_color[k] + (1.0 - last_alpha) * accum[k];
                        }
                        last_alpha = alpha;
                        last_color = pr.color;
                        let mut dl_dalpha = 0.0;
                        for k in 0..3 {
                            dl_dalpha += (pr.color[k] - accum[k]) * dl[k];
                        }
                        dl_dalpha = dl_dalpha * tr - t_final / one_minus * bg_dot;
                        if raw > MAX_ALPHA {
                            continue; // alpha is clamped: no gradient to opacity or shape
                        }
                        o.opacity += gauss * dl_dalpha;
                        let dl_dpower = pr.opacity * gauss * dl_dalpha;
                        o.mean[0] += dl_dpower * (-pr.conic[0] * dx - pr.conic[1] * dy);
                        o.mean[1] += dl_dpower * (-pr.conic[2] * dy - pr.conic[1] * dx);
                        o.conic[0] += dl_dpower * (-0.5 * dx * dx);
                        o.conic[1] += dl_dpower * (-dx * dy);
                        o.conic[2] += dl_dpower * (-0.5 * dy * dy);
                    }
                }
            }
        },
    );

    // 2. Sum per Gaussian in tile-list order (fixed, independent of the thread count).
    let per_g = sum_per_gaussian(&entries, &bins.ids, splats.len());
    drop(entries);

    // 3. Screen-space gradients to parameters, one Gaussian at a time.
    let k_all = splats.rest_coeffs();
    let center = cam.center();
    let per: Vec<ParamGrad> = (0..splats.len())
        .into_par_iter()
        .map(|i| if proj[i].radius > 0.0 { gaussian_backward(splats, i, state, center, &per_g[i]) } else { ParamGrad::default() })
        .collect();
    let mut params = Splats::new(splats.sh_degree);
    params.positions = per.par_iter().map(|g| g.position).collect();
    params.log_scales = per.par_iter().map(|g| g.log_scale).collect();
    params.rotations = per.par_iter().map(|g| g.rotation).collect();
    params.opacity_logits = per.par_iter().map(|g| g.opacity_logit).collect();
    params.sh_dc = per.par_iter().map(|g| g.sh_dc).collect();
    params.sh_rest = vec![0.0; splats.len() * k_all * 3];
    let k_used = math::sh_rest_coeffs(state.degree);
    if k_all > 0 {
        params.sh_rest.par_chunks_mut(k_all * 3).zip(&per).for_each(|(out, g)| out[..k_used * 3].copy_from_slice(&g.sh_rest[..k_used * 3]));
    }
    let (hw, hh) = (w as f32 / 2.0, h as f32 / 2.0);
    let mean2d_ndc_norm = per_g.par_iter().map(|g| ((g.mean[0] * hw).powi(2) + (g.mean[1] * hh).powi(2)).sqrt()).collect();
    Gradients { params, mean2d_ndc_norm }
}

/// Per Gaussian `g < n`, the sum of the `entries` listed for it (`ids[e] == g`), added in list
/// order: a fixed order, so the sums are the same bits on any thread count. A counting sort of
/// the list by Gaussian (counts and slots taken with atomics, then each Gaussian's slots put
/// back in list order) makes every step parallel and linear in the list's length.
fn sum_per_gaussian(entries: &[Grad2d], ids: &[u32], n: usize) -> Vec<Grad2d> {
    let cursor: Vec<AtomicU32> = (0..n).map(|_| AtomicU32::new(0)).collect();
    ids.par_iter().for_each(|&g| {
        cursor[g as usize].fetch_add(1, Relaxed);
    });
    // Each Gaussian's first slot, and its cursor set there.
    let mut starts = Vec::with_capacity(n + 1);
    let mut start = 0u32;
    starts.push(start);
    for c in &cursor {
        start += c.swap(start, Relaxed);
        starts.push(start);
    }
    let slots: Vec<AtomicU32> = (0..ids.len()).map(|_| AtomicU32::new(0)).collect();
    ids.par_iter().enumerate().for_each(|(e, &g)| {
        slots[cursor[g as usize].fetch_add(1, Relaxed) as usize].store(e as u32, Relaxed);
    });
    let mut slots: Vec<u32> = slots.into_iter().map(AtomicU32::into_inner).collect();
    split_at_ranges(&mut slots, &starts)
        .into_par_iter()
        .map(|list| {
            list.sort_unstable();
            let mut sum = Grad2d::default();
            for &e in list.iter() {
                sum.add(&entries[e as usize]);
            }
            sum
        })
        .collect()
}

/// `data` cut into the slices `ranges[i]..ranges[i + 1]` (ascending offsets from 0).
fn split_at_ranges<'a, T>(data: &'a mut [T], ranges: &[u32]) -> Vec<&'a mut [T]> {
    let mut parts = Vec::with_capacity(ranges.len().saturating_sub(1));
    let mut rest = data;
    for r in ranges.windows(2) {
        let (head, tail) = rest.split_at_mut((r[1] - r[0]) as usize);
        parts.push(head);
        rest = tail;
    }
    parts
}

#[derive(Debug, Clone, Copy)]
struct ParamGrad {
    position: [f32; 3],
    log_scale: [f32; 3],
    rotation: [f32; 4],
    opacity_logit: f32,
    sh_dc: [f32; 3],
    sh_rest: [f32; 45],
}

impl Default for ParamGrad {
    fn default() -> Self {
        ParamGrad { position: [0.0; 3], log_scale: [0.0; 3], rotation: [0.0; 4], opacity_logit: 0.0, sh_dc: [0.0; 3], sh_rest: [0.0; 45] }
    }
}

fn gaussian_backward(splats: &Splats, i: usize, state: &RasterState, center: Vec3, g: &Grad2d) -> ParamGrad {
    let cam = &state.camera;
    let pr = &state.projected[i];
    let mut out = ParamGrad::default();
    let pos = Vec3::from_array(splats.positions[i]);
    let t = cam.to_camera(pos);
    let (fx, fy) = (cam.fx, cam.fy);
    let iz = 1.0 / t.z;

    // Mean: (fx x/z + cx, fy y/z + cy).
    let mut dl_dt = Vec3::new(g.mean[0] * fx * iz, g.mean[1] * fy * iz, -(g.mean[0] * fx * t.x + g.mean[1] * fy * t.y) * iz * iz);

    // Conic = inverse of the dilated 2D covariance [a b; b c] (in f64: the determinant can be small).
    let cov3d = math::covariance_3d(splats.log_scales[i], splats.rotations[i]);
    let [a, b, c] = math::project_cov2d(cam, t, &cov3d).map(f64::from);
    let det = a * c - b * b;
    let (id, id2) = (1.0 / det, 1.0 / (det * det));
    let [ga, gb, gc] = g.conic.map(f64::from);
    let dl_da = (ga * (-c * c * id2) + gb * (b * c * id2) + gc * (id - a * c * id2)) as f32;
    let dl_db = (ga * (2.0 * b * c * id2) + gb * (-id - 2.0 * b * b * id2) + gc * (2.0 * a * b * id2)) as f32;
    let dl_dc = (ga * (id - a * c * id2) + gb * (a * b * id2) + gc * (-a * a * id2)) as f32;

    // 2D covariance = T Σ Tᵀ + 0.3 I with rows t0, t1 of T = J W.
    let [lim_x, lim_y] = math::jacobian_limits(cam);
    let (ux, uy) = (t.x / t.z, t.y / t.z);
    let (free_x, free_y) = (ux > -lim_x && ux < lim_x, uy > -lim_y && uy < lim_y);
    let (uxc, uyc) = (ux.clamp(-lim_x, lim_x), uy.clamp(-lim_y, lim_y));
    let (txc, tyc) = (uxc * t.z, uyc * t.z);
    let j0 = Vec3::new(fx * iz, 0.0, -fx * txc * iz * iz);
    let j1 = Vec3::new(0.0, fy * iz, -fy * tyc * iz * iz);
    let wt = cam.rotation.transpose();
    let (t0, t1) = (wt * j0, wt * j1);
    let (s_t0, s_t1) = (cov3d * t0, cov3d * t1);
    let dl_dt0 = 2.0 * dl_da * s_t0 + dl_db * s_t1;
    let dl_dt1 = dl_db * s_t0 + 2.0 * dl_dc * s_t1;
    let dl_dj0 = cam.rotation * dl_dt0;
    let dl_dj1 = cam.rotation * dl_dt1;
    // j0 = (fx/z, 0, -fx·uxc/z), uxc = clamp(x/z); likewise j1.
    let iz2 = iz * iz;
    if free_x {
        dl_dt.x += dl_dj0.z * (-fx * iz2);
        dl_dt.z += dl_dj0.z * (fx * uxc * iz2 + fx * iz * t.x * iz2);
    } else {
        dl_dt.z += dl_dj0.z * (fx * uxc * iz2);
    }
    dl_dt.z += dl_dj0.x * (-fx * iz2);
    if free_y {
        dl_dt.y += dl_dj1.z * (-fy * iz2);
        dl_dt.z += dl_dj1.z * (fy * uyc * iz2 + fy * iz * t.y * iz2);
    } else {
        dl_dt.z += dl_dj1.z * (fy * uyc * iz2);
    }
    dl_dt.z += dl_dj1.y * (-fy * iz2);
    let mut dl_dpos = cam.rotation.transpose() * dl_dt;

    // Σ = M Mᵀ with M = R S: dL/dM = (G + Gᵀ) M, G = dl_da t0t0ᵀ + dl_db t0t1ᵀ + dl_dc t1t1ᵀ.
    let outer = |u: Vec3, v: Vec3| Mat3::from_cols(u * v.x, u * v.y, u * v.z);
    let gs = outer(t0, t0) * (2.0 * dl_da) + (outer(t0, t1) + outer(t1, t0)) * dl_db + outer(t1, t1) * (2.0 * dl_dc);
    let q = splats.rotations[i];
    let r = math::quat_to_mat3(q);
    let s = Vec3::from_array(splats.log_scales[i].map(f32::exp));
    let m = Mat3::from_cols(r.x_axis * s.x, r.y_axis * s.y, r.z_axis * s.z);
    let dm = gs * m;
    let dm_cols = [dm.x_axis, dm.y_axis, dm.z_axis];
    let r_cols = [r.x_axis, r.y_axis, r.z_axis];
    let sv = s.to_array();
    for j in 0..3 {
        out.log_scale[j] = dm_cols[j].dot(r_cols[j]) * sv[j];
    }
    let gr = [dm_cols[0] * sv[0], dm_cols[1] * sv[1], dm_cols[2] * sv[2]];
    out.rotation = quat_backward(q, gr);

    // Opacity through the sigmoid.
    out.opacity_logit = g.opacity * pr.opacity * (1.0 - pr.opacity);

    // SH colour, clamped at 0, and through the view direction to the position.
    let degree = state.degree;
    let k_all = splats.rest_coeffs();
    let k_used = math::sh_rest_coeffs(degree);
    let rest = &splats.sh_rest[i * k_all * 3..(i * k_all + k_used) * 3];
    let diff = pos - center;
    let dir = math::view_dir(center, pos);
    let v = math::sh_color_unclamped(degree, splats.sh_dc[i], rest, dir);
    let dcol: [f32; 3] = std::array::from_fn(|ch| if v[ch] >= 0.0 { g.color[ch] } else { 0.0 });
    let basis = math::sh_basis(degree, dir);
    for ch in 0..3 {
        out.sh_dc[ch] = basis[0] * dcol[ch];
    }
    let mut dl_dbasis = [0.0f32; 16];
    for k in 0..k_used {
        for ch in 0..3 {
            out.sh_rest[k * 3 + ch] = basis[k + 1] * dcol[ch];
            dl_dbasis[k + 1] += rest[k * 3 + ch] * dcol[ch];
        }
    }
    let len = diff.length();
    if degree > 0 && len > 0.0 && diff.try_normalize().is_some() {
        let dl_ddir = sh_basis_backward(degree, dir, &dl_dbasis);
        dl_dpos += (dl_ddir - dir * dir.dot(dl_ddir)) / len;
    }
    out.position = dl_dpos.to_array();
    out
}

/// Gradient w.r.t. the raw quaternion `(w, x, y, z)` given `gr[c] = dL/d(column c of R)`, through
/// the normalisation. A zero quaternion (rendered as the identity) gets zero gradient.
fn quat_backward(q: [f32; 4], gr: [Vec3; 3]) -> [f32; 4] {
    let n = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    if !(n > 0.0 && n.is_finite()) {
        return [0.0; 4];
    }
    let [w, x, y, z] = math::normalize_quat(q);
    let (g0, g1, g2) = (gr[0], gr[1], gr[2]);
    let dw = 2.0 * (z * g0.y - y * g0.z - z * g1.x + x * g1.z + y * g2.x - x * g2.y);
    let dx = 2.0 * (y * g0.y + z * g0.z + y * g1.x - 2.0 * x * g1.y + w * g1.z + z * g2.x - w * g2.y - 2.0 * x * g2.z);
    let dy = 2.0 * (-2.0 * y * g0.x + x * g0.y - w * g0.z + x * g1.x + z * g1.z + w * g2.x + z * g2.y - 2.0 * y * g2.z);
    let dz = 2.0 * (-2.0 * z * g0.x + w * g0.y + x * g0.z - w * g1.x - 2.0 * z * g1.y + y * g1.z + x * g2.x + y * g2.y);
    let dq = [dw, dx, dy, dz];
    let qn = [w, x, y, z];
    let proj: f32 = (0..4).map(|k| qn[k] * dq[k]).sum();
    std::array::from_fn(|k| (dq[k] - qn[k] * proj) / n)
}

/// `Σ_k dl_dbasis[k] · d(basis_k)/d(dir)` for the basis of [`math::sh_basis`].
fn sh_basis_backward(degree: u8, dir: Vec3, g: &[f32; 16]) -> Vec3 {
    let (x, y, z) = (dir.x, dir.y, dir.z);
    let mut d = Vec3::new(-SH_C1 * g[3], -SH_C1 * g[1], SH_C1 * g[2]);
    if degree >= 2 {
        let c = SH_C2;
        d.x += c[0] * y * g[4] - 2.0 * c[2] * x * g[6] + c[3] * z * g[7] + 2.0 * c[4] * x * g[8];
        d.y += c[0] * x * g[4] + c[1] * z * g[5] - 2.0 * c[2] * y * g[6] - 2.0 * c[4] * y * g[8];
        d.z += c[1] * y * g[5] + 4.0 * c[2] * z * g[6] + c[3] * x * g[7];
    }
    if degree >= 3 {
        let c = SH_C3;
        let (xx, yy, zz) = (x * x, y * y, z * z);
        d.x += c[0] * 6.0 * x * y * g[9] + c[1] * y * z * g[10] - c[2] * 2.0 * x * y * g[11] - c[3] * 6.0 * x * z * g[12]
            + c[4] * (4.0 * zz - 3.0 * xx - yy) * g[13]
            + c[5] * 2.0 * x * z * g[14]
            + c[6] * 3.0 * (xx - yy) * g[15];
        d.y += c[0] * 3.0 * (xx - yy) * g[9] + c[1] * x * z * g[10] + c[2] * (4.0 * zz - xx - 3.0 * yy) * g[11]
            - c[3] * 6.0 * y * z * g[12]
            - c[4] * 2.0 * x * y * g[13]
            - c[5] * 2.0 * y * z * g[14]
            - c[6] * 6.0 * x * y * g[15];
        d.z += c[1] * x * y * g[10]
            + c[2] * 8.0 * y * z * g[11]
            + c[3] * (6.0 * zz - 3.0 * xx - 3.0 * yy) * g[12]
            + c[4] * 8.0 * x * z * g[13]
            + c[5] * (xx - yy) * g[14];
    }
    d
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The parallel counting sort adds each Gaussian's entries in list order: the same bits as
    /// one plain pass over the list, on one thread or several (the list, ~120k entries, is long
    /// enough for three threads to split it: with the slots left unsorted this failed here).
    #[test]
    fn per_gaussian_sums_are_the_list_order_fold() {
        let (n, tiles) = (2000usize, 200u32);
        let mut rng = crate::rng::Rng::new(7);
        // Tile-major lists, each Gaussian at most once per tile, some Gaussians in none.
        let mut ids = Vec::new();
        for _ in 0..tiles {
            let mut tile: Vec<u32> = (0..n as u32).filter(|_| rng.uniform() < 0.3).collect();
            rng.shuffle(&mut tile);
            ids.extend(tile);
        }
        let v = |rng: &mut crate::rng::Rng| (rng.uniform() - 0.5) * 10f32.powi((rng.uniform() * 8.0) as i32 - 4);
        let entries: Vec<Grad2d> = ids
            .iter()
            .map(|_| Grad2d {
                mean: [v(&mut rng), v(&mut rng)],
                conic: [v(&mut rng), v(&mut rng), v(&mut rng)],
                opacity: v(&mut rng),
                color: [v(&mut rng), v(&mut rng), v(&mut rng)],
            })
            .collect();
        let mut want = vec![Grad2d::default(); n];
        for (e, &g) in entries.iter().zip(&ids) {
            want[g as usize].add(e);
        }
        let bits = |s: &[Grad2d]| -> Vec<u32> {
            s.iter()
                .flat_map(|g| g.mean.iter().chain(&g.conic).chain([&g.opacity]).chain(&g.color).map(|x| x.to_bits()).collect::<Vec<_>>())
                .collect()
        };
        for threads in [1, 3] {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            let got = pool.install(|| sum_per_gaussian(&entries, &ids, n));
            assert_eq!(bits(&got), bits(&want), "{threads} threads");
        }
        assert!(bits(&sum_per_gaussian(&[], &[], 4)).iter().all(|&b| b == 0));
    }
}

//! Finite-difference checks of the rasterizer's backward pass against an independent f64 forward.
//!
//! The oracle below evaluates the same render (EWA projection with the Jacobian clamp, +0.3
//! dilation, tile-rectangle footprint, alpha clamp/skip, front-to-back compositing, SH with the
//! clamp at 0) entirely in f64 from f64 parameters, so central differences with h = 1e-5 have
//! truncation error ~1e-10 and round-off ~1e-11: the reference gradient is exact to far better
//! than the f32 analytic gradient under test.
//!
//! Tolerance: per parameter `|analytic - fd| <= 2e-3·|fd| + 2e-3·max|fd over the group|`. The
//! analytic gradient is computed in f32 and sums thousands of per-pixel terms whose transmittances
//! are recovered by division, so relative errors of ~1e-4 are expected; 2e-3 leaves margin while
//! still catching any missing or wrong term (those give O(1) relative errors). Parameters whose
//! finite difference straddles a discontinuity (alpha skip at 1/255, tile rectangle change) are
//! detected by comparing one-sided differences and skipped; the test asserts that few are.

use glam::{DMat3, DVec3, Vec3};
use gscodec::raster;
use gscodec::rng::Rng;
use gscodec::testkit::{random_splats_in, SceneRanges};
use gscodec_decoder::math::{sh_rest_coeffs, SH_C0, SH_C1, SH_C2, SH_C3, TILE};
use gscodec_decoder::render::render;
use gscodec_decoder::{Camera, RenderOptions, Splats};

/// Uniform in [-1, 1): the weights of the pixels in the scalar whose gradient is checked.
fn weight(rng: &mut Rng) -> f64 {
    2.0 * rng.uniform_f64() - 1.0
}

/// Flat f64 parameter vector in `Splats` order: per group, all Gaussians.
fn to_flat(s: &Splats) -> Vec<f64> {
    let mut v: Vec<f64> = Vec::new();
    v.extend(s.positions.as_flattened().iter().map(|&x| x as f64));
    v.extend(s.log_scales.as_flattened().iter().map(|&x| x as f64));
    v.extend(s.rotations.as_flattened().iter().map(|&x| x as f64));
    v.extend(s.opacity_logits.iter().map(|&x| x as f64));
    v.extend(s.sh_dc.as_flattened().iter().map(|&x| x as f64));
    v.extend(s.sh_rest.iter().map(|&x| x as f64));
    v
}

fn group_ranges(n: usize, k: usize) -> Vec<(&'static str, std::ops::Range<usize>)> {
    let sizes = [("position", 3 * n), ("log_scale", 3 * n), ("rotation", 4 * n), ("opacity", n), ("sh_dc", 3 * n), ("sh_rest", k * 3 * n)];
    let mut o = 0;
    sizes
        .iter()
        .map(|&(name, len)| {
            let r = o..o + len;
            o += len;
            (name, r)
        })
        .collect()
}

fn sh_basis64(degree: u8, d: DVec3) -> [f64; 16] {
    let mut b = [0.0; 16];
    b[0] = SH_C0 as f64;
    let (x, y, z) = (d.x, d.y, d.z);
    let c1 = SH_C1 as f64;
    let c2 = SH_C2.map(f64::from);
    let c3 = SH_C3.map(f64::from);
    if degree >= 1 {
        b[1] = -c1 * y;
        b[2] = c1 * z;
        b[3] = -c1 * x;
    }
    if degree >= 2 {
        b[4] = c2[0] * x * y;
        b[5] = c2[1] * y * z;
        b[6] = c2[2] * (2.0 * z * z - x * x - y * y);
        b[7] = c2[3] * x * z;
        b[8] = c2[4] * (x * x - y * y);
    }
    if degree >= 3 {
        let (xx, yy, zz) = (x * x, y * y, z * z);
        b[9] = c3[0] * y * (3.0 * xx - yy);
        b[10] = c3[1] * x * y * z;
        b[11] = c3[2] * y * (4.0 * zz - xx - yy);
        b[12] = c3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy);
        b[13] = c3[4] * x * (4.0 * zz - xx - yy);
        b[14] = c3[5] * z * (xx - yy);
        b[15] = c3[6] * x * (xx - 3.0 * yy);
    }
    b
}

/// `Σ weights · image` of the f64 render of the flat parameters.
fn oracle(p: &[f64], n: usize, sh_degree: u8, degree: u8, cam: &Camera, bg: [f64; 3], weights: &[f64]) -> f64 {
    let kall = sh_rest_coeffs(sh_degree);
    let g = group_ranges(n, kall);
    let (pos, ls, rot, op, dc, rest) =
        (&p[g[0].1.clone()], &p[g[1].1.clone()], &p[g[2].1.clone()], &p[g[3].1.clone()], &p[g[4].1.clone()], &p[g[5].1.clone()]);
    let w_rot = cam.rotation.as_dmat3();
    let (fx, fy, cx, cy) = (cam.fx as f64, cam.fy as f64, cam.cx as f64, cam.cy as f64);
    let center = -(w_rot.transpose() * cam.translation.as_dvec3());
    struct P {
        mean: [f64; 2],
        conic: [f64; 3],
        depth: f64,
        rect: [u32; 4],
        opacity: f64,
        color: [f64; 3],
        idx: usize,
    }
    let mut ps = Vec::new();
    for i in 0..n {
        let x = DVec3::new(pos[3 * i], pos[3 * i + 1], pos[3 * i + 2]);
        let t = w_rot * x + cam.translation.as_dvec3();
        if !(t.z > cam.znear as f64) {
            continue;
        }
        let q = [rot[4 * i], rot[4 * i + 1], rot[4 * i + 2], rot[4 * i + 3]];
        let qn = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
        let [qw, qx, qy, qz] = q.map(|v| v / qn);
        let r = DMat3::from_cols(
            DVec3::new(1.0 - 2.0 * (qy * qy + qz * qz), 2.0 * (qx * qy + qw * qz), 2.0 * (qx * qz - qw * qy)),
            DVec3::new(2.0 * (qx * qy - qw * qz), 1.0 - 2.0 * (qx * qx + qz * qz), 2.0 * (qy * qz + qw * qx)),
            DVec3::new(2.0 * (qx * qz + qw * qy), 2.0 * (qy * qz - qw * qx), 1.0 - 2.0 * (qx * qx + qy * qy)),
        );
        let s = DVec3::new(ls[3 * i].exp(), ls[3 * i + 1].exp(), ls[3 * i + 2].exp());
        let m = DMat3::from_cols(r.x_axis * s.x, r.y_axis * s.y, r.z_axis * s.z);
        let cov = m * m.transpose();
        let lim_x = 1.3 * cam.width as f64 / (2.0 * fx);
        let lim_y = 1.3 * cam.height as f64 / (2.0 * fy);
        let tx = (t.x / t.z).clamp(-lim_x, lim_x) * t.z;
        let ty = (t.y / t.z).clamp(-lim_y, lim_y) * t.z;
        let j0 = DVec3::new(fx / t.z, 0.0, -fx * tx / (t.z * t.z));
        let j1 = DVec3::new(0.0, fy / t.z, -fy * ty / (t.z * t.z));
        let (t0, t1) = (w_rot.transpose() * j0, w_rot.transpose() * j1);
        let a = t0.dot(cov * t0) + 0.3;
        let b = t0.dot(cov * t1);
        let c = t1.dot(cov * t1) + 0.3;
        let det = a * c - b * b;
        if !(det > 0.0) {
            continue;
        }
        let mid = 0.5 * (a + c);
        let radius = (3.0 * (mid + (mid * mid - det).max(0.1).sqrt()).sqrt()).ceil();
        let mean = [fx * t.x / t.z + cx, fy * t.y / t.z + cy];
        let (gx, gy) = (cam.width.div_ceil(TILE) as f64, cam.height.div_ceil(TILE) as f64);
        let tl = TILE as f64;
        let lo = |p: f64, g: f64| ((p - 0.5 - radius) / tl).clamp(0.0, g) as u32;
        let hi = |p: f64, g: f64| ((p - 0.5 + radius + tl - 1.0) / tl).clamp(0.0, g) as u32;
        let rect = [lo(mean[0], gx), lo(mean[1], gy), hi(mean[0], gx), hi(mean[1], gy)];
        if rect[2] <= rect[0] || rect[3] <= rect[1] {
            continue;
        }
        let dir = (x - center).normalize();
        let basis = sh_basis64(degree, dir);
        let mut color = [0.0; 3];
        for ch in 0..3 {
            let mut v = basis[0] * dc[3 * i + ch] + 0.5;
            for k in 0..sh_rest_coeffs(degree) {
                v += basis[k + 1] * rest[(i * kall + k) * 3 + ch];
            }
            color[ch] = v.max(0.0);
        }
        let opacity = 1.0 / (1.0 + (-op[i]).exp());
        ps.push(P { mean, conic: [c / det, -b / det, a / det], depth: t.z, rect, opacity, color, idx: i });
    }
    ps.sort_by(|a, b| a.depth.total_cmp(&b.depth).then(a.idx.cmp(&b.idx)));
    let mut total = 0.0;
    for y in 0..cam.height {
        for x in 0..cam.width {
            let (tx, ty) = (x / TILE, y / TILE);
            let mut col = [0.0; 3];
            let mut tr = 1.0;
            for p in &ps {
                if tx < p.rect[0] || tx >= p.rect[2] || ty < p.rect[1] || ty >= p.rect[3] {
                    continue;
                }
                let (dx, dy) = (p.mean[0] - 0.5 - x as f64, p.mean[1] - 0.5 - y as f64);
                let power = -0.5 * (p.conic[0] * dx * dx + p.conic[2] * dy * dy) - p.conic[1] * dx * dy;
                if power > 0.0 {
                    continue;
                }
                let alpha = (p.opacity * power.exp()).min(0.99);
                if alpha < 1.0 / 255.0 {
                    continue;
                }
                let next = tr * (1.0 - alpha);
                if next < 1e-4 {
                    break;
                }
                for k in 0..3 {
                    col[k] += p.color[k] * alpha * tr;
                }
                tr = next;
            }
            let pi = ((y * cam.width + x) * 3) as usize;
            for k in 0..3 {
                total += weights[pi + k] * (col[k] + tr * bg[k]);
            }
        }
    }
    total
}

fn camera() -> Camera {
    Camera::look_at(Vec3::new(0.3, -0.4, -4.0), Vec3::new(0.0, 0.0, 0.0), Vec3::new(0.0, -1.0, 0.1), 64, 48, 1.0)
}

/// `n` Gaussians in front of [`camera`], small enough that few parameters sit at a discontinuity.
fn random_scene(seed: u64, n: usize, degree: u8) -> Splats {
    let ranges = SceneRanges { extent: [0.9, 0.7, 0.8], log_scale: [-2.6, -1.4], opacity: [-1.0, 2.0], sh_dc: 1.0, sh_rest: 0.3 };
    random_splats_in(n, degree, seed, &ranges)
}

/// Checks every parameter of `s`; returns the number of parameters skipped at discontinuities.
fn check(name: &str, s: &Splats, cam: &Camera, bg: [f32; 3], degree: u8, seed: u64) -> usize {
    let mut rng = Rng::new(seed);
    let n = s.len();
    let weights: Vec<f64> = (0..(cam.width * cam.height * 3) as usize).map(|_| weight(&mut rng)).collect();
    let opts = RenderOptions { background: bg, max_sh_degree: degree };
    let (img, state) = raster::forward(s, cam, &opts);
    assert_eq!(img, render(s, cam, &opts), "{name}: forward differs from the decoder's render");
    let dl: Vec<f32> = weights.iter().map(|&w| w as f32).collect();
    let grads = raster::backward(s, &state, &dl);
    let analytic: Vec<f64> = to_flat(&grads.params);
    let p0 = to_flat(s);
    let bg64 = bg.map(f64::from);
    let f = |p: &[f64]| oracle(p, n, s.sh_degree, degree, cam, bg64, &weights);
    let f0 = f(&p0);
    let h = 1e-5;
    let mut skipped = 0;
    let mut checked_nonzero = 0;
    for (group, range) in group_ranges(n, s.rest_coeffs()) {
        let mut fd = Vec::new();
        let mut idx = Vec::new();
        for j in range.clone() {
            let mut p = p0.clone();
            p[j] += h;
            let fp = f(&p);
            p[j] -= 2.0 * h;
            let fm = f(&p);
            let (d_fwd, d_bwd) = ((fp - f0) / h, (f0 - fm) / h);
            // A jump between the two sides means a discontinuity inside [-h, h]: skip.
            if (d_fwd - d_bwd).abs() > 1e-2 * (d_fwd.abs() + d_bwd.abs()) + 1e-3 {
                skipped += 1;
                continue;
            }
            fd.push((fp - fm) / (2.0 * h));
            idx.push(j);
        }
        let scale = fd.iter().fold(0.0f64, |a, b| a.max(b.abs()));
        for (d, &j) in fd.iter().zip(&idx) {
            let a = analytic[j];
            let err = (a - d).abs();
            assert!(
                err <= 2e-3 * d.abs() + 2e-3 * scale + 1e-7,
                "{name}: {group}[{}] (Gaussian {}): analytic {a:e}, finite difference {d:e}",
                j - range.start,
                (j - range.start) / (range.len() / n).max(1)
            );
            if d.abs() > 1e-3 * scale && scale > 0.0 {
                checked_nonzero += 1;
            }
        }
    }
    assert!(checked_nonzero > 0, "{name}: no non-zero gradient was checked");
    assert!(skipped * 20 <= p0.len(), "{name}: {skipped} of {} parameters skipped", p0.len());
    skipped
}

#[test]
fn random_scenes_all_degrees() {
    let cam = camera();
    for (seed, degree) in [(1u64, 0u8), (2, 1), (3, 2), (4, 3)] {
        let s = random_scene(seed, 8, 3);
        check(&format!("random seed {seed} degree {degree}"), &s, &cam, [0.2, 0.5, 0.9], degree, seed + 100);
    }
}

#[test]
fn white_background_and_clamped_colours() {
    let cam = camera();
    let mut s = random_scene(7, 6, 3);
    // Strongly negative DC: colour clamped at 0 on some channels.
    s.sh_dc[0] = [-3.0, 0.1, -2.5];
    s.sh_dc[1] = [-1.9, -1.6, 0.3];
    check("clamped colours", &s, &cam, [1.0; 3], 3, 8);
}

#[test]
fn tiny_huge_and_degenerate_scales() {
    let cam = camera();
    let mut s = random_scene(11, 6, 1);
    s.log_scales[0] = [-9.0, -9.0, -9.0]; // sub-pixel: footprint is the 0.3 px² dilation
    s.log_scales[1] = [0.8, 0.6, 0.7]; // fills the view
    s.opacity_logits[1] = -2.0;
    s.log_scales[2] = [-1.5, -1.7, -11.0]; // flat disc: near-degenerate 3D covariance
    s.log_scales[3] = [-1.2, -12.0, -12.0]; // needle
    check("tiny/huge/degenerate", &s, &cam, [0.0; 3], 1, 12);
}

#[test]
fn saturated_opacity() {
    let cam = camera();
    let mut s = random_scene(21, 6, 2);
    s.opacity_logits[0] = 9.0; // alpha clamps at 0.99 near the centre
    s.opacity_logits[1] = 30.0;
    s.opacity_logits[2] = -4.0; // mostly under the 1/255 cut
    check("saturated opacity", &s, &cam, [0.3, 0.3, 0.3], 2, 22);
}

#[test]
fn frustum_edge_jacobian_clamp() {
    let cam = camera();
    let mut s = random_scene(31, 4, 1);
    // Centres well outside the view (|x/z| > 1.3·tan(fov/2)), large enough to reach into it.
    let c2w = cam.rotation.transpose();
    let place = |u: f32, v: f32, z: f32| (c2w * (Vec3::new(u * z, v * z, z) - cam.translation)).to_array();
    let (lx, ly) = (cam.width as f32 / (2.0 * cam.fx), cam.height as f32 / (2.0 * cam.fy));
    s.positions[0] = place(1.6 * lx, 0.1, 4.0);
    s.log_scales[0] = [-0.2, -0.6, -0.4];
    s.positions[1] = place(-0.2, -1.7 * ly, 3.5);
    s.log_scales[1] = [-0.5, -0.1, -0.3];
    s.positions[2] = place(-1.5 * lx, 1.5 * ly, 4.5);
    s.log_scales[2] = [-0.1, -0.2, 0.0];
    // Confirm the clamp is active for these.
    for i in 0..3 {
        let t = cam.to_camera(Vec3::from_array(s.positions[i]));
        assert!((t.x / t.z).abs() > 1.3 * lx || (t.y / t.z).abs() > 1.3 * ly);
    }
    check("frustum edge", &s, &cam, [0.1, 0.2, 0.3], 1, 32);
}

#[test]
fn backward_is_deterministic_across_thread_counts() {
    let cam = camera();
    let s = random_scene(41, 200, 3);
    let opts = RenderOptions { background: [1.0; 3], max_sh_degree: 3 };
    let mut rng = Rng::new(42);
    let dl: Vec<f32> = (0..(cam.width * cam.height * 3)).map(|_| weight(&mut rng) as f32).collect();
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        pool.install(|| {
            let (_, st) = raster::forward(&s, &cam, &opts);
            raster::backward(&s, &st, &dl)
        })
    };
    let (img, _) = raster::forward(&s, &cam, &opts);
    assert_eq!(img, render(&s, &cam, &opts), "forward differs from the decoder's render");
    let a = run(1);
    assert_eq!(a, run(2));
    assert_eq!(a, run(3));
}

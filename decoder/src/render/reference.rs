//! An f64, brute-force renderer with the same semantics as [`super::render`]: every pixel walks
//! every Gaussian in global depth order. Slow and simple; tests use it to bound the f32 error.

use super::{Image, RenderOptions};
use crate::camera::Camera;
use crate::math::{sh_basis, sh_rest_coeffs, TILE};
use crate::splats::Splats;
use glam::{DMat3, DVec3, Vec3};

struct P64 {
    mean: [f64; 2],
    conic: [f64; 3],
    depth: f64,
    rect: [u32; 4],
    opacity: f64,
    color: [f64; 3],
}

fn quat_mat(q: [f32; 4]) -> DMat3 {
    let q = q.map(f64::from);
    let n = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    let [w, x, y, z] = if n > 0.0 { q.map(|v| v / n) } else { [1.0, 0.0, 0.0, 0.0] };
    DMat3::from_cols(
        DVec3::new(1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y)),
        DVec3::new(2.0 * (x * y - w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z + w * x)),
        DVec3::new(2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y)),
    )
}

fn project(s: &Splats, i: usize, cam: &Camera, degree: u8) -> Option<P64> {
    let rot = cam.rotation.as_dmat3();
    let pos = Vec3::from_array(s.positions[i]).as_dvec3();
    let t = rot * pos + cam.translation.as_dvec3();
    if !(t.z > cam.znear as f64) {
        return None;
    }
    let r = quat_mat(s.rotations[i]);
    let sc = DVec3::from_array(s.log_scales[i].map(|v| (v as f64).exp()));
    let m = DMat3::from_cols(r.x_axis * sc.x, r.y_axis * sc.y, r.z_axis * sc.z);
    let cov = m * m.transpose();
    let (fx, fy) = (cam.fx as f64, cam.fy as f64);
    let lim_x = 1.3 * cam.width as f64 / (2.0 * fx);
    let lim_y = 1.3 * cam.height as f64 / (2.0 * fy);
    let tx = (t.x / t.z).clamp(-lim_x, lim_x) * t.z;
    let ty = (t.y / t.z).clamp(-lim_y, lim_y) * t.z;
    let j0 = DVec3::new(fx / t.z, 0.0, -fx * tx / (t.z * t.z));
    let j1 = DVec3::new(0.0, fy / t.z, -fy * ty / (t.z * t.z));
    let (t0, t1) = (rot.transpose() * j0, rot.transpose() * j1);
    let a = t0.dot(cov * t0) + 0.3;
    let b = t0.dot(cov * t1);
    let c = t1.dot(cov * t1) + 0.3;
    let det = a * c - b * b;
    if !(det > 0.0) || !det.is_finite() {
        return None;
    }
    let mid = 0.5 * (a + c);
    let radius = (3.0 * (mid + (mid * mid - det).max(0.1).sqrt()).sqrt()).ceil();
    let mean = [fx * t.x / t.z + cam.cx as f64, fy * t.y / t.z + cam.cy as f64];
    let (gx, gy) = (cam.width.div_ceil(TILE) as f64, cam.height.div_ceil(TILE) as f64);
    let tl = TILE as f64;
    let lo = |p: f64, g: f64| ((p - 0.5 - radius) / tl).clamp(0.0, g) as u32;
    let hi = |p: f64, g: f64| ((p - 0.5 + radius + tl - 1.0) / tl).clamp(0.0, g) as u32;
    let rect = [lo(mean[0], gx), lo(mean[1], gy), hi(mean[0], gx), hi(mean[1], gy)];
    if rect[2] <= rect[0] || rect[3] <= rect[1] {
        return None;
    }
    let dir = (pos - cam.center().as_dvec3()).try_normalize().unwrap_or(DVec3::Z);
    let basis = sh_basis(degree, dir.as_vec3()).map(f64::from);
    let k_all = sh_rest_coeffs(s.sh_degree);
    let mut color = [0.0; 3];
    for ch in 0..3 {
        let mut v = basis[0] * s.sh_dc[i][ch] as f64 + 0.5;
        for k in 0..sh_rest_coeffs(degree) {
            v += basis[k + 1] * s.sh_rest[(i * k_all + k) * 3 + ch] as f64;
        }
        color[ch] = v.max(0.0);
    }
    let opacity = 1.0 / (1.0 + (-(s.opacity_logits[i] as f64)).exp());
    Some(P64 { mean, conic: [c / det, -b / det, a / det], depth: t.z, rect, opacity, color })
}

/// Renders in f64 by brute force (every pixel visits every Gaussian). The result is rounded to f32.
pub fn render_f64(splats: &Splats, cam: &Camera, opts: &RenderOptions) -> Image {
    let degree = opts.max_sh_degree.min(splats.sh_degree);
    let mut ps: Vec<(usize, P64)> = (0..splats.len()).filter_map(|i| project(splats, i, cam, degree).map(|p| (i, p))).collect();
    ps.sort_by(|a, b| a.1.depth.total_cmp(&b.1.depth).then(a.0.cmp(&b.0)));
    let mut img = Image::filled(cam.width, cam.height, [0.0; 3]);
    for y in 0..cam.height {
        for x in 0..cam.width {
            let (tx, ty) = (x / TILE, y / TILE);
            let mut c = [0.0f64; 3];
            let mut tr = 1.0f64;
            for (_, p) in &ps {
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
                    c[k] += p.color[k] * alpha * tr;
                }
                tr = next;
            }
            let i = ((y * cam.width + x) * 3) as usize;
            for k in 0..3 {
                img.data[i + k] = (c[k] + tr * opts.background[k] as f64) as f32;
            }
        }
    }
    img
}

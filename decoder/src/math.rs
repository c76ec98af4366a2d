//! The one definition of the per-Gaussian math: covariance, EWA projection, SH colour.
//! The CPU/GPU renderers and the encoder's differentiable rasterizer all follow these functions.

use crate::camera::Camera;
use glam::{Mat3, Vec3};

/// Real SH basis constants of the reference 3DGS implementation: degree 0.
pub const SH_C0: f32 = 0.282_094_8;
/// Degree 1.
pub const SH_C1: f32 = 0.488_602_52;
/// Degree 2.
pub const SH_C2: [f32; 5] = [1.092_548_4, -1.092_548_4, 0.315_391_57, -1.092_548_4, 0.546_274_2];
/// Degree 3.
pub const SH_C3: [f32; 7] = [-0.590_043_6, 2.890_611_4, -0.457_045_8, 0.373_176_34, -0.457_045_8, 1.445_305_7, -0.590_043_6];

/// Screen-space dilation added to the 2D covariance diagonal (pixels²).
pub const COV2D_DILATION: f32 = 0.3;
/// Maximum alpha of one Gaussian at one pixel.
pub const MAX_ALPHA: f32 = 0.99;
/// Contributions with alpha below this are skipped.
pub const MIN_ALPHA: f32 = 1.0 / 255.0;
/// Compositing stops once transmittance would fall below this.
pub const MIN_TRANSMITTANCE: f32 = 1e-4;
/// Screen tile size in pixels.
pub const TILE: u32 = 16;

/// `(d+1)^2 - 1`: number of non-DC SH coefficients per channel.
pub const fn sh_rest_coeffs(degree: u8) -> usize {
    let d = degree as usize;
    (d + 1) * (d + 1) - 1
}

/// Logistic function, safe for any finite input.
pub fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + (-x).exp())
}

/// Normalised quaternion `(w, x, y, z)`; a zero quaternion becomes the identity.
pub fn normalize_quat(q: [f32; 4]) -> [f32; 4] {
    let n = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    if n > 0.0 && n.is_finite() {
        [q[0] / n, q[1] / n, q[2] / n, q[3] / n]
    } else {
        [1.0, 0.0, 0.0, 0.0]
    }
}

/// Rotation matrix of a (not necessarily normalised) quaternion `(w, x, y, z)`.
pub fn quat_to_mat3(q: [f32; 4]) -> Mat3 {
    let [w, x, y, z] = normalize_quat(q);
    Mat3::from_cols(
        Vec3::new(1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y)),
        Vec3::new(2.0 * (x * y - w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z + w * x)),
        Vec3::new(2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y)),
    )
}

/// World-space covariance `R S Sᵀ Rᵀ` with `S = diag(exp(log_scale))`.
pub fn covariance_3d(log_scale: [f32; 3], rot: [f32; 4]) -> Mat3 {
    let r = quat_to_mat3(rot);
    let s = Vec3::from_array(log_scale.map(f32::exp));
    let m = Mat3::from_cols(r.x_axis * s.x, r.y_axis * s.y, r.z_axis * s.z);
    m * m.transpose()
}

/// The bounds ±1.3·tan(half-FOV) to which `x/z` and `y/z` are clamped before the EWA Jacobian is
/// formed (see [`project_cov2d`]).
pub fn jacobian_limits(cam: &Camera) -> [f32; 2] {
    [1.3 * (cam.width as f32 / (2.0 * cam.fx)), 1.3 * (cam.height as f32 / (2.0 * cam.fy))]
}

/// Jacobian-clamped EWA projection of a 3D covariance to the dilated 2D covariance `[a, b, c]`
/// (`[[a, b], [b, c]]`), for a Gaussian whose centre is `t` in camera space.
///
/// As in the reference rasterizer, `x/z` and `y/z` are clamped to ±1.3·tan(half-FOV) before the
/// Jacobian is formed, so Gaussians far outside the view do not blow up.
pub fn project_cov2d(cam: &Camera, t: Vec3, cov3d: &Mat3) -> [f32; 3] {
    let [lim_x, lim_y] = jacobian_limits(cam);
    let tx = (t.x / t.z).clamp(-lim_x, lim_x) * t.z;
    let ty = (t.y / t.z).clamp(-lim_y, lim_y) * t.z;
    let (iz, iz2) = (1.0 / t.z, 1.0 / (t.z * t.z));
    // J rows (third row is zero).
    let j0 = Vec3::new(cam.fx * iz, 0.0, -cam.fx * tx * iz2);
    let j1 = Vec3::new(0.0, cam.fy * iz, -cam.fy * ty * iz2);
    let wt = cam.rotation.transpose(); // columns are rows of W
    let t0 = wt * j0; // row 0 of T = J W
    let t1 = wt * j1;
    let a = t0.dot(*cov3d * t0) + COV2D_DILATION;
    let b = t0.dot(*cov3d * t1);
    let c = t1.dot(*cov3d * t1) + COV2D_DILATION;
    [a, b, c]
}

/// Inverse (conic `[A, B, C]` with `power = -½(A dx² + C dy²) - B dx dy`) and the 3σ pixel radius
/// of a 2D covariance; `None` when it is singular or not finite.
pub fn conic_and_radius(cov2d: [f32; 3]) -> Option<([f32; 3], f32)> {
    let [a, b, c] = cov2d;
    let det = a * c - b * b;
    if !(det > 0.0) || !det.is_finite() {
        return None;
    }
    let inv = 1.0 / det;
    let mid = 0.5 * (a + c);
    let lambda1 = mid + (mid * mid - det).max(0.1).sqrt();
    let radius = (3.0 * lambda1.sqrt()).ceil();
    radius.is_finite().then_some(([c * inv, -b * inv, a * inv], radius))
}

/// SH basis values for `dir` (unit vector), in the band order of the reference implementation.
/// Index 0 is the DC term; entries beyond `(degree+1)^2` are zero.
pub fn sh_basis(degree: u8, dir: Vec3) -> [f32; 16] {
    let mut b = [0.0f32; 16];
    b[0] = SH_C0;
    if degree == 0 {
        return b;
    }
    let (x, y, z) = (dir.x, dir.y, dir.z);
    b[1] = -SH_C1 * y;
    b[2] = SH_C1 * z;
    b[3] = -SH_C1 * x;
    if degree == 1 {
        return b;
    }
    let (xx, yy, zz, xy, yz, xz) = (x * x, y * y, z * z, x * y, y * z, x * z);
    b[4] = SH_C2[0] * xy;
    b[5] = SH_C2[1] * yz;
    b[6] = SH_C2[2] * (2.0 * zz - xx - yy);
    b[7] = SH_C2[3] * xz;
    b[8] = SH_C2[4] * (xx - yy);
    if degree == 2 {
        return b;
    }
    b[9] = SH_C3[0] * y * (3.0 * xx - yy);
    b[10] = SH_C3[1] * xy * z;
    b[11] = SH_C3[2] * y * (4.0 * zz - xx - yy);
    b[12] = SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy);
    b[13] = SH_C3[4] * x * (4.0 * zz - xx - yy);
    b[14] = SH_C3[5] * z * (xx - yy);
    b[15] = SH_C3[6] * x * (xx - 3.0 * yy);
    b
}

/// Unclamped SH colour `Σ_k basis_k · coeff_k + 0.5` for view direction `dir` (unit, from the
/// camera centre towards the Gaussian). `rest` is `[k][channel]` as in [`crate::Splats`].
pub fn sh_color_unclamped(degree: u8, dc: [f32; 3], rest: &[f32], dir: Vec3) -> [f32; 3] {
    let basis = sh_basis(degree, dir);
    let mut col = [basis[0] * dc[0] + 0.5, basis[0] * dc[1] + 0.5, basis[0] * dc[2] + 0.5];
    for (k, coeffs) in rest.chunks_exact(3).enumerate() {
        for c in 0..3 {
            col[c] += basis[k + 1] * coeffs[c];
        }
    }
    col
}

/// Rendered colour of a Gaussian: SH colour + 0.5, clamped at 0 (no upper clamp).
pub fn sh_color(degree: u8, dc: [f32; 3], rest: &[f32], dir: Vec3) -> [f32; 3] {
    sh_color_unclamped(degree, dc, rest, dir).map(|v| v.max(0.0))
}

/// Unit view direction from the camera centre to `pos`; +z when they coincide.
pub fn view_dir(cam_center: Vec3, pos: Vec3) -> Vec3 {
    (pos - cam_center).try_normalize().unwrap_or(Vec3::Z)
}

/// The screen tiles `[x0, x1) x [y0, y1)` touched by a Gaussian at `mean` (continuous image
/// coordinates) with pixel radius `radius`, following the reference rasterizer's `getRect`.
pub fn tile_rect(mean: [f32; 2], radius: f32, width: u32, height: u32) -> [u32; 4] {
    let (gx, gy) = (width.div_ceil(TILE) as f32, height.div_ceil(TILE) as f32);
    let t = TILE as f32;
    // The reference rasterizer works in pixel-index coordinates (pixel centre = integer).
    let (px, py) = (mean[0] - 0.5, mean[1] - 0.5);
    let lo = |p: f32, g: f32| ((p - radius) / t).clamp(0.0, g) as u32;
    let hi = |p: f32, g: f32| ((p + radius + t - 1.0) / t).clamp(0.0, g) as u32;
    [lo(px, gx), lo(py, gy), hi(px, gx), hi(py, gy)]
}

/// Whether a Gaussian can reach alpha ≥ [`MIN_ALPHA`] at any pixel centre of the pixel-index box
/// `[x0, x1] x [y0, y1]` (inclusive). `mean` is in continuous image coordinates.
///
/// This is a conservative bound: a `false` means every pixel of the box would skip this Gaussian
/// anyway, so dropping it from the tile's list leaves the image bit-identical. It finds the
/// minimum of the quadratic form `dᵀ Q d` (`Q` = conic) over the box of offsets, which lies at
/// the centre when the box contains it, otherwise on one of the four edges.
pub fn reaches_box(mean: [f32; 2], conic: [f32; 3], opacity: f32, box_px: [f32; 4]) -> bool {
    reaches_box_with(mean, conic, opacity, alpha_level(opacity), box_px)
}

/// `ln(MIN_ALPHA·(1 − 1e-3) / opacity)`: the exponent below which [`reaches_box`]'s alpha falls
/// short, for [`reaches_box_with`].
pub fn alpha_level(opacity: f32) -> f32 {
    (f64::from(MIN_ALPHA * (1.0 - 1e-3)) / f64::from(opacity)).ln() as f32
}

/// [`reaches_box`] given `level = alpha_level(opacity)`: the same answer, without `exp` unless the
/// exponent lies within 1e-3 of the level (where the rounding of `exp` and of the level could
/// matter). Binning calls it for every tile a Gaussian's rectangle covers.
#[inline]
pub fn reaches_box_with(mean: [f32; 2], conic: [f32; 3], opacity: f32, level: f32, box_px: [f32; 4]) -> bool {
    // A small margin keeps the test conservative under f32 rounding.
    let power = -0.5 * box_qmin(mean, conic, box_px) * (1.0 - 1e-3);
    if power.is_finite() && level.is_finite() {
        if power > level + 1e-3 {
            return true;
        }
        if power < level - 1e-3 {
            return false;
        }
    }
    !(opacity * power.exp() < MIN_ALPHA * (1.0 - 1e-3))
}

/// The least `dᵀ Q d` (`Q` = `conic`) over the offsets `d = mean − pixel` of the pixel centres of
/// `box_px`: 0 when the box holds the centre, otherwise on one of its four edges.
fn box_qmin(mean: [f32; 2], conic: [f32; 3], box_px: [f32; 4]) -> f32 {
    let [a, b, c] = conic;
    // Offsets d = mean_ref - pixel for pixels in the box (pixel centre = index + 0.5).
    let (mx, my) = (mean[0] - 0.5, mean[1] - 0.5);
    let (dx0, dx1) = (mx - box_px[2], mx - box_px[0]);
    let (dy0, dy1) = (my - box_px[3], my - box_px[1]);
    let q = |dx: f32, dy: f32| a * dx * dx + 2.0 * b * dx * dy + c * dy * dy;
    if dx0 <= 0.0 && 0.0 <= dx1 && dy0 <= 0.0 && 0.0 <= dy1 {
        0.0
    } else {
        let along_y = |dx: f32| q(dx, (-b * dx / c).clamp(dy0, dy1));
        let along_x = |dy: f32| q((-b * dy / a).clamp(dx0, dx1), dy);
        along_y(dx0).min(along_y(dx1)).min(along_x(dy0)).min(along_x(dy1))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// [`reaches_box_with`]'s shortcut gives the answer of the `exp` test it skips, also for
    /// opacities chosen so that the alpha lands within ±1e-2 … ±1e-8 of the threshold, at 0, 1,
    /// denormal and non-finite opacities and for degenerate conics.
    #[test]
    fn reaching_a_box_without_exp_is_the_exp_test() {
        let exact =
            |mean, conic, opacity: f32, bx| !(opacity * (-0.5 * box_qmin(mean, conic, bx) * (1.0 - 1e-3)).exp() < MIN_ALPHA * (1.0 - 1e-3));
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 40) as f32 / (1u64 << 24) as f32
        };
        let (mut checked, mut near) = (0, 0);
        for _ in 0..20_000 {
            let mean = [next() * 64.0 - 16.0, next() * 64.0 - 16.0];
            let (a, c) = ((next() * 2.0).powi(3) + 1e-4, (next() * 2.0).powi(3) + 1e-4);
            let b = (next() * 2.0 - 1.0) * (a * c).sqrt() * if next() < 0.1 { 1.0 } else { 0.99 };
            let conic = [a, b, c];
            let bx = [16.0, 16.0, 31.0, 31.0];
            let power = -0.5 * box_qmin(mean, conic, bx) * (1.0 - 1e-3);
            let at_threshold = MIN_ALPHA * (1.0 - 1e-3) / power.exp();
            let mut opacities = vec![next(), 0.0, 1.0, 1e-40, f32::NAN, f32::INFINITY];
            for d in [0.0, 1e-8, 1e-7, 1e-6, 1e-5, 1e-4, 1e-3, 2e-3, 1e-2] {
                opacities.extend([at_threshold * (1.0 + d), at_threshold * (1.0 - d)]);
            }
            for opacity in opacities {
                let fast = reaches_box_with(mean, conic, opacity, alpha_level(opacity), bx);
                assert_eq!(fast, exact(mean, conic, opacity, bx), "mean {mean:?} conic {conic:?} opacity {opacity:e}");
                assert_eq!(reaches_box(mean, conic, opacity, bx), fast);
                checked += 1;
                near += usize::from(exact(mean, conic, opacity * 1.001, bx) != exact(mean, conic, opacity / 1.001, bx));
            }
        }
        // Many of the cases sit at the threshold, where the answer turns within ±0.1 %.
        assert!(near > checked / 10, "{near} of {checked} cases near the threshold");
    }
}

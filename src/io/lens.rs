//! Camera lens models (COLMAP's and nerfstudio's) and undistortion to a pinhole camera.
//!
//! A [`Lens`] maps a camera-space direction `(x/z, y/z)` (the *normalised* pinhole coordinates
//! `(u, v)`) to image pixels: `distort` gives the distorted normalised coordinates and the pixel is
//! `(fx·x_d + cx, fy·y_d + cy)` with COLMAP's pixel convention (the top-left corner is `(0, 0)`,
//! pixel `(i, j)`'s centre is `(i + 0.5, j + 0.5)`, the same as gscodec's [`Camera`]).
//!
//! The forward maps are COLMAP's (`src/colmap/sensor/models.h`) term for term; the inverse
//! ([`Lens::undistort`]) is Newton's method on the forward map with a convergence test, except for
//! `FOV`, which has a closed-form inverse. Fisheye models first map the direction to the
//! equidistant plane, `θ = atan(r)`, `(u, v)·θ/r`, then add the polynomial distortion in that
//! plane; directions at or beyond 90° from the axis have no pinhole image.
//!
//! [`undistort_image`] resamples an image to a pinhole camera once, before training: the
//! rasterizer and its gradients are pinhole-only, so modelling distortion in the projection would
//! mean a second projection and Jacobian in every renderer (CPU, GPU, decoder).

use gscodec_decoder::{Camera, Image};
use rayon::prelude::*;

/// How a lens bends rays, in normalised coordinates (focal length 1, principal point 0).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Distortion {
    /// None (`SIMPLE_PINHOLE`, `PINHOLE`).
    None,
    /// Radial polynomial `k1 r² + k2 r⁴ + k3 r⁶ + k4 r⁸` plus tangential `p1, p2`
    /// (`SIMPLE_RADIAL`, `RADIAL`, `OPENCV`; nerfstudio's `OPENCV` with `k3`, `k4`).
    RadialTangential { k: [f64; 4], p: [f64; 2] },
    /// Rational radial `(1 + k1 r² + k2 r⁴ + k3 r⁶) / (1 + k4 r² + k5 r⁴ + k6 r⁶)` plus tangential
    /// (`FULL_OPENCV`).
    Rational { k: [f64; 6], p: [f64; 2] },
    /// Equidistant fisheye, then radial `k1 θ² + … + k4 θ⁸`, tangential `p1, p2` and thin prism
    /// `sx1, sy1` in the fisheye plane (`OPENCV_FISHEYE`, `SIMPLE_RADIAL_FISHEYE`,
    /// `RADIAL_FISHEYE`, `THIN_PRISM_FISHEYE`).
    Fisheye { k: [f64; 4], p: [f64; 2], s: [f64; 2] },
    /// Field-of-view model with angle `omega` (`FOV`).
    Fov { omega: f64 },
    /// Equidistant fisheye, then radial `1 + k0 θ² + … + k5 θ¹²` scaling the point, then
    /// tangential `p0, p1` and thin prism `s0 r² + s1 r⁴`, `s2 r² + s3 r⁴` on that scaled point
    /// (`RAD_TAN_THIN_PRISM_FISHEYE`, Project Aria's calibration model).
    RadTanThinPrism { k: [f64; 6], p: [f64; 2], s: [f64; 4] },
    /// Division model: `x = 2u / (1 + √(1 − 4k|u|²))`, inverse `u = x / (1 + k|x|²)`
    /// (`SIMPLE_DIVISION`, `DIVISION`).
    Division { k: f64 },
    /// Enhanced unified camera model: `x = u / (α√(β|u|² + 1) + 1 − α)` (`EUCM`).
    Eucm { alpha: f64, beta: f64 },
}

/// Intrinsics plus distortion of one camera, for an image of `width × height` pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lens {
    pub width: u32,
    pub height: u32,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub distortion: Distortion,
}

/// COLMAP camera models: (id, name, parameter names in COLMAP's order). Every perspective
/// model COLMAP defines (`src/colmap/sensor/models.h`); its one spherical model,
/// `EQUIRECTANGULAR` (id 17), is [`COLMAP_UNSUPPORTED`].
pub const COLMAP_MODELS: [(i32, &str, &[&str]); 17] = [
    (0, "SIMPLE_PINHOLE", &["f", "cx", "cy"]),
    (1, "PINHOLE", &["fx", "fy", "cx", "cy"]),
    (2, "SIMPLE_RADIAL", &["f", "cx", "cy", "k"]),
    (3, "RADIAL", &["f", "cx", "cy", "k1", "k2"]),
    (4, "OPENCV", &["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"]),
    (5, "OPENCV_FISHEYE", &["fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"]),
    (6, "FULL_OPENCV", &["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"]),
    (7, "FOV", &["fx", "fy", "cx", "cy", "omega"]),
    (8, "SIMPLE_RADIAL_FISHEYE", &["f", "cx", "cy", "k"]),
    (9, "RADIAL_FISHEYE", &["f", "cx", "cy", "k1", "k2"]),
    (10, "THIN_PRISM_FISHEYE", &["fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "k4", "sx1", "sy1"]),
    (11, "RAD_TAN_THIN_PRISM_FISHEYE", &["fx", "fy", "cx", "cy", "k0", "k1", "k2", "k3", "k4", "k5", "p0", "p1", "s0", "s1", "s2", "s3"]),
    (12, "SIMPLE_DIVISION", &["f", "cx", "cy", "k"]),
    (13, "DIVISION", &["fx", "fy", "cx", "cy", "k"]),
    (14, "SIMPLE_FISHEYE", &["f", "cx", "cy"]),
    (15, "FISHEYE", &["fx", "fy", "cx", "cy"]),
    (16, "EUCM", &["fx", "fy", "cx", "cy", "alpha", "beta"]),
];

/// COLMAP camera models gscodec refuses, by id and name, with the reason.
pub const COLMAP_UNSUPPORTED: [(i32, &str, &str); 1] =
    [(17, "EQUIRECTANGULAR", "a spherical (360°) camera, which no pinhole view covers; not supported")];

/// The error message for a COLMAP model id or name that is not in [`COLMAP_MODELS`].
pub fn colmap_model_error(id: Option<i32>, name: Option<&str>) -> String {
    match COLMAP_UNSUPPORTED.iter().find(|m| Some(m.0) == id || Some(m.1) == name) {
        Some((id, name, why)) => format!("camera model {name} (id {id}) is {why}"),
        None => match (id, name) {
            (_, Some(n)) => format!("unknown camera model `{n}`"),
            (Some(i), None) => format!("unknown camera model id {i}"),
            (None, None) => "unknown camera model".into(),
        },
    }
}

/// Newton's method stops when the residual is below this (normalised units: 1e-12 focal lengths).
const NEWTON_TOLERANCE: f64 = 1e-12;
const NEWTON_MAX_ITERS: usize = 100;

impl Lens {
    /// A lens from a COLMAP model name and its parameters (in COLMAP's order).
    pub fn from_colmap(model: &str, width: u32, height: u32, p: &[f64]) -> Result<Lens, String> {
        let n = COLMAP_MODELS.iter().find(|m| m.1 == model).ok_or_else(|| colmap_model_error(None, Some(model)))?.2.len();
        if p.len() != n {
            return Err(format!("{model} has {n} parameters, got {}", p.len()));
        }
        let z2 = [0.0; 2];
        let (f, d) = match model {
            "SIMPLE_PINHOLE" => ([p[0], p[0], p[1], p[2]], Distortion::None),
            "PINHOLE" => ([p[0], p[1], p[2], p[3]], Distortion::None),
            "SIMPLE_RADIAL" => ([p[0], p[0], p[1], p[2]], Distortion::RadialTangential { k: [p[3], 0.0, 0.0, 0.0], p: z2 }),
            "RADIAL" => ([p[0], p[0], p[1], p[2]], Distortion::RadialTangential { k: [p[3], p[4], 0.0, 0.0], p: z2 }),
            "OPENCV" => ([p[0], p[1], p[2], p[3]], Distortion::RadialTangential { k: [p[4], p[5], 0.0, 0.0], p: [p[6], p[7]] }),
            "OPENCV_FISHEYE" => ([p[0], p[1], p[2], p[3]], Distortion::Fisheye { k: [p[4], p[5], p[6], p[7]], p: z2, s: z2 }),
            "FULL_OPENCV" => {
                ([p[0], p[1], p[2], p[3]], Distortion::Rational { k: [p[4], p[5], p[8], p[9], p[10], p[11]], p: [p[6], p[7]] })
            }
            "FOV" => ([p[0], p[1], p[2], p[3]], Distortion::Fov { omega: p[4] }),
            "SIMPLE_RADIAL_FISHEYE" => ([p[0], p[0], p[1], p[2]], Distortion::Fisheye { k: [p[3], 0.0, 0.0, 0.0], p: z2, s: z2 }),
            "RADIAL_FISHEYE" => ([p[0], p[0], p[1], p[2]], Distortion::Fisheye { k: [p[3], p[4], 0.0, 0.0], p: z2, s: z2 }),
            "THIN_PRISM_FISHEYE" => {
                ([p[0], p[1], p[2], p[3]], Distortion::Fisheye { k: [p[4], p[5], p[8], p[9]], p: [p[6], p[7]], s: [p[10], p[11]] })
            }
            "RAD_TAN_THIN_PRISM_FISHEYE" => (
                [p[0], p[1], p[2], p[3]],
                Distortion::RadTanThinPrism { k: [p[4], p[5], p[6], p[7], p[8], p[9]], p: [p[10], p[11]], s: [p[12], p[13], p[14], p[15]] },
            ),
            "SIMPLE_DIVISION" => ([p[0], p[0], p[1], p[2]], Distortion::Division { k: p[3] }),
            "DIVISION" => ([p[0], p[1], p[2], p[3]], Distortion::Division { k: p[4] }),
            "SIMPLE_FISHEYE" => ([p[0], p[0], p[1], p[2]], Distortion::Fisheye { k: [0.0; 4], p: z2, s: z2 }),
            "FISHEYE" => ([p[0], p[1], p[2], p[3]], Distortion::Fisheye { k: [0.0; 4], p: z2, s: z2 }),
            "EUCM" => ([p[0], p[1], p[2], p[3]], Distortion::Eucm { alpha: p[4], beta: p[5] }),
            _ => unreachable!("model checked above"),
        };
        Lens::new(width, height, f, d)
    }

    /// A lens from `[fx, fy, cx, cy]` and a distortion, validated.
    pub fn new(width: u32, height: u32, f: [f64; 4], distortion: Distortion) -> Result<Lens, String> {
        let lens = Lens { width, height, fx: f[0], fy: f[1], cx: f[2], cy: f[3], distortion };
        if !(f.iter().all(|v| v.is_finite()) && f[0] > 0.0 && f[1] > 0.0 && width > 0 && height > 0) {
            return Err(format!("invalid intrinsics {f:?} for a {width}x{height} image"));
        }
        let fov_ok = match distortion {
            Distortion::Fov { omega } => omega.is_finite() && omega > 0.0 && omega < std::f64::consts::PI,
            _ => true,
        };
        if !fov_ok {
            return Err("FOV model needs 0 < omega < π".into());
        }
        if let Distortion::Eucm { alpha, beta } = distortion {
            if !((0.0..=1.0).contains(&alpha) && beta > 0.0) {
                return Err(format!("EUCM needs 0 ≤ alpha ≤ 1 and beta > 0, got alpha {alpha}, beta {beta}"));
            }
        }
        Ok(lens.simplified())
    }

    /// `Distortion::None` when every distortion coefficient is zero.
    fn simplified(mut self) -> Lens {
        let zero = match self.distortion {
            Distortion::RadialTangential { k, p } => k.iter().chain(&p).all(|&v| v == 0.0),
            Distortion::Rational { k, p } => k.iter().chain(&p).all(|&v| v == 0.0),
            Distortion::Division { k } => k == 0.0,
            Distortion::Eucm { alpha, .. } => alpha == 0.0,
            _ => false,
        };
        if zero {
            self.distortion = Distortion::None;
        }
        self
    }

    /// Whether the lens is a plain pinhole.
    pub fn is_pinhole(&self) -> bool {
        self.distortion == Distortion::None
    }

    /// The same lens for the image resized to `width × height` (the image's corners stay its
    /// corners, so every pixel coordinate scales by `width'/width`, `height'/height`).
    pub fn resized(&self, width: u32, height: u32) -> Lens {
        let (sx, sy) = (width as f64 / self.width as f64, height as f64 / self.height as f64);
        Lens { width, height, fx: self.fx * sx, fy: self.fy * sy, cx: self.cx * sx, cy: self.cy * sy, ..*self }
    }

    /// Normalised pinhole coordinates to normalised distorted coordinates (COLMAP's forward map).
    pub fn distort(&self, u: f64, v: f64) -> (f64, f64) {
        match self.distortion {
            Distortion::None => (u, v),
            Distortion::Fov { omega } => {
                let r2 = u * u + v * v;
                let f = fov_factor(omega, r2);
                (u * f, v * f)
            }
            Distortion::Fisheye { .. } | Distortion::RadTanThinPrism { .. } => {
                let (a, b) = fisheye_from_normal(u, v);
                self.plane(a, b)
            }
            Distortion::Division { k } => {
                let d2 = 1.0 - 4.0 * k * (u * u + v * v);
                let r = if d2 >= 0.0 { 2.0 / (1.0 + d2.sqrt()) } else { f64::NAN };
                (u * r, v * r)
            }
            Distortion::Eucm { alpha, beta } => {
                let den = alpha * (beta * (u * u + v * v) + 1.0).sqrt() + 1.0 - alpha;
                let f = if den > f64::EPSILON { 1.0 / den } else { f64::NAN };
                (u * f, v * f)
            }
            _ => self.plane(u, v),
        }
    }

    /// The additive distortion in the model's plane (the pinhole plane, or the equidistant
    /// fisheye plane): `(a, b) + Δ(a, b)`.
    fn plane(&self, a: f64, b: f64) -> (f64, f64) {
        let (a2, b2, ab) = (a * a, b * b, a * b);
        let r2 = a2 + b2;
        match self.distortion {
            Distortion::RadialTangential { k, p } | Distortion::Fisheye { k, p, .. } => {
                let radial = r2 * (k[0] + r2 * (k[1] + r2 * (k[2] + r2 * k[3])));
                let s = if let Distortion::Fisheye { s, .. } = self.distortion { s } else { [0.0; 2] };
                (
                    a + a * radial + 2.0 * p[0] * ab + p[1] * (r2 + 2.0 * a2) + s[0] * r2,
                    b + b * radial + 2.0 * p[1] * ab + p[0] * (r2 + 2.0 * b2) + s[1] * r2,
                )
            }
            Distortion::Rational { k, p } => {
                let num = 1.0 + r2 * (k[0] + r2 * (k[1] + r2 * k[2]));
                let den = 1.0 + r2 * (k[3] + r2 * (k[4] + r2 * k[5]));
                let radial = num / den;
                (a * radial + 2.0 * p[0] * ab + p[1] * (r2 + 2.0 * a2), b * radial + 2.0 * p[1] * ab + p[0] * (r2 + 2.0 * b2))
            }
            Distortion::RadTanThinPrism { k, p, s } => {
                let t = r2 * (k[0] + r2 * (k[1] + r2 * (k[2] + r2 * (k[3] + r2 * (k[4] + r2 * k[5])))));
                let (x, y) = (a * (1.0 + t), b * (1.0 + t));
                let (x2, y2, xy) = (x * x, y * y, x * y);
                let q2 = x2 + y2;
                let q4 = q2 * q2;
                (
                    x + 2.0 * p[1] * xy + p[0] * (q2 + 2.0 * x2) + s[0] * q2 + s[1] * q4,
                    y + 2.0 * p[0] * xy + p[1] * (q2 + 2.0 * y2) + s[2] * q2 + s[3] * q4,
                )
            }
            Distortion::None | Distortion::Fov { .. } | Distortion::Division { .. } | Distortion::Eucm { .. } => (a, b),
        }
    }

    /// Inverse of [`Lens::distort`]: the normalised pinhole coordinates whose image is `(x, y)`,
    /// or `None` when Newton's method does not converge to a point where the map is locally
    /// invertible (outside the lens's valid region, or beyond 90° for a fisheye).
    pub fn undistort(&self, x: f64, y: f64) -> Option<(f64, f64)> {
        if !(x.is_finite() && y.is_finite()) {
            return None;
        }
        match self.distortion {
            Distortion::None => Some((x, y)),
            Distortion::Fov { omega } => {
                let r2 = x * x + y * y;
                let f = fov_inverse_factor(omega, r2);
                if r2.sqrt() * omega >= std::f64::consts::FRAC_PI_2 {
                    return None;
                }
                Some((x * f, y * f))
            }
            Distortion::Fisheye { .. } | Distortion::RadTanThinPrism { .. } => {
                let (a, b) = self.invert_plane(x, y)?;
                normal_from_fisheye(a, b)
            }
            Distortion::Division { k } => {
                // The forward map's principal branch covers k·|x|² in (−1, 1).
                let ks = k * (x * x + y * y);
                (ks > -1.0 && ks < 1.0).then(|| (x / (1.0 + ks), y / (1.0 + ks)))
            }
            Distortion::Eucm { alpha, beta } => {
                // COLMAP's closed-form lift; `None` behind the camera or outside the model's disc.
                let r2 = x * x + y * y;
                let radicand = 1.0 - (2.0 * alpha - 1.0) * beta * r2;
                if radicand < 0.0 {
                    return None;
                }
                let den = alpha * radicand.sqrt() + 1.0 - alpha;
                let mz = (1.0 - alpha * alpha * beta * r2) / den;
                (den > f64::EPSILON && mz > f64::EPSILON).then(|| (x / mz, y / mz))
            }
            _ => self.invert_plane(x, y),
        }
    }

    /// Solves `plane(a, b) = (x, y)` by Newton's method (central-difference Jacobian).
    fn invert_plane(&self, x: f64, y: f64) -> Option<(f64, f64)> {
        let (mut a, mut b) = (x, y);
        for _ in 0..NEWTON_MAX_ITERS {
            let (fa, fb) = self.plane(a, b);
            let (ra, rb) = (fa - x, fb - y);
            let h = 1e-7 * (1.0 + a.abs().max(b.abs()));
            let (pa, pb) = self.plane(a + h, b);
            let (ma, mb) = self.plane(a - h, b);
            let (qa, qb) = self.plane(a, b + h);
            let (na, nb) = self.plane(a, b - h);
            let (j00, j10) = ((pa - ma) / (2.0 * h), (pb - mb) / (2.0 * h));
            let (j01, j11) = ((qa - na) / (2.0 * h), (qb - nb) / (2.0 * h));
            let det = j00 * j11 - j01 * j10;
            if ra.hypot(rb) < NEWTON_TOLERANCE {
                // Converged: accept only where the map is orientation-preserving (not folded).
                return (det > 0.0).then_some((a, b));
            }
            if !(det.is_finite() && det.abs() > 1e-300) {
                return None;
            }
            let da = (j11 * ra - j01 * rb) / det;
            let db = (-j10 * ra + j00 * rb) / det;
            a -= da;
            b -= db;
            if !(a.is_finite() && b.is_finite()) {
                return None;
            }
        }
        None
    }

    /// Pixel coordinates of normalised distorted coordinates.
    pub fn to_pixel(&self, x: f64, y: f64) -> (f64, f64) {
        (self.fx * x + self.cx, self.fy * y + self.cy)
    }

    /// Normalised distorted coordinates of a pixel position.
    pub fn from_pixel(&self, px: f64, py: f64) -> (f64, f64) {
        ((px - self.cx) / self.fx, (py - self.cy) / self.fy)
    }

    /// The pinhole camera [`undistort_image`] produces for this lens: same focal length (reduced
    /// when the undistorted field would be more than twice the image's size), cropped to the
    /// largest axis-aligned rectangle whose every pixel has a source inside the image (no blank
    /// border). `None` when no such rectangle exists.
    pub fn pinhole_target(&self) -> Option<Lens> {
        if self.is_pinhole() {
            return Some(*self);
        }
        let (w, h) = (self.width as f64, self.height as f64);
        let steps = (self.width.max(self.height) as usize).clamp(16, 1024);
        let edge = |t: f64, px: &dyn Fn(f64) -> (f64, f64)| {
            let (qx, qy) = px(t);
            let (x, y) = self.from_pixel(qx, qy);
            self.undistort(x, y)
        };
        // Each edge's inner bound. A point with no pinhole image (beyond 90° for a fisheye, e.g.
        // the corners of a full-frame fisheye) lies infinitely far out and bounds nothing; an edge
        // with fewer than half of its points invertible is not trusted.
        let (mut left, mut right, mut top, mut bottom) = (f64::MIN, f64::MAX, f64::MIN, f64::MAX);
        let mut found = [0usize; 4];
        for i in 0..=steps {
            let t = i as f64 / steps as f64;
            if let Some((u, _)) = edge(t, &|t| (0.0, t * h)) {
                left = left.max(u);
                found[0] += 1;
            }
            if let Some((u, _)) = edge(t, &|t| (w, t * h)) {
                right = right.min(u);
                found[1] += 1;
            }
            if let Some((_, v)) = edge(t, &|t| (t * w, 0.0)) {
                top = top.max(v);
                found[2] += 1;
            }
            if let Some((_, v)) = edge(t, &|t| (t * w, h)) {
                bottom = bottom.min(v);
                found[3] += 1;
            }
        }
        if found.iter().any(|&n| 2 * n < steps + 1) {
            return None;
        }
        if !(left < right && top < bottom) {
            return None;
        }
        let scale = 1f64.min(2.0 * w / ((right - left) * self.fx)).min(2.0 * h / ((bottom - top) * self.fy));
        let (fx, fy) = (self.fx * scale, self.fy * scale);
        let (ow, oh) = (((right - left) * fx).floor(), ((bottom - top) * fy).floor());
        if ow < 1.0 || oh < 1.0 {
            return None;
        }
        Some(Lens { width: ow as u32, height: oh as u32, fx, fy, cx: -left * fx, cy: -top * fy, distortion: Distortion::None })
    }
}

/// COLMAP's FOV factor `atan(2 r tan(ω/2)) / (r ω)` with its series near `ω = 0` and `r = 0`.
fn fov_factor(omega: f64, r2: f64) -> f64 {
    let o2 = omega * omega;
    if o2 < 1e-4 {
        o2 * r2 / 3.0 - o2 / 12.0 + 1.0
    } else if r2 < 1e-4 {
        let t = (omega / 2.0).tan();
        -2.0 * t * (4.0 * r2 * t * t - 3.0) / (3.0 * omega)
    } else {
        let r = r2.sqrt();
        (2.0 * r * (omega / 2.0).tan()).atan() / (r * omega)
    }
}

/// The inverse FOV factor `tan(r ω) / (2 r tan(ω/2))` with COLMAP's series.
fn fov_inverse_factor(omega: f64, r2: f64) -> f64 {
    let o2 = omega * omega;
    if o2 < 1e-4 {
        o2 * r2 / 3.0 - o2 / 12.0 + 1.0
    } else if r2 < 1e-4 {
        omega * (o2 * r2 + 3.0) / (6.0 * (omega / 2.0).tan())
    } else {
        let r = r2.sqrt();
        (r * omega).tan() / (2.0 * r * (omega / 2.0).tan())
    }
}

/// Pinhole-plane point to the equidistant fisheye plane: `(u, v)·atan(r)/r`.
fn fisheye_from_normal(u: f64, v: f64) -> (f64, f64) {
    let r = u.hypot(v);
    if r < 1e-12 {
        (u, v)
    } else {
        let f = r.atan() / r;
        (u * f, v * f)
    }
}

/// Inverse of [`fisheye_from_normal`]; `None` at or beyond 90°.
fn normal_from_fisheye(a: f64, b: f64) -> Option<(f64, f64)> {
    let theta = a.hypot(b);
    if theta >= std::f64::consts::FRAC_PI_2 * (1.0 - 1e-9) {
        return None;
    }
    if theta < 1e-12 {
        return Some((a, b));
    }
    let f = theta.tan() / theta;
    Some((a * f, b * f))
}

/// Bilinear sample at continuous pixel position `(px, py)` (pixel centres at `i + 0.5`), edges
/// clamped.
fn bilinear(img: &Image, px: f64, py: f64) -> [f32; 3] {
    let (x, y) = (px - 0.5, py - 0.5);
    let (x0, y0) = (x.floor(), y.floor());
    let (tx, ty) = ((x - x0) as f32, (y - y0) as f32);
    let cl = |v: f64, n: u32| v.clamp(0.0, (n - 1) as f64) as u32;
    let (xa, xb) = (cl(x0, img.width), cl(x0 + 1.0, img.width));
    let (ya, yb) = (cl(y0, img.height), cl(y0 + 1.0, img.height));
    let (p00, p10, p01, p11) = (img.pixel(xa, ya), img.pixel(xb, ya), img.pixel(xa, yb), img.pixel(xb, yb));
    std::array::from_fn(|c| {
        let top = p00[c] + (p10[c] - p00[c]) * tx;
        let bot = p01[c] + (p11[c] - p01[c]) * tx;
        top + (bot - top) * ty
    })
}

/// Resamples `img`, taken through `lens`, to the pinhole camera `target` (from
/// [`Lens::pinhole_target`]): each output pixel centre is distorted exactly and the source is
/// sampled bilinearly there.
pub fn undistort_image(img: &Image, lens: &Lens, target: &Lens) -> Image {
    let lens = lens.resized(img.width, img.height);
    let (w, h) = (target.width, target.height);
    let mut data = vec![0.0f32; w as usize * h as usize * 3];
    data.par_chunks_mut(w as usize * 3).enumerate().for_each(|(j, row)| {
        for i in 0..w as usize {
            let (u, v) = target.from_pixel(i as f64 + 0.5, j as f64 + 0.5);
            let (x, y) = lens.distort(u, v);
            let (px, py) = lens.to_pixel(x, y);
            row[i * 3..i * 3 + 3].copy_from_slice(&bilinear(img, px, py));
        }
    });
    Image { width: w, height: h, data }
}

/// Applies `lens`'s distortion to a pinhole image (the inverse of [`undistort_image`]): each
/// output pixel (an image of `lens.width × lens.height`) looks up the pinhole `source` taken with
/// `pinhole` by undistorting its centre; pixels with no pinhole preimage get `fill`. For tests and
/// synthetic distorted datasets.
pub fn distort_image(source: &Image, pinhole: &Lens, lens: &Lens, fill: [f32; 3]) -> Image {
    let (w, h) = (lens.width, lens.height);
    let mut data = vec![0.0f32; w as usize * h as usize * 3];
    data.par_chunks_mut(w as usize * 3).enumerate().for_each(|(j, row)| {
        for i in 0..w as usize {
            let (x, y) = lens.from_pixel(i as f64 + 0.5, j as f64 + 0.5);
            let px = match lens.undistort(x, y) {
                Some((u, v)) => {
                    let (px, py) = pinhole.to_pixel(u, v);
                    bilinear(source, px, py)
                }
                None => fill,
            };
            row[i * 3..i * 3 + 3].copy_from_slice(&px);
        }
    });
    Image { width: w, height: h, data }
}

/// Applies a pinhole lens's intrinsics to a camera (same pose).
pub fn apply_pinhole(camera: &mut Camera, lens: &Lens) {
    debug_assert!(lens.is_pinhole());
    camera.width = lens.width;
    camera.height = lens.height;
    camera.fx = lens.fx as f32;
    camera.fy = lens.fy as f32;
    camera.cx = lens.cx as f32;
    camera.cy = lens.cy as f32;
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lenses() -> Vec<(&'static str, Vec<f64>)> {
        vec![
            ("SIMPLE_RADIAL", vec![100.0, 64.0, 48.0, -0.12]),
            ("RADIAL", vec![100.0, 64.0, 48.0, -0.1, 0.02]),
            ("OPENCV", vec![100.0, 98.0, 63.0, 49.0, -0.1, 0.02, 0.001, -0.002]),
            ("OPENCV_FISHEYE", vec![60.0, 61.0, 64.0, 48.0, 0.05, -0.01, 0.002, -0.0005]),
            ("FULL_OPENCV", vec![100.0, 98.0, 63.0, 49.0, -0.1, 0.02, 0.001, -0.002, 0.003, 0.01, -0.002, 0.001]),
            ("FOV", vec![90.0, 91.0, 64.0, 48.0, 0.9]),
            ("SIMPLE_RADIAL_FISHEYE", vec![60.0, 64.0, 48.0, 0.04]),
            ("RADIAL_FISHEYE", vec![60.0, 64.0, 48.0, 0.04, -0.01]),
            ("THIN_PRISM_FISHEYE", vec![60.0, 61.0, 64.0, 48.0, 0.05, -0.01, 0.001, -0.001, 0.002, -0.0005, 0.001, -0.002]),
            (
                "RAD_TAN_THIN_PRISM_FISHEYE",
                vec![60.0, 61.0, 64.0, 48.0, 0.05, -0.01, 0.002, -0.0005, 1e-4, -1e-5, 0.001, -0.002, 0.001, -0.0005, -0.001, 0.0002],
            ),
            ("SIMPLE_DIVISION", vec![100.0, 64.0, 48.0, -0.15]),
            ("DIVISION", vec![100.0, 98.0, 63.0, 49.0, 0.2]),
            ("SIMPLE_FISHEYE", vec![60.0, 64.0, 48.0]),
            ("FISHEYE", vec![60.0, 61.0, 64.0, 48.0]),
            ("EUCM", vec![60.0, 61.0, 64.0, 48.0, 0.55, 1.05]),
        ]
    }

    #[test]
    fn every_model_round_trips() {
        for (model, p) in lenses() {
            let lens = Lens::from_colmap(model, 128, 96, &p).unwrap();
            assert!(!lens.is_pinhole(), "{model}");
            let mut worst: f64 = 0.0;
            for j in 0..=12 {
                for i in 0..=16 {
                    let (px, py) = (i as f64 * 128.0 / 16.0, j as f64 * 96.0 / 12.0);
                    let (x, y) = lens.from_pixel(px, py);
                    let (u, v) = lens.undistort(x, y).unwrap_or_else(|| panic!("{model}: no preimage of pixel ({px}, {py})"));
                    let (x2, y2) = lens.distort(u, v);
                    worst = worst.max((x2 - x).hypot(y2 - y));
                    // and back again from the pinhole side
                    let (u2, v2) = lens.undistort(x2, y2).unwrap();
                    worst = worst.max((u2 - u).hypot(v2 - v));
                }
            }
            assert!(worst < 1e-10, "{model}: round-trip error {worst:e}");
        }
    }

    #[test]
    fn forward_maps_match_hand_computed_values() {
        // OPENCV at (u, v) = (0.3, -0.2): r² = 0.13, radial = k1 r² + k2 r⁴.
        let l = Lens::from_colmap("OPENCV", 10, 10, &[1.0, 1.0, 0.0, 0.0, -0.1, 0.02, 0.001, -0.002]).unwrap();
        let (u, v, r2) = (0.3f64, -0.2f64, 0.13f64);
        let radial = -0.1 * r2 + 0.02 * r2 * r2;
        let x = u + u * radial + 2.0 * 0.001 * u * v + -0.002 * (r2 + 2.0 * u * u);
        let y = v + v * radial + 2.0 * -0.002 * u * v + 0.001 * (r2 + 2.0 * v * v);
        let (dx, dy) = l.distort(u, v);
        assert!((dx - x).abs() < 1e-15 && (dy - y).abs() < 1e-15);
        // OPENCV_FISHEYE: θ = atan(r), θd = θ(1 + k1θ² + …), x = u·θd/r.
        let l = Lens::from_colmap("OPENCV_FISHEYE", 10, 10, &[1.0, 1.0, 0.0, 0.0, 0.05, -0.01, 0.002, -0.0005]).unwrap();
        let r = r2.sqrt();
        let t = r.atan();
        let t2 = t * t;
        let td = t * (1.0 + 0.05 * t2 - 0.01 * t2 * t2 + 0.002 * t2.powi(3) - 0.0005 * t2.powi(4));
        let (dx, dy) = l.distort(u, v);
        assert!((dx - u * td / r).abs() < 1e-14 && (dy - v * td / r).abs() < 1e-14);
        // FOV: x = u · atan(2 r tan(ω/2)) / (r ω).
        let l = Lens::from_colmap("FOV", 10, 10, &[1.0, 1.0, 0.0, 0.0, 0.9]).unwrap();
        let f = (2.0 * r * 0.45f64.tan()).atan() / (r * 0.9);
        let (dx, _) = l.distort(u, v);
        assert!((dx - u * f).abs() < 1e-15);
        // RAD_TAN_THIN_PRISM_FISHEYE: (a, b) = (u, v)·θ/r, scaled by 1 + k0θ² + … + k5θ¹², then
        // tangential p0 p1 and thin prism s0..s3 on the scaled point.
        let (k, p, s) = ([0.05, -0.01, 0.002, -0.0005, 1e-4, -1e-5], [0.001, -0.002], [0.001, -0.0005, -0.001, 0.0002]);
        let params = [[1.0, 1.0, 0.0, 0.0], k[..4].try_into().unwrap(), [k[4], k[5], p[0], p[1]], s].concat();
        let l = Lens::from_colmap("RAD_TAN_THIN_PRISM_FISHEYE", 10, 10, &params).unwrap();
        let (a, b) = (u * t / r, v * t / r);
        let scale = 1.0 + (0..6).map(|i| k[i] * t2.powi(i as i32 + 1)).sum::<f64>();
        let (x, y) = (a * scale, b * scale);
        let q2 = x * x + y * y;
        let xd = x + 2.0 * p[1] * x * y + p[0] * (q2 + 2.0 * x * x) + s[0] * q2 + s[1] * q2 * q2;
        let yd = y + 2.0 * p[0] * x * y + p[1] * (q2 + 2.0 * y * y) + s[2] * q2 + s[3] * q2 * q2;
        let (dx, dy) = l.distort(u, v);
        assert!((dx - xd).abs() < 1e-15 && (dy - yd).abs() < 1e-15, "{dx} {dy} vs {xd} {yd}");
        // DIVISION: x = 2u / (1 + √(1 − 4k r²)); EUCM: x = u / (α√(βr² + 1) + 1 − α).
        let l = Lens::from_colmap("DIVISION", 10, 10, &[1.0, 1.0, 0.0, 0.0, 0.2]).unwrap();
        let (dx, _) = l.distort(u, v);
        assert!((dx - 2.0 * u / (1.0 + (1.0 - 0.8 * r2).sqrt())).abs() < 1e-15);
        let l = Lens::from_colmap("EUCM", 10, 10, &[1.0, 1.0, 0.0, 0.0, 0.55, 1.05]).unwrap();
        let (dx, _) = l.distort(u, v);
        assert!((dx - u / (0.55 * (1.05 * r2 + 1.0f64).sqrt() + 0.45)).abs() < 1e-15);
    }

    #[test]
    fn zero_distortion_is_pinhole_and_fisheye_rejects_beyond_90_degrees() {
        let l = Lens::from_colmap("OPENCV", 10, 10, &[5.0, 5.0, 5.0, 5.0, 0.0, 0.0, 0.0, 0.0]).unwrap();
        assert!(l.is_pinhole());
        let l = Lens::from_colmap("OPENCV_FISHEYE", 10, 10, &[5.0, 5.0, 5.0, 5.0, 0.0, 0.0, 0.0, 0.0]).unwrap();
        assert!(!l.is_pinhole());
        assert!(l.undistort(1.6, 0.0).is_none(), "θ = 1.6 rad is beyond 90°");
        assert!(l.undistort(1.0, 0.0).is_some());
        assert!(Lens::from_colmap("OPENCV", 10, 10, &[5.0; 4]).is_err());
        assert!(Lens::from_colmap("NOPE", 10, 10, &[]).is_err());
        // Division and EUCM without distortion are pinhole; EUCM's parameters are checked.
        assert!(Lens::from_colmap("DIVISION", 10, 10, &[5.0, 5.0, 5.0, 5.0, 0.0]).unwrap().is_pinhole());
        assert!(Lens::from_colmap("EUCM", 10, 10, &[5.0, 5.0, 5.0, 5.0, 0.0, 1.0]).unwrap().is_pinhole());
        assert!(Lens::from_colmap("EUCM", 10, 10, &[5.0, 5.0, 5.0, 5.0, 1.5, 1.0]).is_err());
        // The spherical model is refused by name, whether named or numbered.
        let e = Lens::from_colmap("EQUIRECTANGULAR", 10, 10, &[10.0, 10.0]).unwrap_err();
        assert!(e.contains("EQUIRECTANGULAR (id 17)") && e.contains("not supported"), "{e}");
        assert_eq!(colmap_model_error(Some(17), None), e);
        assert_eq!(colmap_model_error(Some(99), None), "unknown camera model id 99");
    }

    #[test]
    fn pinhole_target_has_no_blank_pixels() {
        let mut all = lenses();
        // A full-frame fisheye whose corners are beyond 90° (θ = 80/45 rad).
        all.push(("OPENCV_FISHEYE", vec![45.0, 45.0, 64.0, 48.0, 0.0, 0.0, 0.0, 0.0]));
        for (model, p) in all {
            let lens = Lens::from_colmap(model, 128, 96, &p).unwrap();
            let t = lens.pinhole_target().unwrap_or_else(|| panic!("{model}"));
            assert!(t.width > 32 && t.height > 24 && t.width <= 256 && t.height <= 192, "{model}: {t:?}");
            // Every output pixel centre lands inside the source image.
            for j in 0..t.height {
                for i in 0..t.width {
                    let (u, v) = t.from_pixel(i as f64 + 0.5, j as f64 + 0.5);
                    let (x, y) = lens.distort(u, v);
                    let (px, py) = lens.to_pixel(x, y);
                    assert!(
                        (-1e-6..=128.0 + 1e-6).contains(&px) && (-1e-6..=96.0 + 1e-6).contains(&py),
                        "{model}: ({i},{j}) -> ({px},{py})"
                    );
                }
            }
        }
    }
}

//! Pinhole cameras in the OpenCV convention: x right, y down, z forward.

use glam::{Mat3, Vec3};

/// A pinhole camera. `rotation`/`translation` map world to camera: `p_cam = R p_world + t`.
///
/// Pixel `(i, j)` covers `[i, i+1) x [j, j+1)` in continuous image coordinates, so its centre is at
/// `(i + 0.5, j + 0.5)`; a camera-space point projects to `(fx x/z + cx, fy y/z + cy)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Camera {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Focal length along x, in pixels.
    pub fx: f32,
    /// Focal length along y, in pixels.
    pub fy: f32,
    /// Principal point x, in continuous pixel coordinates.
    pub cx: f32,
    /// Principal point y, in continuous pixel coordinates.
    pub cy: f32,
    /// World-to-camera rotation `R`.
    pub rotation: Mat3,
    /// World-to-camera translation `t`.
    pub translation: Vec3,
    /// Gaussians whose centre has camera depth `z <= znear` are not drawn.
    pub znear: f32,
}

/// Near plane per unit of camera-rig size, and the default near plane in scene units.
///
/// The reference rasterizer culls at a fixed depth of 0.2, which breaks rescaled scenes (DESIGN
/// §8); we scale the near plane with the cameras instead: datasets use `DEFAULT_ZNEAR × s` with
/// `s` the median distance of the camera centres to their mean, orbits `DEFAULT_ZNEAR × radius`.
/// 0.05 gives the NeRF-synthetic rig (s = 4.03) a near plane of 0.2015, the reference's 0.2.
/// Rescaled scenes should scale it too ([`Camera::scaled`]).
pub const DEFAULT_ZNEAR: f32 = 0.05;

impl Camera {
    /// A camera from its world-to-camera rotation and translation, principal point at the centre.
    pub fn new(width: u32, height: u32, fx: f32, fy: f32, rotation: Mat3, translation: Vec3) -> Self {
        Camera { width, height, fx, fy, cx: width as f32 / 2.0, cy: height as f32 / 2.0, rotation, translation, znear: DEFAULT_ZNEAR }
    }

    /// From a NeRF/Blender camera-to-world matrix (OpenGL axes: x right, y up, z back), row-major 4x4.
    pub fn from_nerf_c2w(c2w: [[f32; 4]; 4], width: u32, height: u32, fx: f32, fy: f32, cx: f32, cy: f32) -> Self {
        // OpenGL -> OpenCV camera axes: flip y and z columns of the rotation.
        let col = |j: usize, s: f32| Vec3::new(c2w[0][j] * s, c2w[1][j] * s, c2w[2][j] * s);
        let r_c2w = Mat3::from_cols(col(0, 1.0), col(1, -1.0), col(2, -1.0));
        let center = Vec3::new(c2w[0][3], c2w[1][3], c2w[2][3]);
        let rotation = r_c2w.transpose();
        let translation = -(rotation * center);
        Camera { width, height, fx, fy, cx, cy, rotation, translation, znear: DEFAULT_ZNEAR }
    }

    /// A camera at `eye` looking at `target`; `up` is the world direction that appears up in the image.
    pub fn look_at(eye: Vec3, target: Vec3, up: Vec3, width: u32, height: u32, fov_x: f32) -> Self {
        let z = (target - eye).normalize();
        let x = z.cross(up).normalize_or(z.cross(Vec3::X).normalize_or(Vec3::Y)); // right = forward × up
        let y = z.cross(x);
        let rotation = Mat3::from_cols(x, y, z).transpose();
        let fx = width as f32 / (2.0 * (fov_x / 2.0).tan());
        Camera::new(width, height, fx, fx, rotation, -(rotation * eye))
    }

    /// `n` cameras evenly spaced on a circle of `radius` around `center` at `elevation` radians
    /// above the horizontal plane, with `up` as the world up axis.
    pub fn orbit(n: usize, center: Vec3, radius: f32, elevation: f32, up: Vec3, width: u32, height: u32, fov_x: f32) -> Vec<Camera> {
        let up = up.normalize();
        let a = up.any_orthonormal_vector();
        let b = up.cross(a);
        (0..n)
            .map(|i| {
                let phi = std::f32::consts::TAU * i as f32 / n.max(1) as f32;
                let dir = (a * phi.cos() + b * phi.sin()) * elevation.cos() + up * elevation.sin();
                let mut cam = Camera::look_at(center + dir * radius, center, up, width, height, fov_x);
                cam.znear = DEFAULT_ZNEAR * radius;
                cam
            })
            .collect()
    }

    /// Camera centre in world space.
    pub fn center(&self) -> Vec3 {
        -(self.rotation.transpose() * self.translation)
    }

    /// World point to camera space.
    pub fn to_camera(&self, p: Vec3) -> Vec3 {
        self.rotation * p + self.translation
    }

    /// The same camera for a scene scaled by `s` about the origin.
    pub fn scaled(&self, s: f32) -> Camera {
        Camera { translation: self.translation * s, znear: self.znear * s, ..*self }
    }

    /// Same camera at another resolution (intrinsics scaled accordingly).
    pub fn resized(&self, width: u32, height: u32) -> Camera {
        let (sx, sy) = (width as f32 / self.width as f32, height as f32 / self.height as f32);
        Camera { width, height, fx: self.fx * sx, fy: self.fy * sy, cx: self.cx * sx, cy: self.cy * sy, ..*self }
    }
}

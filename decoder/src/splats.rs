//! The scene: Gaussians as structure-of-arrays.

use rayon::prelude::*;

use crate::math::sh_rest_coeffs;

/// A problem with the contents of a scene.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SceneError {
    /// The SH degree is above 3.
    #[error("SH degree {0} is not supported (0..=3)")]
    BadShDegree(u8),
    /// An array's length does not match the Gaussian count.
    #[error("array `{name}` has {got} entries, expected {expected}")]
    LengthMismatch {
        /// The array's field name.
        name: &'static str,
        /// Its length.
        got: usize,
        /// The length it should have.
        expected: usize,
    },
    /// A value is NaN or infinite.
    #[error("Gaussian {index}: `{name}` is not finite")]
    NonFinite {
        /// The Gaussian.
        index: usize,
        /// The array's field name.
        name: &'static str,
    },
    /// A rotation is the zero quaternion.
    #[error("Gaussian {index}: rotation quaternion has zero norm")]
    ZeroQuaternion {
        /// The Gaussian.
        index: usize,
    },
}

/// 3D Gaussians, structure-of-arrays, in the parameterisation of the reference 3DGS trainer.
///
/// * `rotations` are quaternions `(w, x, y, z)`; they need not be normalised (the renderer does).
/// * `log_scales` are natural logs of the three standard deviations.
/// * `opacity_logits` go through a sigmoid.
/// * `sh_dc` is the degree-0 SH coefficient per channel (colour = SH + 0.5).
/// * `sh_rest` holds, for Gaussian `i`, coefficient `k` (1-based band order minus the DC term,
///   `k < K = (d+1)^2 - 1`) of channel `c` at `sh_rest[(i * K + k) * 3 + c]`
///   (coefficient-major, channels interleaved — unlike the channel-major `.ply` layout).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Splats {
    /// SH degree `d` (0..=3).
    pub sh_degree: u8,
    /// Centres x y z.
    pub positions: Vec<[f32; 3]>,
    /// Natural logs of the standard deviations along the local axes.
    pub log_scales: Vec<[f32; 3]>,
    /// Quaternions `(w, x, y, z)`, not necessarily normalised.
    pub rotations: Vec<[f32; 4]>,
    /// Opacities before the sigmoid.
    pub opacity_logits: Vec<f32>,
    /// Degree-0 SH coefficient per colour channel.
    pub sh_dc: Vec<[f32; 3]>,
    /// Higher SH coefficients, `[(i * K + k) * 3 + c]` (see above).
    pub sh_rest: Vec<f32>,
}

impl Splats {
    /// An empty scene of the given SH degree.
    pub fn new(sh_degree: u8) -> Self {
        Splats { sh_degree, ..Default::default() }
    }

    /// Number of Gaussians.
    pub fn len(&self) -> usize {
        self.positions.len()
    }

    /// Whether the scene has no Gaussians.
    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }

    /// Number of non-DC SH coefficients per channel, `(d+1)^2 - 1`.
    pub fn rest_coeffs(&self) -> usize {
        sh_rest_coeffs(self.sh_degree)
    }

    /// The `K*3` rest coefficients of Gaussian `i` (`[k][channel]`).
    pub fn rest_of(&self, i: usize) -> &[f32] {
        let k3 = self.rest_coeffs() * 3;
        &self.sh_rest[i * k3..(i + 1) * k3]
    }

    /// Appends one Gaussian; `rest` must hold `rest_coeffs() * 3` values.
    pub fn push(&mut self, pos: [f32; 3], log_scale: [f32; 3], rot: [f32; 4], opacity_logit: f32, dc: [f32; 3], rest: &[f32]) {
        debug_assert_eq!(rest.len(), self.rest_coeffs() * 3);
        self.positions.push(pos);
        self.log_scales.push(log_scale);
        self.rotations.push(rot);
        self.opacity_logits.push(opacity_logit);
        self.sh_dc.push(dc);
        self.sh_rest.extend_from_slice(rest);
    }

    /// Keeps the Gaussians for which `keep(i)` is true, in order.
    pub fn retain_indices(&mut self, keep: impl Fn(usize) -> bool) {
        let k3 = self.rest_coeffs() * 3;
        let mut out = Splats::new(self.sh_degree);
        for i in 0..self.len() {
            if keep(i) {
                out.push(
                    self.positions[i],
                    self.log_scales[i],
                    self.rotations[i],
                    self.opacity_logits[i],
                    self.sh_dc[i],
                    &self.sh_rest[i * k3..(i + 1) * k3],
                );
            }
        }
        *self = out;
    }

    /// The same scene with SH truncated (or zero-extended) to `degree`.
    pub fn with_sh_degree(&self, degree: u8) -> Splats {
        let (k_old, k_new) = (self.rest_coeffs(), sh_rest_coeffs(degree));
        let mut out = Splats { sh_degree: degree, sh_rest: Vec::with_capacity(self.len() * k_new * 3), ..self.clone() };
        for i in 0..self.len() {
            for k in 0..k_new {
                for c in 0..3 {
                    out.sh_rest.push(if k < k_old { self.sh_rest[(i * k_old + k) * 3 + c] } else { 0.0 });
                }
            }
        }
        out
    }

    /// Checks array lengths, finiteness and non-zero quaternions.
    pub fn validate(&self) -> Result<(), SceneError> {
        if self.sh_degree > 3 {
            return Err(SceneError::BadShDegree(self.sh_degree));
        }
        let n = self.len();
        let check = |name, got| if got == n { Ok(()) } else { Err(SceneError::LengthMismatch { name, got, expected: n }) };
        check("log_scales", self.log_scales.len())?;
        check("rotations", self.rotations.len())?;
        check("opacity_logits", self.opacity_logits.len())?;
        check("sh_dc", self.sh_dc.len())?;
        let k3 = self.rest_coeffs() * 3;
        if self.sh_rest.len() != n * k3 {
            return Err(SceneError::LengthMismatch { name: "sh_rest", got: self.sh_rest.len(), expected: n * k3 });
        }
        for i in 0..n {
            let finite = |v: &[f32]| v.iter().all(|x| x.is_finite());
            let fields: [(&'static str, bool); 6] = [
                ("position", finite(&self.positions[i])),
                ("scale", finite(&self.log_scales[i])),
                ("rotation", finite(&self.rotations[i])),
                ("opacity", self.opacity_logits[i].is_finite()),
                ("f_dc", finite(&self.sh_dc[i])),
                ("f_rest", finite(&self.sh_rest[i * k3..(i + 1) * k3])),
            ];
            if let Some((name, _)) = fields.iter().find(|(_, ok)| !ok) {
                return Err(SceneError::NonFinite { index: i, name });
            }
            if self.rotations[i].iter().all(|&x| x == 0.0) {
                return Err(SceneError::ZeroQuaternion { index: i });
            }
        }
        Ok(())
    }

    /// Axis-aligned bounds of the positions, `None` when empty.
    pub fn bounds(&self) -> Option<([f32; 3], [f32; 3])> {
        let mut it = self.positions.iter();
        let first = *it.next()?;
        Some(it.fold((first, first), |(lo, hi), p| (std::array::from_fn(|a| lo[a].min(p[a])), std::array::from_fn(|a| hi[a].max(p[a])))))
    }

    /// The scene as a binary little-endian INRIA `.ply` file (normals written as zero, like the
    /// reference trainer): what `gscodec decode` writes.
    pub fn to_ply(&self) -> Vec<u8> {
        let k = self.rest_coeffs();
        let n = self.len();
        let mut names: Vec<String> =
            ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"].iter().map(|s| s.to_string()).collect();
        names.extend((0..3 * k).map(|i| format!("f_rest_{i}")));
        names.extend(["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"].iter().map(|s| s.to_string()));
        let mut header = format!("ply\nformat binary_little_endian 1.0\nelement vertex {n}\n");
        for name in &names {
            header.push_str(&format!("property float {name}\n"));
        }
        header.push_str("end_header\n");
        let stride = names.len() * 4;
        let mut out = header.into_bytes();
        let start = out.len();
        out.resize(start + n * stride, 0);
        out[start..].par_chunks_mut(stride).enumerate().for_each(|(i, rec)| {
            let mut vals = Vec::with_capacity(names.len());
            vals.extend_from_slice(&self.positions[i]);
            vals.extend_from_slice(&[0.0; 3]);
            vals.extend_from_slice(&self.sh_dc[i]);
            let rest = &self.sh_rest[i * k * 3..(i + 1) * k * 3];
            for c in 0..3 {
                for kk in 0..k {
                    vals.push(rest[kk * 3 + c]);
                }
            }
            vals.push(self.opacity_logits[i]);
            vals.extend_from_slice(&self.log_scales[i]);
            vals.extend_from_slice(&self.rotations[i]);
            for (dst, v) in rec.chunks_exact_mut(4).zip(vals) {
                dst.copy_from_slice(&v.to_le_bytes());
            }
        });
        out
    }
}

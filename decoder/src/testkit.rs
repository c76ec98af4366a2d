//! The test kit of both crates: how a test skips, random scenes, the camera rig of synthetic
//! scenes and the shared GPU renderer. Not part of the decoder's API (hidden from its docs); it
//! lives in the lowest crate so that the decoder's tests and the encoder's (through
//! `gscodec::testkit`, which adds the real-data locator) use one definition of each.
//!
//! | item | one job |
//! |---|---|
//! | [`skip`] | a test that cannot run says so: `SKIPPED: <test>: <reason>` |
//! | [`random_splats`], [`random_splats_in`], [`SceneRanges`] | seeded random scenes of any size and SH degree |
//! | [`extreme_splats`] | DESIGN §8's extreme Gaussians in one scene |
//! | [`rig_cameras`] | the cameras around a synthetic scene at the origin |
//! | `gpu_renderer` (feature `gpu`) | one wgpu renderer per test binary, or a skip when there is no adapter |
//!
//! Random inputs come from [`crate::rng::Rng`], the project's one PRNG.

use crate::math::sh_rest_coeffs;
use crate::rng::Rng;
use crate::{Camera, Splats};
use glam::Vec3;
use std::io::Write;

/// The environment variable naming a file that [`skip`] appends its line to.
pub const SKIP_LOG_ENV: &str = "GSCODEC_SKIP_LOG";

/// Reports that the calling test skips (the caller then returns): prints
/// `SKIPPED: <binary>::<test>: <reason>` on stdout and, when `$GSCODEC_SKIP_LOG` names a file,
/// appends the same line to it. `cargo test` hides a passing test's stdout, so CI counts the
/// lines of that file (`scripts/count-skips`). The test's name is its thread's, which the test
/// harness sets.
pub fn skip(reason: impl std::fmt::Display) {
    let line = format!("SKIPPED: {}: {reason}", test_name());
    println!("{line}");
    if let Some(path) = std::env::var_os(SKIP_LOG_ENV) {
        // One `write` of a whole line to a file opened for appending: lines from parallel tests
        // and test binaries do not interleave.
        let appended =
            std::fs::OpenOptions::new().create(true).append(true).open(&path).and_then(|mut f| f.write_all(format!("{line}\n").as_bytes()));
        if let Err(e) = appended {
            panic!("{}: cannot append the skip line: {e}", std::path::Path::new(&path).display());
        }
    }
}

/// `<binary>::<test>`: the test binary's name without cargo's hash suffix, and the current
/// thread's name (the harness names each test's thread after the test).
fn test_name() -> String {
    let exe = std::env::current_exe().ok().and_then(|p| p.file_stem().map(|s| s.to_string_lossy().into_owned())).unwrap_or_default();
    let binary = match exe.rsplit_once('-') {
        Some((name, hash)) if !hash.is_empty() && hash.bytes().all(|b| b.is_ascii_hexdigit()) => name.to_string(),
        _ => exe,
    };
    let thread = std::thread::current();
    format!("{binary}::{}", thread.name().unwrap_or("?"))
}

/// Parameter ranges of [`random_splats_in`]. The default is a small coloured scene that
/// [`rig_cameras`] at radius 3.5–4 sees whole: centres in the unit ball, log-scales in
/// [−2.6, −1.8], opacity logits in [1, 3], SH DC in ±0.8, higher bands in ±0.3.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SceneRanges {
    /// Semi-axes of the ellipsoid around the origin whose inside holds the centres (uniformly).
    pub extent: [f32; 3],
    /// Range of each log-scale (uniform per axis).
    pub log_scale: [f32; 2],
    /// Range of the opacity logits (uniform).
    pub opacity: [f32; 2],
    /// The SH DC coefficients are uniform in `±sh_dc`.
    pub sh_dc: f32,
    /// The higher-band SH coefficients are uniform in `±sh_rest`.
    pub sh_rest: f32,
}

impl Default for SceneRanges {
    fn default() -> Self {
        SceneRanges { extent: [1.0; 3], log_scale: [-2.6, -1.8], opacity: [1.0, 3.0], sh_dc: 0.8, sh_rest: 0.3 }
    }
}

/// `n` random Gaussians of SH degree `degree` from `seed`, with [`SceneRanges::default`].
pub fn random_splats(n: usize, degree: u8, seed: u64) -> Splats {
    random_splats_in(n, degree, seed, &SceneRanges::default())
}

/// `n` random Gaussians of SH degree `degree` from `seed` within `ranges`. Rotations are
/// uniformly distributed (normalised 4-D normal quaternions, stored unnormalised).
pub fn random_splats_in(n: usize, degree: u8, seed: u64, ranges: &SceneRanges) -> Splats {
    let mut rng = Rng::new(seed);
    let mut s = Splats::new(degree);
    let rest_len = sh_rest_coeffs(degree) * 3;
    let [lo, hi] = ranges.log_scale;
    let [op_lo, op_hi] = ranges.opacity;
    while s.len() < n {
        let p = [0, 1, 2].map(|_| 2.0 * rng.uniform() - 1.0);
        if p.iter().map(|v| v * v).sum::<f32>() > 1.0 {
            continue;
        }
        let pos = [0, 1, 2].map(|a| p[a] * ranges.extent[a]);
        let log_scale = [0, 1, 2].map(|_| rng.range(lo, hi));
        let rot = [0, 1, 2, 3].map(|_| rng.normal());
        let dc = [0, 1, 2].map(|_| rng.range(-ranges.sh_dc, ranges.sh_dc));
        let rest: Vec<f32> = (0..rest_len).map(|_| rng.range(-ranges.sh_rest, ranges.sh_rest)).collect();
        s.push(pos, log_scale, rot, rng.range(op_lo, op_hi), dc, &rest);
    }
    s
}

/// One scene with DESIGN §8's extreme Gaussians, all valid input: sub-pixel and view-filling
/// (log-scale −20 and +10), degenerate covariances (a disc and a needle), a nearly zero-norm
/// quaternion, opacity logits ±100, one Gaussian at the origin (put a camera there to test "at the
/// camera centre") and an ordinary one; SH rest coefficients of ±1 at `degree`. (An exactly
/// zero quaternion is invalid input: [`Splats::validate`] refuses it.)
pub fn extreme_splats(degree: u8) -> Splats {
    let mut s = Splats::new(degree);
    let rest: Vec<f32> = (0..sh_rest_coeffs(degree) * 3).map(|i| if i % 2 == 0 { 1.0 } else { -1.0 }).collect();
    let q = [1.0, 0.0, 0.0, 0.0];
    let mut push =
        |pos: [f32; 3], log_scale: [f32; 3], rot: [f32; 4], opacity: f32| s.push(pos, log_scale, rot, opacity, [0.5, -0.5, 1.0], &rest);
    push([0.2, 0.1, 0.3], [-2.0; 3], q, 1.0); // ordinary
    push([0.1, -0.2, 0.0], [-20.0; 3], q, 2.0); // sub-pixel
    push([0.0, 0.0, 0.5], [10.0; 3], q, -1.0); // fills every view
    push([-0.3, 0.2, 0.1], [-1.0, -1.2, -20.0], [0.9, 0.3, -0.2, 0.1], 3.0); // flat disc
    push([0.3, 0.3, -0.2], [-0.5, -20.0, -20.0], [0.2, 0.9, 0.1, -0.4], 3.0); // needle
    push([-0.1, -0.1, -0.1], [-2.0; 3], [1e-30, 0.0, 0.0, 0.0], 1.0); // nearly zero-norm quaternion
    push([0.15, -0.05, 0.2], [-1.5; 3], q, 100.0); // opaque
    push([-0.2, 0.0, 0.25], [-1.5; 3], q, -100.0); // invisible
    push([0.0; 3], [-2.5; 3], q, 2.0); // at the origin
    s
}

/// The camera rig of the synthetic scenes of tests and benches: `n` cameras around the origin at
/// `radius`, half on a ring 0.35 rad above the x-y plane and half 0.25 rad below it (up +z,
/// horizontal field of view 0.9 rad). Scenes framed from their own content use
/// `gscodec::views::orbit_cameras`.
pub fn rig_cameras(n: usize, radius: f32, width: u32, height: u32) -> Vec<Camera> {
    let half = n / 2;
    let mut cams = Camera::orbit(half, Vec3::ZERO, radius, 0.35, Vec3::Z, width, height, 0.9);
    cams.extend(Camera::orbit(n - half, Vec3::ZERO, radius, -0.25, Vec3::Z, width, height, 0.9));
    cams
}

/// One wgpu renderer for the whole test binary (device creation and shader compilation are slow
/// on a software adapter). Without any adapter it calls [`skip`] (each caller's test says it
/// skipped) and returns `None`.
///
/// # Panics
/// When an adapter exists but the renderer cannot be created on it: that is a failure, not a skip.
#[cfg(feature = "gpu")]
pub fn gpu_renderer() -> Option<&'static crate::render::gpu::GpuRenderer> {
    use crate::render::gpu::{GpuError, GpuRenderer};
    static RENDERER: std::sync::OnceLock<Result<GpuRenderer, String>> = std::sync::OnceLock::new();
    let made = RENDERER.get_or_init(|| match GpuRenderer::new() {
        Ok(r) => {
            eprintln!("GPU tests use adapter: {}", r.adapter_name());
            Ok(r)
        }
        Err(GpuError::NoAdapter(e)) => Err(format!("no GPU adapter ({e}); install mesa-vulkan-drivers for lavapipe")),
        Err(e) => panic!("an adapter exists but the renderer failed: {e}"),
    });
    match made {
        Ok(r) => Some(r),
        Err(reason) => {
            skip(reason);
            None
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn random_scenes_are_seeded_sized_and_within_their_ranges() {
        let r = SceneRanges { extent: [2.0, 1.0, 0.5], log_scale: [-4.0, -3.0], opacity: [-1.0, 0.0], sh_dc: 0.3, sh_rest: 0.1 };
        let s = random_splats_in(500, 2, 9, &r);
        assert_eq!((s.len(), s.sh_degree), (500, 2));
        s.validate().unwrap();
        assert_eq!(s, random_splats_in(500, 2, 9, &r));
        assert_ne!(s, random_splats_in(500, 2, 10, &r));
        for i in 0..s.len() {
            let p = s.positions[i];
            assert!((0..3).map(|a| (p[a] / r.extent[a]).powi(2)).sum::<f32>() <= 1.0);
            assert!(s.log_scales[i].iter().all(|v| (-4.0..=-3.0).contains(v)));
            assert!((-1.0..=0.0).contains(&s.opacity_logits[i]));
            assert!(s.sh_dc[i].iter().all(|v| v.abs() <= 0.3));
        }
        assert!(s.sh_rest.iter().all(|v| v.abs() <= 0.1));
        // Centres fill the ellipsoid rather than one corner of it.
        let spread = |a: usize| s.positions.iter().map(|p| p[a]).fold(0.0f32, |m, v| m.max(v.abs())) / r.extent[a];
        assert!((0..3).all(|a| spread(a) > 0.8));
        assert_eq!(s.sh_rest.len(), 500 * 8 * 3);
        assert!(s.sh_rest.iter().any(|&v| v != 0.0));
    }

    #[test]
    fn extreme_scene_is_valid_input_and_rig_cameras_look_at_the_origin() {
        extreme_splats(3).validate().unwrap();
        let cams = rig_cameras(5, 4.0, 32, 24);
        assert_eq!(cams.len(), 5);
        for c in &cams {
            assert!((c.center().length() - 4.0).abs() < 1e-4);
            assert!(c.to_camera(Vec3::ZERO).z > 3.9, "the origin is in front of every camera");
        }
    }
}

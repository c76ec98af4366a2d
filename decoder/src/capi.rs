//! C ABI (cargo feature `capi`); the declarations are in `include/gscodec.h`.
//!
//! * Every function catches panics (`catch_unwind`), so no unwinding crosses the boundary; a
//!   caught panic becomes `GSC_ERR_INTERNAL`.
//! * Failures return a negative code, one per [`DecodeError::class`] (plus `GSC_ERR_ARGUMENT`
//!   and `GSC_ERR_INTERNAL`; [`gsc_error_class`] names a code), and set a thread-local message
//!   readable with [`gsc_last_error`] until the next failing call on the same thread.
//! * A decoded scene is an opaque `GscScene*` owned by the caller and released with
//!   [`gsc_scene_free`]; the array pointers it hands out live exactly as long as the scene.

#![allow(unsafe_code)] // the C ABI takes raw pointers; every unsafe block states its contract

use crate::{decode_with, peek_header, DecodeError, Decoder, Limits, Splats};
use std::cell::RefCell;
use std::ffi::{c_char, c_int, CString};
use std::panic::{catch_unwind, AssertUnwindSafe};

/// Success.
pub const GSC_OK: c_int = 0;
/// A required pointer argument was NULL (or an argument was out of range).
pub const GSC_ERR_ARGUMENT: c_int = -1;
/// Class `format`: not a valid `.gsc` file (bad magic, truncated, corrupt, missing section,
/// trailing data).
pub const GSC_ERR_FORMAT: c_int = -2;
/// Class `unsupported`: another major version, or an unknown required section.
pub const GSC_ERR_UNSUPPORTED: c_int = -3;
/// A bug inside the decoder (a caught panic).
pub const GSC_ERR_INTERNAL: c_int = -4;
/// Class `checksum`: a CRC-32 does not match.
pub const GSC_ERR_CHECKSUM: c_int = -5;
/// Class `limits`: the file exceeds the format's bounds or the caller's limits.
pub const GSC_ERR_LIMITS: c_int = -6;
/// Class `io`: reading the input failed.
pub const GSC_ERR_IO: c_int = -7;

/// Limits of a decode (see [`Limits`]); `gsc_default_limits` gives the defaults.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct GscLimits {
    /// Most Gaussians a file may hold.
    pub max_gaussians: u32,
    /// Byte budget of the decode (file + decoded values + scene).
    pub max_bytes: u64,
    /// SH bands above this degree (0..=3) are not decoded.
    pub max_sh_degree: c_int,
}

/// A decoded scene (opaque to C).
pub struct GscScene {
    splats: Splats,
}

thread_local! {
    static LAST_ERROR: RefCell<CString> = RefCell::new(CString::default());
}

fn set_error(msg: impl std::fmt::Display) {
    let text = CString::new(msg.to_string().replace('\0', " ")).unwrap_or_default();
    LAST_ERROR.with(|e| *e.borrow_mut() = text);
}

/// Runs `f`, turning a panic into `GSC_ERR_INTERNAL`.
fn guarded(f: impl FnOnce() -> c_int) -> c_int {
    match catch_unwind(AssertUnwindSafe(f)) {
        Ok(code) => code,
        Err(p) => {
            let what = p.downcast_ref::<&str>().map(|s| s.to_string()).or_else(|| p.downcast_ref::<String>().cloned()).unwrap_or_default();
            set_error(format!("internal error: {what}"));
            GSC_ERR_INTERNAL
        }
    }
}

fn decode_error_code(e: &DecodeError) -> c_int {
    set_error(e);
    match e.class() {
        "format" => GSC_ERR_FORMAT,
        "checksum" => GSC_ERR_CHECKSUM,
        "unsupported" => GSC_ERR_UNSUPPORTED,
        "limits" => GSC_ERR_LIMITS,
        "io" => GSC_ERR_IO,
        _ => GSC_ERR_INTERNAL,
    }
}

/// The class name of a result code: `"ok"`, `"argument"`, `"format"`, `"checksum"`,
/// `"unsupported"`, `"limits"`, `"io"`, `"internal"`, or `"unknown"` (a static string).
#[no_mangle]
pub extern "C" fn gsc_error_class(code: c_int) -> *const c_char {
    let name: &'static [u8] = match code {
        GSC_OK => b"ok\0",
        GSC_ERR_ARGUMENT => b"argument\0",
        GSC_ERR_FORMAT => b"format\0",
        GSC_ERR_CHECKSUM => b"checksum\0",
        GSC_ERR_UNSUPPORTED => b"unsupported\0",
        GSC_ERR_LIMITS => b"limits\0",
        GSC_ERR_IO => b"io\0",
        GSC_ERR_INTERNAL => b"internal\0",
        _ => b"unknown\0",
    };
    name.as_ptr() as *const c_char
}

/// The default limits (16.7 M Gaussians, 4 GiB, SH degree 3).
#[no_mangle]
pub extern "C" fn gsc_default_limits() -> GscLimits {
    let l = Limits::default();
    GscLimits { max_gaussians: l.max_gaussians, max_bytes: l.max_bytes, max_sh_degree: c_int::from(l.max_sh_degree) }
}

/// # Safety
/// `data` must point to `len` readable bytes (or be NULL with `len == 0`).
unsafe fn bytes<'a>(data: *const u8, len: usize) -> Option<&'a [u8]> {
    if data.is_null() {
        return (len == 0).then_some(&[]);
    }
    // SAFETY: the caller guarantees `len` readable bytes at `data`.
    Some(unsafe { std::slice::from_raw_parts(data, len) })
}

/// Decodes `len` bytes at `data` into a new scene stored in `*out` (NULL on failure), with the
/// default limits. `max_sh_degree` (0..=3) skips higher SH bands; `threads` = 0 uses all cores,
/// 1 decodes on the calling thread.
///
/// # Safety
/// `data` must point to `len` readable bytes; `out` must be a valid pointer to write to.
#[no_mangle]
pub unsafe extern "C" fn gsc_decode(data: *const u8, len: usize, max_sh_degree: c_int, threads: c_int, out: *mut *mut GscScene) -> c_int {
    let limits = GscLimits { max_sh_degree, ..gsc_default_limits() };
    // SAFETY: the caller's guarantees are passed on unchanged.
    unsafe { gsc_decode_limited(data, len, &limits, threads, out) }
}

/// As [`gsc_decode`], with `*limits` (NULL: the defaults).
///
/// # Safety
/// `data` must point to `len` readable bytes; `limits` is NULL or readable; `out` must be a
/// valid pointer to write to.
#[no_mangle]
pub unsafe extern "C" fn gsc_decode_limited(
    data: *const u8,
    len: usize,
    limits: *const GscLimits,
    threads: c_int,
    out: *mut *mut GscScene,
) -> c_int {
    guarded(|| {
        if out.is_null() {
            set_error("gsc_decode: `out` is NULL");
            return GSC_ERR_ARGUMENT;
        }
        // SAFETY: checked non-null; the caller guarantees it is writable.
        unsafe { *out = std::ptr::null_mut() };
        let Some(input) = (unsafe { bytes(data, len) }) else {
            set_error("gsc_decode: `data` is NULL");
            return GSC_ERR_ARGUMENT;
        };
        // SAFETY: NULL or readable per the contract.
        let l = if limits.is_null() { gsc_default_limits() } else { unsafe { *limits } };
        if !(0..=3).contains(&l.max_sh_degree) || threads < 0 {
            set_error(format!("gsc_decode: max_sh_degree {} must be 0..=3 and threads {threads} >= 0", l.max_sh_degree));
            return GSC_ERR_ARGUMENT;
        }
        let limits = Limits { max_gaussians: l.max_gaussians, max_bytes: l.max_bytes, max_sh_degree: l.max_sh_degree as u8 };
        let result = if threads == 0 {
            decode_with(input, &limits)
        } else {
            let mut d = Decoder::with_limits(input, limits);
            d.set_threads(threads as usize);
            d.read_info().and_then(|r| r.decode())
        };
        match result {
            Ok(splats) => {
                // SAFETY: as above.
                unsafe { *out = Box::into_raw(Box::new(GscScene { splats })) };
                GSC_OK
            }
            Err(e) => decode_error_code(&e),
        }
    })
}

/// Reads only the header: Gaussian count and SH degree (either output pointer may be NULL).
///
/// # Safety
/// `data` must point to `len` readable bytes; non-NULL outputs must be writable.
#[no_mangle]
pub unsafe extern "C" fn gsc_peek_header(data: *const u8, len: usize, count: *mut u32, sh_degree: *mut c_int) -> c_int {
    guarded(|| {
        let Some(input) = (unsafe { bytes(data, len) }) else {
            set_error("gsc_peek_header: `data` is NULL");
            return GSC_ERR_ARGUMENT;
        };
        match peek_header(input) {
            Ok(h) => {
                // SAFETY: non-null outputs are writable per the contract.
                unsafe {
                    if !count.is_null() {
                        *count = h.gaussians;
                    }
                    if !sh_degree.is_null() {
                        *sh_degree = h.sh_degree as c_int;
                    }
                }
                GSC_OK
            }
            Err(e) => decode_error_code(&e),
        }
    })
}

/// Releases a scene from [`gsc_decode`]; NULL is ignored.
///
/// # Safety
/// `scene` must come from [`gsc_decode`] and not have been freed already.
#[no_mangle]
pub unsafe extern "C" fn gsc_scene_free(scene: *mut GscScene) {
    if !scene.is_null() {
        let _ = catch_unwind(AssertUnwindSafe(|| {
            // SAFETY: created by Box::into_raw in gsc_decode, freed once per the contract.
            drop(unsafe { Box::from_raw(scene) });
        }));
    }
}

/// # Safety
/// `scene` is NULL or a live scene from [`gsc_decode`].
unsafe fn with_scene<T: Default>(scene: *const GscScene, f: impl FnOnce(&Splats) -> T) -> T {
    if scene.is_null() {
        return T::default();
    }
    // SAFETY: live scene per the contract; `f` only reads.
    let s = unsafe { &(*scene).splats };
    catch_unwind(AssertUnwindSafe(|| f(s))).unwrap_or_default()
}

macro_rules! accessor {
    ($(#[$doc:meta])* $name:ident, $field:ident) => {
        $(#[$doc])*
        ///
        /// # Safety
        /// `scene` is NULL (gives NULL) or a live scene from [`gsc_decode`].
        #[no_mangle]
        pub unsafe extern "C" fn $name(scene: *const GscScene) -> *const f32 {
            unsafe { with_scene(scene, |s| Ptr(s.$field.as_ptr() as *const f32)) }.0
        }
    };
}

/// Raw pointer with a NULL default (for [`with_scene`]).
struct Ptr(*const f32);
impl Default for Ptr {
    fn default() -> Self {
        Ptr(std::ptr::null())
    }
}

/// Number of Gaussians (0 for NULL).
///
/// # Safety
/// `scene` is NULL or a live scene from [`gsc_decode`].
#[no_mangle]
pub unsafe extern "C" fn gsc_scene_count(scene: *const GscScene) -> usize {
    unsafe { with_scene(scene, |s| s.len()) }
}

/// SH degree of the decoded scene (after `max_sh_degree`), -1 for NULL.
///
/// # Safety
/// `scene` is NULL or a live scene from [`gsc_decode`].
#[no_mangle]
pub unsafe extern "C" fn gsc_scene_sh_degree(scene: *const GscScene) -> c_int {
    if scene.is_null() {
        return -1;
    }
    unsafe { with_scene(scene, |s| s.sh_degree as c_int) }
}

/// Non-DC SH coefficients per channel, `(degree+1)^2 - 1` (0 for NULL).
///
/// # Safety
/// `scene` is NULL or a live scene from [`gsc_decode`].
#[no_mangle]
pub unsafe extern "C" fn gsc_scene_sh_rest_coeffs(scene: *const GscScene) -> usize {
    unsafe { with_scene(scene, |s| s.rest_coeffs()) }
}

accessor!(
    /// `count × 3` floats: x, y, z.
    gsc_scene_positions, positions
);
accessor!(
    /// `count × 3` floats: natural-log standard deviations.
    gsc_scene_log_scales, log_scales
);
accessor!(
    /// `count × 4` floats: quaternion w, x, y, z (not necessarily normalised).
    gsc_scene_rotations, rotations
);
accessor!(
    /// `count` floats: opacity before the sigmoid.
    gsc_scene_opacity_logits, opacity_logits
);
accessor!(
    /// `count × 3` floats: SH DC coefficient per channel (colour = 0.28209479·dc + 0.5).
    gsc_scene_sh_dc, sh_dc
);
accessor!(
    /// `count × K × 3` floats: for Gaussian `i`, coefficient `k`, channel `c` at `(i*K + k)*3 + c`
    /// with `K = gsc_scene_sh_rest_coeffs(scene)`.
    gsc_scene_sh_rest, sh_rest
);

/// The message of the last failure on this thread ("" if none). Valid until the next failing call
/// on this thread; never NULL.
#[no_mangle]
pub extern "C" fn gsc_last_error() -> *const c_char {
    LAST_ERROR.with(|e| e.borrow().as_ptr())
}

/// Library version, e.g. `"0.1.0"` (static string).
#[no_mangle]
pub extern "C" fn gsc_version() -> *const c_char {
    concat!(env!("CARGO_PKG_VERSION"), "\0").as_ptr() as *const c_char
}

/// A pinhole camera (OpenCV axes: x right, y down, z forward): `p_cam = R p_world + t`.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct GscCamera {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Focal length along x, in pixels.
    pub fx: f32,
    /// Focal length along y, in pixels.
    pub fy: f32,
    /// Principal point x, in continuous pixel coordinates (pixel centres at i + 0.5).
    pub cx: f32,
    /// Principal point y.
    pub cy: f32,
    /// World-to-camera rotation `R`, row-major.
    pub rotation: [f32; 9],
    /// World-to-camera translation `t`.
    pub translation: [f32; 3],
    /// Near plane: Gaussians at camera depth `z <= znear` are not drawn (<= 0: 0.05).
    pub znear: f32,
}

/// Output pixels: 4 floats per pixel, linear RGB as rendered plus alpha 1.
pub const GSC_PIXEL_RGBA_F32: c_int = 0;
/// Output pixels: 4 bytes per pixel, RGB clamped to [0, 1] and rounded to 0..=255, alpha 255.
pub const GSC_PIXEL_RGBA_U8: c_int = 1;
/// `gsc_render` ran the CPU renderer.
pub const GSC_RENDERER_CPU: c_int = 1;
/// `gsc_render` ran the GPU (wgpu) renderer.
pub const GSC_RENDERER_GPU: c_int = 2;

/// The process-wide GPU renderer, created on first use; `None` when there is no adapter.
#[cfg(feature = "gpu")]
fn gpu_renderer() -> Option<&'static crate::render::gpu::GpuRenderer> {
    static R: std::sync::OnceLock<Option<crate::render::gpu::GpuRenderer>> = std::sync::OnceLock::new();
    R.get_or_init(|| crate::render::gpu::GpuRenderer::new().ok()).as_ref()
}

/// Renders with the GPU when asked and possible, else the CPU; says which ran.
fn render_any(s: &Splats, cam: &crate::Camera, opts: &crate::RenderOptions, use_gpu: bool) -> (crate::Image, c_int) {
    #[cfg(feature = "gpu")]
    if use_gpu {
        if let Some(Ok(img)) = gpu_renderer().map(|r| r.render(s, cam, opts)) {
            return (img, GSC_RENDERER_GPU);
        }
    }
    #[cfg(not(feature = "gpu"))]
    let _ = use_gpu;
    (crate::render::render(s, cam, opts), GSC_RENDERER_CPU)
}

/// Renders `scene` from `*camera` into the caller's `out` buffer (`out_len` bytes, at least
/// `width × height × 16` for `GSC_PIXEL_RGBA_F32` or `× 4` for `GSC_PIXEL_RGBA_U8`), rows top
/// to bottom. `background` (NULL: black) is RGB; `max_sh_degree` 0..=3. `use_gpu` != 0 renders
/// with the GPU renderer when the library was built with feature `gpu` and an adapter exists
/// (falling back to the CPU renderer otherwise); `*renderer` (if not NULL) receives
/// `GSC_RENDERER_GPU` or `GSC_RENDERER_CPU`. On failure `out` is left untouched.
///
/// # Safety
/// `scene` is a live scene from [`gsc_decode`]; `camera` is readable; `background` is NULL or
/// 3 readable floats; `out` points to `out_len` writable bytes (4-byte aligned for f32);
/// `renderer` is NULL or writable.
#[no_mangle]
pub unsafe extern "C" fn gsc_render(
    scene: *const GscScene,
    camera: *const GscCamera,
    background: *const f32,
    max_sh_degree: c_int,
    pixel_format: c_int,
    use_gpu: c_int,
    out: *mut std::ffi::c_void,
    out_len: usize,
    renderer: *mut c_int,
) -> c_int {
    guarded(|| {
        if scene.is_null() || camera.is_null() || out.is_null() {
            set_error("gsc_render: `scene`, `camera` and `out` must not be NULL");
            return GSC_ERR_ARGUMENT;
        }
        // SAFETY: non-null and readable per the contract.
        let (c, s) = unsafe { (*camera, &(*scene).splats) };
        let bg = if background.is_null() { [0.0; 3] } else { unsafe { *(background as *const [f32; 3]) } };
        let per_pixel = match pixel_format {
            GSC_PIXEL_RGBA_F32 => 16,
            GSC_PIXEL_RGBA_U8 => 4,
            _ => {
                set_error(format!("gsc_render: unknown pixel format {pixel_format}"));
                return GSC_ERR_ARGUMENT;
            }
        };
        let needed = (c.width as u64 * c.height as u64).checked_mul(per_pixel);
        let finite = c.rotation.iter().chain(&c.translation).chain(&[c.fx, c.fy, c.cx, c.cy, c.znear]).chain(&bg).all(|v| v.is_finite());
        if !(0..=3).contains(&max_sh_degree) || !finite || c.fx <= 0.0 || c.fy <= 0.0 || needed.is_none_or(|n| n > out_len as u64) {
            set_error(format!(
                "gsc_render: need max_sh_degree 0..=3 ({max_sh_degree}), finite camera and background, fx, fy > 0, and {} output bytes ({out_len} given)",
                needed.map_or("too many".into(), |n| n.to_string())
            ));
            return GSC_ERR_ARGUMENT;
        }
        if pixel_format == GSC_PIXEL_RGBA_F32 && (out as usize) % 4 != 0 {
            set_error("gsc_render: `out` must be 4-byte aligned for GSC_PIXEL_RGBA_F32");
            return GSC_ERR_ARGUMENT;
        }
        let mut cam = crate::Camera::new(
            c.width,
            c.height,
            c.fx,
            c.fy,
            glam::Mat3::from_cols_array(&c.rotation).transpose(),
            glam::Vec3::from(c.translation),
        );
        (cam.cx, cam.cy) = (c.cx, c.cy);
        if c.znear > 0.0 {
            cam.znear = c.znear;
        }
        let opts = crate::RenderOptions { background: bg, max_sh_degree: max_sh_degree as u8 };
        let (img, which) = render_any(s, &cam, &opts, use_gpu != 0);
        let pixels = img.data.chunks_exact(3);
        if pixel_format == GSC_PIXEL_RGBA_F32 {
            // SAFETY: `out_len >= needed` writable, aligned bytes per the checks and contract.
            let dst = unsafe { std::slice::from_raw_parts_mut(out as *mut f32, pixels.len() * 4) };
            for (d, p) in dst.chunks_exact_mut(4).zip(pixels) {
                d.copy_from_slice(&[p[0], p[1], p[2], 1.0]);
            }
        } else {
            // SAFETY: as above.
            let dst = unsafe { std::slice::from_raw_parts_mut(out as *mut u8, pixels.len() * 4) };
            let q = |v: f32| (v.clamp(0.0, 1.0) * 255.0).round() as u8;
            for (d, p) in dst.chunks_exact_mut(4).zip(pixels) {
                d.copy_from_slice(&[q(p[0]), q(p[1]), q(p[2]), 255]);
            }
        }
        if !renderer.is_null() {
            // SAFETY: writable per the contract.
            unsafe { *renderer = which };
        }
        GSC_OK
    })
}

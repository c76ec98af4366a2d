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
/// default limits. `max_sh_degree` (0..=3) skips higher SH bands; `threads` = 0 uses all cores.
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
pub unsafe extern "C" fn gsc_decode_limited(data: *const u8, len: usize, limits: *const GscLimits, threads: c_int, out: *mut *mut GscScene) -> c_int {
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

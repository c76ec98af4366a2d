//! The C ABI from C: `tests/c/decode_gsc.c` is compiled with the system `cc` against
//! `include/gscodec.h` and the crate's static library, run on every conformance vector, and its
//! dump must equal the Rust decoder's output bit for bit.
#![cfg(feature = "capi")]

use gscodec_decoder::decode;
use std::path::{Path, PathBuf};
use std::process::Command;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap().to_path_buf()
}

/// The crate's static library: cargo builds it (hashed name) in the `deps/` folder next to this
/// test binary when it builds the library for the test. Builds with other feature sets leave
/// their own `.a` there too, so take the newest one that holds the C ABI (`gsc_render`).
fn static_lib() -> PathBuf {
    let deps = std::env::current_exe().unwrap().parent().unwrap().to_path_buf();
    let mut libs: Vec<PathBuf> = std::fs::read_dir(&deps)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.file_name().unwrap().to_string_lossy().starts_with("libgscodec_decoder") && p.extension().is_some_and(|e| e == "a"))
        .collect();
    libs.sort_by_key(|p| std::cmp::Reverse(p.metadata().and_then(|m| m.modified()).ok()));
    let holds_capi = |p: &PathBuf| std::fs::read(p).is_ok_and(|b| b.windows(10).any(|w| w == b"gsc_render"));
    libs.into_iter().find(holds_capi).unwrap_or_else(|| panic!("no libgscodec_decoder*.a with the C ABI in {}", deps.display()))
}

fn rust_dump(bytes: &[u8]) -> Vec<u8> {
    let s = decode(bytes).unwrap();
    let mut out = Vec::new();
    out.extend_from_slice(&(s.len() as u32).to_le_bytes());
    out.extend_from_slice(&(s.sh_degree as i32).to_le_bytes());
    let floats = s
        .positions
        .iter()
        .flatten()
        .chain(s.log_scales.iter().flatten())
        .chain(s.rotations.iter().flatten())
        .chain(s.opacity_logits.iter())
        .chain(s.sh_dc.iter().flatten())
        .chain(s.sh_rest.iter());
    floats.for_each(|v| out.extend_from_slice(&v.to_le_bytes()));
    out
}

#[test]
fn c_program_decodes_like_rust() {
    let lib = static_lib();
    let dir = TempDir::new();
    let exe = dir.0.join("decode_gsc");
    let cc = std::env::var("CC").unwrap_or_else(|_| "cc".into());
    let status = Command::new(&cc)
        .arg(repo().join("decoder/tests/c/decode_gsc.c"))
        .arg("-I")
        .arg(repo().join("include"))
        .args(["-std=c99", "-Wall", "-Werror", "-o"])
        .arg(&exe)
        .arg(&lib)
        .args(["-lpthread", "-ldl", "-lm"])
        .status()
        .unwrap_or_else(|e| panic!("cannot run the C compiler `{cc}`: {e}"));
    assert!(status.success(), "C compilation failed");
    let vectors: Vec<PathBuf> = std::fs::read_dir(repo().join("bitstream-spec/vectors"))
        .expect("bitstream-spec/vectors")
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "gsc"))
        .collect();
    assert!(!vectors.is_empty());
    for v in vectors {
        let out = dir.0.join("dump.bin");
        let run = Command::new(&exe).arg(&v).arg(&out).output().unwrap();
        assert!(run.status.success(), "{}: {}{}", v.display(), String::from_utf8_lossy(&run.stdout), String::from_utf8_lossy(&run.stderr));
        eprint!("{}: {}", v.display(), String::from_utf8_lossy(&run.stdout));
        assert!(std::fs::read(&out).unwrap() == rust_dump(&std::fs::read(&v).unwrap()), "{}: C and Rust decodes differ", v.display());
    }
}

/// A scratch folder for the C build, removed when the test ends (pass or fail).
struct TempDir(PathBuf);

impl TempDir {
    fn new() -> Self {
        let d = std::env::temp_dir().join(format!("gscodec-capi-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        TempDir(d)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// `gsc_render` through the C ABI equals the Rust CPU render (f32 exactly, u8 as its rounding),
/// the GPU choice is stated (and within 45 dB of the CPU image when it ran), and bad arguments
/// fail without touching the buffer.
#[test]
fn c_render_to_buffer_matches_rust_render() {
    use gscodec_decoder::capi::*;
    use gscodec_decoder::render::render;
    use gscodec_decoder::{Camera, RenderOptions};
    let path = repo().join("bitstream-spec/vectors/hand.gsc");
    let bytes = std::fs::read(&path).unwrap();
    let mut scene = std::ptr::null_mut();
    assert_eq!(unsafe { gsc_decode(bytes.as_ptr(), bytes.len(), 3, 1, &mut scene) }, GSC_OK);
    let s = decode(&bytes).unwrap();
    assert!(!s.is_empty());
    // Look at the scene's centroid from a distance of twice its extent.
    let n = s.len() as f32;
    let mean = s.positions.iter().fold(glam::Vec3::ZERO, |a, p| a + glam::Vec3::from(*p) / n);
    let extent = s.positions.iter().map(|p| (glam::Vec3::from(*p) - mean).length()).fold(0.0f32, f32::max).max(1e-3);
    let cam = Camera::look_at(mean - glam::Vec3::new(0.3, 0.2, 2.0) * extent, mean, glam::Vec3::new(0.0, -1.0, 0.0), 61, 37, 0.9);
    let c = GscCamera {
        width: cam.width,
        height: cam.height,
        fx: cam.fx,
        fy: cam.fy,
        cx: cam.cx,
        cy: cam.cy,
        rotation: cam.rotation.transpose().to_cols_array(),
        translation: cam.translation.to_array(),
        znear: cam.znear,
    };
    let bg = [0.2f32, 0.1, 0.0];
    let opts = RenderOptions { background: bg, max_sh_degree: 2 };
    let want = render(&s, &cam, &opts);
    assert!(want.data.chunks(3).any(|p| p != bg), "the camera sees the scene");
    let pixels = (cam.width * cam.height) as usize;
    let mut f32_out = vec![0.0f32; pixels * 4];
    let mut used = 0;
    let rc = unsafe { gsc_render(scene, &c, bg.as_ptr(), 2, GSC_PIXEL_RGBA_F32, 0, f32_out.as_mut_ptr().cast(), pixels * 16, &mut used) };
    assert_eq!((rc, used), (GSC_OK, GSC_RENDERER_CPU));
    let rgba: Vec<f32> = want.data.chunks(3).flat_map(|p| [p[0], p[1], p[2], 1.0]).collect();
    assert!(f32_out == rgba, "C ABI f32 render differs from the Rust render");
    let mut u8_out = vec![0u8; pixels * 4];
    let rc = unsafe {
        gsc_render(scene, &c, bg.as_ptr(), 2, GSC_PIXEL_RGBA_U8, 0, u8_out.as_mut_ptr().cast(), pixels * 4, std::ptr::null_mut())
    };
    assert_eq!(rc, GSC_OK);
    let q: Vec<u8> = rgba.iter().map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8).collect();
    assert!(u8_out == q);

    // GPU when asked: which renderer ran is stated; the image agrees with the CPU render.
    let rc = unsafe { gsc_render(scene, &c, bg.as_ptr(), 2, GSC_PIXEL_RGBA_F32, 1, f32_out.as_mut_ptr().cast(), pixels * 16, &mut used) };
    assert_eq!(rc, GSC_OK);
    eprintln!("gsc_render(use_gpu = 1) ran renderer {used} (1 CPU, 2 GPU)");
    if cfg!(feature = "gpu") {
        assert!(used == GSC_RENDERER_GPU || used == GSC_RENDERER_CPU);
    } else {
        assert_eq!(used, GSC_RENDERER_CPU);
    }
    let mse = f32_out.iter().zip(&rgba).map(|(a, b)| ((a - b) as f64).powi(2)).sum::<f64>() / rgba.len() as f64;
    assert!(mse == 0.0 || 10.0 * (1.0 / mse).log10() >= 45.0, "GPU render too far from CPU: mse {mse}");

    // Bad arguments: too small a buffer, unknown format, NULL camera; the buffer is untouched.
    let mut small = vec![7u8; pixels * 4 - 1];
    for (fmt, len, camp) in
        [(GSC_PIXEL_RGBA_U8, small.len(), &c as *const GscCamera), (5, small.len(), &c), (GSC_PIXEL_RGBA_U8, small.len(), std::ptr::null())]
    {
        let rc = unsafe { gsc_render(scene, camp, std::ptr::null(), 2, fmt, 0, small.as_mut_ptr().cast(), len, std::ptr::null_mut()) };
        assert_eq!(rc, GSC_ERR_ARGUMENT);
    }
    assert!(small.iter().all(|&v| v == 7));
    unsafe { gsc_scene_free(scene) };
}

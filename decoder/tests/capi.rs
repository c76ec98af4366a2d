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
/// test binary when it builds the library for the test; the newest one is this build's.
fn static_lib() -> PathBuf {
    let deps = std::env::current_exe().unwrap().parent().unwrap().to_path_buf();
    std::fs::read_dir(&deps)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.file_name().unwrap().to_string_lossy().starts_with("libgscodec_decoder") && p.extension().is_some_and(|e| e == "a"))
        .max_by_key(|p| p.metadata().and_then(|m| m.modified()).ok())
        .unwrap_or_else(|| panic!("no libgscodec_decoder*.a in {}", deps.display()))
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

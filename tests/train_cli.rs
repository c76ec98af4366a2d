//! `gscodec train` from the outside: trains the bundled sample, writes the scene and report,
//! and rejects bad input with exit 2 and no output.

use std::path::PathBuf;
use std::process::Command;

fn tiny() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("samples/tiny")
}

#[test]
fn trains_the_sample_and_writes_scene_and_report() {
    let dir = tempfile::tempdir().unwrap();
    let (out, rep) = (dir.path().join("out.ply"), dir.path().join("r.json"));
    let o = Command::new(env!("CARGO_BIN_EXE_gscodec"))
        .args(["train", tiny().to_str().unwrap(), "-o", out.to_str().unwrap(), "--iters", "60", "--init-points", "500"])
        .args(["--report", rep.to_str().unwrap(), "--eval-every", "30"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(stdout.contains("PSNR") && stdout.contains("SSIM"), "{stdout}");
    let scene = gscodec::io::read_ply(&out).unwrap();
    assert!(!scene.is_empty());
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(&rep).unwrap()).unwrap();
    let pts = r["points"].as_array().unwrap();
    assert_eq!(pts.last().unwrap()["iteration"], 60);
    assert!(pts.iter().any(|p| p["iteration"] == 30 && p["test_psnr"].is_number()));
    assert!(r["test_psnr"].as_f64().unwrap() > 10.0);
}

#[test]
fn bad_input_exits_2_without_output() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out.ply");
    for args in [
        vec!["train".to_string(), dir.path().join("missing").display().to_string(), "-o".into(), out.display().to_string()],
        vec!["train".to_string(), tiny().display().to_string(), "-o".into(), dir.path().join("out.txt").display().to_string()],
        vec!["train".to_string(), tiny().display().to_string(), "-o".into(), out.display().to_string(), "--iters".into(), "0".into()],
        vec![
            "train".to_string(),
            tiny().display().to_string(),
            "-o".into(),
            out.display().to_string(),
            "--densify-grad-threshold".into(),
            "0".into(),
        ],
    ] {
        let o = Command::new(env!("CARGO_BIN_EXE_gscodec")).args(&args).output().unwrap();
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", String::from_utf8_lossy(&o.stderr));
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.starts_with("error: ") && err.lines().count() == 1, "{err}");
        assert!(!out.exists());
    }
}

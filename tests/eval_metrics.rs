//! `gscodec eval` reports every metric (DESIGN §10), per view on request.

use std::path::PathBuf;
use std::process::Command;

fn tiny() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("samples/tiny")
}

fn eval(args: &[&str]) -> serde_json::Value {
    let o = Command::new(env!("CARGO_BIN_EXE_gscodec")).arg("eval").args(args).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_slice(&o.stdout).unwrap()
}

#[test]
fn json_has_every_metric_and_per_view_rows() {
    let truth = tiny().join("truth.ply");
    let j = eval(&[truth.to_str().unwrap(), tiny().to_str().unwrap(), "--split", "all", "--json", "--per-view"]);
    for k in ["psnr", "ssim", "ms_ssim", "flip", "wd", "bytes", "gaussians", "render_ms"] {
        assert!(j.get(k).is_some(), "missing {k}: {j}");
    }
    let rows = j["per_view"].as_array().unwrap();
    assert_eq!(rows.len() as u64, j["views"].as_u64().unwrap());
    assert_eq!(rows.len(), 16);
    assert_eq!(rows[3]["index"], 3);
    // The mean is the mean of the rows.
    let mean: f64 = rows.iter().map(|r| r["psnr"].as_f64().unwrap()).sum::<f64>() / rows.len() as f64;
    assert!((mean - j["psnr"].as_f64().unwrap()).abs() < 1e-9);
}

#[test]
fn ms_ssim_and_flip_on_views_large_enough() {
    // Orbit views of 176x168 px: MS-SSIM has its 5 scales. Identical scenes are perfect.
    let truth = tiny().join("truth.ply");
    let t = truth.to_str().unwrap();
    let j = eval(&[t, "--reference", t, "--orbit", "2", "--size", "176x168", "--json"]);
    assert!((j["ms_ssim"].as_f64().unwrap() - 1.0).abs() < 1e-9, "{j}");
    assert_eq!(j["flip"].as_f64(), Some(0.0));

    // Another scene is worse on both.
    let dir = tempfile::tempdir().unwrap();
    let other = dir.path().join("o");
    let st = Command::new(env!("CARGO_BIN_EXE_gscodec"))
        .args(["sample", other.to_str().unwrap(), "--gaussians", "300", "--views", "1", "--size", "8x8", "--seed", "3", "--quiet"])
        .status()
        .unwrap();
    assert!(st.success());
    let o = other.join("truth.ply");
    let j = eval(&[o.to_str().unwrap(), "--reference", t, "--orbit", "2", "--size", "176x168", "--json"]);
    let (ms, flip) = (j["ms_ssim"].as_f64().unwrap(), j["flip"].as_f64().unwrap());
    assert!(ms < 0.95 && flip > 0.05, "{j}");
}

//! The CLI from outside: render / convert / eval / sample happy paths and every bad-input case.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn gscodec(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_gscodec")).args(args).output().unwrap()
}

fn tiny() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/tiny")
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Exit 2, exactly one `error:` line on stderr mentioning `needle`, nothing at `out`.
fn assert_bad(args: &[&str], needle: &str, out: &Path) {
    let o = gscodec(args);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
    let lines: Vec<&str> = err.lines().filter(|l| l.starts_with("error:")).collect();
    assert_eq!(lines.len(), 1, "{args:?}: {err}");
    assert!(lines[0].contains(needle), "{args:?}: `{}` lacks `{needle}`", lines[0]);
    assert!(!err.contains("panicked"), "{err}");
    assert!(!out.exists(), "{args:?} left {}", out.display());
    // No temporary left beside the output either.
    let parent = out.parent().unwrap();
    let stray: Vec<_> =
        std::fs::read_dir(parent).unwrap().flatten().filter(|e| e.file_name().to_string_lossy().contains(".tmp-")).collect();
    assert!(stray.is_empty(), "{args:?} left temporaries");
}

fn ply_with(edit: impl Fn(&mut Vec<u8>, usize)) -> Vec<u8> {
    let mut b = std::fs::read(tiny().join("truth.ply")).unwrap();
    let start = b.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
    edit(&mut b, start);
    b
}

#[test]
fn bad_inputs_exit_2_with_one_error_line_and_no_output() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let out = d.join("out");
    let out_ply = d.join("out.ply");
    // 62 floats per Gaussian (x y z nx ny nz, 3 dc, 45 rest, opacity, 3 scale, 4 rot).
    let stride = 62 * 4;
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        ("nan.ply", ply_with(|b, s| b[s + 4..s + 8].copy_from_slice(&f32::NAN.to_le_bytes())), "not finite"),
        ("zeroquat.ply", ply_with(|b, s| b[s + stride - 16..s + stride].fill(0)), "zero norm"),
        ("truncated.ply", ply_with(|b, _| b.truncate(b.len() - 100)), "truncated"),
        (
            "lying.ply",
            ply_with(|b, _| *b = String::from_utf8_lossy(b).replacen("vertex 1000", "vertex 99999999", 1).into_bytes()),
            "truncated",
        ),
    ];
    for (name, bytes, msg) in &cases {
        let p = d.join(name);
        std::fs::write(&p, bytes).unwrap();
        assert_bad(&["render", s(&p), "--orbit", "2", "-o", s(&out)], msg, &out);
        assert_bad(&["convert", s(&p), s(&out_ply)], name, &out_ply);
        assert_bad(&["eval", s(&p), s(&tiny())], name, &out);
    }
    let missing = d.join("missing.ply");
    assert_bad(&["render", s(&missing), "--orbit", "1", "-o", s(&out)], "missing.ply", &out);
    assert_bad(&["convert", s(&missing), s(&out_ply)], "missing.ply", &out_ply);
    let truth = tiny().join("truth.ply");
    assert_bad(&["convert", s(&truth), s(&d.join("x.unknown"))], "x.unknown", &d.join("x.unknown"));
    assert_bad(&["render", s(&truth), "--cameras", s(&missing), "-o", s(&out)], "missing.ply", &out);
    // A COLMAP camera model gscodec does not know (distorted models are undistorted when loading).
    let colmap = d.join("colmap");
    std::fs::create_dir_all(colmap.join("sparse/0")).unwrap();
    std::fs::create_dir_all(colmap.join("images")).unwrap();
    std::fs::copy(tiny().join("train/r_0.png"), colmap.join("images/a.png")).unwrap();
    std::fs::write(colmap.join("sparse/0/cameras.txt"), "1 EQUIRECTANGULAR 64 64 50 50 32 32\n").unwrap();
    std::fs::write(colmap.join("sparse/0/images.txt"), "1 1 0 0 0 0 0 4 1 a.png\n\n").unwrap();
    assert_bad(&["render", s(&truth), "--cameras", s(&colmap), "-o", s(&out)], "camera model EQUIRECTANGULAR (id 17) is a spherical", &out);
    assert_bad(&["render", s(&truth), "--cameras", s(&colmap), "-o", s(&out)], "cameras.txt", &out);
    // Bad flags.
    assert_bad(&["render", s(&truth), "--orbit", "2", "--size", "0x5", "-o", s(&out)], "0x5", &out);
    assert_bad(&["render", s(&truth), "-o", s(&out)], "required", &out);
    assert_bad(&["render", s(&truth), "--orbit", "2", "--background", "2,0,0", "-o", s(&out)], "2,0,0", &out);
    assert_bad(&["render", s(&truth), "--orbit", "2", "--format", "gif", "-o", s(&out)], "gif", &out);
    assert_bad(&["eval", s(&truth)], "required", &out);
    assert_bad(&["sample", s(&out), "--views", "0", "--quiet"], "positive", &out);
    assert_bad(&["sample", s(&out), "--scene", s(&missing), "--quiet"], "missing.ply", &out);
    assert_bad(&["sample", s(&out), "--scene", s(&d.join("nan.ply")), "--quiet"], "not finite", &out);
    assert_bad(&["sample", s(&out), "--scene", s(&truth), "--gaussians", "10", "--quiet"], "--gaussians", &out);
    assert_bad(&["sample", s(&out), "--up", "x", "--quiet"], "required", &out);
    let empty = d.join("empty.ply");
    std::fs::write(
        &empty,
        ply_with(|b, s| {
            b.truncate(s);
            *b = String::from_utf8_lossy(b).replacen("vertex 1000", "vertex 0", 1).into_bytes();
        }),
    )
    .unwrap();
    assert_bad(&["sample", s(&out), "--scene", s(&empty), "--quiet"], "empty.ply", &out);
    // A sweep of an unreadable input leaves no output directory behind.
    assert_bad(&["sweep", s(&d.join("nan.ply")), "-o", s(&out), "--lambdas", "20", "--quiet"], "not finite", &out);
}

#[test]
fn an_output_in_a_missing_directory_is_refused_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let nodir = dir.path().join("nodir");
    let truth = tiny().join("truth.ply");
    let gsc = nodir.join("o.gsc");
    let ply = nodir.join("o.ply");
    let encoded = dir.path().join("t.gsc");
    let (report, data, trained) = (nodir.join("r.json"), tiny(), dir.path().join("t.ply"));
    assert!(gscodec(&["convert", s(&truth), s(&encoded)]).status.success());
    let cases: [&[&str]; 6] = [
        &["encode", s(&truth), "-o", s(&gsc), "--quiet"],
        &["encode", s(&truth), "-o", s(&encoded), "--report", s(&report), "--quiet"],
        &["decode", s(&encoded), "-o", s(&ply)],
        &["convert", s(&truth), s(&ply)],
        &["train", s(&data), "-o", s(&ply), "--iters", "1", "--quiet"],
        &["train", s(&data), "-o", s(&trained), "--report", s(&report), "--iters", "1", "--quiet"],
    ];
    for args in cases {
        let o = gscodec(args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
        assert_eq!(err.lines().count(), 1, "{args:?}: {err}");
        assert!(err.starts_with("error: ") && err.contains("nodir") && err.contains("does not exist"), "{args:?}: {err}");
        assert!(!nodir.exists());
    }
    assert!(!trained.exists(), "train wrote its scene before refusing the report");
    // An output that is a directory.
    let o = gscodec(&["encode", s(&truth), "-o", s(dir.path()), "--quiet"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.starts_with("error: ") && err.contains("is a directory") && err.lines().count() == 1, "{err}");
}

#[test]
fn render_cameras_names_frames_by_index_and_reproduces_the_sample() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("r");
    let truth = tiny().join("truth.ply");
    let o = gscodec(&["render", s(&truth), "--cameras", s(&tiny()), "--split", "test", "-o", s(&out), "--quiet"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let mut names: Vec<String> = std::fs::read_dir(&out).unwrap().map(|e| e.unwrap().file_name().into_string().unwrap()).collect();
    names.sort();
    assert_eq!(names, ["000.png", "008.png"]);
    let a = image::open(out.join("008.png")).unwrap().to_rgb8();
    let b = image::open(tiny().join("train/r_8.png")).unwrap().to_rgb8();
    assert!(a == b);
    // EXR output, orbit, explicit size.
    let exr = dir.path().join("e");
    let o = gscodec(&["render", s(&truth), "--orbit", "3", "--up", "z", "--size", "40x30", "--format", "exr", "-o", s(&exr), "--quiet"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for i in 0..3 {
        let bytes = std::fs::read(exr.join(format!("00{i}.exr"))).unwrap();
        assert_eq!(&bytes[..4], &[0x76, 0x2f, 0x31, 0x01]);
    }
}

#[test]
fn convert_ply_round_trips_and_eval_reports_metrics() {
    let dir = tempfile::tempdir().unwrap();
    let truth = tiny().join("truth.ply");
    let copy = dir.path().join("copy.ply");
    assert!(gscodec(&["convert", s(&truth), s(&copy)]).status.success());
    assert!(std::fs::read(&copy).unwrap() == std::fs::read(&truth).unwrap());

    let o = gscodec(&["eval", s(&truth), s(&tiny()), "--split", "all", "--json"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    // Only 8-bit rounding separates the renders from the stored PNGs.
    assert!(j["psnr"].as_f64().unwrap() > 50.0, "{j}");
    assert!(j["ssim"].as_f64().unwrap() > 0.999, "{j}");
    assert_eq!(j["gaussians"], 1000);
    assert_eq!(j["bytes"].as_u64().unwrap(), std::fs::metadata(&truth).unwrap().len());
    assert!(j["render_ms"].as_f64().unwrap() > 0.0);
    assert!(j["flip"].as_f64().unwrap() < 0.01, "{j}");
    assert!(j["ms_ssim"].is_null(), "64x64 views are too small for MS-SSIM: {j}");

    let o = gscodec(&["eval", s(&truth), "--reference", s(&truth), "--orbit", "2", "--size", "32x32", "--json"]);
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!((j["psnr"].as_f64(), j["ssim"].as_f64()), (Some(100.0), Some(1.0)));

    // A different scene scores lower against the reference.
    let other = dir.path().join("other");
    assert!(gscodec(&["sample", s(&other), "--gaussians", "300", "--views", "1", "--size", "8x8", "--seed", "3", "--quiet"])
        .status
        .success());
    let o = gscodec(&["eval", s(&other.join("truth.ply")), "--reference", s(&truth), "--orbit", "2", "--size", "32x32", "--json"]);
    let j: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!(j["psnr"].as_f64().unwrap() < 40.0, "{j}");
}

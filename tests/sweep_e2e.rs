//! `gscodec sweep` end to end on `samples/tiny/truth.ply`: real encodes, decodes and evals (in process).

use std::path::PathBuf;
use std::process::Command;

#[test]
fn sweep_two_lambdas_on_the_tiny_sample() {
    let truth = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("samples/tiny/truth.ply");
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("sw");
    let run = || {
        Command::new(env!("CARGO_BIN_EXE_gscodec"))
            .arg("sweep")
            .arg(&truth)
            .arg("-o")
            .arg(&out)
            .args(["--lambdas", "2,200", "--loss", "l1ssim", "--iters", "2", "--quiet"])
            .output()
            .unwrap()
    };
    let res = run();
    assert!(res.status.success(), "{}", String::from_utf8_lossy(&res.stderr));
    for f in ["rd.csv", "rd.svg", "time.svg", "summary.json"] {
        assert!(out.join(f).is_file(), "{f} missing");
    }
    let csv = std::fs::read_to_string(out.join("rd.csv")).unwrap();
    let rows: Vec<Vec<&str>> = csv.lines().skip(1).map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), 2, "{csv}");
    // Sorted by λ descending: the λ = 200 row first, with the smaller file and lower quality.
    assert_eq!((rows[0][0], rows[1][0]), ("200", "2"));
    let num = |r: &Vec<&str>, i: usize| r[i].parse::<f64>().unwrap_or_else(|_| panic!("column {i} of {r:?}"));
    assert!(num(&rows[0], 2) < num(&rows[1], 2), "bytes must grow as λ falls: {csv}");
    assert!(num(&rows[0], 4) < num(&rows[1], 4), "PSNR must grow as λ falls: {csv}");
    for r in &rows {
        assert!(num(r, 5) > 0.0 && num(r, 5) <= 1.0, "ssim {r:?}");
        assert!(num(r, 6) > 0.0 && num(r, 6) <= 1.0, "ms_ssim (256x256 orbit views) {r:?}");
        assert!(num(r, 7) >= 0.0 && num(r, 7) < 1.0, "flip {r:?}");
        assert!(num(r, 9) > 0.0 && num(r, 10) > 0.0, "times {r:?}");
    }
    // Bytes are the real .gsc sizes.
    let gsc = std::fs::metadata(out.join("points/l1ssim_lambda2/scene.gsc")).unwrap().len();
    assert_eq!(gsc, num(&rows[1], 2) as u64);

    // Resuming: nothing left to do, same table.
    let before = std::fs::metadata(out.join("points/l1ssim_lambda2/scene.gsc")).unwrap().modified().unwrap();
    let res = run();
    assert!(res.status.success());
    assert_eq!(std::fs::read_to_string(out.join("rd.csv")).unwrap(), csv);
    assert_eq!(std::fs::metadata(out.join("points/l1ssim_lambda2/scene.gsc")).unwrap().modified().unwrap(), before);
}

/// A dataset sweep of `l1ssim` and `wdr` (WD-R only in retraining) trains each λ once: both
/// points carry the same run from the images, to the wall-clock second, and differ after it.
#[test]
fn a_dataset_sweep_trains_once_for_both_losses() {
    let tiny = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("samples/tiny");
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("sw");
    let res = Command::new(env!("CARGO_BIN_EXE_gscodec"))
        .arg("sweep")
        .arg(&tiny)
        .arg("-o")
        .arg(&out)
        .args(["--lambdas", "20", "--loss", "l1ssim,wdr", "--iters", "30", "--backend", "cpu", "--jobs", "2", "--quiet"])
        .output()
        .unwrap();
    assert!(res.status.success(), "{}", String::from_utf8_lossy(&res.stderr));
    let report = |loss: &str| -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(out.join(format!("points/{loss}_lambda20/report.json"))).unwrap()).unwrap()
    };
    let (l1, wdr) = (report("l1ssim"), report("wdr"));
    let main_run = |r: &serde_json::Value| -> Vec<(u64, f64)> {
        let s = r["series"].as_array().unwrap().iter().filter(|p| p["iteration"].as_u64().unwrap() <= 30 && p["trial"] == "train");
        s.map(|p| (p["iteration"].as_u64().unwrap(), p["wall_s"].as_f64().unwrap())).collect()
    };
    assert!(main_run(&l1).len() >= 5, "{}", l1["series"]);
    assert_eq!(main_run(&l1), main_run(&wdr), "one training, timed once");
    assert_eq!((l1["loss"].as_str(), wdr["loss"].as_str(), wdr["wd_warmup"].as_f64()), (Some("l1ssim"), Some("wdr"), Some(1.0)));
    assert_ne!(
        std::fs::read(out.join("points/l1ssim_lambda20/scene.gsc")).unwrap(),
        std::fs::read(out.join("points/wdr_lambda20/scene.gsc")).unwrap()
    );
}

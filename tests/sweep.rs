//! `gscodec sweep` machinery on fake per-point results (collect, tables, plots, BD-rates, jobs),
//! and one in-process sweep of the tiny sample with two jobs.

use std::path::Path;
use std::process::Command;

use gscodec::encoder::SearchDistortion;
use gscodec::sweep::results::{read_results, PointResult, TimelinePoint, CSV_HEADER};
use gscodec::sweep::Point;

fn gscodec() -> Command {
    Command::new(env!("CARGO_BIN_EXE_gscodec"))
}

/// A fake finished point: quality grows with log-size; `scale` multiplies the size.
fn fake(loss: &str, lambda: f64, scale: f64) -> PointResult {
    let bytes0 = 2e4 / lambda.sqrt(); // bigger files for smaller λ
    let q = (bytes0 / 1e4).ln();
    PointResult {
        lambda,
        loss: loss.into(),
        iters: None,
        seed: 0,
        retrain_iters: 0,
        wd_features: None,
        wd_sigma: None,
        wd_warmup: None,
        search_distortion: SearchDistortion::Mse,
        max_gaussians: None,
        init: None,
        bytes: (bytes0 * scale).round() as u64,
        gaussians: (bytes0 / 10.0) as u64,
        psnr: Some(20.0 + 3.0 * q),
        ssim: Some(0.7 + 0.05 * q),
        ms_ssim: None,
        flip: Some(0.3 - 0.04 * q),
        wd: Some(1.0 / (1.0 + q)),
        encode_s: 12.5,
        decode_s: 0.25,
        timeline: (0..5).map(|i| TimelinePoint { time_s: i as f64 * 2.0, psnr: Some(15.0 + q * i as f64), wd: None }).collect(),
    }
}

fn write_point(dir: &Path, r: &PointResult) {
    let d = dir.join("points").join(Point { lambda: r.lambda, loss: r.loss.clone(), seed: r.seed }.dir_name());
    std::fs::create_dir_all(&d).unwrap();
    std::fs::write(d.join("result.json"), serde_json::to_string(r).unwrap()).unwrap();
}

#[test]
fn collect_writes_tables_plots_and_bd_rates() {
    let tmp = tempfile::tempdir().unwrap();
    let lambdas = [0.1, 0.03, 0.01, 0.003, 0.001];
    for &l in &lambdas {
        write_point(tmp.path(), &fake("l1ssim", l, 1.0));
        // wdr reaches the same quality with exactly half the bytes: BD-rate −50 % everywhere.
        write_point(tmp.path(), &fake("wdr", l, 0.5));
    }
    let out = tmp.path().join("out");
    let res = gscodec().arg("sweep").arg("unused").arg("-o").arg(&out).arg("--collect").arg(tmp.path()).output().unwrap();
    assert!(res.status.success(), "{}", String::from_utf8_lossy(&res.stderr));
    let stdout = String::from_utf8(res.stdout).unwrap();
    for m in ["psnr", "ssim", "flip", "wd"] {
        let line = stdout.lines().find(|l| l.contains(&format!("on {m}:"))).unwrap_or_else(|| panic!("{stdout}"));
        let v: f64 = line.rsplit(' ').next().unwrap().trim_end_matches('%').parse().unwrap();
        assert!((v + 50.0).abs() < 0.5, "{line}");
    }
    assert!(stdout.contains("on ms_ssim: n/a"), "{stdout}");

    let csv = std::fs::read_to_string(out.join("rd.csv")).unwrap();
    let lines: Vec<&str> = csv.lines().collect();
    assert_eq!(lines[0], CSV_HEADER);
    assert_eq!(lines.len(), 11);
    // l1ssim first, λ descending, so bytes grow down its rows; ms_ssim empty.
    let bytes: Vec<u64> = lines[1..6].iter().map(|l| l.split(',').nth(2).unwrap().parse().unwrap()).collect();
    assert!(bytes.windows(2).all(|w| w[0] < w[1]), "{bytes:?}");
    assert!(lines[1].starts_with("0.1,l1ssim,"));
    assert_eq!(lines[1].split(',').nth(6), Some(""));

    let rd = std::fs::read_to_string(out.join("rd.svg")).unwrap();
    assert_eq!(rd.matches("<polyline").count(), 8, "two losses on four metrics with data");
    let time = std::fs::read_to_string(out.join("time.svg")).unwrap();
    assert_eq!(time.matches("<polyline").count(), 10, "one PSNR curve per run, no WD panels");
    assert!(time.contains("wdr: PSNR during encode") && !time.contains("WD during"));

    let summary: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(summary["points"].as_array().unwrap().len(), 10);
    // bd_rate.<loss>.<metric>: percent against l1ssim, null (with a note) where not computable.
    let bd = &summary["bd_rate"]["wdr"];
    for m in ["psnr", "ssim", "flip", "wd"] {
        assert!((bd[m].as_f64().unwrap() + 50.0).abs() < 0.5, "{m}: {bd}");
    }
    assert!(bd["ms_ssim"].is_null() && summary["bd_rate_notes"]["wdr"]["ms_ssim"].is_string(), "{summary}");
    assert!(summary["bd_rate"].get("l1ssim").is_none(), "the anchor has no BD-rate against itself");
    assert_eq!(read_results(tmp.path()).unwrap().len(), 10);
}

/// Two seeds: the table and the BD-rates are of the seeds' mean points, and each seed's own
/// BD-rates come beside them.
#[test]
fn collect_of_two_seeds_gives_mean_curves_and_each_seeds_bd_rates() {
    let tmp = tempfile::tempdir().unwrap();
    let lambdas = [0.1, 0.03, 0.01, 0.003, 0.001];
    for &l in &lambdas {
        // the same quality at every λ for both seeds; wdr is half the bytes with seed 0 and 0.8
        // of them with seed 1: BD-rates −50 % and −20 %, and −35 % for the mean sizes
        for seed in [0, 1] {
            write_point(tmp.path(), &PointResult { seed, ..fake("l1ssim", l, 1.0) });
            write_point(tmp.path(), &PointResult { seed, ..fake("wdr", l, [0.5, 0.8][seed as usize]) });
        }
    }
    assert_eq!(read_results(tmp.path()).unwrap().len(), 20);
    let out = tmp.path().join("out");
    let res = gscodec().arg("sweep").arg("unused").arg("-o").arg(&out).arg("--collect").arg(tmp.path()).output().unwrap();
    assert!(res.status.success(), "{}", String::from_utf8_lossy(&res.stderr));
    let stdout = String::from_utf8(res.stdout).unwrap();
    let line = stdout.lines().find(|l| l.contains("on flip:")).unwrap();
    // (sizes are whole bytes: the rates are within 0.01 % of these)
    assert_eq!(line, "BD-rate wdr vs l1ssim on flip: -35.00% (mean of 2 seeds; seed 0 -50.00%, seed 1 -20.00%)", "{stdout}");

    let summary: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(summary["points"].as_array().unwrap().len(), 20, "every seed's points");
    let near = |v: &serde_json::Value, want: f64| (v.as_f64().unwrap() - want).abs() < 0.005;
    for m in ["psnr", "ssim", "flip", "wd"] {
        assert!(near(&summary["bd_rate"]["wdr"][m], -35.0), "{m}: {summary}");
        assert!(near(&summary["bd_rate_by_seed"]["0"]["wdr"][m], -50.0) && near(&summary["bd_rate_by_seed"]["1"]["wdr"][m], -20.0));
    }
    assert!(summary["bd_rate_notes_by_seed"]["1"]["wdr"]["ms_ssim"].is_string());
    // rd.csv: one row per (λ, loss), of the mean sizes
    let csv = std::fs::read_to_string(out.join("rd.csv")).unwrap();
    let lines: Vec<&str> = csv.lines().collect();
    assert_eq!(lines.len(), 11);
    let wdr = lines.iter().find(|l| l.starts_with("0.1,wdr,")).unwrap();
    let bytes0 = 2e4 / 0.1f64.sqrt();
    let mean = ((bytes0 * 0.5).round() + (bytes0 * 0.8).round()) / 2.0;
    assert_eq!(wdr.split(',').nth(2).unwrap(), format!("{}", mean.round()));
    let time = std::fs::read_to_string(out.join("time.svg")).unwrap();
    assert!(time.contains("seed 1") && time.matches("<polyline").count() == 20, "one time series per run");
    // a seed with points of one loss only: its BD-rates are n/a
    write_point(tmp.path(), &PointResult { seed: 2, ..fake("l1ssim", 0.1, 1.0) });
    let res = gscodec().arg("sweep").arg("unused").arg("-o").arg(&out).arg("--collect").arg(tmp.path()).output().unwrap();
    assert!(res.status.success(), "{}", String::from_utf8_lossy(&res.stderr));
    let stdout = String::from_utf8(res.stdout).unwrap();
    assert!(stdout.contains("(mean of 3 seeds; seed 0 -50.00%, seed 1 -20.00%, seed 2 n/a (no wdr points))"), "{stdout}");
    std::fs::remove_dir_all(tmp.path().join("points/l1ssim_lambda0.1_seed2")).unwrap();
    // one seed: no per-seed maps
    let one = tmp.path().join("one");
    std::fs::create_dir_all(one.join("points")).unwrap();
    for r in read_results(tmp.path()).unwrap().into_iter().filter(|r| r.seed == 1) {
        write_point(&one, &r);
    }
    let res = gscodec().arg("sweep").arg("unused").arg("-o").arg(&one).arg("--collect").arg(&one).output().unwrap();
    assert!(res.status.success() && !String::from_utf8_lossy(&res.stdout).contains("seeds"));
    let summary: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(one.join("summary.json")).unwrap()).unwrap();
    assert!(near(&summary["bd_rate"]["wdr"]["flip"], -20.0) && summary.get("bd_rate_by_seed").is_none());
}

#[test]
fn collect_of_nothing_or_garbage_is_bad_input() {
    let tmp = tempfile::tempdir().unwrap();
    let res = gscodec().args(["sweep", "x", "-o"]).arg(tmp.path().join("o")).arg("--collect").arg(tmp.path()).output().unwrap();
    assert_eq!(res.status.code(), Some(2));
    let d = tmp.path().join("points/l1ssim_lambda0.1");
    std::fs::create_dir_all(&d).unwrap();
    std::fs::write(d.join("result.json"), "{ not json").unwrap();
    let res = gscodec().args(["sweep", "x", "-o"]).arg(tmp.path().join("o")).arg("--collect").arg(tmp.path()).output().unwrap();
    assert_eq!(res.status.code(), Some(2));
    let err = String::from_utf8_lossy(&res.stderr);
    assert!(err.starts_with("error: ") && err.contains("result.json") && err.lines().count() == 1, "{err}");
    assert!(!tmp.path().join("o/rd.csv").exists());
}

#[test]
fn bad_flags_and_missing_input_exit_2() {
    let tmp = tempfile::tempdir().unwrap();
    for args in [vec!["--lambdas", "0.1,-2"], vec!["--loss", "mse"]] {
        let res = gscodec().args(["sweep"]).arg(tmp.path()).arg("-o").arg(tmp.path().join("o")).args(&args).output().unwrap();
        assert_eq!(res.status.code(), Some(2), "{args:?}");
    }
    let res = gscodec().args(["sweep", "/no/such/scene", "-o"]).arg(tmp.path().join("o")).output().unwrap();
    assert_eq!(res.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&res.stderr).contains("/no/such/scene"));
}

#[test]
fn finished_points_are_skipped() {
    // Every point already has its result: nothing is encoded, the tables are (re)written.
    let tmp = tempfile::tempdir().unwrap();
    let input = tmp.path().join("scene.ply");
    std::fs::write(&input, "ply\n").unwrap();
    let out = tmp.path().join("sw");
    for l in [0.1, 0.01] {
        write_point(&out, &fake("l1ssim", l, 1.0));
    }
    let res = gscodec().arg("sweep").arg(&input).arg("-o").arg(&out).args(["--lambdas", "0.1,0.01", "--loss", "l1ssim"]).output().unwrap();
    assert!(res.status.success(), "{}", String::from_utf8_lossy(&res.stderr));
    assert!(String::from_utf8_lossy(&res.stderr).contains("2 finished point(s) kept, 0 to run"));
    assert_eq!(std::fs::read_to_string(out.join("rd.csv")).unwrap().lines().count(), 3);
    // Other settings (--iters) redo the points; here the input is no scene: bad input, exit 2
    // naming it, the old results stay.
    let res = gscodec()
        .arg("sweep")
        .arg(&input)
        .arg("-o")
        .arg(&out)
        .args(["--lambdas", "0.1", "--loss", "l1ssim", "--iters", "7"])
        .output()
        .unwrap();
    assert_eq!(res.status.code(), Some(2));
    let err = String::from_utf8_lossy(&res.stderr);
    assert!(err.starts_with("error: ") && err.contains("scene.ply") && err.lines().count() == 1, "{err}");
    assert!(out.join("points/l1ssim_lambda0.1/result.json").exists());
}

#[test]
fn emit_jobs_writes_slurm_and_parallel_lists() {
    let tmp = tempfile::tempdir().unwrap();
    let input = tmp.path().join("scene.ply");
    std::fs::write(&input, "ply\n").unwrap();
    let file = tmp.path().join("jobs.sh");
    let res = gscodec()
        .arg("sweep")
        .arg(&input)
        .arg("-o")
        .arg(tmp.path().join("sw"))
        .args(["--lambdas", "0.1,0.01,0.001", "--loss", "l1ssim,wdr", "--iters", "100", "--emit-jobs"])
        .arg(&file)
        .output()
        .unwrap();
    assert!(res.status.success(), "{}", String::from_utf8_lossy(&res.stderr));
    let script = std::fs::read_to_string(&file).unwrap();
    assert!(script.starts_with("#!/bin/bash") && script.contains("#SBATCH --array=0-5"));
    let list = std::fs::read_to_string(tmp.path().join("jobs.commands.txt")).unwrap();
    assert_eq!(list.lines().count(), 6);
    assert!(list.lines().all(|l| l.contains(" sweep ") && l.contains("--points-only") && l.contains("--iters 100")));
    assert!(list.contains("--lambdas 0.001 --loss wdr"));

    // A dataset trained from its images: l1ssim and wdr (WD-R only in retraining) share the
    // training at each λ, so each λ is one job running both points; at share 0.3 they do not.
    let tiny = Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/tiny");
    let emit = |extra: &[&str]| {
        let res = gscodec()
            .arg("sweep")
            .arg(&tiny)
            .arg("-o")
            .arg(tmp.path().join("sw"))
            .args(["--lambdas", "0.1,0.01,0.001", "--loss", "l1ssim,wdr", "--iters", "100", "--emit-jobs"])
            .arg(&file)
            .args(extra)
            .output()
            .unwrap();
        assert!(res.status.success(), "{}", String::from_utf8_lossy(&res.stderr));
        std::fs::read_to_string(tmp.path().join("jobs.commands.txt")).unwrap()
    };
    let list = emit(&[]);
    assert_eq!(list.lines().count(), 3, "{list}");
    assert!(list.lines().all(|l| l.contains(" --loss l1ssim,wdr ")), "{list}");
    assert_eq!(emit(&["--wd-warmup", "0.3"]).lines().count(), 6);
}

#[test]
fn two_jobs_run_points_in_process_with_typed_reports() {
    let truth = Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/tiny/truth.ply");
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("sw");
    let res = gscodec()
        .arg("sweep")
        .arg(&truth)
        .arg("-o")
        .arg(&out)
        .args(["--lambdas", "2,200", "--loss", "l1ssim,wdr", "--jobs", "2", "--backend", "cpu", "--quiet"])
        .output()
        .unwrap();
    assert!(res.status.success(), "{}", String::from_utf8_lossy(&res.stderr));
    let rows = read_results(&out).unwrap();
    assert_eq!(rows.len(), 4);
    for r in &rows {
        let dir = out.join("points").join(format!("{}_lambda{}", r.loss, r.lambda));
        assert_eq!(std::fs::metadata(dir.join("scene.gsc")).unwrap().len(), r.bytes);
        let report: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(dir.join("report.json")).unwrap()).unwrap();
        assert_eq!(report["file_bytes"].as_u64(), Some(r.bytes));
        assert_eq!(report["lambda"].as_f64(), Some(r.lambda));
        // No training (--iters 0 for a .ply): the orbit PSNR of the report is the point's PSNR.
        assert!((report["orbit_psnr"].as_f64().unwrap() - r.psnr.unwrap()).abs() < 0.05, "{report} vs {r:?}");
        assert!(!r.timeline.is_empty(), "the RD search trials form the time series");
    }
    let summary: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    assert!(summary["bd_rate"]["wdr"]["psnr"].is_number() || summary["bd_rate_notes"]["wdr"]["psnr"].is_string(), "{summary}");
    let rd = std::fs::read_to_string(out.join("rd.svg")).unwrap();
    assert!(rd.contains("l1ssim") && rd.contains("wdr"), "one curve per loss");
}

#[test]
fn a_point_of_another_wd_sigma_or_warmup_is_redone() {
    use gscodec::sweep::{Plan, Point};
    let tmp = tempfile::tempdir().unwrap();
    let plan = Plan {
        input: "lego".into(),
        out: tmp.path().to_path_buf(),
        lambdas: vec![2.0],
        losses: vec!["l1ssim".into(), "wdr".into()],
        iters: None,
        seeds: vec![0],
        // as the fake results (and every result from before retraining existed)
        retrain_iters: Some(0),
        coding_breakdown: false,
        features: gscodec::loss::FeatureSpec::Pyramid,
        wd_sigma: None,
        // the share results from before --wd-warmup existed were trained with
        wd_warmup: Some(0.1),
        search_distortion: SearchDistortion::Mse,
        max_gaussians: None,
        init: None,
        backend: gscodec::encoder::Backend::Cpu,
        dataset_args: Vec::new(),
    };
    let (l1, wdr) = (Point { lambda: 2.0, loss: "l1ssim".into(), seed: 0 }, Point { lambda: 2.0, loss: "wdr".into(), seed: 0 });
    // a wdr result from before --wd-sigma existed (no wd_sigma) was trained at σ = 4
    write_point(tmp.path(), &fake("l1ssim", 2.0, 1.0));
    write_point(tmp.path(), &fake("wdr", 2.0, 1.0));
    let s2 = Plan { wd_sigma: Some(2.0), ..plan.clone() };
    let s4 = Plan { wd_sigma: Some(4.0), ..plan.clone() };
    assert!(plan.is_done(&wdr) && s4.is_done(&wdr) && !s2.is_done(&wdr));
    // l1ssim has no σ: finished whatever --wd-sigma says
    assert!(plan.is_done(&l1) && s2.is_done(&l1));
    write_point(tmp.path(), &PointResult { wd_sigma: Some(2.0), ..fake("wdr", 2.0, 1.0) });
    assert!(s2.is_done(&wdr) && !plan.is_done(&wdr) && !s4.is_done(&wdr));
    // the warm-up share likewise: a result without one was trained with the paper's 0.1, which is
    // not today's default (0.3); a result at 0.5 (the default before session 21) is redone under
    // the default
    let default_warmup = Plan { wd_warmup: None, ..s2.clone() };
    let w5 = Plan { wd_warmup: Some(0.5), ..s2.clone() };
    assert!(s2.is_done(&wdr) && !default_warmup.is_done(&wdr) && !w5.is_done(&wdr) && w5.is_done(&l1));
    write_point(tmp.path(), &PointResult { wd_sigma: Some(2.0), wd_warmup: Some(0.3), ..fake("wdr", 2.0, 1.0) });
    assert!(default_warmup.is_done(&wdr) && !w5.is_done(&wdr));
    // the feature space likewise: a result without one was trained in `pyramid`, which is no
    // longer the default (jobs name it; the default they leave out)
    let colour = Plan { features: gscodec::loss::FeatureSpec::PyramidColour, ..default_warmup.clone() };
    assert!(!colour.is_done(&wdr) && colour.is_done(&l1));
    assert!(!colour.point_command(&wdr).join(" ").contains("--features"));
    assert!(default_warmup.point_command(&wdr).join(" ").contains("--features pyramid "));
    assert_eq!(colour.settings()["features"], "pyramid-colour");
    let r = PointResult { wd_sigma: Some(2.0), wd_warmup: Some(0.3), ..fake("wdr", 2.0, 1.0) };
    write_point(tmp.path(), &PointResult { wd_features: Some("pyramid-colour".into()), ..r.clone() });
    assert!(colour.is_done(&wdr) && !default_warmup.is_done(&wdr));
    assert_eq!(colour.encoder_config(&wdr).unwrap().loss.features, gscodec::loss::FeatureSpec::PyramidColour);
    write_point(tmp.path(), &PointResult { wd_features: Some("pyramid".into()), ..r });
    assert!(default_warmup.is_done(&wdr) && !colour.is_done(&wdr));
    write_point(tmp.path(), &PointResult { wd_sigma: Some(2.0), wd_warmup: Some(0.5), ..fake("wdr", 2.0, 1.0) });
    assert!(w5.is_done(&wdr) && !default_warmup.is_done(&wdr) && !s2.is_done(&wdr));
    // a result from before --seeds existed was trained with seed 0; another seed's point is
    // another directory, and a result of another seed in a point's directory is redone
    let l1_seed1 = Point { seed: 1, ..l1.clone() };
    assert!(w5.is_done(&l1) && !w5.is_done(&l1_seed1));
    write_point(tmp.path(), &PointResult { seed: 1, ..fake("l1ssim", 2.0, 1.0) });
    assert!(w5.is_done(&l1_seed1) && w5.is_done(&l1));
    std::fs::copy(w5.point_dir(&l1_seed1).join("result.json"), w5.point_dir(&l1).join("result.json")).unwrap();
    assert!(!w5.is_done(&l1));
    // the default retraining (a third of the iterations) redoes a point trained without it
    let retrain = Plan { retrain_iters: None, ..w5.clone() };
    assert!(w5.is_done(&wdr) && !retrain.is_done(&wdr));
    write_point(tmp.path(), &PointResult { wd_sigma: Some(2.0), wd_warmup: Some(0.5), retrain_iters: 1000, ..fake("wdr", 2.0, 1.0) });
    assert!(retrain.is_done(&wdr) && !w5.is_done(&wdr));
    // the search's distortion: a result from before the option was measured with the MSE
    let by_loss = Plan { search_distortion: SearchDistortion::Loss, ..retrain.clone() };
    assert!(!by_loss.is_done(&wdr));
    let r = PointResult { wd_sigma: Some(2.0), wd_warmup: Some(0.5), retrain_iters: 1000, ..fake("wdr", 2.0, 1.0) };
    write_point(tmp.path(), &PointResult { search_distortion: SearchDistortion::Loss, ..r });
    assert!(by_loss.is_done(&wdr) && !retrain.is_done(&wdr));
    assert!(by_loss.point_command(&wdr).join(" ").contains("--search-distortion loss"));
    assert!(!retrain.point_command(&wdr).join(" ").contains("--search-distortion"));
    // a Gaussian budget: a point grown without one is redone under one, and the other way round
    let capped = Plan { max_gaussians: Some(15_000), ..by_loss.clone() };
    assert!(by_loss.is_done(&wdr) && !capped.is_done(&wdr));
    let r = PointResult {
        wd_sigma: Some(2.0),
        wd_warmup: Some(0.5),
        retrain_iters: 1000,
        search_distortion: SearchDistortion::Loss,
        ..fake("wdr", 2.0, 1.0)
    };
    write_point(tmp.path(), &PointResult { max_gaussians: Some(15_000), ..r.clone() });
    assert!(capped.is_done(&wdr) && !by_loss.is_done(&wdr));
    assert!(!Plan { max_gaussians: Some(20_000), ..capped.clone() }.is_done(&wdr));
    let default_budget = gscodec::train::TrainConfig::default().max_gaussians;
    write_point(tmp.path(), &PointResult { max_gaussians: None, ..r.clone() });
    assert!(Plan { max_gaussians: Some(default_budget), ..capped.clone() }.is_done(&wdr), "the default budget, given");
    assert!(capped.point_command(&wdr).join(" ").contains("--max-gaussians 15000"));
    assert!(!by_loss.point_command(&wdr).join(" ").contains("--max-gaussians"));
    assert!(Plan { max_gaussians: Some(0), ..capped.clone() }.validate().unwrap_err().to_string().contains("--max-gaussians 0"));
    // a trained scene coded against the dataset (`--init`): a point trained from the images is
    // redone, and the other way round
    let init = Plan { init: Some("/s/scene.ply".into()), ..capped.clone() };
    write_point(tmp.path(), &PointResult { max_gaussians: Some(15_000), ..r.clone() });
    assert!(capped.is_done(&wdr) && !init.is_done(&wdr));
    // (retrained as `--init` retrains by default: a point of the 1000 steps before is redone)
    write_point(tmp.path(), &PointResult { max_gaussians: Some(15_000), init: Some("/s/scene.ply".into()), ..r.clone() });
    assert!(!init.is_done(&wdr) && !capped.is_done(&wdr));
    let init_r = PointResult { retrain_iters: gscodec::encoder::INIT_RETRAIN_ITERS, init: Some("/s/scene.ply".into()), ..r.clone() };
    write_point(tmp.path(), &PointResult { max_gaussians: Some(15_000), ..init_r });
    assert!(init.is_done(&wdr) && !capped.is_done(&wdr));
    assert!(!Plan { init: Some("/s/other.ply".into()), ..capped.clone() }.is_done(&wdr));
    assert!(init.point_command(&wdr).join(" ").contains("--init /s/scene.ply"));
    assert_eq!(init.settings()["init"], "/s/scene.ply");
    let on_a_scene = Plan { input: "/s/scene.ply".into(), ..init };
    assert!(on_a_scene.validate().unwrap_err().to_string().contains("--init needs a dataset input"));
    // with retraining and no share given, a dataset's wdr points train WD-R only in retraining
    // (share 1): a result at 0.3 (the default of sessions 21–24) is redone, one at 1 is done
    let by_default = Plan { wd_warmup: None, max_gaussians: None, search_distortion: SearchDistortion::Mse, ..retrain.clone() };
    let r = PointResult { wd_sigma: Some(2.0), retrain_iters: 1000, ..fake("wdr", 2.0, 1.0) };
    write_point(tmp.path(), &PointResult { wd_warmup: Some(0.3), ..r.clone() });
    assert!(!by_default.is_done(&wdr));
    write_point(tmp.path(), &PointResult { wd_warmup: Some(1.0), ..r });
    assert!(by_default.is_done(&wdr) && Plan { wd_warmup: Some(1.0), ..by_default.clone() }.is_done(&wdr));
}

/// `sweep DATASET --init SCENE`: every point codes the given trained scene against the dataset
/// (no training from the images), measured on the held-out views; a missing scene is bad input.
#[test]
fn a_sweep_of_a_trained_scene_against_its_dataset() {
    let tiny = Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/tiny");
    let truth = tiny.join("truth.ply");
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("sw");
    let sweep = |init: &Path| {
        gscodec()
            .arg("sweep")
            .arg(&tiny)
            .arg("-o")
            .arg(&out)
            .arg("--init")
            .arg(init)
            .args(["--lambdas", "20,200", "--loss", "l1ssim", "--retrain-iters", "0", "--backend", "cpu", "--quiet"])
            .output()
            .unwrap()
    };
    let res = sweep(&truth);
    assert!(res.status.success(), "{}", String::from_utf8_lossy(&res.stderr));
    let rows = read_results(&out).unwrap();
    assert_eq!(rows.len(), 2);
    let canonical = std::fs::canonicalize(&truth).unwrap().display().to_string();
    for r in &rows {
        assert_eq!(r.init.as_deref(), Some(canonical.as_str()));
        // The sample's images were rendered from this scene: far above what training gives.
        assert!(r.psnr.unwrap() > 30.0, "{r:?}");
        let report: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(out.join("points").join(format!("l1ssim_lambda{}", r.lambda)).join("report.json")).unwrap(),
        )
        .unwrap();
        assert_eq!((report["iters"].as_u64(), report["train"].is_null()), (Some(0), true));
    }
    let bytes = |l: f64| rows.iter().find(|r| r.lambda == l).unwrap().bytes;
    assert!(bytes(20.0) > bytes(200.0), "λ 20 keeps more than λ 200: {rows:?}");
    let missing = tmp.path().join("missing.ply");
    let res = sweep(&missing);
    assert_eq!(res.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&res.stderr).contains("missing.ply"));
}

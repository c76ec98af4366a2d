//! `gscodec encode/decode/info` from outside: outputs, exit codes, one-line errors.

use std::path::Path;
use std::process::Command;

fn gscodec(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_gscodec")).args(args).output().unwrap()
}

fn vectors() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("bitstream-spec/vectors")
}

#[test]
fn decode_and_info_of_a_vector() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("hand.ply");
    let gsc = vectors().join("hand.gsc");
    let o = gscodec(&["decode", gsc.to_str().unwrap(), "-o", out.to_str().unwrap(), "--quiet"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(std::fs::read(&out).unwrap(), std::fs::read(vectors().join("hand.ply")).unwrap());
    let o = gscodec(&["info", gsc.to_str().unwrap(), "--json"]);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["gaussians"], 3);
    assert_eq!(v["sh_degree"], 1);
    assert_eq!(v["version"], "3.0");
    assert!(v["sections"].as_array().unwrap().len() >= 5);
}

/// `info` of the 5.0 vector names each SH band's mode and codebook rows (SPEC §3.2).
#[test]
fn info_shows_each_sh_band_mode() {
    let gsc = vectors().join("vq.gsc");
    let o = gscodec(&["info", gsc.to_str().unwrap(), "--json"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["version"], "5.0");
    let bands = v["sh_bands"].as_array().unwrap();
    assert_eq!((bands.len(), &bands[0]["mode"], &bands[0]["codebook_rows"]), (2, &"codebook".into(), &16.into()));
    assert_eq!((&bands[1]["mode"], &bands[1]["codebook_rows"]), (&"per-coefficient".into(), &serde_json::Value::Null));
    assert!(v["group_bytes"]["sh_band1 codebook"].as_u64().unwrap() > 0);
    let text = String::from_utf8_lossy(&gscodec(&["info", gsc.to_str().unwrap()]).stdout).into_owned();
    assert!(text.contains("sh_band1    codebook of 16 rows") && text.contains("sh_band2    per coefficient"), "{text}");
}

/// `info` of a 6.0 file with importance classes (SPEC §4): its two levels and how much coarser
/// the second is; a file without them has no factors.
#[test]
fn info_shows_importance_classes() {
    let json = |name: &str| -> serde_json::Value {
        let o = gscodec(&["info", vectors().join(name).to_str().unwrap(), "--json"]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        serde_json::from_slice(&o.stdout).unwrap()
    };
    let v = json("classes.gsc");
    assert_eq!((&v["version"], &v["levels"]), (&"6.0".into(), &serde_json::json!([500, 500])));
    assert_eq!(v["level_step_factors"], serde_json::json!([1.0, 2.0]));
    assert_eq!(json("vq.gsc")["level_step_factors"], serde_json::json!([]));
    let text = String::from_utf8_lossy(&gscodec(&["info", vectors().join("classes.gsc").to_str().unwrap()]).stdout).into_owned();
    assert!(text.contains("classes     steps per level (scale step over level 0's): ×1, ×2"), "{text}");
}

#[test]
fn progressive_encode_writes_levels_that_info_shows() {
    let dir = tempfile::tempdir().unwrap();
    let input = Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/tiny/truth.ply");
    let (one, levels) = (dir.path().join("one.gsc"), dir.path().join("levels.gsc"));
    for (gsc, extra) in [(&one, None), (&levels, Some("--progressive"))] {
        let mut args = vec!["encode", input.to_str().unwrap(), "-o", gsc.to_str().unwrap(), "--quiet"];
        args.extend(extra);
        let o = gscodec(&args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    }
    let info =
        |gsc: &Path| serde_json::from_slice::<serde_json::Value>(&gscodec(&["info", gsc.to_str().unwrap(), "--json"]).stdout).unwrap();
    let (a, b) = (info(&one), info(&levels));
    // 3.0 for one level, 4.0 with levels; 5.0 (levels too) when the search coded a band by a
    // codebook; 6.0 when it chose importance classes (parameters per level); 8.0 when a channel
    // has a neighbour-context table; 9.0 when SH bands share one codebook's index.
    let codebooks = |v: &serde_json::Value| v["sh_bands"].as_array().unwrap().iter().any(|b| b["mode"] == "codebook");
    // A 6.0 or 8.0 file lists a step factor per level (one level: [1.0]); classes are two.
    let classes = |v: &serde_json::Value| v["level_step_factors"].as_array().unwrap().len() > 1;
    let neighbours = |v: &serde_json::Value| !v["neighbour_channels"].as_array().unwrap().is_empty();
    let shared = |v: &serde_json::Value| v["sh_bands"].as_array().unwrap().iter().any(|b| b["index_of_band_below"] == true);
    let version = |v: &serde_json::Value, plain: &str| {
        if shared(v) {
            "9.0".to_string()
        } else if neighbours(v) {
            "8.0".to_string()
        } else if classes(v) {
            "6.0".to_string()
        } else if codebooks(v) {
            "5.0".to_string()
        } else {
            plain.to_string()
        }
    };
    assert_eq!((a["version"].as_str().unwrap(), b["version"].as_str().unwrap()), (&version(&a, "3.0")[..], &version(&b, "4.0")[..]));
    assert_eq!(a["gaussians"], b["gaussians"]);
    let n = b["gaussians"].as_u64().unwrap();
    let sizes: Vec<u64> = b["levels"].as_array().unwrap().iter().map(|v| v.as_u64().unwrap()).collect();
    assert_eq!((sizes.len(), sizes.iter().sum::<u64>(), sizes[0]), (5, n, n.div_ceil(16)));
    // One level, or two: the classes' tail.
    assert_eq!(a["levels"].as_array().unwrap().len(), if classes(&a) { 2 } else { 1 });
    let text = String::from_utf8_lossy(&gscodec(&["info", levels.to_str().unwrap()]).stdout).into_owned();
    assert!(text.contains("levels      5: "), "{text}");
}

#[test]
fn bad_files_exit_2_with_one_error_line_and_no_output() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("bad.gsc");
    let mut bytes = std::fs::read(vectors().join("tiny.gsc")).unwrap();
    let mid = bytes.len() / 2;
    bytes[mid] ^= 0x40;
    std::fs::write(&bad, &bytes).unwrap();
    let out = dir.path().join("out.ply");
    for args in [vec!["decode", bad.to_str().unwrap(), "-o", out.to_str().unwrap()], vec!["info", bad.to_str().unwrap()]] {
        let o = gscodec(&args);
        assert_eq!(o.status.code(), Some(2));
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(err.lines().count(), 1, "{err}");
        assert!(err.starts_with("error: ") && err.contains("bad.gsc") && err.contains("checksum"), "{err}");
    }
    assert!(!out.exists());
}

#[test]
fn huge_lambda_encodes_an_empty_scene_that_decodes() {
    let dir = tempfile::tempdir().unwrap();
    let gsc = dir.path().join("e.gsc");
    let ply = dir.path().join("e.ply");
    let input = Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/tiny/truth.ply");
    let o = gscodec(&["encode", input.to_str().unwrap(), "-o", gsc.to_str().unwrap(), "--lambda", "1e12", "--quiet"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let o = gscodec(&["decode", gsc.to_str().unwrap(), "-o", ply.to_str().unwrap()]);
    assert!(o.status.success());
    let o = gscodec(&["info", gsc.to_str().unwrap(), "--json"]);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["gaussians"], 0);
    let o = gscodec(&["encode", input.to_str().unwrap(), "-o", gsc.to_str().unwrap(), "--lambda", "-1"]);
    assert_eq!(o.status.code(), Some(2));
}

#[test]
fn fine_tuning_encode_writes_a_decodable_file_and_report() {
    let dir = tempfile::tempdir().unwrap();
    let gsc = dir.path().join("t.gsc");
    let report = dir.path().join("r.json");
    let input = Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/tiny/truth.ply");
    let o = gscodec(&[
        "encode",
        input.to_str().unwrap(),
        "-o",
        gsc.to_str().unwrap(),
        "--iters",
        "3",
        "--lambda",
        "20",
        "--report",
        report.to_str().unwrap(),
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
    let bytes = std::fs::read(&gsc).unwrap();
    assert_eq!(r["file_bytes"].as_u64().unwrap() as usize, bytes.len());
    let est = r["estimated_bytes"].as_f64().unwrap();
    assert!((est - bytes.len() as f64).abs() / (bytes.len() as f64) < 0.05, "{est} vs {}", bytes.len());
    assert!(r["orbit_psnr"].as_f64().unwrap() > 25.0);
    assert!(r["series"].as_array().unwrap().iter().any(|p| p["trial"] == "train"));
    assert_eq!(
        (&r["backend"], &r["train"]["backend"], &r["loss"], &r["lambda"]),
        (&"cpu".into(), &"cpu".into(), &"wdr".into(), &20.0.into())
    );
    let stages = &r["stages"];
    assert!(stages["train_s"].as_f64().unwrap() > 0.0 && stages["total_s"].as_f64().unwrap() >= stages["rd_search_s"].as_f64().unwrap());
    assert!(r["steps"]["sh_dc"].as_f64().unwrap() > 0.0);
    gscodec_decoder::decode(&bytes).unwrap();
}

/// Without the `gpu` feature, `--backend gpu` is bad input (one line, exit 2, no output file);
/// `cpu` and `auto` train.
#[cfg(not(feature = "gpu"))]
#[test]
fn backend_gpu_is_refused_without_a_gpu_trainer() {
    let dir = tempfile::tempdir().unwrap();
    let gsc = dir.path().join("g.gsc");
    let input = Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/tiny/truth.ply");
    let o = gscodec(&["encode", input.to_str().unwrap(), "-o", gsc.to_str().unwrap(), "--iters", "2", "--backend", "gpu"]);
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.lines().count() == 1 && err.contains("GPU training not available"), "{err}");
    assert!(!gsc.exists());
}

/// `--target-psnr`: the file `eval --reference INPUT --orbit 8` measures reaches the target, and
/// the report lists the search's encodes, each printed as it finished; an unreachable target is
/// bad input.
#[test]
fn target_psnr_is_reached_as_eval_measures_it() {
    let dir = tempfile::tempdir().unwrap();
    let gsc = dir.path().join("t.gsc");
    let report = dir.path().join("r.json");
    let input = Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/tiny/truth.ply");
    let (inp, out, rep) = (input.to_str().unwrap(), gsc.to_str().unwrap(), report.to_str().unwrap());
    let o = gscodec(&["encode", inp, "-o", out, "--target-psnr", "38", "--report", rep]);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    let o = gscodec(&["eval", out, "--reference", inp, "--orbit", "8", "--json", "--quiet"]);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let psnr = v["psnr"].as_f64().unwrap();
    assert!(psnr >= 38.0 - 0.01, "{psnr}");
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
    assert!((r["orbit_psnr"].as_f64().unwrap() - psnr).abs() < 0.01, "report {} vs eval {psnr}", r["orbit_psnr"]);
    let probes = r["target"]["probes"].as_array().unwrap();
    assert!(probes.len() > 2);
    // One line per encode, in the search's order, with its λ, bytes, PSNR and verdict.
    let lines: Vec<&str> = stderr.lines().filter(|l| l.starts_with("encode ")).collect();
    assert_eq!(lines.len(), probes.len(), "{stderr}");
    for (i, (line, p)) in lines.iter().zip(probes).enumerate() {
        let psnr = p["psnr"].as_f64().unwrap();
        let met = if psnr >= 38.0 { "meets" } else { "misses" };
        let (lambda, rest) = line.strip_prefix(&format!("encode {}: λ = ", i + 1)).and_then(|l| l.split_once(", ")).expect(line);
        // serde_json may read the report's λ an ulp off.
        let want_lambda = p["lambda"].as_f64().unwrap();
        assert!((lambda.parse::<f64>().unwrap() - want_lambda).abs() <= 1e-12 * want_lambda, "{line}: {want_lambda}");
        let seconds = p["seconds"].as_f64().unwrap();
        assert!(seconds > 0.0, "{p}");
        assert_eq!(rest, format!("{} bytes, orbit PSNR {psnr:.2} dB: {met} the target ({seconds:.1} s)", p["bytes"]));
    }
    let bytes = std::fs::metadata(&gsc).unwrap().len();
    assert!(probes.iter().filter(|p| p["psnr"].as_f64().unwrap() >= 38.0).all(|p| p["bytes"].as_u64().unwrap() >= bytes));
    let o = gscodec(&["encode", inp, "-o", out, "--target-psnr", "190", "--quiet"]);
    assert_eq!(o.status.code(), Some(2));
    let o = gscodec(&["encode", inp, "-o", out, "--target-psnr", "30", "--lambda", "3"]);
    assert_eq!(o.status.code(), Some(2), "a target and a λ conflict");
}

/// A dataset's target reads its held-out views, as `gscodec eval OUT DATASET` measures them:
/// `--target-psnr` gives the smallest probe that reaches the PSNR there, `--target-bytes` the best
/// PSNR there within the size; an unreachable target is bad input and writes nothing. (`--init`
/// the dataset's own truth and no retraining, so that each probe is one RD search.)
#[test]
fn a_dataset_target_is_met_on_its_held_out_views() {
    let dir = tempfile::tempdir().unwrap();
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let (data, init) = (root.join("samples/tiny"), root.join("samples/tiny/truth.ply"));
    let (data, init) = (data.to_str().unwrap(), init.to_str().unwrap());
    let gsc = dir.path().join("t.gsc");
    let report = dir.path().join("r.json");
    let (out, rep) = (gsc.to_str().unwrap(), report.to_str().unwrap());
    let heldout_psnr = || {
        let o = gscodec(&["eval", out, data, "--json", "--quiet"]);
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        v["psnr"].as_f64().unwrap()
    };
    for (flag, value) in [("--target-psnr", "40"), ("--target-bytes", "6000")] {
        let o = gscodec(&["encode", data, "--init", init, "--retrain-iters", "0", "-o", out, flag, value, "--report", rep, "--quiet"]);
        assert!(o.status.success() && o.stderr.is_empty(), "{}", String::from_utf8_lossy(&o.stderr));
        let (psnr, bytes) = (heldout_psnr(), std::fs::metadata(&gsc).unwrap().len());
        let r: serde_json::Value = serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
        let probes = r["target"]["probes"].as_array().unwrap();
        assert!(probes.len() > 2 && probes.iter().all(|p| p["trained"] == false), "{flag}: {probes:?}");
        let of = |p: &serde_json::Value| (p["bytes"].as_u64().unwrap(), p["psnr"].as_f64().unwrap());
        let chosen = probes.iter().map(of).find(|p| p.0 == bytes).expect("the file is one of the probes");
        assert!((chosen.1 - psnr).abs() < 0.01, "{flag}: probe {} dB, eval {psnr} dB", chosen.1);
        if flag == "--target-psnr" {
            assert!(psnr >= 40.0 - 0.01, "{psnr}");
            assert!(probes.iter().map(of).filter(|p| p.1 >= 40.0).all(|p| p.0 >= bytes), "the smallest that reaches 40 dB");
        } else {
            assert!(bytes <= 6000, "{bytes}");
            assert!(probes.iter().map(of).filter(|p| p.0 <= 6000).all(|p| p.1 <= psnr), "the best within 6000 bytes");
        }
    }
    // With retraining every probe retrains.
    let o =
        gscodec(&["encode", data, "--init", init, "--retrain-iters", "5", "-o", out, "--target-psnr", "40", "--report", rep, "--quiet"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (psnr, bytes) = (heldout_psnr(), std::fs::metadata(&gsc).unwrap().len());
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
    let probes = r["target"]["probes"].as_array().unwrap();
    assert!(probes.len() > 1 && probes.iter().all(|p| p["trained"] == true), "{probes:?}");
    assert!(psnr >= 40.0 - 0.01 && r["retrain_iters"] == 5, "{psnr} {r}");
    let of = |p: &serde_json::Value| (p["bytes"].as_u64().unwrap(), p["psnr"].as_f64().unwrap());
    assert!(probes.iter().map(of).filter(|p| p.1 >= 40.0).all(|p| p.0 >= bytes), "the smallest that reaches 40 dB: {probes:?}");
    // Trained from the images once (20 iterations here), then coded at each probe's λ.
    let o = gscodec(&[
        "encode",
        data,
        "--iters",
        "20",
        "--retrain-iters",
        "0",
        "-o",
        out,
        "--target-bytes",
        "6000",
        "--report",
        rep,
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
    assert!(
        std::fs::metadata(&gsc).unwrap().len() <= 6000 && r["iters"] == 20 && r["target"]["probes"].as_array().unwrap().len() > 2,
        "{r}"
    );
    std::fs::remove_file(&gsc).unwrap();
    let o = gscodec(&["encode", data, "--init", init, "--retrain-iters", "0", "-o", out, "--target-psnr", "100", "--quiet"]);
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.starts_with("error: ") && err.contains("not reachable") && err.lines().count() == 1, "{err}");
    assert!(!gsc.exists(), "no output for a target not met");
}

/// `encode --profile anchor` writes a 7.0 file (SPEC §12) that decodes, that `info` describes and
/// whose report's PSNR is what `eval` measures; `--profile auto` writes, byte for byte, one of
/// the two profiles' files.
#[test]
fn anchor_profile_encodes_decodes_and_auto_picks_one_of_the_two() {
    let dir = tempfile::tempdir().unwrap();
    let input = Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/tiny/truth.ply");
    let encode = |profile: &str| -> (Vec<u8>, serde_json::Value) {
        let gsc = dir.path().join(format!("{profile}.gsc"));
        let report = dir.path().join(format!("{profile}.json"));
        let o = gscodec(&[
            "encode",
            input.to_str().unwrap(),
            "-o",
            gsc.to_str().unwrap(),
            "--profile",
            profile,
            "--iters",
            "5",
            "--lambda",
            "20",
            "--report",
            report.to_str().unwrap(),
            "--quiet",
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        (std::fs::read(&gsc).unwrap(), serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap())
    };
    let (bytes, r) = encode("anchor");
    assert_eq!((&r["profile"], r["file_bytes"].as_u64().unwrap() as usize), (&"anchor".into(), bytes.len()));
    assert!(r["anchor"]["anchors"].as_u64().unwrap() > 0 && r["explicit_alternative"].is_array());
    let scene = gscodec_decoder::decode(&bytes).unwrap();
    assert_eq!(scene.len() as u64, r["gaussians"].as_u64().unwrap());
    let gsc = dir.path().join("anchor.gsc");
    let o = gscodec(&["info", gsc.to_str().unwrap(), "--json"]);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!((&v["version"], &v["profile"]), (&"7.0".into(), &"anchor".into()));
    assert_eq!(v["anchors"]["anchors"], r["anchor"]["anchors"]);
    let o = gscodec(&["eval", gsc.to_str().unwrap(), "--reference", input.to_str().unwrap(), "--orbit", "8", "--json"]);
    let e: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!((e["psnr"].as_f64().unwrap() - r["orbit_psnr"].as_f64().unwrap()).abs() < 1e-6);
    let (explicit, _) = encode("explicit");
    let (auto, ra) = encode("auto");
    let expected = if ra["profile"] == "anchor" { &bytes } else { &explicit };
    assert!(&auto == expected, "auto wrote the {} profile's file", ra["profile"]);
    assert!(ra["anchor"].is_object());
    // A dataset: trained from its images (the explicit scene), then the anchors fitted to it.
    let (from_images, images_report) = (dir.path().join("images.gsc"), dir.path().join("images.json"));
    let dataset = Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/tiny");
    let o = gscodec(&[
        "encode",
        dataset.to_str().unwrap(),
        "-o",
        from_images.to_str().unwrap(),
        "--iters",
        "20",
        "--loss",
        "l1ssim",
        "--profile",
        "anchor",
        "--anchor-iters",
        "5",
        "--report",
        images_report.to_str().unwrap(),
        "--quiet",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let bytes = std::fs::read(&from_images).unwrap();
    assert_eq!(gscodec_decoder::peek_header(&bytes).unwrap().version_major, 7);
    gscodec_decoder::decode(&bytes).unwrap();
    // The series ends with the anchor file (not the explicit one) on the held-out views.
    let r: serde_json::Value = serde_json::from_slice(&std::fs::read(&images_report).unwrap()).unwrap();
    let coded = r["series"].as_array().unwrap().iter().rfind(|p| p["trial"] == "coded").unwrap().clone();
    assert_eq!(coded["estimated_bits"].as_f64(), Some(8.0 * bytes.len() as f64));
    let o = gscodec(&["eval", from_images.to_str().unwrap(), dataset.to_str().unwrap(), "--json", "--quiet"]);
    let e: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!((e["psnr"].as_f64().unwrap() - coded["heldout_psnr"].as_f64().unwrap()).abs() < 1e-6, "{e} against {coded}");
    // The anchor shape flags are checked at the door: exit 2, one line, no output.
    let out = dir.path().join("bad.gsc");
    let o = gscodec(&["encode", input.to_str().unwrap(), "-o", out.to_str().unwrap(), "--profile", "anchor", "--anchor-hidden", "513"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(!out.exists());
}

/// `encode --seed` reaches the trainer: another seed than the default 0 trains another scene
/// (that one seed gives one file is `tests/threads.rs`'s business). `--retrain-iters`: the
/// Gaussians the RD search keeps, trained again on the images, cover for those it pruned: on the
/// sample the file is smaller and its held-out PSNR higher than without. `--coding-breakdown`:
/// its last cumulative row is the file itself (bytes and held-out PSNR). `--search-distortion`
/// reaches the report, and its file decodes; `--max-gaussians` and `--densify-grad-threshold`
/// reach the trainer (their effect: `tests/schedule.rs`).
#[test]
fn encode_seed_and_retraining_change_the_training() {
    let dir = tempfile::tempdir().unwrap();
    let tiny = Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/tiny");
    let encode = |name: &str, extra: &[&str]| {
        let (gsc, report) = (dir.path().join(name), dir.path().join(format!("{name}.json")));
        let mut args = vec!["encode", tiny.to_str().unwrap(), "-o", gsc.to_str().unwrap(), "--iters", "20", "--loss", "l1ssim"];
        args.extend(["--backend", "cpu", "--report", report.to_str().unwrap(), "--quiet"]);
        let o = gscodec(&[&args[..], extra].concat());
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let r: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(report).unwrap()).unwrap();
        let coded = r["series"].as_array().unwrap().iter().find(|p| p["trial"] == "coded").unwrap()["heldout_psnr"].as_f64().unwrap();
        (std::fs::read(gsc).unwrap(), coded, r)
    };
    let (default, psnr, report) = encode("plain.gsc", &["--retrain-iters", "0"]);
    assert_eq!(report["retrain_iters"], 0);
    assert_eq!(report["train"]["config"]["max_gaussians"], 100_000);
    let (_, _, report) = encode("capped.gsc", &["--retrain-iters", "0", "--max-gaussians", "12345", "--densify-grad-threshold", "0.0001"]);
    assert_eq!(report["train"]["config"]["max_gaussians"], 12_345, "the budget reaches the trainer");
    let threshold = report["train"]["config"]["densify_grad_threshold"].as_f64().unwrap();
    assert!((threshold - 1e-4).abs() < 1e-9, "the threshold reaches the trainer: {threshold}");
    assert!(encode("three.gsc", &["--retrain-iters", "0", "--seed", "3"]).0 != default, "another seed trains another scene");
    assert!(report.get("coding_breakdown").is_none(), "only when asked");
    assert_eq!(report["search_distortion"], "mse");
    let (by_loss, _, report) = encode("loss.gsc", &["--retrain-iters", "0", "--search-distortion", "loss"]);
    assert_eq!(report["search_distortion"], "loss");
    let decoded = gscodec_decoder::decode(&by_loss).unwrap();
    assert_eq!(decoded.len(), report["gaussians"].as_u64().unwrap() as usize);
    let (retrained, retrained_psnr, report) = encode("retrained.gsc", &["--retrain-iters", "10", "--coding-breakdown"]);
    assert_eq!((report["retrain_iters"].as_u64(), report["iters"].as_u64()), (Some(10), Some(20)));
    let rows = report["coding_breakdown"].as_array().unwrap();
    let stages: Vec<&str> = rows.iter().map(|r| r["stage"].as_str().unwrap()).collect();
    assert_eq!(stages[..2], ["uncoded", "quantised"]);
    assert_eq!(rows[0]["bytes"], serde_json::Value::Null);
    let file = &rows[5];
    assert_eq!(file["stage"], "+ importance classes");
    assert_eq!((file["bytes"].as_u64(), file["heldout_psnr"].as_f64()), (Some(retrained.len() as u64), Some(retrained_psnr)));
    assert!(rows.iter().all(|r| r["heldout_psnr"].as_f64().is_some_and(f64::is_finite)));
    assert_eq!(rows.len(), 8);
    assert!(
        retrained.len() < default.len() && retrained_psnr > psnr + 0.5,
        "{} B {retrained_psnr} dB against {} B {psnr} dB",
        retrained.len(),
        default.len()
    );
}

/// `encode DATASET --init SCENE` codes a scene trained elsewhere against the dataset, with no
/// training from the images: here the sample's ground truth, which its images were rendered
/// from, so the coded file's held-out PSNR (the report's, which `eval` agrees with) is far above
/// what 20 iterations from scratch give. `--retrain-iters` fine-tunes it to the training
/// images. An `--init` without a dataset, an unreadable scene and `--iters` beside it are
/// refused (exit 2, no output).
#[test]
fn encode_init_codes_a_trained_scene_against_the_dataset() {
    let dir = tempfile::tempdir().unwrap();
    let tiny = Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/tiny");
    let truth = tiny.join("truth.ply");
    let encode = |name: &str, extra: &[&str]| {
        let (gsc, report) = (dir.path().join(name), dir.path().join(format!("{name}.json")));
        let mut args = vec!["encode", tiny.to_str().unwrap(), "-o", gsc.to_str().unwrap(), "--loss", "l1ssim", "--backend", "cpu"];
        args.extend(["--report", report.to_str().unwrap(), "--quiet"]);
        let o = gscodec(&[&args[..], extra].concat());
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let r: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(report).unwrap()).unwrap();
        let coded = r["series"].as_array().unwrap().iter().find(|p| p["trial"] == "coded").unwrap()["heldout_psnr"].as_f64().unwrap();
        (gsc, coded, r)
    };
    let (_, scratch, _) = encode("scratch.gsc", &["--iters", "20", "--retrain-iters", "0"]);
    let (coded, psnr, report) = encode("init.gsc", &["--init", truth.to_str().unwrap(), "--retrain-iters", "0"]);
    assert_eq!(report["init"], truth.to_str().unwrap());
    assert_eq!((report["iters"].as_u64(), report["retrain_iters"].as_u64()), (Some(0), Some(0)));
    assert!(report["train"].is_null(), "no training from the images");
    assert!(report.get("retrain_lambda").is_none());
    assert!(psnr > scratch + 5.0 && psnr > 30.0, "{psnr} dB from the truth against {scratch} dB from scratch");
    let o = gscodec(&["eval", coded.to_str().unwrap(), tiny.to_str().unwrap(), "--json", "--quiet"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let eval: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!((eval["psnr"].as_f64().unwrap() - psnr).abs() < 1e-6, "eval {} against the report's {psnr}", eval["psnr"]);
    // Retraining fine-tunes the kept Gaussians to the training images, the run in `train`.
    let (retrained, _, report) = encode("retrained.gsc", &["--init", truth.to_str().unwrap(), "--retrain-iters", "10"]);
    assert_eq!((report["iters"].as_u64(), report["retrain_iters"].as_u64()), (Some(0), Some(10)));
    assert_eq!(report["train"]["config"]["iters"], 10);
    // Its rate term at a share of λ (docs/wd.md §27); none without retraining.
    let lambda = report["lambda"].as_f64().unwrap();
    assert_eq!(report["retrain_lambda"].as_f64(), Some(lambda * gscodec::encoder::RETRAIN_RATE_WEIGHT));
    let decoded = gscodec_decoder::decode(&std::fs::read(retrained).unwrap()).unwrap();
    assert_eq!(decoded.len(), report["gaussians"].as_u64().unwrap() as usize);
    // Refused: a scene input, a missing scene, training flags beside it.
    let out = dir.path().join("bad.gsc");
    let refused = |args: &[&str], says: &str| {
        let o = gscodec(&[&["encode"], args, &["-o", out.to_str().unwrap(), "--quiet"]].concat());
        assert_eq!(o.status.code(), Some(2), "{args:?}");
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(err.contains(says), "{args:?}: {err}");
        assert!(!out.exists());
    };
    refused(&[truth.to_str().unwrap(), "--init", truth.to_str().unwrap()], "--init needs a dataset input");
    let missing = dir.path().join("missing.ply");
    refused(&[tiny.to_str().unwrap(), "--init", missing.to_str().unwrap()], "missing.ply");
    refused(&[tiny.to_str().unwrap(), "--init", truth.to_str().unwrap(), "--iters", "5"], "cannot be used with");
}

/// A scene's encode states its orbit PSNR, and below 30 dB says how to ask for a quality; a
/// dataset's encode states the held-out PSNR instead, with no note. Both are what `eval` reads.
#[test]
fn encode_states_the_orbit_psnr_and_notes_a_low_one() {
    let dir = tempfile::tempdir().unwrap();
    let tiny = Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/tiny");
    let (input, out) = (tiny.join("truth.ply"), dir.path().join("t.gsc"));
    let (input, tiny, out) = (input.to_str().unwrap(), tiny.to_str().unwrap(), out.to_str().unwrap());
    // encode's stderr, and the dB it states after `label`.
    let encode = |args: &[&str], label: &str| -> (String, f64) {
        let o = gscodec(&[&["encode", "-o", out], args].concat());
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let err = String::from_utf8_lossy(&o.stderr).into_owned();
        let at = err.find(label).unwrap_or_else(|| panic!("no {label} in: {err}")) + label.len();
        let db = err[at..].split(' ').next().unwrap().parse().unwrap();
        (err, db)
    };
    let eval = |args: &[&str]| -> f64 {
        let o = gscodec(&[&["eval", out], args, &["--json"]].concat());
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        serde_json::from_slice::<serde_json::Value>(&o.stdout).unwrap()["psnr"].as_f64().unwrap()
    };
    let (fine, db) = encode(&[input, "--lambda", "20"], "orbit PSNR ");
    assert!((db - eval(&["--reference", input, "--orbit", "8"])).abs() < 0.006, "{fine}");
    assert!(db >= 30.0 && !fine.contains("note:"), "{fine}");
    let (coarse, db) = encode(&[input, "--lambda", "100000"], "orbit PSNR ");
    assert!(db < 30.0 && coarse.contains("note: orbit PSNR below 30 dB at λ 100000"), "{coarse}");
    let (err, db) = encode(&[tiny, "--iters", "20", "--lambda", "100000"], "held-out PSNR ");
    assert!((db - eval(&[tiny])).abs() < 0.006, "{err}");
    assert!(!err.contains("orbit PSNR") && !err.contains("note:"), "{err}");
}

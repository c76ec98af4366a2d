//! SOG v2, PlayCanvas compressed PLY and glTF (KHR_gaussian_splatting): write → read round trips
//! within each format's quantisation, the reference tool's files (tests/data/formats, made by
//! splat-transform from samples/tiny/truth.ply) read back to the source, and bad input through
//! `gscodec convert`.

use gscodec::decoder::math::{covariance_3d, normalize_quat, sigmoid, SH_C0};
use gscodec::decoder::Splats;
use gscodec::io::compressed_ply::{decode_compressed_ply, encode_compressed_ply, CHUNK_SIZE};
use gscodec::io::gltf::{decode_gltf, encode_glb, encode_gltf};
use gscodec::io::ply::read_ply;
use gscodec::io::sog::{decode_sog_bundle, encode_sog_bundle, morton_order, quantize_1d};
use gscodec::io::{read_scene, write_scene};
use gscodec::rng::Rng;
use gscodec::testkit::{random_splats_in, SceneRanges};
use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn data(name: &str) -> PathBuf {
    root().join("tests/data/formats").join(name)
}

fn truth() -> Splats {
    read_ply(&root().join("samples/tiny/truth.ply")).unwrap()
}

/// A random scene with every attribute spread over a wide range.
fn scene(n: usize, degree: u8) -> Splats {
    let ranges = SceneRanges { extent: [20.0, 5.0, 50.0], log_scale: [-9.0, 3.0], opacity: [-8.0, 8.0], sh_dc: 3.0, sh_rest: 0.9 };
    random_splats_in(n, degree, 0x9e37_79b9_7f4a_7c15, &ranges)
}

/// `1 − |q·p|` of the normalised quaternions: 0 for the same rotation.
fn rot_err(a: [f32; 4], b: [f32; 4]) -> f32 {
    let (a, b) = (normalize_quat(a), normalize_quat(b));
    1.0 - (0..4).map(|i| a[i] * b[i]).sum::<f32>().abs()
}

/// The entry of a sorted codebook nearest to `v`.
fn nearest(cb: &[f32], v: f32) -> f32 {
    cb.iter().copied().min_by(|a, b| (a - v).abs().total_cmp(&(b - v).abs())).unwrap()
}

/// Largest half-gap between neighbouring codebook entries: the worst error of a value inside the
/// codebook's range.
fn half_gap(cb: &[f32]) -> f32 {
    cb.windows(2).map(|w| (w[1] - w[0]) / 2.0).fold(0.0, f32::max)
}

/// SOG: positions within half a 16-bit step of the log-transformed extent, rotations within a
/// byte per component, opacity within half of 1/255, scales / colours / SH exactly the nearest
/// codebook entry (1024 Gaussians: the SH palette holds every vector, so it adds no error).
#[test]
fn sog_round_trip_within_quantisation() {
    let s = scene(1024, 3);
    let bytes = encode_sog_bundle(&s).unwrap();
    let d = decode_sog_bundle(&bytes).unwrap();
    assert_eq!((d.len(), d.sh_degree), (s.len(), 3));
    let order = morton_order(&s.positions);
    let lt = |v: f32| v.signum() * (v.abs() + 1.0).ln();
    let step: Vec<f32> = (0..3)
        .map(|a| {
            let (lo, hi) = s.positions.iter().map(|p| lt(p[a])).fold((f32::MAX, f32::MIN), |(l, h), v| (l.min(v), h.max(v)));
            (hi - lo) / 65535.0
        })
        .collect();
    let k = s.rest_coeffs();
    let flat = |f: &dyn Fn(usize) -> Vec<f32>| -> Vec<f32> { order.iter().flat_map(|&g| f(g)).collect() };
    let (scale_cb, _) = quantize_1d(&flat(&|g| s.log_scales[g].to_vec()));
    let (dc_cb, _) = quantize_1d(&flat(&|g| s.sh_dc[g].to_vec()));
    let (sh_cb, _) = quantize_1d(&flat(&|g| s.rest_of(g).to_vec()));
    assert!(half_gap(&scale_cb) < 0.05 && half_gap(&dc_cb) < 0.05 && half_gap(&sh_cb) < 0.02, "codebooks too coarse");
    for (t, &g) in order.iter().enumerate() {
        for a in 0..3 {
            let x = s.positions[g][a];
            let bound = (x.abs() + 1.0) * (0.5 * step[a]).exp_m1() + 1e-5 * (x.abs() + 1.0);
            assert!((d.positions[t][a] - x).abs() <= bound, "Gaussian {g} axis {a}: {} vs {x} (bound {bound})", d.positions[t][a]);
            assert_eq!(d.log_scales[t][a], nearest(&scale_cb, s.log_scales[g][a]));
            assert_eq!(d.sh_dc[t][a], nearest(&dc_cb, s.sh_dc[g][a]));
        }
        assert!(rot_err(d.rotations[t], s.rotations[g]) < 5e-5, "Gaussian {g}: {:?} vs {:?}", d.rotations[t], s.rotations[g]);
        assert!((sigmoid(d.opacity_logits[t]) - sigmoid(s.opacity_logits[g])).abs() <= 0.5 / 255.0 + 1e-6);
        for (j, &v) in s.rest_of(g).iter().enumerate() {
            assert_eq!(d.sh_rest[t * k * 3 + j], nearest(&sh_cb, v), "Gaussian {g} SH {j}");
        }
    }
}

/// Bundled and unbundled SOG hold the same scene; degree 0 has no SH files; large scenes keep a
/// palette of the reference's size and stay close.
#[test]
fn sog_unbundled_and_palette() {
    let dir = tempfile::tempdir().unwrap();
    let s = scene(3000, 1);
    let (bundle, meta) = (dir.path().join("a.sog"), dir.path().join("unb/meta.json"));
    write_scene(&bundle, &s).unwrap();
    write_scene(&meta, &s).unwrap();
    let (a, b) = (read_scene(&bundle).unwrap(), read_scene(&meta).unwrap());
    assert_eq!(a, b);
    let names: Vec<String> =
        std::fs::read_dir(dir.path().join("unb")).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into()).collect();
    assert_eq!(names.len(), 8, "{names:?}");
    // 3000 Gaussians → a 2048-entry palette: SH error stays well below the coefficients' spread.
    let order = morton_order(&s.positions);
    let (mut err, mut sq) = (0.0f64, 0.0f64);
    for (t, &g) in order.iter().enumerate() {
        for (j, &v) in s.rest_of(g).iter().enumerate() {
            err += f64::from(a.sh_rest[t * 9 + j] - v).powi(2);
            sq += f64::from(v).powi(2);
        }
    }
    assert!(err / sq < 0.25, "palette error {:.3} of the SH energy", err / sq);
    let d0 = decode_sog_bundle(&encode_sog_bundle(&s.with_sh_degree(0)).unwrap()).unwrap();
    assert_eq!(d0.sh_degree, 0);
}

/// Compressed PLY: each field within half a step of its chunk's range (11/10/11 bits for
/// position and scale, 8 for colour and opacity, 10 per small quaternion component, 8/256 for SH).
#[test]
fn compressed_ply_round_trip_within_quantisation() {
    for degree in [0, 2, 3] {
        let s = scene(700, degree);
        let d = decode_compressed_ply(&encode_compressed_ply(&s).unwrap()).unwrap();
        assert_eq!((d.len(), d.sh_degree), (s.len(), degree));
        let order = morton_order(&s.positions);
        let k = s.rest_coeffs();
        for (c, members) in order.chunks(CHUNK_SIZE).enumerate() {
            let range = |f: &dyn Fn(usize) -> [f32; 3]| -> [f32; 3] {
                std::array::from_fn(|a| {
                    let (lo, hi) = members.iter().map(|&g| f(g)[a]).fold((f32::MAX, f32::MIN), |(l, h), v| (l.min(v), h.max(v)));
                    hi - lo
                })
            };
            let (pr, sr, cr) = (range(&|g| s.positions[g]), range(&|g| s.log_scales[g]), range(&|g| s.sh_dc[g]));
            for (j, &g) in members.iter().enumerate() {
                let t = c * CHUNK_SIZE + j;
                for (a, bits) in [11, 10, 11].into_iter().enumerate() {
                    let half = 0.5 / ((1u32 << bits) - 1) as f32;
                    assert!((d.positions[t][a] - s.positions[g][a]).abs() <= pr[a] * half + 1e-5 * pr[a].max(1.0));
                    assert!((d.log_scales[t][a] - s.log_scales[g][a]).abs() <= sr[a] * half + 1e-5);
                    let dc_bound = cr[a] * SH_C0 * (0.5 / 255.0) / SH_C0 + 1e-4;
                    assert!((d.sh_dc[t][a] - s.sh_dc[g][a]).abs() <= dc_bound, "dc {} vs {}", d.sh_dc[t][a], s.sh_dc[g][a]);
                }
                assert!(rot_err(d.rotations[t], s.rotations[g]) < 3e-6);
                assert!((sigmoid(d.opacity_logits[t]) - sigmoid(s.opacity_logits[g])).abs() <= 0.5 / 255.0 + 1e-6);
                for (i, &v) in s.rest_of(g).iter().enumerate() {
                    assert!((d.sh_rest[t * k * 3 + i] - v).abs() <= 0.5 * 8.0 / 256.0 + 1e-6);
                }
            }
        }
    }
}

/// glTF: positions, quaternions and SH are exact (the frame turn only flips signs); scales and
/// opacities go through exp/ln and sigmoid/logit in f32.
#[test]
fn gltf_round_trip_is_exact_up_to_activations() {
    for degree in [0, 1, 3] {
        let s = scene(300, degree);
        for bytes in [encode_glb(&s).unwrap(), encode_gltf(&s).unwrap()] {
            let d = decode_gltf(&bytes, None).unwrap();
            assert_eq!(d.sh_degree, degree);
            assert_eq!(d.positions, s.positions);
            assert_eq!(d.sh_dc, s.sh_dc);
            assert_eq!(d.sh_rest, s.sh_rest);
            for i in 0..s.len() {
                assert!(rot_err(d.rotations[i], s.rotations[i]) < 1e-6);
                for a in 0..3 {
                    assert!((d.log_scales[i][a] - s.log_scales[i][a]).abs() < 1e-5);
                }
                assert!((sigmoid(d.opacity_logits[i]) - sigmoid(s.opacity_logits[i])).abs() < 1e-6);
            }
        }
    }
}

/// A node's translation and uniform scale apply (in glTF's frame); a rotation is refused.
#[test]
fn gltf_node_transforms() {
    let s = scene(10, 1);
    let mut doc: serde_json::Value = serde_json::from_slice(&encode_gltf(&s).unwrap()).unwrap();
    doc["nodes"][0]["translation"] = serde_json::json!([1.0, 2.0, 3.0]);
    doc["nodes"][0]["scale"] = serde_json::json!([2.0, 2.0, 2.0]);
    let d = decode_gltf(&serde_json::to_vec(&doc).unwrap(), None).unwrap();
    for i in 0..s.len() {
        let p = s.positions[i];
        // glTF position (−x, −y, z), scaled by 2, moved by (1, 2, 3), turned back.
        let want = [2.0 * p[0] - 1.0, 2.0 * p[1] - 2.0, 2.0 * p[2] + 3.0];
        for a in 0..3 {
            assert!((d.positions[i][a] - want[a]).abs() < 1e-4, "{:?} vs {want:?}", d.positions[i]);
            assert!((d.log_scales[i][a] - s.log_scales[i][a] - 2f32.ln()).abs() < 1e-5);
        }
    }
    doc["nodes"][0]["rotation"] = serde_json::json!([0.0, std::f64::consts::FRAC_1_SQRT_2, 0.0, std::f64::consts::FRAC_1_SQRT_2]);
    let e = decode_gltf(&serde_json::to_vec(&doc).unwrap(), None).unwrap_err();
    assert!(e.contains("rotation"), "{e}");
}

/// Pairs every decoded Gaussian with a distinct source Gaussian whose position lies within
/// `pos_tol(decoded index, axis)` and that `same` accepts.
fn match_all(src: &Splats, dec: &Splats, pos_tol: &dyn Fn(usize, usize) -> f32, same: &dyn Fn(usize, usize) -> bool) {
    assert_eq!(src.len(), dec.len());
    let mut used = vec![false; src.len()];
    for t in 0..dec.len() {
        let mut cand =
            (0..src.len()).filter(|&g| !used[g] && (0..3).all(|a| (src.positions[g][a] - dec.positions[t][a]).abs() <= pos_tol(t, a)));
        let best = cand.find(|&g| same(g, t));
        let g = best.unwrap_or_else(|| panic!("decoded Gaussian {t} at {:?} matches no source Gaussian", dec.positions[t]));
        used[g] = true;
    }
}

/// Log-transformed step of a SOG file's means, read from its meta.json.
fn sog_steps(meta: &[u8]) -> [f32; 3] {
    let m: serde_json::Value = serde_json::from_slice(meta).unwrap();
    std::array::from_fn(|a| ((m["means"]["maxs"][a].as_f64().unwrap() - m["means"]["mins"][a].as_f64().unwrap()) / 65535.0) as f32)
}

fn sog_meta_from_zip(path: &Path) -> Vec<u8> {
    let mut z = zip::ZipArchive::new(std::fs::File::open(path).unwrap()).unwrap();
    let mut out = Vec::new();
    std::io::Read::read_to_end(&mut z.by_name("meta.json").unwrap(), &mut out).unwrap();
    out
}

/// splat-transform's SOG (bundled and unbundled) reads back to truth.ply: positions within one
/// 16-bit step of the log extent (the reference truncates), rotations within a byte per component,
/// opacity within 1/255, scales and colours within the codebook's largest half-gap; SH through
/// its 512-entry k-means palette stays close in energy.
#[test]
fn reference_sog_matches_source() {
    let src = truth();
    for (path, meta) in [
        (data("tiny.sog"), sog_meta_from_zip(&data("tiny.sog"))),
        (data("tiny-sog/meta.json"), std::fs::read(data("tiny-sog/meta.json")).unwrap()),
    ] {
        let d = read_scene(&path).unwrap();
        assert_eq!((d.len(), d.sh_degree), (1000, 3), "{}", path.display());
        let step = sog_steps(&meta);
        let m: serde_json::Value = serde_json::from_slice(&meta).unwrap();
        let cb = |key: &str| -> Vec<f32> { m[key]["codebook"].as_array().unwrap().iter().map(|v| v.as_f64().unwrap() as f32).collect() };
        let (scale_tol, dc_tol) = (half_gap(&cb("scales")) + 1e-5, half_gap(&cb("sh0")) + 1e-5);
        let tol = |t: usize, a: usize| (d.positions[t][a].abs() + 1.0) * step[a].exp_m1() * 1.01 + 1e-6;
        let same = |g: usize, t: usize| {
            rot_err(src.rotations[g], d.rotations[t]) < 1e-4
                && (sigmoid(src.opacity_logits[g]) - sigmoid(d.opacity_logits[t])).abs() <= 1.0 / 255.0 + 1e-6
                && (0..3).all(|a| {
                    (src.log_scales[g][a] - d.log_scales[t][a]).abs() <= scale_tol && (src.sh_dc[g][a] - d.sh_dc[t][a]).abs() <= dc_tol
                })
        };
        match_all(&src, &d, &tol, &same);
        let energy = |s: &Splats| s.sh_rest.iter().map(|&v| f64::from(v).powi(2)).sum::<f64>();
        assert!((energy(&d) / energy(&src) - 1.0).abs() < 0.2, "SH energy {} vs {}", energy(&d), energy(&src));
    }
}

/// splat-transform's compressed PLY reads back to truth.ply within half a step of each chunk's
/// range (the ranges are the decoded chunk's own extremes, which decode exactly).
#[test]
fn reference_compressed_ply_matches_source() {
    let src = truth();
    let d = read_scene(&data("tiny.compressed.ply")).unwrap();
    assert_eq!((d.len(), d.sh_degree), (1000, 3));
    let chunk_range = |t: usize, f: &dyn Fn(usize) -> f32| -> f32 {
        let c = t / CHUNK_SIZE;
        let (lo, hi) =
            (c * CHUNK_SIZE..((c + 1) * CHUNK_SIZE).min(d.len())).map(f).fold((f32::MAX, f32::MIN), |(l, h), v| (l.min(v), h.max(v)));
        hi - lo
    };
    let half = |a: usize| 0.5 / ((1u32 << [11, 10, 11][a]) - 1) as f32;
    let tol = |t: usize, a: usize| chunk_range(t, &|i| d.positions[i][a]) * half(a) * 1.01 + 1e-6;
    let k = d.rest_coeffs();
    let same = |g: usize, t: usize| {
        rot_err(src.rotations[g], d.rotations[t]) < 3e-6
            && (sigmoid(src.opacity_logits[g]) - sigmoid(d.opacity_logits[t])).abs() <= 0.5 / 255.0 + 1e-6
            && (0..3).all(|a| {
                (src.log_scales[g][a] - d.log_scales[t][a]).abs() <= chunk_range(t, &|i| d.log_scales[i][a]) * half(a) * 1.01 + 1e-6
                    && (src.sh_dc[g][a] - d.sh_dc[t][a]).abs() <= chunk_range(t, &|i| d.sh_dc[i][a]) * (0.5 / 255.0) * 1.01 + 1e-5
            })
            && (0..3 * k).all(|j| (src.sh_rest[g * 3 * k + j] - d.sh_rest[t * 3 * k + j]).abs() <= 0.5 * 8.0 / 256.0 + 1e-6)
    };
    match_all(&src, &d, &tol, &same);
}

/// splat-transform's GLB (SH degree 1) reads back to truth.ply: same order, values equal up to
/// float rounding of its frame turn and activations.
#[test]
fn reference_glb_matches_source() {
    let src = truth().with_sh_degree(1);
    let d = read_scene(&data("tiny-sh1.glb")).unwrap();
    assert_eq!((d.len(), d.sh_degree), (1000, 1));
    for i in 0..d.len() {
        for a in 0..3 {
            assert!((d.positions[i][a] - src.positions[i][a]).abs() < 1e-5, "{i}: {:?} vs {:?}", d.positions[i], src.positions[i]);
            assert!((d.log_scales[i][a] - src.log_scales[i][a]).abs() < 1e-5);
            assert!((d.sh_dc[i][a] - src.sh_dc[i][a]).abs() < 1e-6);
        }
        assert!(rot_err(d.rotations[i], src.rotations[i]) < 1e-6);
        assert!((sigmoid(d.opacity_logits[i]) - sigmoid(src.opacity_logits[i])).abs() < 1e-6);
        for j in 0..9 {
            assert!(
                (d.sh_rest[i * 9 + j] - src.sh_rest[i * 9 + j]).abs() < 1e-5,
                "{i} SH {j}: {} vs {}",
                d.sh_rest[i * 9 + j],
                src.sh_rest[i * 9 + j]
            );
        }
    }
}

/// `gscodec convert` to and from every format keeps the scene (via the formats above).
#[test]
fn convert_between_formats() {
    let dir = tempfile::tempdir().unwrap();
    let truth_ply = root().join("samples/tiny/truth.ply");
    for name in ["a.sog", "b/meta.json", "c.compressed.ply", "d.glb", "e.gltf"] {
        let out = dir.path().join(name);
        let o = Command::new(env!("CARGO_BIN_EXE_gscodec"))
            .args(["convert", truth_ply.to_str().unwrap(), out.to_str().unwrap()])
            .output()
            .unwrap();
        assert!(o.status.success(), "{name}: {}", String::from_utf8_lossy(&o.stderr));
        let back = dir.path().join(format!("{}.ply", name.replace('/', "_")));
        let o =
            Command::new(env!("CARGO_BIN_EXE_gscodec")).args(["convert", out.to_str().unwrap(), back.to_str().unwrap()]).output().unwrap();
        assert!(o.status.success(), "{name} back: {}", String::from_utf8_lossy(&o.stderr));
        let s = read_ply(&back).unwrap();
        assert_eq!((s.len(), s.sh_degree), (1000, 3), "{name}");
    }
}

/// Exit 2, one `error: FILE: …` line naming the input and `needle`, no output file.
fn assert_bad(input: &Path, needle: &str) {
    let out = input.with_file_name("out.ply");
    let o = Command::new(env!("CARGO_BIN_EXE_gscodec")).args(["convert", input.to_str().unwrap(), out.to_str().unwrap()]).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(2), "{}: {err}", input.display());
    let lines: Vec<&str> = err.lines().filter(|l| !l.trim().is_empty()).collect();
    assert_eq!(lines.len(), 1, "{err}");
    assert!(lines[0].starts_with(&format!("error: {}: ", input.display())), "{}", lines[0]);
    assert!(lines[0].contains(needle), "`{}` lacks `{needle}`", lines[0]);
    assert!(!out.exists());
}

#[test]
fn malformed_inputs_fail_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let p = |n: &str| dir.path().join(n);
    // Truncated zip: the central directory is gone.
    let sog = std::fs::read(data("tiny.sog")).unwrap();
    std::fs::write(p("trunc.sog"), &sog[..sog.len() / 2]).unwrap();
    assert_bad(&p("trunc.sog"), "zip");
    // A SOG bundle without meta.json.
    std::fs::write(p("empty.sog"), &sog[..0]).unwrap();
    assert_bad(&p("empty.sog"), "zip");
    // meta.json without its `means` key (images beside it intact).
    std::fs::create_dir(p("nomeans")).unwrap();
    for e in std::fs::read_dir(data("tiny-sog")).unwrap() {
        let e = e.unwrap();
        std::fs::copy(e.path(), p("nomeans").join(e.file_name())).unwrap();
    }
    let mut meta: serde_json::Value = serde_json::from_slice(&std::fs::read(data("tiny-sog/meta.json")).unwrap()).unwrap();
    meta.as_object_mut().unwrap().remove("means");
    std::fs::write(p("nomeans/meta.json"), serde_json::to_vec(&meta).unwrap()).unwrap();
    assert_bad(&p("nomeans/meta.json"), "missing field `means`");
    // An image missing from the folder.
    std::fs::remove_file(p("nomeans/quats.webp")).unwrap();
    meta["means"] =
        serde_json::from_slice::<serde_json::Value>(&std::fs::read(data("tiny-sog/meta.json")).unwrap()).unwrap()["means"].clone();
    std::fs::write(p("nomeans/meta.json"), serde_json::to_vec(&meta).unwrap()).unwrap();
    assert_bad(&p("nomeans/meta.json"), "quats.webp");
    // glTF: an accessor claiming more elements than its buffer view holds, one that does not exist,
    // and a truncated GLB.
    let s = scene(20, 1);
    let mut doc: serde_json::Value = serde_json::from_slice(&encode_gltf(&s).unwrap()).unwrap();
    doc["accessors"][1]["count"] = serde_json::json!(1_000_000_000u64);
    std::fs::write(p("count.gltf"), serde_json::to_vec(&doc).unwrap()).unwrap();
    assert_bad(&p("count.gltf"), "accessor 1");
    doc["accessors"][1]["count"] = serde_json::json!(20);
    doc["meshes"][0]["primitives"][0]["attributes"]["KHR_gaussian_splatting:OPACITY"] = serde_json::json!(99);
    std::fs::write(p("noacc.gltf"), serde_json::to_vec(&doc).unwrap()).unwrap();
    assert_bad(&p("noacc.gltf"), "accessor 99 does not exist");
    let glb = encode_glb(&s).unwrap();
    std::fs::write(p("trunc.glb"), &glb[..glb.len() - 100]).unwrap();
    assert_bad(&p("trunc.glb"), "truncated");
    // Compressed PLY cut short.
    let cply = std::fs::read(data("tiny.compressed.ply")).unwrap();
    std::fs::write(p("trunc.compressed.ply"), &cply[..cply.len() - 1000]).unwrap();
    assert_bad(&p("trunc.compressed.ply"), "truncated");
}

/// Random byte edits and truncations of each reference file: the readers return an error or a
/// scene, never panic (and never allocate for a size the data cannot back).
#[test]
fn mutated_files_never_panic() {
    let mut rng = Rng::new(0x2545_f491_4f6c_dd1d);
    let mut next = move || rng.next_u64();
    let files: [(&str, fn(&[u8]) -> bool); 3] = [
        ("tiny.sog", |b| decode_sog_bundle(b).is_ok()),
        ("tiny.compressed.ply", |b| decode_compressed_ply(b).is_ok()),
        ("tiny-sh1.glb", |b| decode_gltf(b, None).is_ok()),
    ];
    for (name, decode) in files {
        let orig = std::fs::read(data(name)).unwrap();
        assert!(decode(&orig), "{name}");
        for round in 0..150 {
            let mut b = orig.clone();
            if round % 5 == 0 {
                b.truncate((next() % b.len() as u64) as usize);
            } else {
                for _ in 0..1 + next() % 8 {
                    let at = (next() % b.len() as u64) as usize;
                    b[at] = next() as u8;
                }
            }
            let _ = decode(&b);
        }
    }
    // The unbundled folder (no zip CRC in the way): edit one of its files per round.
    let dir = tempfile::tempdir().unwrap();
    let names: Vec<std::ffi::OsString> = std::fs::read_dir(data("tiny-sog")).unwrap().map(|e| e.unwrap().file_name()).collect();
    let copy_all = || {
        names.iter().for_each(|n| {
            std::fs::copy(data("tiny-sog").join(n), dir.path().join(n)).unwrap();
        })
    };
    for _ in 0..100 {
        copy_all();
        let victim = dir.path().join(&names[(next() % names.len() as u64) as usize]);
        let mut b = std::fs::read(&victim).unwrap();
        for _ in 0..1 + next() % 4 {
            let at = (next() % b.len() as u64) as usize;
            b[at] = next() as u8;
        }
        std::fs::write(&victim, &b).unwrap();
        let _ = read_scene(&dir.path().join("meta.json"));
    }
    // A meta.json announcing far more Gaussians than its images hold.
    copy_all();
    let mut meta: serde_json::Value = serde_json::from_slice(&std::fs::read(data("tiny-sog/meta.json")).unwrap()).unwrap();
    meta["count"] = serde_json::json!(1u64 << 40);
    std::fs::write(dir.path().join("meta.json"), serde_json::to_vec(&meta).unwrap()).unwrap();
    let e = read_scene(&dir.path().join("meta.json")).unwrap_err().to_string();
    assert!(e.contains("fewer than count"), "{e}");
}

/// Accessors in the extension's integer forms (normalized unsigned-byte opacity, normalized
/// signed-short rotation) and a buffer in an external `.bin` file beside the `.gltf`.
#[test]
fn gltf_integer_accessors_and_external_buffer() {
    use base64::Engine;
    let s = scene(8, 0);
    let mut doc: serde_json::Value = serde_json::from_slice(&encode_gltf(&s).unwrap()).unwrap();
    let b64 = doc["buffers"][0]["uri"].as_str().unwrap().split_once(";base64,").unwrap().1.to_string();
    let mut bin = base64::engine::general_purpose::STANDARD.decode(b64).unwrap();
    // Opacity as u8 normalized: byte b reads as b/255.
    let op: Vec<u8> = (0..8).map(|i| (i * 30 + 10) as u8).collect();
    // Rotation (x, y, z, w) as i16 normalized: the identity and a quarter turn about z.
    let rot: Vec<i16> = (0..8).flat_map(|i| if i % 2 == 0 { [0, 0, 0, 32767] } else { [0, 0, 23170, 23170] }).collect();
    let (op_at, rot_at) = (bin.len(), bin.len() + 8);
    bin.extend_from_slice(&op);
    bin.extend(rot.iter().flat_map(|v| v.to_le_bytes()));
    let views = doc["bufferViews"].as_array_mut().unwrap();
    views.push(serde_json::json!({ "buffer": 0, "byteOffset": op_at, "byteLength": 8 }));
    views.push(serde_json::json!({ "buffer": 0, "byteOffset": rot_at, "byteLength": 64 }));
    let nv = views.len();
    let accs = doc["accessors"].as_array_mut().unwrap();
    accs.push(serde_json::json!({ "bufferView": nv - 2, "componentType": 5121, "normalized": true, "count": 8, "type": "SCALAR" }));
    accs.push(serde_json::json!({ "bufferView": nv - 1, "componentType": 5122, "normalized": true, "count": 8, "type": "VEC4" }));
    let na = accs.len();
    let attrs = &mut doc["meshes"][0]["primitives"][0]["attributes"];
    attrs["KHR_gaussian_splatting:OPACITY"] = serde_json::json!(na - 2);
    attrs["KHR_gaussian_splatting:ROTATION"] = serde_json::json!(na - 1);
    doc["buffers"][0] = serde_json::json!({ "byteLength": bin.len(), "uri": "scene.bin" });
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("scene.bin"), &bin).unwrap();
    std::fs::write(dir.path().join("scene.gltf"), serde_json::to_vec(&doc).unwrap()).unwrap();
    let d = read_scene(&dir.path().join("scene.gltf")).unwrap();
    assert_eq!(d.positions, s.positions);
    for i in 0..8 {
        assert!((sigmoid(d.opacity_logits[i]) - op[i] as f32 / 255.0).abs() < 1e-6);
        // The covariance in the .ply frame is the glTF one turned back: T Σ' T, T = diag(−1, −1, 1).
        let q_gltf = if i % 2 == 0 { [1.0, 0.0, 0.0, 0.0] } else { [0.70710677, 0.0, 0.0, 0.70710677] };
        let t = glam::Mat3::from_diagonal(glam::Vec3::new(-1.0, -1.0, 1.0));
        let want = t * covariance_3d(s.log_scales[i], q_gltf) * t;
        let got = covariance_3d(d.log_scales[i], d.rotations[i]);
        assert!(want.abs_diff_eq(got, 1e-4 * want.abs().to_cols_array().iter().fold(1e-6f32, |m, v| m.max(*v))), "{i}: {got} vs {want}");
    }
    std::fs::remove_file(dir.path().join("scene.bin")).unwrap();
    assert!(read_scene(&dir.path().join("scene.gltf")).unwrap_err().to_string().contains("scene.bin"));
}

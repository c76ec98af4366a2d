//! SPZ / .splat interop: the reference baseline (skipped when ../shared/data is absent) and
//! write → read round trips within each format's quantisation.

use gscodec::decoder::math::{normalize_quat, sh_rest_coeffs, sigmoid};
use gscodec::decoder::Splats;
use gscodec::io::ply::read_ply;
use gscodec::io::splat::{decode_splat, encode_splat};
use gscodec::io::spz::{decode_spz, encode_spz, read_spz, SpzVersion};
use gscodec::testkit::{random_splats_in, shared_data, SceneRanges};
use std::path::Path;

fn max_abs_diff(a: impl IntoIterator<Item = f32>, b: impl IntoIterator<Item = f32>) -> f32 {
    a.into_iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max)
}

/// Our reading of the reference tool's v4 file equals the reference tool's own decode.
#[test]
fn k7000_spz_matches_reference_decode() {
    let (Some(spz), Some(ply)) = (shared_data("spz-baseline/k7000.spz"), shared_data("spz-baseline/k7000_spz_decoded.ply")) else { return };
    let ours = read_spz(&spz).unwrap();
    let theirs = read_ply(&ply).unwrap();
    assert_eq!((ours.len(), ours.sh_degree), (theirs.len(), theirs.sh_degree));
    assert_eq!((ours.len(), ours.sh_degree), (9080, 3));
    let eps = 1e-6;
    assert_eq!(ours.positions, theirs.positions, "positions are exact fixed point");
    assert!(max_abs_diff(ours.log_scales.iter().flatten().copied(), theirs.log_scales.iter().flatten().copied()) < eps);
    assert!(max_abs_diff(ours.rotations.iter().flatten().copied(), theirs.rotations.iter().flatten().copied()) < eps);
    assert!(max_abs_diff(ours.opacity_logits.iter().copied(), theirs.opacity_logits.iter().copied()) < 1e-5);
    assert!(max_abs_diff(ours.sh_dc.iter().flatten().copied(), theirs.sh_dc.iter().flatten().copied()) < eps);
    assert_eq!(ours.sh_rest, theirs.sh_rest, "SH bytes map exactly");
}

/// Every baseline file decodes, and re-encoding our decode as v4 gives back the same scene.
#[test]
fn baseline_files_reencode_losslessly() {
    for name in ["k7000.spz", "fruit.spz", "playbot_lod3.spz"] {
        let Some(p) = shared_data(&format!("spz-baseline/{name}")) else { return };
        let s = read_spz(&p).unwrap();
        for v in [SpzVersion::V4, SpzVersion::V3] {
            let again = decode_spz(&encode_spz(&s, v).unwrap()).unwrap();
            assert_eq!(again.positions, s.positions, "{name} {v:?}");
            assert_eq!(again.sh_rest, s.sh_rest, "{name} {v:?}");
            assert_eq!(again.log_scales, s.log_scales, "{name} {v:?}");
            assert_eq!(again.sh_dc, s.sh_dc, "{name} {v:?}");
            assert_eq!(again.opacity_logits, s.opacity_logits, "{name} {v:?}");
            let worst = s.rotations.iter().zip(&again.rotations).map(|(&a, &b)| rot_err(a, b)).fold(0.0, f32::max);
            assert!(worst < 1e-5, "{name} {v:?}: rotation error {worst}");
        }
    }
}

/// Wide ranges: positions far from the origin, tiny to huge scales, nearly transparent to opaque.
fn scene(n: usize, degree: u8) -> Splats {
    let ranges = SceneRanges { extent: [50.0; 3], log_scale: [-9.0, 5.0], opacity: [-6.0, 6.0], sh_dc: 3.0, sh_rest: 0.9 };
    random_splats_in(n, degree, 0x1234_5678, &ranges)
}

/// Angle-free rotation error: 1 - |<q1, q2>| for normalised quaternions (same rotation up to sign).
fn rot_err(a: [f32; 4], b: [f32; 4]) -> f32 {
    let (a, b) = (normalize_quat(a), normalize_quat(b));
    1.0 - (0..4).map(|i| a[i] * b[i]).sum::<f32>().abs()
}

#[test]
fn spz_round_trip_within_quantisation() {
    for degree in [0u8, 1, 3] {
        let s = scene(500, degree);
        for v in [SpzVersion::V3, SpzVersion::V4] {
            let bytes = encode_spz(&s, v).unwrap();
            let d = decode_spz(&bytes).unwrap();
            assert_eq!((d.len(), d.sh_degree), (s.len(), degree));
            // 12 fractional bits: half a step is 2^-13.
            assert!(max_abs_diff(d.positions.iter().flatten().copied(), s.positions.iter().flatten().copied()) <= 0.5 / 4096.0 + 1e-5);
            // log-scale bytes step 1/16
            assert!(max_abs_diff(d.log_scales.iter().flatten().copied(), s.log_scales.iter().flatten().copied()) <= 0.5 / 16.0 + 1e-5);
            // alpha byte: sigmoid within half a step of 1/255
            assert!(
                max_abs_diff(d.opacity_logits.iter().map(|&o| sigmoid(o)), s.opacity_logits.iter().map(|&o| sigmoid(o)))
                    <= 0.5 / 255.0 + 1e-5
            );
            // colour: dc step 1/(0.15*255)
            assert!(max_abs_diff(d.sh_dc.iter().flatten().copied(), s.sh_dc.iter().flatten().copied()) <= 0.5 / (0.15 * 255.0) + 1e-4);
            // SH: band 1 bucket 8/128 (half = 1/32 plus rounding), higher bands 16/128
            for (i, (a, b)) in d.sh_rest.iter().zip(&s.sh_rest).enumerate() {
                let band1 = (i / 3) % sh_rest_coeffs(degree) < 3;
                let tol = if band1 { 4.5 / 128.0 } else { 8.5 / 128.0 };
                assert!((a - b).abs() <= tol + 1e-6, "sh {i}: {a} vs {b}");
            }
            let worst = s.rotations.iter().zip(&d.rotations).map(|(&a, &b)| rot_err(a, b)).fold(0.0, f32::max);
            assert!(worst < 2e-5, "{v:?} rotation error {worst}");
            // Decoding twice is identical; re-encoding the decode is a fixed point.
            assert_eq!(decode_spz(&encode_spz(&d, v).unwrap()).unwrap().positions, d.positions);
        }
    }
}

#[test]
fn splat_round_trip_within_quantisation() {
    let s = scene(300, 2);
    let bytes = encode_splat(&s);
    assert_eq!(bytes.len(), 300 * 32);
    let d = decode_splat(&bytes).unwrap();
    assert_eq!(d.sh_degree, 0);
    // The writer reorders by size x opacity; match Gaussians by position (exact f32).
    let mut order = vec![0usize; s.len()];
    for i in 0..s.len() {
        let j = d.positions.iter().position(|p| *p == s.positions[i]).expect("position kept exactly");
        order[j] = i;
        for a in 0..3 {
            assert!((d.log_scales[j][a] - s.log_scales[i][a]).abs() < 1e-5);
        }
        assert!((sigmoid(d.opacity_logits[j]) - sigmoid(s.opacity_logits[i])).abs() <= 0.5 / 255.0 + 1e-5);
        assert!(rot_err(d.rotations[j], s.rotations[i]) < 2e-3);
    }
    // Order: non-increasing exp(sum log-scale) * opacity of the source Gaussians.
    let imp: Vec<f32> = order.iter().map(|&i| s.log_scales[i].iter().sum::<f32>().exp() * sigmoid(s.opacity_logits[i])).collect();
    assert!(imp.windows(2).all(|w| w[0] >= w[1]));
    assert!(decode_splat(&bytes[..31]).is_err());
}

/// `gscodec convert` picks SPZ / .splat by extension; bad SPZ input is one `error:` line, exit 2,
/// and no output file.
#[test]
fn convert_cli_round_trips_through_spz_and_splat() {
    let exe = env!("CARGO_BIN_EXE_gscodec");
    let truth = Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/tiny/truth.ply");
    let dir = tempfile::tempdir().unwrap();
    let (spz, back, splat) = (dir.path().join("t.spz"), dir.path().join("t.ply"), dir.path().join("t.splat"));
    let run = |a: &Path, b: &Path| std::process::Command::new(exe).arg("convert").arg(a).arg(b).output().unwrap();
    assert!(run(&truth, &spz).status.success());
    assert!(run(&spz, &back).status.success());
    assert!(run(&spz, &splat).status.success());
    let (orig, again) = (read_ply(&truth).unwrap(), read_ply(&back).unwrap());
    assert_eq!((again.len(), again.sh_degree), (orig.len(), orig.sh_degree));
    assert!(max_abs_diff(again.positions.iter().flatten().copied(), orig.positions.iter().flatten().copied()) <= 0.5 / 4096.0 + 1e-5);
    assert_eq!(std::fs::metadata(&splat).unwrap().len(), orig.len() as u64 * 32);
    let bad = dir.path().join("bad.spz");
    std::fs::write(&bad, b"NGSP\x04\0\0\0garbage").unwrap();
    let out = dir.path().join("never.ply");
    let r = run(&bad, &out);
    assert_eq!(r.status.code(), Some(2));
    let err = String::from_utf8_lossy(&r.stderr);
    assert!(err.starts_with("error: ") && err.contains("bad.spz") && err.lines().count() == 1, "{err}");
    assert!(!out.exists());
}

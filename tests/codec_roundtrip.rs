//! Encoder ⇄ decoder: bit-exact round trips, determinism, leave-out and refusal of bad input.

use glam::Vec3;
use gscodec::rate::{self, quantise, EncodeConfig};
use gscodec::rng::Rng;
use gscodec::testkit::{extreme_splats, random_splats_in, rig_cameras, SceneRanges};
use gscodec_decoder::bitstream::{VERSION_MAJOR_NEIGHBOURS, VERSION_MAJOR_SHARED};
use gscodec_decoder::render::render;
use gscodec_decoder::{decode, decode_with, Camera, DecodeError, FormatErrorKind, Limits, RenderOptions, Splats};

/// A deterministic random scene of `n` Gaussians (SH degree `d`) spread over `extent`, its
/// scales, flat ones included, in proportion.
fn scene(n: usize, d: u8, extent: f32, seed: u64) -> Splats {
    let e = extent.max(1e-3).ln();
    let ranges = SceneRanges {
        extent: [extent, extent, 0.5 * extent],
        log_scale: [e - 8.0, e - 3.0],
        opacity: [-6.0, 6.0],
        sh_dc: 1.0,
        sh_rest: 0.2,
    };
    random_splats_in(n, d, seed, &ranges)
}

#[test]
fn decode_of_encode_is_the_dequantised_scene_bit_exactly() {
    for (n, d, extent) in [(1, 0, 1.0), (500, 3, 1.0), (300, 1, 1e-4), (300, 2, 1e5), (2, 3, 0.0)] {
        let s = scene(n, d, extent, n as u64);
        let (bytes, report, q) = rate::encode(&s, &EncodeConfig::default()).unwrap();
        let decoded = decode(&bytes).unwrap();
        let expected = quantise::dequantise(&q);
        assert_eq!(decoded, expected, "n={n} d={d} extent={extent}");
        assert_eq!(report.file_bytes, bytes.len());
        decoded.validate().unwrap();
        // Positions stay within a grid step of the input (no wrap-around), scene-scale invariant.
        let (lo, hi) = s.bounds().unwrap();
        for p in &decoded.positions {
            for a in 0..3 {
                let slack = (hi[a] - lo[a]) * 1e-3 + 1e-30;
                assert!(p[a] >= lo[a] - slack && p[a] <= hi[a] + slack);
            }
        }
    }
}

/// A Gaussian is the same with its axes relabelled (permuted, signs flipped) and its rotation
/// turned to match; the encoder codes each in the cheapest labelling, so the file does not
/// depend on the one the input uses, and the smallest-three index of uniformly random rotations
/// is always `w` (a constant channel).
#[test]
fn the_file_does_not_depend_on_how_the_input_labels_a_gaussians_axes() {
    let s = scene(3000, 2, 1.0, 21);
    // q ⊗ i, q ⊗ j, q ⊗ k: half turns about an axis, exact in f32 (components permuted, signs
    // flipped); the scales stay.
    let mut t = s.clone();
    for (n, r) in t.rotations.iter_mut().enumerate() {
        let [w, x, y, z] = *r;
        *r = match n % 4 {
            0 => [w, x, y, z],
            1 => [-x, w, z, -y],
            2 => [-y, -z, w, x],
            _ => [-z, y, -x, w],
        };
    }
    let (a, report, _) = rate::encode(&s, &EncodeConfig::default()).unwrap();
    let (b, _, _) = rate::encode(&t, &EncodeConfig::default()).unwrap();
    assert!(a == b, "the same Gaussians, another labelling: another file");
    let rotation = report.groups.iter().find(|g| g.group == "rotation").unwrap();
    assert!(rotation.constant_channels >= 1, "the index channel is constant: {rotation:?}");
    // A quarter turn about z swaps the x and y axes, so the scales swap too: not exact in f32,
    // so the file may differ in a few values, not in size beyond rounding.
    let mut u = s.clone();
    let h = std::f64::consts::FRAC_1_SQRT_2;
    for (r, l) in u.rotations.iter_mut().zip(u.log_scales.iter_mut()) {
        let [w, x, y, z] = r.map(f64::from);
        *r = [h * (w - z), h * (x + y), h * (y - x), h * (z + w)].map(|v| v as f32);
        *l = [l[1], l[0], l[2]];
    }
    let (c, _, _) = rate::encode(&u, &EncodeConfig::default()).unwrap();
    let ratio = c.len() as f64 / a.len() as f64;
    assert!((ratio - 1.0).abs() < 0.002, "{} against {} bytes", c.len(), a.len());
}

/// Opacities above the renderer's α cap (`quantise::opacity_logit_cap`) are coded at the cap:
/// the file does not depend on how far above it a trained scene pushed them, and they decode
/// within a step of it.
#[test]
fn opacities_above_the_alpha_cap_are_coded_at_the_cap() {
    let mut s = scene(2000, 0, 1.0, 5);
    // A third of the Gaussians saturated, their logits spread up to 19 as training leaves them.
    for (i, o) in s.opacity_logits.iter_mut().enumerate() {
        if i % 3 == 0 {
            *o = 5.0 + 14.0 * ((i * 7919) % 1000) as f32 / 1000.0;
        }
    }
    let config = EncodeConfig::default();
    let cap = quantise::opacity_logit_cap(config.steps.opacity);
    let mut at_cap = s.clone();
    at_cap.opacity_logits.iter_mut().for_each(|o| *o = o.min(cap));
    let (a, _, _) = rate::encode(&s, &config).unwrap();
    let (b, _, _) = rate::encode(&at_cap, &config).unwrap();
    assert!(a == b, "logits above the cap reach the file");
    let decoded = decode(&a).unwrap();
    let top = decoded.opacity_logits.iter().fold(f32::MIN, |m, &o| m.max(o));
    assert!((cap - config.steps.opacity..=cap + config.steps.opacity).contains(&top), "decoded logit {top}, cap {cap}");
}

#[test]
fn rate_estimate_matches_file_size() {
    let s = scene(3000, 3, 1.0, 7);
    let (bytes, report, _) = rate::encode(&s, &EncodeConfig::default()).unwrap();
    let est = report.estimated_bits() / 8.0;
    let actual = bytes.len() as f64;
    for g in &report.groups {
        eprintln!("{} est {:.0} stream {} table {}", g.group, g.estimated_bits / 8.0, g.stream_bytes, g.table_bytes);
    }
    assert!((est - actual).abs() / actual < 0.03, "estimated {est} actual {actual}");
}

#[test]
fn decode_is_identical_across_thread_counts_and_runs() {
    let s = scene(2000, 3, 3.0, 11);
    let (bytes, _, _) = rate::encode(&s, &EncodeConfig::default()).unwrap();
    let one = decode_threads(&bytes, 1).unwrap();
    let four = decode_threads(&bytes, 4).unwrap();
    let again = decode_threads(&bytes, 4).unwrap();
    let bits = |s: &Splats| s.positions.iter().flatten().chain(s.sh_rest.iter()).map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&one), bits(&four));
    assert_eq!(one, again);
    // Encoding is deterministic too.
    assert_eq!(rate::encode(&s, &EncodeConfig::default()).unwrap().0, bytes);
}

#[test]
fn max_sh_degree_skips_bands() {
    let s = scene(200, 3, 1.0, 3);
    let (bytes, _, _) = rate::encode(&s, &EncodeConfig::default()).unwrap();
    let full = decode(&bytes).unwrap();
    let d1 = decode_with(&bytes, &Limits { max_sh_degree: 1, ..Limits::default() }).unwrap();
    assert_eq!(d1.sh_degree, 1);
    assert_eq!(d1, full.with_sh_degree(1));
}

#[test]
fn leave_out_constant_channels_zero_bands_and_transparent_gaussians() {
    let mut s = scene(100, 3, 1.0, 5);
    // Band 3 and 2 all zero: dropped; opacity constant; half the Gaussians invisible.
    for i in 0..s.len() {
        for k in 3..15 {
            for c in 0..3 {
                s.sh_rest[(i * 15 + k) * 3 + c] = 0.0;
            }
        }
        s.opacity_logits[i] = if i % 2 == 0 { 2.0 } else { -8.0 };
    }
    let (bytes, report, _) = rate::encode(&s, &EncodeConfig::default()).unwrap();
    assert_eq!(report.sh_degree, 1);
    assert_eq!(report.gaussians, 50);
    let info = gscodec_decoder::inspect(&bytes).unwrap();
    assert!(info.constant_channels.contains(&"opacity/0".to_string()));
    assert!(!info.info.sections.iter().any(|x| x.name == "opacity" && x.kind >= 0x20), "constant group has no stream");
    assert_eq!(info.encoder.map(|e| e.input_gaussians), Some(100));
}

#[test]
fn empty_and_huge_lambda_give_valid_files() {
    let empty = Splats::new(3);
    let (bytes, _, _) = rate::encode(&empty, &EncodeConfig::default()).unwrap();
    assert!(decode(&bytes).unwrap().is_empty());
    let s = scene(300, 3, 1.0, 9);
    let (bytes, report, _) = rate::encode(&s, &EncodeConfig::for_lambda(rate::Lambda::new(1e12).unwrap())).unwrap();
    assert_eq!(report.gaussians, 0);
    assert!(decode(&bytes).unwrap().is_empty());
    let sizes: Vec<usize> = [0.0, 1.0, 10.0, 100.0]
        .iter()
        .map(|&l| rate::encode(&s, &EncodeConfig::for_lambda(rate::Lambda::new(l).unwrap())).unwrap().0.len())
        .collect();
    assert!(sizes.windows(2).all(|w| w[1] < w[0]), "{sizes:?}");
}

/// DESIGN §8's extreme Gaussians (scales e^−20 … e^10, degenerate covariances, opacity logits
/// ±100, one at the camera centre) code and decode to the dequantised scene, which renders to
/// finite pixels from the origin and from outside.
#[test]
fn extreme_gaussians_round_trip_and_render_finite() {
    let s = extreme_splats(3);
    let (bytes, report, q) = rate::encode(&s, &EncodeConfig::default()).unwrap();
    let decoded = decode(&bytes).unwrap();
    assert_eq!(decoded, quantise::dequantise(&q));
    assert!(report.gaussians >= s.len() - 1, "only the invisible Gaussian may be left out: {}", report.gaussians);
    let at_origin = Camera::look_at(Vec3::ZERO, Vec3::Z, Vec3::NEG_Y, 40, 30, 1.0);
    for cam in rig_cameras(2, 3.0, 40, 30).into_iter().chain([at_origin]) {
        for scene in [&s, &decoded] {
            let img = render(scene, &cam, &RenderOptions::default());
            assert!(img.data.iter().all(|v| v.is_finite() && *v >= 0.0), "non-finite or negative pixel");
        }
    }
}

#[test]
fn nan_input_is_refused() {
    let mut s = scene(10, 0, 1.0, 1);
    s.log_scales[3][1] = f32::NAN;
    assert!(rate::encode(&s, &EncodeConfig::default()).is_err());
    s.log_scales[3][1] = 0.0;
    s.positions[2][0] = f32::INFINITY;
    assert!(rate::encode(&s, &EncodeConfig::default()).is_err());
}

#[test]
fn mutated_files_never_panic() {
    let s = scene(300, 3, 1.0, 13);
    let (bytes, _, _) = rate::encode(&s, &EncodeConfig::default()).unwrap();
    let mut rng = Rng::new(99);
    let mut rnd = move |m: usize| rng.below(m.max(1));
    let mut errors = 0;
    for _ in 0..3000 {
        let mut b = bytes.clone();
        for _ in 0..1 + rnd(4) {
            match rnd(3) {
                0 => {
                    let i = rnd(b.len());
                    b[i] ^= 1 << rnd(8);
                }
                1 => b.truncate(rnd(b.len())),
                _ => {
                    let i = rnd(b.len() + 1);
                    b.insert(i, rnd(256) as u8);
                }
            }
            if b.is_empty() {
                break;
            }
        }
        if decode_threads(&b, 1).is_err() {
            errors += 1;
        }
    }
    // CRCs catch (nearly) every mutation.
    assert!(errors > 2900, "{errors}");
}

#[test]
fn typed_errors_for_bad_files() {
    let s = scene(20, 0, 1.0, 2);
    let (bytes, _, _) = rate::encode(&s, &EncodeConfig::default()).unwrap();
    let e = decode(b"PK\x03\x04").unwrap_err();
    assert_eq!(e.format_error().map(|f| f.kind()), Some(FormatErrorKind::BadMagic));
    let mut newer = bytes.clone();
    newer[4] = VERSION_MAJOR_SHARED + 1;
    assert!(matches!(decode(&newer), Err(DecodeError::Unsupported(u)) if u.version() == Some((VERSION_MAJOR_SHARED + 1, 0))));
    let e = decode(&bytes[..bytes.len() - 1]).unwrap_err();
    assert_eq!(e.format_error().map(|f| f.kind()), Some(FormatErrorKind::Truncated));
    // Hostile Gaussian count: refused before anything is allocated.
    let mut hostile = bytes.clone();
    hostile[8..12].copy_from_slice(&u32::MAX.to_le_bytes());
    assert_eq!(decode(&hostile).unwrap_err().class(), "limits");
}

#[test]
fn context_coded_channels_round_trip_across_chunk_boundaries() {
    // 70,000 Gaussians (two chunks) whose SH coefficients are zero in some regions and large in
    // others: a Gaussian's value predicts its Morton neighbour's, so context tables pay.
    let mut s = scene(70_000, 1, 1.0, 11);
    let k3 = s.rest_coeffs() * 3;
    for i in 0..s.len() {
        let p = s.positions[i];
        let active = (p[0] * 3.0).sin() * (p[1] * 2.0).cos() > 0.3;
        for c in 0..k3 {
            s.sh_rest[i * k3 + c] = if active { 0.3 * (p[2] * 5.0 + c as f32).sin() } else { 0.0 };
        }
    }
    // Mode 2 (format 3.0); neighbour contexts have their own test.
    let config = EncodeConfig { learned_tables: false, neighbour_tables: false, ..EncodeConfig::default() };
    let (bytes, report, q) = rate::encode(&s, &config).unwrap();
    let band1 = report.groups.iter().find(|g| g.group == "sh_band1").unwrap();
    assert!(band1.context_channels > 0, "contexts not chosen: {band1:?}");
    assert!(band1.context_bits < band1.histogram_bits);
    let expected = quantise::dequantise(&q);
    for threads in [1, 3] {
        assert_eq!(decode_threads(&bytes, threads).unwrap(), expected, "{threads} threads");
    }
    let est = report.estimated_bits() / 8.0;
    assert!((est - bytes.len() as f64).abs() / (bytes.len() as f64) < 0.01, "estimated {est} actual {}", bytes.len());
}

/// Neighbour-context tables (mode 3, format 8.0): a scene whose attributes vary smoothly in space
/// (each Gaussian's values predict its Morton neighbour's) takes them on most channels, SH bands
/// included, and decodes bit-exactly: whole and to a lower SH degree, on 1 and 3 threads,
/// across a chunk boundary (70,000 Gaussians), while the decoder splits the 21 channels of band
/// 3 into jobs (a job whose first channel reads the channel below decodes that one too). The
/// rate estimate stays exact, and the same scene without them is larger.
#[test]
fn neighbour_tables_round_trip_bit_exactly() {
    let mut s = scene(70_000, 3, 1.0, 17);
    let k3 = s.rest_coeffs() * 3;
    for i in 0..s.len() {
        let p = s.positions[i];
        let f = |a: f32, b: f32| (p[0] * a + b).sin() * (p[1] * (a + 1.0)).cos() + 0.3 * (p[2] * 2.0 * a).sin();
        s.log_scales[i] = [-5.0 + f(3.0, 0.0), -5.5 + f(2.0, 1.0), -6.0 + f(4.0, 2.0)];
        s.sh_dc[i] = [f(2.5, 0.3), f(3.5, 0.7), f(1.5, 0.9)];
        for c in 0..k3 {
            s.sh_rest[i * k3 + c] = 0.2 * f(2.0 + (c / 3) as f32 * 0.3, c as f32);
        }
    }
    let config = EncodeConfig { learned_tables: false, ..EncodeConfig::default() };
    let (bytes, report, q) = rate::encode(&s, &config).unwrap();
    assert_eq!(bytes[4], VERSION_MAJOR_NEIGHBOURS, "neighbour tables make an 8.0 file");
    for g in ["scale", "sh_dc", "sh_band3"] {
        let r = report.groups.iter().find(|r| r.group == g).unwrap();
        assert!(r.neighbour_channels > 0, "{g}: {r:?}");
    }
    let info = gscodec_decoder::inspect(&bytes).unwrap();
    assert!(info.neighbour_channels.iter().any(|c| c.starts_with("sh_band3/")), "{:?}", info.neighbour_channels);
    let expected = quantise::dequantise(&q);
    for threads in [1, 3] {
        assert_eq!(decode_threads(&bytes, threads).unwrap(), expected, "{threads} threads");
    }
    let one = decode_with(&bytes, &Limits { max_sh_degree: 1, ..Limits::default() }).unwrap();
    assert_eq!(one, expected.with_sh_degree(1));
    let est = report.estimated_bits() / 8.0;
    assert!((est - bytes.len() as f64).abs() / (bytes.len() as f64) < 0.01, "estimated {est} actual {}", bytes.len());
    let (without, _, q0) = rate::encode(&s, &EncodeConfig { neighbour_tables: false, ..config }).unwrap();
    assert_eq!(decode(&without).unwrap(), quantise::dequantise(&q0));
    assert!(bytes.len() < without.len() * 9 / 10, "{} against {} without", bytes.len(), without.len());
}

/// Decodes with `threads` worker threads (0: the global pool) through the reader door.
fn decode_threads(bytes: &[u8], threads: usize) -> Result<Splats, gscodec_decoder::DecodeError> {
    let mut d = gscodec_decoder::Decoder::new(bytes);
    d.set_threads(threads);
    d.read_info()?.decode()
}

/// Every Gaussian of `s` as the bit patterns of its values, sorted: the scene as a multiset.
fn gaussian_multiset(s: &Splats) -> Vec<Vec<u32>> {
    let mut rows: Vec<Vec<u32>> = (0..s.len())
        .map(|i| {
            let mut r: Vec<f32> =
                [&s.positions[i][..], &s.log_scales[i], &s.rotations[i], &[s.opacity_logits[i]], &s.sh_dc[i], s.rest_of(i)].concat();
            r.iter_mut().for_each(|v| *v += 0.0); // −0.0 and +0.0 alike: order changes no value
            r.iter().map(|v| v.to_bits()).collect()
        })
        .collect();
    rows.sort();
    rows
}

#[test]
fn progressive_file_is_the_same_scene_most_significant_first() {
    let s = scene(3000, 2, 1.0, 5);
    // Without neighbour tables (format 8.0) one level is a 3.0 file; a progressive file never
    // has them (its levels share one set of parameter sections).
    let (plain, _, _) = rate::encode(&s, &EncodeConfig { neighbour_tables: false, ..EncodeConfig::default() }).unwrap();
    let (levels, _, q) = rate::encode(&s, &EncodeConfig { progressive: true, ..EncodeConfig::default() }).unwrap();
    assert_eq!((plain[4], levels[4]), (3, 4), "one level is a 3.0 file, levels a 4.0 one");
    let (a, b) = (decode(&plain).unwrap(), decode(&levels).unwrap());
    assert_eq!(b, quantise::dequantise(&q), "decode of the progressive file is the encoder's scene");
    assert_eq!(gaussian_multiset(&a), gaussian_multiset(&b), "the same Gaussians in another order");
    let info = gscodec_decoder::inspect(&levels).unwrap();
    // Level ends at ⌈N/16⌉, ⌈N/8⌉, ⌈N/4⌉, ⌈N/2⌉, N (N after pruning).
    let ends: Vec<usize> = [16, 8, 4, 2, 1].iter().map(|&d| b.len().div_ceil(d)).collect();
    let sizes: Vec<usize> = ends.iter().scan(0, |prev, &e| Some(e - std::mem::replace(prev, e))).collect();
    assert_eq!(info.levels, sizes);
    assert_eq!(info.levels, q.levels);
    // Importance falls from level to level (measured on the decoded scene, as the encoder did on
    // its input: means, since quantisation moves values near the cuts).
    let sig = gscodec::rate::importance::significance(&b);
    let mut start = 0;
    let means: Vec<f64> = info
        .levels
        .iter()
        .map(|&k| {
            start += k;
            sig[start - k..start].iter().map(|&v| v as f64).sum::<f64>() / k as f64
        })
        .collect();
    assert!(means.windows(2).all(|w| w[0] > w[1]), "mean significance per level {means:?}");
}

/// Every prefix of the progressive file `pb` (every 997 bytes) decodes to a growing prefix of
/// `full`, its decode: the same Gaussians, and the same SH where the prefix has every band; the
/// whole file decodes to `full`.
fn prefixes_decode_to_prefixes(pb: &[u8], full: &Splats) {
    let mut last = 0;
    for arrived in (0..=pb.len()).step_by(997).chain([pb.len()]) {
        if let Some(p) = gscodec_decoder::decode_prefix(&pb[..arrived], &Limits::default()).unwrap() {
            assert!(p.len() >= last);
            last = p.len();
            assert_eq!(p.positions[..], full.positions[..p.len()]);
            assert_eq!(p.log_scales[..], full.log_scales[..p.len()]);
            if p.sh_degree == full.sh_degree {
                assert_eq!(p.sh_rest[..], full.sh_rest[..p.sh_rest.len()]);
            }
        }
    }
    assert_eq!(gscodec_decoder::decode_prefix(pb, &Limits::default()).unwrap().unwrap(), *full);
}

/// SH bands coded by vector quantisation (format 5.0, SPEC §3.2): decode is the encoder's scene
/// bit-exactly — every band row one of its codebook's — whole, progressive, by prefix, and with
/// fewer SH bands; a file without codebooks stays 3.0.
#[test]
fn codebook_bands_round_trip_bit_exactly() {
    let s = scene(3000, 3, 1.0, 21);
    let config = EncodeConfig { sh_vq: [16, 0, 300], neighbour_tables: false, ..EncodeConfig::default() };
    let (bytes, report, q) = rate::encode(&s, &config).unwrap();
    assert_eq!(bytes[4], 5, "codebooks make a 5.0 file");
    let decoded = decode(&bytes).unwrap();
    assert_eq!(decoded, quantise::dequantise(&q));
    let rows = |g: &str| report.groups.iter().find(|r| r.group == g).unwrap().codebook_rows;
    assert_eq!((rows("sh_band1"), rows("sh_band2"), rows("sh_band3")), (16, 0, 300));
    let info = gscodec_decoder::inspect(&bytes).unwrap();
    assert_eq!(info.codebooks, vec![(1, 16), (3, 300)]);
    // Band 1 of every Gaussian is one of 16 rows.
    let k = decoded.rest_coeffs();
    let mut band1: Vec<Vec<u32>> =
        (0..decoded.len()).map(|i| decoded.sh_rest[i * k * 3..][..9].iter().map(|v| v.to_bits()).collect()).collect();
    band1.sort();
    band1.dedup();
    assert!(band1.len() <= 16, "{} distinct band-1 rows", band1.len());
    // Fewer SH bands: the same scene truncated.
    let two = decode_with(&bytes, &Limits { max_sh_degree: 2, ..Limits::default() }).unwrap();
    assert_eq!(two, decoded.with_sh_degree(2));
    // Progressive with codebooks: 5.0 with levels; every prefix decodes to a prefix of the scene.
    let (pb, _, pq) = rate::encode(&s, &EncodeConfig { progressive: true, ..config }).unwrap();
    assert_eq!(pb[4], 5);
    let full = decode(&pb).unwrap();
    assert_eq!(full, quantise::dequantise(&pq));
    prefixes_decode_to_prefixes(&pb, &full);
    // No codebook: 3.0, as before.
    assert_eq!(rate::encode(&s, &EncodeConfig { neighbour_tables: false, ..EncodeConfig::default() }).unwrap().0[4], 3);
}

/// Importance classes (format 6.0, SPEC §4): the less significant Gaussians in a level of their
/// own with coarser steps. Decode is the encoder's scene bit-exactly — whole, with fewer SH
/// bands, progressive and by prefix — the tail level's steps are the factor times the others'
/// (not the rotation index's, nor a codebook band's) and its position grid coarser, its
/// Gaussians are the less significant ones, and the file is smaller than without the tail.
#[test]
fn importance_classes_round_trip_bit_exactly() {
    use gscodec::rate::CoarseTail;
    use gscodec_decoder::bitstream::{layout::Group, params::read_all_params, parse};
    let s = scene(3000, 3, 1.0, 31);
    let config = EncodeConfig { sh_vq: [16, 0, 0], tail: CoarseTail::new(0.5, 2.0), neighbour_tables: false, ..EncodeConfig::default() };
    let (bytes, _, q) = rate::encode(&s, &config).unwrap();
    assert_eq!(bytes[4], 6, "parameters per level make a 6.0 file");
    let decoded = decode(&bytes).unwrap();
    assert_eq!(decoded, quantise::dequantise(&q));
    let n = decoded.len();
    assert_eq!(q.levels, vec![n - n / 2, n / 2]);
    // Level 1's steps: twice level 0's, but the rotation index and the codebook band 1.
    let c = parse(&bytes).unwrap();
    let params = read_all_params(&c, 3, 2).unwrap();
    for ((g, p0), (_, p1)) in params.of_level(0).iter().zip(params.of_level(1)) {
        for (j, (s0, s1)) in p0.steps.iter().zip(&p1.steps).enumerate() {
            let same = (*g == Group::Rotation && j == 0) || *g == Group::Sh1 || *g == Group::Position;
            assert_eq!(*s1, if same { *s0 } else { 2.0 * s0 }, "{} channel {j}", g.name());
        }
    }
    // Its position grid has one bit per axis fewer (⌊log₂ 2⌋), over the same bounds.
    let (grid0, grid1) = (params.of_level(0)[0].1.grid.unwrap(), params.of_level(1)[0].1.grid.unwrap());
    assert_eq!((grid1.0, grid1.2), (grid0.0, grid0.2 - 1));
    assert!((0..3).all(|a| grid1.1[a] > 1.9 * grid0.1[a]), "{grid0:?} {grid1:?}");
    let (g1, p1) = &params.of_level(1)[5];
    assert!(*g1 == Group::Sh1 && p1.codebook.is_some(), "the codebook is shared by both levels");
    // The tail is the less significant half.
    let sig = gscodec::rate::importance::significance(&decoded);
    let mean = |r: std::ops::Range<usize>| sig[r.clone()].iter().map(|&v| v as f64).sum::<f64>() / r.len() as f64;
    assert!(mean(0..n - n / 2) > 2.0 * mean(n - n / 2..n), "{} vs {}", mean(0..n - n / 2), mean(n - n / 2..n));
    let (plain, _, _) = rate::encode(&s, &EncodeConfig { tail: CoarseTail::OFF, ..config }).unwrap();
    assert!(bytes.len() < plain.len(), "{} bytes with the tail, {} without", bytes.len(), plain.len());
    assert_eq!(plain[4], 5);
    // Each group's own multiplier of the factor (CoarseTail::groups): rotation ×2 and DC ×½ in
    // the tail, its position grid following 2 × 2 (two bits fewer); still the encoder's scene.
    let mut tail = CoarseTail::new(0.5, 2.0);
    for (g, m) in [(Group::Position, 2.0), (Group::Rotation, 2.0), (Group::ShDc, 0.5)] {
        tail.groups[g as usize] = m;
    }
    let (own, _, own_q) = rate::encode(&s, &EncodeConfig { tail, ..config }).unwrap();
    assert_eq!(decode(&own).unwrap(), quantise::dequantise(&own_q));
    let own_params = read_all_params(&parse(&own).unwrap(), 3, 2).unwrap();
    for ((g, p0), (_, p1)) in own_params.of_level(0).iter().zip(own_params.of_level(1)) {
        let m = match g {
            Group::Position | Group::Sh1 => 1.0,
            Group::Rotation => 4.0,
            Group::ShDc => 1.0,
            _ => 2.0,
        };
        for (j, (s0, s1)) in p0.steps.iter().zip(&p1.steps).enumerate() {
            let m = if *g == Group::Rotation && j == 0 { 1.0 } else { m };
            assert_eq!(*s1, m * s0, "{} channel {j}", g.name());
        }
    }
    let (own0, own1) = (own_params.of_level(0)[0].1.grid.unwrap(), own_params.of_level(1)[0].1.grid.unwrap());
    assert_eq!(own1.2, own0.2 - 2);
    // Fewer SH bands: the same scene truncated.
    let two = decode_with(&bytes, &Limits { max_sh_degree: 2, ..Limits::default() }).unwrap();
    assert_eq!(two, decoded.with_sh_degree(2));
    // Progressive: the levels wholly in the tail (the last two, 1/4 + 1/2) take the factor; every
    // prefix decodes to a prefix of the scene.
    let progressive = EncodeConfig { progressive: true, tail: CoarseTail::new(0.75, 2.0), ..config };
    let (pb, _, pq) = rate::encode(&s, &progressive).unwrap();
    assert_eq!((pb[4], pq.level_factors.clone()), (6, vec![1.0, 1.0, 1.0, 2.0, 2.0]));
    let full = decode(&pb).unwrap();
    assert_eq!(full, quantise::dequantise(&pq));
    prefixes_decode_to_prefixes(&pb, &full);
    // Random mutations are refused (or decode), never panic.
    let mut rng = Rng::new(9);
    for _ in 0..1000 {
        let mut b = bytes.clone();
        for _ in 0..1 + rng.below(3) {
            let i = rng.below(b.len());
            b[i] ^= 1 << rng.below(8);
        }
        let _ = decode(&b);
    }
}

/// Random mutations of a 5.0 file with codebooks are refused (or decode), never panic.
#[test]
fn mutated_codebook_files_never_panic() {
    let s = scene(400, 3, 1.0, 23);
    let (bytes, _, _) = rate::encode(&s, &EncodeConfig { sh_vq: [8, 32, 64], ..EncodeConfig::default() }).unwrap();
    let mut rng = Rng::new(7);
    for _ in 0..2000 {
        let mut b = bytes.clone();
        for _ in 0..1 + rng.below(3) {
            let i = rng.below(b.len());
            b[i] ^= 1 << rng.below(8);
        }
        let _ = decode_threads(&b, 1);
    }
}

/// One joint codebook for every SH band (`sh_joint`, SPEC §3.2, format 9.0): bands 2 and 3 share
/// band 1's row index and hold no stream; the file decodes to the quantised scene bit-exactly,
/// in levels and importance classes too, and at a lower SH degree to the truncated scene.
#[test]
fn a_shared_sh_index_round_trips_bit_exactly() {
    use gscodec::rate::CoarseTail;
    use gscodec_decoder::bitstream::{layout::Group, params::read_all_params, parse};
    let s = scene(3000, 3, 1.0, 33);
    let config = EncodeConfig { sh_vq: [64, 0, 0], sh_joint: true, ..EncodeConfig::default() };
    let (bytes, _, q) = rate::encode(&s, &config).unwrap();
    assert_eq!(bytes[4], VERSION_MAJOR_SHARED);
    assert!(q.shared_index);
    let k = q.codebooks[0].1.len();
    assert!(k > 1 && k <= 64, "{k} rows");
    assert!(q.codebooks.iter().all(|(_, cb)| cb.len() == k && cb.index == q.codebooks[0].1.index), "one index, K rows per band");
    let decoded = decode(&bytes).unwrap();
    assert_eq!(decoded, quantise::dequantise(&q));
    // At most K distinct SH rows (all bands together).
    let mut rows: Vec<Vec<u32>> = decoded.sh_rest.chunks_exact(45).map(|r| r.iter().map(|v| v.to_bits()).collect()).collect();
    rows.sort();
    rows.dedup();
    assert!(rows.len() <= k, "{} distinct rows", rows.len());
    let c = parse(&bytes).unwrap();
    let params = read_all_params(&c, 3, 1).unwrap();
    for (g, p) in params.of_level(0) {
        assert_eq!(p.shares_index(), matches!(g, Group::Sh2 | Group::Sh3), "{}", g.name());
    }
    assert_eq!(decode_with(&bytes, &Limits { max_sh_degree: 1, ..Limits::default() }).unwrap(), decoded.with_sh_degree(1));
    assert_eq!(decode_with(&bytes, &Limits { max_sh_degree: 2, ..Limits::default() }).unwrap(), decoded.with_sh_degree(2));
    // The same codebook rows coded per band cost more: the joint index is one channel, not three.
    let (separate, _, _) = rate::encode(&s, &EncodeConfig { sh_vq: [64, 64, 64], sh_joint: false, ..config }).unwrap();
    assert!(bytes.len() < separate.len(), "{} bytes joint, {} separate", bytes.len(), separate.len());
    // Importance classes and progressive levels: parameter sections per level.
    for c in
        [EncodeConfig { tail: CoarseTail::new(0.5, 2.0), ..config }, EncodeConfig { progressive: true, neighbour_tables: false, ..config }]
    {
        let (b, _, q) = rate::encode(&s, &c).unwrap();
        assert_eq!(b[4], VERSION_MAJOR_SHARED);
        let full = decode(&b).unwrap();
        assert_eq!(full, quantise::dequantise(&q));
        if c.progressive {
            prefixes_decode_to_prefixes(&b, &full);
        }
    }
    // A scene of SH degree 1 has no band to share with: band 1 alone, a file of before 9.0.
    let (one, _, q1) = rate::encode(&s.with_sh_degree(1), &config).unwrap();
    assert!(!q1.shared_index && one[4] < VERSION_MAJOR_SHARED);
    assert_eq!(decode(&one).unwrap(), quantise::dequantise(&q1));
}

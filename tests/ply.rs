//! `.ply` round trips and format variants.

use gscodec::decoder::Splats;
use gscodec::io::ply::{read_ply, read_ply_bytes, write_ply};
use gscodec::rng::Rng;
use std::path::Path;

/// A small seeded scene of the given SH degree with values of every magnitude.
fn scene(degree: u8, n: usize) -> Splats {
    let mut s = Splats::new(degree);
    let mut rng = Rng::new(0x9e37_79b9);
    let mut rnd = move || (rng.uniform() - 0.5) * 10f32.powi(rng.below(7) as i32 - 3);
    let k3 = s.rest_coeffs() * 3;
    for _ in 0..n {
        let rest: Vec<f32> = (0..k3).map(|_| rnd()).collect();
        s.push([rnd(), rnd(), rnd()], [rnd(), rnd(), rnd()], [rnd() + 1.0, rnd(), rnd(), rnd()], rnd(), [rnd(), rnd(), rnd()], &rest);
    }
    s
}

/// Property names and values per Gaussian in the INRIA order (with normals and an extra property).
fn named_values(s: &Splats) -> (Vec<String>, Vec<Vec<f32>>) {
    let k = s.rest_coeffs();
    let mut names: Vec<String> = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"].map(String::from).to_vec();
    names.extend((0..3 * k).map(|i| format!("f_rest_{i}")));
    names.extend(["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3", "extra"].map(String::from));
    let rows = (0..s.len())
        .map(|i| {
            let mut v = s.positions[i].to_vec();
            v.extend([0.0; 3]);
            v.extend(s.sh_dc[i]);
            let rest = s.rest_of(i);
            for c in 0..3 {
                for kk in 0..k {
                    v.push(rest[kk * 3 + c]);
                }
            }
            v.push(s.opacity_logits[i]);
            v.extend(s.log_scales[i]);
            v.extend(s.rotations[i]);
            v.push(42.0);
            v
        })
        .collect();
    (names, rows)
}

/// Writes the scene with properties in reversed order, in ascii or big-endian binary.
fn variant(s: &Splats, ascii: bool) -> Vec<u8> {
    let (mut names, mut rows) = named_values(s);
    names.reverse();
    rows.iter_mut().for_each(|r| r.reverse());
    let fmt = if ascii { "ascii" } else { "binary_big_endian" };
    let mut out = format!("ply\nformat {fmt} 1.0\ncomment variant\nelement vertex {}\n", s.len());
    for n in &names {
        out.push_str(&format!("property float {n}\n"));
    }
    out.push_str("element face 0\nproperty list uchar int vertex_indices\nend_header\n");
    let mut out = out.into_bytes();
    for r in &rows {
        if ascii {
            // `{:?}` prints the shortest string that parses back to the same f32.
            let line: Vec<String> = r.iter().map(|v| format!("{v:?}")).collect();
            out.extend(line.join(" ").bytes());
            out.push(b'\n');
        } else {
            r.iter().for_each(|v| out.extend(v.to_be_bytes()));
        }
    }
    out
}

fn bits(s: &Splats) -> Vec<u32> {
    let mut v = vec![s.sh_degree as u32, s.len() as u32];
    v.extend(s.positions.iter().flatten().map(|x| x.to_bits()));
    v.extend(s.log_scales.iter().flatten().map(|x| x.to_bits()));
    v.extend(s.rotations.iter().flatten().map(|x| x.to_bits()));
    v.extend(s.opacity_logits.iter().map(|x| x.to_bits()));
    v.extend(s.sh_dc.iter().flatten().map(|x| x.to_bits()));
    v.extend(s.sh_rest.iter().map(|x| x.to_bits()));
    v
}

#[test]
fn write_read_is_bit_exact_for_every_degree() {
    let dir = tempfile::tempdir().unwrap();
    for degree in 0..=3 {
        let s = scene(degree, 257);
        let path = dir.path().join(format!("d{degree}.ply"));
        write_ply(&path, &s).unwrap();
        let back = read_ply(&path).unwrap();
        assert!(bits(&back) == bits(&s), "degree {degree}");
        // Re-writing gives the same bytes.
        assert_eq!(back.to_ply(), std::fs::read(&path).unwrap());
    }
}

#[test]
fn ascii_and_big_endian_equal_binary() {
    for degree in [0, 1, 3] {
        let s = scene(degree, 50);
        let bin = read_ply_bytes(&s.to_ply(), Path::new("bin.ply")).unwrap();
        let ascii = read_ply_bytes(&variant(&s, true), Path::new("ascii.ply")).unwrap();
        let be = read_ply_bytes(&variant(&s, false), Path::new("be.ply")).unwrap();
        assert!(bits(&bin) == bits(&s));
        assert!(bits(&ascii) == bits(&s), "ascii degree {degree}");
        assert!(bits(&be) == bits(&s), "big endian degree {degree}");
    }
}

#[test]
fn channel_major_f_rest_maps_to_coefficient_major() {
    // One degree-1 Gaussian with f_rest_i = i: coefficient k of channel c is f_rest_{c*3+k}.
    let mut s = Splats::new(1);
    s.push([0.0; 3], [0.0; 3], [1.0, 0.0, 0.0, 0.0], 0.0, [0.0; 3], &[0.0; 9]);
    let mut bytes = s.to_ply();
    let body = bytes.len() - 4 * (9 + 9 + 8);
    for i in 0..9 {
        let at = body + 4 * (9 + i);
        bytes[at..at + 4].copy_from_slice(&(i as f32).to_le_bytes());
    }
    let r = read_ply_bytes(&bytes, Path::new("m.ply")).unwrap();
    for k in 0..3 {
        for c in 0..3 {
            assert_eq!(r.sh_rest[k * 3 + c], (c * 3 + k) as f32);
        }
    }
}

#[test]
fn integer_and_double_properties_are_converted() {
    let mut text = String::from("ply\nformat binary_little_endian 1.0\nelement vertex 1\n");
    for (ty, name) in [
        ("double", "x"),
        ("int", "y"),
        ("uchar", "z"),
        ("short", "f_dc_0"),
        ("float", "f_dc_1"),
        ("char", "f_dc_2"),
        ("ushort", "opacity"),
        ("uint", "scale_0"),
        ("float", "scale_1"),
        ("float", "scale_2"),
        ("double", "rot_0"),
        ("float", "rot_1"),
        ("float", "rot_2"),
        ("float", "rot_3"),
    ] {
        text.push_str(&format!("property {ty} {name}\n"));
    }
    text.push_str("end_header\n");
    let mut b = text.into_bytes();
    b.extend(1.5f64.to_le_bytes());
    b.extend((-7i32).to_le_bytes());
    b.push(200u8);
    b.extend((-3i16).to_le_bytes());
    b.extend(0.25f32.to_le_bytes());
    b.push((-1i8) as u8);
    b.extend(9u16.to_le_bytes());
    b.extend(11u32.to_le_bytes());
    b.extend(0f32.to_le_bytes());
    b.extend(0f32.to_le_bytes());
    b.extend(1f64.to_le_bytes());
    b.extend([0u8; 12]);
    let s = read_ply_bytes(&b, Path::new("t.ply")).unwrap();
    assert_eq!(s.positions[0], [1.5, -7.0, 200.0]);
    assert_eq!(s.sh_dc[0], [-3.0, 0.25, -1.0]);
    assert_eq!(s.opacity_logits[0], 9.0);
    assert_eq!(s.log_scales[0], [11.0, 0.0, 0.0]);
    assert_eq!(s.rotations[0], [1.0, 0.0, 0.0, 0.0]);
}

#[test]
fn bad_files_are_input_errors() {
    let good = scene(1, 4).to_ply();
    let header_len = good.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
    let set_f32 = |b: &mut Vec<u8>, at: usize, v: f32| b[at..at + 4].copy_from_slice(&v.to_le_bytes());
    let stride = (good.len() - header_len) / 4;
    let mut cases: Vec<(&str, Vec<u8>)> = Vec::new();
    let mut nan = good.clone();
    set_f32(&mut nan, header_len + stride + 4, f32::NAN);
    cases.push(("not finite", nan));
    let mut inf = good.clone();
    set_f32(&mut inf, header_len + 4 * 9, f32::INFINITY);
    cases.push(("not finite", inf));
    let mut zq = good.clone();
    for j in 0..4 {
        set_f32(&mut zq, header_len + 2 * stride + stride - 16 + 4 * j, 0.0);
    }
    cases.push(("zero norm", zq));
    cases.push(("truncated", good[..good.len() - 3].to_vec()));
    // The good file with one header edit.
    let edited =
        |from: &str, to: &str| [String::from_utf8_lossy(&good[..header_len]).replace(from, to).as_bytes(), &good[header_len..]].concat();
    cases.push(("truncated", edited("vertex 4", "vertex 5")));
    cases.push(("extra bytes", edited("vertex 4", "vertex 3")));
    cases.push(("truncated", edited("vertex 4", "vertex 18446744073709551615")));
    cases.push(("`opacity` is missing", edited("property float opacity\n", "")));
    cases.push(("8 `f_rest_*`", edited("property float f_rest_8\n", "")));
    cases.push(("unknown property type", edited("property float x\n", "property quux x\n")));
    cases.push(("magic", b"PK\x03\x04garbage".to_vec()));
    cases.push(("end_header", b"ply\nformat ascii 1.0\nelement vertex 1\n".to_vec()));
    for (want, bytes) in cases {
        let err = read_ply_bytes(&bytes, Path::new("bad.ply")).unwrap_err();
        assert_eq!(err.exit_code(), 2);
        let msg = err.to_string();
        assert!(msg.starts_with("bad.ply: ") && msg.contains(want), "expected `{want}` in `{msg}`");
    }
}

#[test]
fn shared_scenes_load() {
    let Some(dir) = gscodec::testkit::shared_data("scenes") else { return };
    for (name, n) in [("k7000.ply", 9080), ("fruit-drops.ply", 4721), ("playbot-lod3.ply", 31000)] {
        let s = read_ply(&dir.join(name)).unwrap();
        assert_eq!((s.len(), s.sh_degree), (n, 3), "{name}");
    }
}

//! Conformance vectors (`bitstream-spec/vectors/`): each `NAME.gsc` decodes to exactly
//! `NAME.ply`, whose SHA-256 is listed in `SHA256SUMS` (for `chunks`, whose 4.8 MB output is not
//! stored, the hash alone). Regenerate (after a deliberate format change only) with
//! `cargo test --test vectors -- --ignored regenerate`, then `python3
//! bitstream-spec/make_bad_vectors.py`, which makes `quirks` and the bad vectors (SPEC §9.2, §9.3)
//! from `hand` and adds their lines to `SHA256SUMS`.

use std::path::{Path, PathBuf};

use gscodec::anchor::AnchorConfig;
use gscodec::rate::{self, CoarseTail, EncodeConfig};
use gscodec::rng::Rng;
use gscodec_decoder::bitstream::{self, Header, VERSION_MAJOR_UNIFORM, VERSION_MINOR};
use gscodec_decoder::{decode, Decoder, Limits, Splats};
use sha2::{Digest, Sha256};

const NAMES: [&str; 15] = [
    "empty",
    "empty3",
    "one",
    "hand",
    "edge",
    "tiny",
    "chunks",
    "quirks",
    "levels",
    "vq",
    "classes",
    "anchor",
    "neighbour",
    "nbedge",
    "shared",
];
/// Vectors made by `bitstream-spec/make_bad_vectors.py`, not by our encoder.
const SCRIPTED: [&str; 1] = ["quirks"];
/// Vectors whose expected `.ply` is given by its SHA-256 only.
const HASH_ONLY: [&str; 1] = ["chunks"];

fn dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("bitstream-spec/vectors")
}

/// The SHA-256 that `SHA256SUMS` lists for `NAME.ply`.
fn expected_hash<'a>(sums: &'a str, name: &str) -> &'a str {
    let line = sums.lines().find(|l| l.ends_with(&format!("  {name}.ply"))).unwrap_or_else(|| panic!("{name} not in SHA256SUMS"));
    &line[..64]
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// Three hand-written Gaussians, SH degree 1.
fn hand_scene() -> Splats {
    let mut s = Splats::new(1);
    s.push(
        [0.0, 0.0, 0.0],
        [-2.0, -2.0, -2.0],
        [1.0, 0.0, 0.0, 0.0],
        2.0,
        [0.5, 0.0, -0.5],
        &[0.1, 0.0, 0.0, 0.0, 0.1, 0.0, 0.0, 0.0, 0.1],
    );
    s.push([1.0, 0.5, -0.25], [-1.0, -3.0, -2.5], [0.7, 0.7, 0.1, 0.0], -1.0, [0.0, 1.0, 0.0], &[0.0; 9]);
    s.push(
        [-1.0, 2.0, 0.75],
        [-4.0, -4.0, -4.0],
        [0.0, 0.0, 0.0, -1.0],
        5.0,
        [-1.0, 0.25, 0.3],
        &[-0.2, 0.05, 0.0, 0.0, 0.0, 0.3, 0.1, 0.1, 0.1],
    );
    s
}

fn random_rotation(rng: &mut Rng) -> [f32; 4] {
    let q = [rng.normal(), rng.normal(), rng.normal(), rng.normal()];
    let l = q.iter().map(|v| v * v).sum::<f32>().sqrt().max(1e-6);
    q.map(|v| v / l)
}

/// One Gaussian of SH degree 3: every channel (and the position length) is a constant table,
/// so the only data sections are the position ones.
fn one_scene() -> Splats {
    let mut s = Splats::new(3);
    let rest: Vec<f32> = (0..45).map(|i| 0.02 * (i as f32 - 22.0)).collect();
    s.push([0.25, -0.5, 2.0], [-2.5, -3.0, -1.5], [0.9, 0.1, -0.3, 0.2], 0.7, [0.4, -0.2, 0.9], &rest);
    s
}

/// 3000 Gaussians of SH degree 2 that reach the rarer paths of SPEC §5–6: escaped values (both
/// signs, in coded and context-coded channels), constant scale and opacity channels (their data
/// sections absent), context-coded SH channels.
fn edge_scene() -> Splats {
    let mut rng = Rng::new(7);
    let mut s = Splats::new(2);
    for i in 0..3000 {
        let p = [rng.range(-1.0, 1.0), rng.range(-1.0, 1.0), rng.range(-1.0, 1.0)];
        let smooth = (3.0 * p[0]).sin() + (2.0 * p[1]).cos();
        let mut dc = [smooth, 0.5 * smooth + 0.1 * p[2], rng.range(-0.3, 0.3)];
        let mut rest = [0.0f32; 24];
        for r in rest.iter_mut().take(9) {
            *r = 0.1 * rng.normal();
        }
        // Band 1 is zero on half the scene: in Morton order a zero follows a zero, which the
        // context tables (mode 2) exploit.
        if p[0] < 0.0 {
            rest[..9].fill(0.0);
        }
        match i {
            17 => dc[0] = 300.0,
            1234 => dc[1] = -250.0,
            2000 => rest[4] = 1e4,
            2500 => rest[0] = -5e3,
            _ => {}
        }
        s.push(p, [-3.0; 3], random_rotation(&mut rng), 1.5, dc, &rest);
    }
    s
}

/// 70,000 Gaussians of SH degree 0: two chunks (65,536 + 4,464), so the per-chunk restart of
/// the Morton code and of the contexts is exercised.
fn chunks_scene() -> Splats {
    let mut rng = Rng::new(11);
    let mut s = Splats::new(0);
    let colours = [[0.8, 0.1, -0.4], [-0.5, 0.6, 0.2], [0.0, 0.0, 1.0], [1.2, -1.0, 0.3]];
    // Mostly the first choice, so that the file stays small.
    let mut pick = |n: usize| if rng.below(16) == 0 { rng.below(n) } else { 0 };
    for i in 0..70_000 {
        let p = [(i % 42) as f32 * 0.1, ((i / 42) % 42) as f32 * 0.1, (i / (42 * 42)) as f32 * 0.1];
        let scale = [-3.0, -3.5, -4.0][pick(3)];
        let rotation = [[1.0, 0.0, 0.0, 0.0], [0.6, 0.8, 0.0, 0.0], [0.5, -0.5, 0.5, 0.5]][pick(3)];
        s.push(p, [scale, scale + 0.5, scale], rotation, [0.5, 2.0][pick(2)], colours[pick(4)], &[]);
    }
    s
}

fn vector_scene(name: &str) -> Splats {
    match name {
        "empty" => Splats::new(0),
        "one" => one_scene(),
        "hand" => hand_scene(),
        "edge" | "nbedge" => edge_scene(),
        "tiny" | "levels" | "vq" | "classes" | "anchor" | "neighbour" | "shared" => {
            gscodec::io::read_ply(&Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/tiny/truth.ply")).unwrap()
        }
        "chunks" => chunks_scene(),
        _ => unreachable!("{name}"),
    }
}

#[test]
#[ignore]
fn regenerate() {
    let mut sums = String::new();
    for name in NAMES.into_iter().filter(|n| !SCRIPTED.contains(n)) {
        let bytes = if name == "empty3" {
            // No Gaussians but SH degree 3 (our encoder writes D = 0 for an empty scene): the
            // output still lists the 45 rest properties.
            let h = Header { version_major: VERSION_MAJOR_UNIFORM, version_minor: VERSION_MINOR, gaussians: 0, sh_degree: 3 };
            bitstream::write(&h, &[])
        } else if name == "anchor" {
            // The tiny scene in the anchor profile (format 7.0, SPEC §12): distilled only (no
            // fine-tuning), SH degree 1, 8 features, 16 hidden units.
            let scene = vector_scene(name);
            let sig = gscodec::rate::importance::significance(&scene);
            let cfg = AnchorConfig { features: 8, hidden: 16, distill_iters: 200, iters: 0, ..AnchorConfig::default() };
            gscodec::anchor::encode(&scene, &sig, &cfg, (scene.len(), scene.sh_degree), None).bytes
        } else {
            // `levels`: the tiny scene in importance levels (format 4.0, SPEC §3.1). `vq`: the tiny
            // scene to SH degree 2, band 1 by a codebook of 16 rows, band 2 per coefficient
            // (format 5.0, SPEC §3.2). `classes`: `vq` with its less significant half in a level
            // of its own, coded with twice the steps and a grid of one bit less (format 6.0:
            // parameters per level, SPEC §4). `neighbour`: `classes` with neighbour-context tables
            // (format 8.0, SPEC §4.3), codebook rows included; `nbedge`: `edge` with them, escapes
            // included. `shared`: the tiny scene with one codebook of 32 rows for its three SH
            // bands, bands 2 and 3 sharing band 1's index, and its less significant half in a
            // level of its own (format 9.0, SPEC §3.2), without neighbour-context tables. The
            // others are written without them, in the format they stand for.
            let old = EncodeConfig { neighbour_tables: false, ..EncodeConfig::default() };
            let classes = EncodeConfig { max_sh_degree: 2, sh_vq: [16, 0, 0], tail: CoarseTail::new(0.5, 2.0), ..old };
            let config = match name {
                "levels" => EncodeConfig { progressive: true, ..old },
                "vq" => EncodeConfig { max_sh_degree: 2, sh_vq: [16, 0, 0], ..old },
                "classes" => classes,
                "neighbour" => EncodeConfig { neighbour_tables: true, ..classes },
                "nbedge" => EncodeConfig::default(),
                "shared" => EncodeConfig { sh_vq: [32, 0, 0], sh_joint: true, tail: CoarseTail::new(0.5, 2.0), ..old },
                _ => old,
            };
            rate::encode(&vector_scene(name), &config).unwrap().0
        };
        std::fs::write(dir().join(format!("{name}.gsc")), &bytes).unwrap();
        let ply = decode(&bytes).unwrap().to_ply();
        if !HASH_ONLY.contains(&name) {
            std::fs::write(dir().join(format!("{name}.ply")), &ply).unwrap();
        }
        sums += &format!("{}  {name}.ply\n", hex(&Sha256::digest(&ply)));
    }
    std::fs::write(dir().join("SHA256SUMS"), sums).unwrap();
}

#[test]
fn vectors_decode_to_their_expected_output() {
    let sums = std::fs::read_to_string(dir().join("SHA256SUMS")).unwrap();
    for name in NAMES {
        let bytes = std::fs::read(dir().join(format!("{name}.gsc"))).unwrap();
        for threads in [1, 4] {
            let ply = {
                let mut d = Decoder::new(&bytes[..]);
                d.set_threads(threads);
                d.read_info().and_then(|r| r.decode())
            }
            .unwrap()
            .to_ply();
            assert_eq!(expected_hash(&sums, name), hex(&Sha256::digest(&ply)), "{name}");
            if !HASH_ONLY.contains(&name) {
                assert_eq!(ply, std::fs::read(dir().join(format!("{name}.ply"))).unwrap(), "{name}");
            }
        }
    }
}

/// Whether python3 with numpy is there to run `bitstream-spec/*.py`; says so when it is not.
fn python_with_numpy(what: &str) -> bool {
    let python = std::process::Command::new("python3").args(["-c", "import numpy"]).output();
    let found = python.is_ok_and(|o| o.status.success());
    if !found {
        eprintln!("SKIPPED: python3 with numpy not found; {what} was not run");
    }
    found
}

/// Runs `bitstream-spec/specdec.py INPUT OUTPUT`.
fn specdec(input: &Path, output: &Path) -> std::process::Output {
    std::process::Command::new("python3").arg(dir().join("../specdec.py")).arg(input).arg(output).output().unwrap()
}

/// `bitstream-spec/specdec.py`, a decoder written from SPEC.md alone, decodes every vector to
/// the same expected output: the spec, not just our code, defines the format. Needs python3
/// with numpy (`.ci/run` installs them); without them the test says so and checks nothing.
#[test]
fn independent_python_decoder_agrees() {
    if !python_with_numpy("the independent decoder") {
        return;
    }
    let sums = std::fs::read_to_string(dir().join("SHA256SUMS")).unwrap();
    let out = tempfile::tempdir().unwrap();
    for name in NAMES {
        let ply = out.path().join(format!("{name}.ply"));
        let run = specdec(&dir().join(format!("{name}.gsc")), &ply);
        assert!(run.status.success(), "{name}: {}", String::from_utf8_lossy(&run.stderr));
        assert_eq!(expected_hash(&sums, name), hex(&Sha256::digest(std::fs::read(&ply).unwrap())), "{name}");
    }
}

/// `bitstream-spec/vectors/bad/EXPECTED`: (file name, error class, reason) per bad vector.
fn bad_vectors() -> Vec<(String, String, String)> {
    let expected = std::fs::read_to_string(dir().join("bad/EXPECTED")).unwrap();
    let rows: Vec<(String, String, String)> = expected
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| {
            let mut f = l.splitn(3, ' ');
            let (name, class, reason) = (f.next().unwrap(), f.next().unwrap(), f.next().unwrap_or_default());
            assert!(["io", "format", "checksum", "unsupported", "limits"].contains(&class), "{l}");
            (name.to_string(), class.to_string(), reason.to_string())
        })
        .collect();
    assert!(rows.len() >= 8, "EXPECTED lists {} bad vectors", rows.len());
    rows
}

/// The bad vectors (SPEC §9.2) are the committed files, and every one is refused by the CLI: exit
/// code 2, one line `error: FILE: …` on stderr, no output file. The library's error class must be the
/// one `EXPECTED` lists (SPEC §9.1).
#[test]
fn bad_vectors_are_refused_by_the_cli() {
    let sums = std::fs::read_to_string(dir().join("SHA256SUMS")).unwrap();
    let out = tempfile::tempdir().unwrap();
    let ply = out.path().join("out.ply");
    for (name, class, reason) in bad_vectors() {
        let path = dir().join("bad").join(&name);
        let bytes = std::fs::read(&path).unwrap();
        let listed = sums.lines().find(|l| l.ends_with(&format!("  bad/{name}"))).unwrap_or_else(|| panic!("{name} not in SHA256SUMS"));
        assert_eq!(&listed[..64], hex(&Sha256::digest(&bytes)), "{name} differs from SHA256SUMS");
        let err = decode(&bytes).expect_err(&format!("{name} ({reason}) decoded"));
        assert_eq!(err.class(), class, "{name} ({reason}): {err}");
        let run = std::process::Command::new(env!("CARGO_BIN_EXE_gscodec"))
            .args(["decode", "--quiet"])
            .arg(&path)
            .arg("-o")
            .arg(&ply)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&run.stderr);
        assert_eq!(run.status.code(), Some(2), "{name} ({reason}): {stderr}");
        assert_eq!(stderr.lines().count(), 1, "{name}: {stderr}");
        assert!(stderr.starts_with("error: ") && stderr.contains(&name), "{name}: {stderr}");
        assert!(!ply.exists(), "{name}: output written");
    }
}

/// `specdec.py` refuses every bad vector with the class EXPECTED lists (exit 1, one line naming
/// the class, no output), and `make_bad_vectors.py` still makes exactly the committed vectors.
#[test]
fn bad_vectors_are_refused_by_the_independent_decoder() {
    if !python_with_numpy("the bad vectors' check with the independent decoder") {
        return;
    }
    let out = tempfile::tempdir().unwrap();
    let ply = out.path().join("out.ply");
    for (name, class, reason) in bad_vectors() {
        let run = specdec(&dir().join("bad").join(&name), &ply);
        let stderr = String::from_utf8_lossy(&run.stderr);
        assert_eq!(run.status.code(), Some(1), "{name} ({reason}): {stderr}");
        assert_eq!(stderr.lines().count(), 1, "{name}: {stderr}");
        assert!(stderr.contains(&format!("{name}: {class}: ")), "{name}: expected class {class}: {stderr}");
        assert!(!ply.exists(), "{name}: output written");
    }
    let made = out.path().join("made");
    let run = std::process::Command::new("python3").arg(dir().join("../make_bad_vectors.py")).arg("--out").arg(&made).output().unwrap();
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let committed = std::fs::read_to_string(dir().join("bad/EXPECTED")).unwrap();
    assert_eq!(std::fs::read_to_string(made.join("EXPECTED")).unwrap(), committed);
    for (name, ..) in bad_vectors() {
        assert!(std::fs::read(made.join(&name)).unwrap() == std::fs::read(dir().join("bad").join(&name)).unwrap(), "{name} is stale");
    }
    assert!(std::fs::read(made.join("quirks.gsc")).unwrap() == std::fs::read(dir().join("quirks.gsc")).unwrap(), "quirks.gsc is stale");
}

#[test]
fn mutated_vectors_never_panic() {
    let mut state = 2024u64;
    let mut rnd = move |m: usize| {
        state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((state >> 33) as usize) % m.max(1)
    };
    let limits = Limits::default();
    for name in NAMES {
        let bytes = std::fs::read(dir().join(format!("{name}.gsc"))).unwrap();
        for _ in 0..1500 {
            let mut b = bytes.clone();
            match rnd(4) {
                0 => {
                    let i = rnd(b.len());
                    b[i] ^= 1 << rnd(8);
                }
                1 => b.truncate(rnd(b.len())),
                2 => b.insert(rnd(b.len() + 1), rnd(256) as u8),
                _ => {
                    // Mutate, then repair the checksums so the damage reaches the table and stream parsers.
                    let i = rnd(b.len());
                    b[i] = rnd(256) as u8;
                    repair_crcs(&mut b);
                }
            }
            let _ = decode(&b);
            let _ = gscodec_decoder::inspect(&b);
            let _ = gscodec_decoder::decode_prefix(&b, &limits);
        }
    }
}

/// Recomputes the section and header CRCs of a (possibly damaged) file where the table is readable.
fn repair_crcs(b: &mut [u8]) {
    if b.len() < 16 {
        return;
    }
    let s = u16::from_le_bytes([b[6], b[7]]) as usize;
    let table_end = 16 + 16 * s;
    if b.len() < table_end + 4 {
        return;
    }
    let mut at = table_end + 4;
    for e in 0..s {
        let ent = 16 + 16 * e;
        let len = u32::from_le_bytes(b[ent + 8..ent + 12].try_into().unwrap()) as usize;
        if at + len > b.len() {
            return;
        }
        let crc = crc32(&b[at..at + len]);
        b[ent + 12..ent + 16].copy_from_slice(&crc.to_le_bytes());
        at += len;
    }
    let crc = crc32(&b[..table_end]);
    b[table_end..table_end + 4].copy_from_slice(&crc.to_le_bytes());
}

fn crc32(data: &[u8]) -> u32 {
    let mut c = !0u32;
    for &x in data {
        c ^= u32::from(x);
        for _ in 0..8 {
            c = if c & 1 != 0 { (c >> 1) ^ 0xEDB8_8320 } else { c >> 1 };
        }
    }
    !c
}

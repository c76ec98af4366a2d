//! Conformance vectors (`bitstream-spec/vectors/`): each `NAME.gsc` decodes to exactly
//! `NAME.ply`, whose SHA-256 is listed in `SHA256SUMS`. Regenerate (after a deliberate format
//! change only) with `cargo test --test vectors -- --ignored regenerate`.

use std::path::{Path, PathBuf};

use gscodec::rate::{self, EncodeConfig};
use gscodec_decoder::{decode, DecodeOptions, Splats};
use sha2::{Digest, Sha256};

const NAMES: [&str; 3] = ["empty", "hand", "tiny"];

fn dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("bitstream-spec/vectors")
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

#[test]
#[ignore]
fn regenerate() {
    let tiny = gscodec::io::read_ply(&Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/tiny/truth.ply")).unwrap();
    let mut sums = String::new();
    for (name, scene) in [("empty", Splats::new(0)), ("hand", hand_scene()), ("tiny", tiny)] {
        let (bytes, _, _) = rate::encode(&scene, &EncodeConfig::default()).unwrap();
        std::fs::write(dir().join(format!("{name}.gsc")), &bytes).unwrap();
        let ply = decode(&bytes, &DecodeOptions::default()).unwrap().to_ply();
        std::fs::write(dir().join(format!("{name}.ply")), &ply).unwrap();
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
            let ply = decode(&bytes, &DecodeOptions { threads, ..Default::default() }).unwrap().to_ply();
            let expected = sums.lines().find(|l| l.ends_with(&format!("  {name}.ply"))).unwrap();
            assert_eq!(&expected[..64], hex(&Sha256::digest(&ply)), "{name}");
            assert_eq!(ply, std::fs::read(dir().join(format!("{name}.ply"))).unwrap(), "{name}");
        }
    }
}

#[test]
fn mutated_vectors_never_panic() {
    let mut state = 2024u64;
    let mut rnd = move |m: usize| {
        state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((state >> 33) as usize) % m.max(1)
    };
    let opts = DecodeOptions { threads: 1, ..Default::default() };
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
            let _ = decode(&b, &opts);
            let _ = gscodec_decoder::inspect(&b);
            let _ = gscodec_decoder::decode_prefix(&b, &opts);
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

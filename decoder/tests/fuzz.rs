//! Plain-test fuzzing of the decoder door (the `decoder/fuzz` target's logic, run in CI): seeded
//! random byte strings and mutated conformance vectors (bit flips, byte writes, truncations,
//! insertions, splices of two vectors, and the same with every CRC repaired so the damage reaches
//! the table, parameter and stream parsers) go through `Decoder` (one byte per read and from a
//! slice), `decode_with`, `decode_prefix` and `inspect` under tight limits. Each must return a
//! scene that validates or a typed error of one of the five classes; a panic fails the test.

use gscodec_decoder::rng::Rng;
use gscodec_decoder::{decode_prefix, decode_with, inspect, DecodeError, Decoder, Limits, Splats};
use std::io::Read;
use std::path::Path;

/// Tight limits: enough for the vectors' own scenes (up to 70,000 Gaussians), little more.
const LIMITS: Limits = Limits { max_gaussians: 1 << 17, max_bytes: 48 << 20, max_sh_degree: 3 };

fn vectors() -> Vec<Vec<u8>> {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../bitstream-spec/vectors");
    let mut paths: Vec<_> = std::fs::read_dir(&dir)
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()))
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "gsc"))
        .collect();
    paths.sort();
    assert!(paths.len() >= 5, "conformance vectors missing in {}", dir.display());
    paths.iter().map(|p| std::fs::read(p).unwrap()).collect()
}

/// A uniform index below `m` (0 for m = 0).
fn below(rng: &mut Rng, m: usize) -> usize {
    rng.below(m.max(1))
}

/// Recomputes the header and section CRCs of whatever the table describes.
fn repair_crcs(b: &mut [u8]) {
    if b.len() < 16 {
        return;
    }
    let table_end = 16 + 16 * u16::from_le_bytes([b[6], b[7]]) as usize;
    if b.len() < table_end + 4 {
        return;
    }
    let mut at = table_end + 4;
    for entry in (16..table_end).step_by(16) {
        let len = u32::from_le_bytes(b[entry + 8..entry + 12].try_into().unwrap()) as usize;
        if at + len > b.len() {
            break;
        }
        let crc = crc32fast::hash(&b[at..at + len]);
        b[entry + 12..entry + 16].copy_from_slice(&crc.to_le_bytes());
        at += len;
    }
    let crc = crc32fast::hash(&b[..table_end]);
    b[table_end..table_end + 4].copy_from_slice(&crc.to_le_bytes());
}

/// One byte per `read` call.
struct OneByte<'a>(&'a [u8]);

impl Read for OneByte<'_> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        match (self.0.split_first(), buf.first_mut()) {
            (Some((b, rest)), Some(dst)) => {
                *dst = *b;
                self.0 = rest;
                Ok(1)
            }
            _ => Ok(0),
        }
    }
}

fn typed(r: &Result<Splats, DecodeError>, what: &str) {
    match r {
        Ok(s) => assert!(s.validate().is_ok() || s.is_empty(), "{what}: decoded an invalid scene"),
        Err(e) => {
            assert!(["format", "checksum", "unsupported", "limits"].contains(&e.class()), "{what}: {e} ({})", e.class());
            assert!(!e.to_string().is_empty());
        }
    }
}

/// Every entry point on `b`; returns whether the slice decode succeeded.
fn check(b: &[u8], what: &str, one_byte: bool) -> bool {
    let full = decode_with(b, &LIMITS);
    typed(&full, what);
    let mut d = Decoder::with_limits(b, LIMITS);
    d.set_threads(1);
    let door = d.read_info().and_then(|r| r.decode());
    typed(&door, what);
    assert_eq!(door.is_ok(), full.is_ok(), "{what}: the reader and slice doors disagree");
    if let (Ok(a), Ok(b)) = (&door, &full) {
        assert_eq!(a, b, "{what}");
    }
    if one_byte {
        let streamed = Decoder::with_limits(OneByte(b), LIMITS).read_info().and_then(|r| r.decode());
        assert_eq!(streamed.is_ok(), full.is_ok(), "{what}: one byte per read");
    }
    match decode_prefix(b, &LIMITS) {
        Ok(Some(s)) => {
            if let Ok(f) = &full {
                assert_eq!(&s, f, "{what}: prefix decode of the whole file");
            }
        }
        Ok(None) => assert!(full.is_err(), "{what}: decode_prefix waits on a complete file"),
        Err(e) => assert_ne!(e.class(), "io"),
    }
    if let Err(e) = inspect(b) {
        assert_ne!(e.class(), "io");
    }
    full.is_ok()
}

#[test]
fn random_and_mutated_bytes_give_scenes_or_typed_errors() {
    let vectors = vectors();
    for (i, v) in vectors.iter().enumerate() {
        assert!(check(v, &format!("vector {i}"), true), "vector {i} does not decode");
    }
    let mut rng = Rng::new(0x5eed_f00d_1234_5678);
    let (mut decoded, mut cases) = (0, 0);
    // Random bytes, some behind a valid magic and version.
    for i in 0..500 {
        let len = below(&mut rng, 200);
        let mut b: Vec<u8> = (0..len).map(|_| below(&mut rng, 256) as u8).collect();
        if i % 2 == 0 && b.len() >= 6 {
            b[..6].copy_from_slice(&[0x8A, b'G', b'S', b'C', 3, 0]);
        }
        if i % 4 == 0 {
            repair_crcs(&mut b);
        }
        decoded += usize::from(check(&b, &format!("random {i}"), i % 10 == 0));
        cases += 1;
    }
    for round in 0..3000 {
        let v = &vectors[below(&mut rng, vectors.len())];
        let mut b = v.clone();
        let what = match below(&mut rng, 5) {
            0 => {
                for _ in 0..1 + below(&mut rng, 3) {
                    let i = below(&mut rng, b.len());
                    b[i] ^= 1 << below(&mut rng, 8);
                }
                "bit flips"
            }
            1 => {
                let i = below(&mut rng, b.len());
                b[i] = below(&mut rng, 256) as u8;
                "byte write"
            }
            2 => {
                b.truncate(below(&mut rng, b.len()));
                "truncation"
            }
            3 => {
                b.insert(below(&mut rng, b.len() + 1), below(&mut rng, 256) as u8);
                "insertion"
            }
            _ => {
                let w = &vectors[below(&mut rng, vectors.len())];
                let (cut, from) = (below(&mut rng, b.len()), below(&mut rng, w.len()));
                b.truncate(cut);
                b.extend_from_slice(&w[from..]);
                "splice"
            }
        };
        // Half the cases get valid CRCs, so they reach the parsers behind the checksums.
        if round % 2 == 1 {
            repair_crcs(&mut b);
        }
        decoded += usize::from(check(&b, &format!("{what} {round}"), round % 50 == 0));
        cases += 1;
    }
    eprintln!("{cases} cases, {decoded} decoded to a valid scene, the rest typed errors");
    assert!(decoded < cases, "no mutation was refused");
}

/// The levels section (SPEC §3.1) of `levels.gsc` replaced by random chunk and level lists —
/// sizes of 0, 1, around the real ones, 65,536 and beyond, sums right and wrong — with the table
/// and CRCs made valid, so that every one reaches the levels reader and what follows it.
#[test]
fn random_levels_sections_give_scenes_or_typed_errors() {
    let bytes = std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("../bitstream-spec/vectors/levels.gsc")).unwrap();
    let table_end = 20 + 16 * usize::from(u16::from_le_bytes([bytes[6], bytes[7]]));
    assert_eq!(u16::from_le_bytes([bytes[16], bytes[17]]), 0x01, "the levels section is the first entry");
    let old_len = u32::from_le_bytes(bytes[24..28].try_into().unwrap()) as usize;
    let varint = |out: &mut Vec<u8>, mut v: u32| loop {
        let b = (v & 0x7f) as u8;
        v >>= 7;
        out.push(if v != 0 { b | 0x80 } else { b });
        if v == 0 {
            break;
        }
    };
    let mut rng = Rng::new(0x001e_7e15);
    let sizes = [0u32, 1, 2, 62, 63, 64, 125, 250, 500, 937, 1000, 65_536, 65_537, u32::MAX];
    let (mut decoded, mut cases) = (0, 0);
    for round in 0..600 {
        let mut payload = Vec::new();
        let levels = below(&mut rng, 7) as u32;
        varint(&mut payload, levels);
        for _ in 0..levels {
            let chunks = below(&mut rng, 4) as u32;
            varint(&mut payload, chunks);
            for _ in 0..chunks {
                varint(&mut payload, sizes[below(&mut rng, sizes.len())]);
            }
        }
        if round % 3 == 0 {
            // One level of chunks summing to N, split at random points.
            payload.clear();
            let mut cuts: Vec<u32> = (0..below(&mut rng, 6)).map(|_| 1 + below(&mut rng, 999) as u32).chain([0, 1000]).collect();
            cuts.sort_unstable();
            cuts.dedup();
            varint(&mut payload, 1);
            varint(&mut payload, cuts.len() as u32 - 1);
            cuts.windows(2).for_each(|w| varint(&mut payload, w[1] - w[0]));
        }
        let mut b = bytes[..table_end].to_vec();
        b[24..28].copy_from_slice(&(payload.len() as u32).to_le_bytes());
        b.extend_from_slice(&payload);
        b.extend_from_slice(&bytes[table_end + old_len..]);
        repair_crcs(&mut b);
        decoded += usize::from(check(&b, &format!("levels {round}"), false));
        cases += 1;
    }
    eprintln!("{cases} levels sections, {decoded} decoded");
    assert!(decoded < cases);
}

//! The player-facing API on the conformance vectors: decoding from a reader, progressive decoding
//! of a file that is still arriving, and `to_ply`.

use gscodec_decoder::{decode, decode_prefix, decode_reader, DecodeError, DecodeOptions, FormatErrorKind};
use std::path::{Path, PathBuf};

fn vector(name: &str) -> Vec<u8> {
    let path: PathBuf = Path::new(env!("CARGO_MANIFEST_DIR")).join("../bitstream-spec/vectors").join(name);
    std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

#[test]
fn every_prefix_decodes_to_nothing_the_base_or_more_bands() {
    let bytes = vector("tiny.gsc");
    let options = DecodeOptions::default();
    let full = decode(&bytes, &options).unwrap();
    assert_eq!(full.sh_degree, 3);
    let base = decode(&bytes, &DecodeOptions { max_sh_degree: 0, ..options }).unwrap();
    let mut first_base = None;
    let mut last_degree = None;
    for n in 0..=bytes.len() {
        let Some(s) = decode_prefix(&bytes[..n], &options).unwrap() else {
            assert!(last_degree.is_none(), "a longer prefix lost the scene at {n}");
            continue;
        };
        assert!(last_degree.is_none_or(|d| s.sh_degree >= d), "degree went down at {n}");
        last_degree = Some(s.sh_degree);
        first_base.get_or_insert(n);
        // What is shown is always the full decode cut to the degree that has arrived.
        assert_eq!(s, full.with_sh_degree(s.sh_degree), "prefix {n}");
    }
    assert_eq!(last_degree, Some(3));
    // The base is usable before the SH bands have arrived.
    let first_base = first_base.unwrap();
    assert!(first_base < bytes.len(), "base needs {first_base} of {} bytes", bytes.len());
    assert_eq!(decode_prefix(&bytes[..first_base], &options).unwrap().unwrap(), base);
}

#[test]
fn prefix_decoding_still_rejects_corruption() {
    let mut bytes = vector("tiny.gsc");
    let e = decode_prefix(b"PK\x03\x04 not a gsc file at all", &DecodeOptions::default()).unwrap_err();
    assert_eq!(e.format_error().map(|f| f.kind()), Some(FormatErrorKind::BadMagic));
    // A flipped byte in the first payload (a parameter section) fails its CRC as soon as it arrives.
    let table_end = 20 + 16 * usize::from(u16::from_le_bytes([bytes[6], bytes[7]]));
    bytes[table_end + 2] ^= 0x40;
    assert!(matches!(decode_prefix(&bytes[..table_end + 100], &DecodeOptions::default()), Err(DecodeError::Checksum(_))));
}

#[test]
fn reader_and_slice_decode_alike_and_to_ply_is_the_vector() {
    for name in ["hand", "tiny", "empty"] {
        let bytes = vector(&format!("{name}.gsc"));
        let s = decode_reader(std::io::Cursor::new(&bytes), &DecodeOptions::default()).unwrap();
        assert_eq!(s, decode(&bytes, &DecodeOptions::default()).unwrap());
        assert_eq!(s.to_ply(), vector(&format!("{name}.ply")), "{name}");
    }
    struct Broken;
    impl std::io::Read for Broken {
        fn read(&mut self, _: &mut [u8]) -> std::io::Result<usize> {
            Err(std::io::Error::other("disk on fire"))
        }
    }
    assert!(matches!(decode_reader(Broken, &DecodeOptions::default()), Err(DecodeError::Io(m)) if m.to_string().contains("disk on fire")));
}

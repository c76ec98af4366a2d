//! The player-facing API on the conformance vectors: the `Decoder` → `Reader` door (limits,
//! any reader, caller-owned output), progressive decoding of a file that is still arriving, and
//! `to_ply`.

use gscodec_decoder::{decode, decode_prefix, decode_with, DecodeError, Decoder, FormatErrorKind, Limit, Limits, SectionId, Splats};
use std::io::Read;
use std::path::{Path, PathBuf};

fn vector(name: &str) -> Vec<u8> {
    let path: PathBuf = Path::new(env!("CARGO_MANIFEST_DIR")).join("../bitstream-spec/vectors").join(name);
    std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// A reader that hands out one byte per call.
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

#[test]
fn every_prefix_decodes_to_nothing_the_base_or_more_bands() {
    let bytes = vector("tiny.gsc");
    let limits = Limits::default();
    let full = decode(&bytes).unwrap();
    assert_eq!(full.sh_degree, 3);
    let base = decode_with(&bytes, &Limits { max_sh_degree: 0, ..limits }).unwrap();
    let mut first_base = None;
    let mut last_degree = None;
    for n in 0..=bytes.len() {
        let Some(s) = decode_prefix(&bytes[..n], &limits).unwrap() else {
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
    assert_eq!(decode_prefix(&bytes[..first_base], &limits).unwrap().unwrap(), base);
}

/// The Gaussians `range` of `s`, as a scene.
fn slice(s: &Splats, range: std::ops::Range<usize>) -> Splats {
    let mut out = s.clone();
    out.retain_indices(|i| range.contains(&i));
    out
}

#[test]
fn every_prefix_of_a_progressive_file_is_whole_levels() {
    let bytes = vector("levels.gsc");
    let limits = Limits::default();
    let full = decode(&bytes).unwrap();
    let info = gscodec_decoder::inspect(&bytes).unwrap();
    assert_eq!((info.info.header.version_major, full.len(), full.sh_degree), (4, 1000, 3));
    assert_eq!(info.levels, vec![63, 62, 125, 250, 500]);
    // The Gaussian counts a prefix may show: every level complete, or none.
    let ends: Vec<usize> = info
        .levels
        .iter()
        .scan(0, |e, &k| {
            *e += k;
            Some(*e)
        })
        .collect();
    let mut shown = Vec::new();
    for n in 0..=bytes.len() {
        let Some(s) = decode_prefix(&bytes[..n], &limits).unwrap() else {
            assert!(shown.is_empty(), "a longer prefix lost the scene at {n}");
            continue;
        };
        assert!(ends.contains(&s.len()), "prefix {n}: {} Gaussians is not a level boundary", s.len());
        if let Some(&(len, degree)) = shown.last() {
            assert!(s.len() >= len && s.sh_degree >= degree, "prefix {n} shows less than a shorter one");
        }
        // The first Gaussians of the full decode, with the bands that have arrived.
        assert_eq!(s, slice(&full, 0..s.len()).with_sh_degree(s.sh_degree), "prefix {n}");
        if shown.last() != Some(&(s.len(), s.sh_degree)) {
            shown.push((s.len(), s.sh_degree));
        }
    }
    // Level by level with the base only, then the SH bands one by one.
    assert_eq!(shown, vec![(63, 0), (125, 0), (250, 0), (500, 0), (1000, 0), (1000, 1), (1000, 2), (1000, 3)]);
    // The levels section is checked as soon as it arrives: one chunk size off is an error.
    let mut bad = bytes.clone();
    let table_end = 20 + 16 * usize::from(u16::from_le_bytes([bad[6], bad[7]]));
    bad[table_end + 2] ^= 1; // the first level's chunk size (63 → 62)
    assert_eq!(decode_prefix(&bad[..table_end + 40], &limits).unwrap_err().class(), "checksum");
}

#[test]
fn prefix_decoding_still_rejects_corruption() {
    let mut bytes = vector("tiny.gsc");
    let e = decode_prefix(b"PK\x03\x04 not a gsc file at all", &Limits::default()).unwrap_err();
    assert_eq!(e.format_error().map(|f| f.kind()), Some(FormatErrorKind::BadMagic));
    // A flipped byte in the first payload (a parameter section) fails its CRC as soon as it arrives.
    let table_end = 20 + 16 * usize::from(u16::from_le_bytes([bytes[6], bytes[7]]));
    bytes[table_end + 2] ^= 0x40;
    let e = decode_prefix(&bytes[..table_end + 100], &Limits::default()).unwrap_err();
    let DecodeError::Checksum(c) = e else { panic!("{e}") };
    assert_eq!((c.section(), c.offset()), (Some(SectionId { kind: 0x10, chunk: 0 }), table_end as u64));
}

#[test]
fn readers_and_slices_decode_alike_and_to_ply_is_the_vector() {
    for name in ["hand", "tiny", "empty", "chunks"] {
        let bytes = vector(&format!("{name}.gsc"));
        let from_slice = decode(&bytes).unwrap();
        let from_file = Decoder::new(
            std::fs::File::open(Path::new(env!("CARGO_MANIFEST_DIR")).join("../bitstream-spec/vectors").join(format!("{name}.gsc")))
                .unwrap(),
        )
        .read_info()
        .unwrap()
        .decode()
        .unwrap();
        assert_eq!(from_file, from_slice, "{name}");
        if bytes.len() < 100_000 {
            let r = Decoder::new(OneByte(&bytes)).read_info().unwrap();
            assert_eq!(r.decode().unwrap(), from_slice, "{name}: one byte per read");
        }
        if name != "chunks" {
            assert_eq!(from_slice.to_ply(), vector(&format!("{name}.ply")), "{name}");
        }
    }
}

#[test]
fn read_info_reads_only_the_table_and_reports_it() {
    let bytes = vector("tiny.gsc");
    let mut rest = &bytes[..];
    let reader = Decoder::new(&mut rest).read_info().unwrap();
    let info = reader.info();
    let table = 20 + 16 * info.sections.len();
    assert_eq!((info.header.gaussians, info.header.sh_degree, info.file_bytes), (1000, 3, bytes.len() as u64));
    assert!(info.sections.iter().any(|s| s.name == "position" && s.kind == 0x20));
    assert_eq!(info.sections.iter().map(|s| s.bytes).sum::<usize>() + table, bytes.len());
    assert_eq!(reader.output_sh_degree(), 3);
    assert!(reader.required_bytes() > 2 * 1000 * 59 * 4);
    drop(reader);
    assert_eq!(rest.len(), bytes.len() - table, "read_info read past the section table");
}

#[test]
fn decode_into_reuses_the_callers_scene() {
    let tiny = vector("tiny.gsc");
    let hand = vector("hand.gsc");
    let mut scene = Splats::new(0);
    Decoder::new(&tiny[..]).read_info().unwrap().decode_into(&mut scene).unwrap();
    assert_eq!(scene, decode(&tiny).unwrap());
    Decoder::new(&hand[..]).read_info().unwrap().decode_into(&mut scene).unwrap();
    assert_eq!(scene, decode(&hand).unwrap(), "a smaller scene replaces a larger one");
    // On error the caller's scene is left as it was.
    let mut bad = tiny.clone();
    let last = bad.len() - 1;
    bad[last] ^= 1;
    let before = scene.clone();
    assert_eq!(Decoder::new(&bad[..]).read_info().unwrap().decode_into(&mut scene).unwrap_err().class(), "checksum");
    assert_eq!(scene, before);
}

#[test]
fn limits_refuse_before_reading_the_payloads() {
    let bytes = vector("tiny.gsc");
    let too_few = Limits { max_gaussians: 999, ..Limits::default() };
    let e = Decoder::with_limits(&bytes[..], too_few).read_info().unwrap_err();
    let DecodeError::LimitsExceeded(l) = &e else { panic!("{e}") };
    assert_eq!((l.limit(), l.value_and_max(), l.is_caller_limit()), (Limit::Gaussians, (1000, 999), true), "{e}");
    assert!(e.to_string().contains("max_gaussians"), "{e}");
    let e = decode_with(&bytes, &too_few).unwrap_err();
    assert_eq!(e.class(), "limits");
    let e = decode_prefix(&bytes, &too_few).unwrap_err();
    assert_eq!(e.class(), "limits");
    // The byte budget counts the file and twice the scene; dropping SH bands lowers it.
    let r = Decoder::new(&bytes[..]).read_info().unwrap();
    let need = r.required_bytes();
    let exact = Limits { max_bytes: need, ..Limits::default() };
    assert!(Decoder::with_limits(&bytes[..], exact).read_info().is_ok());
    let short = Limits { max_bytes: need - 1, ..Limits::default() };
    assert!(matches!(Decoder::with_limits(&bytes[..], short).read_info(), Err(DecodeError::LimitsExceeded(_))));
    let sh0 = Limits { max_bytes: need - 1, max_sh_degree: 0, ..Limits::default() };
    let scene = Decoder::with_limits(&bytes[..], sh0).read_info().unwrap().decode().unwrap();
    assert_eq!((scene.len(), scene.sh_degree), (1000, 0));
}

#[test]
fn reader_errors_are_typed() {
    #[derive(Debug)]
    struct Broken;
    impl Read for Broken {
        fn read(&mut self, _: &mut [u8]) -> std::io::Result<usize> {
            Err(std::io::Error::other("disk on fire"))
        }
    }
    let e = Decoder::new(Broken).read_info().unwrap_err();
    assert!(matches!(&e, DecodeError::Io(m) if m.to_string().contains("disk on fire")), "{e}");
    assert_eq!(e.class(), "io");
    // Truncated in the payloads: a format error naming the section; trailing bytes likewise.
    let bytes = vector("tiny.gsc");
    let e = Decoder::new(&bytes[..bytes.len() - 3]).read_info().unwrap().decode().unwrap_err();
    let f = e.format_error().unwrap();
    assert_eq!(f.kind(), FormatErrorKind::Truncated);
    assert!(f.section().is_some(), "{e}");
    let longer = [&bytes[..], b"x"].concat();
    let e = Decoder::new(&longer[..]).read_info().unwrap().decode().unwrap_err();
    assert_eq!(e.format_error().map(|f| (f.kind(), f.offset())), Some((FormatErrorKind::TrailingData, bytes.len() as u64)));
    assert_eq!(decode(&longer).unwrap_err().format_error().map(|f| f.kind()), Some(FormatErrorKind::TrailingData));
    // Fewer bytes than the header: bad magic below 4 bytes, truncation above.
    assert_eq!(decode(&bytes[..3]).unwrap_err().format_error().map(|f| f.kind()), Some(FormatErrorKind::BadMagic));
    let e = Decoder::new(&bytes[..10]).read_info().unwrap_err();
    assert_eq!(e.format_error().map(|f| f.kind()), Some(FormatErrorKind::Truncated));
}

/// `bitstream-spec/vectors/bad/EXPECTED` lists each bad vector with its error class: every entry
/// point refuses it with that class (and the fuzz test covers their mutations).
#[test]
fn bad_vectors_fail_with_their_class() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../bitstream-spec/vectors/bad");
    let Ok(expected) = std::fs::read_to_string(dir.join("EXPECTED")) else {
        gscodec_decoder::testkit::skip(format_args!("no {}", dir.join("EXPECTED").display()));
        return;
    };
    let mut checked = 0;
    for line in expected.lines().filter(|l| !l.starts_with('#') && !l.trim().is_empty()) {
        let mut words = line.split_whitespace();
        let (name, class) = (words.next().unwrap(), words.next().unwrap());
        let bytes = std::fs::read(dir.join(name)).unwrap_or_else(|e| panic!("{name}: {e}"));
        let e = decode(&bytes).unwrap_err();
        assert_eq!(e.class(), class, "{name}: {e}");
        let e = Decoder::new(&bytes[..]).read_info().and_then(|r| r.decode()).unwrap_err();
        assert_eq!(e.class(), class, "{name} (reader): {e}");
        checked += 1;
    }
    assert!(checked >= 8, "only {checked} bad vectors");
}

/// A short input whose table declares a 3 GB section (within the default byte budget) is refused
/// as truncated after reading what is there, without a buffer of the declared size.
#[test]
fn a_huge_declared_section_costs_only_what_arrives() {
    let mut b = Vec::new();
    b.extend_from_slice(&[0x8A, b'G', b'S', b'C', 3, 0, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0]);
    b.extend_from_slice(&0x101u16.to_le_bytes()); // padding, optional
    b.extend_from_slice(&0u16.to_le_bytes());
    b.extend_from_slice(&1u32.to_le_bytes());
    b.extend_from_slice(&3_000_000_000u32.to_le_bytes());
    b.extend_from_slice(&0u32.to_le_bytes());
    let crc = crc32fast::hash(&b);
    b.extend_from_slice(&crc.to_le_bytes());
    b.extend_from_slice(&[0; 100]);
    let reader = Decoder::new(&b[..]).read_info().unwrap();
    assert_eq!(reader.info().file_bytes, 36 + 3_000_000_000);
    let e = reader.decode().unwrap_err();
    assert_eq!(
        e.format_error().map(|f| (f.kind(), f.section())),
        Some((FormatErrorKind::Truncated, Some(SectionId { kind: 0x101, chunk: 0 })))
    );
}

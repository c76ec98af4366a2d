//! Any byte string through the decoder door under tight limits: `read_info` + `decode` (one byte
//! per read and from a slice), `decode_with`, `decode_prefix` and `inspect` return Ok or a typed
//! `DecodeError`, never panic, and agree with each other. Seed corpus:
//! `bitstream-spec/vectors/*.gsc`. `cd decoder/fuzz && cargo +nightly fuzz run decode`.
#![no_main]

use gscodec_decoder::{decode_prefix, decode_with, inspect, peek_header, Decoder, Limits};
use libfuzzer_sys::fuzz_target;

/// A reader that hands out one byte per call.
struct OneByte<'a>(&'a [u8]);

impl std::io::Read for OneByte<'_> {
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

fuzz_target!(|data: &[u8]| {
    let limits = Limits { max_gaussians: 1 << 16, max_bytes: 64 << 20, max_sh_degree: 3 };
    let _ = peek_header(data);
    let _ = inspect(data);
    let full = decode_with(data, &limits);
    if let Ok(s) = &full {
        assert!(s.validate().is_ok());
    }
    let mut d = Decoder::with_limits(OneByte(data), limits);
    d.set_threads(1);
    let streamed = d.read_info().and_then(|r| r.decode());
    assert_eq!(streamed.as_ref().ok(), full.as_ref().ok());
    // A prefix decode of the whole input agrees with decode whenever decode succeeds.
    if let Ok(Some(s)) = decode_prefix(data, &limits) {
        assert!(s.validate().is_ok());
        if let Ok(f) = &full {
            assert_eq!(&s, f);
        }
    }
});

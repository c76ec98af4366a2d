//! Any byte string: decode and inspect must return (Ok or a DecodeError), never panic or
//! allocate beyond the input-size bound. Seed corpus: `bitstream-spec/vectors/*.gsc`.
#![no_main]

use gscodec_decoder::{decode, inspect, peek_header, DecodeOptions};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = peek_header(data);
    let _ = inspect(data);
    if let Ok(s) = decode(data, &DecodeOptions { max_sh_degree: 3, threads: 1 }) {
        assert!(s.validate().is_ok());
    }
});

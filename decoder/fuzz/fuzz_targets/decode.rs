//! Any byte string: decode, decode_prefix and inspect must return (Ok or a DecodeError), never panic or
//! allocate beyond the input-size bound. Seed corpus: `bitstream-spec/vectors/*.gsc`.
#![no_main]

use gscodec_decoder::{decode, decode_prefix, inspect, peek_header, DecodeOptions};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = peek_header(data);
    let _ = inspect(data);
    let options = DecodeOptions { max_sh_degree: 3, threads: 1 };
    let full = decode(data, &options);
    if let Ok(s) = &full {
        assert!(s.validate().is_ok());
    }
    // A prefix decode of the whole input agrees with decode whenever decode succeeds.
    if let Ok(Some(s)) = decode_prefix(data, &options) {
        assert!(s.validate().is_ok());
        if let Ok(f) = &full {
            assert_eq!(&s, f);
        }
    }
});

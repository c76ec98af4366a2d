//! Decodes a `.gsc` file and prints what it holds and how long decoding took.
//!
//! `cargo run --release -p gscodec-decoder --example decode -- scene.gsc [threads] [repeats]`
//! (threads 0 = all cores; repeats > 1 reports the fastest run, handy under a profiler).

use gscodec_decoder::{peek_header, Decoder, Limits};
use std::time::Instant;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let Some(path) = args.get(1) else {
        eprintln!("usage: decode FILE.gsc [threads] [repeats]");
        std::process::exit(2);
    };
    let threads = args.get(2).and_then(|a| a.parse().ok()).unwrap_or(0);
    let repeats = args.get(3).and_then(|a| a.parse().ok()).unwrap_or(1usize).max(1);
    let bytes = std::fs::read(path).unwrap_or_else(|e| {
        eprintln!("error: {path}: {e}");
        std::process::exit(2);
    });
    let header = match peek_header(&bytes) {
        Ok(h) => h,
        Err(e) => {
            eprintln!("error: {path}: {e}");
            std::process::exit(2);
        }
    };
    let mut best = f64::INFINITY;
    let mut splats = None;
    for _ in 0..repeats {
        let t = Instant::now();
        let mut decoder = Decoder::with_limits(&bytes[..], Limits::none());
        decoder.set_threads(threads);
        match decoder.read_info().and_then(|r| r.decode()) {
            Ok(s) => splats = Some(s),
            Err(e) => {
                eprintln!("error: {path}: {e}");
                std::process::exit(2);
            }
        }
        best = best.min(t.elapsed().as_secs_f64());
    }
    let s = splats.expect("at least one run");
    println!(
        "{path}: version {}.{}, {} Gaussians, SH degree {}, {} bytes; decoded in {:.3} ms ({:.2} M Gaussians/s)",
        header.version_major,
        header.version_minor,
        s.len(),
        s.sh_degree,
        bytes.len(),
        best * 1e3,
        s.len() as f64 / best / 1e6
    );
}

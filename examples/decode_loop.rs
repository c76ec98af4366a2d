//! Decode time of a `.gsc` (or `.spz`) file, N decodes on T threads (profiling aid).
use gscodec::decoder::Decoder;
fn main() {
    let a: Vec<String> = std::env::args().collect();
    let bytes = std::fs::read(&a[1]).unwrap();
    let n: usize = a[2].parse().unwrap();
    let threads: usize = a[3].parse().unwrap();
    let spz = a[1].ends_with(".spz");
    let t = std::time::Instant::now();
    let mut g = 0;
    for _ in 0..n {
        let s = if spz {
            gscodec::io::spz::decode_spz(&bytes).unwrap()
        } else {
            let mut d = Decoder::new(&bytes[..]);
            d.set_threads(threads);
            d.read_info().and_then(|r| r.decode()).unwrap()
        };
        g += s.len();
    }
    let e = t.elapsed().as_secs_f64();
    println!("{} Gaussians, {:.3} ms per decode, {:.2} M G/s", g / n, 1e3 * e / n as f64, g as f64 / e / 1e6);
}

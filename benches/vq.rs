//! k-means of an SH band (`rate::vq::kmeans`, the RD search's codebook stage) on a generated
//! band shaped like a quantised one: 12,000 rows, two fifths of them zero (bands the search
//! dropped), the rest small integers whose spread falls with the channel.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use gscodec::rate::vq::kmeans;
use gscodec_decoder::rng::Rng;

fn band(n: usize, c: usize, seed: u64) -> (Vec<Vec<i32>>, Vec<f32>) {
    let mut rng = Rng::new(seed);
    let mut chans = vec![Vec::with_capacity(n); c];
    for _ in 0..n {
        let zero = rng.uniform() < 0.4;
        for (j, ch) in chans.iter_mut().enumerate() {
            ch.push(if zero { 0 } else { (rng.normal() * 6.0 / (1.0 + 0.3 * j as f32)).round() as i32 });
        }
    }
    let weights = (0..n).map(|_| rng.uniform()).collect();
    (chans, weights)
}

fn vq(c: &mut Criterion) {
    let mut g = c.benchmark_group("kmeans");
    g.sample_size(10);
    for (channels, k) in [(9, 256), (15, 1024), (21, 4096)] {
        let (chans, w) = band(12_000, channels, 3);
        // The RD search runs k-means inside the thread pool, as here.
        g.bench_with_input(BenchmarkId::new(format!("c{channels}"), k), &k, |b, &k| {
            b.iter(|| rayon::join(|| kmeans(&chans, &w, k, 1), || ()).0)
        });
    }
    g.finish();
}

criterion_group!(benches, vq);
criterion_main!(benches);

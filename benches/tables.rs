//! Neighbour-table fitting (`rate::tables::with_neighbours`, mode 3 of SPEC §4.3): what every
//! encode of the RD search does for each coded channel. Generated channels shaped like quantised
//! ones in Morton order: a slowly varying field plus small integer noise, the channel below
//! following the same field, in two streams (chunks).

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use gscodec::rate::tables::with_neighbours;
use gscodec_decoder::rng::Rng;

fn channel(n: usize, spread: f32, seed: u64) -> (Vec<i32>, Vec<i32>) {
    let mut rng = Rng::new(seed);
    let field: Vec<f32> = (0..n).map(|i| (i as f32 * 0.003).sin() * spread + (i as f32 * 0.0007).cos() * spread * 0.5).collect();
    let lower = field.iter().map(|&f| (f + rng.normal() * 2.0).round() as i32).collect();
    let values = field.iter().map(|&f| (0.7 * f + rng.normal() * 3.0).round() as i32).collect();
    (values, lower)
}

fn tables(c: &mut Criterion) {
    let mut g = c.benchmark_group("with_neighbours");
    g.sample_size(10);
    for n in [12_000, 120_000] {
        let (values, lower) = channel(n, 20.0, 5);
        let chunks = [0..n / 2, n / 2..n];
        g.bench_with_input(BenchmarkId::new("below", n), &n, |b, _| b.iter(|| with_neighbours(&values, &lower, &chunks)));
        g.bench_with_input(BenchmarkId::new("first", n), &n, |b, _| b.iter(|| with_neighbours(&values, &[], &chunks)));
    }
    g.finish();
}

criterion_group!(benches, tables);
criterion_main!(benches);

//! `.ply` read throughput (MB/s) on a generated 100k-Gaussian SH-degree-3 scene.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use gscodec::io::ply::read_ply_bytes;
use gscodec::sample::scene;
use std::path::Path;

fn ply_read(c: &mut Criterion) {
    let bytes = scene(100_000, 7).to_ply();
    let mut g = c.benchmark_group("ply");
    g.throughput(Throughput::Bytes(bytes.len() as u64));
    g.sample_size(20);
    g.bench_function("read_100k_sh3", |b| b.iter(|| read_ply_bytes(&bytes, Path::new("bench.ply")).unwrap()));
    let s = read_ply_bytes(&bytes, Path::new("bench.ply")).unwrap();
    g.bench_function("write_100k_sh3", |b| b.iter(|| s.to_ply()));
    g.finish();
}

criterion_group!(benches, ply_read);
criterion_main!(benches);

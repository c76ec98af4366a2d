//! CPU render time per 256x256 frame at 10k and 100k Gaussians (SH degree 3).

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use glam::Vec3;
use gscodec::decoder::{render::render, Camera, RenderOptions, Splats};

fn scene(n: usize) -> Splats {
    // Deterministic pseudo-random cloud in the unit cube with scene-typical sizes.
    let mut rng = gscodec::rng::Rng::new(0x1234_5678_9abc_def1);
    let mut next = move || rng.uniform();
    let mut s = Splats::new(3);
    // Sizes shrink with density so the screen coverage per frame stays comparable.
    let base = -2.5 - 0.5 * (n as f32 / 10_000.0).log2().max(0.0) / 1.5;
    for _ in 0..n {
        let p = [next() * 2.0 - 1.0, next() * 2.0 - 1.0, next() * 2.0 - 1.0];
        let ls = [base - next(), base - next(), base - next()];
        let q = [next() - 0.5, next() - 0.5, next() - 0.5, next() - 0.5];
        let rest: Vec<f32> = (0..45).map(|_| (next() - 0.5) * 0.2).collect();
        s.push(p, ls, q, next() * 4.0 - 1.0, [next() - 0.5, next() - 0.5, next() - 0.5], &rest);
    }
    s
}

fn bench_render(c: &mut Criterion) {
    let cam = Camera::look_at(Vec3::new(0.0, -1.0, -3.0), Vec3::ZERO, Vec3::new(0.0, -1.0, 0.0), 256, 256, 0.8);
    let mut group = c.benchmark_group("cpu_render_256x256");
    group.sample_size(20);
    for n in [10_000usize, 100_000] {
        let s = scene(n);
        group.bench_with_input(BenchmarkId::from_parameter(n), &s, |b, s| b.iter(|| render(s, &cam, &RenderOptions::default())));
    }
    group.finish();
}

criterion_group!(benches, bench_render);
criterion_main!(benches);

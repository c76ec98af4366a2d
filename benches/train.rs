//! One training iteration (forward + L1/SSIM loss + backward + Adam step) at 200x200 with 10k and
//! 50k Gaussians (SH degree 3). The per-stage split is printed by
//! `cargo run --release --example train_stages`.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use gscodec::loss::L1Ssim;
use gscodec::raster;
use gscodec::rate::group::Group;
use gscodec::train::adam::Adam;
use gscodec::train::targets::{orbit_cameras, render_targets, toy_scene};
use gscodec_decoder::RenderOptions;

fn bench_iteration(c: &mut Criterion) {
    let mut group = c.benchmark_group("train_iteration_200x200");
    group.sample_size(10);
    for n in [10_000usize, 50_000] {
        let shrink = (n as f32 / 120.0).cbrt().ln();
        let mut truth = toy_scene(n, 1).with_sh_degree(3);
        truth.log_scales.iter_mut().for_each(|l| *l = l.map(|v| v - shrink));
        let ds = render_targets(&truth, &orbit_cameras(2, 4.0, 200, 200), [1.0; 3]);
        let mut params = toy_scene(n, 2).with_sh_degree(3);
        params.log_scales.iter_mut().for_each(|l| *l = l.map(|v| v - shrink));
        let mut adam = Adam::new(&params);
        let opts = RenderOptions { background: [1.0; 3], max_sh_degree: 3 };
        let frame = &ds.frames[0];
        group.bench_with_input(BenchmarkId::from_parameter(n), &n, |b, _| {
            b.iter(|| {
                let (img, st) = raster::forward(&params, &frame.camera, &opts);
                let (_, dl) = L1Ssim::default().eval(&img, &frame.image);
                let g = raster::backward(&params, &st, &dl);
                adam.step(&mut params, &g.params, |grp| if grp == Group::Position { 1e-5 } else { 1e-4 });
            })
        });
    }
    group.finish();
}

criterion_group!(benches, bench_iteration);
criterion_main!(benches);

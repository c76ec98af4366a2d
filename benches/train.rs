//! One training iteration at 200x200 (lego-200's size) with 10k Gaussians (SH degree 3), split by
//! stage, each at 1 and 2 threads: projection, tile binning + depth sort, the whole forward render
//! (rasterizing = forward − project − sort), L1+SSIM loss, backward, Adam, the non-finite checks,
//! and one densify step (run every 100 iterations by the reference schedule); plus the whole
//! iteration with 10k and 50k Gaussians. Figures in docs/train.md.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use gscodec::loss::L1Ssim;
use gscodec::raster;
use gscodec::rate::group::Group;
use gscodec::rng::Rng;
use gscodec::testkit::{bench_splats, rig_cameras};
use gscodec::train::adam::{first_non_finite, Adam};
use gscodec::train::densify::{densify_and_prune_keeping, DensifyParams, DensifyStats};
use gscodec::train::targets::render_targets;
use gscodec_decoder::render::{bin_tiles, preprocess};
use gscodec_decoder::{Image, RenderOptions, Splats};

fn setup(n: usize) -> (Splats, Image, gscodec_decoder::Camera) {
    let ds = render_targets(&bench_splats(n, 1), &rig_cameras(2, 4.0, 200, 200), [1.0; 3]);
    let params = bench_splats(n, 2);
    (params, (*ds.frames[0].image.get().unwrap()).clone(), ds.frames[0].camera)
}

const OPTS: RenderOptions = RenderOptions { background: [1.0; 3], max_sh_degree: 3 };

fn bench_stages(c: &mut Criterion) {
    gscodec::cli::keep_freed_memory(); // as the CLI runs
    let (params, target, cam) = setup(10_000);
    let (img, st) = raster::forward(&params, &cam, &OPTS);
    let (_, dl) = L1Ssim::default().eval(&img, &target);
    let grads = raster::backward(&params, &st, &dl);
    // Densification statistics as after 100 iterations: a quarter of the Gaussians above the
    // gradient threshold, half of those large enough to split.
    let mut rng = Rng::new(5);
    let stats = DensifyStats {
        grad_accum: (0..params.len()).map(|_| rng.range(0.0, 8e-4)).collect(),
        count: vec![1; params.len()],
        max_radius: (0..params.len()).map(|_| rng.range(0.0, 10.0)).collect(),
    };
    let dp = DensifyParams {
        grad_threshold: 6e-4,
        percent_dense: 0.01,
        extent: 1.0,
        min_opacity: 0.005,
        max_screen_radius: None,
        max_world_fraction: 0.1,
        max_gaussians: 100_000,
    };
    let mut group = c.benchmark_group("train_stage_200x200_10k");
    group.sample_size(10);
    for threads in [1usize, 2] {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
        group.bench_with_input(BenchmarkId::new("project", threads), &threads, |b, _| {
            b.iter(|| pool.install(|| preprocess(&params, &cam, OPTS.max_sh_degree)))
        });
        group.bench_with_input(BenchmarkId::new("sort", threads), &threads, |b, _| {
            b.iter(|| pool.install(|| bin_tiles(&st.projected, cam.width, cam.height)))
        });
        group.bench_with_input(BenchmarkId::new("forward", threads), &threads, |b, _| {
            b.iter(|| pool.install(|| raster::forward(&params, &cam, &OPTS)))
        });
        group.bench_with_input(BenchmarkId::new("loss", threads), &threads, |b, _| {
            b.iter(|| pool.install(|| L1Ssim::default().eval(&img, &target)))
        });
        group.bench_with_input(BenchmarkId::new("backward", threads), &threads, |b, _| {
            b.iter(|| pool.install(|| raster::backward(&params, &st, &dl)))
        });
        let (mut p, mut adam) = (params.clone(), Adam::new(&params));
        group.bench_with_input(BenchmarkId::new("adam", threads), &threads, |b, _| {
            b.iter(|| pool.install(|| adam.step(&mut p, &grads.params, |g| if g == Group::Position { 1e-5 } else { 1e-4 })))
        });
        group.bench_with_input(BenchmarkId::new("finite_check", threads), &threads, |b, _| {
            b.iter(|| pool.install(|| (first_non_finite(&grads.params), first_non_finite(&params))))
        });
        group.bench_with_input(BenchmarkId::new("densify", threads), &threads, |b, _| {
            b.iter_batched(
                || (params.clone(), Adam::new(&params), Rng::new(9)),
                |(mut p, mut a, mut r)| pool.install(|| densify_and_prune_keeping(&mut p, &mut a, &stats, &dp, &mut r, 0)),
                criterion::BatchSize::LargeInput,
            )
        });
    }
    group.finish();
}

fn bench_iteration(c: &mut Criterion) {
    gscodec::cli::keep_freed_memory(); // as the CLI runs
    let mut group = c.benchmark_group("train_iteration_200x200");
    group.sample_size(10);
    for n in [10_000usize, 50_000] {
        let (mut params, target, cam) = setup(n);
        let mut adam = Adam::new(&params);
        group.bench_with_input(BenchmarkId::from_parameter(n), &n, |b, _| {
            b.iter(|| {
                let (img, st) = raster::forward(&params, &cam, &OPTS);
                let (_, dl) = L1Ssim::default().eval(&img, &target);
                let g = raster::backward(&params, &st, &dl);
                adam.step(&mut params, &g.params, |grp| if grp == Group::Position { 1e-5 } else { 1e-4 });
            })
        });
    }
    group.finish();
}

criterion_group!(benches, bench_stages, bench_iteration);
criterion_main!(benches);

#![allow(missing_docs)] // criterion_group! generates undocumented items
//! GPU frame time without I/O: the scene is uploaded once, then each frame projects, sorts and
//! rasterizes into a GPU-resident image (no readback of the image). 1920×1080, seeded random
//! scenes of 125k, 1 M and 3 M SH-degree-3 Gaussians spread in front of the camera, plus the
//! split per stage (project / sort / rasterize; GPU timestamps where the adapter has them).
//!
//! `cargo bench -p gscodec-decoder --features gpu --bench gpu_frame`
//! Environment: `GSC_BENCH_SIZES=125000,1000000` picks the scene sizes; `GSC_BENCH_SCENE=x.gsc`
//! renders a decoded file instead of the random scenes. Prints a skip line without an adapter.

use criterion::{criterion_group, criterion_main, Criterion};
use glam::Vec3;
use gscodec_decoder::render::gpu::{GpuError, GpuRenderer, StageTimes};
use gscodec_decoder::render::{bin_tiles, preprocess};
use gscodec_decoder::testkit::{random_splats_in, SceneRanges};
use gscodec_decoder::{Camera, RenderOptions, Splats};
use std::time::Duration;

const W: u32 = 1920;
const H: u32 = 1080;

/// A seeded random scene of `n` Gaussians in the unit cube (SH degree 3). Trained scenes hold many
/// small Gaussians: the scales shrink with `n` so the (tile, Gaussian) pairs stay a few per
/// Gaussian (the same rule as the CPU renderer's frame-time test).
fn scene(n: usize) -> Splats {
    let ranges = SceneRanges { extent: [1.0; 3], log_scale: [-4.5, -1.5], opacity: [-3.0, 4.0], sh_dc: 1.5, sh_rest: 0.3 };
    let mut s = random_splats_in(n, 3, 11, &ranges);
    let shrink = 1.5 + (n as f32 / 100_000.0).log10() * 0.5;
    s.log_scales.iter_mut().flatten().for_each(|v| *v -= shrink);
    s
}

fn camera() -> Camera {
    Camera::look_at(Vec3::new(0.3, -0.4, -3.5), Vec3::ZERO, Vec3::new(0.0, -1.0, 0.0), W, H, 0.9)
}

fn scenes() -> Vec<(String, Splats)> {
    if let Ok(path) = std::env::var("GSC_BENCH_SCENE") {
        let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("{path}: {e}"));
        let s = gscodec_decoder::decode(&bytes).unwrap_or_else(|e| panic!("{path}: {e}"));
        return vec![(format!("{path} ({})", s.len()), s)];
    }
    let sizes = std::env::var("GSC_BENCH_SIZES").unwrap_or_else(|_| "125000,1000000,3000000".into());
    sizes
        .split(',')
        .map(|v| v.trim().parse::<usize>().expect("GSC_BENCH_SIZES: comma-separated counts"))
        .map(|n| (n.to_string(), scene(n)))
        .collect()
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn gpu_frame(c: &mut Criterion) {
    let r = match GpuRenderer::new() {
        Ok(r) => r,
        Err(GpuError::NoAdapter(e)) => {
            eprintln!("SKIP gpu_frame: no GPU adapter available ({e})");
            return;
        }
        Err(e) => panic!("an adapter exists but the renderer failed: {e}"),
    };
    let cam = camera();
    let opts = RenderOptions::default();
    eprintln!("gpu_frame on {} (software: {}), {W}x{H}, GPU timestamps: {}", r.adapter_name(), r.is_software(), r.has_timestamps());
    let mut group = c.benchmark_group("gpu_frame_1080p");
    group.sample_size(10).warm_up_time(Duration::from_secs(1)).measurement_time(Duration::from_secs(3));
    for (name, s) in scenes() {
        let pairs = bin_tiles(&preprocess(&s, &cam, 3), W, H).ids.len();
        let gpu = r.upload(&s, 3).unwrap();
        drop(s);
        group.bench_function(format!("frame/{name}"), |b| {
            b.iter(|| {
                let f = r.render_frame(&gpu, &cam, &opts).unwrap();
                r.sync().unwrap();
                f
            })
        });
        let runs: Vec<StageTimes> = (0..15).map(|_| r.render_frame_timed(&gpu, &cam, &opts).unwrap().1).collect();
        let ms = |f: fn(&StageTimes) -> f64| median(runs.iter().map(f).collect()) * 1e3;
        let (p, so, ra) = (ms(|t| t.project), ms(|t| t.sort), ms(|t| t.rasterize));
        let sum = p + so + ra;
        eprintln!(
            "stages {name} Gaussians ({pairs} tile pairs), median of 15 ({}): project {p:.2} ms ({:.0}%), sort {so:.2} ms ({:.0}%), rasterize {ra:.2} ms ({:.0}%), sum {sum:.2} ms",
            if runs[0].gpu_timestamps { "GPU timestamps" } else { "host time per stage" },
            100.0 * p / sum,
            100.0 * so / sum,
            100.0 * ra / sum,
        );
    }
    group.finish();
}

criterion_group!(benches, gpu_frame);
criterion_main!(benches);

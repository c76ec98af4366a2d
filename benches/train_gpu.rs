//! GPU training iteration time by stage (feature `gpu`): one iteration at 200×200 with 10k and 50k
//! Gaussians (SH degree 3), the scene of `benches/train.rs` (the CPU counterpart), and at 1280×960
//! (1.2 MP) with 1 M Gaussians. Each stage is submitted and waited for on its own, so the sum is a
//! little more than a pipelined iteration (`iteration`: all stages in one submission, as the
//! trainer records them). Skips (prints why) when there is no adapter.
//!
//! Environment: `GSC_TRAIN_SIZES=200x200:10000,1280x960:1000000` picks `WxH:Gaussians` cases
//! (default: the three above); `GSC_TRAIN_STAGES=iteration` times only whole iterations (e.g. for
//! a memory measurement). `scripts/device-measure` runs it on a device machine.
//!
//! `wd stage (wdr)`: the WD-R stage after the loss (built-in features, reference statistics
//! cached; `… reference recomputed`: as for views over the cache budget); `iteration wdr`: an
//! iteration with it.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use gscodec::loss::LossKind;
use gscodec::testkit::{bench_splats, rig_cameras};
use gscodec::train::gpu::wd::{WdConfig, WdStage};
use gscodec::train::gpu::{Gpu, Session};
use gscodec::train::targets::render_targets;
use gscodec_decoder::Image;

fn wait(gpu: &Gpu) {
    gpu.device.poll(wgpu::PollType::wait_indefinitely()).unwrap();
}

/// `(width, height, Gaussians)` cases from `GSC_TRAIN_SIZES`.
fn cases() -> Vec<(u32, u32, usize)> {
    let spec = std::env::var("GSC_TRAIN_SIZES").unwrap_or_else(|_| "200x200:10000,200x200:50000,1280x960:1000000".into());
    spec.split(',')
        .map(|c| {
            let bad = || -> (u32, u32, usize) { panic!("GSC_TRAIN_SIZES: `{c}` is not WxH:N") };
            let Some((size, n)) = c.trim().split_once(':') else { return bad() };
            let Some((w, h)) = size.split_once('x') else { return bad() };
            match (w.parse(), h.parse(), n.parse()) {
                (Ok(w), Ok(h), Ok(n)) => (w, h, n),
                _ => bad(),
            }
        })
        .collect()
}

fn bench_stages(c: &mut Criterion) {
    let Some(gpu) = Gpu::new().unwrap() else {
        eprintln!("SKIP: no GPU adapter");
        return;
    };
    eprintln!("adapter: {}", gpu.adapter_name());
    let only_iteration = std::env::var("GSC_TRAIN_STAGES").is_ok_and(|v| v == "iteration");
    let mut group = c.benchmark_group("train_gpu");
    group.sample_size(10);
    for (w, h, n) in cases() {
        let id = format!("{w}x{h}/{n}");
        let params = bench_splats(n, 2);
        let cam = rig_cameras(2, 4.0, w, h).remove(0);
        // The target: a render of another random scene at small sizes; a flat grey at large ones
        // (the CPU render of a million Gaussians would dominate the set-up; the loss costs the same).
        let image = if n <= 100_000 {
            (*render_targets(&bench_splats(n, 1), &[cam], [1.0; 3]).frames[0].image.get().unwrap()).clone()
        } else {
            Image::filled(w, h, [0.5; 3])
        };
        let target = gpu.storage_init("target", bytemuck::cast_slice(&image.data));
        let mut s = Session::new(&gpu, &params).unwrap();
        drop(params);
        let lr = [1e-5, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4];
        let mut stage = |name: &str, f: &mut dyn FnMut(&mut Session, &mut wgpu::CommandEncoder)| {
            group.bench_with_input(BenchmarkId::new(name, &id), &n, |b, _| {
                b.iter(|| {
                    let mut enc = gpu.device.create_command_encoder(&Default::default());
                    f(&mut s, &mut enc);
                    gpu.queue.submit([enc.finish()]);
                    wait(&gpu);
                })
            });
        };
        // A first iteration sizes the key buffers and the image buffers.
        stage("iteration", &mut |s, enc| {
            s.project(enc, &cam, [1.0; 3], 3).unwrap();
            s.rasterize(enc, &cam).unwrap();
            s.loss(enc, &target, 0.2);
            s.backward(enc, &cam, true);
            s.adam(enc, lr);
        });
        if only_iteration {
            continue;
        }
        stage("project+scan", &mut |s, enc| s.project(enc, &cam, [1.0; 3], 3).unwrap());
        stage("sort+rasterize", &mut |s, enc| s.rasterize(enc, &cam).unwrap());
        stage("loss", &mut |s, enc| s.loss(enc, &target, 0.2));
        stage("backward", &mut |s, enc| s.backward(enc, &cam, true));
        stage("adam", &mut |s, enc| s.adam(enc, lr));
        let wdr = WdConfig::new(LossKind::Wdr, None, None, None, 1);
        let mut wd = WdStage::new(&gpu, wdr, w, h).unwrap();
        let mut wd_uncached = WdStage::new(&gpu, WdConfig { cache_bytes: 0, ..wdr }, w, h).unwrap();
        stage("wd stage (wdr)", &mut |s, enc| wd.record(s, enc, 0, &target, true).unwrap());
        stage("wd stage (wdr), reference recomputed", &mut |s, enc| wd_uncached.record(s, enc, 0, &target, true).unwrap());
        stage("iteration wdr", &mut |s, enc| {
            s.project(enc, &cam, [1.0; 3], 3).unwrap();
            s.rasterize(enc, &cam).unwrap();
            s.loss(enc, &target, 0.2);
            wd.record(s, enc, 0, &target, true).unwrap();
            s.backward(enc, &cam, true);
            s.adam(enc, lr);
        });
    }
    group.finish();
}

criterion_group!(benches, bench_stages);
criterion_main!(benches);

//! GPU training iteration time by stage (feature `gpu`): one iteration at 200×200 with 10k and 50k
//! Gaussians (SH degree 3), the scene of `benches/train.rs` (the CPU counterpart). Each stage is
//! submitted and waited for on its own, so the sum is a little more than a pipelined iteration.
//! Skips (prints why) when there is no adapter.

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use gscodec::testkit::{random_splats, rig_cameras};
use gscodec::train::gpu::{Gpu, Session};
use gscodec::train::targets::render_targets;

fn wait(gpu: &Gpu) {
    gpu.device.poll(wgpu::PollType::wait_indefinitely()).unwrap();
}

fn bench_stages(c: &mut Criterion) {
    let Some(gpu) = Gpu::new().unwrap() else {
        eprintln!("SKIP: no GPU adapter");
        return;
    };
    eprintln!("adapter: {}", gpu.adapter_name());
    let mut group = c.benchmark_group("train_gpu_200x200");
    group.sample_size(10);
    for n in [10_000usize, 50_000] {
        let shrink = (n as f32 / 120.0).cbrt().ln();
        let mut truth = random_splats(n, 1, 1).with_sh_degree(3);
        truth.log_scales.iter_mut().for_each(|l| *l = l.map(|v| v - shrink));
        let ds = render_targets(&truth, &rig_cameras(2, 4.0, 200, 200), [1.0; 3]);
        let mut params = random_splats(n, 1, 2).with_sh_degree(3);
        params.log_scales.iter_mut().for_each(|l| *l = l.map(|v| v - shrink));
        let frame = &ds.frames[0];
        let cam = frame.camera;
        let target = gpu.storage_init("target", bytemuck::cast_slice(&frame.image.get().unwrap().data));
        let mut s = Session::new(&gpu, &params).unwrap();
        let pairs = s.project(&cam, [1.0; 3], 3).unwrap().pairs;
        let lr = [1e-5, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4];
        group.bench_with_input(BenchmarkId::new("project+scan+readback", n), &n, |b, _| b.iter(|| s.project(&cam, [1.0; 3], 3).unwrap()));
        let mut stage = |name: &str, f: &mut dyn FnMut(&mut Session, &mut wgpu::CommandEncoder)| {
            group.bench_with_input(BenchmarkId::new(name, n), &n, |b, _| {
                b.iter(|| {
                    let mut enc = gpu.device.create_command_encoder(&Default::default());
                    f(&mut s, &mut enc);
                    gpu.queue.submit([enc.finish()]);
                    wait(&gpu);
                })
            });
        };
        stage("sort+rasterize", &mut |s, enc| s.rasterize(enc, &cam, pairs).unwrap());
        stage("loss", &mut |s, enc| s.loss(enc, &target, 0.2));
        stage("backward", &mut |s, enc| s.backward(enc, &cam, true));
        stage("adam", &mut |s, enc| s.adam(enc, lr));
        stage("iteration", &mut |s, enc| {
            s.rasterize(enc, &cam, pairs).unwrap();
            s.loss(enc, &target, 0.2);
            s.backward(enc, &cam, true);
            s.adam(enc, lr);
        });
    }
    group.finish();
}

criterion_group!(benches, bench_stages);
criterion_main!(benches);

//! The WD-R stage's cost on the GPU trainer against the L1+SSIM loss and a whole iteration, with
//! the stages timed in interleaved rounds (so a loaded machine's drift hits all of them alike);
//! prints the median of each. The scene is `benches/train_gpu.rs`'s (200×200, 10k Gaussians).
//!
//! `cargo run --features gpu --example wd_gpu_cost [-- ROUNDS]`

use gscodec::loss::LossKind;
use gscodec::testkit::{bench_splats, rig_cameras};
use gscodec::train::gpu::wd::{WdConfig, WdStage};
use gscodec::train::gpu::{Gpu, Session};
use gscodec::train::targets::render_targets;
use std::time::Instant;

fn main() {
    let rounds: usize = std::env::args().nth(1).and_then(|a| a.parse().ok()).unwrap_or(15);
    let gpu = Gpu::new().unwrap().expect("a GPU adapter (lavapipe will do)");
    eprintln!("adapter: {}", gpu.adapter_name());
    let n = 10_000usize;
    let ds = render_targets(&bench_splats(n, 1), &rig_cameras(2, 4.0, 200, 200), [1.0; 3]);
    let params = bench_splats(n, 2);
    let cam = ds.frames[0].camera;
    let target = gpu.storage_init("target", bytemuck::cast_slice(&ds.frames[0].image.get().unwrap().data));
    let mut s = Session::new(&gpu, &params).unwrap();
    let mut enc = gpu.device.create_command_encoder(&Default::default());
    s.project(&mut enc, &cam, [1.0; 3], 3).unwrap();
    s.rasterize(&mut enc, &cam).unwrap();
    gpu.queue.submit([enc.finish()]);
    let lr = [1e-5, 1e-4, 1e-4, 1e-4, 1e-4, 1e-4];
    let config = WdConfig::new(LossKind::Wdr, None, None, None, 1);
    let mut cached = WdStage::new(&gpu, config, cam.width, cam.height).unwrap();
    let mut uncached = WdStage::new(&gpu, WdConfig { cache_bytes: 0, ..config }, cam.width, cam.height).unwrap();

    let names = ["L1+SSIM loss", "WD-R stage (cached reference)", "WD-R stage (reference recomputed)", "iteration l1ssim", "iteration wdr"];
    let mut times: Vec<Vec<f64>> = vec![Vec::new(); names.len()];
    for round in 0..=rounds {
        for (k, t) in times.iter_mut().enumerate() {
            let mut enc = gpu.device.create_command_encoder(&Default::default());
            let t0 = Instant::now();
            if k >= 3 {
                s.project(&mut enc, &cam, [1.0; 3], 3).unwrap();
                s.rasterize(&mut enc, &cam).unwrap();
            }
            s.loss(&mut enc, &target, 0.2);
            match k {
                1 | 4 => cached.record(&s, &mut enc, 0, &target, true).unwrap(),
                2 => uncached.record(&s, &mut enc, 0, &target, true).unwrap(),
                _ => {}
            }
            if k >= 3 {
                s.backward(&mut enc, &cam, true);
                s.adam(&mut enc, lr);
            }
            gpu.queue.submit([enc.finish()]);
            gpu.device.poll(wgpu::PollType::wait_indefinitely()).unwrap();
            // Round 0 warms up (first use fills the cached reference).
            if round > 0 {
                t.push(t0.elapsed().as_secs_f64() * 1e3);
            }
        }
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let m: Vec<f64> = times.iter_mut().map(median).collect();
    // Rows 1 and 2 include the L1+SSIM loss they follow; the stage alone is the difference.
    for (name, ms) in names.iter().zip(&m) {
        println!("{name:36} {ms:9.1} ms (median of {rounds})");
    }
    println!("WD-R stage alone, cached reference:     {:9.1} ms", m[1] - m[0]);
    println!("WD-R stage alone, reference recomputed: {:9.1} ms", m[2] - m[0]);
    println!("iteration wdr / iteration l1ssim:       {:9.2}", m[4] / m[3]);
}

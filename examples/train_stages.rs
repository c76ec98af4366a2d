//! Per-stage wall time of one training iteration (project, sort, rasterize, loss, backward,
//! optimiser) at 200x200 for 10k and 50k Gaussians.
//!
//! `cargo run --release --example train_stages [N_ITERS]`
//!
//! Prints wall time and, on Linux, CPU time (summed over the process's threads from
//! `/proc/self/task/*/schedstat`), which is the meaningful figure on a shared, loaded machine.

use gscodec::loss::L1Ssim;
use gscodec::raster;
use gscodec::rate::group::Group;
use gscodec::testkit::{random_splats, rig_cameras};
use gscodec::train::adam::Adam;
use gscodec::train::targets::render_targets;
use gscodec_decoder::RenderOptions;
use std::time::Instant;

/// CPU time of all threads of this process, seconds (0 where /proc is unavailable).
fn cpu_seconds() -> f64 {
    let Ok(dir) = std::fs::read_dir("/proc/self/task") else { return 0.0 };
    dir.filter_map(|e| std::fs::read_to_string(e.ok()?.path().join("schedstat")).ok())
        .filter_map(|s| s.split_whitespace().next()?.parse::<u64>().ok())
        .sum::<u64>() as f64
        * 1e-9
}

fn main() {
    let iters: usize = std::env::args().nth(1).and_then(|a| a.parse().ok()).unwrap_or(20);
    for n in [10_000usize, 50_000] {
        // A lego-like density: many small Gaussians in the unit ball, seen from 4 units away.
        let mut truth = random_splats(n, 1, 1);
        let shrink = (n as f32 / 120.0).cbrt().ln();
        truth.log_scales.iter_mut().for_each(|l| *l = l.map(|v| v - shrink));
        let cams = rig_cameras(4, 4.0, 200, 200);
        let ds = render_targets(&truth, &cams, [1.0; 3]);
        let mut params = random_splats(n, 1, 2);
        params.log_scales.iter_mut().for_each(|l| *l = l.map(|v| v - shrink));
        let mut adam = Adam::new(&params);
        let opts = RenderOptions { background: [1.0; 3], max_sh_degree: 1 };
        let loss = L1Ssim::default();
        let mut t = [0.0f64; 6];
        let mut cpu = [0.0f64; 4];
        for it in 0..iters {
            let f = &ds.frames[it % ds.frames.len()];
            let c0 = cpu_seconds();
            let (img, st, ft) = raster::forward_timed(&params, &f.camera, &opts);
            let c1 = cpu_seconds();
            let t0 = Instant::now();
            let (_, dl) = loss.eval(&img, &f.image.get().unwrap());
            let t1 = Instant::now();
            let c2 = cpu_seconds();
            let g = raster::backward(&params, &st, &dl);
            let t2 = Instant::now();
            let c3 = cpu_seconds();
            adam.step(&mut params, &g.params, |grp| if grp == Group::Position { 1e-4 } else { 1e-3 });
            let t3 = Instant::now();
            let c4 = cpu_seconds();
            for (acc, v) in t.iter_mut().zip([
                ft.project,
                ft.sort,
                ft.rasterize,
                (t1 - t0).as_secs_f64(),
                (t2 - t1).as_secs_f64(),
                (t3 - t2).as_secs_f64(),
            ]) {
                *acc += v;
            }
            for (acc, v) in cpu.iter_mut().zip([c1 - c0, c2 - c1, c3 - c2, c4 - c3]) {
                *acc += v;
            }
        }
        let ms = t.map(|v| 1e3 * v / iters as f64);
        let cms = cpu.map(|v| 1e3 * v / iters as f64);
        println!(
            "{n:>6} Gaussians, 200x200, {} threads: project {:.1} ms, sort {:.1} ms, rasterize {:.1} ms, loss {:.1} ms, backward {:.1} ms, optimiser {:.1} ms, total {:.1} ms/iter",
            rayon::current_num_threads(),
            ms[0], ms[1], ms[2], ms[3], ms[4], ms[5], ms.iter().sum::<f64>()
        );
        println!(
            "{n:>6} Gaussians, CPU time: forward {:.1} ms, loss {:.1} ms, backward {:.1} ms, optimiser {:.1} ms, total {:.1} CPU-ms/iter",
            cms[0],
            cms[1],
            cms[2],
            cms[3],
            cms.iter().sum::<f64>()
        );
    }
}

//! The GPU trainer against its CPU oracle (feature `gpu`; runs on Mesa's lavapipe in CI and skips
//! with a message when there is no adapter at all):
//! - forward image and every parameter gradient of the rasterizer + projection backward against
//!   `gscodec::raster::{forward, backward}` on small random scenes (several seeds) and DESIGN §8's
//!   extreme cases (tiny and view-filling Gaussians, Gaussians at the near plane, opacity logits
//!   ±100); the CPU backward is itself checked against f64 finite differences in raster_grad.rs;
//! - L1 + SSIM loss value and gradient against `gscodec::loss::L1Ssim`;
//! - 300 training iterations on a small synthetic dataset: held-out PSNR within 0.5 dB of the CPU
//!   trainer, the same report shape (points, evaluations), similar scene size;
//! - WD (built-in features) value and image gradient, and the whole WD-R loss (fixed and
//!   normalised γ, warm-up), against `gscodec::loss::{wd, wdr}`; 60 WD-R iterations on
//!   `samples/tiny` through `--backend gpu`: held-out PSNR within 0.3 dB of the CPU trainer;
//! - one shared training device per process, on which two trainings run at once.
//!
//! Tolerances: per value `|gpu − cpu| ≤ ATOL·max|cpu over the group| + RTOL·|cpu|` with
//! ATOL = 1e-3, RTOL = 1e-3. The GPU sums per-pixel terms with float atomics in any order and
//! computes the conic derivative in f32 (the CPU in f64), so relative differences of ~1e-5 are
//! expected; a missing or wrong term gives O(1) differences. Any NaN fails.
#![cfg(feature = "gpu")]

use glam::{Mat3, Quat, Vec3};
use gscodec::encoder::{Backend, LossSpec, TrainJob};
use gscodec::io::{load_dataset, LoadOptions, Split};
use gscodec::loss::features::pyramid::Pyramid;
use gscodec::loss::wd::Sigma;
use gscodec::loss::wdr::{self, WdDistortion, WdrLoss};
use gscodec::loss::{FeatureSpec, ImageLoss, L1Ssim, LossKind};
use gscodec::raster;
use gscodec::testkit::{random_splats, rig_cameras};
use gscodec::train::gpu::{self, Gpu, GpuLoss};
use gscodec::train::targets::render_targets;
use gscodec::train::{RunOptions, TrainConfig, TrainReport};
use gscodec_decoder::{Camera, Image, RenderOptions, Splats};
use std::path::Path;

const ATOL: f32 = 1e-3;
const RTOL: f32 = 1e-3;

fn device() -> Option<Gpu> {
    match Gpu::new().expect("an adapter exists but the GPU trainer could not start") {
        Some(g) => {
            eprintln!("adapter: {} (subgroups: {}, timestamps: {})", g.adapter_name(), g.subgroups, g.timestamps);
            Some(g)
        }
        None => {
            gscodec::testkit::skip("no GPU adapter available; install mesa-vulkan-drivers for lavapipe");
            None
        }
    }
}

/// Deterministic uniform numbers in [0, 1).
struct Lcg(u64);
impl Lcg {
    fn next(&mut self) -> f32 {
        self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((self.0 >> 40) as f32) / (1u64 << 24) as f32
    }
    fn range(&mut self, a: f32, b: f32) -> f32 {
        a + (b - a) * self.next()
    }
}

/// `n` random Gaussians of SH degree 3 in a ball of radius `r` around the origin.
fn random_scene(n: usize, seed: u64, r: f32, log_scale: (f32, f32), logit: (f32, f32)) -> Splats {
    let mut g = Lcg(seed * 7919 + 17);
    let mut s = Splats::new(3);
    for _ in 0..n {
        let pos = [g.range(-r, r), g.range(-r, r), g.range(-r, r)];
        let ls = [g.range(log_scale.0, log_scale.1), g.range(log_scale.0, log_scale.1), g.range(log_scale.0, log_scale.1)];
        let q = [g.range(-1.0, 1.0), g.range(-1.0, 1.0), g.range(-1.0, 1.0), g.range(-1.0, 1.0)];
        let dc = [g.range(-1.5, 1.5), g.range(-1.5, 1.5), g.range(-1.5, 1.5)];
        let rest: Vec<f32> = (0..45).map(|_| g.range(-0.3, 0.3)).collect();
        s.push(pos, ls, q, g.range(logit.0, logit.1), dc, &rest);
    }
    s
}

fn camera(w: u32, h: u32, eye: Vec3) -> Camera {
    let mut c = Camera::look_at(eye, Vec3::ZERO, Vec3::Y, w, h, 0.9);
    c.znear = 0.2;
    c
}

fn groups(s: &Splats) -> [(&'static str, Vec<f32>); 6] {
    [
        ("position", s.positions.as_flattened().to_vec()),
        ("log_scale", s.log_scales.as_flattened().to_vec()),
        ("rotation", s.rotations.as_flattened().to_vec()),
        ("opacity", s.opacity_logits.clone()),
        ("sh_dc", s.sh_dc.as_flattened().to_vec()),
        ("sh_rest", s.sh_rest.clone()),
    ]
}

fn assert_close(what: &str, gpu: &[f32], cpu: &[f32]) {
    assert_eq!(gpu.len(), cpu.len(), "{what}: lengths differ");
    let scale = cpu.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    let mut worst = (0.0f32, 0usize);
    for (i, (g, c)) in gpu.iter().zip(cpu).enumerate() {
        assert!(g.is_finite(), "{what}[{i}]: GPU value {g} is not finite (CPU {c})");
        let err = (g - c).abs() / (ATOL * scale + RTOL * c.abs()).max(f32::MIN_POSITIVE);
        if err > worst.0 {
            worst = (err, i);
        }
    }
    let i = worst.1;
    eprintln!("  {what}: max|cpu| {scale:.3e}, worst error {:.3} of the tolerance at [{i}]", worst.0);
    assert!(worst.0 <= 1.0, "{what}[{i}]: GPU {} vs CPU {} (max|cpu| {scale:e})", gpu[i], cpu[i]);
}

/// Renders and backpropagates a random image gradient on both; compares everything.
fn compare_backward(gpu: &Gpu, name: &str, s: &Splats, cam: &Camera, degree: u8, bg: [f32; 3], seed: u64) {
    eprintln!("{name}: {} Gaussians, {}x{}, degree {degree}", s.len(), cam.width, cam.height);
    let opts = RenderOptions { background: bg, max_sh_degree: degree };
    let (img, state) = raster::forward(s, cam, &opts);
    let mut g = Lcg(seed + 99);
    let dl: Vec<f32> = (0..img.data.len()).map(|_| g.range(-1.0, 1.0) / img.data.len() as f32).collect();
    let cpu = raster::backward(s, &state, &dl);
    let (gimg, grads, norm) = gpu::render_backward(gpu, s, cam, &opts, &dl).unwrap();
    let drawn = state.projected.iter().filter(|p| p.radius > 0.0).count();
    assert!(drawn > 0, "{name}: nothing drawn, the case tests nothing");
    let max_diff = img.data.iter().zip(&gimg.data).fold(0.0f32, |m, (a, b)| m.max((a - b).abs()));
    eprintln!("  image: max |gpu - cpu| = {max_diff:.2e} ({drawn} Gaussians drawn)");
    assert!(gimg.data.iter().all(|v| v.is_finite()), "{name}: non-finite pixel");
    assert!(max_diff < 1e-4, "{name}: images differ by {max_diff}");
    for ((gname, gv), (_, cv)) in groups(&grads).iter().zip(groups(&cpu.params).iter()) {
        assert_close(&format!("{name} {gname}"), gv, cv);
    }
    assert_close(&format!("{name} |dL/dmean2d|"), &norm, &cpu.mean2d_ndc_norm);
}

#[test]
fn gradients_match_cpu_on_random_scenes() {
    let Some(gpu) = device() else { return };
    for seed in 0..4u64 {
        let s = random_scene(150, seed, 1.0, (-3.5, -1.5), (-3.0, 3.0));
        let eye = Quat::from_rotation_y(seed as f32) * Vec3::new(0.0, 0.6, 4.0);
        // 72×40: partial tiles at the right and bottom edges.
        let cam = camera(72, 40, eye);
        let bg = if seed % 2 == 0 { [1.0; 3] } else { [0.1, 0.4, 0.7] };
        compare_backward(&gpu, &format!("seed {seed}"), &s, &cam, (seed % 4) as u8, bg, seed);
    }
}

#[test]
fn gradients_match_cpu_in_extreme_cases() {
    let Some(gpu) = device() else { return };
    let cam = camera(48, 48, Vec3::new(0.0, 0.0, 3.0));
    // Tiny Gaussians (sub-pixel: the 0.3 dilation dominates).
    let tiny = random_scene(200, 11, 0.8, (-9.0, -7.0), (-2.0, 4.0));
    compare_backward(&gpu, "tiny", &tiny, &cam, 3, [1.0; 3], 1);
    // View-filling Gaussians (a few, large and close).
    let big = random_scene(6, 12, 0.5, (0.0, 0.8), (-1.0, 1.0));
    compare_backward(&gpu, "view-filling", &big, &cam, 2, [0.0; 3], 2);
    // At the near plane: centres spread around z = znear in camera space.
    let mut near = random_scene(120, 13, 0.3, (-3.0, -2.0), (0.0, 3.0));
    for (i, p) in near.positions.iter_mut().enumerate() {
        p[2] = 3.0 - cam.znear + (i as f32 / 120.0 - 0.5) * 0.2; // camera depth znear ± 0.1
    }
    compare_backward(&gpu, "near plane", &near, &cam, 1, [1.0; 3], 3);
    // Opacity logits ±100 (saturated sigmoid, clamped alpha).
    let mut sat = random_scene(100, 14, 0.8, (-3.0, -2.0), (0.0, 0.0));
    for (i, l) in sat.opacity_logits.iter_mut().enumerate() {
        *l = if i % 2 == 0 { 100.0 } else { -100.0 };
    }
    compare_backward(&gpu, "opacity ±100", &sat, &cam, 3, [1.0; 3], 4);
    // A degenerate rotation (zero quaternion renders as the identity, zero gradient).
    let mut zq = random_scene(30, 15, 0.8, (-3.0, -2.0), (0.0, 2.0));
    zq.rotations[0] = [0.0; 4];
    compare_backward(&gpu, "zero quaternion", &zq, &cam, 0, [1.0; 3], 5);
}

#[test]
fn loss_matches_cpu() {
    let Some(gpu) = device() else { return };
    for (seed, (w, h)) in [(0u64, (37u32, 23u32)), (1, (64, 64))] {
        let mut g = Lcg(seed + 5);
        let a = Image { width: w, height: h, data: (0..w * h * 3).map(|_| g.next()).collect() };
        // A target correlated with `a` (SSIM away from 0).
        let b = Image { width: w, height: h, data: a.data.iter().map(|v| (v * 0.8 + 0.2 * g.next()).min(1.0)).collect() };
        let (cl, cg) = L1Ssim::default().eval(&a, &b);
        let (gl, gg) = gpu::loss_and_grad(&gpu, &a, &b, 0.2).unwrap();
        eprintln!("{w}x{h}: loss GPU {gl:.7} CPU {cl:.7}");
        assert!((gl - cl).abs() <= 1e-5 + 1e-4 * cl.abs(), "loss GPU {gl} vs CPU {cl}");
        assert_close(&format!("{w}x{h} dL/dimage"), &gg, &cg);
    }
}

/// A random distortion gradient of the shape of `s` (values ±`scale`).
fn random_gradient(s: &Splats, seed: u64, scale: f32) -> Splats {
    let mut g = Lcg(seed + 31);
    let mut r = s.clone();
    let mut fill = |v: &mut [f32]| v.iter_mut().for_each(|x| *x = g.range(-scale, scale));
    fill(r.positions.as_flattened_mut());
    fill(r.log_scales.as_flattened_mut());
    fill(r.rotations.as_flattened_mut());
    fill(&mut r.opacity_logits);
    fill(r.sh_dc.as_flattened_mut());
    fill(&mut r.sh_rest);
    r
}

/// The GPU rate term against `RateTerm` (the CPU oracle, f64 densities, itself checked against
/// finite differences in src/rate/term.rs): the quantised render values, `w·R`, the gradient
/// (distortion + rate) of every group, ∂(D + w·R)/∂ln s per group and the steps after one Adam
/// step, after the first call (densities fitted) and after the third (densities and steps updated
/// twice). Scenes of SH degree 1 and 3 with steps learned, degree 2 with fixed steps; opacity
/// logits spanning the "kept" factor's transition. Tolerances: the gradients as above (f32 vs
/// f64); `w·R` and the steps 1e-4 relative; ∂/∂ln s 1e-3 of the largest group's plus 1e-3
/// relative (sums of thousands of f32 terms of both signs).
#[test]
fn rate_term_matches_cpu() {
    use gscodec::rate::group::Group;
    use gscodec::rate::term::RateTerm;
    use gscodec::rate::{Lambda, Steps};
    let Some(gpu) = device() else { return };
    for (seed, degree, learn, deadzone) in [(1u64, 1u8, true, 0.0), (2, 3, true, 0.3), (3, 2, false, 0.2)] {
        let s = random_scene(400, seed, 1.0, (-5.0, -1.0), (-8.0, 4.0)).with_sh_degree(degree);
        let dist = random_gradient(&s, seed, 1e-3);
        let steps = Steps { rest_deadzone: deadzone, ..Steps::default() };
        let mut term = RateTerm::new(Lambda::new(1e5).unwrap(), steps, 0.02);
        term.learn_steps = learn;
        for calls in [1usize, 3] {
            let name = format!("degree {degree}, learn {learn}, dead zone {deadzone}, call {calls}");
            let mut cpu = term.clone();
            let (mut value, mut grad, mut rendered) = (0.0, dist.clone(), s.clone());
            for it in 0..calls {
                rendered = cpu.render_params(&s, it).unwrap();
                grad = dist.clone();
                value = cpu.rate_and_grad(&s, &mut grad, it);
            }
            let (gv, gg, state, grendered) = gpu::rate_and_grad(&gpu, &s, &dist, term.clone(), calls).unwrap();
            eprintln!("{name}: w·R GPU {gv:.6e} CPU {value:.6e}, bits {:.1}", cpu.last_bits);
            assert!((gv - value).abs() <= 1e-4 * value.abs(), "{name}: w·R GPU {gv} vs CPU {value}");
            assert!((state.bits - cpu.last_bits).abs() <= 1e-4 * cpu.last_bits, "{name}: bits {} vs {}", state.bits, cpu.last_bits);
            // Rounding to the step: the same bin except where v/s sits within float error of a half
            // (the learned steps themselves agree to float rounding).
            let (a, b) = (gscodec::train::gpu::session::to_records(&grendered), gscodec::train::gpu::session::to_records(&rendered));
            let differ = a.iter().zip(&b).filter(|(x, y)| (*x - *y).abs() > 1e-4 * y.abs().max(1e-3)).count();
            assert!(differ <= a.len() / 1000, "{name}: {differ} of {} quantised values differ", a.len());
            for ((gname, gv), (_, cv)) in groups(&gg).iter().zip(groups(&grad).iter()) {
                assert_close(&format!("{name} {gname}"), gv, cv);
            }
            let top = Group::ALL.iter().fold(0.0f64, |m, &g| m.max(cpu.last_step_gradient[g].abs()));
            for g in Group::ALL {
                let (a, c) = (state.d_log_step[g], cpu.last_step_gradient[g]);
                assert!((a - c).abs() <= 1e-3 * top + 1e-3 * c.abs(), "{name}: ∂/∂ln s of {g:?}: GPU {a} vs CPU {c}");
                let (sa, sc) = (state.steps.of(g), cpu.steps.of(g));
                assert!((sa - sc).abs() <= 1e-4 * sc, "{name}: step of {g:?}: GPU {sa} vs CPU {sc}");
            }
            if learn {
                assert_ne!(cpu.steps, steps, "{name}: the steps did not move; the comparison says nothing");
            }
        }
    }
}

/// As the CPU trainer (tests/train.rs): with a rate term the held-out PSNR reported, at an
/// evaluation and at the end, is of the scene as training renders it (quantised with the steps
/// the GPU holds), not of the raw parameters.
#[test]
fn held_out_psnr_is_of_the_quantised_scene_under_a_rate_term() {
    use gscodec::rate::term::RateTerm;
    use gscodec::rate::{Lambda, Steps};
    let Some(gpu) = device() else { return };
    let ds = toy_dataset();
    let steps = Steps { sh_dc: 0.15, opacity: 0.6, scale: 0.3, ..Steps::default() };
    let term = || RateTerm::new(Lambda::new(1.0).unwrap(), steps, 1.0 / 255.0);
    let cfg = TrainConfig { iters: 20, seed: 5, init_points: 300, densify: false, eval_interval: 10, ..Default::default() };
    let (out, report) =
        gpu::train_with(&gpu, &ds, None, &cfg, &GpuLoss::default(), Some(term()), &mut |_| {}, &RunOptions::default()).unwrap();
    let test = ds.split(Split::Test);
    let psnr = |s: &Splats| gscodec::metrics::view::mean_psnr_ssim(s, &test, ds.background).unwrap().unwrap().0;
    let (reported, of_quantised, of_raw) = (report.test_psnr.unwrap(), psnr(&term().render_params(&out, cfg.iters).unwrap()), psnr(&out));
    eprintln!("reported {reported:.4} dB, quantised {of_quantised:.4}, raw {of_raw:.4}");
    assert_eq!(reported.to_bits(), of_quantised.to_bits());
    assert!((of_raw - of_quantised).abs() > 1e-3, "raw {of_raw} and quantised {of_quantised} agree: the test says nothing");
}

fn tiny_dataset() -> gscodec::io::Dataset {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/tiny");
    load_dataset(&root, &LoadOptions::default()).unwrap()
}

/// 16 views (32×32, white background) of a 120-Gaussian toy scene: small enough for lavapipe.
fn toy_dataset() -> gscodec::io::Dataset {
    let scene = random_splats(120, 1, 3);
    render_targets(&scene, &rig_cameras(16, 3.5, 32, 32), [1.0; 3])
}

#[test]
fn training_matches_cpu_psnr() {
    let Some(gpu) = device() else { return };
    let ds = toy_dataset();
    assert!(!ds.split(Split::Test).is_empty());
    let cfg = TrainConfig { iters: 300, seed: 3, init_points: 500, eval_interval: 100, ..Default::default() };
    let (cpu_s, cpu_r): (Splats, TrainReport) =
        gscodec::train::train(&ds, None, &cfg, Box::new(L1Ssim::default()), None, &mut |_| {}).unwrap();
    let mut calls = 0;
    let (gpu_s, gpu_r) = gpu::train_on(&gpu, &ds, None, &cfg, &GpuLoss::default(), &mut |p| {
        calls += 1;
        assert_eq!(p.iteration, calls);
    })
    .unwrap();
    assert_eq!(calls, 300);
    let (pc, pg) = (cpu_r.test_psnr.unwrap(), gpu_r.test_psnr.unwrap());
    eprintln!(
        "held-out PSNR: CPU {pc:.2} dB ({} Gaussians, {:.1} s), GPU {pg:.2} dB ({} Gaussians, {:.1} s, stages {:?})",
        cpu_s.len(),
        cpu_r.train_seconds,
        gpu_s.len(),
        gpu_r.train_seconds,
        gpu_r.stages
    );
    assert!(pc > 20.0, "the CPU run learned little ({pc:.2} dB): the comparison would say nothing");
    // The GPU trainer's sums (atomic f32 adds in the backward pass) run in a different order
    // from run to run, so its PSNR varies: on lavapipe (Mesa llvmpipe, LLVM 15) this run gave
    // 27.04 dB alone and 27.20 dB inside the full suite, against the CPU's fixed 26.87 dB. 0.5 dB
    // leaves room for that spread; a wrong gradient costs several dB.
    assert!((pc - pg).abs() <= 0.5, "GPU {pg:.2} dB vs CPU {pc:.2} dB");
    assert!(gpu_r.points.iter().all(|p| p.loss.is_finite()), "{:?}", gpu_r.points);
    assert_eq!(gpu_r.points.len(), cpu_r.points.len());
    assert!(gpu_r.points.iter().filter(|p| p.test_psnr.is_some()).count() == 3, "evaluations at 100, 200 and the end");
    // Same schedule, same densification rules: similar scene sizes.
    let (a, b) = (cpu_s.len() as f64, gpu_s.len() as f64);
    assert!((a - b).abs() <= 0.1 * a, "{a} vs {b} Gaussians");
    assert_eq!(gpu_r.loss, "l1ssim");
    assert_eq!((cpu_r.backend, gpu_r.backend), ("cpu", "gpu"));
    // The key buffers grew ahead of the pair count: no frame lost pairs.
    assert_eq!((cpu_r.truncated_frames, gpu_r.truncated_frames), (0, 0));
    // Stage times are measured (timestamps or wall time).
    let st = gpu_r.stages;
    assert!(st.rasterize > 0.0 && st.project + st.sort + st.rasterize + st.loss + st.backward + st.optimiser <= gpu_r.train_seconds * 1.5);
}

/// No read-back per iteration: over 50 iterations (densification and evaluations off) the GPU
/// trainer waits for the GPU once for the first frame's pair count (to size the key buffers),
/// once for the scalars at iteration 32 (`READ_EVERY`), once for the rest at the end and once for
/// the trained scene; the report still has every point's mean loss.
#[test]
fn fifty_iterations_read_back_four_times() {
    let Some(gpu) = device() else { return };
    let ds = toy_dataset();
    let cfg = TrainConfig { iters: 50, seed: 1, init_points: 300, eval_interval: 0, densify: false, ..Default::default() };
    let before = gpu.readbacks();
    let (_, r) = gpu::train_on(&gpu, &ds, None, &cfg, &GpuLoss::default(), &mut |_| {}).unwrap();
    let reads = gpu.readbacks() - before;
    assert_eq!(gpu::READ_EVERY, 32);
    assert_eq!(reads, 4, "read-backs in 50 iterations");
    assert_eq!(r.points.len(), 50, "a point per iteration (iters / 500 < 1)");
    assert!(r.points.iter().all(|p| p.loss.is_finite() && p.loss > 0.0), "{:?}", r.points);
    assert!(r.stages.rasterize > 0.0 || !gpu.timestamps);
}

/// The process's shared training device (what `--backend gpu|auto` trains on): one device,
/// whoever asks, and two trainings at once on it (a sweep's `--jobs`) both run to the end.
#[test]
fn trainings_share_one_device_and_run_at_once() {
    if device().is_none() {
        return;
    }
    let a = Gpu::shared().unwrap().expect("an adapter exists");
    let b = Gpu::shared().unwrap().expect("an adapter exists");
    assert!(std::sync::Arc::ptr_eq(&a, &b), "one device per process");
    let ds = toy_dataset();
    let reports: Vec<TrainReport> = std::thread::scope(|s| {
        let runs: Vec<_> = [1u64, 2]
            .into_iter()
            .map(|seed| {
                let (gpu, ds) = (a.clone(), &ds);
                s.spawn(move || {
                    let cfg = TrainConfig { iters: 40, seed, init_points: 300, eval_interval: 0, densify: false, ..Default::default() };
                    gpu::train_on(&gpu, ds, None, &cfg, &GpuLoss::default(), &mut |_| {}).unwrap().1
                })
            })
            .collect();
        runs.into_iter().map(|r| r.join().unwrap()).collect()
    });
    for r in &reports {
        assert_eq!((r.backend, r.points.len()), ("gpu", 40));
        assert!(r.points.iter().all(|p| p.loss.is_finite() && p.loss > 0.0), "{:?}", r.points);
        assert!(r.test_psnr.is_some_and(|p| p.is_finite() && p > 5.0), "{:?}", r.test_psnr);
    }
}

/// Checkpoints on the GPU backend, in the CPU trainer's format: 300 iterations on the toy dataset
/// stopped after iteration 150 (`stop_after`, as Ctrl-C does) and resumed continue the run — the
/// resumed run starts at 151, its report has the uninterrupted run's points (iterations and
/// evaluations), its Gaussian count is within 10 % and its held-out PSNR within 0.3 dB of an
/// uninterrupted GPU run. Not bit-exact: GPU training is not (float atomics). The CPU trainer
/// resumes the same checkpoint too (one format).
#[test]
fn a_resumed_gpu_run_continues() {
    use gscodec::train::RunOptions;
    let Some(gpu) = device() else { return };
    let ds = toy_dataset();
    let cfg = TrainConfig { iters: 300, seed: 3, init_points: 500, eval_interval: 100, ..Default::default() };
    let (whole_s, whole) = gpu::train_on(&gpu, &ds, None, &cfg, &GpuLoss::default(), &mut |_| {}).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let stop = RunOptions { checkpoint: Some(dir.path().to_path_buf()), stop_after: Some(150), ..Default::default() };
    let e = gpu::train_with(&gpu, &ds, None, &cfg, &GpuLoss::default(), None, &mut |_| {}, &stop).unwrap_err();
    assert!(e.to_string().contains("interrupted after iteration 150 of 300"), "{e}");
    let resume = RunOptions { resume: Some(dir.path().to_path_buf()), ..Default::default() };
    let mut first = None;
    let (s, r) =
        gpu::train_with(&gpu, &ds, None, &cfg, &GpuLoss::default(), None, &mut |p| _ = *first.get_or_insert(p.iteration), &resume).unwrap();
    assert_eq!(first, Some(151));
    let its = |r: &TrainReport| r.points.iter().map(|p| (p.iteration, p.test_psnr.is_some())).collect::<Vec<_>>();
    assert_eq!(its(&r), its(&whole));
    assert!(r.points.iter().all(|p| p.loss.is_finite()));
    let (pw, pr) = (whole.test_psnr.unwrap(), r.test_psnr.unwrap());
    eprintln!("uninterrupted: {pw:.2} dB, {} Gaussians; resumed at 151: {pr:.2} dB, {} Gaussians", whole_s.len(), s.len());
    assert!((pw - pr).abs() <= 0.3, "resumed {pr:.2} dB vs uninterrupted {pw:.2} dB");
    let (a, b) = (whole_s.len() as f64, s.len() as f64);
    assert!((a - b).abs() <= 0.1 * a, "{a} vs {b} Gaussians");
    // The CPU trainer reads the GPU's checkpoint (the same format and run fingerprint).
    let cpu = gscodec::train::train_with(&ds, None, &cfg, Box::new(L1Ssim::default()), None, &mut |_| {}, &resume).unwrap();
    assert!((cpu.1.test_psnr.unwrap() - pw).abs() <= 0.5, "CPU resume of the GPU checkpoint: {:?}", cpu.1.test_psnr);
    // A run with another loss is another run: its resume is refused.
    let wdr = GpuLoss::from(gscodec::loss::LossKind::Wdr);
    let e = gpu::train_with(&gpu, &ds, None, &cfg, &wdr, None, &mut |_| {}, &resume).unwrap_err();
    assert!(e.to_string().contains("the checkpoint is of another run"), "{e}");
}

#[test]
fn unsupported_losses_are_input_errors() {
    let ds = tiny_dataset();
    let cfg = TrainConfig { iters: 1, ..Default::default() };
    let vgg = FeatureSpec::Vgg16("vgg16.safetensors".into());
    for kind in [LossKind::Wd, LossKind::Wdr] {
        let e = gpu::train(&ds, None, &cfg, &GpuLoss::new(kind, &vgg, None, None), &mut |_| {}).unwrap_err();
        assert_eq!(e.exit_code(), 2);
        assert!(e.to_string().contains("pyramid") && e.to_string().contains("--backend cpu"), "{e}");
        let e = GpuLoss::new(kind, &FeatureSpec::Pyramid, Some(-1.0), None).check().unwrap_err();
        assert!(e.exit_code() == 2 && e.to_string().contains("--wd-gamma"), "{e}");
        let e = GpuLoss::new(kind, &FeatureSpec::Pyramid, None, Some(0.5)).check().unwrap_err();
        assert!(e.exit_code() == 2 && e.to_string().contains("--wd-sigma 0.5"), "{e}");
        GpuLoss::new(kind, &FeatureSpec::Pyramid, None, Some(2.0)).check().unwrap();
        let e = GpuLoss::new(kind, &FeatureSpec::Pyramid, None, None).with_warmup(Some(1.5)).check().unwrap_err();
        assert!(e.exit_code() == 2 && e.to_string().contains("--wd-warmup 1.5"), "{e}");
        GpuLoss::new(kind, &FeatureSpec::Pyramid, None, None).with_warmup(Some(1.0)).check().unwrap();
        // the warm-up share sets the GPU WD stage's first iteration as the CPU loss's
        let wc = |f| gscodec::train::gpu::wd::WdConfig::new(kind, None, None, f, 300).warmup;
        assert_eq!((wc(Some(0.1)), wc(Some(0.0)), wc(None)), (30, 0, 90));
        GpuLoss::new(kind, &FeatureSpec::Pyramid, None, None).check().unwrap();
    }
    let _ = Mat3::IDENTITY;
}

/// `gscodec encode samples/tiny/truth.ply --iters 30 --loss l1ssim --backend gpu` (fine-tuning
/// under D + λ·R with the rate term and learned steps on the GPU) against `--backend cpu`: the
/// file decodes to the same Gaussian count and lands within 2 % of the CPU's size and 0.3 dB of
/// its orbit PSNR. The two backends run the same maths; they differ by float-atomic summation
/// order and f32 vs f64 densities, so the trained values (and the learned steps) agree to ~1e-4
/// (measured at 60 iterations: 15,394 vs 15,400 bytes, 42.64 vs 42.54 dB).
#[test]
fn encode_on_the_gpu_lands_near_the_cpu() {
    let Some(_gpu) = device() else { return };
    let dir = tempfile::tempdir().unwrap();
    let ply = Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/tiny/truth.ply");
    let run = |backend: &str| {
        let out = dir.path().join(format!("{backend}.gsc"));
        let report = dir.path().join(format!("{backend}.json"));
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_gscodec"))
            .args(["encode", ply.to_str().unwrap(), "-o", out.to_str().unwrap(), "--iters", "30", "--loss", "l1ssim"])
            .args(["--backend", backend, "--report", report.to_str().unwrap(), "--quiet"])
            .output()
            .unwrap();
        assert!(o.status.success(), "{backend}: {}", String::from_utf8_lossy(&o.stderr));
        let r: serde_json::Value = serde_json::from_slice(&std::fs::read(&report).unwrap()).unwrap();
        assert_eq!(r["backend"], backend);
        (out, r["file_bytes"].as_f64().unwrap(), r["orbit_psnr"].as_f64().unwrap(), r["gaussians"].as_u64().unwrap())
    };
    let (_, cpu_bytes, cpu_psnr, _) = run("cpu");
    let (gsc, gpu_bytes, gpu_psnr, gpu_n) = run("gpu");
    eprintln!("cpu {cpu_bytes} bytes {cpu_psnr:.2} dB; gpu {gpu_bytes} bytes {gpu_psnr:.2} dB");
    assert!((gpu_bytes - cpu_bytes).abs() <= 0.02 * cpu_bytes, "{gpu_bytes} vs {cpu_bytes} bytes");
    assert!((gpu_psnr - cpu_psnr).abs() <= 0.3, "{gpu_psnr:.2} vs {cpu_psnr:.2} dB");
    let decoded = gscodec_decoder::decode(&std::fs::read(&gsc).unwrap()).unwrap();
    assert_eq!(decoded.len() as u64, gpu_n);
}

/// A random image and a target correlated with it (away from both WD's and SSIM's degenerate cases).
fn image_pair(seed: u64, w: u32, h: u32) -> (Image, Image) {
    let mut g = Lcg(seed + 31);
    let target = Image { width: w, height: h, data: (0..w * h * 3).map(|_| g.next()).collect() };
    let rendered = Image { width: w, height: h, data: target.data.iter().map(|v| (v * 0.7 + 0.3 * g.next()).min(1.0)).collect() };
    (rendered, target)
}

fn assert_value(what: &str, gpu: f64, cpu: f64) {
    eprintln!("{what}: GPU {gpu:.7e} CPU {cpu:.7e}");
    assert!(gpu.is_finite() && (gpu - cpu).abs() <= 1e-4 * cpu.abs() + 1e-9, "{what}: GPU {gpu} vs CPU {cpu}");
}

/// d_WD (built-in features, σ = 4 and σ = 2, whose level 0 counts on the ½-resolution arrays)
/// and its image gradient: GPU kernels against `wd.rs` / `pyramid.rs` at odd and even sizes (the
/// CPU gradient is checked against f64 finite differences in tests/wd.rs).
#[test]
fn wd_value_and_gradient_match_cpu() {
    let Some(gpu) = device() else { return };
    for (bank, spec) in [(Pyramid::LUMA, FeatureSpec::Pyramid), (Pyramid::COLOUR, FeatureSpec::PyramidColour)] {
        for sigma in [4.0, 2.0] {
            for (seed, (w, h)) in [(0u64, (37u32, 29u32)), (1, (64, 64)), (2, (23, 40))] {
                let (r, t) = image_pair(seed, w, h);
                let (cv, cg) = WdDistortion::new(Box::new(bank)).with_sigma(Sigma::Constant(sigma)).value_and_grad(&r, &t, None);
                // `wd` with γ = 1 past its warm-up is d_WD itself.
                let loss = GpuLoss::new(LossKind::Wd, &spec, Some(1.0), Some(sigma));
                let (gv, gg) = gpu::training_loss_and_grad(&gpu, &r, &t, &loss, 1, 1).unwrap();
                let what = format!("{spec} σ {sigma} {w}x{h}");
                assert_value(&format!("{what} d_WD"), gv, cv);
                assert_close(&format!("{what} d(d_WD)/dimage"), &gg, &cg);
            }
        }
    }
}

/// The whole WD-R loss: γ·(d_WD + β·L_orig) with a fixed γ and with the normalised γ measured on
/// this view, and `L_orig` alone during the warm-up, against `wdr.rs`.
#[test]
fn wdr_loss_and_gradient_match_cpu() {
    let Some(gpu) = device() else { return };
    let (r, t) = image_pair(7, 37, 29);
    for gamma in [Some(0.03), None] {
        let mut cpu = WdrLoss::new(Box::new(Pyramid::LUMA), 1);
        if let Some(g) = gamma {
            cpu = cpu.with_fixed_gamma(g);
        }
        let (cv, cg) = cpu.loss_and_grad(&r, &t, 0, 1);
        let loss = GpuLoss::new(LossKind::Wdr, &FeatureSpec::Pyramid, gamma, None);
        let (gv, gg) = gpu::training_loss_and_grad(&gpu, &r, &t, &loss, 1, 1).unwrap();
        assert_value(&format!("WD-R, gamma {gamma:?}"), gv, cv);
        assert_close(&format!("WD-R gradient, gamma {gamma:?}"), &gg, &cg);
    }
    // In the warm-up (iterations 5 and 30 of 100) both train with L_orig alone; from
    // iteration 31 both with WD-R; at the share 1 neither does at the last iteration.
    let loss = GpuLoss::new(LossKind::Wdr, &FeatureSpec::Pyramid, None, None);
    let (lo, _) = wdr::l_orig(&r, &t);
    for (share, iter, warm) in [(None, 5, true), (None, 30, true), (None, 31, false), (Some(1.0), 100, true)] {
        let loss = loss.with_warmup(share);
        let (gv, gg) = gpu::training_loss_and_grad(&gpu, &r, &t, &loss, 100, iter).unwrap();
        let mut cpu = WdrLoss::new(Box::new(Pyramid::LUMA), 100);
        cpu.warmup = wdr::warmup_iters(100, share.unwrap_or(wdr::WARMUP_FRACTION));
        let (cv, cg) = cpu.loss_and_grad(&r, &t, 0, iter);
        assert_value(&format!("WD-R, iteration {iter}"), gv, cv);
        assert_close(&format!("WD-R gradient, iteration {iter}"), &gg, &cg);
        assert_eq!(cv == lo, warm, "iteration {iter}: L_orig alone is the warm-up");
    }
}

/// 60 iterations of WD-R (normalised γ, warm-up of 18) on `samples/tiny` through the backend seam
/// (`--backend gpu`, as `gscodec train samples/tiny --loss wdr --backend gpu --iters 60`): held-out
/// PSNR within 0.3 dB of the CPU trainer.
#[test]
fn wdr_training_matches_cpu_psnr() {
    let Some(_gpu) = device() else { return };
    let ds = tiny_dataset();
    let cfg = TrainConfig { iters: 60, seed: 5, init_points: 500, eval_interval: 0, ..Default::default() };
    let spec = LossSpec { kind: LossKind::Wdr, ..LossSpec::default() };
    let run = RunOptions::default();
    let job = || TrainJob { dataset: &ds, init: None, config: &cfg, loss: &spec, rate: None, run: &run };
    let (_, cpu_r) = Backend::Cpu.resolve().unwrap().train(job(), &mut |_| {}).unwrap();
    let (_, gpu_r) = Backend::Gpu.resolve().unwrap().train(job(), &mut |_| {}).unwrap();
    let (pc, pg) = (cpu_r.test_psnr.unwrap(), gpu_r.test_psnr.unwrap());
    eprintln!(
        "WD-R held-out PSNR: CPU {pc:.3} dB ({:.1} s), GPU {pg:.3} dB ({:.1} s, stages {:?})",
        cpu_r.train_seconds, gpu_r.train_seconds, gpu_r.stages
    );
    assert_eq!((cpu_r.backend, gpu_r.backend), ("cpu", "gpu"));
    assert_eq!((cpu_r.loss.as_str(), gpu_r.loss.as_str()), ("wdr", "wdr"));
    assert!(gpu_r.points.iter().all(|p| p.loss.is_finite()), "{:?}", gpu_r.points);
    assert!((pc - pg).abs() <= 0.3, "GPU {pg:.3} dB vs CPU {pc:.3} dB");
    // The logged WD-R loss γ·(d_WD + β·L_orig) after the warm-up (γ measured on both sides).
    let (lc, lg) = (cpu_r.points.last().unwrap().loss, gpu_r.points.last().unwrap().loss);
    eprintln!("last logged loss: CPU {lc:.5}, GPU {lg:.5}");
    assert!((lc - lg).abs() <= 0.02 * lc.abs(), "GPU loss {lg} vs CPU {lc}");
}

/// The WD stage's memory: one view's cached reference statistics hold, with σ = 4, the means and
/// standard deviations of level 2 of the 3 + 16 full-resolution channels (at ½ resolution) and of
/// level 1 of the 16 ½-resolution channels, and the 16 + 16 channels at ¼ and ⅛ (level 0):
/// 750,000 floats at 200² (3.0 MB), 18.75 M at 1000² (75 MB). `pyramid-colour` adds, per
/// opponent signal, level 1 of its ½-resolution stage and its ¼ and ⅛ stages: 2 × 370,000 more
/// at 200².
#[test]
fn wd_stage_memory_per_view() {
    for (colour, (w, h), want) in [
        (false, (200u32, 200u32), 750_000u64 * 4),
        (false, (1000, 1000), 18_750_000 * 4),
        (true, (200, 200), 1_490_000 * 4),
        (true, (1000, 1000), 37_250_000 * 4),
    ] {
        let (arena, reference) = gpu::wd::WdStage::memory(w, h, 4.0, colour);
        eprintln!(
            "{w}x{h}, colour {colour}: WD working memory {:.1} MB, reference statistics {:.1} MB per view",
            arena as f64 / 1e6,
            reference as f64 / 1e6
        );
        assert_eq!(reference, want, "{w}x{h}, colour {colour}");
    }
}

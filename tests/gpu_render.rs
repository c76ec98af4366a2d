//! `--backend gpu` against the CPU renderer on real scenes: the tiny sample (always present) and
//! k7000 (skipped when ../shared/data is absent). Requires PSNR(GPU, CPU) ≥ 45 dB. Set
//! `GSCODEC_DUMP_DIR` to also write both renders as PNG for inspection.
#![cfg(feature = "gpu")]

use glam::Vec3;
use gscodec::decoder::render::gpu::GpuRenderer;
use gscodec::decoder::render::render;
use gscodec::decoder::{Camera, RenderOptions, Splats};
use gscodec::io::image::write_png;
use gscodec::io::{load_dataset, read_ply, LoadOptions};
use gscodec::metrics::psnr;
use gscodec::testkit::{gpu_renderer, shared_data};
use std::path::Path;

fn compare(r: &GpuRenderer, name: &str, s: &Splats, cams: &[Camera], opts: &RenderOptions) {
    for (i, cam) in cams.iter().enumerate() {
        let cpu = render(s, cam, opts);
        let gpu = r.render(s, cam, opts).unwrap();
        let p = psnr(&cpu, &gpu);
        eprintln!("{name} view {i} ({}x{}): PSNR(GPU, CPU) = {p:.1} dB", cam.width, cam.height);
        if let Ok(dir) = std::env::var("GSCODEC_DUMP_DIR") {
            write_png(&Path::new(&dir).join(format!("{name}_{i}_cpu.png")), &cpu).unwrap();
            write_png(&Path::new(&dir).join(format!("{name}_{i}_gpu.png")), &gpu).unwrap();
        }
        assert!(p >= 45.0, "{name} view {i}: PSNR {p:.2} dB < 45");
    }
}

#[test]
fn sample_scene_gpu_matches_cpu() {
    let Some(r) = gpu_renderer() else { return };
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/tiny");
    let s = read_ply(&root.join("truth.ply")).unwrap();
    let ds = load_dataset(&root, &LoadOptions::default()).unwrap();
    let cams: Vec<Camera> = ds.frames.iter().take(3).map(|f| f.camera.resized(96, 96)).collect();
    compare(r, "tiny", &s, &cams, &RenderOptions { background: ds.background, max_sh_degree: 3 });
}

#[test]
fn k7000_gpu_matches_cpu() {
    let Some(path) = shared_data("scenes/k7000.ply") else { return };
    let Some(r) = gpu_renderer() else { return };
    let s = read_ply(&path).unwrap();
    let (lo, hi) = s.bounds().unwrap();
    let (lo, hi) = (Vec3::from_array(lo), Vec3::from_array(hi));
    let center = (lo + hi) * 0.5;
    let radius = (hi - lo).length() * 0.6;
    let cams = Camera::orbit(2, center, radius, 0.4, Vec3::new(0.0, -1.0, 0.0), 160, 120, 1.0);
    compare(r, "k7000", &s, &cams, &RenderOptions::default());
}

//! The procedural sample: determinism, and the NeRF camera convention end to end.

use glam::Vec3;
use gscodec::decoder::render::render;
use gscodec::decoder::{Camera, RenderOptions};
use gscodec::io::image::to_rgb8;
use gscodec::io::{load_dataset, read_ply, LoadOptions, Split};
use gscodec::sample::{write_sample, SampleOptions};
use std::path::Path;

fn tiny() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/tiny")
}

#[test]
fn rendering_truth_from_the_dataset_cameras_reproduces_the_pngs() {
    let ds = load_dataset(&tiny(), &LoadOptions::default()).unwrap();
    let scene = read_ply(&tiny().join("truth.ply")).unwrap();
    assert_eq!((ds.frames.len(), scene.len(), scene.sh_degree), (16, 1000, 3));
    let opts = RenderOptions { background: ds.background, max_sh_degree: 3 };
    for f in ds.split(Split::All) {
        let img = render(&scene, &f.camera, &opts);
        let stored: Vec<u8> = f.image.get().unwrap().data.iter().map(|v| (v * 255.0).round() as u8).collect();
        assert!(to_rgb8(&img) == stored, "frame {} differs", f.name);
    }
}

#[test]
fn regenerating_the_tiny_sample_gives_the_same_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("tiny");
    let opts = SampleOptions { gaussians: 1000, views: 16, width: 64, height: 64, seed: 0 };
    write_sample(&out, &opts, &indicatif::ProgressBar::hidden()).unwrap();
    let mut names = vec!["transforms_train.json".to_string(), "truth.ply".to_string()];
    names.extend((0..16).map(|i| format!("train/r_{i}.png")));
    for n in names {
        assert!(std::fs::read(out.join(&n)).unwrap() == std::fs::read(tiny().join(&n)).unwrap(), "{n} differs");
    }
    // Another seed gives another scene.
    let other = dir.path().join("other");
    write_sample(&other, &SampleOptions { seed: 1, ..opts }, &indicatif::ProgressBar::hidden()).unwrap();
    assert!(std::fs::read(other.join("truth.ply")).unwrap() != std::fs::read(out.join("truth.ply")).unwrap());
}

#[test]
fn look_at_keeps_up_up_and_right_right() {
    // Looking along +y with +z up: +z projects above the centre, +x to the right.
    let cam = Camera::look_at(Vec3::new(0.0, -5.0, 0.0), Vec3::ZERO, Vec3::Z, 64, 64, 1.0);
    let project = |p: Vec3| {
        let t = cam.to_camera(p);
        (cam.fx * t.x / t.z + cam.cx, cam.fy * t.y / t.z + cam.cy)
    };
    assert!(project(Vec3::new(0.0, 0.0, 1.0)).1 < 32.0);
    assert!(project(Vec3::new(1.0, 0.0, 0.0)).0 > 32.0);
}

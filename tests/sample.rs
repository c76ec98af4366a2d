//! The procedural sample: determinism, and the NeRF camera convention end to end.

use glam::Vec3;
use gscodec::decoder::render::render;
use gscodec::decoder::{Camera, RenderOptions};
use gscodec::io::image::to_rgb8;
use gscodec::io::{load_dataset, read_ply, LoadOptions, Split};
use gscodec::sample::{write_sample, write_scene_sample, Rig, SampleOptions};
use gscodec::views::robust_frame;
use std::path::Path;

fn tiny() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/tiny")
}

/// Rendering `dir`'s `truth.ply` from the cameras `load_dataset` rebuilds gives every stored PNG.
fn assert_truth_reproduces_the_pngs(dir: &Path) {
    let ds = load_dataset(dir, &LoadOptions::default()).unwrap();
    let scene = read_ply(&dir.join("truth.ply")).unwrap();
    let opts = RenderOptions { background: ds.background, max_sh_degree: 3 };
    for f in ds.split(Split::All) {
        let img = render(&scene, &f.camera, &opts);
        let stored: Vec<u8> = f.image.get().unwrap().data.iter().map(|v| (v * 255.0).round() as u8).collect();
        assert!(to_rgb8(&img) == stored, "frame {} differs", f.name);
    }
}

#[test]
fn rendering_truth_from_the_dataset_cameras_reproduces_the_pngs() {
    let ds = load_dataset(&tiny(), &LoadOptions::default()).unwrap();
    let scene = read_ply(&tiny().join("truth.ply")).unwrap();
    assert_eq!((ds.frames.len(), scene.len(), scene.sh_degree), (16, 1000, 3));
    assert_truth_reproduces_the_pngs(&tiny());
}

/// `sample --scene`: a dataset of any scene, its cameras framing it as the evaluation orbit does.
#[test]
fn a_scenes_sample_looks_at_its_robust_centre_from_the_orbit_distance() {
    // The tiny sample's scene moved off the origin and turned to -y up, so that the rig must
    // find it: (x, y, z) -> (x, -z, y) + t.
    let mut scene = read_ply(&tiny().join("truth.ply")).unwrap();
    let t = Vec3::new(3.0, -1.0, 2.0);
    for p in &mut scene.positions {
        *p = (Vec3::new(p[0], -p[2], p[1]) + t).into();
    }
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("moved");
    let opts = SampleOptions { gaussians: 0, views: 12, width: 48, height: 40, seed: 5 };
    write_scene_sample(&out, Path::new("moved.ply"), &scene, Vec3::NEG_Y, &opts, &indicatif::ProgressBar::hidden()).unwrap();
    assert!(read_ply(&out.join("truth.ply")).unwrap() == scene, "truth.ply is the scene given");
    assert_truth_reproduces_the_pngs(&out);

    let (centre, extent) = robust_frame(&scene);
    let rig = Rig::around(&scene, Vec3::NEG_Y);
    assert_eq!((rig.centre, rig.radius), (centre, 2.5 * extent));
    let ds = load_dataset(&out, &LoadOptions::default()).unwrap();
    assert_eq!(ds.frames.len(), 12);
    let mut heights = Vec::new();
    for f in ds.split(Split::All) {
        let cam = &f.camera;
        assert_eq!((cam.width, cam.height), (48, 40));
        assert!((cam.center().distance(centre) - rig.radius).abs() < 1e-4 * rig.radius, "{}", f.name);
        // The centre projects to the image centre; world up (-y) points up the image.
        let project = |p: Vec3| {
            let c = cam.to_camera(p);
            (cam.fx * c.x / c.z + cam.cx, cam.fy * c.y / c.z + cam.cy)
        };
        let (u, v) = project(centre);
        assert!((u - 24.0).abs() < 1e-2 && (v - 20.0).abs() < 1e-2, "{}: centre at ({u}, {v})", f.name);
        assert!(project(centre - Vec3::Y * 0.1 * extent).1 < v, "{}: -y is not up", f.name);
        // Elevation above the plane normal to -y, between 15° and 65°.
        let e = ((centre.y - cam.center().y) / rig.radius).asin().to_degrees();
        assert!((14.9..65.1).contains(&e), "{}: elevation {e}", f.name);
        heights.push(e);
    }
    assert!(heights.iter().cloned().fold(f32::MAX, f32::min) < 30.0 && heights.iter().cloned().fold(0.0, f32::max) > 50.0);
    let text = std::fs::read_to_string(out.join("transforms_train.json")).unwrap();
    let json: serde_json::Value = serde_json::from_str(&text).unwrap();
    assert_eq!(json["camera_angle_x"].as_f64(), Some(f64::from(gscodec::views::ORBIT_FOV_X)));
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

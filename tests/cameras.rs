//! Lens distortion end to end: a synthetic scene photographed through a known distortion, loaded
//! (undistorted by the loader) and trained on, against the same scene's pinhole images.

use glam::Quat;
use gscodec::decoder::render::render;
use gscodec::decoder::{Camera, Image, RenderOptions, Splats};
use gscodec::io::image::write_png;
use gscodec::io::lens::{distort_image, Distortion, Lens};
use gscodec::io::{load_dataset, Dataset, LoadOptions, Split};
use gscodec::loss::L1Ssim;
use gscodec::metrics::psnr;
use gscodec::metrics::view::mean_psnr_ssim;
use gscodec::testkit::{random_splats, rig_cameras};
use gscodec::train::targets::render_targets;
use gscodec::train::{train, TrainConfig};
use std::path::Path;

const W: u32 = 64;
const H: u32 = 48;
const F: f64 = 56.0;

fn opencv() -> Lens {
    Lens::new(W, H, [F, F * 1.02, 31.5, 24.5], Distortion::RadialTangential { k: [-0.18, 0.04, 0.0, 0.0], p: [0.002, -0.003] }).unwrap()
}

fn fisheye() -> Lens {
    Lens::new(W, H, [F * 0.9, F * 0.9, 32.5, 23.5], Distortion::Fisheye { k: [0.03, -0.01, 0.0, 0.0], p: [0.0; 2], s: [0.0; 2] }).unwrap()
}

/// The photo `lens` takes from `cam`'s pose: the scene rendered through a pinhole camera at twice
/// the resolution, wide enough to cover the lens's field, resampled through the distortion.
fn photo(scene: &Splats, cam: &Camera, lens: &Lens, bg: [f32; 3]) -> Image {
    let mut reach: f64 = 0.0;
    for i in 0..=32 {
        let t = i as f64 / 32.0;
        for (px, py) in [(t * W as f64, 0.0), (t * W as f64, H as f64), (0.0, t * H as f64), (W as f64, t * H as f64)] {
            let (x, y) = lens.from_pixel(px, py);
            let (u, v) = lens.undistort(x, y).unwrap();
            reach = reach.max(u.abs()).max(v.abs());
        }
    }
    let f_hi = 2.0 * F;
    let side = (2.0 * (reach * f_hi).ceil() + 4.0) as u32;
    let hi = Lens::new(side, side, [f_hi, f_hi, side as f64 / 2.0, side as f64 / 2.0], Distortion::None).unwrap();
    let mut pin = *cam;
    gscodec::io::lens::apply_pinhole(&mut pin, &hi);
    let img = render(scene, &pin, &RenderOptions { background: bg, max_sh_degree: 3 });
    distort_image(&img, &hi, lens, bg)
}

/// A COLMAP text dataset of `photos` taken with `lens` (one camera) from `cams`' poses.
fn write_colmap(dir: &Path, model: &str, params: &[f64], cams: &[Camera], photos: &[Image]) {
    let sparse = dir.join("sparse/0");
    std::fs::create_dir_all(&sparse).unwrap();
    std::fs::create_dir_all(dir.join("images")).unwrap();
    let ps: Vec<String> = params.iter().map(|v| format!("{v:?}")).collect();
    std::fs::write(sparse.join("cameras.txt"), format!("1 {model} {W} {H} {}\n", ps.join(" "))).unwrap();
    let mut s = String::new();
    for (i, (c, img)) in cams.iter().zip(photos).enumerate() {
        let q = Quat::from_mat3(&c.rotation);
        let t = c.translation;
        s += &format!("{} {} {} {} {} {} {} {} 1 v{i:03}.png\n\n", i + 1, q.w, q.x, q.y, q.z, t.x, t.y, t.z);
        write_png(&dir.join(format!("images/v{i:03}.png")), img).unwrap();
    }
    std::fs::write(sparse.join("images.txt"), s).unwrap();
}

fn lens_params(l: &Lens) -> (&'static str, Vec<f64>) {
    match l.distortion {
        Distortion::RadialTangential { k, p } => ("OPENCV", vec![l.fx, l.fy, l.cx, l.cy, k[0], k[1], p[0], p[1]]),
        Distortion::Fisheye { k, .. } => ("OPENCV_FISHEYE", vec![l.fx, l.fy, l.cx, l.cy, k[0], k[1], k[2], k[3]]),
        _ => unreachable!(),
    }
}

#[test]
fn undistorted_photos_match_pinhole_renders_of_the_loaded_cameras() {
    let scene = random_splats(150, 1, 2);
    let bg = [0.0; 3];
    let cams = rig_cameras(4, 3.5, W, H);
    for lens in [opencv(), fisheye()] {
        let photos: Vec<Image> = cams.iter().map(|c| photo(&scene, c, &lens, bg)).collect();
        let dir = tempfile::tempdir().unwrap();
        let (model, params) = lens_params(&lens);
        write_colmap(dir.path(), model, &params, &cams, &photos);
        let ds = load_dataset(dir.path(), &LoadOptions { cache: false, ..Default::default() }).unwrap();
        for (f, photo) in ds.frames.iter().zip(&photos) {
            let direct = render(&scene, &f.camera, &RenderOptions { background: bg, max_sh_degree: 3 });
            let good = psnr(&f.image.get().unwrap(), &direct);
            // Ignoring the distortion (the photo as a pinhole image with the lens's intrinsics).
            let mut naive = f.camera;
            naive.width = W;
            naive.height = H;
            (naive.fx, naive.fy, naive.cx, naive.cy) = (lens.fx as f32, lens.fy as f32, lens.cx as f32, lens.cy as f32);
            let bad = psnr(photo, &render(&scene, &naive, &RenderOptions { background: bg, max_sh_degree: 3 }));
            eprintln!(
                "{model} {}: {}x{} undistorted vs direct {good:.2} dB; distortion ignored {bad:.2} dB",
                f.name, f.camera.width, f.camera.height
            );
            assert!(good > 30.0 && good > bad + 6.0, "{model} {}: {good:.2} dB vs ignored {bad:.2} dB", f.name);
        }
    }
}

#[test]
fn training_on_distorted_photos_matches_training_on_pinhole_images() {
    let scene = random_splats(150, 1, 4);
    let bg = [0.0; 3];
    let lens = opencv();
    let cams = rig_cameras(16, 3.5, W, H);
    // Reference: pinhole images with the lens's focal length and principal point.
    let pinhole: Vec<Camera> =
        cams.iter().map(|c| Camera { fx: lens.fx as f32, fy: lens.fy as f32, cx: lens.cx as f32, cy: lens.cy as f32, ..*c }).collect();
    let reference = render_targets(&scene, &pinhole, bg);
    let photos: Vec<Image> = cams.iter().map(|c| photo(&scene, c, &lens, bg)).collect();
    let dir = tempfile::tempdir().unwrap();
    let (model, params) = lens_params(&lens);
    write_colmap(dir.path(), model, &params, &cams, &photos);
    let distorted = load_dataset(dir.path(), &LoadOptions::default()).unwrap();
    assert_eq!(distorted.frames.len(), 16);
    // Held out for both: exact pinhole renders of the frames every 8th (the test split).
    let held_out: Vec<_> = reference.split(Split::Test).into_iter().cloned().collect();
    let held = Dataset { frames: held_out, background: bg, ..Default::default() };
    // Mean over two seeds: one 300-iteration run varies by about a dB.
    let run = |ds: &Dataset| {
        let psnr = |seed| {
            let cfg = TrainConfig { iters: 300, seed, init_points: 600, eval_interval: 0, ..Default::default() };
            let (s, _) = train(ds, None, &cfg, Box::new(L1Ssim::default()), None, &mut |_| {}).unwrap();
            mean_psnr_ssim(&s, &held.split(Split::All), bg).unwrap().unwrap().0
        };
        (psnr(3) + psnr(4)) / 2.0
    };
    let (p_ref, p_dist) = (run(&reference), run(&distorted));
    eprintln!("held-out PSNR: trained on pinhole images {p_ref:.2} dB, on distorted photos {p_dist:.2} dB");
    assert!(p_ref > 20.0, "reference training failed: {p_ref:.2} dB");
    assert!((p_ref - p_dist).abs() < 1.0, "pinhole {p_ref:.2} dB vs distorted {p_dist:.2} dB");
}

#[test]
fn nerf_json_distortion_keys_and_per_frame_intrinsics() {
    let scene = random_splats(100, 1, 5);
    let bg = [1.0; 3];
    let cams = rig_cameras(2, 3.5, W, H);
    let lens = opencv();
    let fish = fisheye();
    let dir = tempfile::tempdir().unwrap();
    std::fs::create_dir_all(dir.path().join("images")).unwrap();
    let mut frames = Vec::new();
    for (i, (c, l)) in cams.iter().zip([lens, fish]).enumerate() {
        write_png(&dir.path().join(format!("images/f{i}.png")), &photo(&scene, c, &l, bg)).unwrap();
        // NeRF c2w in OpenGL axes from the OpenCV world-to-camera pose.
        let r = c.rotation.transpose();
        let centre = c.center();
        let col = |j: usize, s: f32| [r.col(j).x * s, r.col(j).y * s, r.col(j).z * s];
        let (x, y, z) = (col(0, 1.0), col(1, -1.0), col(2, -1.0));
        let m = serde_json::json!([[x[0], y[0], z[0], centre.x], [x[1], y[1], z[1], centre.y], [x[2], y[2], z[2], centre.z], [0, 0, 0, 1]]);
        let mut f = serde_json::json!({"file_path": format!("images/f{i}"), "transform_matrix": m,
            "fl_x": l.fx, "fl_y": l.fy, "cx": l.cx, "cy": l.cy, "w": W, "h": H});
        match l.distortion {
            Distortion::RadialTangential { k, p } => {
                f["k1"] = k[0].into();
                f["k2"] = k[1].into();
                f["p1"] = p[0].into();
                f["p2"] = p[1].into();
            }
            Distortion::Fisheye { k, .. } => {
                f["camera_model"] = "OPENCV_FISHEYE".into();
                (0..4).for_each(|j| f[format!("k{}", j + 1)] = k[j].into());
            }
            _ => unreachable!(),
        }
        frames.push(f);
    }
    // A listed frame without its image: skipped with a warning.
    frames.push(serde_json::json!({"file_path": "images/gone.png", "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,4],[0,0,0,1]]}));
    let json = serde_json::json!({"camera_model": "OPENCV", "fl_x": 1.0, "frames": frames});
    std::fs::write(dir.path().join("transforms.json"), json.to_string()).unwrap();
    let ds = load_dataset(dir.path(), &LoadOptions::default()).unwrap();
    assert_eq!(ds.frames.len(), 2);
    for f in &ds.frames {
        let direct = render(&scene, &f.camera, &RenderOptions { background: bg, max_sh_degree: 3 });
        let p = psnr(&f.image.get().unwrap(), &direct);
        eprintln!("{}: {}x{} {p:.2} dB", f.name, f.camera.width, f.camera.height);
        assert!(p > 30.0, "{}: {p:.2} dB", f.name);
    }
}

#[test]
fn downscale_uses_images_n_and_max_size_resizes() {
    let scene = random_splats(100, 1, 6);
    let ropts = RenderOptions { background: [0.0; 3], max_sh_degree: 3 };
    let (w2, h2) = (2 * W, 2 * H);
    let cams: Vec<Camera> = rig_cameras(2, 3.5, w2, h2)
        .into_iter()
        .map(|c| Camera { fx: 2.0 * F as f32, fy: 2.0 * F as f32, cx: W as f32, cy: H as f32, ..c })
        .collect();
    let dir = tempfile::tempdir().unwrap();
    let full: Vec<Image> = cams.iter().map(|c| render(&scene, c, &ropts)).collect();
    write_colmap(dir.path(), "PINHOLE", &[2.0 * F, 2.0 * F, W as f64, H as f64], &cams, &full);
    // cameras.txt declares the full size.
    let sparse = dir.path().join("sparse/0/cameras.txt");
    std::fs::write(&sparse, format!("1 PINHOLE {w2} {h2} {} {} {W} {H}\n", 2.0 * F, 2.0 * F)).unwrap();
    // images_2/: a half-size set that differs from a box filter of the full images (flat grey).
    std::fs::create_dir_all(dir.path().join("images_2")).unwrap();
    let grey = Image { width: W, height: H, data: vec![0.5; (W * H * 3) as usize] };
    for i in 0..2 {
        write_png(&dir.path().join(format!("images_2/v{i:03}.png")), &grey).unwrap();
    }
    let load = |downscale, max_size| load_dataset(dir.path(), &LoadOptions { downscale, max_size, ..Default::default() }).unwrap();
    let half = load(2, None);
    let c = half.frames[0].camera;
    assert_eq!((c.width, c.height, c.fx, c.cx, c.cy), (W, H, F as f32, W as f32 / 2.0, H as f32 / 2.0));
    assert!(half.frames[0].image.get().unwrap().data.iter().all(|&v| (v - 128.0 / 255.0).abs() < 1e-6), "read from images_2/");
    // No images_4/: an exact 4×4 box filter of the full images.
    let quarter = load(4, None);
    let c = quarter.frames[0].camera;
    assert_eq!((c.width, c.height, c.fx, c.cx), (W / 2, H / 2, F as f32 / 2.0, W as f32 / 4.0));
    // --max-size 40 on 128×96: 40×30, every intrinsic ×40/128 (= ×30/96).
    let small = load(1, Some(40));
    for (f, cam) in small.frames.iter().zip(&cams) {
        let c = f.camera;
        assert_eq!((c.width, c.height), (40, 30));
        assert!(
            (c.fx - 35.0).abs() < 1e-5 && (c.cx - W as f32 * 40.0 / 128.0).abs() < 1e-5 && (c.cy - H as f32 * 30.0 / 96.0).abs() < 1e-5
        );
        let p = psnr(&f.image.get().unwrap(), &render(&scene, &c, &ropts));
        let shifted = psnr(&f.image.get().unwrap(), &render(&scene, &Camera { cx: c.cx + 0.5, ..c }, &ropts));
        eprintln!("max-size 40: {p:.2} dB against a direct render, {shifted:.2} dB half a pixel off");
        assert!(p > 30.0 && p > shifted + 3.0, "{p:.2} vs {shifted:.2}");
        assert!(c.rotation.abs_diff_eq(cam.rotation, 1e-6));
    }
}

//! Dataset loading: NeRF transforms, COLMAP .bin/.txt, the shared lego-200 set.

use glam::{Mat3, Quat, Vec3};
use gscodec::decoder::camera::DEFAULT_ZNEAR;
use gscodec::decoder::{Camera, Image};
use gscodec::io::colmap::read_model;
use gscodec::io::image::write_png;
use gscodec::io::{load_dataset, LoadOptions, Split};
use std::path::Path;

mod common;

fn gradient(w: u32, h: u32) -> Image {
    let data = (0..w * h).flat_map(|i| [(i % w) as f32 / w as f32, (i / w) as f32 / h as f32, 0.5]).collect();
    Image { width: w, height: h, data }
}

/// (id, model id, model name, width, height, params)
type Cam = (u32, i32, &'static str, u64, u64, Vec<f64>);
/// (id, qvec, tvec, camera id, name)
type Img = (u32, [f64; 4], [f64; 3], u32, &'static str);

/// A small COLMAP model: two cameras, three images, four points.
struct Model {
    cams: Vec<Cam>,
    imgs: Vec<Img>,
    pts: Vec<(u64, [f64; 3], [u8; 3])>,
}

fn model() -> Model {
    Model {
        cams: vec![(1, 1, "PINHOLE", 32, 24, vec![30.0, 31.0, 16.5, 11.5]), (7, 0, "SIMPLE_PINHOLE", 32, 24, vec![28.0, 16.0, 12.0])],
        imgs: vec![
            (3, [0.9, 0.1, -0.2, 0.3], [0.5, -1.0, 4.0], 7, "c.png"),
            (1, [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 5.0], 1, "a.png"),
            (2, [0.7, 0.7, 0.1, 0.0], [1.0, 2.0, 3.0], 1, "b.png"),
        ],
        pts: vec![
            (1, [0.1, 0.2, 0.3], [255, 0, 10]),
            (5, [-1.5, 2.25, 1e-3], [1, 2, 3]),
            (9, [3.0, -4.0, 5.0], [200, 100, 50]),
            (10, [0.0; 3], [0, 0, 0]),
        ],
    }
}

fn write_bin(m: &Model, dir: &Path) {
    let mut c = Vec::new();
    c.extend((m.cams.len() as u64).to_le_bytes());
    for (id, model, _, w, h, p) in &m.cams {
        c.extend((*id as i32).to_le_bytes());
        c.extend(model.to_le_bytes());
        c.extend(w.to_le_bytes());
        c.extend(h.to_le_bytes());
        p.iter().for_each(|v| c.extend(v.to_le_bytes()));
    }
    std::fs::write(dir.join("cameras.bin"), c).unwrap();
    let mut b = Vec::new();
    b.extend((m.imgs.len() as u64).to_le_bytes());
    for (id, q, t, cam, name) in &m.imgs {
        b.extend((*id as i32).to_le_bytes());
        q.iter().chain(t).for_each(|v| b.extend(v.to_le_bytes()));
        b.extend((*cam as i32).to_le_bytes());
        b.extend(name.as_bytes());
        b.push(0);
        b.extend(2u64.to_le_bytes());
        for k in 0..2 {
            b.extend((k as f64 * 3.5).to_le_bytes());
            b.extend(1.25f64.to_le_bytes());
            b.extend((k as i64 - 1).to_le_bytes());
        }
    }
    std::fs::write(dir.join("images.bin"), b).unwrap();
    let mut p = Vec::new();
    p.extend((m.pts.len() as u64).to_le_bytes());
    for (id, xyz, rgb) in &m.pts {
        p.extend(id.to_le_bytes());
        xyz.iter().for_each(|v| p.extend(v.to_le_bytes()));
        p.extend(rgb);
        p.extend(0.5f64.to_le_bytes());
        p.extend(1u64.to_le_bytes());
        p.extend(1i32.to_le_bytes());
        p.extend(0i32.to_le_bytes());
    }
    std::fs::write(dir.join("points3D.bin"), p).unwrap();
}

fn write_txt(m: &Model, dir: &Path) {
    let mut c = String::from("# Camera list with one line of data per camera:\n");
    for (id, _, name, w, h, p) in &m.cams {
        let ps: Vec<String> = p.iter().map(|v| format!("{v:?}")).collect();
        c += &format!("{id} {name} {w} {h} {}\n", ps.join(" "));
    }
    std::fs::write(dir.join("cameras.txt"), c).unwrap();
    let mut s = String::from("# Image list with two lines of data per image:\n");
    for (i, (id, q, t, cam, name)) in m.imgs.iter().enumerate() {
        s += &format!("{id} {:?} {:?} {:?} {:?} {:?} {:?} {:?} {cam} {name}\n", q[0], q[1], q[2], q[3], t[0], t[1], t[2]);
        // One image with an empty POINTS2D line, the others with points.
        s += if i == 1 { "\n" } else { "0.0 1.25 -1 3.5 1.25 0\n" };
    }
    std::fs::write(dir.join("images.txt"), s).unwrap();
    let mut p = String::from("# 3D point list\n");
    for (id, xyz, rgb) in &m.pts {
        p += &format!("{id} {:?} {:?} {:?} {} {} {} 0.5 1 0\n", xyz[0], xyz[1], xyz[2], rgb[0], rgb[1], rgb[2]);
    }
    std::fs::write(dir.join("points3D.txt"), p).unwrap();
}

fn colmap_dir(m: &Model, bin: bool) -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    let sparse = dir.path().join("sparse/0");
    std::fs::create_dir_all(&sparse).unwrap();
    std::fs::create_dir_all(dir.path().join("images")).unwrap();
    for (_, _, _, _, name) in &m.imgs {
        write_png(&dir.path().join("images").join(name), &gradient(32, 24)).unwrap();
    }
    if bin {
        write_bin(m, &sparse)
    } else {
        write_txt(m, &sparse)
    }
    dir
}

#[test]
fn colmap_bin_and_txt_load_identically() {
    let m = model();
    let (b, t) = (colmap_dir(&m, true), colmap_dir(&m, false));
    let (mb, mt) = (read_model(&b.path().join("sparse/0")).unwrap(), read_model(&t.path().join("sparse/0")).unwrap());
    assert_eq!(mb, mt);
    assert_eq!((mb.cameras.len(), mb.images.len(), mb.points.len()), (2, 3, 4));
    let (db, dt) = (load_dataset(b.path(), &LoadOptions::default()).unwrap(), load_dataset(t.path(), &LoadOptions::default()).unwrap());
    assert_eq!(db.frames.len(), 3);
    for (x, y) in db.frames.iter().zip(&dt.frames) {
        assert_eq!((x.index, &x.name, x.camera, &*x.image.get().unwrap()), (y.index, &y.name, y.camera, &*y.image.get().unwrap()));
    }
    assert_eq!(db.points, dt.points);
    // Sorted by name; poses are world-to-camera.
    let names: Vec<&str> = db.frames.iter().map(|f| f.name.as_str()).collect();
    assert_eq!(names, ["a.png", "b.png", "c.png"]);
    let c = &db.frames[2].camera;
    let q = Quat::from_xyzw(0.1, -0.2, 0.3, 0.9).normalize();
    assert!((c.rotation - Mat3::from_quat(q)).abs_diff_eq(Mat3::ZERO, 1e-6));
    assert_eq!(c.translation, Vec3::new(0.5, -1.0, 4.0));
    assert_eq!((c.fx, c.fy, c.cx, c.cy), (28.0, 28.0, 16.0, 12.0));
    assert_eq!(db.points[0], ([0.1, 0.2, 0.3], [1.0, 0.0, 10.0 / 255.0]));
}

#[test]
fn nerf_intrinsics_extensions_missing_frames_and_downscale() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::create_dir(dir.path().join("train")).unwrap();
    // RGBA image: half transparent red.
    let rgba = image::RgbaImage::from_pixel(8, 6, image::Rgba([255, 0, 0, 128]));
    rgba.save(dir.path().join("train/a.png")).unwrap();
    write_png(&dir.path().join("train/b.png"), &gradient(8, 6)).unwrap();
    let c2w = |x: f32| serde_json::json!([[1, 0, 0, x], [0, 1, 0, 0], [0, 0, 1, 4], [0, 0, 0, 1]]);
    let json = serde_json::json!({
        "camera_angle_x": 0.9,
        "frames": [
            {"file_path": "./train/a", "transform_matrix": c2w(0.0)},
            {"file_path": "./train/missing", "transform_matrix": c2w(1.0)},
            {"file_path": "train/b.png", "transform_matrix": c2w(2.0), "fl_x": 10.0, "fl_y": 12.0, "cx": 3.0, "cy": 2.5, "w": 16, "h": 12},
        ]
    });
    std::fs::write(dir.path().join("transforms.json"), json.to_string()).unwrap();
    let ds = load_dataset(dir.path(), &LoadOptions::default()).unwrap();
    assert_eq!(ds.frames.iter().map(|f| f.index).collect::<Vec<_>>(), [0, 2]);
    assert_eq!(ds.background, [1.0; 3]);
    let a = &ds.frames[0];
    let alpha = 128.0 / 255.0;
    assert!(
        (a.image.get().unwrap().pixel(3, 3)[1] - (1.0 - alpha)).abs() < 1e-6 && (a.image.get().unwrap().pixel(3, 3)[0] - 1.0).abs() < 1e-6
    );
    assert!((a.camera.fx - 4.0 / (0.45f32).tan()).abs() < 1e-4);
    assert_eq!((a.camera.cx, a.camera.cy), (4.0, 3.0));
    // OpenGL camera at z=4 looking down -z: OpenCV forward is -z, the centre is kept.
    assert!(a.camera.center().abs_diff_eq(Vec3::new(0.0, 0.0, 4.0), 1e-6));
    assert!(a.camera.to_camera(Vec3::ZERO).abs_diff_eq(Vec3::new(0.0, 0.0, 4.0), 1e-6));
    // Declared 16x12 but the image is 8x6: intrinsics halve.
    let b = &ds.frames[1].camera;
    assert_eq!((b.fx, b.fy, b.cx, b.cy), (5.0, 6.0, 1.5, 1.25));
    // Scene scale: centres at x = 0 and 2, median distance to the mean is 1.
    assert!((b.znear - DEFAULT_ZNEAR).abs() < 1e-7);
    let half = load_dataset(dir.path(), &LoadOptions { downscale: 2, ..Default::default() }).unwrap();
    let hb = &half.frames[1];
    assert_eq!((hb.image.get().unwrap().width, hb.image.get().unwrap().height, hb.camera.fx, hb.camera.cx), (4, 3, 2.5, 0.75));
    let px = hb.image.get().unwrap().pixel(1, 1);
    let src = ds.frames[1].image.get().unwrap();
    let mean: f32 = [src.pixel(2, 2), src.pixel(3, 2), src.pixel(2, 3), src.pixel(3, 3)].iter().map(|p| p[0]).sum::<f32>() / 4.0;
    // Prepared images are rounded to 16 bits (cached and fresh loads agree).
    assert!((px[0] - mean).abs() < 1e-5);
}

#[test]
fn nerf_test_file_forms_the_test_split() {
    let dir = tempfile::tempdir().unwrap();
    write_png(&dir.path().join("x.png"), &gradient(4, 4)).unwrap();
    let m = serde_json::json!([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 3], [0, 0, 0, 1]]);
    let frames = |n: usize| serde_json::json!({"camera_angle_x": 1.0, "frames": vec![serde_json::json!({"file_path": "x", "transform_matrix": m}); n]});
    std::fs::write(dir.path().join("transforms_train.json"), frames(3).to_string()).unwrap();
    std::fs::write(dir.path().join("transforms_test.json"), frames(2).to_string()).unwrap();
    let ds = load_dataset(dir.path(), &LoadOptions::default()).unwrap();
    assert_eq!(ds.split(Split::Test).iter().map(|f| f.index).collect::<Vec<_>>(), [3, 4]);
    assert_eq!(ds.split(Split::Train).len(), 3);
    // Degenerate camera spread: the scale falls back to 1.
    assert_eq!(ds.frames[0].camera.znear, DEFAULT_ZNEAR);
}

#[test]
fn lego_200_loads() {
    let Some(dir) = common::shared_data("lego-200") else { return };
    let ds = load_dataset(&dir, &LoadOptions::default()).unwrap();
    assert_eq!(ds.frames.len(), 100);
    assert_eq!(ds.split(Split::Test).len(), 13);
    let f = &ds.frames[0];
    assert_eq!((f.image.get().unwrap().width, f.image.get().unwrap().height), (200, 200));
    assert!((f.camera.fx - 100.0 / (0.691_111_2f32 / 2.0).tan()).abs() < 1e-3);
    // Cameras look at the object near the origin.
    let c: Camera = f.camera;
    assert!(c.to_camera(Vec3::ZERO).z > 2.0);
    assert!(ds.frames.iter().all(|f| f.image.get().unwrap().data.iter().all(|v| (0.0..=1.0).contains(v))));
}

#[test]
fn colmap_every_camera_model_loads_from_bin_and_txt() {
    let n = gscodec::io::lens::COLMAP_MODELS.len();
    let names: &'static [String] = (0..n).map(|i| format!("m{i:02}.png")).collect::<Vec<_>>().leak();
    let (f, cx, cy) = (30.0, 16.0, 12.0);
    let cams: Vec<Cam> = gscodec::io::lens::COLMAP_MODELS
        .iter()
        .map(|&(id, name, params)| {
            let p: Vec<f64> = params
                .iter()
                .map(|&n| match n {
                    "f" | "fx" | "fy" => f,
                    "cx" => cx,
                    "cy" => cy,
                    "omega" => 0.5,
                    "k" | "k1" => -0.05,
                    "alpha" => 0.5,
                    "beta" => 1.0,
                    _ => 0.001,
                })
                .collect();
            (id as u32 + 1, id, name, 32, 24, p)
        })
        .collect();
    let imgs: Vec<Img> =
        (0..n).map(|i| (i as u32 + 1, [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 4.0 + i as f64], i as u32 + 1, names[i].as_str())).collect();
    let m = Model { cams, imgs, pts: model().pts };
    let (b, t) = (colmap_dir(&m, true), colmap_dir(&m, false));
    let (db, dt) = (load_dataset(b.path(), &LoadOptions::default()).unwrap(), load_dataset(t.path(), &LoadOptions::default()).unwrap());
    assert_eq!(db.frames.len(), n);
    for (x, y) in db.frames.iter().zip(&dt.frames) {
        assert_eq!((&x.name, x.camera, &*x.image.get().unwrap()), (&y.name, y.camera, &*y.image.get().unwrap()));
        let c = &x.camera;
        assert_eq!((c.width, c.height), (x.image.get().unwrap().width, x.image.get().unwrap().height));
        assert!(c.width >= 16 && c.height >= 12 && c.width <= 64 && c.height <= 48, "{}: {c:?}", x.name);
    }
    // Pinhole models keep their intrinsics; the others are resampled to a pinhole camera.
    assert_eq!((db.frames[1].camera.fx, db.frames[1].camera.cx, db.frames[1].camera.width), (30.0, 16.0, 32));
    // OPENCV with k1 = -0.05 (barrel): the undistorted field is wider, the focal length is kept.
    let c = &db.frames[4].camera;
    assert!(c.fx == 30.0 && c.cx > 16.1 && c.cx < 16.5 && c.cy > 12.0, "{c:?}");
    // Undistorted images are cached: a second load reads the cache and gives the same frames.
    assert!(b.path().join(".gscodec-cache").read_dir().unwrap().count() >= 9);
    let again = load_dataset(b.path(), &LoadOptions::default()).unwrap();
    assert!(again.frames.iter().zip(&db.frames).all(|(x, y)| x.image.get().unwrap() == y.image.get().unwrap() && x.camera == y.camera));
}

#[test]
fn random_initial_points_lie_in_the_cameras_frusta_and_the_aabb() {
    let dir = tempfile::tempdir().unwrap();
    write_png(&dir.path().join("x.png"), &gradient(40, 30)).unwrap();
    // Two cameras at z = 6 and x = 6 looking at the origin with a narrow field (0.4 rad).
    let json = serde_json::json!({"camera_angle_x": 0.4, "aabb_scale": 2, "frames": [
        {"file_path": "x", "transform_matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 6], [0, 0, 0, 1]]},
        {"file_path": "x", "transform_matrix": [[0, 0, 1, 6], [0, 1, 0, 0], [-1, 0, 0, 0], [0, 0, 0, 1]]},
    ]});
    std::fs::write(dir.path().join("transforms.json"), json.to_string()).unwrap();
    let ds = load_dataset(dir.path(), &LoadOptions::default()).unwrap();
    // instant-ngp: the cube of side aabb_scale in its units (scale 0.33) around the origin.
    let (c, half) = ds.bounds.unwrap();
    assert_eq!(c, [0.0; 3]);
    assert!((half - 2.0 / 0.66).abs() < 1e-5);
    let s = gscodec::train::init::random(&ds, 500, 0, &mut gscodec::rng::Rng::new(1));
    assert_eq!(s.len(), 500);
    let seen = |p: Vec3| {
        ds.frames.iter().any(|f| {
            let q = f.camera.to_camera(p);
            let (u, v) = (f.camera.fx * q.x / q.z + f.camera.cx, f.camera.fy * q.y / q.z + f.camera.cy);
            q.z > f.camera.znear && (0.0..40.0).contains(&u) && (0.0..30.0).contains(&v)
        })
    };
    for p in &s.positions {
        assert!(p.iter().all(|v| v.abs() <= half), "{p:?} outside the aabb");
        assert!(seen(Vec3::from_array(*p)), "{p:?} is in no camera's view");
    }
}

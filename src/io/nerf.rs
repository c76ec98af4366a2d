//! NeRF / Blender / nerfstudio datasets: `transforms*.json` with images beside them.
//!
//! Intrinsics come from `camera_angle_x` (and optionally `camera_angle_y`) or from
//! `fl_x`/`fl_y`/`cx`/`cy`/`w`/`h`, and distortion from `k1 k2 k3 k4 p1 p2` with `camera_model`
//! (`OPENCV`, the default when coefficients are given, or `OPENCV_FISHEYE`, as nerfstudio writes;
//! `PINHOLE`/`SIMPLE_PINHOLE` take no coefficients), all at the top level or per frame (per-frame
//! keys win). When the image on disk is not the `w × h` the file declares, the intrinsics are
//! scaled to the image. `transform_matrix` is camera-to-world in OpenGL axes. `file_path` is
//! relative to the JSON file and may omit the extension (`.png`, `.jpg`, `.jpeg` are tried). RGBA
//! images are composited on white (or `--background`). Frames whose image is missing are skipped
//! with one warning that counts them. Distorted images are undistorted once ([`super::prepare`]).

use super::lens::{Distortion, Lens};
use super::prepare::{downscaled_twin, plan_image, Source, CACHE_DIR};
use super::stream::FrameImage;
use super::{Dataset, Frame, LoadOptions};
use crate::{Error, Result};
use gscodec_decoder::Camera;
use rayon::prelude::*;
use serde_json::Value;
use std::path::{Path, PathBuf};

/// NeRF-synthetic images are composited on white.
pub const NERF_BACKGROUND: [f32; 3] = [1.0; 3];

/// Loads `train` (and, when given, `test`, whose frames become the test split) transforms files.
pub fn load_nerf(train: &Path, test: Option<&Path>, opts: &LoadOptions) -> Result<Dataset> {
    let bounds = read_bounds(train)?;
    let mut specs = parse_transforms(train)?;
    let n_train = specs.len();
    if let Some(test) = test {
        specs.extend(parse_transforms(test)?);
    }
    let total = specs.len();
    let loaded: Vec<Option<Frame>> =
        specs.into_par_iter().enumerate().map(|(index, spec)| spec.load(index, opts)).collect::<Result<_>>()?;
    let missing = loaded.iter().filter(|f| f.is_none()).count();
    if missing == total {
        return Err(Error::input(train, format!("none of the {total} frames' image files exist")));
    }
    if missing > 0 {
        eprintln!("warning: {}: skipped {missing} of {total} frames whose image file is missing", train.display());
    }
    let frames: Vec<Frame> = loaded.into_iter().flatten().collect();
    let test_indices = test.map(|_| frames.iter().map(|f| f.index).filter(|&i| i >= n_train).collect());
    Ok(Dataset { frames, background: opts.background.unwrap_or(NERF_BACKGROUND), points: Vec::new(), test_indices, bounds })
}

/// One frame as the JSON describes it, before its image is read.
pub(crate) struct FrameSpec {
    json: PathBuf,
    /// The JSON file's folder (the cache goes in it).
    dir: PathBuf,
    image: Option<PathBuf>,
    c2w: [[f32; 4]; 4],
    intr: Intrinsics,
}

/// Camera intrinsics keys; any may be absent.
#[derive(Clone, Default)]
struct Intrinsics {
    camera_model: Option<String>,
    /// `k1 k2 k3 k4 p1 p2`.
    dist: [Option<f64>; 6],
    angle_x: Option<f64>,
    angle_y: Option<f64>,
    fl_x: Option<f64>,
    fl_y: Option<f64>,
    cx: Option<f64>,
    cy: Option<f64>,
    w: Option<f64>,
    h: Option<f64>,
}

impl Intrinsics {
    fn read(v: &Value, base: &Intrinsics, bad: &dyn Fn(String) -> Error) -> Result<Intrinsics> {
        let get = |key: &str, old: Option<f64>| -> Result<Option<f64>> {
            match v.get(key) {
                None | Some(Value::Null) => Ok(old),
                Some(x) => match x.as_f64() {
                    Some(f) if f.is_finite() && f > 0.0 => Ok(Some(f)),
                    _ => Err(bad(format!("`{key}` must be a positive number, got {x}"))),
                },
            }
        };
        let mut dist = base.dist;
        for (d, key) in dist.iter_mut().zip(DISTORTION_KEYS) {
            match v.get(key) {
                None | Some(Value::Null) => {}
                Some(x) => match x.as_f64() {
                    Some(f) if f.is_finite() => *d = Some(f),
                    _ => return Err(bad(format!("`{key}` must be a finite number, got {x}"))),
                },
            }
        }
        let camera_model = match v.get("camera_model") {
            None | Some(Value::Null) => base.camera_model.clone(),
            Some(Value::String(m)) => Some(m.clone()),
            Some(x) => return Err(bad(format!("`camera_model` must be a string, got {x}"))),
        };
        Ok(Intrinsics {
            camera_model,
            dist,
            angle_x: get("camera_angle_x", base.angle_x)?,
            angle_y: get("camera_angle_y", base.angle_y)?,
            fl_x: get("fl_x", base.fl_x)?,
            fl_y: get("fl_y", base.fl_y)?,
            cx: get("cx", base.cx)?,
            cy: get("cy", base.cy)?,
            w: get("w", base.w)?,
            h: get("h", base.h)?,
        })
    }
}

/// instant-ngp's default scale from the transforms' units to its unit cube.
pub const NGP_SCALE: f64 = 0.33;

/// The scene cube of an instant-ngp style `aabb_scale` (with its `scale`, default
/// [`NGP_SCALE`]): instant-ngp maps `p ↦ p·scale + 0.5` and bounds the scene by the cube of side
/// `aabb_scale` around `(0.5, 0.5, 0.5)`, i.e. the cube of half side `aabb_scale / (2·scale)` around
/// the origin in the file's units. (`offset` is not read: the default centring is assumed.)
fn read_bounds(path: &Path) -> Result<Option<([f32; 3], f32)>> {
    let bad = |msg: String| Error::input(path, msg);
    let text = std::fs::read_to_string(path).map_err(|e| bad(format!("cannot read: {e}")))?;
    let root: Value = serde_json::from_str(&text).map_err(|e| bad(format!("invalid JSON: {e}")))?;
    let positive = |key: &str| match root.get(key) {
        None | Some(Value::Null) => Ok(None),
        Some(x) => match x.as_f64() {
            Some(f) if f.is_finite() && f > 0.0 => Ok(Some(f)),
            _ => Err(bad(format!("`{key}` must be a positive number, got {x}"))),
        },
    };
    let scale = positive("scale")?.unwrap_or(NGP_SCALE);
    Ok(positive("aabb_scale")?.map(|k| ([0.0; 3], (k / (2.0 * scale)) as f32)))
}

/// The distortion keys, in [`Intrinsics::dist`]'s order.
const DISTORTION_KEYS: [&str; 6] = ["k1", "k2", "k3", "k4", "p1", "p2"];

pub(crate) fn parse_transforms(path: &Path) -> Result<Vec<FrameSpec>> {
    let bad = |msg: String| Error::input(path, msg);
    let text = std::fs::read_to_string(path).map_err(|e| bad(format!("cannot read: {e}")))?;
    let root: Value = serde_json::from_str(&text).map_err(|e| bad(format!("invalid JSON: {e}")))?;
    let global = Intrinsics::read(&root, &Intrinsics::default(), &bad)?;
    let frames = root.get("frames").and_then(Value::as_array).ok_or_else(|| bad("no `frames` array".into()))?;
    let dir = path.parent().unwrap_or(Path::new("."));
    frames
        .iter()
        .enumerate()
        .map(|(i, f)| {
            let badf = |msg: String| bad(format!("frame {i}: {msg}"));
            let intr = Intrinsics::read(f, &global, &badf)?;
            if intr.fl_x.is_none() && intr.angle_x.is_none() {
                return Err(badf("no focal length (`camera_angle_x` or `fl_x`)".into()));
            }
            let file = f.get("file_path").and_then(Value::as_str).ok_or_else(|| badf("no `file_path` string".into()))?;
            let c2w = parse_matrix(f.get("transform_matrix"))
                .ok_or_else(|| badf("`transform_matrix` must be a 4x4 (or 3x4) array of finite numbers".into()))?;
            Ok(FrameSpec { json: path.to_path_buf(), dir: dir.to_path_buf(), image: find_image(&dir.join(file)), c2w, intr })
        })
        .collect()
}

fn parse_matrix(v: Option<&Value>) -> Option<[[f32; 4]; 4]> {
    let rows = v?.as_array()?;
    if rows.len() != 3 && rows.len() != 4 {
        return None;
    }
    let mut m = [[0.0, 0.0, 0.0, 1.0]; 4];
    for (r, row) in rows.iter().enumerate() {
        let row = row.as_array().filter(|a| a.len() == 4)?;
        for (c, x) in row.iter().enumerate() {
            m[r][c] = x.as_f64().filter(|f| f.is_finite())? as f32;
        }
    }
    Some(m)
}

/// The image file for a `file_path`: as given, or with a common extension appended.
fn find_image(p: &Path) -> Option<PathBuf> {
    if p.is_file() {
        return Some(p.to_path_buf());
    }
    ["png", "jpg", "jpeg", "PNG", "JPG", "JPEG"].iter().find_map(|ext| {
        let mut s = p.as_os_str().to_os_string();
        s.push(".");
        s.push(ext);
        let q = PathBuf::from(s);
        q.is_file().then_some(q)
    })
}

impl FrameSpec {
    /// Plans the image and builds the camera; `None` when the image file is missing.
    fn load(self, index: usize, opts: &LoadOptions) -> Result<Option<Frame>> {
        let Some(path) = &self.image else { return Ok(None) };
        let bad = |m: String| Error::input(&self.json, format!("frame {index}: {m}"));
        // Intrinsics without `w`/`h` are for the full-size image, even when a smaller twin is read.
        let (w, h) = image::image_dimensions(path).map_err(|e| Error::input(path, format!("cannot read image: {e}")))?;
        let lens = self.lens(w, h).map_err(bad)?;
        let twin = downscaled_twin(path, opts.downscale);
        let downscale = if twin.is_some() { 1 } else { opts.downscale };
        let src =
            Source { path: twin.unwrap_or_else(|| path.clone()), lens, downscale, background: opts.background.unwrap_or(NERF_BACKGROUND) };
        let planned = plan_image(src, opts, Some(&self.dir.join(CACHE_DIR)))?;
        let pin = *planned.lens();
        let camera = Camera::from_nerf_c2w(self.c2w, pin.width, pin.height, pin.fx as f32, pin.fy as f32, pin.cx as f32, pin.cy as f32);
        let name = path.file_name().unwrap_or_default().to_string_lossy().into_owned();
        Ok(Some(Frame { index, name, camera, image: FrameImage::planned(planned) }))
    }

    /// The lens of this frame for an image of `w × h` pixels on disk (intrinsics declared for
    /// another `w × h` are scaled to it).
    pub(crate) fn lens(&self, w: u32, h: u32) -> std::result::Result<Lens, String> {
        let i = &self.intr;
        let (wf, hf) = (w as f64, h as f64);
        let (decl_w, decl_h) = (i.w.unwrap_or(wf), i.h.unwrap_or(hf));
        let fx = i.fl_x.unwrap_or_else(|| 0.5 * decl_w / (0.5 * i.angle_x.unwrap()).tan());
        let fy = i.fl_y.or_else(|| i.angle_y.map(|a| 0.5 * decl_h / (0.5 * a).tan())).unwrap_or(fx);
        let (cx, cy) = (i.cx.unwrap_or(decl_w / 2.0), i.cy.unwrap_or(decl_h / 2.0));
        if !(fx.is_finite() && fy.is_finite() && fx > 0.0 && fy > 0.0) {
            return Err("bad focal length".into());
        }
        let d = i.dist.map(|v| v.unwrap_or(0.0));
        let any = d.iter().any(|&v| v != 0.0);
        let distortion = match i.camera_model.as_deref() {
            None | Some("OPENCV") => Distortion::RadialTangential { k: [d[0], d[1], d[2], d[3]], p: [d[4], d[5]] },
            Some("OPENCV_FISHEYE") if d[4] == 0.0 && d[5] == 0.0 => {
                Distortion::Fisheye { k: [d[0], d[1], d[2], d[3]], p: [0.0; 2], s: [0.0; 2] }
            }
            Some("OPENCV_FISHEYE") => return Err("OPENCV_FISHEYE takes k1..k4 only, not p1/p2".into()),
            Some("PINHOLE" | "SIMPLE_PINHOLE") if !any => Distortion::None,
            Some(m @ ("PINHOLE" | "SIMPLE_PINHOLE")) => return Err(format!("camera_model {m} with distortion coefficients")),
            Some(m) => return Err(format!("unsupported camera_model `{m}` (OPENCV, OPENCV_FISHEYE, PINHOLE are read)")),
        };
        let (sx, sy) = (wf / decl_w, hf / decl_h);
        Lens::new(w, h, [fx * sx, fy * sy, cx * sx, cy * sy], distortion)
    }

    /// The pinhole camera (distortion ignored) for an image of `w × h` pixels on disk, downscaled by `k`.
    pub(crate) fn camera(&self, w: u32, h: u32, k: u32) -> std::result::Result<Camera, String> {
        let l = self.lens(w, h)?;
        let kf = k.max(1) as f64;
        let (w, h) = (w / k.max(1), h / k.max(1));
        Ok(Camera::from_nerf_c2w(self.c2w, w, h, (l.fx / kf) as f32, (l.fy / kf) as f32, (l.cx / kf) as f32, (l.cy / kf) as f32))
    }
}

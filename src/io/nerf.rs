//! NeRF / Blender datasets: `transforms*.json` with images beside them.
//!
//! Intrinsics come from `camera_angle_x` (and optionally `camera_angle_y`) or from
//! `fl_x`/`fl_y`/`cx`/`cy`/`w`/`h`, at the top level or per frame (per-frame keys win). When the
//! image on disk is not the `w × h` the file declares, the intrinsics are scaled to the image.
//! `transform_matrix` is camera-to-world in OpenGL axes. `file_path` is relative to the JSON file
//! and may omit the extension (`.png`, `.jpg`, `.jpeg` are tried). RGBA images are composited on
//! white. Frames whose image is missing are skipped with one warning that counts them.

use super::image::{downscale, load_image};
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
    Ok(Dataset { frames, background: NERF_BACKGROUND, points: Vec::new(), test_indices })
}

/// One frame as the JSON describes it, before its image is read.
pub(crate) struct FrameSpec {
    json: PathBuf,
    image: Option<PathBuf>,
    c2w: [[f32; 4]; 4],
    intr: Intrinsics,
}

/// Camera intrinsics keys; any may be absent.
#[derive(Clone, Copy, Default)]
struct Intrinsics {
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
    fn read(v: &Value, base: Intrinsics, bad: &dyn Fn(String) -> Error) -> Result<Intrinsics> {
        let get = |key: &str, old: Option<f64>| -> Result<Option<f64>> {
            match v.get(key) {
                None | Some(Value::Null) => Ok(old),
                Some(x) => match x.as_f64() {
                    Some(f) if f.is_finite() && f > 0.0 => Ok(Some(f)),
                    _ => Err(bad(format!("`{key}` must be a positive number, got {x}"))),
                },
            }
        };
        Ok(Intrinsics {
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

pub(crate) fn parse_transforms(path: &Path) -> Result<Vec<FrameSpec>> {
    let bad = |msg: String| Error::input(path, msg);
    let text = std::fs::read_to_string(path).map_err(|e| bad(format!("cannot read: {e}")))?;
    let root: Value = serde_json::from_str(&text).map_err(|e| bad(format!("invalid JSON: {e}")))?;
    let global = Intrinsics::read(&root, Intrinsics::default(), &bad)?;
    let frames = root.get("frames").and_then(Value::as_array).ok_or_else(|| bad("no `frames` array".into()))?;
    let dir = path.parent().unwrap_or(Path::new("."));
    frames
        .iter()
        .enumerate()
        .map(|(i, f)| {
            let badf = |msg: String| bad(format!("frame {i}: {msg}"));
            let intr = Intrinsics::read(f, global, &badf)?;
            if intr.fl_x.is_none() && intr.angle_x.is_none() {
                return Err(badf("no focal length (`camera_angle_x` or `fl_x`)".into()));
            }
            let file = f.get("file_path").and_then(Value::as_str).ok_or_else(|| badf("no `file_path` string".into()))?;
            let c2w = parse_matrix(f.get("transform_matrix"))
                .ok_or_else(|| badf("`transform_matrix` must be a 4x4 (or 3x4) array of finite numbers".into()))?;
            Ok(FrameSpec { json: path.to_path_buf(), image: find_image(&dir.join(file)), c2w, intr })
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
    /// Loads the image and builds the camera; `None` when the image file is missing.
    fn load(self, index: usize, opts: &LoadOptions) -> Result<Option<Frame>> {
        let Some(path) = &self.image else { return Ok(None) };
        let full = load_image(path, NERF_BACKGROUND)?;
        let image = downscale(&full, opts.downscale);
        let camera =
            self.camera(full.width, full.height, opts.downscale).map_err(|m| Error::input(&self.json, format!("frame {index}: {m}")))?;
        let camera = gscodec_decoder::Camera { width: image.width, height: image.height, ..camera };
        let name = path.file_name().unwrap_or_default().to_string_lossy().into_owned();
        Ok(Some(Frame { index, name, camera, image }))
    }

    /// The camera for an image of `w × h` pixels on disk, downscaled by `k`.
    pub(crate) fn camera(&self, w: u32, h: u32, k: u32) -> std::result::Result<Camera, String> {
        let (w, h) = (w as f64, h as f64);
        let i = self.intr;
        // Intrinsics are given for a `w × h` image (default: the image as it is on disk).
        let (decl_w, decl_h) = (i.w.unwrap_or(w), i.h.unwrap_or(h));
        let (sx, sy) = (w / decl_w, h / decl_h);
        let fx = i.fl_x.unwrap_or_else(|| 0.5 * decl_w / (0.5 * i.angle_x.unwrap()).tan());
        let fy = i.fl_y.or_else(|| i.angle_y.map(|a| 0.5 * decl_h / (0.5 * a).tan())).unwrap_or(fx);
        let (cx, cy) = (i.cx.unwrap_or(decl_w / 2.0), i.cy.unwrap_or(decl_h / 2.0));
        if !(fx.is_finite() && fy.is_finite() && fx > 0.0 && fy > 0.0) {
            return Err("bad focal length".into());
        }
        let k = k.max(1);
        let kf = k as f64;
        Ok(Camera::from_nerf_c2w(
            self.c2w,
            w as u32 / k,
            h as u32 / k,
            (fx * sx / kf) as f32,
            (fy * sy / kf) as f32,
            (cx * sx / kf) as f32,
            (cy * sy / kf) as f32,
        ))
    }
}

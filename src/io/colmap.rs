//! COLMAP sparse models: `sparse/0/{cameras,images,points3D}.{bin,txt}` plus `images/`.
//!
//! Every perspective camera model COLMAP defines is read (see [`super::lens::COLMAP_MODELS`] for
//! the parameter orders; the spherical `EQUIRECTANGULAR` is refused naming it); distorted images are undistorted to pinhole once, when loading ([`super::prepare`]).
//! Poses are world-to-camera in OpenCV axes. With `--downscale N`, images come from `images_N/`
//! when the dataset has it (the 3DGS convention). Frames are ordered by
//! image name (as the reference 3DGS does), so the `% 8` test split matches it. Images whose file
//! is missing are skipped with one warning; when an image's size differs from its camera's, the
//! intrinsics are scaled to the image.

use super::lens::{colmap_model_error, Lens, COLMAP_MODELS};
use super::prepare::{plan_image, Source, CACHE_DIR};
use super::stream::FrameImage;
use super::{Dataset, Frame, LoadOptions};
use crate::{Error, Result};
use glam::{Mat3, Quat, Vec3};
use gscodec_decoder::Camera;
use rayon::prelude::*;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// COLMAP datasets have no alpha; renders use a black background like the reference 3DGS.
pub const COLMAP_BACKGROUND: [f32; 3] = [0.0; 3];

/// A COLMAP camera as stored.
#[derive(Debug, Clone, PartialEq)]
pub struct ColmapCamera {
    pub model: String,
    pub width: u64,
    pub height: u64,
    pub params: Vec<f64>,
}

/// A registered image as stored.
#[derive(Debug, Clone, PartialEq)]
pub struct ColmapImage {
    pub id: u32,
    /// World-to-camera rotation `(w, x, y, z)`.
    pub qvec: [f64; 4],
    pub tvec: [f64; 3],
    pub camera_id: u32,
    pub name: String,
}

/// A sparse model: cameras by id, images in file order, points (position, colour).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ColmapModel {
    pub cameras: HashMap<u32, ColmapCamera>,
    pub images: Vec<ColmapImage>,
    pub points: Vec<([f64; 3], [u8; 3])>,
}

/// The sparse model directory of a COLMAP dataset directory (`sparse/0`, `sparse`, or itself).
pub fn find_sparse(dir: &Path) -> Option<PathBuf> {
    [dir.join("sparse/0"), dir.join("sparse"), dir.to_path_buf()]
        .into_iter()
        .find(|d| d.join("cameras.bin").is_file() || d.join("cameras.txt").is_file())
}

/// Reads a sparse model, preferring `.bin` files over `.txt` (per file).
pub fn read_model(sparse: &Path) -> Result<ColmapModel> {
    let pick = |stem: &str| {
        let bin = sparse.join(format!("{stem}.bin"));
        if bin.is_file() {
            (bin, true)
        } else {
            (sparse.join(format!("{stem}.txt")), false)
        }
    };
    let (p, bin) = pick("cameras");
    let cameras = if bin { read_cameras_bin(&p) } else { read_cameras_txt(&p) }?;
    let (p, bin) = pick("images");
    let images = if bin { read_images_bin(&p) } else { read_images_txt(&p) }?;
    for im in &images {
        if !cameras.contains_key(&im.camera_id) {
            return Err(Error::input(&p, format!("image `{}` refers to missing camera {}", im.name, im.camera_id)));
        }
    }
    let (p, bin) = pick("points3D");
    let points = if !p.exists() {
        Vec::new()
    } else if bin {
        read_points_bin(&p)?
    } else {
        read_points_txt(&p)?
    };
    Ok(ColmapModel { cameras, images, points })
}

/// Loads a COLMAP dataset directory (`DIR/sparse/0` + `DIR/images`).
pub fn load_colmap(dir: &Path, opts: &LoadOptions) -> Result<Dataset> {
    let sparse = find_sparse(dir).ok_or_else(|| Error::input(dir, "no COLMAP model (sparse/0/cameras.{bin,txt})"))?;
    let model = read_model(&sparse)?;
    let cam_file = if sparse.join("cameras.bin").is_file() { sparse.join("cameras.bin") } else { sparse.join("cameras.txt") };
    let mut lenses = HashMap::new();
    for (&id, c) in &model.cameras {
        let size = |v: u64| u32::try_from(v).map_err(|_| Error::input(&cam_file, format!("camera {id}: image size {v} too large")));
        let lens = Lens::from_colmap(&c.model, size(c.width)?, size(c.height)?, &c.params)
            .map_err(|m| Error::input(&cam_file, format!("camera {id}: {m}")))?;
        lenses.insert(id, lens);
    }
    let mut images = model.images.clone();
    images.sort_by(|a, b| a.name.cmp(&b.name));
    let image_dir = dir.join("images");
    let k = opts.downscale.max(1);
    let twin_dir = dir.join(format!("images_{k}"));
    let use_twin = k > 1 && twin_dir.is_dir();
    let background = opts.background.unwrap_or(COLMAP_BACKGROUND);
    let cache = dir.join(CACHE_DIR);
    let total = images.len();
    let loaded: Vec<Option<Frame>> = images
        .into_par_iter()
        .enumerate()
        .map(|(index, im)| {
            let full = image_dir.join(&im.name);
            let twin = twin_dir.join(&im.name);
            let path = if use_twin && twin.is_file() { &twin } else { &full };
            if !path.is_file() {
                return Ok(None);
            }
            let src = Source { path: path.clone(), lens: lenses[&im.camera_id], downscale: if path == &twin { 1 } else { k }, background };
            let planned = plan_image(src, opts, Some(&cache))?;
            let pin = *planned.lens();
            let [w, x, y, z] = im.qvec;
            let rotation = Mat3::from_quat(Quat::from_xyzw(x as f32, y as f32, z as f32, w as f32).normalize());
            let translation = Vec3::new(im.tvec[0] as f32, im.tvec[1] as f32, im.tvec[2] as f32);
            let mut camera = Camera::new(pin.width, pin.height, pin.fx as f32, pin.fy as f32, rotation, translation);
            camera.cx = pin.cx as f32;
            camera.cy = pin.cy as f32;
            Ok(Some(Frame { index, name: im.name.clone(), camera, image: FrameImage::planned(planned) }))
        })
        .collect::<Result<_>>()?;
    let missing = loaded.iter().filter(|f| f.is_none()).count();
    if total == 0 || missing == total {
        return Err(Error::input(&image_dir, format!("none of the {total} registered images exist")));
    }
    if missing > 0 {
        eprintln!("warning: {}: skipped {missing} of {total} images whose file is missing", image_dir.display());
    }
    let points = model.points.iter().map(|(p, c)| (p.map(|v| v as f32), c.map(|v| v as f32 / 255.0))).collect();
    Ok(Dataset { frames: loaded.into_iter().flatten().collect(), background, points, test_indices: None, bounds: None })
}

// ---------------------------------------------------------------------------------------------
// Binary files

/// A bounds-checked little-endian reader over a whole file.
struct Bin<'a> {
    path: &'a Path,
    data: Vec<u8>,
    at: usize,
}

impl<'a> Bin<'a> {
    fn open(path: &'a Path) -> Result<Self> {
        let data = std::fs::read(path).map_err(|e| Error::input(path, format!("cannot read: {e}")))?;
        Ok(Bin { path, data, at: 0 })
    }
    fn take(&mut self, n: usize) -> Result<&[u8]> {
        if self.data.len() - self.at < n {
            return Err(Error::input(self.path, format!("truncated at byte {}", self.at)));
        }
        self.at += n;
        Ok(&self.data[self.at - n..self.at])
    }
    fn u64(&mut self) -> Result<u64> {
        Ok(u64::from_le_bytes(self.take(8)?.try_into().unwrap()))
    }
    fn i32(&mut self) -> Result<i32> {
        Ok(i32::from_le_bytes(self.take(4)?.try_into().unwrap()))
    }
    fn f64(&mut self) -> Result<f64> {
        Ok(f64::from_le_bytes(self.take(8)?.try_into().unwrap()))
    }
    fn u8(&mut self) -> Result<u8> {
        Ok(self.take(1)?[0])
    }
    /// A count of records of at least `min_size` bytes each, checked against the bytes left.
    fn count(&mut self, min_size: usize) -> Result<usize> {
        let n = self.u64()?;
        let left = (self.data.len() - self.at) as u128;
        if n as u128 * min_size as u128 > left {
            return Err(Error::input(self.path, format!("count {n} at byte {} exceeds the file size", self.at - 8)));
        }
        Ok(n as usize)
    }
    fn bad(&self, msg: impl std::fmt::Display) -> Error {
        Error::input(self.path, msg)
    }
    fn finish(&self) -> Result<()> {
        if self.at != self.data.len() {
            return Err(self.bad(format!("{} unexpected bytes at the end", self.data.len() - self.at)));
        }
        Ok(())
    }
}

fn check_finite(path: &Path, what: &str, v: &[f64]) -> Result<()> {
    if v.iter().all(|x| x.is_finite()) {
        Ok(())
    } else {
        Err(Error::input(path, format!("{what}: non-finite value in {v:?}")))
    }
}

fn read_cameras_bin(path: &Path) -> Result<HashMap<u32, ColmapCamera>> {
    let mut b = Bin::open(path)?;
    let n = b.count(24)?;
    let mut out = HashMap::new();
    for _ in 0..n {
        let id = b.i32()? as u32;
        let model_id = b.i32()?;
        let &(_, name, names) = COLMAP_MODELS
            .iter()
            .find(|m| m.0 == model_id)
            .ok_or_else(|| b.bad(format!("camera {id}: {}", colmap_model_error(Some(model_id), None))))?;
        let (width, height) = (b.u64()?, b.u64()?);
        let params = (0..names.len()).map(|_| b.f64()).collect::<Result<Vec<_>>>()?;
        check_finite(path, &format!("camera {id}"), &params)?;
        out.insert(id, ColmapCamera { model: name.to_string(), width, height, params });
    }
    b.finish()?;
    Ok(out)
}

fn read_images_bin(path: &Path) -> Result<Vec<ColmapImage>> {
    let mut b = Bin::open(path)?;
    let n = b.count(4 + 56 + 4 + 1 + 8)?;
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        let id = b.i32()? as u32;
        let v: Vec<f64> = (0..7).map(|_| b.f64()).collect::<Result<_>>()?;
        check_finite(path, &format!("image {id}"), &v)?;
        let camera_id = b.i32()? as u32;
        let mut name = Vec::new();
        loop {
            match b.u8()? {
                0 => break,
                c => name.push(c),
            }
        }
        let name = String::from_utf8(name).map_err(|_| b.bad(format!("image {id}: name is not UTF-8")))?;
        let n2d = b.count(24)?;
        b.take(n2d * 24)?;
        out.push(ColmapImage { id, qvec: [v[0], v[1], v[2], v[3]], tvec: [v[4], v[5], v[6]], camera_id, name });
    }
    b.finish()?;
    Ok(out)
}

fn read_points_bin(path: &Path) -> Result<Vec<([f64; 3], [u8; 3])>> {
    let mut b = Bin::open(path)?;
    let n = b.count(8 + 24 + 3 + 8 + 8)?;
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        let id = b.u64()?;
        let p = [b.f64()?, b.f64()?, b.f64()?];
        check_finite(path, &format!("point {id}"), &p)?;
        let c = [b.u8()?, b.u8()?, b.u8()?];
        b.f64()?;
        let track = b.count(8)?;
        b.take(track * 8)?;
        out.push((p, c));
    }
    b.finish()?;
    Ok(out)
}

// ---------------------------------------------------------------------------------------------
// Text files

/// Non-comment lines with their 1-based line numbers.
fn text_lines(path: &Path) -> Result<Vec<(usize, String)>> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::input(path, format!("cannot read: {e}")))?;
    Ok(text.lines().enumerate().filter(|(_, l)| !l.trim_start().starts_with('#')).map(|(i, l)| (i + 1, l.to_string())).collect())
}

fn parse<T: std::str::FromStr>(path: &Path, line: usize, tok: Option<&str>) -> Result<T> {
    let tok = tok.ok_or_else(|| Error::input(path, format!("line {line}: too few fields")))?;
    tok.parse().map_err(|_| Error::input(path, format!("line {line}: cannot parse `{tok}`")))
}

fn read_cameras_txt(path: &Path) -> Result<HashMap<u32, ColmapCamera>> {
    let mut out = HashMap::new();
    for (ln, line) in text_lines(path)? {
        let mut t = line.split_whitespace();
        let Some(first) = t.next() else { continue };
        let id: u32 = parse(path, ln, Some(first))?;
        let model: String = parse(path, ln, t.next())?;
        let np = COLMAP_MODELS
            .iter()
            .find(|m| m.1 == model)
            .ok_or_else(|| Error::input(path, format!("line {ln}: {}", colmap_model_error(None, Some(&model)))))?
            .2
            .len();
        let (width, height) = (parse(path, ln, t.next())?, parse(path, ln, t.next())?);
        let params = (0..np).map(|_| parse(path, ln, t.next())).collect::<Result<Vec<f64>>>()?;
        check_finite(path, &format!("line {ln}"), &params)?;
        out.insert(id, ColmapCamera { model, width, height, params });
    }
    Ok(out)
}

fn read_images_txt(path: &Path) -> Result<Vec<ColmapImage>> {
    let lines = text_lines(path)?;
    let mut out = Vec::new();
    let mut it = lines.iter();
    while let Some((ln, line)) = it.next() {
        let mut t = line.split_whitespace();
        let Some(first) = t.next() else { continue };
        let id: u32 = parse(path, *ln, Some(first))?;
        let v = (0..7).map(|_| parse(path, *ln, t.next())).collect::<Result<Vec<f64>>>()?;
        check_finite(path, &format!("line {ln}"), &v)?;
        let camera_id = parse(path, *ln, t.next())?;
        // The name is the rest of the line (it may contain spaces).
        let name = line.split_whitespace().skip(9).collect::<Vec<_>>().join(" ");
        if name.is_empty() {
            return Err(Error::input(path, format!("line {ln}: missing image name")));
        }
        it.next(); // the POINTS2D line (possibly empty)
        out.push(ColmapImage { id, qvec: [v[0], v[1], v[2], v[3]], tvec: [v[4], v[5], v[6]], camera_id, name });
    }
    Ok(out)
}

fn read_points_txt(path: &Path) -> Result<Vec<([f64; 3], [u8; 3])>> {
    let mut out = Vec::new();
    for (ln, line) in text_lines(path)? {
        let mut t = line.split_whitespace();
        if t.next().is_none() {
            continue;
        }
        let p = [parse(path, ln, t.next())?, parse(path, ln, t.next())?, parse(path, ln, t.next())?];
        check_finite(path, &format!("line {ln}"), &p)?;
        let c = [parse(path, ln, t.next())?, parse(path, ln, t.next())?, parse(path, ln, t.next())?];
        out.push((p, c));
    }
    Ok(out)
}

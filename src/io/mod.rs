//! Reading and writing scenes, datasets and images.

pub mod atomic;
pub mod colmap;
pub mod compressed_ply;
pub mod dataset;
pub mod gltf;
pub mod image;
pub mod lens;
pub mod nerf;
pub mod ply;
pub mod prepare;
pub mod scene;
pub mod sog;
pub mod splat;
pub mod spz;
pub mod stream;

pub use dataset::{Dataset, Frame, Split};
pub use ply::{read_ply, read_ply_bytes, write_ply};
pub use scene::{read_scene, read_scene_with, write_scene};
pub use stream::{FrameImage, DEFAULT_IMAGE_MEMORY};

use crate::{Error, Result};
use gscodec_decoder::camera::DEFAULT_ZNEAR;
use std::path::Path;

/// How to load a dataset (see [`prepare`] for the order of the steps).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LoadOptions {
    /// Integer image downscale factor; 1 = full resolution. Images come from an `images_N/`
    /// folder when the dataset has one, else through an exact `N×N` box filter.
    pub downscale: u32,
    /// Longest image side after the downscale (Lanczos-3 resize); `None` = no limit.
    pub max_size: Option<u32>,
    /// Read and write prepared images in `<dataset>/.gscodec-cache/`.
    pub cache: bool,
    /// Background colour (sRGB in [0,1]) for RGBA images and renders, instead of the layout's
    /// default (white for NeRF, black for COLMAP).
    pub background: Option<[f32; 3]>,
    /// Budget in bytes for the decoded images (f32 RGB, all frames): when they need more they
    /// are read on demand through a cache of this size ([`stream`]); `None` = no limit.
    pub image_memory: Option<u64>,
}

impl Default for LoadOptions {
    fn default() -> Self {
        LoadOptions { downscale: 1, max_size: None, cache: true, background: None, image_memory: Some(DEFAULT_IMAGE_MEMORY) }
    }
}

/// Loads a posed-image dataset directory, detecting its layout:
///
/// * NeRF / Blender: `transforms_train.json` (+ `transforms_test.json`, whose frames then form
///   the test split, appended after the training frames), or `transforms.json`. A path to a
///   `transforms*.json` file is accepted too.
/// * COLMAP: `sparse/0/{cameras,images,points3D}.{bin,txt}` and `images/`.
///
/// Every camera's near plane is scaled with the scene: `znear = 0.05 × s` (`DEFAULT_ZNEAR`; 0.2 for NeRF-synthetic, as the reference rasterizer), where `s` is the
/// median distance of the camera centres to their mean (1 when that is degenerate).
///
/// # Errors
/// [`Error::input`] naming the offending file for anything missing or malformed.
pub fn load_dataset(path: &Path, opts: &LoadOptions) -> Result<Dataset> {
    if opts.downscale == 0 {
        return Err(Error::input(path, "downscale factor must be at least 1"));
    }
    if opts.max_size == Some(0) {
        return Err(Error::input(path, "maximum image size must be at least 1 pixel"));
    }
    let mut ds = if path.is_file() {
        nerf::load_nerf(path, None, opts)?
    } else if path.join("transforms_train.json").is_file() {
        let test = path.join("transforms_test.json");
        nerf::load_nerf(&path.join("transforms_train.json"), test.is_file().then_some(test.as_path()), opts)?
    } else if path.join("transforms.json").is_file() {
        nerf::load_nerf(&path.join("transforms.json"), None, opts)?
    } else if colmap::find_sparse(path).is_some() {
        colmap::load_colmap(path, opts)?
    } else if !path.exists() {
        return Err(Error::input(path, "no such file or directory"));
    } else {
        return Err(Error::input(path, "not a dataset: expected transforms_train.json, transforms.json or a COLMAP sparse/0 model"));
    };
    if let Some(f) = ds.frames.iter().find(|f| f.camera.width == 0 || f.camera.height == 0) {
        return Err(Error::input(path, format!("frame `{}` is empty after downscaling by {}", f.name, opts.downscale)));
    }
    if opts.image_memory.is_some_and(|b| ds.frames.iter().map(|f| f.image.bytes()).sum::<u64>() > b) && !opts.cache {
        eprintln!("warning: {}: the images exceed the image memory budget and are read on demand; with --no-cache resized or undistorted ones are prepared again at every read", path.display());
    }
    stream::hold(&mut ds.frames, opts.image_memory)?;
    let znear = DEFAULT_ZNEAR * scene_scale(&ds);
    ds.frames.iter_mut().for_each(|f| f.camera.znear = znear);
    Ok(ds)
}

/// Median distance of the frames' camera centres to their mean; 1 when degenerate.
pub fn scene_scale(ds: &Dataset) -> f32 {
    camera_spread(ds.frames.iter().map(|f| f.camera.center()))
}

/// Median distance of camera centres to their mean; 1 when degenerate (none, one, all equal).
pub fn camera_spread(centres: impl Iterator<Item = glam::Vec3>) -> f32 {
    let centres: Vec<glam::Vec3> = centres.collect();
    if centres.is_empty() {
        return 1.0;
    }
    let mean = centres.iter().copied().sum::<glam::Vec3>() / centres.len() as f32;
    let mut d: Vec<f32> = centres.iter().map(|c| c.distance(mean)).collect();
    d.sort_by(f32::total_cmp);
    let m = d[d.len() / 2];
    if m.is_finite() && m > 0.0 {
        m
    } else {
        1.0
    }
}

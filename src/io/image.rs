//! Images: load PNG/JPEG (sRGB, alpha composited), write PNG (8-bit) and EXR (32-bit float).
//!
//! All images in gscodec are RGB floats in the renderer's colour space, which is the sRGB-encoded
//! [0,1] space the training photos are in (like the reference 3DGS: no linearisation anywhere).
//! PNG output clamps to [0,1] and rounds to 8 bits. EXR output stores the float values exactly as
//! rendered (unclamped): they are *not* converted to linear light, so an EXR viewer that assumes
//! linear data shows them lighter than the PNG; use EXR to keep full precision and out-of-range
//! values, not for colour-managed display.

use crate::io::atomic::write_bytes_atomic;
use crate::{Error, Result};
use gscodec_decoder::Image;
use std::path::Path;

/// Loads a PNG or JPEG as sRGB floats in [0,1], compositing any alpha channel on `background`
/// (`c·a + bg·(1−a)` in sRGB values, the NeRF-synthetic convention).
///
/// # Errors
/// [`Error::input`] when the file is missing or not a decodable image.
pub fn load_image(path: &Path, background: [f32; 3]) -> Result<Image> {
    let img = image::ImageReader::open(path)
        .map_err(|e| Error::input(path, format!("cannot read image: {e}")))?
        .with_guessed_format()
        .map_err(|e| Error::input(path, format!("cannot read image: {e}")))?
        .decode()
        .map_err(|e| Error::input(path, format!("cannot decode image: {e}")))?;
    let (width, height) = (img.width(), img.height());
    let mut data = Vec::with_capacity(width as usize * height as usize * 3);
    let mut put = |rgba: [f32; 4]| {
        for c in 0..3 {
            data.push(rgba[c] * rgba[3] + background[c] * (1.0 - rgba[3]));
        }
    };
    if img.color().bytes_per_pixel() / img.color().channel_count() > 1 {
        for p in img.to_rgba16().pixels() {
            put(p.0.map(|v| v as f32 / 65535.0));
        }
    } else {
        for p in img.to_rgba8().pixels() {
            put(p.0.map(|v| v as f32 / 255.0));
        }
    }
    Ok(Image { width, height, data })
}

/// Area (box) downscale by an integer factor `k`: output `floor(w/k) × floor(h/k)`, each pixel the
/// mean of a `k×k` block (the right/bottom remainder is dropped, so pixel geometry scales by exactly 1/k).
pub fn downscale(img: &Image, k: u32) -> Image {
    if k <= 1 {
        return img.clone();
    }
    let (w, h) = (img.width / k, img.height / k);
    let mut data = vec![0.0f32; w as usize * h as usize * 3];
    let inv = 1.0 / (k * k) as f32;
    for y in 0..h {
        for x in 0..w {
            let mut acc = [0.0f32; 3];
            for dy in 0..k {
                for dx in 0..k {
                    let p = img.pixel(x * k + dx, y * k + dy);
                    (0..3).for_each(|c| acc[c] += p[c]);
                }
            }
            let o = ((y * w + x) * 3) as usize;
            (0..3).for_each(|c| data[o + c] = acc[c] * inv);
        }
    }
    Image { width: w, height: h, data }
}

/// The 8-bit RGB values [`write_png`] stores: `round(clamp(v, 0, 1) · 255)` (NaN becomes 0).
pub fn to_rgb8(img: &Image) -> Vec<u8> {
    img.data.iter().map(|&v| (if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) } * 255.0).round() as u8).collect()
}

/// Writes an 8-bit RGB PNG (values clamped to [0,1] and rounded), atomically.
pub fn write_png(path: &Path, img: &Image) -> Result<()> {
    use image::ImageEncoder;
    let mut bytes = Vec::new();
    image::codecs::png::PngEncoder::new(&mut bytes)
        .write_image(&to_rgb8(img), img.width, img.height, image::ExtendedColorType::Rgb8)
        .map_err(|e| Error::failure(path, format!("cannot encode PNG: {e}")))?;
    write_bytes_atomic(path, &bytes)
}

/// Writes a 32-bit float RGB EXR with the values as rendered (see the module docs), atomically.
pub fn write_exr(path: &Path, img: &Image) -> Result<()> {
    use exr::prelude::*;
    let w = img.width as usize;
    let channels = SpecificChannels::rgb(|Vec2(x, y): Vec2<usize>| {
        let i = (y * w + x) * 3;
        (img.data[i], img.data[i + 1], img.data[i + 2])
    });
    let mut cursor = std::io::Cursor::new(Vec::new());
    exr::prelude::Image::from_channels((w, img.height as usize), channels)
        .write()
        .to_buffered(&mut cursor)
        .map_err(|e| crate::Error::failure(path, format!("cannot encode EXR: {e}")))?;
    write_bytes_atomic(path, &cursor.into_inner())
}

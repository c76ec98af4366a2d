//! From an image file and its lens to a training image and pinhole intrinsics: size reduction
//! (`--downscale`, `--max-size`), undistortion, and an on-disk cache of the result.
//!
//! Order: the file's own size fixes the lens (intrinsics declared for another size are scaled to
//! it); an integer `--downscale k` is an exact `k×k` box filter (`floor(w/k) × floor(h/k)`, every
//! coordinate ×1/k), `--max-size` then resizes with a Lanczos-3 filter so the longer side is at most
//! that many pixels, and a distorted lens is finally resampled to a pinhole camera at that size.
//!
//! Resizing keeps the image's corners at its corners: with the pixel-centre convention (pixel `i`
//! covers `[i, i+1)`, centre `i + 0.5`), the continuous coordinate maps as `x' = x·w'/w`, so
//! `fx' = fx·w'/w` and `cx' = cx·w'/w` exactly (not `(cx + 0.5)·w'/w − 0.5`, which is the rule for
//! the other, centre-at-integer convention).
//!
//! Results that took more than decoding (a downscale, resize or undistortion) are stored as 16-bit
//! PNGs under `<dataset>/.gscodec-cache/`, named by a hash of the source file (path, size,
//! modification time) and every setting that shapes the result; they are always rounded to 16 bits,
//! so a cached and a fresh load give identical pixels.

use super::image::{downscale, load_image};
use super::lens::{undistort_image, Lens};
use super::LoadOptions;
use crate::io::atomic::write_bytes_atomic;
use crate::{Error, Result};
use gscodec_decoder::Image;
use std::path::{Path, PathBuf};

/// Bumped whenever the preparation changes what it produces.
const CACHE_VERSION: u64 = 1;
/// The cache folder's name inside a dataset folder.
pub const CACHE_DIR: &str = ".gscodec-cache";

/// Whether the cache-write warning was printed (once per process, not once per image).
static CACHE_WARNED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// What [`prepare`] needs to know about one frame's image.
#[derive(Debug, Clone)]
pub struct Source {
    pub path: PathBuf,
    /// The lens, with intrinsics for an image of `lens.width × lens.height` (scaled to the file's
    /// real size when it differs).
    pub lens: Lens,
    /// The integer box downscale still to apply (1 when the file comes from an `images_N/` folder).
    pub downscale: u32,
    /// Background RGBA images are composited on.
    pub background: [f32; 3],
}

/// One frame's image, planned from its file's header but not read yet: its final size and
/// pinhole lens are known, [`Planned::load`] produces the pixels (the same ones every time).
#[derive(Debug, Clone)]
pub struct Planned {
    src: Source,
    /// The file's size when planned.
    file_size: (u32, u32),
    plan: Plan,
    /// Whether producing the image takes more than decoding the file (a downscale, resize or
    /// undistortion): such results are rounded to 16 bits and cached.
    slow: bool,
    /// The cache file, when caching is on and the image is slow to produce.
    cache: Option<PathBuf>,
}

/// Plans the preparation of `src` (reads the file's header only).
///
/// # Errors
/// An unreadable image header, an image empty after the downscale, or a lens with no
/// undistorted region.
pub fn plan_image(src: Source, opts: &LoadOptions, cache_dir: Option<&Path>) -> Result<Planned> {
    let path = &src.path;
    let (w, h) = image::image_dimensions(path).map_err(|e| Error::input(path, format!("cannot read image: {e}")))?;
    let plan = plan(&src.lens.resized(w, h), src.downscale, opts.max_size).map_err(|m| Error::input(path, m))?;
    let slow = plan.downscale > 1 || plan.resize.is_some() || !plan.source.is_pinhole();
    let cache = cache_dir.filter(|_| slow && opts.cache).map(|d| d.join(format!("{:016x}.png", cache_key(&src, opts, path))));
    Ok(Planned { src, file_size: (w, h), plan, slow, cache })
}

impl Planned {
    /// The pinhole lens of the prepared image (its size is the image's).
    pub fn lens(&self) -> &Lens {
        &self.plan.target
    }

    /// The image file.
    pub fn path(&self) -> &Path {
        &self.src.path
    }

    /// Bytes of the prepared image as f32 RGB.
    pub fn bytes(&self) -> u64 {
        self.plan.target.width as u64 * self.plan.target.height as u64 * 12
    }

    /// Whether [`Planned::load`] would do more than decode a file (a slow preparation not cached yet).
    pub fn needs_preparing(&self) -> bool {
        self.slow && !self.cache.as_ref().is_some_and(|c| c.is_file())
    }

    /// The prepared image: from the cache when it holds it, else decoded, resized, undistorted
    /// (and cached). Cached and fresh loads give identical pixels.
    ///
    /// # Errors
    /// An unreadable image, or one whose size changed since it was planned.
    pub fn load(&self) -> Result<Image> {
        let (path, plan) = (&self.src.path, &self.plan);
        if let Some(c) = &self.cache {
            if let Ok(img) = load_image(c, [0.0; 3]) {
                if (img.width, img.height) == (plan.target.width, plan.target.height) {
                    return Ok(img);
                }
            }
        }
        let mut img = load_image(path, self.src.background)?;
        if (img.width, img.height) != self.file_size {
            return Err(Error::input(path, "image size changed while reading"));
        }
        img = downscale(&img, plan.downscale);
        if let Some((rw, rh)) = plan.resize {
            img = resize(&img, rw, rh);
        }
        if !plan.source.is_pinhole() {
            img = undistort_image(&img, &plan.source, &plan.target);
        }
        if self.slow {
            let bytes = png16(&mut img);
            if let Some(c) = &self.cache {
                // A cache that cannot be written is only slower.
                let ok = c.parent().is_some_and(|d| std::fs::create_dir_all(d).is_ok()) && write_bytes_atomic(c, &bytes).is_ok();
                if !ok && !CACHE_WARNED.swap(true, std::sync::atomic::Ordering::Relaxed) {
                    eprintln!("warning: {}: cannot write the image cache (images are prepared again next time)", c.display());
                }
            }
        }
        debug_assert_eq!((img.width, img.height), (plan.target.width, plan.target.height));
        Ok(img)
    }
}

/// The prepared image and the pinhole lens it was taken with ([`plan_image`] then [`Planned::load`]).
pub fn prepare(src: Source, opts: &LoadOptions, cache_dir: Option<&Path>) -> Result<(Image, Lens)> {
    let p = plan_image(src, opts, cache_dir)?;
    Ok((p.load()?, p.plan.target))
}

/// The sizes and lenses of each step.
#[derive(Debug, Clone)]
struct Plan {
    downscale: u32,
    resize: Option<(u32, u32)>,
    /// The (possibly distorted) lens of the image after downscale and resize.
    source: Lens,
    /// The pinhole lens of the final image.
    target: Lens,
}

/// `lens` is the lens of the file as it is on disk.
fn plan(lens: &Lens, k: u32, max_size: Option<u32>) -> std::result::Result<Plan, String> {
    let k = k.max(1);
    let (w1, h1) = (lens.width / k, lens.height / k);
    if w1 == 0 || h1 == 0 {
        return Err(format!("a {}x{} image is empty after downscaling by {k}", lens.width, lens.height));
    }
    let kf = k as f64;
    let mut source = Lens { width: w1, height: h1, fx: lens.fx / kf, fy: lens.fy / kf, cx: lens.cx / kf, cy: lens.cy / kf, ..*lens };
    let mut resize = None;
    if let Some(m) = max_size.filter(|&m| w1.max(h1) > m) {
        let s = m as f64 / w1.max(h1) as f64;
        let (w2, h2) = (((w1 as f64 * s).round() as u32).clamp(1, m), ((h1 as f64 * s).round() as u32).clamp(1, m));
        resize = Some((w2, h2));
        source = source.resized(w2, h2);
    }
    let target = source.pinhole_target().ok_or("the lens has no undistorted region without blank pixels (distortion too strong)")?;
    Ok(Plan { downscale: k, resize, source, target })
}

/// Lanczos-3 resize (the `image` crate widens the kernel by the reduction factor, so it
/// antialiases), values clamped to [0, 1].
pub fn resize(img: &Image, w: u32, h: u32) -> Image {
    let buf: image::Rgb32FImage = image::ImageBuffer::from_raw(img.width, img.height, img.data.clone()).expect("buffer size");
    let out = image::imageops::resize(&buf, w, h, image::imageops::FilterType::Lanczos3);
    Image { width: w, height: h, data: out.into_raw().into_iter().map(|v| v.clamp(0.0, 1.0)).collect() }
}

/// Rounds `img` to 16 bits per channel in place and returns it as PNG bytes.
fn png16(img: &mut Image) -> Vec<u8> {
    let q: Vec<u16> = img.data.iter().map(|&v| (v.clamp(0.0, 1.0) * 65535.0).round() as u16).collect();
    img.data.iter_mut().zip(&q).for_each(|(v, &q)| *v = q as f32 / 65535.0);
    let buf: image::ImageBuffer<image::Rgb<u16>, Vec<u16>> = image::ImageBuffer::from_raw(img.width, img.height, q).expect("buffer size");
    let mut bytes = std::io::Cursor::new(Vec::new());
    image::DynamicImage::ImageRgb16(buf).write_to(&mut bytes, image::ImageFormat::Png).expect("PNG encoding to memory");
    bytes.into_inner()
}

/// FNV-1a over everything that shapes the prepared image.
fn cache_key(src: &Source, opts: &LoadOptions, path: &Path) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut eat = |bytes: &[u8]| {
        for &b in bytes {
            h = (h ^ b as u64).wrapping_mul(0x0100_0000_01b3);
        }
    };
    eat(&CACHE_VERSION.to_le_bytes());
    let abs: PathBuf = path.canonicalize().unwrap_or_else(|_| path.to_path_buf());
    eat(abs.to_string_lossy().as_bytes());
    if let Ok(m) = std::fs::metadata(path) {
        eat(&m.len().to_le_bytes());
        if let Ok(t) = m.modified().map(|t| t.duration_since(std::time::UNIX_EPOCH).unwrap_or_default()) {
            eat(&t.as_nanos().to_le_bytes());
        }
    }
    eat(format!("{:?}", src.lens).as_bytes());
    eat(&src.downscale.to_le_bytes());
    eat(&opts.max_size.unwrap_or(0).to_le_bytes());
    src.background.iter().for_each(|v| eat(&v.to_bits().to_le_bytes()));
    h
}

/// The `images_N/` twin of an image path when `k > 1` and it exists (the 3DGS convention: a
/// folder beside `images/` holding the images downscaled by `N`): replaces the path component
/// `images` (the last one before the file) by `images_N`.
pub fn downscaled_twin(path: &Path, k: u32) -> Option<PathBuf> {
    if k <= 1 {
        return None;
    }
    let comps: Vec<_> = path.components().collect();
    let i = comps.iter().rposition(|c| c.as_os_str() == "images")?;
    let mut twin = PathBuf::new();
    for (j, c) in comps.iter().enumerate() {
        if j == i {
            twin.push(format!("images_{k}"));
        } else {
            twin.push(c.as_os_str());
        }
    }
    twin.is_file().then_some(twin)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::lens::Distortion;

    #[test]
    fn plan_scales_intrinsics_exactly() {
        let lens = Lens::new(101, 60, [80.0, 81.0, 50.25, 30.5], Distortion::None).unwrap();
        // Box downscale by 2 drops the last column: geometry ×1/2 exactly.
        let p = plan(&lens, 2, None).unwrap();
        assert_eq!((p.target.width, p.target.height), (50, 30));
        assert_eq!((p.target.fx, p.target.fy, p.target.cx, p.target.cy), (40.0, 40.5, 25.125, 15.25));
        // --max-size 40 on 101×60: ×40/101, height round(60·40/101) = 24.
        let p = plan(&lens, 1, Some(40)).unwrap();
        assert_eq!((p.target.width, p.target.height), (40, 24));
        assert!((p.target.cx - 50.25 * 40.0 / 101.0).abs() < 1e-12 && (p.target.fx - 80.0 * 40.0 / 101.0).abs() < 1e-12);
        assert!((p.target.cy - 30.5 * 24.0 / 60.0).abs() < 1e-12 && (p.target.fy - 81.0 * 24.0 / 60.0).abs() < 1e-12);
        assert!(plan(&lens, 200, None).is_err());
    }
}

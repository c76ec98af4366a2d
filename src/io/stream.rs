//! Dataset images held in memory, or read on demand within a memory budget.
//!
//! [`super::load_dataset`] plans every frame's image from its file's header (final size and
//! pinhole lens, [`Planned`]), then [`hold`]s them: when their decoded size (f32 RGB, 12 bytes a
//! pixel) fits the budget they are all loaded once, as before; otherwise only the plans are kept
//! and each [`FrameImage::get`] reads the image (from the prepared-image cache or the file)
//! through one [`ImageCache`] shared by the dataset's frames, a least-recently-used cache bounded
//! by the budget. A streamed load gives exactly the pixels of an in-memory load, so training and
//! evaluation do not depend on the budget.

use super::prepare::Planned;
use super::Frame;
use crate::Result;
use gscodec_decoder::Image;
use rayon::prelude::*;
use std::collections::{HashMap, VecDeque};
use std::sync::{Arc, Mutex};

/// Default budget for a dataset's decoded images, bytes (`--image-memory 2048`).
pub const DEFAULT_IMAGE_MEMORY: u64 = 2048 << 20;

/// A frame's image (sRGB in [0,1], composited on the dataset's background): in memory, or read
/// on demand. Cloning shares the pixels or the cache.
#[derive(Clone)]
pub struct FrameImage(Repr);

#[derive(Clone)]
enum Repr {
    Memory(Arc<Image>),
    Disk { planned: Arc<Planned>, cache: Option<(Arc<ImageCache>, usize)> },
}

impl FrameImage {
    /// An image planned but not read ([`Self::get`] reads it every time until [`hold`] attaches a cache).
    pub fn planned(p: Planned) -> Self {
        FrameImage(Repr::Disk { planned: Arc::new(p), cache: None })
    }

    /// The image: shared when in memory, else read (or taken from the cache).
    ///
    /// # Errors
    /// The file can no longer be read, or its size changed since the dataset was loaded.
    pub fn get(&self) -> Result<Arc<Image>> {
        match &self.0 {
            Repr::Memory(img) => Ok(img.clone()),
            Repr::Disk { planned, cache: None } => Ok(Arc::new(planned.load()?)),
            Repr::Disk { planned, cache: Some((cache, key)) } => cache.get_or_load(*key, || planned.load()),
        }
    }

    /// Whether the image is read on demand rather than held in memory.
    pub fn is_streamed(&self) -> bool {
        matches!(self.0, Repr::Disk { .. })
    }

    /// Size of the decoded image (f32 RGB), bytes.
    pub fn bytes(&self) -> u64 {
        match &self.0 {
            Repr::Memory(img) => img.data.len() as u64 * 4,
            Repr::Disk { planned, .. } => planned.bytes(),
        }
    }

    /// The cache this image is read through, when streamed by [`hold`].
    pub fn cache(&self) -> Option<&Arc<ImageCache>> {
        match &self.0 {
            Repr::Disk { cache: Some((c, _)), .. } => Some(c),
            _ => None,
        }
    }
}

impl From<Image> for FrameImage {
    fn from(img: Image) -> Self {
        FrameImage(Repr::Memory(Arc::new(img)))
    }
}

impl std::fmt::Debug for FrameImage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.0 {
            Repr::Memory(img) => write!(f, "FrameImage::Memory({}x{})", img.width, img.height),
            Repr::Disk { planned, .. } => write!(f, "FrameImage::Disk({})", planned.path().display()),
        }
    }
}

/// Loads every frame's image into memory when their decoded sizes add up to at most `budget`
/// bytes (`None`: no limit); otherwise prepares once the images that need resizing or
/// undistorting and have no cached copy (so later reads only decode), and attaches one
/// [`ImageCache`] of `budget` bytes shared by all frames.
///
/// # Errors
/// An image that cannot be read or prepared.
pub fn hold(frames: &mut [Frame], budget: Option<u64>) -> Result<()> {
    let total: u64 = frames.iter().map(|f| f.image.bytes()).sum();
    match budget {
        Some(b) if total > b => {
            frames
                .par_iter()
                .filter(|f| matches!(&f.image.0, Repr::Disk { planned, .. } if planned.needs_preparing()))
                .try_for_each(|f| f.image.get().map(drop))?;
            let cache = Arc::new(ImageCache::new(b));
            for (key, f) in frames.iter_mut().enumerate() {
                if let Repr::Disk { cache: c, .. } = &mut f.image.0 {
                    *c = Some((cache.clone(), key));
                }
            }
        }
        _ => {
            let images: Vec<Arc<Image>> = frames.par_iter().map(|f| f.image.get()).collect::<Result<_>>()?;
            frames.iter_mut().zip(images).for_each(|(f, img)| f.image = FrameImage(Repr::Memory(img)));
        }
    }
    Ok(())
}

/// Decoded images by key, least recently used evicted first, at most `budget` bytes of them
/// (an image larger than the budget is returned but not kept).
pub struct ImageCache {
    budget: u64,
    state: Mutex<CacheState>,
}

#[derive(Default)]
struct CacheState {
    images: HashMap<usize, Arc<Image>>,
    /// Keys, least recently used first.
    order: VecDeque<usize>,
    bytes: u64,
    loads: u64,
}

fn image_bytes(img: &Image) -> u64 {
    img.data.len() as u64 * 4
}

impl ImageCache {
    pub fn new(budget: u64) -> Self {
        ImageCache { budget, state: Mutex::new(CacheState::default()) }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, CacheState> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The image of `key`, loaded with `load` when not cached (outside the lock, so several
    /// threads may load at once).
    ///
    /// # Errors
    /// What `load` returns.
    pub fn get_or_load(&self, key: usize, load: impl FnOnce() -> Result<Image>) -> Result<Arc<Image>> {
        {
            let mut s = self.lock();
            if let Some(img) = s.images.get(&key).cloned() {
                s.order.retain(|&k| k != key);
                s.order.push_back(key);
                return Ok(img);
            }
        }
        let img = Arc::new(load()?);
        let bytes = image_bytes(&img);
        let mut s = self.lock();
        s.loads += 1;
        if bytes <= self.budget && !s.images.contains_key(&key) {
            while s.bytes + bytes > self.budget {
                let Some(old) = s.order.pop_front() else { break };
                if let Some(o) = s.images.remove(&old) {
                    s.bytes -= image_bytes(&o);
                }
            }
            s.bytes += bytes;
            s.order.push_back(key);
            s.images.insert(key, img.clone());
        }
        Ok(img)
    }

    /// The budget, bytes.
    pub fn budget(&self) -> u64 {
        self.budget
    }

    /// Bytes of the images held now (never above the budget).
    pub fn bytes(&self) -> u64 {
        self.lock().bytes
    }

    /// How many times an image was read from disk.
    pub fn loads(&self) -> u64 {
        self.lock().loads
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn img(w: u32, v: f32) -> Image {
        Image { width: w, height: 1, data: vec![v; w as usize * 3] }
    }

    #[test]
    fn cache_keeps_the_most_recent_images_within_its_budget() {
        // Three 12-byte-a-pixel images of 10 pixels (120 bytes) in a 250-byte cache: two fit.
        let c = ImageCache::new(250);
        for k in 0..3 {
            assert_eq!(c.get_or_load(k, || Ok(img(10, k as f32))).unwrap().data[0], k as f32);
        }
        assert_eq!((c.loads(), c.bytes()), (3, 240));
        // 1 and 2 are cached; 0 was evicted.
        c.get_or_load(1, || panic!("1 is cached")).unwrap();
        assert_eq!(c.get_or_load(0, || Ok(img(10, 0.0))).unwrap().data[0], 0.0);
        assert_eq!(c.loads(), 4);
        // Using 1 made 2 the least recent: loading 0 evicted 2, not 1.
        c.get_or_load(1, || panic!("1 is still cached")).unwrap();
        c.get_or_load(2, || Ok(img(10, 2.0))).unwrap();
        assert_eq!((c.loads(), c.bytes()), (5, 240));
        // Too large for the budget: returned, not kept, nothing evicted.
        assert_eq!(c.get_or_load(9, || Ok(img(30, 9.0))).unwrap().width, 30);
        assert_eq!((c.loads(), c.bytes()), (6, 240));
        // Errors pass through and cache nothing.
        assert!(c.get_or_load(7, || Err(crate::Error::Input("gone".into()))).is_err());
        let zero = ImageCache::new(0);
        zero.get_or_load(0, || Ok(img(1, 0.0))).unwrap();
        zero.get_or_load(0, || Ok(img(1, 0.0))).unwrap();
        assert_eq!((zero.loads(), zero.bytes()), (2, 0));
    }
}

//! A posed-image dataset, whatever file layout it came from.

use super::stream::FrameImage;
use gscodec_decoder::Camera;

/// One posed view.
#[derive(Debug, Clone)]
pub struct Frame {
    /// Index of the frame in the dataset's own frame order (used for the `% 8` test split).
    pub index: usize,
    /// Image file name without directory, for messages and output naming.
    pub name: String,
    pub camera: Camera,
    /// sRGB in [0,1], already composited on `Dataset::background`; in memory or read on demand
    /// (see [`super::stream`]). Its size is the camera's.
    pub image: FrameImage,
}

/// Posed images plus an optional initial point cloud.
#[derive(Debug, Clone, Default)]
pub struct Dataset {
    pub frames: Vec<Frame>,
    /// Background colour RGBA images were composited on (white for NeRF-synthetic).
    pub background: [f32; 3],
    /// Initial points (COLMAP `points3D`): positions and sRGB colours in [0,1].
    pub points: Vec<([f32; 3], [f32; 3])>,
    /// Explicit test frame indices when the dataset has its own test list; otherwise `index % 8 == 0`.
    pub test_indices: Option<Vec<usize>>,
    /// The cube the scene lies in, as `(centre, half side)`, when the dataset says (NeRF
    /// `aabb_scale`): random initial points are drawn in it.
    pub bounds: Option<([f32; 3], f32)>,
}

/// Which frames to use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Split {
    Train,
    Test,
    All,
}

impl Dataset {
    /// Whether frame `f` is held out for evaluation.
    pub fn is_test(&self, f: &Frame) -> bool {
        match &self.test_indices {
            Some(t) => t.contains(&f.index),
            None => f.index % 8 == 0,
        }
    }

    /// The frames of a split, in frame order.
    pub fn split(&self, split: Split) -> Vec<&Frame> {
        self.frames
            .iter()
            .filter(|f| match split {
                Split::All => true,
                Split::Test => self.is_test(f),
                Split::Train => !self.is_test(f),
            })
            .collect()
    }
}

//! Reading and writing scenes, datasets and images.

pub mod atomic;
pub mod dataset;

pub use dataset::{Dataset, Frame, Split};
pub mod splat;
pub mod spz;

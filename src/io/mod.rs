//! Reading and writing scenes, datasets and images.

pub mod atomic;
pub mod dataset;
pub mod ply;

pub use dataset::{Dataset, Frame, Split};
pub use ply::{read_ply, read_ply_bytes, write_ply};

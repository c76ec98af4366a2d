//! `gscodec-decoder`: everything a player needs to restore and draw a gscodec scene.
//!
//! * [`Splats`] — the decoded scene as structure-of-arrays.
//! * [`Camera`] — a pinhole camera in the OpenCV convention (x right, y down, z forward).
//! * [`math`] — the one definition of covariance, EWA projection and spherical-harmonic colour.
//! * [`render`] — the tile-based CPU rasterizer (f32) and its f64 reference.

#[cfg(feature = "capi")]
pub mod capi;
pub mod camera;
pub mod math;
pub mod render;
pub mod splats;

pub use camera::Camera;
pub use render::{Image, RenderOptions};
pub use splats::{SceneError, Splats};

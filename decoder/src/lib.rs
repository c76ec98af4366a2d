//! `gscodec-decoder`: everything a player needs to restore and draw a gscodec scene.
//!
//! * [`decode`] / [`decode_reader`] / [`decode_prefix`] (progressive) / [`peek_header`] — `.gsc`
//!   bytes to a [`Splats`] scene ([`Splats::to_ply`] writes it out).
//! * [`bitstream`] — the container format (one definition, read and written here).
//! * [`entropy`] — integer probability tables and ANS coding via constriction.
//! * [`Splats`] — the decoded scene as structure-of-arrays.
//! * [`Camera`] — a pinhole camera in the OpenCV convention (x right, y down, z forward).
//! * [`math`] — the one definition of covariance, EWA projection and spherical-harmonic colour.
//! * [`render`] — the tile-based CPU rasterizer (f32), its f64 reference and, with the `gpu`
//!   feature, the wgpu renderer `render::gpu`.
//! * `capi` (feature `capi`) — the C ABI declared in `include/gscodec.h`.

pub mod bitstream;
pub mod camera;
#[cfg(feature = "capi")]
pub mod capi;
mod decode;
pub mod entropy;
pub mod math;
pub mod render;
pub mod splats;

pub use bitstream::layout::Group;
pub use bitstream::DecodeError;
pub use camera::Camera;
pub use decode::{decode, decode_prefix, decode_reader, inspect, peek_header, DecodeOptions, FileInfo, SectionInfo};
pub use render::{Image, RenderOptions};
pub use splats::{SceneError, Splats};

//! `gscodec-decoder`: everything a player needs to restore and draw a gscodec scene.
//!
//! # Decoding
//!
//! [`Decoder::new`]`(reader)` with [`Limits`] → [`Decoder::read_info`] (header and section
//! table, limits checked) → [`Reader::decode`] or [`Reader::decode_into`] a caller-owned
//! [`Splats`]. [`decode`] does it in one call for bytes in memory; [`decode_prefix`] decodes a
//! file that is still arriving; [`inspect`] lists what a file holds. Errors are a
//! [`DecodeError`] sorted by cause, with [`DecodeError::class`] naming it.
//!
//! ```
//! # let bytes = std::fs::read(concat!(env!("CARGO_MANIFEST_DIR"), "/../bitstream-spec/vectors/hand.gsc")).unwrap();
//! use gscodec_decoder::{Decoder, Limits};
//! let reader = Decoder::with_limits(&bytes[..], Limits::default()).read_info()?;
//! assert_eq!(reader.gaussians(), 3);
//! let scene = reader.decode()?;
//! std::fs::write(std::env::temp_dir().join("hand.ply"), scene.to_ply()).unwrap();
//! # Ok::<(), gscodec_decoder::DecodeError>(())
//! ```
//!
//! # Modules
//!
//! | module | what |
//! |---|---|
//! | [`splats`] | [`Splats`], the decoded scene as structure-of-arrays |
//! | [`camera`] | [`Camera`], a pinhole camera in the OpenCV convention (x right, y down, z forward) |
//! | [`math`] | the one definition of covariance, EWA projection and spherical-harmonic colour |
//! | [`render`] | the tile-based CPU rasterizer ([`render::render`]) and, with the `gpu` feature, the wgpu renderer `render::gpu` |
//! | `capi` | (feature `capi`) the C ABI declared in `include/gscodec.h` |
//!
//! The format's elements (`bitstream`), the entropy coder (`entropy`) and the WGSL sources
//! (`shaders`) are public for the encoder crate `gscodec` but hidden: they are not a stable API.
#![cfg_attr(not(feature = "capi"), forbid(unsafe_code))]
#![cfg_attr(feature = "capi", deny(unsafe_code))]

#[doc(hidden)]
pub mod bitstream;
pub mod camera;
#[cfg(feature = "capi")]
pub mod capi;
mod decode;
mod decoder;
#[doc(hidden)]
pub mod entropy;
mod error;
pub mod math;
mod par;
pub mod render;
#[doc(hidden)]
pub mod rng;
#[cfg(feature = "gpu")]
#[doc(hidden)]
pub mod shaders;
pub mod splats;
#[doc(hidden)]
pub mod testkit;

pub use bitstream::info::EncoderInfo;
pub use bitstream::layout::Group;
pub use bitstream::Header;
pub use camera::Camera;
pub use decoder::{
    decode, decode_prefix, decode_with, inspect, peek_header, prefix_extent, AnchorSummary, Decoder, FileInfo, Info, Limits, Reader,
    SectionInfo,
};
pub use error::{ChecksumError, DecodeError, FormatError, FormatErrorKind, Limit, LimitError, SectionId, UnsupportedError};
pub use render::{Image, RenderOptions};
pub use splats::{SceneError, Splats};

/// The Rust examples of `docs/decoder.md`, run as doctests (the file is outside the package, so
/// only under `cargo test --doc` in this repository).
#[cfg(doctest)]
#[doc = include_str!("../../docs/decoder.md")]
pub struct DecoderGuide;

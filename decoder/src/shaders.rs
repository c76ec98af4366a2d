//! The WGSL sources of the GPU renderer (`decoder/shaders/`), for reuse by the encoder's GPU
//! trainer (projection, scan, sort). Each kernel file is compiled with [`COMMON`] prepended.
//! Not a stable API.

/// Shared structs, constants and helpers of every kernel.
pub const COMMON: &str = include_str!("../shaders/common.wgsl");
/// `project`: per Gaussian, camera transform, EWA covariance, conic, radius, SH colour, tile count.
pub const PROJECT: &str = include_str!("../shaders/project.wgsl");
/// `emit`: one `(tile, depth, id)` key per (tile, Gaussian) pair.
pub const EMIT: &str = include_str!("../shaders/emit.wgsl");
/// `scan_blocks` / `scan_add`: exclusive prefix sum.
pub const SCAN: &str = include_str!("../shaders/scan.wgsl");
/// `radix_count` / `radix_scatter`: stable LSD radix sort, 4 bits per pass.
pub const RADIX_SORT: &str = include_str!("../shaders/radix_sort.wgsl");
/// `tile_ranges` / `rasterize`: per-tile slices of the sorted keys and front-to-back compositing.
pub const RASTERIZE: &str = include_str!("../shaders/rasterize.wgsl");

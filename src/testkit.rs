//! The test kit of the encoder's tests, benches and examples: everything of the decoder's kit
//! (`gscodec_decoder::testkit`: [`skip`], random and extreme scenes, the camera rig, the GPU
//! renderer) plus the locator of the real test data. Not part of the API.

pub use gscodec_decoder::testkit::*;
use std::path::PathBuf;

/// The environment variable that points at the real test data from elsewhere.
pub const DATA_ENV: &str = "GSCODEC_DATA";

/// The real test data directory (scenes, lego-200 …): `$GSCODEC_DATA`, else `../shared/data`
/// beside the repository. It may not exist; see [`shared_data`].
pub fn data_dir() -> PathBuf {
    std::env::var_os(DATA_ENV).map(PathBuf::from).unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data"))
}

/// `sub` inside [`data_dir`] when it exists; otherwise the calling test [`skip`]s (it says so)
/// and gets `None`, so that the suite passes without the data.
pub fn shared_data(sub: &str) -> Option<PathBuf> {
    let p = data_dir().join(sub);
    if p.exists() {
        Some(p)
    } else {
        skip(format_args!("{} is absent (set {DATA_ENV})", p.display()));
        None
    }
}

/// `n` random Gaussians of seed `seed` at SH degree 3, their scales shrunk as the count grows so
/// that the tile pairs per Gaussian stay a few: the scenes of the trainer benches (fit seed 2 to
/// renders of seed 1).
pub fn bench_splats(n: usize, seed: u64) -> gscodec_decoder::Splats {
    let shrink = (n as f32 / 120.0).cbrt().ln();
    let mut s = random_splats(n, 1, seed).with_sh_degree(3);
    s.log_scales.iter_mut().for_each(|l| *l = l.map(|v| v - shrink));
    s
}

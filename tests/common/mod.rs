//! Helpers shared by the integration tests.
#![allow(dead_code)]

use std::path::PathBuf;

/// The shared real-data directory: `$GSCODEC_DATA`, else `../shared/data` beside the repository.
/// `None` (and a note on stderr) when absent, so tests that need it skip cleanly.
pub fn shared_data(sub: &str) -> Option<PathBuf> {
    let root = std::env::var_os("GSCODEC_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data"));
    let p = root.join(sub);
    if p.exists() {
        Some(p)
    } else {
        eprintln!("skipped: {} is absent (set GSCODEC_DATA)", p.display());
        None
    }
}

//! Kept only for `tests/dataset.rs` until it calls `gscodec::testkit::shared_data` directly
//! (the one data locator); then delete this file.
#![allow(unused_imports)]

pub use gscodec::testkit::shared_data;

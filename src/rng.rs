//! The project's one deterministic random number generator (SplitMix64): procedural samples,
//! initialisation, view order and densification noise, and the tests' random inputs
//! ([`crate::testkit`]). It is defined in the decoder crate (`gscodec_decoder::rng`), the lowest
//! crate of the workspace, so that the decoder's own tests use the same one.

pub use gscodec_decoder::rng::Rng;

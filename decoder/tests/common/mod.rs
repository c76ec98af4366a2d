//! Shared helpers of the decoder's integration tests.
#![allow(dead_code)]

use gscodec_decoder::math::sh_rest_coeffs;
use gscodec_decoder::Splats;

/// Small deterministic PRNG (xorshift64*), uniform in [0,1).
pub struct Rng(pub u64);

impl Rng {
    pub fn next(&mut self) -> f32 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        ((self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 40) as f32) / (1u64 << 24) as f32
    }

    pub fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.next()
    }
}

/// `n` random Gaussians in the cube [-1, 1]³ with log-scales in `[min_log_scale, -1.5]`.
pub fn random_scene(n: usize, degree: u8, seed: u64, min_log_scale: f32) -> Splats {
    let mut rng = Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1);
    let mut s = Splats::new(degree);
    let k = sh_rest_coeffs(degree) * 3;
    let ls = min_log_scale..-1.5;
    for _ in 0..n {
        let pos = [rng.range(-1.0, 1.0), rng.range(-1.0, 1.0), rng.range(-1.0, 1.0)];
        let scale = [rng.range(ls.start, ls.end), rng.range(ls.start, ls.end), rng.range(ls.start, ls.end)];
        let rot = [rng.range(-1.0, 1.0), rng.range(-1.0, 1.0), rng.range(-1.0, 1.0), rng.range(-1.0, 1.0)];
        let dc = [rng.range(-1.5, 1.5), rng.range(-1.5, 1.5), rng.range(-1.5, 1.5)];
        let rest: Vec<f32> = (0..k).map(|_| rng.range(-0.3, 0.3)).collect();
        s.push(pos, scale, rot, rng.range(-3.0, 4.0), dc, &rest);
    }
    s
}

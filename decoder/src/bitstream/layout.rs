//! What the sections of a `.gsc` file hold: attribute groups, their channels, chunking, the
//! Morton ordering of positions and the dequantisation formulas (SPEC §6, §8).

/// Gaussians are coded in chunks of this many; each (group, chunk) is an independent stream.
pub const CHUNK: usize = 1 << 16;
/// Largest position grid resolution in bits per axis (3 × 21 = 63-bit Morton codes).
pub const MAX_POSITION_BITS: u8 = 21;

/// An attribute group: one parameter section and one data stream per chunk.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Group {
    Position = 0,
    Scale = 1,
    Rotation = 2,
    Opacity = 3,
    ShDc = 4,
    Sh1 = 5,
    Sh2 = 6,
    Sh3 = 7,
}

impl Group {
    pub const ALL: [Group; 8] =
        [Group::Position, Group::Scale, Group::Rotation, Group::Opacity, Group::ShDc, Group::Sh1, Group::Sh2, Group::Sh3];

    /// Section kind of this group's parameter (tables + steps) section.
    pub fn params_kind(self) -> u16 {
        0x10 + self as u16
    }

    /// Section kind of this group's per-chunk data streams.
    pub fn data_kind(self) -> u16 {
        0x20 + self as u16
    }

    pub fn name(self) -> &'static str {
        ["position", "scale", "rotation", "opacity", "sh_dc", "sh_band1", "sh_band2", "sh_band3"][self as usize]
    }

    /// SH band of an SH-rest group (1..=3); 0 for the others.
    pub fn sh_band(self) -> u8 {
        match self {
            Group::Sh1 => 1,
            Group::Sh2 => 2,
            Group::Sh3 => 3,
            _ => 0,
        }
    }

    /// The group holding SH band `b` (1..=3).
    pub fn for_band(b: u8) -> Group {
        [Group::Sh1, Group::Sh2, Group::Sh3][b as usize - 1]
    }

    /// Channels coded per Gaussian (for Position: the one Morton-delta length channel).
    pub fn channels(self) -> usize {
        match self {
            Group::Position => 1,
            Group::Scale | Group::ShDc => 3,
            Group::Rotation => 4,
            Group::Opacity => 1,
            Group::Sh1 => 9,
            Group::Sh2 => 15,
            Group::Sh3 => 21,
        }
    }

    /// Groups present in a file of SH degree `d`.
    pub fn present(d: u8) -> impl Iterator<Item = Group> {
        Group::ALL.into_iter().filter(move |g| g.sh_band() <= d)
    }
}

/// Optional section: encoder information (`u32` Gaussians before pruning, `u8` SH degree of the input).
pub const INFO_KIND: u16 = 0x100;
/// Optional section: padding (ignored).
pub const PADDING_KIND: u16 = 0x101;

/// Number of chunks for `n` Gaussians.
pub fn chunk_count(n: usize) -> usize {
    n.div_ceil(CHUNK)
}

/// Interleaves three `bits`-bit coordinates into a Morton code: bit k of x goes to bit 3k,
/// of y to 3k+1, of z to 3k+2.
pub fn morton_encode(q: [u32; 3], bits: u8) -> u64 {
    let mut m = 0u64;
    for k in 0..bits as u32 {
        for (a, &v) in q.iter().enumerate() {
            m |= u64::from((v >> k) & 1) << (3 * k + a as u32);
        }
    }
    m
}

/// Inverse of [`morton_encode`] (bits above `3·bits` are ignored).
pub fn morton_decode(m: u64, bits: u8) -> [u32; 3] {
    let mask = ((1u64 << bits) - 1) as u32;
    [compact_every_third(m) & mask, compact_every_third(m >> 1) & mask, compact_every_third(m >> 2) & mask]
}

/// Gathers bits 0, 3, 6, …, 60 of `x` into bits 0..21.
fn compact_every_third(x: u64) -> u32 {
    let mut x = x & 0x1249_2492_4924_9249;
    x = (x ^ (x >> 2)) & 0x10c3_0c30_c30c_30c3;
    x = (x ^ (x >> 4)) & 0x100f_00f0_0f00_f00f;
    x = (x ^ (x >> 8)) & 0x001f_0000_ff00_00ff;
    x = (x ^ (x >> 16)) & 0x001f_0000_0000_ffff;
    x = (x ^ (x >> 32)) & 0x001f_ffff;
    x as u32
}

/// Dequantises a grid coordinate: `origin + q·step` in f32 (two rounded operations, no FMA).
pub fn dequantise_position(origin: f32, step: f32, q: u32) -> f32 {
    let scaled = q as f32 * step;
    origin + scaled
}

/// Rebuilds a unit quaternion `(w, x, y, z)` from smallest-three form: `largest` is the index of
/// the omitted component, `c` the other three in index order (already dequantised).
pub fn rotation_from_smallest_three(largest: usize, c: [f32; 3]) -> [f32; 4] {
    let sumsq = c[0] * c[0] + c[1] * c[1] + c[2] * c[2];
    let big = (1.0 - sumsq).max(0.0).sqrt();
    let mut out = [0.0f32; 4];
    let mut j = 0;
    for (i, o) in out.iter_mut().enumerate() {
        if i == largest {
            *o = big;
        } else {
            *o = c[j];
            j += 1;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn morton_round_trip_and_order() {
        for q in [[0, 0, 0], [1, 2, 3], [(1 << 21) - 1, 5, (1 << 21) - 1]] {
            assert_eq!(morton_decode(morton_encode(q, 21), 21), q);
        }
        assert_eq!(morton_encode([1, 0, 0], 4), 1);
        assert_eq!(morton_encode([0, 1, 0], 4), 2);
        assert_eq!(morton_encode([0, 0, 1], 4), 4);
        assert_eq!(morton_encode([2, 0, 0], 4), 8);
        // Against the bit-by-bit definition, for every grid size.
        let mut x = 0x9e37_79b9_7f4a_7c15u64;
        for bits in 1..=21u8 {
            for _ in 0..200 {
                x = x.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                let m = x & ((1u64 << (3 * bits)) - 1);
                let mut q = [0u32; 3];
                for k in 0..u32::from(bits) {
                    for (a, v) in q.iter_mut().enumerate() {
                        *v |= (((m >> (3 * k + a as u32)) & 1) as u32) << k;
                    }
                }
                assert_eq!(morton_decode(m, bits), q);
                assert_eq!(morton_encode(q, bits), m);
            }
        }
    }

    #[test]
    fn smallest_three_rebuilds_unit_quaternion() {
        let q = rotation_from_smallest_three(2, [0.5, -0.5, 0.5]);
        assert_eq!(q, [0.5, -0.5, 0.5, 0.5]);
    }
}

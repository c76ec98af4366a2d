//! Dequantisation (SPEC §8) and assembly of dequantised channel values into a [`Splats`] scene
//! (SPEC §7): the decoder writes the base groups straight into the scene's rows and scatters the
//! SH pieces with [`scatter_sh`]; the encoder builds what a decoder will restore with
//! [`assemble`], which places every group the same way.

use std::ops::Range;

use rayon::prelude::*;

use super::layout::Group;
use crate::Splats;

/// A channel value `v` with step `s`: `f32(v) · s` (SPEC §8).
#[inline(always)]
pub fn dequantise_value(v: i32, step: f32) -> f32 {
    v as f32 * step
}

/// A grid coordinate: `origin + q·step` in f32 (two rounded operations, no FMA).
#[inline(always)]
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

/// Turns rotation channel rows `(index, c0, c1, c2)` (the index as an exact f32, the
/// components dequantised) into quaternions, in place; an index outside 0..=3 is an error.
pub fn rotations_in_place(rows: &mut [f32]) -> Result<(), &'static str> {
    for v in rows.chunks_exact_mut(4) {
        if !matches!(v[0], 0.0 | 1.0 | 2.0 | 3.0) {
            return Err("rotation index outside 0..4");
        }
        let q = rotation_from_smallest_three(v[0] as usize, [v[1], v[2], v[3]]);
        v.copy_from_slice(&q);
    }
    Ok(())
}

/// Integer channels of a group other than position (`channels[c][i]`: channel c of Gaussian i)
/// dequantised with `steps`, in the assembler's layout: Gaussian-major values, quaternions for
/// rotation.
pub fn dequantise_channels(group: Group, steps: &[f32], channels: &[&[i32]]) -> Result<Vec<f32>, &'static str> {
    let n = channels.first().map_or(0, |c| c.len());
    let mut vals = Vec::with_capacity(n * channels.len());
    for i in 0..n {
        vals.extend(channels.iter().zip(steps).map(|(c, &s)| dequantise_value(c[i], s)));
    }
    if group == Group::Rotation {
        rotations_in_place(&mut vals)?;
    }
    Ok(vals)
}

/// Dequantised values of one group for a run of Gaussians: `values` holds, for Gaussians
/// `first .. first + count`, the row entries `columns` (position: x y z; rotation: w x y z;
/// other groups: a range of its channels), Gaussian-major.
#[derive(Debug, Clone)]
pub struct Piece<'a> {
    /// The group.
    pub group: Group,
    /// First Gaussian.
    pub first: usize,
    /// Columns of the group's row (SH bands: channel `3·m + c` of band b).
    pub columns: Range<usize>,
    /// `count × columns.len()` values, or with `codebook` one row index per Gaussian.
    pub values: &'a [f32],
    /// An SH band coded by a codebook (SPEC §3.2): its rows, `columns.len()` values each;
    /// `values` are indices into them (exact in f32, already checked to be in range).
    pub codebook: Option<&'a [f32]>,
}

impl Piece<'_> {
    fn count(&self) -> usize {
        match self.codebook {
            Some(_) => self.values.len(),
            None => self.values.len() / self.columns.len().max(1),
        }
    }
}

/// Builds a scene of `n` Gaussians and SH degree `degree` from `pieces` into `out` (its
/// allocations are reused). The pieces of each base group, in order of `first`, must cover
/// Gaussians `0..n`; SH pieces may cover any runs of Gaussians, and SH values no piece covers are
/// zero.
pub fn assemble(n: usize, degree: u8, pieces: &[Piece<'_>], out: &mut Splats) {
    out.sh_degree = degree;
    let of = |group: Group| {
        let mut ps: Vec<&Piece> = pieces.iter().filter(|p| p.group == group).collect();
        ps.sort_by_key(|p| p.first);
        ps
    };
    fn rows<const W: usize>(dst: &mut Vec<[f32; W]>, ps: &[&Piece<'_>], n: usize) {
        dst.clear();
        dst.reserve(n);
        for p in ps {
            dst.extend(p.values.chunks_exact(W).map(|v| std::array::from_fn(|i| v[i])));
        }
    }
    let Splats { positions, log_scales, rotations, opacity_logits, sh_dc, sh_rest, .. } = out;
    let scatter_sh = || scatter_sh(n, degree, pieces, sh_rest);
    crate::par::join(
        || crate::par::join(|| rows(positions, &of(Group::Position), n), || rows(log_scales, &of(Group::Scale), n)),
        || {
            crate::par::join(
                || {
                    crate::par::join(
                        || rows(rotations, &of(Group::Rotation), n),
                        || {
                            opacity_logits.clear();
                            opacity_logits.extend(of(Group::Opacity).iter().flat_map(|p| p.values));
                        },
                    )
                },
                || crate::par::join(|| rows(sh_dc, &of(Group::ShDc), n), scatter_sh),
            )
        },
    );
}

/// Writes the SH pieces among `pieces` into `sh_rest`, the rest coefficients of `n` Gaussians of
/// SH degree `degree` (resized to them; values no piece covers are zero). SH pieces may cover
/// any runs of Gaussians.
pub fn scatter_sh(n: usize, degree: u8, pieces: &[Piece<'_>], sh_rest: &mut Vec<f32>) {
    let row = crate::math::sh_rest_coeffs(degree) * 3;
    sh_rest.clear();
    sh_rest.resize(n * row, 0.0);
    if row == 0 {
        return;
    }
    // SH channel j of band b is rest value (b²−1)·3 + j of its Gaussian.
    let sh: Vec<(usize, &Piece)> = pieces
        .iter()
        .filter(|p| (1..=degree).contains(&p.group.sh_band()))
        .map(|p| {
            let b = p.group.sh_band() as usize;
            ((b * b - 1) * 3 + p.columns.start, p)
        })
        .collect();
    // Blocks of rows between consecutive piece boundaries: each piece covers whole blocks.
    let mut cuts: Vec<usize> = sh.iter().flat_map(|(_, p)| [p.first, p.first + p.count()]).chain([0, n]).filter(|&c| c <= n).collect();
    cuts.sort_unstable();
    cuts.dedup();
    let mut blocks: Vec<(usize, &mut [f32])> = Vec::with_capacity(cuts.len());
    let mut rest = &mut sh_rest[..];
    for w in cuts.windows(2) {
        let (block, tail) = std::mem::take(&mut rest).split_at_mut((w[1] - w[0]) * row);
        blocks.push((w[0], block));
        rest = tail;
    }
    // Row `i` of the block at `start`, from the pieces `mine` that cover the block.
    let fill = |start: usize, mine: &[(usize, &Piece)], i: usize, dst: &mut [f32]| {
        for &(col, p) in mine {
            let (w, at) = (p.columns.len(), start - p.first + i);
            let src = match p.codebook {
                Some(rows) => &rows[p.values[at] as usize * w..][..w],
                None => &p.values[at * w..][..w],
            };
            dst[col..col + w].copy_from_slice(src);
        }
    };
    let covering = |start: usize, rows: &[f32]| -> Vec<(usize, &Piece)> {
        let count = rows.len() / row;
        sh.iter().filter(|(_, p)| p.first <= start && p.first + p.count() >= start + count).copied().collect()
    };
    if crate::par::sequential() {
        for (start, rows) in blocks {
            let mine = covering(start, rows);
            rows.chunks_exact_mut(row).enumerate().for_each(|(i, dst)| fill(start, &mine, i, dst));
        }
    } else {
        blocks.into_par_iter().for_each(|(start, rows)| {
            let mine = covering(start, rows);
            rows.par_chunks_mut(row).enumerate().with_min_len(1024).for_each(|(i, dst)| fill(start, &mine, i, dst));
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn smallest_three_rebuilds_unit_quaternion() {
        let q = rotation_from_smallest_three(2, [0.5, -0.5, 0.5]);
        assert_eq!(q, [0.5, -0.5, 0.5, 0.5]);
        let mut rows = [2.0, 0.5, -0.5, 0.5];
        rotations_in_place(&mut rows).unwrap();
        assert_eq!(rows, q);
        assert!(rotations_in_place(&mut [4.0, 0.0, 0.0, 0.0]).is_err());
    }

    #[test]
    fn sh_pieces_are_scattered_coefficient_major() {
        // Two Gaussians of degree 2: band 1 in one piece, band 2 in two channel ranges.
        let b1: Vec<f32> = (0..18).map(|v| v as f32).collect();
        let b2a: Vec<f32> = (0..16).map(|v| 100.0 + v as f32).collect();
        let b2b: Vec<f32> = (0..14).map(|v| 200.0 + v as f32).collect();
        let base =
            |group, w| Piece { group, first: 0, columns: 0..w, values: Box::leak(vec![1.0; 2 * w].into_boxed_slice()), codebook: None };
        let pieces = [
            base(Group::Position, 3),
            base(Group::Scale, 3),
            base(Group::Rotation, 4),
            base(Group::Opacity, 1),
            base(Group::ShDc, 3),
            Piece { group: Group::Sh1, first: 0, columns: 0..9, values: &b1, codebook: None },
            Piece { group: Group::Sh2, first: 0, columns: 0..8, values: &b2a, codebook: None },
            Piece { group: Group::Sh2, first: 0, columns: 8..15, values: &b2b, codebook: None },
        ];
        let mut s = Splats::new(0);
        assemble(2, 2, &pieces, &mut s);
        assert_eq!((s.len(), s.sh_degree, s.rest_coeffs()), (2, 2, 8));
        let expected1: Vec<f32> = [&b1[9..18], &b2a[8..16], &b2b[7..14]].concat();
        assert_eq!(s.rest_of(1), &expected1[..]);
        assert_eq!(s.rest_of(0)[..9], b1[..9]);
    }
}

//! The position stream (SPEC §6.1): grid coordinates interleaved into Morton codes, sorted, and
//! coded per chunk as deltas — each delta's bit length through the length table, then the bits
//! below its leading one raw.

use super::assemble::dequantise_position;
use super::params::{Grid, GroupParams};
use super::stream::{next_stream, push_stream, stream_decoder};
use super::tables::ChannelTable;
use super::{ByteReader, ByteWriter};
use crate::entropy::SymbolEncoder;
use crate::error::{DecodeError, Place};

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

/// The length value `L` of a Morton delta: its bit length (0 for 0).
pub fn delta_length(d: u64) -> u32 {
    64 - d.leading_zeros()
}

/// Raw bits a delta costs after its length value: `L − 1` (none for L ≤ 1).
pub fn delta_raw_bits(d: u64) -> u32 {
    delta_length(d).saturating_sub(1)
}

/// The deltas of Morton codes sorted within each chunk (`chunks`: the Gaussians of each, in
/// order, covering `morton`), restarting at 0 in each chunk.
pub fn morton_deltas(morton: &[u64], chunks: &[std::ops::Range<usize>]) -> Vec<u64> {
    chunks
        .iter()
        .flat_map(|r| {
            let c = &morton[r.clone()];
            let mut prev = 0;
            c.iter().map(move |&m| {
                let d = m - prev;
                prev = m;
                d
            })
        })
        .collect()
}

/// Writes the data section of one position chunk: one stream holding, per Gaussian, the delta's
/// length under `length_table` and its raw bits, most significant piece first.
pub fn write_position_stream(length_table: &ChannelTable, deltas: &[u64]) -> Vec<u8> {
    let mut e = SymbolEncoder::new();
    for &d in deltas {
        let len = delta_length(d);
        e.value(length_table, 0, len as i32);
        if len >= 2 {
            let rest = d & ((1u64 << (len - 1)) - 1);
            let mut left = len - 1;
            while left > 0 {
                let take = left.min(32);
                left -= take;
                e.raw_bits(((rest >> left) & ((1u64 << take) - 1)) as u32, take);
            }
        }
    }
    let mut section = ByteWriter::new();
    push_stream(&mut section, e);
    section.buf
}

/// The dequantised position of Morton code `m` on `grid` (SPEC §8).
pub fn position_of(m: u64, grid: &Grid) -> [f32; 3] {
    let (origin, step, bits) = grid;
    let q = morton_decode(m, *bits);
    std::array::from_fn(|a| dequantise_position(origin[a], step[a], q[a]))
}

/// Decodes the position stream of a chunk into `out`: 3 coordinates per Gaussian.
pub(crate) fn decode_positions(p: &GroupParams, r: &mut ByteReader<'_>, out: &mut [f32]) -> Result<(), DecodeError> {
    let Some(grid) = p.grid else { return Err(r.corrupt("position parameters without a grid")) };
    let count = out.len() / 3;
    let mut rows = out.chunks_exact_mut(3);
    decode_morton(p, r, count, |m, at| {
        let xyz = position_of(m, &grid);
        if !xyz.iter().all(|x| x.is_finite()) {
            return Err(at.corrupt("dequantised value is not finite"));
        }
        rows.next().map(|row| row.copy_from_slice(&xyz)).ok_or_else(|| at.corrupt("position count"))
    })
}

/// Decodes the Morton codes of a position stream (SPEC §6.1) of `count` Gaussians, handing each
/// to `each` in order (with the stream's place for errors).
#[inline(always)]
pub(crate) fn decode_morton(
    p: &GroupParams,
    r: &mut ByteReader<'_>,
    count: usize,
    mut each: impl FnMut(u64, Place) -> Result<(), DecodeError>,
) -> Result<(), DecodeError> {
    let Some(grid) = p.grid else { return Err(r.corrupt("position parameters without a grid")) };
    let max_len = 3 * u32::from(grid.2);
    let limit = 1u64 << max_len; // bits <= 21, so at most 2^63
    let mut m: u64 = 0;
    decode_lengths(&p.tables[0], r, count, max_len, |delta, at| {
        m = m.checked_add(delta).filter(|&m| m < limit).ok_or_else(|| at.corrupt("position outside the grid"))?;
        each(m, at)
    })
}

/// Decodes the next stream of `r` as `count` values in the length + raw bits code of SPEC §6.1
/// (`L` from `table`, at most `max_len`; then `L − 1` raw bits below the leading one), handing
/// each to `each`, and checks the stream's end.
#[inline(always)]
pub(crate) fn decode_lengths(
    table: &ChannelTable,
    r: &mut ByteReader<'_>,
    count: usize,
    max_len: u32,
    mut each: impl FnMut(u64, Place) -> Result<(), DecodeError>,
) -> Result<(), DecodeError> {
    let (data, at) = next_stream(r)?;
    let mut d = stream_decoder(data, at)?;
    for _ in 0..count {
        let len = d.value(table, 0);
        if len < 0 || len as u32 > max_len {
            return Err(at.corrupt("coded length too long"));
        }
        let len = len as u32;
        let value = if len <= 1 {
            u64::from(len)
        } else {
            let mut rest = 0u64;
            let mut left = len - 1;
            while left > 0 {
                let take = left.min(32);
                rest = (rest << take) | u64::from(d.raw_bits(take));
                left -= take;
            }
            (1u64 << (len - 1)) | rest
        };
        each(value, at)?;
    }
    d.finish().map_err(|what| at.corrupt(what))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::entropy::FreqTable;

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
    fn position_stream_round_trips_with_long_deltas() {
        let grid: Grid = ([0.0; 3], [1.0; 3], 21);
        // Deltas of every length 0..=63, including ones needing two raw pieces.
        let mut morton = vec![0u64, 0, 1];
        for len in 2..=63u32 {
            let last = *morton.last().unwrap();
            morton.push(last + (1u64 << (len - 1)) + 1);
            if morton.last().unwrap() >= &(1u64 << 63) {
                morton.pop();
                break;
            }
        }
        let deltas = morton_deltas(&morton, &[0..morton.len()]);
        let mut weights = vec![1u32; 64];
        weights[0] = 5;
        let table = ChannelTable::Coded { lo: 0, table: FreqTable::from_weights(&weights) };
        let section = write_position_stream(&table, &deltas);
        let p = GroupParams { steps: vec![], tables: vec![table], grid: Some(grid), codebook: None };
        let mut xyz = vec![0.0; 3 * morton.len()];
        decode_positions(&p, &mut ByteReader::new(&section), &mut xyz).unwrap();
        let expected: Vec<f32> = morton.iter().flat_map(|&m| position_of(m, &grid)).collect();
        assert_eq!(xyz, expected);
        // One Gaussian fewer leaves the stream unfinished: an error, not a panic.
        assert_eq!(decode_positions(&p, &mut ByteReader::new(&section), &mut xyz[3..]).unwrap_err().class(), "format");
    }
}

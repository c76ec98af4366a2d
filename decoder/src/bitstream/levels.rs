//! The levels section (SPEC §3.1, kind `0x01`, format 4.0): how the Gaussians are split into
//! chunks, and the chunks into importance levels. A 3.0 file has no such section: its layout is
//! one level of [`CHUNK`]-Gaussian chunks ([`Layout::uniform`]).

use std::ops::Range;

use super::layout::CHUNK;
use super::{ByteReader, ByteWriter};
use crate::error::DecodeError;

/// Chunks and levels of a file: chunk `c` holds the Gaussians `chunk_range(c)`, level `l` the
/// chunks `level_chunks(l)`. Levels and chunks are in file order.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Layout {
    /// Gaussians of each chunk (1..=65,536 each).
    pub chunk_sizes: Vec<u32>,
    /// Chunks of each level (≥ 1 each, summing to the number of chunks).
    pub level_chunks: Vec<u32>,
}

impl Layout {
    /// The layout of a 3.0 file of `n` Gaussians: one level, chunks of [`CHUNK`] (the last one
    /// shorter). Empty for `n = 0`.
    pub fn uniform(n: usize) -> Layout {
        Layout::from_levels(&[n])
    }

    /// Levels of the given Gaussian counts (zero counts are left out), each split into chunks of
    /// [`CHUNK`] (its last one shorter): what our encoder writes.
    pub fn from_levels(levels: &[usize]) -> Layout {
        let mut l = Layout::default();
        for &n in levels.iter().filter(|&&n| n > 0) {
            let chunks = n.div_ceil(CHUNK);
            l.chunk_sizes.extend((0..chunks).map(|c| (CHUNK.min(n - c * CHUNK)) as u32));
            l.level_chunks.push(chunks as u32);
        }
        l
    }

    /// Number of Gaussians.
    pub fn gaussians(&self) -> usize {
        self.chunk_sizes.iter().map(|&k| k as usize).sum()
    }

    /// Number of chunks.
    pub fn chunks(&self) -> usize {
        self.chunk_sizes.len()
    }

    /// The Gaussians of every chunk, in order.
    pub fn chunk_ranges(&self) -> Vec<Range<usize>> {
        let mut start = 0;
        self.chunk_sizes
            .iter()
            .map(|&k| {
                start += k as usize;
                start - k as usize..start
            })
            .collect()
    }

    /// The chunks of every level, in order.
    pub fn level_ranges(&self) -> Vec<Range<usize>> {
        let mut start = 0;
        self.level_chunks
            .iter()
            .map(|&c| {
                start += c as usize;
                start - c as usize..start
            })
            .collect()
    }

    /// The number of Gaussians of every level.
    pub fn level_sizes(&self) -> Vec<usize> {
        self.level_ranges().into_iter().map(|r| self.chunk_sizes[r].iter().map(|&k| k as usize).sum()).collect()
    }

    /// Reads a levels section of a file of `n` Gaussians (SPEC §3.1): `varint L`, then per level
    /// `varint C` and `C × varint K`. Every count is checked as it is read (a chunk of 1..=65,536
    /// Gaussians, a level of ≥ 1 chunk, at most 65,536 chunks, no more Gaussians than `n`), so
    /// memory stays within the section's length; the sizes must sum to `n` and the section must
    /// be consumed exactly.
    pub fn read(r: &mut ByteReader<'_>, n: usize) -> Result<Layout, DecodeError> {
        let mut l = Layout::default();
        let mut total = 0usize;
        let levels = r.varint("level count")?;
        for _ in 0..levels {
            let at = r.clone();
            let chunks = r.varint("chunk count of a level")?;
            if chunks == 0 {
                return Err(at.corrupt("level of zero chunks"));
            }
            if l.chunks() + chunks as usize > 1 << 16 {
                return Err(at.corrupt("more than 65,536 chunks"));
            }
            for _ in 0..chunks {
                let at = r.clone();
                let k = r.varint("chunk size")? as usize;
                if k == 0 || k > CHUNK {
                    return Err(at.corrupt("chunk size outside 1..=65536"));
                }
                total += k;
                if total > n {
                    return Err(at.corrupt("chunk sizes add up to more than the Gaussian count"));
                }
                l.chunk_sizes.push(k as u32);
            }
            l.level_chunks.push(chunks);
        }
        if total != n {
            return Err(r.corrupt("chunk sizes add up to less than the Gaussian count"));
        }
        if r.remaining() != 0 {
            return Err(r.corrupt("bytes after the levels"));
        }
        Ok(l)
    }

    /// The levels section's payload.
    pub fn write(&self) -> Vec<u8> {
        let mut w = ByteWriter::new();
        w.varint(self.level_chunks.len() as u32);
        for r in self.level_ranges() {
            w.varint(r.len() as u32);
            self.chunk_sizes[r].iter().for_each(|&k| w.varint(k));
        }
        w.buf
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn levels_split_into_chunks_and_read_back() {
        let l = Layout::from_levels(&[3, 0, 70_000, 65_536]);
        assert_eq!(l.chunk_sizes, vec![3, 65_536, 4_464, 65_536]);
        assert_eq!(l.level_chunks, vec![1, 2, 1]);
        assert_eq!(l.level_sizes(), vec![3, 70_000, 65_536]);
        assert_eq!(l.chunk_ranges()[2], 65_539..70_003);
        assert_eq!(l.gaussians(), 135_539);
        let bytes = l.write();
        assert_eq!(Layout::read(&mut ByteReader::new(&bytes), 135_539).unwrap(), l);
        assert_eq!(Layout::uniform(70_000), Layout { chunk_sizes: vec![65_536, 4_464], level_chunks: vec![2] });
        assert_eq!(Layout::uniform(0), Layout::default());
    }

    #[test]
    fn bad_levels_are_format_errors() {
        let section = |v: &[u32]| {
            let mut w = ByteWriter::new();
            v.iter().for_each(|&x| w.varint(x));
            w.buf
        };
        let read = |v: &[u32], n| Layout::read(&mut ByteReader::new(&section(v)), n).map_err(|e| e.class());
        assert!(read(&[2, 1, 5, 2, 3, 4], 12).is_ok());
        for (bad, why) in [
            (&[2, 1, 5, 2, 3, 4][..], "sum above n"),
            (&[1, 1, 5][..], "sum below n"),
            (&[2, 1, 11, 0][..], "level of no chunks"),
            (&[1, 2, 0, 12][..], "zero chunk"),
            (&[1, 1, 65_537][..], "chunk above 65536"),
            (&[0][..], "no levels"),
            (&[1, 1][..], "truncated"),
        ] {
            let n = if why == "chunk above 65536" { 65_537 } else { 12 - (why == "sum above n") as usize };
            assert_eq!(read(bad, n), Err("format"), "{why}");
        }
        let mut extra = section(&[1, 1, 12]);
        extra.push(0);
        assert_eq!(Layout::read(&mut ByteReader::new(&extra), 12).map_err(|e| e.class()), Err("format"));
    }
}

//! Symbol streams: constriction's queue range coder (`u32` words, `u64` state, 16-bit
//! probabilities) with our integer tables as its models. The decoder reads untrusted words
//! through a bounds-checked backend; no call can panic on garbage (SPEC §5, §9).

use std::cell::Cell;
use std::num::NonZeroU32;
use std::rc::Rc;

use constriction::backends::ReadWords;
use constriction::stream::model::{DecoderModel, EncoderModel, EntropyModel};
use constriction::stream::queue::{DefaultRangeEncoder, RangeDecoder};
use constriction::stream::{Decode, Encode};
use constriction::Queue;

use super::{ChannelTable, FreqTable, PRECISION};
use crate::bitstream::bytes::{unzigzag, zigzag};
use crate::bitstream::DecodeError;

/// Reads past the end of a stream give zero words; more than this many such reads is corruption.
pub const MAX_OVERRUN_WORDS: usize = 2;

impl EntropyModel<PRECISION> for &FreqTable {
    type Symbol = usize;
    type Probability = u32;
}

impl EncoderModel<PRECISION> for &FreqTable {
    fn left_cumulative_and_probability(&self, symbol: impl core::borrow::Borrow<usize>) -> Option<(u32, NonZeroU32)> {
        let s = *symbol.borrow();
        (s < self.len()).then(|| (self.left(s), NonZeroU32::new(self.freq(s)).expect("frequencies are non-zero")))
    }
}

impl DecoderModel<PRECISION> for &FreqTable {
    fn quantile_function(&self, quantile: u32) -> (usize, u32, NonZeroU32) {
        let s = self.lookup(quantile);
        (s, self.left(s), NonZeroU32::new(self.freq(s)).expect("frequencies are non-zero"))
    }
}

/// `k` raw bits (1..=16): the uniform distribution over `0..2^k`, each value with frequency `2^(16-k)`.
#[derive(Clone, Copy)]
struct RawBits(u32);

impl EntropyModel<PRECISION> for RawBits {
    type Symbol = u32;
    type Probability = u32;
}

impl EncoderModel<PRECISION> for RawBits {
    fn left_cumulative_and_probability(&self, symbol: impl core::borrow::Borrow<u32>) -> Option<(u32, NonZeroU32)> {
        let s = *symbol.borrow();
        let shift = PRECISION as u32 - self.0;
        (s < 1 << self.0).then(|| (s << shift, NonZeroU32::new(1 << shift).expect("non-zero")))
    }
}

impl DecoderModel<PRECISION> for RawBits {
    fn quantile_function(&self, quantile: u32) -> (u32, u32, NonZeroU32) {
        let shift = PRECISION as u32 - self.0;
        let s = quantile >> shift;
        (s, s << shift, NonZeroU32::new(1 << shift).expect("non-zero"))
    }
}

/// Little-endian `u32` words from a byte slice; counts reads past the end.
#[derive(Debug)]
struct WordReader<'a> {
    data: &'a [u8],
    pos: usize,
    overrun: Rc<Cell<usize>>,
}

impl ReadWords<u32, Queue> for WordReader<'_> {
    type ReadError = std::convert::Infallible;

    fn read(&mut self) -> Result<Option<u32>, Self::ReadError> {
        match self.data.get(self.pos..self.pos + 4) {
            Some(b) => {
                self.pos += 4;
                Ok(Some(u32::from_le_bytes([b[0], b[1], b[2], b[3]])))
            }
            None => {
                self.overrun.set(self.overrun.get() + 1);
                Ok(None)
            }
        }
    }
}

/// Decodes symbols from one independent stream.
pub struct SymbolDecoder<'a> {
    inner: RangeDecoder<u32, u64, WordReader<'a>>,
    overrun: Rc<Cell<usize>>,
}

impl<'a> SymbolDecoder<'a> {
    /// `data` must be a whole number of 32-bit little-endian words.
    pub fn new(data: &'a [u8]) -> Result<Self, DecodeError> {
        if data.len() % 4 != 0 {
            return Err(DecodeError::Corrupt("stream length is not a multiple of 4"));
        }
        let overrun = Rc::new(Cell::new(0));
        let Ok(inner) = RangeDecoder::with_backend(WordReader { data, pos: 0, overrun: overrun.clone() });
        Ok(SymbolDecoder { inner, overrun })
    }

    fn check(&self) -> Result<(), DecodeError> {
        if self.overrun.get() > MAX_OVERRUN_WORDS {
            return Err(DecodeError::Corrupt("symbol stream ends early"));
        }
        Ok(())
    }

    /// One symbol of `table`.
    pub fn symbol(&mut self, table: &FreqTable) -> Result<usize, DecodeError> {
        let s = self.inner.decode_symbol(table).map_err(|_| DecodeError::Corrupt("invalid symbol stream"))?;
        self.check()?;
        Ok(s)
    }

    /// `k` raw bits, 1..=16.
    fn raw_piece(&mut self, k: u32) -> Result<u32, DecodeError> {
        let s = self.inner.decode_symbol(RawBits(k)).map_err(|_| DecodeError::Corrupt("invalid symbol stream"))?;
        self.check()?;
        Ok(s)
    }

    /// `bits` (0..=32) raw bits in pieces of at most 16, most significant piece first.
    pub fn raw_bits(&mut self, bits: u32) -> Result<u32, DecodeError> {
        let mut v: u64 = 0;
        let mut left = bits;
        while left > 0 {
            let take = left.min(16);
            let piece = self.raw_piece(take)?;
            v = (v << take) | u64::from(piece);
            left -= take;
        }
        Ok(v as u32)
    }

    /// One value of a channel (handles constants and escapes).
    pub fn value(&mut self, channel: &ChannelTable) -> Result<i32, DecodeError> {
        match channel {
            ChannelTable::Constant(v) => Ok(*v),
            ChannelTable::Coded { lo, table } => {
                let s = self.symbol(table)?;
                if s + 1 == table.len() {
                    Ok(unzigzag(self.raw_bits(32)?))
                } else {
                    // lo + n does not overflow: checked when the table was read.
                    Ok(lo + s as i32)
                }
            }
        }
    }
}

/// Encodes symbols into one independent stream.
pub struct SymbolEncoder {
    inner: DefaultRangeEncoder,
}

impl Default for SymbolEncoder {
    fn default() -> Self {
        Self::new()
    }
}

impl SymbolEncoder {
    pub fn new() -> Self {
        SymbolEncoder { inner: DefaultRangeEncoder::new() }
    }

    pub fn symbol(&mut self, table: &FreqTable, s: usize) {
        self.inner.encode_symbol(s, table).expect("symbol in table");
    }

    pub fn raw_bits(&mut self, value: u32, bits: u32) {
        let mut left = bits;
        while left > 0 {
            let take = left.min(16);
            left -= take;
            let piece = ((u64::from(value) >> left) & ((1 << take) - 1)) as u32;
            self.inner.encode_symbol(piece, RawBits(take)).expect("raw bits");
        }
    }

    /// One value of a channel; out-of-range values are escaped. Returns nothing for constants
    /// (the caller guarantees the value equals the constant).
    pub fn value(&mut self, channel: &ChannelTable, v: i32) {
        match channel {
            ChannelTable::Constant(c) => debug_assert_eq!(*c, v),
            ChannelTable::Coded { lo, table } => {
                let n = table.len() - 1;
                match v.checked_sub(*lo) {
                    Some(d) if d >= 0 && (d as usize) < n => self.symbol(table, d as usize),
                    _ => {
                        self.symbol(table, n);
                        self.raw_bits(zigzag(v), 32);
                    }
                }
            }
        }
    }

    /// Bits a value costs under `channel` (the exact ideal code length).
    pub fn value_bits(channel: &ChannelTable, v: i32) -> f64 {
        match channel {
            ChannelTable::Constant(_) => 0.0,
            ChannelTable::Coded { lo, table } => {
                let n = table.len() - 1;
                match v.checked_sub(*lo) {
                    Some(d) if d >= 0 && (d as usize) < n => table.bits(d as usize),
                    _ => table.bits(n) + 32.0,
                }
            }
        }
    }

    /// Seals the stream and returns its bytes (little-endian words).
    pub fn finish(self) -> Vec<u8> {
        let words = self.inner.into_compressed().expect("vec backend");
        words.iter().flat_map(|w| w.to_le_bytes()).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_with_escapes_and_raw_bits() {
        let ch = ChannelTable::Coded { lo: -3, table: FreqTable::from_weights(&[1, 5, 20, 5, 1, 1]) };
        let values: Vec<i32> = (0..5000).map(|i| ((i * 7919) % 13) as i32 - 6).chain([i32::MIN, i32::MAX, 0]).collect();
        let mut e = SymbolEncoder::new();
        for (i, &v) in values.iter().enumerate() {
            e.value(&ch, v);
            e.raw_bits(i as u32 % 1000, 10);
        }
        let bytes = e.finish();
        let mut d = SymbolDecoder::new(&bytes).unwrap();
        for (i, &v) in values.iter().enumerate() {
            assert_eq!(d.value(&ch).unwrap(), v);
            assert_eq!(d.raw_bits(10).unwrap(), i as u32 % 1000);
        }
    }

    #[test]
    fn garbage_never_panics() {
        let t = FreqTable::from_weights(&[1, 100, 3]);
        let mut seed = 12345u64;
        for len in 0..64 {
            let bytes: Vec<u8> = (0..len * 4)
                .map(|_| {
                    seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                    (seed >> 56) as u8
                })
                .collect();
            let mut d = SymbolDecoder::new(&bytes).unwrap();
            for _ in 0..1000 {
                if d.symbol(&t).is_err() {
                    break;
                }
            }
        }
    }
}

//! Symbol streams: constriction's stack ANS coder (`u32` words, `u64` state, 16-bit
//! probabilities) with our integer tables as its models (SPEC §5). Each stream is stored with
//! its words in the order the decoder reads them, so a stream decodes front to back. Decoding
//! untrusted words cannot panic: garbage decodes to garbage symbols, and [`SymbolDecoder::finish`]
//! rejects a stream that does not end exactly where its encoder started.

use std::num::NonZeroU32;

use constriction::backends::ReadWords;
use constriction::stream::model::{DecoderModel, EncoderModel, EntropyModel};
use constriction::stream::stack::{AnsCoder, DefaultAnsCoder};
use constriction::stream::{Decode, Encode};
use constriction::{CoderError, Stack};

use super::neighbour::{Neighbour, NeighbourDecoder};
use super::{symbol_of, ChannelTable, FreqTable, Lookup, PRECISION};
use crate::bitstream::bytes::{unzigzag, zigzag};

impl EntropyModel<PRECISION> for Lookup<'_> {
    type Symbol = usize;
    type Probability = u32;
}

impl DecoderModel<PRECISION> for Lookup<'_> {
    #[inline(always)]
    fn quantile_function(&self, quantile: u32) -> (usize, u32, NonZeroU32) {
        let (s, left, freq) = self.find(quantile);
        // Tables are strictly increasing (`FreqTable::from_weights`), so `freq > 0`.
        (s, left, NonZeroU32::new(freq).unwrap_or(NonZeroU32::MIN))
    }
}

/// `k` raw bits (1..=16): the uniform distribution over `0..2^k`, each value with frequency `2^(16-k)`.
#[derive(Clone, Copy)]
struct RawBits(u32);

impl EntropyModel<PRECISION> for RawBits {
    type Symbol = u32;
    type Probability = u32;
}

impl DecoderModel<PRECISION> for RawBits {
    #[inline(always)]
    fn quantile_function(&self, quantile: u32) -> (u32, u32, NonZeroU32) {
        let shift = PRECISION as u32 - self.0;
        let s = quantile >> shift;
        (s, s << shift, NonZeroU32::new(1 << shift).expect("non-zero"))
    }
}

/// One coded interval `(left cumulative, frequency)`: what the encoder needs of any symbol.
#[derive(Clone, Copy)]
struct Interval(u32, NonZeroU32);

impl EntropyModel<PRECISION> for Interval {
    type Symbol = ();
    type Probability = u32;
}

impl EncoderModel<PRECISION> for Interval {
    fn left_cumulative_and_probability(&self, _: impl core::borrow::Borrow<()>) -> Option<(u32, NonZeroU32)> {
        Some((self.0, self.1))
    }
}

/// Little-endian `u32` words from a byte slice, front to back; `rest` is what is left to read.
#[derive(Debug)]
struct WordReader<'a> {
    rest: &'a [u8],
}

impl ReadWords<u32, Stack> for WordReader<'_> {
    type ReadError = std::convert::Infallible;

    #[inline(always)]
    fn read(&mut self) -> Result<Option<u32>, Self::ReadError> {
        Ok(self.rest.split_first_chunk::<4>().map(|(word, rest)| {
            self.rest = rest;
            u32::from_le_bytes(*word)
        }))
    }
}

/// The value of a decode result whose error types are uninhabited.
#[inline(always)]
fn infallible<T>(r: Result<T, CoderError<std::convert::Infallible, std::convert::Infallible>>) -> T {
    match r {
        Ok(v) => v,
        Err(CoderError::Frontend(e) | CoderError::Backend(e)) => match e {},
    }
}

/// Decodes symbols from one independent stream.
pub struct SymbolDecoder<'a> {
    inner: AnsCoder<u32, u64, WordReader<'a>>,
}

impl<'a> SymbolDecoder<'a> {
    /// `data` must be a whole number of 32-bit little-endian words, the first one non-zero;
    /// the error says which rule failed.
    pub fn new(data: &'a [u8]) -> Result<Self, &'static str> {
        if data.len() % 4 != 0 {
            return Err("stream length is not a multiple of 4");
        }
        AnsCoder::from_compressed(WordReader { rest: data })
            .map(|inner| SymbolDecoder { inner })
            .map_err(|_| "stream starts with a zero word")
    }

    /// One symbol of `table`.
    #[inline(always)]
    pub fn symbol(&mut self, table: Lookup<'_>) -> usize {
        infallible(self.inner.decode_symbol(table))
    }

    /// `bits` (0..=32) raw bits in pieces of at most 16, most significant piece first.
    pub fn raw_bits(&mut self, bits: u32) -> u32 {
        let mut v: u64 = 0;
        let mut left = bits;
        while left > 0 {
            let take = left.min(16);
            let piece = infallible(self.inner.decode_symbol(RawBits(take)));
            v = (v << take) | u64::from(piece);
            left -= take;
        }
        v as u32
    }

    /// One value of a coded channel: `lo + s`, or after the escape symbol 32 raw bits.
    #[inline(always)]
    pub fn coded_value(&mut self, lo: i32, table: Lookup<'_>) -> i32 {
        let s = self.symbol(table);
        if s + 1 == table.len() {
            unzigzag(self.raw_bits(32))
        } else {
            // lo + n does not overflow: checked when the table was read.
            lo + s as i32
        }
    }

    /// One value of a channel in context `ctx` (see [`super::context`]; ignored unless the
    /// channel is context-coded). Constants read nothing.
    #[inline(always)]
    pub fn value(&mut self, channel: &ChannelTable, ctx: usize) -> i32 {
        match channel {
            ChannelTable::Constant(v) => *v,
            ChannelTable::Coded { lo, table } => self.coded_value(*lo, table.lookup_table()),
            ChannelTable::Context { lo, tables, .. } => self.coded_value(*lo, tables[ctx].lookup_table()),
            // Callers read neighbour-context channels with `neighbour_value`; the tables this is
            // used for (position lengths) are checked to be mode 0 or 1 when read.
            ChannelTable::Neighbour(_) => unreachable!("a neighbour-context channel read without its neighbours"),
        }
    }

    /// One value of a neighbour-context channel (SPEC §4.3) whose previous value is `prev` and
    /// value below `lower`; `None` when the prediction plus the difference leaves `i32`.
    #[inline(always)]
    pub fn neighbour_value(&mut self, t: &NeighbourDecoder<'_>, prev: i32, lower: i32) -> Option<i32> {
        let (table, mu) = t.context(prev, lower);
        let s = self.symbol(table);
        if s + 1 == table.len() {
            Some(unzigzag(self.raw_bits(32)))
        } else {
            t.value(mu, s)
        }
    }

    /// Checks that the stream ended where its encoder began: every word read and the state back
    /// to zero. Anything else means the stream was not produced for the values decoded from it.
    pub fn finish(self) -> Result<(), &'static str> {
        let (reader, state) = self.inner.into_raw_parts();
        if !reader.rest.is_empty() || state != 0 {
            return Err("symbol stream does not end where its values do");
        }
        Ok(())
    }
}

/// Encodes symbols into one independent stream. ANS codes last-in first-out, so symbols are
/// collected in decode order and coded in reverse by [`SymbolEncoder::finish`].
#[derive(Default)]
pub struct SymbolEncoder {
    intervals: Vec<Interval>,
}

impl SymbolEncoder {
    pub fn new() -> Self {
        SymbolEncoder::default()
    }

    pub fn symbol(&mut self, table: &FreqTable, s: usize) {
        assert!(s < table.len(), "symbol outside its table");
        self.intervals.push(Interval(table.left(s), NonZeroU32::new(table.freq(s)).expect("frequencies are non-zero")));
    }

    pub fn raw_bits(&mut self, value: u32, bits: u32) {
        let mut left = bits;
        while left > 0 {
            let take = left.min(16);
            left -= take;
            let piece = ((u64::from(value) >> left) & ((1 << take) - 1)) as u32;
            let shift = PRECISION as u32 - take;
            self.intervals.push(Interval(piece << shift, NonZeroU32::new(1 << shift).expect("non-zero")));
        }
    }

    /// One value of a channel in context `ctx`; out-of-range values are escaped. Codes nothing
    /// for constants (the caller guarantees the value equals the constant).
    pub fn value(&mut self, channel: &ChannelTable, ctx: usize, v: i32) {
        match channel.contexts() {
            None => debug_assert_eq!(channel, &ChannelTable::Constant(v)),
            Some((lo, _, tables)) => {
                let (table, n) = (tables[ctx], tables[ctx].len() - 1);
                let s = symbol_of(lo, n, v);
                self.symbol(table, s);
                if s == n {
                    self.raw_bits(zigzag(v), 32);
                }
            }
        }
    }

    /// One value of a neighbour-context channel (SPEC §4.3) after `prev`, with `lower` below it;
    /// values the window does not reach are escaped.
    pub fn neighbour_value(&mut self, t: &Neighbour, prev: i32, lower: i32, v: i32) {
        let (table, s) = t.code(prev, lower, v);
        self.symbol(table, s);
        if s + 1 == table.len() {
            self.raw_bits(zigzag(v), 32);
        }
    }

    /// Bits a neighbour-context value costs (the exact ideal code length).
    pub fn neighbour_bits(t: &Neighbour, prev: i32, lower: i32, v: i32) -> f64 {
        let (table, s) = t.code(prev, lower, v);
        table.bits(s) + if s + 1 == table.len() { 32.0 } else { 0.0 }
    }

    /// Bits a value costs under `channel` in context `ctx` (the exact ideal code length).
    pub fn value_bits(channel: &ChannelTable, ctx: usize, v: i32) -> f64 {
        match channel.contexts() {
            None => 0.0,
            Some((lo, _, tables)) => {
                let (table, n) = (tables[ctx], tables[ctx].len() - 1);
                let s = symbol_of(lo, n, v);
                table.bits(s) + if s == n { 32.0 } else { 0.0 }
            }
        }
    }

    /// Codes the collected symbols and returns the stream's bytes: little-endian words in the
    /// order the decoder reads them.
    pub fn finish(self) -> Vec<u8> {
        let mut ans = DefaultAnsCoder::new();
        for &i in self.intervals.iter().rev() {
            ans.encode_symbol((), i).expect("intervals are valid");
        }
        let words = ans.into_compressed().expect("vec backend");
        words.iter().rev().flat_map(|w| w.to_le_bytes()).collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_with_escapes_and_raw_bits() {
        let ch = ChannelTable::Coded { lo: -3, table: FreqTable::from_weights(&[1, 5, 20, 5, 1, 1]) };
        let values: Vec<i32> = (0..5000).map(|i: i32| (i * 7919) % 13 - 6).chain([i32::MIN, i32::MAX, 0]).collect();
        let mut e = SymbolEncoder::new();
        for (i, &v) in values.iter().enumerate() {
            e.value(&ch, 0, v);
            e.raw_bits(i as u32 % 1000, 10);
        }
        let bytes = e.finish();
        let mut d = SymbolDecoder::new(&bytes).unwrap();
        for (i, &v) in values.iter().enumerate() {
            assert_eq!(d.value(&ch, 0), v);
            assert_eq!(d.raw_bits(10), i as u32 % 1000);
        }
        d.finish().unwrap();
    }

    #[test]
    fn empty_and_all_zero_symbol_streams() {
        // Coding only the first symbol (left cumulative 0) from the empty state stays at state 0:
        // the stream is empty and still decodes.
        let t = FreqTable::from_weights(&[9, 1]);
        let mut e = SymbolEncoder::new();
        (0..100).for_each(|_| e.symbol(&t, 0));
        let bytes = e.finish();
        assert!(bytes.is_empty());
        let mut d = SymbolDecoder::new(&bytes).unwrap();
        assert!((0..100).all(|_| d.symbol(t.lookup_table()) == 0));
        d.finish().unwrap();
    }

    #[test]
    fn finish_rejects_streams_that_do_not_match_their_values() {
        let t = FreqTable::from_weights(&[1, 2, 3, 4]);
        let mut e = SymbolEncoder::new();
        (0..1000).for_each(|i| e.symbol(&t, i % 4));
        let bytes = e.finish();
        // Too few values read, and a stream with one word dropped.
        let mut d = SymbolDecoder::new(&bytes).unwrap();
        (0..999).for_each(|_| _ = d.symbol(t.lookup_table()));
        assert!(d.finish().is_err());
        let mut d = SymbolDecoder::new(&bytes[..bytes.len() - 4]).unwrap();
        (0..1000).for_each(|_| _ = d.symbol(t.lookup_table()));
        assert!(d.finish().is_err());
        assert!(SymbolDecoder::new(&[0, 0, 0, 0, 1, 0, 0, 0]).is_err(), "leading zero word");
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
            if let Ok(mut d) = SymbolDecoder::new(&bytes) {
                for _ in 0..1000 {
                    _ = d.symbol(t.lookup_table());
                    _ = d.raw_bits(32);
                }
                _ = d.finish();
            }
        }
    }
}

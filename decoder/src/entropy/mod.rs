//! Integer probability tables and symbol coding with constriction's ANS coder.
//!
//! Every probability the decoder uses comes from a [`FreqTable`]: 16-bit fixed-point
//! frequencies rebuilt from integer weights read from the bitstream by integer arithmetic
//! only (SPEC §4.2). Values outside a channel's table range are sent through an escape symbol
//! followed by 32 raw bits. How a channel's tables are stored is [`crate::bitstream::tables`].

mod coder;
pub mod neighbour;

pub use coder::{SymbolDecoder, SymbolEncoder};

#[doc(hidden)]
pub use crate::bitstream::tables::ChannelTable;

/// Probabilities are fixed point with this many bits: they sum to `1 << PRECISION`.
pub const PRECISION: usize = 16;
pub const TOTAL: u32 = 1 << PRECISION;
/// Largest number of in-range symbols a table may have (the escape symbol comes on top).
pub const MAX_SYMBOLS: usize = 4096;

/// A cumulative frequency table over symbols `0..len()`; every symbol has a non-zero frequency.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FreqTable {
    /// `cdf[0] = 0`, `cdf[len] = TOTAL`, strictly increasing.
    cdf: Vec<u32>,
    /// `bucket[b]` = the symbol holding quantile `b << shift`: where the decoder's search for a
    /// quantile in bucket `b` starts (a derived cache of `cdf`).
    bucket: Vec<u16>,
    /// `2^(16 - shift)` buckets: about two per symbol, 64 to 4096.
    shift: u32,
}

impl FreqTable {
    /// Rebuilds frequencies from integer weights (SPEC §4.2): with `n` symbols, `R = 2^16 - n`
    /// and `T = Σw` (all weights 1 when `T = 0`), `f_s = 1 + ⌊w_s·R/T⌋`; what is left of `2^16`
    /// goes to the first symbol of largest weight.
    pub fn from_weights(weights: &[u32]) -> FreqTable {
        let n = weights.len();
        assert!((2..=MAX_SYMBOLS + 1).contains(&n), "table needs 2..=4097 symbols");
        let sum: u64 = weights.iter().map(|&x| u64::from(x)).sum();
        // All weights 1 when they sum to 0.
        let (ones, total) = if sum == 0 { (1, n as u64) } else { (0, sum) };
        let r = u64::from(TOTAL) - n as u64;
        let share = Share::new(r, total);
        let mut cdf = Vec::with_capacity(n + 1);
        cdf.push(0);
        let (mut acc, mut best, mut best_w) = (0u32, 0, 0);
        for (s, &x) in weights.iter().enumerate() {
            let w = x | ones;
            acc += 1 + share.of(w);
            cdf.push(acc);
            if w > best_w {
                (best, best_w) = (s, w);
            }
        }
        // The remainder of 2^16 to the first symbol of largest weight: every later bound moves.
        let rest = TOTAL - acc;
        cdf[best + 1..].iter_mut().for_each(|c| *c += rest);
        // Bucket b starts in the symbol s with cdf[s] <= b·2^shift < cdf[s+1].
        let shift = PRECISION as u32 - (n.next_power_of_two().trailing_zeros() + 3).clamp(8, 12);
        let mut bucket = vec![0u16; (TOTAL >> shift) as usize];
        let first_bucket = |c: u32| (c.div_ceil(1 << shift)) as usize;
        for (s, w) in cdf.windows(2).enumerate() {
            bucket[first_bucket(w[0])..first_bucket(w[1])].fill(s as u16); // s < n <= 4097
        }
        FreqTable { cdf, bucket, shift }
    }

    /// Number of symbols (including the escape symbol where there is one).
    pub fn len(&self) -> usize {
        self.cdf.len() - 1
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Frequency of symbol `s` (out of `2^16`).
    pub fn freq(&self, s: usize) -> u32 {
        self.cdf[s + 1] - self.cdf[s]
    }

    /// Cost of symbol `s` in bits.
    pub fn bits(&self, s: usize) -> f64 {
        PRECISION as f64 - f64::from(self.freq(s)).log2()
    }

    fn left(&self, s: usize) -> u32 {
        self.cdf[s]
    }

    /// The decoder's view of the table (slices, no indirection through the table).
    pub fn lookup_table(&self) -> Lookup<'_> {
        Lookup { cdf: &self.cdf, bucket: &self.bucket, shift: self.shift }
    }
}

/// `⌊w·r/t⌋` for weights `w ≤ t` (so the quotient is at most `r < 2^16`), exactly, without an
/// integer division per weight. `w·(r/t)` in `f64` is within `2^16·2^−51` of the true quotient,
/// so truncating it is the floor or one off it, and one integer check corrects that. (Tables are
/// rebuilt for every channel of a file, neighbour-context files have many, and reading their
/// parameters was a sixth of decoding a small scene while this was a division per weight.)
#[derive(Clone, Copy)]
struct Share {
    r: u64,
    t: u64,
    ratio: f64,
}

impl Share {
    /// For `1 ≤ t < 2^47` (4,097 weights below 2^32 sum to less than 2^45), `r < 2^16`.
    fn new(r: u64, t: u64) -> Share {
        debug_assert!(r < 1 << 16 && (1..1 << 47).contains(&t));
        Share { r, t, ratio: r as f64 / t as f64 }
    }

    #[inline(always)]
    fn of(self, w: u32) -> u32 {
        debug_assert!(u64::from(w) <= self.t);
        let num = u64::from(w) * self.r;
        let q = (f64::from(w) * self.ratio) as i64 as u64;
        let q = if q * self.t > num {
            q - 1
        } else if (q + 1) * self.t <= num {
            q + 1
        } else {
            q
        };
        q as u32
    }
}

/// What the decoder needs of a [`FreqTable`] to turn a quantile into a symbol.
#[derive(Debug, Clone, Copy)]
pub struct Lookup<'a> {
    cdf: &'a [u32],
    bucket: &'a [u16],
    shift: u32,
}

impl Lookup<'_> {
    /// Number of symbols.
    #[inline(always)]
    pub fn len(self) -> usize {
        self.cdf.len() - 1
    }

    pub fn is_empty(self) -> bool {
        self.len() == 0
    }

    /// The symbol whose interval holds `q < 2^16` with its left cumulative frequency and
    /// frequency: a bucket lookup, then a short forward scan over the symbols sharing the bucket.
    #[inline(always)]
    fn find(self, q: u32) -> (usize, u32, u32) {
        let mut s = usize::from(self.bucket[(q >> self.shift) as usize]);
        let mut right = self.cdf[s + 1];
        while right <= q {
            s += 1;
            right = self.cdf[s + 1];
        }
        let left = self.cdf[s];
        (s, left, right - left)
    }
}

/// Number of contexts of a context-coded channel.
pub const CONTEXTS: usize = 4;

/// The context of a value whose predecessor in the channel (previous Gaussian of the chunk;
/// `centre` for the first) is `prev`: how far `prev` lies from the channel's centre,
/// 0 → 0, 1 → 1, 2..=3 → 2, ≥ 4 → 3 (SPEC §5.2).
#[inline(always)]
pub fn context(prev: i32, centre: i32) -> usize {
    // A table lookup on the clamped distance: no data-dependent branch in the decoder's loop.
    const CLASS: [u8; 5] = [0, 1, 2, 2, 3];
    let d = (i64::from(prev) - i64::from(centre)).unsigned_abs().min(4);
    usize::from(CLASS[d as usize])
}

/// The values of one stream with their contexts: value i's context is [`context`] of value
/// i−1, and of `centre` for the first (SPEC §5.2). The encoder's side of the decoder's running
/// previous value.
pub fn in_context(values: &[i32], centre: i32) -> impl Iterator<Item = (usize, i32)> + '_ {
    let prevs = std::iter::once(centre).chain(values.iter().copied());
    prevs.zip(values).map(move |(prev, &v)| (context(prev, centre), v))
}

/// The symbol of value `v` in a table over `lo .. lo + n`: `v − lo`, or the escape `n` outside.
pub fn symbol_of(lo: i32, n: usize, v: i32) -> usize {
    let d = i64::from(v) - i64::from(lo);
    if d >= 0 && (d as usize) < n {
        d as usize
    } else {
        n
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shares_are_integer_floors() {
        let mut rng = crate::rng::Rng::new(0x9E37_79B9_7F4A_7C15);
        let mut next = move || rng.next_u64();
        for i in 0..200_000 {
            // Totals of up to 4,097 weights below 2^32, weights up to the total.
            let t = 1 + next() % (1 << (1 + i % 44));
            let r = u64::from(TOTAL) - 2 - next() % 4096;
            let share = Share::new(r, t);
            let w = (next() % (t + 1)).min(u64::from(u32::MAX));
            // Weights whose share is (or is next to) an exact integer, where rounding could land
            // on the wrong side: w·r/t = k exactly when w = k·t/r.
            let k = next() % (r + 1);
            let exact = k * t / r;
            for w in [w, exact, exact.saturating_sub(1), exact + 1] {
                if w <= t && w <= u64::from(u32::MAX) {
                    assert_eq!(u64::from(share.of(w as u32)), w * r / t, "{w}·{r}/{t}");
                }
            }
        }
    }

    /// SPEC §4.2 with 128-bit integer division: the reference `from_weights` follows.
    fn spec_frequencies(weights: &[u32]) -> Vec<u32> {
        let n = weights.len();
        let w: Vec<u128> = if weights.iter().all(|&x| x == 0) { vec![1; n] } else { weights.iter().map(|&x| u128::from(x)).collect() };
        let (t, r) = (w.iter().sum::<u128>(), u128::from(TOTAL) - n as u128);
        let mut f: Vec<u32> = w.iter().map(|&x| 1 + (x * r / t) as u32).collect();
        let best = (0..n).fold(0, |b, s| if w[s] > w[b] { s } else { b });
        f[best] += TOTAL - f.iter().sum::<u32>();
        f
    }

    #[test]
    fn frequencies_follow_the_spec() {
        let mut rng = crate::rng::Rng::new(0x2545_F491_4F6C_DD1D);
        let mut next = move || rng.next_u64();
        for i in 0..2_000 {
            let n = 2 + (next() % 4096) as usize;
            let bits = 1 + i % 32;
            let weights: Vec<u32> = (0..n).map(|_| if next() % 4 == 0 { 0 } else { (next() % (1 << bits)) as u32 }).collect();
            let t = FreqTable::from_weights(&weights);
            assert_eq!((0..n).map(|s| t.freq(s)).collect::<Vec<_>>(), spec_frequencies(&weights), "weights of {bits} bits");
        }
        for w in [vec![0, 0], vec![u32::MAX, u32::MAX], vec![u32::MAX; 4097], vec![0, 7, 7, 0]] {
            let t = FreqTable::from_weights(&w);
            assert_eq!((0..w.len()).map(|s| t.freq(s)).collect::<Vec<_>>(), spec_frequencies(&w));
        }
    }

    #[test]
    fn weights_normalise_to_total_with_nonzero_frequencies() {
        for weights in [vec![0, 0], vec![1, 0, 0, 5], vec![u32::MAX, 1, 0], vec![7; 4097]] {
            let t = FreqTable::from_weights(&weights);
            assert_eq!(t.cdf[t.len()], TOTAL);
            assert!((0..t.len()).all(|s| t.freq(s) >= 1));
        }
        let t = FreqTable::from_weights(&[3, 1]);
        // R = 65534, f = 1 + 49150, 1 + 16383 = 49151, 16384; remainder 1 to symbol 0.
        assert_eq!((t.freq(0), t.freq(1)), (49152, 16384));
    }

    #[test]
    fn context_classes() {
        let cases = [
            (0, 0, 0),
            (1, 0, 1),
            (-1, 0, 1),
            (3, 1, 2),
            (-2, 1, 2),
            (-3, 1, 3),
            (4, 0, 3),
            (i32::MIN, i32::MAX, 3),
            (i32::MAX, i32::MAX, 0),
        ];
        for (prev, centre, k) in cases {
            assert_eq!(context(prev, centre), k, "prev {prev} centre {centre}");
        }
    }

    #[test]
    fn lookup_inverts_the_cdf() {
        let t = FreqTable::from_weights(&[5, 0, 9, 1]);
        for q in 0..TOTAL {
            let (s, left, freq) = t.lookup_table().find(q);
            assert!(t.left(s) <= q && q < t.left(s) + t.freq(s));
            assert_eq!((left, freq), (t.left(s), t.freq(s)));
        }
    }
}

//! Neighbour-context tables (table mode 3, SPEC §4.3, format 8.0).
//!
//! A value is predicted from the channel's previous value in the chunk (the previous Gaussian in
//! Morton order, a spatial neighbour) and coded as its difference from the prediction under a
//! two-sided geometric window. The context — which prediction and which window — is chosen by
//! where the previous value and the value of the channel below (channel `j − 1` of the same
//! Gaussian) fall among stored thresholds. A context costs three small numbers instead of a
//! weight list, so a channel can afford many of them; every table is derived from integers.

use super::{FreqTable, Lookup};

/// The window ratios `r_ρ · 2^16`, `ρ = 0..64` (SPEC §4.3): `round(2^16 · exp(−1/s_ρ))` with
/// spreads `s_ρ = 2^((2ρ − 24)/9)` from 0.16 to 2,600 values, capped at 65,535.
pub const RATIOS: [u32; 64] = [
    115, 283, 617, 1200, 2125, 3466, 5274, 7557, 10287, 13399, 16807, 20411, 24109, 27809, 31429, 34905, 38190, 41250, 44069, 46637, 48958,
    51039, 52894, 54537, 55986, 57259, 58374, 59346, 60193, 60928, 61565, 62117, 62594, 63006, 63361, 63667, 63930, 64157, 64352, 64520,
    64664, 64788, 64894, 64985, 65064, 65131, 65189, 65238, 65280, 65317, 65348, 65375, 65398, 65418, 65434, 65449, 65461, 65472, 65481,
    65489, 65496, 65501, 65506, 65511,
];

/// Largest reach `E` of a window: differences `−E..=E` have symbols, others are escaped.
pub const MAX_REACH: u32 = 2047;
/// Most thresholds on the previous value, and on the value below.
pub const MAX_THRESHOLDS: usize = 15;
/// Largest mix `a`: the prediction is `(a·prev + (4 − a)·centre + 2) >> 2`.
pub const MAX_MIX: u8 = 4;

/// One context's prediction and window.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct NeighbourContext {
    /// Weight of the previous value in the prediction, in quarters (0..=4).
    pub mix: u8,
    /// The context's fixed part of the prediction.
    pub centre: i32,
    /// The window: index into [`RATIOS`].
    pub ratio: u8,
}

/// The context of a value whose previous value is `prev` and whose value below is `lower`, under
/// thresholds `prev_at` and `lower_at`: `bp·(L + 1) + bl`, `bp` the thresholds `≤ prev`, `bl`
/// those `≤ lower`, `L = lower_at.len()` (SPEC §4.3).
#[inline(always)]
pub fn context(prev_at: &[i32], lower_at: &[i32], prev: i32, lower: i32) -> usize {
    at_or_below(prev_at, prev) * (lower_at.len() + 1) + at_or_below(lower_at, lower)
}

/// How many of `thresholds` are `≤ v`.
#[inline(always)]
fn at_or_below(thresholds: &[i32], v: i32) -> usize {
    thresholds.iter().filter(|&&t| v >= t).count()
}

impl NeighbourContext {
    /// The prediction after `prev`: `⌊(a·prev + (4 − a)·centre + 2) / 4⌋`, `a` the mix.
    #[inline(always)]
    pub fn predict(self, prev: i32) -> i64 {
        (i64::from(self.mix) * i64::from(prev) + i64::from(MAX_MIX - self.mix) * i64::from(self.centre) + 2) >> 2
    }
}

/// A mode-3 channel table (SPEC §4.3).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Neighbour {
    /// `E`: the window covers differences `−E..=E` (1..=[`MAX_REACH`]).
    pub reach: u32,
    /// The previous value of a chunk's first value.
    pub start: i32,
    /// Thresholds on the previous value (at most [`MAX_THRESHOLDS`]).
    pub prev_at: Vec<i32>,
    /// Thresholds on the value below (none for channel 0).
    pub lower_at: Vec<i32>,
    /// `(prev_at.len() + 1) · (lower_at.len() + 1)` contexts, previous-value bucket major.
    pub contexts: Vec<NeighbourContext>,
    /// One window table per ratio in use; `window[c]` is context c's.
    tables: Vec<FreqTable>,
    window: Vec<u8>,
}

/// The window table of ratio index `ratio` and reach `e` (SPEC §4.3).
pub fn window(ratio: u8, e: u32) -> FreqTable {
    FreqTable::from_weights(&window_weights(RATIOS[usize::from(ratio)], e))
}

/// The weights of the window of ratio `r` (×2^16) and reach `e` (SPEC §4.3): `2e + 2` symbols,
/// symbol `e + d` and `e − d` weighing `W(|d|)` with `W(0) = 2^30`, `W(k+1) = ⌊W(k)·r / 2^16⌋`,
/// and the escape (last) 0.
fn window_weights(r: u32, e: u32) -> Vec<u32> {
    let e = e as usize;
    let mut w = vec![0u32; 2 * e + 2];
    let mut x: u64 = 1 << 30;
    for d in 0..=e {
        w[e + d] = x as u32;
        w[e - d] = x as u32;
        x = (x * u64::from(r)) >> 16;
    }
    w
}

impl Neighbour {
    /// The table from its stored fields; the caller has checked them (SPEC §4.3).
    pub fn new(reach: u32, start: i32, prev_at: Vec<i32>, lower_at: Vec<i32>, contexts: Vec<NeighbourContext>) -> Neighbour {
        debug_assert_eq!(contexts.len(), (prev_at.len() + 1) * (lower_at.len() + 1));
        let mut ratios: Vec<u8> = Vec::new();
        let which = contexts
            .iter()
            .map(|c| match ratios.iter().position(|&r| r == c.ratio) {
                Some(i) => i as u8,
                None => {
                    ratios.push(c.ratio);
                    (ratios.len() - 1) as u8
                }
            })
            .collect();
        let tables = ratios.iter().map(|&r| window(r, reach)).collect();
        Neighbour { reach, start, prev_at, lower_at, contexts, tables, window: which }
    }

    /// Whether a value's context depends on the channel below.
    pub fn uses_lower(&self) -> bool {
        !self.lower_at.is_empty()
    }

    /// The context of a value whose previous value is `prev` and whose value below is `lower`
    /// ([`context`]).
    #[inline(always)]
    pub fn context(&self, prev: i32, lower: i32) -> usize {
        context(&self.prev_at, &self.lower_at, prev, lower)
    }

    /// The prediction in context `c` after `prev` ([`NeighbourContext::predict`]).
    #[inline(always)]
    pub fn predict(&self, c: usize, prev: i32) -> i64 {
        self.contexts[c].predict(prev)
    }

    /// Context `c`'s table.
    #[inline(always)]
    pub fn table(&self, c: usize) -> &FreqTable {
        &self.tables[usize::from(self.window[c])]
    }

    /// The symbol of `v` predicted by `mu`: `v − mu + E`, or the escape `2E + 1`.
    #[inline(always)]
    pub fn symbol(&self, mu: i64, v: i32) -> usize {
        let e = i64::from(self.reach);
        let d = i64::from(v) - mu;
        if d.abs() <= e {
            (d + e) as usize
        } else {
            2 * self.reach as usize + 1
        }
    }

    /// The table and symbol that code `v` after `prev`, with `lower` below it (the encoder's side).
    pub fn code(&self, prev: i32, lower: i32, v: i32) -> (&FreqTable, usize) {
        let c = self.context(prev, lower);
        (self.table(c), self.symbol(self.predict(c, prev), v))
    }

    /// The value of in-window symbol `s` predicted by `mu`; `None` outside `i32`.
    #[inline(always)]
    pub fn value(&self, mu: i64, s: usize) -> Option<i32> {
        i32::try_from(mu + s as i64 - i64::from(self.reach)).ok()
    }
}

/// The widest span of thresholds whose counts [`BucketTable`] keeps in a table (4 KB, built once
/// per channel and chunk); wider ones are counted per value.
const MAX_TABLE_SPAN: i64 = 1 << 12;

/// `count of thresholds ≤ v`, times a factor, as a table over the thresholds' span (values
/// below it count none, values above it all), or counted where the span is too wide.
#[derive(Debug, Clone)]
struct BucketTable<'a> {
    min: i64,
    counts: Vec<u8>,
    thresholds: &'a [i32],
    factor: u8,
}

impl<'a> BucketTable<'a> {
    fn new(thresholds: &'a [i32], factor: usize) -> BucketTable<'a> {
        let (min, max) = thresholds.iter().fold((i64::MAX, i64::MIN), |(a, b), &t| (a.min(t.into()), b.max(t.into())));
        let counts = if thresholds.is_empty() || max - min + 2 > MAX_TABLE_SPAN {
            Vec::new()
        } else {
            // Index i holds the value min − 1 + i, up to max (min − 1 is below every threshold).
            std::iter::once(0).chain((min..=max).map(|v| (at_or_below(thresholds, v as i32) * factor) as u8)).collect()
        };
        BucketTable { min: min.saturating_sub(1), counts, thresholds, factor: factor as u8 }
    }

    #[inline(always)]
    fn get(&self, v: i32) -> usize {
        if self.thresholds.is_empty() {
            0
        } else if self.counts.is_empty() {
            at_or_below(self.thresholds, v) * usize::from(self.factor)
        } else {
            let i = (i64::from(v) - self.min).clamp(0, self.counts.len() as i64 - 1);
            usize::from(self.counts[i as usize])
        }
    }
}

/// One context as the decoder runs it: its window's lookup and its prediction's parts.
#[derive(Debug, Clone, Copy)]
struct DecodeContext<'a> {
    lookup: Lookup<'a>,
    mix: i64,
    /// `(4 − a)·centre + 2`.
    offset: i64,
}

/// A mode-3 table prepared for decoding: the contexts found by table lookups instead of
/// counting thresholds, each context's window and prediction side by side (the same values
/// as [`Neighbour::context`] and [`Neighbour::predict`]).
#[derive(Debug, Clone)]
pub struct NeighbourDecoder<'a> {
    prev: BucketTable<'a>,
    lower: BucketTable<'a>,
    contexts: Vec<DecodeContext<'a>>,
    table: &'a Neighbour,
}

impl<'a> NeighbourDecoder<'a> {
    pub fn new(t: &'a Neighbour) -> NeighbourDecoder<'a> {
        let contexts = (0..t.contexts.len())
            .map(|c| {
                let k = t.contexts[c];
                let (mix, centre) = (i64::from(k.mix), i64::from(k.centre));
                DecodeContext { lookup: t.table(c).lookup_table(), mix, offset: (i64::from(MAX_MIX) - mix) * centre + 2 }
            })
            .collect();
        NeighbourDecoder {
            prev: BucketTable::new(&t.prev_at, t.lower_at.len() + 1),
            lower: BucketTable::new(&t.lower_at, 1),
            contexts,
            table: t,
        }
    }

    /// The window of the value after `prev` with `lower` below it, and its prediction.
    #[inline(always)]
    pub fn context(&self, prev: i32, lower: i32) -> (Lookup<'a>, i64) {
        let c = self.contexts[self.prev.get(prev) + self.lower.get(lower)];
        (c.lookup, (c.mix * i64::from(prev) + c.offset) >> 2)
    }

    /// The value of in-window symbol `s` predicted by `mu` ([`Neighbour::value`]).
    #[inline(always)]
    pub fn value(&self, mu: i64, s: usize) -> Option<i32> {
        self.table.value(mu, s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The decoder's table lookups give the contexts and predictions of SPEC §4.3's definition,
    /// for thresholds in any order (the format allows it), narrow and wide spans, and values at
    /// and beyond the thresholds and `i32`'s ends.
    #[test]
    fn the_decoders_contexts_are_the_specs() {
        let mut rng = crate::rng::Rng::new(0x5DEE_CE66_D1CE_4E5B);
        for case in 0..400 {
            let spread: i64 = [3, 40, 1000, 5000, 1 << 20, 1 << 31][case % 6];
            let mut value = |m: i64| (rng.next_u64() % (2 * m as u64)) as i64 - m;
            let mut thresholds =
                |k: i64| -> Vec<i32> { (0..k.abs()).map(|_| value(spread).clamp(i32::MIN.into(), i32::MAX.into()) as i32).collect() };
            let (mut prev_at, mut lower_at) = (thresholds(case as i64 % 16), thresholds((case as i64 / 16) % 16));
            // Narrow spans at i32's ends.
            if case % 50 == 7 {
                (prev_at, lower_at) = (vec![i32::MIN + 2, i32::MIN, i32::MIN + 1], vec![i32::MAX - 3, i32::MAX]);
            }
            let count = (prev_at.len() + 1) * (lower_at.len() + 1);
            let mut rng2 = crate::rng::Rng::new(case as u64);
            let contexts = (0..count)
                .map(|_| {
                    let r = rng2.next_u64();
                    NeighbourContext { mix: (r % 5) as u8, centre: ((r >> 8) % 2001) as i32 - 1000, ratio: ((r >> 20) % 64) as u8 }
                })
                .collect();
            let t = Neighbour::new(1 + (case as u32 % 40), 0, prev_at.clone(), lower_at.clone(), contexts);
            let d = NeighbourDecoder::new(&t);
            let probes: Vec<i32> =
                prev_at
                    .iter()
                    .chain(&lower_at)
                    .flat_map(|&x| [x.saturating_sub(1), x, x.saturating_add(1)])
                    .chain([i32::MIN, i32::MIN + 1, -1, 0, 1, i32::MAX - 1, i32::MAX])
                    .chain((0..20).map(|_| {
                        ((rng2.next_u64() % (4 * spread) as u64) as i64 - 2 * spread).clamp(i32::MIN.into(), i32::MAX.into()) as i32
                    }))
                    .collect();
            for &prev in &probes {
                for &lower in probes.iter().step_by(3) {
                    let c = t.context(prev, lower);
                    let (lookup, mu) = d.context(prev, lower);
                    assert_eq!(mu, t.predict(c, prev), "case {case}: prev {prev}, lower {lower}");
                    assert!(std::ptr::eq(lookup.cdf, t.table(c).lookup_table().cdf), "case {case}: prev {prev}, lower {lower}");
                }
            }
        }
    }
}

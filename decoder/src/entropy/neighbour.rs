//! Neighbour-context tables (table mode 3, SPEC §4.3, format 8.0).
//!
//! A value is predicted from the channel's previous value in the chunk (the previous Gaussian in
//! Morton order, a spatial neighbour) and coded as its difference from the prediction under a
//! two-sided geometric window. The context — which prediction and which window — is chosen by
//! where the previous value and the value of the channel below (channel `j − 1` of the same
//! Gaussian) fall among stored thresholds. A context costs three small numbers instead of a
//! weight list, so a channel can afford many of them; every table is derived from integers.

use super::FreqTable;

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
    let bp = prev_at.iter().filter(|&&t| prev >= t).count();
    let bl = lower_at.iter().filter(|&&t| lower >= t).count();
    bp * (lower_at.len() + 1) + bl
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

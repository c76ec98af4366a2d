//! Choosing a channel's integer table: range, escape and weight precision that minimise
//! table bytes plus coded bits (the static-histogram model), and its exact cost.

use std::collections::HashMap;
use std::ops::Range;
use std::sync::{Arc, Mutex};

use gscodec_decoder::bitstream::ByteWriter;
use gscodec_decoder::entropy::neighbour::{self, Neighbour, NeighbourContext, MAX_MIX, MAX_REACH, RATIOS};
use gscodec_decoder::entropy::{in_context, symbol_of, ChannelTable, FreqTable, SymbolEncoder, CONTEXTS, MAX_SYMBOLS};

/// A channel's table as it will be written, with its cost on the values it codes.
#[derive(Debug, Clone)]
pub struct ChosenTable {
    pub table: ChannelTable,
    /// Serialised table bytes (what [`ChannelTable::read`] parses).
    pub bytes: Vec<u8>,
    /// Ideal code length of the channel's values under `table`, in bits.
    pub bits: f64,
}

/// Builds the table for `values` from weights proportional to `weights_of(range)`; `counts`
/// are the observed counts used to measure the cost. Candidates: several ranges (full, or
/// trimmed with escapes for the rare tails) × weight scales; the cheapest wins.
pub fn choose(values: &[i32]) -> ChosenTable {
    choose_with(values, None)
}

/// As [`choose`], but the distribution shape comes from `model_weights(lo, n)` (a learned
/// density rendered as non-negative weights over `lo..lo+n` and the escape) when given.
pub fn choose_with(values: &[i32], model: Option<&dyn Fn(i32, usize) -> Vec<f64>>) -> ChosenTable {
    let (Some(&min), Some(&max)) = (values.iter().min(), values.iter().max()) else {
        return constant(0);
    };
    if min == max {
        return constant(min);
    }
    let mut sorted = values.to_vec();
    sorted.sort_unstable();
    let quantile = |f: f64| sorted[((sorted.len() - 1) as f64 * f).round() as usize];
    let mut best: Option<ChosenTable> = None;
    for trim in [0.0, 1e-4, 1e-3, 1e-2] {
        let (lo, hi) = (quantile(trim), quantile(1.0 - trim));
        let n = (i64::from(hi) - i64::from(lo) + 1) as usize;
        if n > MAX_SYMBOLS || (lo == hi && trim > 0.0) {
            continue;
        }
        let mut counts = vec![0u64; n + 1];
        for &v in values {
            counts[symbol_of(lo, n, v)] += 1;
        }
        let shape: Vec<f64> = match model {
            Some(m) => m(lo, n),
            None => counts.iter().map(|&c| c as f64).collect(),
        };
        let (weights, table, bits) = best_weights(&shape, &counts);
        let mut w = ByteWriter::new();
        ChannelTable::write_coded(&mut w, lo, &weights);
        let cand = ChosenTable { table: ChannelTable::Coded { lo, table }, bytes: w.buf, bits };
        if best.as_ref().is_none_or(|b| cand.total_bits() < b.total_bits()) {
            best = Some(cand);
        }
    }
    best.unwrap_or_else(|| wide(values))
}

/// Weights proportional to `shape` at the precision (peak weight 15 … 10⁶) that minimises
/// weight bytes + coded bits of `counts` (the last symbol is the escape, +32 raw bits); with
/// the table and the coded bits.
fn best_weights(shape: &[f64], counts: &[u64]) -> (Vec<u32>, FreqTable, f64) {
    let n = counts.len() - 1;
    let peak = shape.iter().cloned().fold(0.0, f64::max).max(1e-300);
    let mut best: Option<(f64, Vec<u32>, FreqTable, f64)> = None;
    for scale in [15.0, 127.0, 1023.0, 16383.0, 1e6] {
        let weights: Vec<u32> = shape.iter().map(|&c| (c / peak * scale).round() as u32).collect();
        let table = FreqTable::from_weights(&weights);
        let bits: f64 = counts
            .iter()
            .enumerate()
            .filter(|(_, &c)| c > 0)
            .map(|(s, &c)| c as f64 * (table.bits(s) + if s == n { 32.0 } else { 0.0 }))
            .sum();
        let mut w = ByteWriter::new();
        weights.iter().for_each(|&x| w.varint(x));
        let total = bits + 8.0 * w.buf.len() as f64;
        if best.as_ref().is_none_or(|b| total < b.0) {
            best = Some((total, weights, table, bits));
        }
    }
    let (_, weights, table, bits) = best.expect("at least one precision");
    (weights, table, bits)
}

/// The context-coded version of a coded channel `base` (same range and escape): one histogram
/// per context, contexts as the decoder sees them: per chunk (`chunks`, one stream each),
/// [`in_context`] with the channel's median as the centre.
pub fn with_contexts(values: &[i32], base: &ChosenTable, chunks: &[Range<usize>]) -> Option<ChosenTable> {
    let ChannelTable::Coded { lo, table } = &base.table else { return None };
    let (lo, n) = (*lo, table.len() - 1);
    let mut scratch = values.to_vec();
    let half = scratch.len() / 2;
    let centre = *scratch.select_nth_unstable(half).1; // the median
    let mut counts = [(); CONTEXTS].map(|_| vec![0u64; n + 1]);
    for chunk in chunks {
        for (ctx, v) in in_context(&values[chunk.clone()], centre) {
            counts[ctx][symbol_of(lo, n, v)] += 1;
        }
    }
    let mut bits = 0.0;
    let chosen = counts.map(|c| {
        let shape: Vec<f64> = c.iter().map(|&x| x as f64).collect();
        let (weights, table, b) = best_weights(&shape, &c);
        bits += b;
        (weights, table)
    });
    let [(w0, t0), (w1, t1), (w2, t2), (w3, t3)] = chosen;
    let mut w = ByteWriter::new();
    ChannelTable::write_context(&mut w, lo, centre, &[w0, w1, w2, w3]);
    Some(ChosenTable { table: ChannelTable::Context { lo, centre, tables: Box::new([t0, t1, t2, t3]) }, bytes: w.buf, bits })
}

/// Bits of a difference of magnitude `d` under each window of reach `e` (SPEC §4.3):
/// `bits[d][ρ]` for `d = 0..=e`, and at `d = e + 1` an escape (its symbol and 32 raw bits).
/// The tables depend on `e` alone, so they are kept for the `e` met (up to 32 MB of them; then
/// the memo starts afresh).
fn window_bits(e: u32) -> Arc<Vec<WindowRow>> {
    static MEMO: Mutex<Option<HashMap<u32, Arc<Vec<WindowRow>>>>> = Mutex::new(None);
    const MEMO_BYTES: usize = 32 << 20;
    let size = |e: u32| (e as usize + 2) * std::mem::size_of::<WindowRow>();
    if let Some(b) = MEMO.lock().expect("memo").get_or_insert_with(HashMap::new).get(&e) {
        return b.clone();
    }
    let eu = e as usize;
    let windows: Vec<FreqTable> = (0..RATIOS.len() as u8).map(|r| neighbour::window(r, e)).collect();
    let bits: Vec<WindowRow> = (0..=eu + 1)
        .map(|d| std::array::from_fn(|r| if d > eu { windows[r].bits(2 * eu + 1) + 32.0 } else { windows[r].bits(eu + d) }))
        .collect();
    let bits = Arc::new(bits);
    let mut memo = MEMO.lock().expect("memo");
    let memo = memo.get_or_insert_with(HashMap::new);
    if memo.keys().map(|&k| size(k)).sum::<usize>() + size(e) > MEMO_BYTES {
        memo.clear();
    }
    memo.insert(e, bits.clone());
    bits
}

/// The bits of one difference under every window ratio ([`window_bits`]).
type WindowRow = [f64; RATIOS.len()];

/// Up to `buckets − 1` thresholds splitting the sorted `values` into about equal parts (each
/// above the smallest value, none repeated).
fn quantile_thresholds(sorted: &[i32], buckets: usize) -> Vec<i32> {
    let mut t: Vec<i32> = (1..buckets).map(|k| sorted[k * sorted.len() / buckets]).filter(|&x| x > sorted[0]).collect();
    t.dedup();
    t
}

/// A context's distinct `(prev, value)` pairs in the order they first occur, each with the
/// number of times it occurs. (Quantised values repeat: a context's pairs are about a tenth as
/// many distinct as in all, and the fit below visits each distinct one once per mix.)
type Pairs = Vec<(i32, i32, u32)>;

/// One context's best prediction and window for its `(prev, value)` pairs: the centre is the
/// values' median; every mix and (coarse to fine) every ratio is tried. With its bits.
fn fit_context(pairs: &[(i32, i32, u32)], reach: u32, bits: &[WindowRow]) -> (NeighbourContext, f64) {
    // The median: the value at position ⌊n/2⌋ of all n values in order.
    let mut vs: Vec<(i32, u32)> = pairs.iter().map(|p| (p.1, p.2)).collect();
    vs.sort_unstable();
    let half = vs.iter().map(|v| u64::from(v.1)).sum::<u64>() / 2;
    let mut below = 0;
    let centre = vs.iter().find(|v| {
        below += u64::from(v.1);
        below > half
    });
    let centre = centre.expect("a context has pairs").0;
    let mut best = (NeighbourContext { mix: 0, centre, ratio: 0 }, f64::INFINITY);
    // How often each |difference| occurs (the escape at reach + 1), and which ones do, in the
    // order they first occur (the order the costs below are summed in).
    let mut counts = vec![0u32; reach as usize + 2];
    let mut seen: Vec<usize> = Vec::new();
    for mix in 0..=MAX_MIX {
        let k = NeighbourContext { mix, centre, ratio: 0 };
        for &(prev, v, times) in pairs {
            let d = (i64::from(v) - k.predict(prev)).unsigned_abs().min(u64::from(reach) + 1) as usize;
            if counts[d] == 0 {
                seen.push(d);
            }
            counts[d] += times;
        }
        let runs: Vec<(usize, f64)> = seen.drain(..).map(|d| (d, f64::from(std::mem::take(&mut counts[d])))).collect();
        // Every fourth ratio, then the ratios around the cheapest of them; of equal costs the
        // first ratio.
        let (coarse, _) = cheapest(&runs, bits, 0, 4, RATIOS.len() / 4);
        let first = coarse.saturating_sub(3);
        let (fine, c) = cheapest(&runs, bits, first, 1, (coarse + 4).min(RATIOS.len()) - first);
        if c < best.1 {
            best = (NeighbourContext { mix, centre, ratio: fine as u8 }, c);
        }
    }
    best
}

/// Of the `n` (at most 16) ratios `first + k·stride`, the one whose window codes `runs` (each
/// difference with how often it occurs) in the fewest bits, with those bits; of equal costs the
/// first. Each ratio's bits are summed in the order of `runs`, all ratios in one pass.
fn cheapest(runs: &[(usize, f64)], bits: &[WindowRow], first: usize, stride: usize, n: usize) -> (usize, f64) {
    let mut cost = [0.0f64; 16];
    for &(d, times) in runs {
        let row = &bits[d];
        cost[..n].iter_mut().enumerate().for_each(|(k, c)| *c += times * row[first + k * stride]);
    }
    let k = (1..n).fold(0, |best, k| if cost[k].total_cmp(&cost[best]).is_lt() { k } else { best });
    (first + k * stride, cost[k])
}

/// A channel's distinct (previous value, value, octile of the value below) in the order they
/// first occur, with their counts: what every threshold shape of [`with_neighbours`] splits
/// into its contexts' [`Pairs`], as its thresholds on the value below are among the octiles.
struct DistinctPairs {
    list: Vec<(i32, i32, usize, u32)>,
    /// Octile thresholds of the values below (none for channel 0).
    octiles: Vec<i32>,
}

impl DistinctPairs {
    /// `lower_sorted` is `lower` sorted; each chunk's first value follows `start`.
    fn new(values: &[i32], lower: &[i32], lower_sorted: &[i32], chunks: &[Range<usize>], start: i32) -> DistinctPairs {
        let octiles = if lower.is_empty() { vec![] } else { quantile_thresholds(lower_sorted, 8) };
        let mut list: Vec<(i32, i32, usize, u32)> = Vec::new();
        // Where each distinct triple is in `list` (u32::MAX: not yet): a table over every
        // (previous value, value, octile) of the values' span where that is not much larger
        // than the values, else a hash map.
        let (lo, hi) = values.iter().fold((start, start), |(a, b), &v| (a.min(v), b.max(v)));
        let span = (i64::from(hi) - i64::from(lo) + 1) as usize;
        let buckets = octiles.len() + 1;
        let dense = span.checked_mul(span).and_then(|x| x.checked_mul(buckets)).filter(|&size| size <= 4 * values.len() + 4096);
        let mut table = vec![u32::MAX; dense.unwrap_or(0)];
        let mut map: HashMap<(i32, i32, usize), u32, foldhash::fast::FixedState> = HashMap::default();
        for chunk in chunks {
            let mut prev = start;
            for i in chunk.clone() {
                let (v, octile) = (values[i], if lower.is_empty() { 0 } else { octiles.iter().filter(|&&t| lower[i] >= t).count() });
                let at = match dense {
                    Some(_) => &mut table[((prev.abs_diff(lo) as usize) * span + v.abs_diff(lo) as usize) * buckets + octile],
                    None => map.entry((prev, v, octile)).or_insert(u32::MAX),
                };
                if *at == u32::MAX {
                    *at = list.len() as u32;
                    list.push((prev, v, octile, 0));
                }
                list[*at as usize].3 += 1;
                prev = v;
            }
        }
        DistinctPairs { list, octiles }
    }

    /// Each context's pairs under thresholds `prev_at` and `lower_at` (a subset of the
    /// octiles). A value below stands for its octile by the octile's lower end: a threshold of
    /// `lower_at` is at or below the one iff it is at or below the other.
    fn split(&self, prev_at: &[i32], lower_at: &[i32]) -> Vec<Pairs> {
        debug_assert!(lower_at.iter().all(|t| self.octiles.contains(t)), "thresholds below among the octiles");
        let mut pairs: Vec<Pairs> = vec![Vec::new(); (prev_at.len() + 1) * (lower_at.len() + 1)];
        for &(prev, v, octile, times) in &self.list {
            let lower = if octile == 0 { i32::MIN } else { self.octiles[octile - 1] };
            pairs[neighbour::context(prev_at, lower_at, prev, lower)].push((prev, v, times));
        }
        pairs
    }
}

/// The neighbour-context table (mode 3, SPEC §4.3) of a channel: `lower` holds the values of
/// the channel below (empty for channel 0), `chunks` the streams (each restarts the previous
/// value). Thresholds split the previous values (and the values below) into up to 8 equal
/// parts; fewer parts are tried too, and the cheapest table (bytes + bits) is kept. `None` for
/// a constant channel.
pub fn with_neighbours(values: &[i32], lower: &[i32], chunks: &[Range<usize>]) -> Option<ChosenTable> {
    let (Some(&min), Some(&max)) = (values.iter().min(), values.iter().max()) else { return None };
    if min == max {
        return None;
    }
    let mut sorted = values.to_vec();
    sorted.sort_unstable();
    let start = sorted[sorted.len() / 2];
    let mut lower_sorted = lower.to_vec();
    lower_sorted.sort_unstable();
    let distinct = DistinctPairs::new(values, lower, &lower_sorted, chunks, start);
    // The table of reach `reach` for these contexts: (bytes, contexts, bits).
    let fit = |prev_at: &[i32], lower_at: &[i32], pairs: &[Pairs], reach: u32| {
        let bits = window_bits(reach);
        let mut total = 0.0;
        let contexts: Vec<NeighbourContext> = pairs
            .iter()
            .map(|p| {
                if p.is_empty() {
                    return NeighbourContext { mix: 0, centre: start, ratio: 0 };
                }
                let (k, b) = fit_context(p, reach, &bits);
                total += b;
                k
            })
            .collect();
        let mut w = ByteWriter::new();
        ChannelTable::write_neighbour(&mut w, reach, start, prev_at, lower_at, &contexts);
        (w.buf, contexts, total)
    };
    let cost = |c: &(Vec<u8>, Vec<NeighbourContext>, f64)| c.2 + 8.0 * c.0.len() as f64;
    // First with a reach that no difference exceeds, over every threshold shape; the cheapest
    // shape is then fitted again with the reach its differences need (a smaller table to build
    // in the decoder, fewer symbols to share the probability) and kept if cheaper still.
    let reach = (i64::from(max) - i64::from(min)).min(i64::from(MAX_REACH)) as u32;
    let mut best: Option<(Vec<i32>, Vec<i32>, Vec<Pairs>, (Vec<u8>, Vec<NeighbourContext>, f64))> = None;
    for (pb, lb) in [(8, 8), (8, 1), (4, 4), (4, 1), (2, 1)] {
        if lb > 1 && lower.is_empty() {
            continue;
        }
        let prev_at = quantile_thresholds(&sorted, pb);
        let lower_at = if lb > 1 { quantile_thresholds(&lower_sorted, lb) } else { vec![] };
        let pairs = distinct.split(&prev_at, &lower_at);
        let cand = fit(&prev_at, &lower_at, &pairs, reach);
        if best.as_ref().is_none_or(|b| cost(&cand) < cost(&b.3)) {
            best = Some((prev_at, lower_at, pairs, cand));
        }
    }
    let (prev_at, lower_at, pairs, mut chosen) = best?;
    let mut chosen_reach = reach;
    let needed = pairs
        .iter()
        .zip(&chosen.1)
        .flat_map(|(p, k)| p.iter().map(move |&(prev, v, _)| (i64::from(v) - k.predict(prev)).unsigned_abs()))
        .max()
        .unwrap_or(1)
        .clamp(1, u64::from(reach)) as u32;
    if needed < reach {
        let again = fit(&prev_at, &lower_at, &pairs, needed);
        if cost(&again) < cost(&chosen) {
            (chosen, chosen_reach) = (again, needed);
        }
    }
    let (bytes, contexts, bits) = chosen;
    let table = ChannelTable::Neighbour(Box::new(Neighbour::new(chosen_reach, start, prev_at, lower_at, contexts)));
    Some(ChosenTable { table, bytes, bits })
}

/// The models for one channel: the static histogram, the learned (trained Laplace) density and
/// the context-coded histograms, each with its table; the cheapest (table bytes + coded bits)
/// is the one to store.
pub struct Compared {
    pub best: ChosenTable,
    /// Total bits (table + stream) under the static histogram.
    pub histogram_bits: f64,
    /// Total bits (table + stream) under the learned density (NaN when not tried).
    pub learned_bits: f64,
    /// Total bits (table + stream) with one histogram per context (NaN when not tried).
    pub context_bits: f64,
    /// Total bits (table + stream) with neighbour contexts (NaN when not tried).
    pub neighbour_bits: f64,
}

/// The static histogram, and its context-coded versions when `contexts` gives the chunks (the
/// learned cost is NaN): one histogram per context (mode 2), and with `neighbours` (the values
/// of the channel below, empty for a first channel) neighbour contexts (mode 3, format 8.0).
pub fn histogram_only(values: &[i32], contexts: Option<&[Range<usize>]>, neighbours: Option<&[i32]>) -> Compared {
    let hist = choose(values);
    let h = hist.total_bits();
    let ctx = contexts.and_then(|chunks| with_contexts(values, &hist, chunks));
    let c = ctx.as_ref().map_or(f64::NAN, ChosenTable::total_bits);
    let nb = contexts.zip(neighbours).and_then(|(chunks, lower)| with_neighbours(values, lower, chunks));
    let nbits = nb.as_ref().map_or(f64::NAN, ChosenTable::total_bits);
    let mut best = match ctx {
        Some(ctx) if c < h => ctx,
        _ => hist,
    };
    if let Some(nb) = nb.filter(|_| nbits < best.total_bits()) {
        best = nb;
    }
    Compared { best, histogram_bits: h, learned_bits: f64::NAN, context_bits: c, neighbour_bits: nbits }
}

/// Builds all the tables for `values` (contexts only when `contexts` gives the chunks, each one
/// stream; neighbour contexts as [`histogram_only`]) and keeps the cheapest.
pub fn compare(values: &[i32], contexts: Option<&[Range<usize>]>, neighbours: Option<&[i32]>) -> Compared {
    let mut out = histogram_only(values, contexts, neighbours);
    if matches!(out.best.table, ChannelTable::Constant(_)) {
        out.learned_bits = out.histogram_bits;
        return out;
    }
    let as_f32: Vec<f32> = values.iter().map(|&v| v as f32).collect();
    let mut model = crate::rate::model::LearnedChannel::fit_init(&as_f32);
    model.train(&as_f32, 1.0, 60);
    let shape = move |lo: i32, n: usize| model.weights(lo, n, 1.0);
    let learned = choose_with(values, Some(&shape));
    out.learned_bits = learned.total_bits();
    if out.learned_bits < out.best.total_bits() {
        out.best = learned;
    }
    out
}

impl ChosenTable {
    /// Table bytes plus coded bits.
    pub fn total_bits(&self) -> f64 {
        self.bits + 8.0 * self.bytes.len() as f64
    }
}

fn constant(v: i32) -> ChosenTable {
    let mut w = ByteWriter::new();
    ChannelTable::write_constant(&mut w, v);
    ChosenTable { table: ChannelTable::Constant(v), bytes: w.buf, bits: 0.0 }
}

/// Fallback for a range wider than any table: the central 4096 values, the rest escaped.
fn wide(values: &[i32]) -> ChosenTable {
    let mut sorted = values.to_vec();
    sorted.sort_unstable();
    let mid = sorted[sorted.len() / 2];
    let lo = mid.saturating_sub(MAX_SYMBOLS as i32 / 2);
    let n = MAX_SYMBOLS;
    let mut weights = vec![0u32; n + 1];
    for &v in values {
        let s = symbol_of(lo, n, v);
        weights[s] = weights[s].saturating_add(1);
    }
    let mut w = ByteWriter::new();
    ChannelTable::write_coded(&mut w, lo, &weights);
    let table = ChannelTable::Coded { lo, table: FreqTable::from_weights(&weights) };
    let bits = values.iter().map(|&v| SymbolEncoder::value_bits(&table, 0, v)).sum();
    ChosenTable { table, bytes: w.buf, bits }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn constant_and_coded_costs_are_exact() {
        assert!(matches!(choose(&[4, 4, 4]).table, ChannelTable::Constant(4)));
        let values: Vec<i32> = (0..1000).map(|i| if i % 4 == 0 { 1 } else { 0 }).collect();
        let t = choose(&values);
        let exact: f64 = values.iter().map(|&v| SymbolEncoder::value_bits(&t.table, 0, v)).sum();
        assert!((t.bits - exact).abs() < 1e-6);
        // Entropy of (1/4, 3/4) is 0.811 bits per value.
        assert!((t.bits / 1000.0 - 0.811).abs() < 0.01, "{}", t.bits / 1000.0);
    }

    /// A channel that follows its neighbours and the channel below, in two streams, with one
    /// value too far for any window: the neighbour table's cost is exactly what the coder spends
    /// (escape included), it is far below the static histogram's, and its bytes read back to it.
    #[test]
    fn neighbour_tables_cost_exactly_what_they_code() {
        let n = 5000;
        let lower: Vec<i32> = (0..n).map(|i| ((i as f32 * 0.01).sin() * 40.0) as i32).collect();
        let values: Vec<i32> = (0..n).map(|i| lower[i] / 2 + ((i * 7919) % 5) as i32 - 2 + if i == 1234 { 100_000 } else { 0 }).collect();
        let chunks = [0..3000, 3000..n];
        let t = with_neighbours(&values, &lower, &chunks).expect("not constant");
        let ChannelTable::Neighbour(nb) = &t.table else { panic!("{:?}", t.table) };
        assert_eq!(nb.reach, 2047, "the outlier's range is beyond any window");
        let mut exact = 0.0;
        for c in &chunks {
            let mut prev = nb.start;
            for i in c.clone() {
                exact += SymbolEncoder::neighbour_bits(nb, prev, lower[i], values[i]);
                prev = values[i];
            }
        }
        assert!((t.bits - exact).abs() <= 1e-9 * exact, "{} against {exact}", t.bits);
        let hist = choose(&values).total_bits();
        assert!(t.total_bits() < 0.6 * hist, "{} against {hist}", t.total_bits());
        let read = ChannelTable::read(&mut gscodec_decoder::bitstream::ByteReader::new(&t.bytes)).unwrap();
        assert_eq!(read, t.table);
        // Constants have no neighbour table; without a channel below the table has no thresholds on one.
        assert!(with_neighbours(&[3; 10], &[], &[0..10]).is_none());
        let ChannelTable::Neighbour(alone) = with_neighbours(&values, &[], &chunks).unwrap().table else { panic!() };
        assert!(alone.lower_at.is_empty());
    }

    /// Every threshold shape's contexts get the pairs they get one value at a time — each
    /// `(prev, value)` as often, in the order it first occurs — and [`fit_context`] fits the
    /// same prediction, window and bits (bit for bit) to them as to the pairs one by one.
    #[test]
    fn distinct_pairs_fit_what_the_pairs_one_by_one_fit() {
        let mut rng = crate::rng::Rng::new(17);
        for case in 0..24 {
            let n = 300 + 97 * case;
            let spread = [3, 9, 40, 400][case % 4];
            let mut draw = |m: i32| (rng.next_u64() % (2 * m as u64 + 1)) as i32 - m;
            let lower: Vec<i32> = (0..n).map(|i| ((i as f32 * 0.05).sin() * spread as f32) as i32 + draw(2)).collect();
            let values: Vec<i32> = (0..n).map(|i| if case % 3 == 0 { draw(spread) } else { lower[i] / 2 + draw(spread / 3 + 1) }).collect();
            let chunks = [0..n / 3, n / 3..n];
            let lower = if case % 5 == 4 { vec![] } else { lower };
            let (mut sorted, mut lower_sorted) = (values.clone(), lower.clone());
            sorted.sort_unstable();
            lower_sorted.sort_unstable();
            let start = sorted[n / 2];
            let distinct = DistinctPairs::new(&values, &lower, &lower_sorted, &chunks, start);
            for (pb, lb) in [(8, 8), (8, 1), (4, 4), (4, 1), (2, 1), (8, 2)] {
                let prev_at = quantile_thresholds(&sorted, pb);
                let lower_at = if lb > 1 && !lower.is_empty() { quantile_thresholds(&lower_sorted, lb) } else { vec![] };
                let mut plain: Vec<Pairs> = vec![Vec::new(); (prev_at.len() + 1) * (lower_at.len() + 1)];
                for c in &chunks {
                    let mut prev = start;
                    for i in c.clone() {
                        let below = if lower.is_empty() { 0 } else { lower[i] };
                        plain[neighbour::context(&prev_at, &lower_at, prev, below)].push((prev, values[i], 1));
                        prev = values[i];
                    }
                }
                let split = distinct.split(&prev_at, &lower_at);
                assert_eq!(split.len(), plain.len());
                for (d, p) in split.iter().zip(&plain) {
                    // The same pairs as often, first occurrences in the same order.
                    let mut firsts: Vec<(i32, i32)> = p.iter().map(|x| (x.0, x.1)).collect();
                    let mut seen = std::collections::HashSet::new();
                    firsts.retain(|x| seen.insert(*x));
                    let mut merged: Vec<(i32, i32)> = Vec::new();
                    for x in d {
                        if !merged.contains(&(x.0, x.1)) {
                            merged.push((x.0, x.1));
                        }
                    }
                    assert_eq!(merged, firsts, "case {case}, shape ({pb}, {lb})");
                    for &(a, b) in &firsts {
                        let times = |l: &Pairs| l.iter().filter(|x| (x.0, x.1) == (a, b)).map(|x| x.2).sum::<u32>();
                        assert_eq!(times(d), times(p));
                    }
                    if p.is_empty() {
                        continue;
                    }
                    for reach in [1, 6, 2047] {
                        let bits = window_bits(reach);
                        let (kd, bd) = fit_context(d, reach, &bits);
                        let (kp, bp) = fit_context(p, reach, &bits);
                        assert_eq!((kd, bd.to_bits()), (kp, bp.to_bits()), "case {case}, shape ({pb}, {lb}), reach {reach}");
                    }
                }
            }
        }
    }

    #[test]
    fn outliers_are_escaped_not_tabled() {
        let mut values: Vec<i32> = (0..10000).map(|i| i % 3).collect();
        values.push(1_000_000_000);
        let t = choose(&values);
        assert!(t.bytes.len() < 16, "table of {} bytes", t.bytes.len());
    }
}

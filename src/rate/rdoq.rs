//! Rate-aware rounding (encoder only): a value may take the integer on the other side of its
//! target instead of the nearest one when the bits its channel's table saves pay for the extra
//! squared error. The decoder is unchanged: these are the encoder's choice of values.
//!
//! For a value whose target is `t` steps, the candidates are `⌊t⌉` and the integer on the other
//! side of `t`; each costs `(t − v)² + μ·bits(v)` (squared error in steps², bits under the table
//! the channel would be coded with, in the context of the values chosen before it). With the
//! step chosen by an RD search at its high-rate optimum, a bit is worth `ln 2 / 6` steps² of
//! squared error (`D(Δ) ∝ Δ²/12`, `R(Δ) = h − log₂ Δ` per value: `dD/dR = Δ² ln 2 / 6`).

use std::hash::Hash;
use std::ops::Range;
use std::sync::Arc;

use gscodec_decoder::bitstream::layout::Group;
use gscodec_decoder::entropy::{context, ChannelTable, SymbolEncoder};
use rayon::prelude::*;

use super::encode::{key128, neighbours_allowed, parameter_parts, GroupCache};
use super::quantise::Quantised;
use super::tables;

/// `μ` at the high-rate optimum: `ln 2 / 6` steps² a bit.
pub const HIGH_RATE_MU: f64 = std::f64::consts::LN_2 / 6.0;

/// The bits value `v` costs under `t` after `prev` (the channel's previous value in the chunk)
/// with `lower` (the value of the channel below), escapes included.
fn value_bits(t: &ChannelTable, prev: i32, lower: i32, v: i32) -> f64 {
    match t {
        ChannelTable::Neighbour(nb) => SymbolEncoder::neighbour_bits(nb, prev, lower, v),
        _ => SymbolEncoder::value_bits(t, context(prev, start(t)), v),
    }
}

/// The previous value of a chunk's first value under `t`.
fn start(t: &ChannelTable) -> i32 {
    match t {
        ChannelTable::Constant(c) => *c,
        ChannelTable::Neighbour(nb) => nb.start,
        _ => t.contexts().expect("a coded table").1,
    }
}

/// Re-rounds `values` (a channel, each value one of the two integers around its target in
/// `targets`, in steps) under `table`: each value, in stream order (`chunks` restart the
/// previous value), takes whichever of those two integers costs less `(t − v)² + mu·bits`.
/// `lower` holds the channel below's values (empty for a first channel).
pub fn round_channel(targets: &[f32], values: &mut [i32], lower: &[i32], chunks: &[Range<usize>], table: &ChannelTable, mu: f64) {
    if matches!(table, ChannelTable::Constant(_)) {
        return;
    }
    for r in chunks {
        let mut prev = start(table);
        for i in r.clone() {
            let t = f64::from(targets[i]);
            let v0 = values[i];
            let other = if t > f64::from(v0) { v0.saturating_add(1) } else { v0.saturating_sub(1) };
            let low = if lower.is_empty() { 0 } else { lower[i] };
            let cost = |v: i32| (t - f64::from(v)).powi(2) + mu * value_bits(table, prev, low, v);
            if cost(other) < cost(v0) {
                values[i] = other;
            }
            prev = values[i];
        }
    }
}

/// Re-rounds the coded channels of `q`'s groups that `targets` lists ([`round_channel`], `μ` =
/// [`HIGH_RATE_MU`]), each part of the file with parameter sections of its own (a level of a
/// file with importance classes or a shared SH index, else the whole scene) under the table
/// fitted to its values rounded to nearest: the static histogram, context or (with
/// `neighbours`, where the file may store them) neighbour-context table the file would store.
/// The learned density is not fitted: the RD search's trials do not fit it either, so a trial
/// and the final encode round alike. `targets` gives each group's channels before rounding, in
/// steps, file order. SH bands coded by codebooks, the rotation's index and constant channels
/// are left as they are. `cache` holds the groups earlier calls rounded from the same targets.
pub fn round_groups(q: &mut Quantised, targets: &[(Group, Vec<Vec<f32>>)], neighbours: bool, cache: Option<&GroupCache>) {
    let parts = parameter_parts(q, &q.layout());
    let neighbours = neighbours && neighbours_allowed(q);
    let vq: Vec<Group> = q.codebooks.iter().map(|c| c.0).collect();
    let mut todo: Vec<(Group, &Vec<Vec<f32>>, &mut Vec<Vec<i32>>)> = q
        .groups
        .iter_mut()
        .filter(|g| !vq.contains(&g.0))
        .filter_map(|g| targets.iter().find(|t| t.0 == g.0).map(|t| (g.0, &t.1, &mut g.2)))
        .collect();
    todo.par_iter_mut().for_each(|(g, t, chans)| {
        let key = key128(|h| {
            (g.name(), &**chans, neighbours, HIGH_RATE_MU.to_bits()).hash(h);
            parts.iter().for_each(|(r, local)| (r.start, r.end, local.iter().map(|c| (c.start, c.end)).collect::<Vec<_>>()).hash(h));
            t.iter().for_each(|c| c.iter().for_each(|x| x.to_bits().hash(h)));
        });
        if let Some(done) = cache.and_then(|c| c.rounded.lock().expect("not poisoned").get(&key).cloned()) {
            **chans = (*done).clone();
            return;
        }
        // The rotation's channel 0 is the index of the omitted component, not a value.
        let first = usize::from(*g == Group::Rotation);
        for j in first..chans.len() {
            let (below, rest) = chans.split_at_mut(j);
            for (r, local) in &parts {
                let lower: &[i32] = if j > 0 { &below[j - 1][r.clone()] } else { &[] };
                let values = &mut rest[0][r.clone()];
                let table = tables::histogram_only(values, Some(local), Some(lower).filter(|_| neighbours)).best.table;
                round_channel(&t[j][r.clone()], values, lower, local, &table, HIGH_RATE_MU);
            }
        }
        if let Some(c) = cache {
            c.rounded.lock().expect("not poisoned").insert(key, Arc::new(chans.clone()));
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use gscodec_decoder::entropy::neighbour::{Neighbour, NeighbourContext};
    use gscodec_decoder::entropy::FreqTable;

    /// Total `(t − v)² + μ·bits` of a channel under a context-free table.
    fn cost(table: &ChannelTable, targets: &[f32], values: &[i32], mu: f64) -> (f64, f64) {
        let bits: f64 = values.iter().map(|&v| value_bits(table, 0, 0, v)).sum();
        let err: f64 = targets.iter().zip(values).map(|(&t, &v)| (f64::from(t) - f64::from(v)).powi(2)).sum();
        (err + mu * bits, bits)
    }

    /// Under a table without contexts every value's choice is independent, so the rounding is
    /// exact: it never costs more than rounding to nearest, moves a value only to the integer
    /// on the other side of its target, with μ = 0 is rounding to nearest, and spends fewer
    /// bits the more a bit is worth.
    #[test]
    fn rate_aware_rounding_minimises_error_plus_weighted_bits() {
        // Symbols −4..=4 (and the escape), most weight at 0.
        let weights = [1, 4, 30, 200, 1000, 200, 30, 4, 1, 0];
        let table = ChannelTable::Coded { lo: -4, table: FreqTable::from_weights(&weights) };
        let mut rng = crate::rng::Rng::new(11);
        let targets: Vec<f32> = (0..2000).map(|_| (rng.uniform() - 0.5) * 8.0).collect();
        let nearest: Vec<i32> = targets.iter().map(|t| t.round() as i32).collect();
        let chunks = [0..1000, 1000..2000];
        let mut last_bits = f64::INFINITY;
        for mu in [0.0, 0.05, 0.1155, 0.3, 1.0] {
            let mut v = nearest.clone();
            round_channel(&targets, &mut v, &[], &chunks, &table, mu);
            if mu == 0.0 {
                assert_eq!(v, nearest);
            }
            assert!(
                v.iter().zip(&targets).all(|(&v, &t)| (f64::from(v) - f64::from(t)).abs() < 1.0),
                "μ {mu}: moved past the next integer"
            );
            let ((j, bits), (j_near, _)) = (cost(&table, &targets, &v, mu), cost(&table, &targets, &nearest, mu));
            assert!(j <= j_near + 1e-9, "μ {mu}: {j} > {j_near}");
            assert!(bits <= last_bits, "μ {mu}: {bits} bits, more than at a smaller μ ({last_bits})");
            last_bits = bits;
        }
        assert!(last_bits < cost(&table, &targets, &nearest, 0.0).1 * 0.9, "a bit worth a step² saves bits");
    }

    /// With a neighbour-context table the choice follows the chain of previous values: targets
    /// just past halfway from the prediction (the previous value) stay at it when bits are
    /// dear, and round up to the next integer when they are free.
    #[test]
    fn a_neighbour_channel_rounds_toward_its_prediction() {
        // One context, predicting the previous value (mix 4), a sharp window (ratio 2).
        let nb = Neighbour::new(8, 0, vec![], vec![], vec![NeighbourContext { mix: 4, centre: 0, ratio: 2 }]);
        let table = ChannelTable::Neighbour(Box::new(nb));
        let targets = vec![0.55f32; 6];
        let nearest = vec![1; 6];
        let mut dear = nearest.clone();
        round_channel(&targets, &mut dear, &[], &[0..6], &table, 0.5);
        assert_eq!(dear, vec![0; 6]);
        let mut free = nearest.clone();
        round_channel(&targets, &mut free, &[], &[0..6], &table, 0.0);
        assert_eq!(free, nearest);
    }
}

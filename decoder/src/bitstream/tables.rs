//! Channel tables (SPEC §4.1): how one integer channel is stored — a constant, one coded table,
//! one table per context, or neighbour contexts (SPEC §4.3) — read and written here; the tables'
//! probabilities are [`FreqTable`]s (SPEC §4.2).

use super::{ByteReader, ByteWriter};
use crate::entropy::neighbour::{Neighbour, NeighbourContext, MAX_MIX, MAX_REACH, MAX_THRESHOLDS, RATIOS};
use crate::entropy::{FreqTable, CONTEXTS, MAX_SYMBOLS};
use crate::error::{self, DecodeError, Limit};

/// How one channel (one integer attribute component) is stored.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ChannelTable {
    /// Every Gaussian has this value; no symbols are coded.
    Constant(i32),
    /// Values `lo .. lo + n` map to symbols `0 .. n`; symbol `n` is the escape.
    Coded {
        /// Value of symbol 0.
        lo: i32,
        /// Frequencies of the `n + 1` symbols.
        table: FreqTable,
    },
    /// As `Coded`, with one table per context: the context of a value is
    /// [`context`](crate::entropy::context)`(previous value of the channel in the chunk, centre)`.
    Context {
        /// Value of symbol 0.
        lo: i32,
        /// The value contexts are measured from (and the previous value of the first).
        centre: i32,
        /// One table per context, all over the same symbols.
        tables: Box<[FreqTable; CONTEXTS]>,
    },
    /// Predicted from the previous value and the value below, contexts chosen by thresholds
    /// (mode 3, format 8.0, SPEC §4.3).
    Neighbour(Box<Neighbour>),
}

impl ChannelTable {
    /// `(lo, centre, table per context)` of a coded channel (a single table serves every context);
    /// `None` for a constant and for neighbour contexts.
    pub fn contexts(&self) -> Option<(i32, i32, [&FreqTable; CONTEXTS])> {
        match self {
            ChannelTable::Constant(_) | ChannelTable::Neighbour(_) => None,
            ChannelTable::Coded { lo, table } => Some((*lo, 0, [table; CONTEXTS])),
            ChannelTable::Context { lo, centre, tables } => Some((*lo, *centre, [&tables[0], &tables[1], &tables[2], &tables[3]])),
        }
    }

    /// Serialises a context-coded channel: `u8 2, svarint centre, svarint lo, varint n`, then
    /// for each context `(n+1) × varint weight`.
    pub fn write_context(w: &mut ByteWriter, lo: i32, centre: i32, weights: &[Vec<u32>; CONTEXTS]) {
        w.u8(2);
        w.svarint(centre);
        w.svarint(lo);
        w.varint((weights[0].len() - 1) as u32);
        for ws in weights {
            for &x in ws {
                w.varint(x);
            }
        }
    }

    /// Serialises: `u8 1, svarint lo, varint n, (n+1) × varint weight`. `weights` are the
    /// weights the table was built from (including the escape weight last).
    pub fn write_coded(w: &mut ByteWriter, lo: i32, weights: &[u32]) {
        w.u8(1);
        w.svarint(lo);
        w.varint((weights.len() - 1) as u32);
        for &x in weights {
            w.varint(x);
        }
    }

    /// Serialises a neighbour-context channel: `u8 3, varint E, svarint start, u8 P, P ×
    /// svarint threshold, u8 L, L × svarint threshold`, then per context `u8 mix, svarint
    /// centre, u8 ratio`.
    pub fn write_neighbour(w: &mut ByteWriter, reach: u32, start: i32, prev_at: &[i32], lower_at: &[i32], contexts: &[NeighbourContext]) {
        w.u8(3);
        w.varint(reach);
        w.svarint(start);
        for at in [prev_at, lower_at] {
            w.u8(at.len() as u8);
            at.iter().for_each(|&x| w.svarint(x));
        }
        for c in contexts {
            w.u8(c.mix);
            w.svarint(c.centre);
            w.u8(c.ratio);
        }
    }

    /// Serialises a constant channel: `u8 0, svarint value`.
    pub fn write_constant(w: &mut ByteWriter, value: i32) {
        w.u8(0);
        w.svarint(value);
    }

    /// Reads one channel table (any mode).
    pub fn read(r: &mut ByteReader<'_>) -> Result<ChannelTable, DecodeError> {
        let at = r.place();
        match r.u8("channel table")? {
            0 => Ok(ChannelTable::Constant(r.svarint("constant value")?)),
            1 => {
                let (lo, n) = read_range(r)?;
                Ok(ChannelTable::Coded { lo, table: read_weights(r, n)? })
            }
            2 => {
                let centre = r.svarint("context centre")?;
                let (lo, n) = read_range(r)?;
                let t = [read_weights(r, n)?, read_weights(r, n)?, read_weights(r, n)?, read_weights(r, n)?];
                Ok(ChannelTable::Context { lo, centre, tables: Box::new(t) })
            }
            3 => read_neighbour(r).map(|t| ChannelTable::Neighbour(Box::new(t))),
            _ => Err(at.corrupt("unknown channel table mode")),
        }
    }
}

/// `svarint lo, varint n` of a coded table, checked.
fn read_range(r: &mut ByteReader<'_>) -> Result<(i32, usize), DecodeError> {
    let lo = r.svarint("table range")?;
    let at = r.place();
    let n = r.varint("table size")? as usize;
    if n == 0 || n > MAX_SYMBOLS {
        // SPEC §4.1: n = 0 or n > 4096 is a limit error.
        return Err(error::limit(Limit::TableSymbols, n as u64, MAX_SYMBOLS as u64, false));
    }
    if lo.checked_add(n as i32).is_none() {
        return Err(at.corrupt("table range overflows"));
    }
    Ok((lo, n))
}

/// The fields of a mode-3 table after its mode byte (SPEC §4.3), checked.
fn read_neighbour(r: &mut ByteReader<'_>) -> Result<Neighbour, DecodeError> {
    let at = r.place();
    let reach = r.varint("window reach")?;
    if reach == 0 || reach > MAX_REACH {
        return Err(at.corrupt("window reach outside 1..=2047"));
    }
    let start = r.svarint("neighbour start")?;
    let mut thresholds = |what| -> Result<Vec<i32>, DecodeError> {
        let at = r.place();
        let k = usize::from(r.u8("threshold count")?);
        if k > MAX_THRESHOLDS {
            return Err(at.corrupt("more than 15 thresholds"));
        }
        (0..k).map(|_| r.svarint(what)).collect()
    };
    let prev_at = thresholds("previous-value threshold")?;
    let lower_at = thresholds("lower-value threshold")?;
    let count = (prev_at.len() + 1) * (lower_at.len() + 1);
    // Each context takes at least three bytes: check before allocating.
    if r.remaining() < 3 * count {
        return Err(r.place().truncated("neighbour contexts"));
    }
    let mut contexts = Vec::with_capacity(count);
    for _ in 0..count {
        let at = r.place();
        let mix = r.u8("context mix")?;
        let centre = r.svarint("context centre")?;
        let ratio = r.u8("context ratio")?;
        if mix > MAX_MIX || usize::from(ratio) >= RATIOS.len() {
            return Err(at.corrupt("context mix above 4 or ratio above 63"));
        }
        contexts.push(NeighbourContext { mix, centre, ratio });
    }
    Ok(Neighbour::new(reach, start, prev_at, lower_at, contexts))
}

/// `(n+1) × varint weight`, rebuilt into a table.
fn read_weights(r: &mut ByteReader<'_>, n: usize) -> Result<FreqTable, DecodeError> {
    // Each weight takes at least one byte: check before allocating.
    if r.remaining() < n + 1 {
        return Err(r.place().truncated("table weights"));
    }
    let mut weights = Vec::with_capacity(n + 1);
    for _ in 0..=n {
        weights.push(r.varint("table weight")?);
    }
    Ok(FreqTable::from_weights(&weights))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_mode_round_trips() {
        let mut w = ByteWriter::new();
        ChannelTable::write_constant(&mut w, -7);
        ChannelTable::write_coded(&mut w, -3, &[1, 5, 0, 2]);
        let weights = [vec![1, 2], vec![3, 4], vec![0, 0], vec![9, 1]];
        ChannelTable::write_context(&mut w, 10, 11, &weights);
        let mut r = ByteReader::new(&w.buf);
        assert_eq!(ChannelTable::read(&mut r).unwrap(), ChannelTable::Constant(-7));
        assert_eq!(ChannelTable::read(&mut r).unwrap(), ChannelTable::Coded { lo: -3, table: FreqTable::from_weights(&[1, 5, 0, 2]) });
        let tables = Box::new(weights.clone().map(|w| FreqTable::from_weights(&w)));
        assert_eq!(ChannelTable::read(&mut r).unwrap(), ChannelTable::Context { lo: 10, centre: 11, tables });
        assert_eq!(r.remaining(), 0);
    }

    #[test]
    fn bad_tables_are_typed_errors() {
        let read = |bytes: &[u8]| ChannelTable::read(&mut ByteReader::new(bytes)).unwrap_err().class();
        assert_eq!(read(&[3]), "format"); // unknown mode
        assert_eq!(read(&[1, 0, 0]), "limits"); // n = 0
        assert_eq!(read(&[1, 0, 0x81, 0x20]), "limits"); // n = 4097
        assert_eq!(read(&[1, 0xfe, 0xff, 0xff, 0xff, 0x0f, 2]), "format"); // lo + n overflows
        assert_eq!(read(&[1, 0, 3, 1, 1]), "format"); // weights truncated
    }
}

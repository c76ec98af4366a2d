//! Data sections (SPEC §6): a sequence of streams, each `varint length` + that many bytes, one
//! per coded channel (positions: one, see [`super::positions`]). The readers decode a chunk's
//! channels straight into dequantised `f32` values; the writers code a chunk's integer channels.

use std::ops::Range;

use super::assemble::{dequantise_value, rotations_in_place};
use super::layout::Group;
use super::params::GroupParams;
use super::tables::ChannelTable;
use super::{ByteReader, ByteWriter};
use crate::entropy::neighbour::NeighbourDecoder;
use crate::entropy::{context, in_context, Lookup, SymbolDecoder, SymbolEncoder, CONTEXTS};
use crate::error::{DecodeError, Place};

/// The next stream of a data section (`varint length`, then `length` bytes) and where it starts.
pub(crate) fn next_stream<'a>(r: &mut ByteReader<'a>) -> Result<(&'a [u8], Place), DecodeError> {
    let len = r.varint("stream length")? as usize;
    let at = r.place();
    Ok((r.take(len, "stream")?, at))
}

/// Appends one stream to a data section: `varint length`, then its bytes.
pub fn push_stream(section: &mut ByteWriter, e: SymbolEncoder) {
    let bytes = e.finish();
    section.varint(bytes.len() as u32);
    section.bytes(&bytes);
}

/// A symbol decoder over a stream, its errors placed at the stream.
pub(crate) fn stream_decoder(data: &[u8], at: Place) -> Result<SymbolDecoder<'_>, DecodeError> {
    SymbolDecoder::new(data).map_err(|what| at.corrupt(what))
}

/// Writes the data section of one chunk of a group other than position: for each coded channel
/// (in channel order) the stream of its values; constant channels write nothing.
/// `channels[j]` are channel j's values for the chunk's Gaussians.
pub fn write_channel_streams(tables: &[&ChannelTable], channels: &[&[i32]]) -> Vec<u8> {
    let mut section = ByteWriter::new();
    for (j, (t, values)) in tables.iter().zip(channels).enumerate() {
        let mut e = SymbolEncoder::new();
        match t {
            ChannelTable::Constant(_) => continue,
            ChannelTable::Neighbour(nb) => {
                let lower = |i: usize| if j > 0 { channels[j - 1][i] } else { 0 };
                let prevs = std::iter::once(nb.start).chain(values.iter().copied());
                prevs.zip(values.iter()).enumerate().for_each(|(i, (prev, &v))| e.neighbour_value(nb, prev, lower(i), v));
            }
            _ => {
                let (_, centre, _) = t.contexts().expect("a coded table");
                in_context(values, centre).for_each(|(ctx, v)| e.value(t, ctx, v));
            }
        }
        push_stream(&mut section, e);
    }
    section.buf
}

/// One coded channel being decoded: its stream, tables and the previous value (the context).
struct Lane<'a> {
    /// The channel, and its column in the output (`None`: decoded only because the context of a
    /// wanted channel above reads it).
    j: usize,
    col: Option<usize>,
    lo: i32,
    centre: i32,
    prev: i32,
    tables: [Lookup<'a>; CONTEXTS],
    scale: f32,
    d: SymbolDecoder<'a>,
    at: Place,
}

impl Lane<'_> {
    /// The lane's next value into `row` and `ints` (`CONTEXT`: pick the table by the previous value).
    #[inline(always)]
    fn decode<const CONTEXT: bool>(&mut self, row: &mut [f32], ints: &mut [i32]) {
        let table = if CONTEXT { self.tables[context(self.prev, self.centre)] } else { self.tables[0] };
        let v = self.d.coded_value(self.lo, table);
        self.prev = v;
        ints[self.j] = v;
        if let Some(col) = self.col {
            row[col] = dequantise_value(v, self.scale);
        }
    }
}

/// A neighbour-context channel being decoded (SPEC §4.3).
struct NeighbourLane<'a> {
    j: usize,
    col: Option<usize>,
    table: NeighbourDecoder<'a>,
    prev: i32,
    scale: f32,
    d: SymbolDecoder<'a>,
    at: Place,
    /// A value left `i32` (reported when the lane finishes, so the loop has no early exit).
    overflow: bool,
}

impl NeighbourLane<'_> {
    /// The lane's next value; the value below it is `ints[j − 1]`, already decoded.
    #[inline(always)]
    fn decode(&mut self, row: &mut [f32], ints: &mut [i32]) {
        let lower = if self.j > 0 { ints[self.j - 1] } else { 0 };
        let v = self.d.neighbour_value(&self.table, self.prev, lower).unwrap_or_else(|| {
            self.overflow = true;
            0
        });
        self.prev = v;
        ints[self.j] = v;
        if let Some(col) = self.col {
            row[col] = dequantise_value(v, self.scale);
        }
    }
}

/// Channels `channels` of a (non-position) group chunk into `vals`, Gaussian-major (`count ×
/// channels.len()`), each value dequantised with `scale[channel]`. Each coded channel has its own
/// stream; decoding them side by side lets the independent coder states overlap in the CPU.
pub(crate) fn decode_channels(
    p: &GroupParams,
    r: &mut ByteReader<'_>,
    scale: &[f32],
    channels: Range<usize>,
    vals: &mut [f32],
) -> Result<(), DecodeError> {
    // Every channel's stream is located (so the section's layout is checked), the wanted ones decoded.
    let mut streams = Vec::with_capacity(p.tables.len());
    for t in &p.tables {
        streams.push(match t {
            ChannelTable::Constant(_) => (&[][..], r.place()),
            ChannelTable::Coded { .. } | ChannelTable::Context { .. } | ChannelTable::Neighbour(_) => next_stream(r)?,
        });
    }
    let w = channels.len();
    // A neighbour-context channel whose context reads the channel below needs that channel
    // decoded too (SPEC §4.3), and so on down: decode from the first channel the wanted ones need.
    let mut first = channels.start;
    while first > 0 && matches!(&p.tables[first], ChannelTable::Neighbour(t) if t.uses_lower()) {
        first -= 1;
    }
    // Every value of the current row as an integer, for the neighbour lanes' contexts.
    let mut ints = vec![0i32; channels.end];
    // Channels with one table, context-coded ones and neighbour-coded ones decode in separate
    // lanes, so that the first skip the context computation; neighbour lanes run last, in
    // channel order, so that the channel below each is decoded when it runs.
    let (mut plain, mut contextual, mut neighbours) = (Vec::with_capacity(w), Vec::new(), Vec::new());
    for j in first..channels.end {
        let col = j.checked_sub(channels.start);
        let (data, at) = streams[j];
        match &p.tables[j] {
            ChannelTable::Constant(v) => {
                ints[j] = *v;
                if let Some(col) = col {
                    vals.iter_mut().skip(col).step_by(w).for_each(|x| *x = dequantise_value(*v, scale[j]));
                }
            }
            ChannelTable::Neighbour(table) => neighbours.push(NeighbourLane {
                j,
                col,
                table: NeighbourDecoder::new(table),
                prev: table.start,
                scale: scale[j],
                d: stream_decoder(data, at)?,
                at,
                overflow: false,
            }),
            t => {
                let (lo, centre, tables) = t.contexts().expect("a coded table");
                let lanes = if matches!(t, ChannelTable::Context { .. }) { &mut contextual } else { &mut plain };
                lanes.push(Lane {
                    j,
                    col,
                    lo,
                    centre,
                    prev: centre,
                    tables: tables.map(|t| t.lookup_table()),
                    scale: scale[j],
                    d: stream_decoder(data, at)?,
                    at,
                });
            }
        }
    }
    for row in vals.chunks_exact_mut(w) {
        plain.iter_mut().for_each(|l| l.decode::<false>(row, &mut ints));
        contextual.iter_mut().for_each(|l| l.decode::<true>(row, &mut ints));
        neighbours.iter_mut().for_each(|l| l.decode(row, &mut ints));
    }
    plain.into_iter().chain(contextual).try_for_each(|l| l.d.finish().map_err(|what| l.at.corrupt(what)))?;
    for l in neighbours {
        if l.overflow {
            return Err(l.at.corrupt("neighbour prediction plus difference outside i32"));
        }
        l.d.finish().map_err(|what| l.at.corrupt(what))?;
    }
    if !vals.iter().fold(true, |ok, x| ok & x.is_finite()) {
        return Err(r.corrupt("dequantised value is not finite"));
    }
    Ok(())
}

/// Decodes channels `channels` of one data section, dequantised, into `out`, Gaussian-major:
/// position 3 coordinates, rotation 4 quaternion components, an SH band with a codebook each
/// Gaussian's row index (exact in f32, checked against the codebook's rows), other groups the
/// channels asked for.
pub(crate) fn decode_data_section(
    g: Group,
    p: &GroupParams,
    r: &mut ByteReader<'_>,
    channels: Range<usize>,
    out: &mut [f32],
) -> Result<(), DecodeError> {
    match g {
        Group::Position => super::positions::decode_positions(p, r, out)?,
        Group::Rotation => {
            // The index channel is read unscaled: f32 holds 0..=3 (and any escaped value) exactly enough.
            decode_channels(p, r, &[1.0, p.steps[1], p.steps[2], p.steps[3]], 0..4, out)?;
            rotations_in_place(out).map_err(|what| r.corrupt(what))?;
        }
        _ => match &p.codebook {
            // An SH band that shares the index of the band below (SPEC §3.2): no stream.
            Some(_) if p.shares_index() => {}
            // Vector-quantised SH band (SPEC §3.2): one index channel, checked; the assembler
            // looks the rows up.
            Some(cb) => {
                decode_channels(p, r, &[1.0], 0..1, out)?;
                // f32(v) < K exactly when v < K, for K ≤ 2^16 (exact in f32; rounding is monotonic).
                if !out.iter().fold(true, |ok, &i| ok & (i >= 0.0 && i < cb.rows as f32)) {
                    return Err(r.corrupt("codebook index out of range"));
                }
            }
            None => decode_channels(p, r, &p.steps, channels, out)?,
        },
    }
    if r.remaining() != 0 {
        return Err(r.corrupt("trailing bytes in a data section"));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use super::*;
    use crate::bitstream::params::Codebook;
    use crate::entropy::FreqTable;

    #[test]
    fn codebook_bands_decode_to_checked_row_indices() {
        // A codebook of two rows; the index channel's table covers 0..4, so 2 and 3 are codable.
        let codebook = Some(Arc::new(Codebook { rows: 2, values: vec![0.5; 2 * 9] }));
        let table = ChannelTable::Coded { lo: 0, table: FreqTable::from_weights(&[1, 1, 1, 1, 1]) };
        let p = GroupParams { steps: vec![1.0], tables: vec![table], grid: None, codebook };
        for (indices, ok) in [([0, 1, 1], true), ([0, 2, 1], false), ([3, 0, 0], false), ([1, 0, -1], false)] {
            let bytes = write_channel_streams(&[&p.tables[0]], &[&indices]);
            let mut out = vec![9.0; 3];
            let result = decode_data_section(Group::Sh1, &p, &mut ByteReader::new(&bytes), 0..9, &mut out);
            match &result {
                Ok(()) => assert_eq!(out, indices.map(|i| i as f32), "{indices:?}"),
                Err(e) => assert!(e.to_string().contains("codebook index out of range"), "{indices:?}: {e}"),
            }
            assert_eq!(result.is_ok(), ok, "{indices:?}");
        }
    }
}

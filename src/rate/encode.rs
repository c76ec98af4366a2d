//! Writing a quantised scene: choosing tables per group, then every section through the
//! writers of `gscodec_decoder::bitstream` (the one definition of the format, beside its readers).

use rayon::prelude::*;
use serde::Serialize;

use gscodec_decoder::bitstream::info::{write_info, EncoderInfo};
use std::ops::Range;

use gscodec_decoder::bitstream::layout::{Group, INFO_KIND, LEVELS_KIND};
use gscodec_decoder::bitstream::params::{write_channel_params, write_position_params};
use gscodec_decoder::bitstream::positions::{delta_length, delta_raw_bits, morton_deltas, write_position_stream};
use gscodec_decoder::bitstream::sections::write_padded;
use gscodec_decoder::bitstream::stream::write_channel_streams;
use gscodec_decoder::bitstream::{Header, Section, SECTION_OPTIONAL, VERSION_MAJOR, VERSION_MAJOR_UNIFORM, VERSION_MINOR};
use gscodec_decoder::entropy::ChannelTable;

use super::quantise::Quantised;
use super::tables::{self, ChosenTable};

/// Bytes and bits of one attribute group.
#[derive(Debug, Clone, Default, Serialize)]
pub struct GroupReport {
    pub group: String,
    /// Parameter section bytes (steps + tables).
    pub table_bytes: usize,
    /// Range-coded stream bytes, all chunks.
    pub stream_bytes: usize,
    /// Ideal code length of the streams under the stored tables (the rate estimate), bits.
    pub estimated_bits: f64,
    /// Channels stored once as a constant.
    pub constant_channels: usize,
    /// Table + stream bits under the static-histogram model alone (the non-learned baseline).
    pub histogram_bits: f64,
    /// Table + stream bits under the learned density alone.
    pub learned_bits: f64,
    /// Table + stream bits with one static histogram per context (previous value's distance
    /// from the channel's centre).
    pub context_bits: f64,
    /// Channels stored with context-coded tables.
    pub context_channels: usize,
}

/// What an encode produced.
#[derive(Debug, Clone, Serialize)]
pub struct EncodeReport {
    pub gaussians: usize,
    pub sh_degree: u8,
    pub position_bits: u8,
    pub file_bytes: usize,
    pub groups: Vec<GroupReport>,
}

impl EncodeReport {
    /// Estimated total bits (tables counted exactly, streams by ideal code length).
    pub fn estimated_bits(&self) -> f64 {
        self.groups.iter().map(|g| g.estimated_bits + 8.0 * g.table_bytes as f64).sum()
    }
}

struct GroupPlan {
    group: Group,
    params: Vec<u8>,
    tables: Vec<ChosenTable>,
    histogram_bits: f64,
    learned_bits: f64,
    context_bits: f64,
}

fn plan(q: &Quantised, chunks: &[Range<usize>], deltas: &[u64], learned: bool) -> Vec<GroupPlan> {
    let compare = |v: &[i32], contexts| if learned { tables::compare(v, contexts) } else { tables::histogram_only(v, contexts) };
    let mut plans = Vec::new();
    let lens: Vec<i32> = deltas.iter().map(|&d| delta_length(d) as i32).collect();
    let cmp = compare(&lens, None); // position lengths are never context-coded (SPEC §4)
    let raw: f64 = lens.iter().map(|&l| (l - 1).max(0) as f64).sum();
    let (hb, lb) = (cmp.histogram_bits + raw, cmp.learned_bits + raw);
    let t = cmp.best;
    plans.push(GroupPlan {
        group: Group::Position,
        params: write_position_params(&q.grid, &t.bytes),
        tables: vec![t],
        histogram_bits: hb,
        learned_bits: lb,
        context_bits: f64::NAN,
    });
    // Every channel of every group in one parallel batch (groups have 1 to 21 channels).
    let all: Vec<&[i32]> = q.groups.iter().flat_map(|(_, _, chans)| chans.iter().map(|c| &c[..])).collect();
    let mut all_cmps = all.par_iter().map(|c| compare(c, Some(chunks))).collect::<Vec<tables::Compared>>().into_iter();
    for (g, steps, chans) in &q.groups {
        let cmps: Vec<tables::Compared> = all_cmps.by_ref().take(chans.len()).collect();
        let histogram_bits = cmps.iter().map(|c| c.histogram_bits).sum();
        let learned_bits = cmps.iter().map(|c| c.learned_bits).sum();
        // A channel where contexts were not tried (a constant) costs its histogram bits.
        let context_bits = cmps.iter().map(|c| if c.context_bits.is_nan() { c.histogram_bits } else { c.context_bits }).sum();
        let ts: Vec<ChosenTable> = cmps.into_iter().map(|c| c.best).collect();
        let params = write_channel_params(steps, ts.iter().map(|t| &t.bytes[..]));
        plans.push(GroupPlan { group: *g, params, tables: ts, histogram_bits, learned_bits, context_bits });
    }
    plans
}

/// The data section of plan `p`'s group for the chunk of Gaussians `range`.
fn encode_chunk(q: &Quantised, p: &GroupPlan, deltas: &[u64], range: Range<usize>) -> Vec<u8> {
    if p.group == Group::Position {
        write_position_stream(&p.tables[0].table, &deltas[range])
    } else {
        let chans = &q.groups.iter().find(|x| x.0 == p.group).expect("group").2;
        let tables: Vec<&ChannelTable> = p.tables.iter().map(|t| &t.table).collect();
        let values: Vec<&[i32]> = chans.iter().map(|c| &c[range.clone()]).collect();
        write_channel_streams(&tables, &values)
    }
}

/// Encodes a quantised scene. `input` = (Gaussians, SH degree) of the encoder's input, for `info`.
///
/// A scene with levels ([`Quantised::levels`]) is written as format 4.0 with a levels section,
/// in the payload order of SPEC §3 for progressive decoding: levels, parameters, then chunk by
/// chunk the base groups (position, scale, rotation, opacity, DC colour), then each SH band chunk
/// by chunk, then info. Without levels it is a 3.0 file (same order, one level).
pub fn write(q: &Quantised, input: (usize, u8), learned_tables: bool) -> (Vec<u8>, EncodeReport) {
    let n = q.len();
    let progressive = !q.levels.is_empty();
    let version_major = if progressive { VERSION_MAJOR } else { VERSION_MAJOR_UNIFORM };
    let header = Header { version_major, version_minor: VERSION_MINOR, gaussians: n as u32, sh_degree: q.sh_degree };
    let info = write_info(&EncoderInfo { input_gaussians: input.0.min(u32::MAX as usize) as u32, input_sh_degree: input.1 });
    let mut report = EncodeReport { gaussians: n, sh_degree: q.sh_degree, position_bits: q.grid.2, file_bytes: 0, groups: Vec::new() };
    let mut payloads: Vec<(u16, u16, u32, Vec<u8>)> = Vec::new();
    if n > 0 {
        let layout = q.layout();
        if progressive {
            payloads.push((LEVELS_KIND, 0, 0, layout.write()));
        }
        let chunks = layout.chunk_ranges();
        let deltas = morton_deltas(&q.morton, &chunks);
        let plans = plan(q, &chunks, &deltas, learned_tables);
        // Chunk-major for the base groups, then band-major for SH (plans are in group order).
        let base = plans.iter().take_while(|p| p.group.sh_band() == 0).count();
        let jobs: Vec<(usize, usize)> = (0..chunks.len())
            .flat_map(|c| (0..base).map(move |p| (p, c)))
            .chain((base..plans.len()).flat_map(|p| (0..chunks.len()).map(move |c| (p, c))))
            .collect();
        let streams: Vec<Vec<u8>> = jobs.par_iter().map(|&(p, c)| encode_chunk(q, &plans[p], &deltas, chunks[c].clone())).collect();
        for p in &plans {
            payloads.push((p.group.params_kind(), 0, 0, p.params.clone()));
            report.groups.push(GroupReport {
                group: p.group.name().into(),
                table_bytes: p.params.len(),
                stream_bytes: 0,
                estimated_bits: p.tables.iter().map(|t| t.bits).sum::<f64>()
                    + if p.group == Group::Position { deltas.iter().map(|&d| delta_raw_bits(d) as f64).sum() } else { 0.0 },
                constant_channels: p.tables.iter().filter(|t| matches!(t.table, ChannelTable::Constant(_))).count(),
                histogram_bits: p.histogram_bits,
                learned_bits: p.learned_bits,
                context_bits: p.context_bits,
                context_channels: p.tables.iter().filter(|t| matches!(t.table, ChannelTable::Context { .. })).count(),
            });
        }
        for (&(p, c), s) in jobs.iter().zip(streams) {
            report.groups[p].stream_bytes += s.len();
            if !s.is_empty() {
                payloads.push((plans[p].group.data_kind(), c as u16, 0, s));
            }
        }
    }
    payloads.push((INFO_KIND, 0, SECTION_OPTIONAL, info));
    let sections: Vec<Section> = payloads.iter().map(|(k, c, f, d)| Section { kind: *k, chunk: *c, flags: *f, data: d }).collect();
    let bytes = write_padded(&header, &sections);
    report.file_bytes = bytes.len();
    (bytes, report)
}

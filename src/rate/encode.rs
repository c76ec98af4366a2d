//! Writing a quantised scene: choosing tables per group, then every section through the
//! writers of `gscodec_decoder::bitstream` (the one definition of the format, beside its readers).

use rayon::prelude::*;
use serde::Serialize;
use std::borrow::Cow;
use std::collections::HashMap;
use std::hash::{BuildHasher, Hash, Hasher};
use std::sync::{Arc, Mutex};

use gscodec_decoder::bitstream::info::{write_info, EncoderInfo};
use std::ops::Range;

use gscodec_decoder::bitstream::layout::{Group, CODEBOOK_KIND, INFO_KIND, LEVELS_KIND};
use gscodec_decoder::bitstream::levels::Layout;
use gscodec_decoder::bitstream::params::{write_channel_params, write_codebook, write_position_params};
use gscodec_decoder::bitstream::positions::{delta_length, delta_raw_bits, morton_deltas, write_position_stream};
use gscodec_decoder::bitstream::sections::write_padded;
use gscodec_decoder::bitstream::stream::write_channel_streams;
use gscodec_decoder::bitstream::{
    Header, Section, SECTION_OPTIONAL, VERSION_MAJOR, VERSION_MAJOR_CODEBOOKS, VERSION_MAJOR_LEVELS, VERSION_MAJOR_NEIGHBOURS,
    VERSION_MAJOR_SHARED, VERSION_MAJOR_UNIFORM, VERSION_MINOR,
};
use gscodec_decoder::entropy::ChannelTable;

use super::quantise::Quantised;
use super::tables::{self, ChosenTable};

/// Bytes and bits of one attribute group.
#[derive(Debug, Clone, Default, Serialize)]
pub struct GroupReport {
    pub group: String,
    /// Parameter section bytes (steps + tables), and the codebook section's for an SH band
    /// coded by vector quantisation.
    pub table_bytes: usize,
    /// Rows of the band's codebook (SPEC §3.2); 0 = coded per coefficient.
    pub codebook_rows: usize,
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
    /// Channels stored with neighbour-context tables (format 8.0).
    pub neighbour_channels: usize,
}

/// What an encode produced.
#[derive(Debug, Clone, Serialize)]
pub struct EncodeReport {
    pub gaussians: usize,
    pub sh_degree: u8,
    pub position_bits: u8,
    pub file_bytes: usize,
    pub groups: Vec<GroupReport>,
    /// Bytes outside the groups' sections: header, section table, levels, info and padding
    /// (exact; a 6.0 file's extra parameter sections each add a table entry).
    pub container_bytes: usize,
}

impl EncodeReport {
    /// Estimated total bits (tables and container counted exactly, streams by ideal code length).
    pub fn estimated_bits(&self) -> f64 {
        self.groups.iter().map(|g| g.estimated_bits + 8.0 * g.table_bytes as f64).sum::<f64>() + 8.0 * self.container_bytes as f64
    }
}

/// Which table models a group's channels may use besides the static histogram and its contexts.
#[derive(Debug, Clone, Copy)]
struct Models {
    /// The learned (trained Laplace) density.
    learned: bool,
    /// Neighbour contexts (table mode 3, format 8.0).
    neighbours: bool,
}

struct GroupPlan {
    group: Group,
    /// Whether a table of the group (or of its codebook) has neighbour contexts (format 8.0).
    neighbours: bool,
    params: Vec<u8>,
    /// The codebook section of an SH band coded by vector quantisation, and its rows.
    codebook: Option<(Vec<u8>, usize)>,
    tables: Vec<ChosenTable>,
    histogram_bits: f64,
    learned_bits: f64,
    context_bits: f64,
}

/// Plans the groups `todo` of `q` (0 = position, `i` = `q.groups[i − 1]`; ascending).
fn plan(q: &Quantised, chunks: &[Range<usize>], deltas: &[u64], models: Models, todo: &[usize]) -> Vec<GroupPlan> {
    // `lower`: the values of the channel below (empty for a first channel), for mode 3.
    let compare = |v: &[i32], contexts: Option<&[Range<usize>]>, lower: &[i32]| {
        let neighbours = Some(lower).filter(|_| models.neighbours);
        if models.learned {
            tables::compare(v, contexts, neighbours)
        } else {
            tables::histogram_only(v, contexts, neighbours)
        }
    };
    let uses_neighbours = |ts: &[ChosenTable]| ts.iter().any(|t| matches!(t.table, ChannelTable::Neighbour(_)));
    let mut plans = Vec::new();
    if todo.contains(&0) {
        let lens: Vec<i32> = deltas.iter().map(|&d| delta_length(d) as i32).collect();
        let cmp = compare(&lens, None, &[]); // no chunks, no contexts: position lengths are never context-coded (SPEC §4)
        let raw: f64 = lens.iter().map(|&l| (l - 1).max(0) as f64).sum();
        let (hb, lb) = (cmp.histogram_bits + raw, cmp.learned_bits + raw);
        let t = cmp.best;
        plans.push(GroupPlan {
            group: Group::Position,
            neighbours: false,
            params: write_position_params(&q.grid, &t.bytes),
            codebook: None,
            tables: vec![t],
            histogram_bits: hb,
            learned_bits: lb,
            context_bits: f64::NAN,
        });
    }
    for &i in todo.iter().filter(|&&i| i > 0) {
        let (g, steps, chans) = &q.groups[i - 1];
        if let Some((_, cb)) = q.codebooks.iter().find(|c| c.0 == *g) {
            // Vector quantisation (SPEC §3.2): the codebook's rows coded like one chunk of K
            // Gaussians, and the band's one channel, the row index.
            let k = cb.len();
            let cols: Vec<Vec<i32>> = (0..cb.channels).map(|j| cb.column(j)).collect();
            let cts: Vec<ChosenTable> = (0..cols.len())
                .into_par_iter()
                .map(|j| compare(&cols[j], Some(&[0..k]), if j > 0 { &cols[j - 1] } else { &[] }).best)
                .collect();
            let book_params = write_channel_params(steps, cts.iter().map(|t| &t.bytes[..]));
            let refs: Vec<&ChannelTable> = cts.iter().map(|t| &t.table).collect();
            let values: Vec<&[i32]> = cols.iter().map(|c| &c[..]).collect();
            let book = write_codebook(k, &book_params, &write_channel_streams(&refs, &values));
            let (params, tables, histogram_bits, learned_bits, context_bits) = if shares_index(q, *g) {
                // The index of band 1 (SPEC §3.2, format 9.0): no channel.
                (write_channel_params(&[], std::iter::empty()), Vec::new(), 0.0, 0.0, 0.0)
            } else {
                let index: Vec<i32> = cb.index.iter().map(|&i| i as i32).collect();
                let c = compare(&index, Some(chunks), &[]);
                let params = write_channel_params(&[1.0], [&c.best.bytes[..]].into_iter());
                (params, vec![c.best], c.histogram_bits, c.learned_bits, c.context_bits)
            };
            let neighbours = uses_neighbours(&cts) || uses_neighbours(&tables);
            plans.push(GroupPlan {
                group: *g,
                neighbours,
                params,
                codebook: Some((book, k)),
                tables,
                histogram_bits,
                learned_bits,
                context_bits,
            });
            continue;
        }
        let cmps: Vec<tables::Compared> =
            (0..chans.len()).into_par_iter().map(|j| compare(&chans[j], Some(chunks), if j > 0 { &chans[j - 1] } else { &[] })).collect();
        let histogram_bits = cmps.iter().map(|c| c.histogram_bits).sum();
        let learned_bits = cmps.iter().map(|c| c.learned_bits).sum();
        // A channel where contexts were not tried (a constant) costs its histogram bits.
        let context_bits = cmps.iter().map(|c| if c.context_bits.is_nan() { c.histogram_bits } else { c.context_bits }).sum();
        let ts: Vec<ChosenTable> = cmps.into_iter().map(|c| c.best).collect();
        let params = write_channel_params(steps, ts.iter().map(|t| &t.bytes[..]));
        plans.push(GroupPlan {
            group: *g,
            neighbours: uses_neighbours(&ts),
            params,
            codebook: None,
            tables: ts,
            histogram_bits,
            learned_bits,
            context_bits,
        });
    }
    plans
}

/// A group's plan and its data sections, chunk by chunk.
struct CodedGroup {
    plan: GroupPlan,
    streams: Vec<Vec<u8>>,
}

/// Coded groups by what determines them, shared by the trial encodes of an RD search: a trial
/// that changes one group's step finds every other group (same values, steps, chunks and table
/// choice) already coded. The key is a 128-bit hash (two SipHash-1-3 of the group's id, steps or
/// grid, chunks, table choice, every value and its codebook if any); entries are never evicted (a search codes about
/// a thousand groups).
///
/// It also holds the SH codebooks the trials computed ([`super::vq::Memo`]).
#[derive(Default)]
pub struct GroupCache {
    groups: Mutex<HashMap<(u64, u64), Arc<CodedGroup>>>,
    /// The trials' SH codebooks.
    pub codebooks: super::vq::Memo,
    /// The trials' rate-aware roundings ([`super::rdoq::round_groups`]), by group, targets and
    /// the values rounded to nearest.
    pub(crate) rounded: Mutex<HashMap<(u64, u64), Arc<Vec<Vec<i32>>>>>,
}

impl GroupCache {
    /// Groups held.
    pub fn len(&self) -> usize {
        self.groups.lock().expect("not poisoned").len()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// A 128-bit cache key: two foldhash (quality) digests, seeded 1 and 2, of what `feed` hashes.
pub(crate) fn key128(feed: impl Fn(&mut foldhash::quality::FoldHasher<'static>)) -> (u64, u64) {
    let hash = |seed: u64| {
        let mut h = foldhash::quality::FixedState::with_seed(seed).build_hasher();
        feed(&mut h);
        h.finish()
    };
    (hash(1), hash(2))
}

/// The cache key of group `i` of `q` (numbered as in [`plan`]).
fn group_key(q: &Quantised, chunks: &[Range<usize>], models: Models, i: usize) -> (u64, u64) {
    key128(|h| {
        (models.learned, models.neighbours, chunks.iter().map(|r| (r.start, r.end)).collect::<Vec<_>>()).hash(h);
        if i == 0 {
            let (lo, step, bits) = &q.grid;
            (lo.map(f32::to_bits), step.map(f32::to_bits), bits, &q.morton).hash(h);
        } else {
            let (g, steps, chans) = &q.groups[i - 1];
            (g.name(), steps.iter().map(|s| s.to_bits()).collect::<Vec<_>>(), chans).hash(h);
            if let Some((_, cb)) = q.codebooks.iter().find(|c| c.0 == *g) {
                (cb.channels, &cb.rows, &cb.index, shares_index(q, *g)).hash(h);
            }
        }
    })
}

/// Plans and codes every group of `q` (numbered as in [`plan`]), taking those `cache` holds
/// from it and adding the others.
fn code_groups(q: &Quantised, chunks: &[Range<usize>], deltas: &[u64], models: Models, cache: Option<&GroupCache>) -> Vec<Arc<CodedGroup>> {
    let count = q.groups.len() + 1;
    let keys: Vec<Option<(u64, u64)>> = (0..count).map(|i| cache.map(|_| group_key(q, chunks, models, i))).collect();
    let mut coded: Vec<Option<Arc<CodedGroup>>> = match cache {
        Some(c) => {
            let map = c.groups.lock().expect("not poisoned");
            keys.iter().map(|k| k.and_then(|k| map.get(&k).cloned())).collect()
        }
        None => vec![None; count],
    };
    let todo: Vec<usize> = (0..count).filter(|&i| coded[i].is_none()).collect();
    let plans = plan(q, chunks, deltas, models, &todo);
    let jobs: Vec<(usize, usize)> = (0..plans.len()).flat_map(|p| (0..chunks.len()).map(move |c| (p, c))).collect();
    let mut streams = jobs.par_iter().map(|&(p, c)| encode_chunk(q, &plans[p], deltas, chunks[c].clone())).collect::<Vec<_>>().into_iter();
    for (plan, i) in plans.into_iter().zip(todo) {
        let g = Arc::new(CodedGroup { plan, streams: streams.by_ref().take(chunks.len()).collect() });
        if let (Some(c), Some(k)) = (cache, keys[i]) {
            c.groups.lock().expect("not poisoned").insert(k, g.clone());
        }
        coded[i] = Some(g);
    }
    coded.into_iter().map(|g| g.expect("coded above")).collect()
}

/// The data section of plan `p`'s group for the chunk of Gaussians `range`.
fn encode_chunk(q: &Quantised, p: &GroupPlan, deltas: &[u64], range: Range<usize>) -> Vec<u8> {
    if p.group == Group::Position {
        write_position_stream(&p.tables[0].table, &deltas[range])
    } else if shares_index(q, p.group) {
        Vec::new()
    } else if let Some((_, cb)) = q.codebooks.iter().find(|c| c.0 == p.group) {
        let index: Vec<i32> = cb.index[range].iter().map(|&i| i as i32).collect();
        write_channel_streams(&[&p.tables[0].table], &[&index])
    } else {
        let chans = &q.groups.iter().find(|x| x.0 == p.group).expect("group").2;
        let tables: Vec<&ChannelTable> = p.tables.iter().map(|t| &t.table).collect();
        let values: Vec<&[i32]> = chans.iter().map(|c| &c[range.clone()]).collect();
        write_channel_streams(&tables, &values)
    }
}

/// Whether SH group `g` of `q` shares band 1's row index (SPEC §3.2, format 9.0).
fn shares_index(q: &Quantised, g: Group) -> bool {
    q.shared_index && g.sh_band() >= 2
}

/// Level `l` of `q` (its Gaussians `r`) as a scene of its own, with that level's steps: what
/// its parameter sections and data sections code in a 6.0 file (SPEC §4). SH codebooks are
/// shared: the level keeps the rows and takes its own indices.
fn level_part(q: &Quantised, l: usize, r: Range<usize>) -> Quantised {
    let groups = (0..q.groups.len())
        .map(|gi| (q.groups[gi].0, q.level_steps(gi, l), q.groups[gi].2.iter().map(|c| c[r.clone()].to_vec()).collect()))
        .collect();
    let codebooks = q
        .codebooks
        .iter()
        .map(|(g, cb)| (*g, super::vq::Codebook { channels: cb.channels, rows: cb.rows.clone(), index: cb.index[r.clone()].to_vec() }))
        .collect();
    Quantised {
        sh_degree: q.sh_degree,
        grid: q.level_grid(l),
        levels: Vec::new(),
        morton: q.morton[r].to_vec(),
        groups,
        codebooks,
        shared_index: q.shared_index,
        level_factors: Vec::new(),
        tail_groups: [1.0; 8],
        level_grids: Vec::new(),
    }
}

/// Whether each level of `q` has parameter sections of its own (SPEC §4): a 6.0 file
/// (importance classes) or a 9.0 file (a shared SH index), like 8.0.
fn params_per_level(q: &Quantised) -> bool {
    !q.level_factors.is_empty() || q.shared_index
}

/// Whether `q`'s channels may take neighbour-context tables: they need a format-8.0 file, whose
/// levels each have their own parameter sections, so not a progressive file whose levels share
/// one set.
pub(crate) fn neighbours_allowed(q: &Quantised) -> bool {
    q.levels.is_empty() || params_per_level(q)
}

/// The parts of `q` (laid out as `layout`) coded with one set of parameter sections each (SPEC
/// §4): every level where [`params_per_level`], else the whole scene. Per part: its Gaussians
/// and its chunks, local to it.
pub(crate) fn parameter_parts(q: &Quantised, layout: &Layout) -> Vec<(Range<usize>, Vec<Range<usize>>)> {
    let chunks = layout.chunk_ranges();
    if !params_per_level(q) {
        return vec![(0..q.len(), chunks)];
    }
    layout
        .level_ranges()
        .into_iter()
        .map(|cr| {
            let r = chunks[cr.start].start..chunks[cr.end - 1].end;
            let local = chunks[cr].iter().map(|c| c.start - r.start..c.end - r.start).collect();
            (r, local)
        })
        .collect()
}

/// Encodes a quantised scene. `input` = (Gaussians, SH degree) of the encoder's input, for `info`.
///
/// A scene with levels ([`Quantised::levels`]) is written as format 4.0 with a levels section,
/// in the payload order of SPEC §3 for progressive decoding: levels, parameters, then chunk by
/// chunk the base groups (position, scale, rotation, opacity, DC colour), then each SH band chunk
/// by chunk, then info. Without levels it is a 3.0 file (same order, one level). A scene with SH
/// codebooks ([`Quantised::codebooks`]) is a 5.0 file (always with a levels section), its
/// codebooks right after the parameter sections; importance classes make it 6.0. With
/// `neighbour_tables`, channels (codebook rows included) may take neighbour-context tables
/// where they are cheaper, and a file that has one is 8.0 (SPEC §4.3); never for a progressive
/// file whose levels share one parameter set. A scene whose SH bands share band 1's row index
/// ([`Quantised::shared_index`]) is a 9.0 file, with parameter sections per level.
pub fn write(q: &Quantised, input: (usize, u8), learned_tables: bool, neighbour_tables: bool) -> (Vec<u8>, EncodeReport) {
    write_cached(q, input, learned_tables, neighbour_tables, None)
}

/// [`write`], taking the groups `cache` holds from it and adding the others: the same bytes and
/// report.
pub fn write_cached(
    q: &Quantised,
    input: (usize, u8),
    learned_tables: bool,
    neighbour_tables: bool,
    cache: Option<&GroupCache>,
) -> (Vec<u8>, EncodeReport) {
    let n = q.len();
    let progressive = !q.levels.is_empty();
    let codebooks = n > 0 && !q.codebooks.is_empty();
    let shared = n > 0 && q.shared_index;
    let per_level = n > 0 && params_per_level(q);
    let models = Models { learned: learned_tables, neighbours: neighbour_tables && neighbours_allowed(q) };
    let info = write_info(&EncoderInfo { input_gaussians: input.0.min(u32::MAX as usize) as u32, input_sh_degree: input.1 });
    let mut report = EncodeReport {
        gaussians: n,
        sh_degree: q.sh_degree,
        position_bits: q.grid.2,
        file_bytes: 0,
        groups: Vec::new(),
        container_bytes: 0,
    };
    let mut payloads: Vec<(u16, u16, u32, &[u8])> = Vec::new();
    let levels;
    let coded;
    let mut neighbours = false;
    if n > 0 {
        let layout = q.layout();
        levels = layout.write();
        let chunks = layout.chunk_ranges();
        let parts: Vec<(Cow<Quantised>, Vec<Range<usize>>)> = parameter_parts(q, &layout)
            .into_iter()
            .enumerate()
            .map(|(l, (r, local))| (if per_level { Cow::Owned(level_part(q, l, r)) } else { Cow::Borrowed(q) }, local))
            .collect();
        coded = parts
            .iter()
            .map(|(pq, ch)| {
                let deltas = morton_deltas(&pq.morton, ch);
                (code_groups(pq, ch, &deltas, models, cache), deltas)
            })
            .collect::<Vec<_>>();
        neighbours = coded.iter().any(|(gs, _)| gs.iter().any(|g| g.plan.neighbours));
        if progressive || codebooks || per_level || neighbours {
            payloads.push((LEVELS_KIND, 0, 0, &levels));
        }
        // Global chunk c → (part, chunk within the part).
        let chunk_of: Vec<(usize, usize)> = parts.iter().enumerate().flat_map(|(p, (_, ch))| (0..ch.len()).map(move |j| (p, j))).collect();
        // Chunk-major for the base groups, then band-major for SH (groups are in group order).
        let groups = coded[0].0.len();
        let base = coded[0].0.iter().take_while(|g| g.plan.group.sh_band() == 0).count();
        let jobs: Vec<(usize, usize)> = (0..chunks.len())
            .flat_map(|c| (0..base).map(move |g| (g, c)))
            .chain((base..groups).flat_map(|g| (0..chunks.len()).map(move |c| (g, c))))
            .collect();
        for (part, (gs, deltas)) in coded.iter().enumerate() {
            for (gi, p) in gs.iter().map(|g| &g.plan).enumerate() {
                payloads.push((p.group.params_kind(), part as u16, 0, &p.params));
                if part == 0 {
                    report.groups.push(GroupReport { group: p.group.name().into(), ..GroupReport::default() });
                }
                let r = &mut report.groups[gi];
                // A codebook is shared by every level: written (and counted) once.
                let book = p.codebook.as_ref().filter(|_| part == 0);
                r.table_bytes += p.params.len() + book.map_or(0, |c| c.0.len());
                r.codebook_rows = p.codebook.as_ref().map_or(0, |c| c.1);
                r.estimated_bits += p.tables.iter().map(|t| t.bits).sum::<f64>()
                    + if p.group == Group::Position { deltas.iter().map(|&d| delta_raw_bits(d) as f64).sum() } else { 0.0 };
                r.constant_channels += p.tables.iter().filter(|t| matches!(t.table, ChannelTable::Constant(_))).count();
                r.histogram_bits += p.histogram_bits;
                r.learned_bits += p.learned_bits;
                r.context_bits += p.context_bits;
                r.context_channels += p.tables.iter().filter(|t| matches!(t.table, ChannelTable::Context { .. })).count();
                r.neighbour_channels += p.tables.iter().filter(|t| matches!(t.table, ChannelTable::Neighbour(_))).count();
            }
        }
        for p in coded[0].0.iter().map(|g| &g.plan) {
            if let Some((book, _)) = &p.codebook {
                payloads.push((CODEBOOK_KIND, u16::from(p.group.sh_band()), 0, book));
            }
        }
        for &(g, c) in &jobs {
            let (part, j) = chunk_of[c];
            let coded_group = &coded[part].0[g];
            let s = &coded_group.streams[j];
            report.groups[g].stream_bytes += s.len();
            if !s.is_empty() {
                payloads.push((coded_group.plan.group.data_kind(), c as u16, 0, s));
            }
        }
    }
    payloads.push((INFO_KIND, 0, SECTION_OPTIONAL, &info));
    let sections: Vec<Section> = payloads.iter().map(|(k, c, f, d)| Section { kind: *k, chunk: *c, flags: *f, data: d }).collect();
    let version_major = match (neighbours, per_level, codebooks, progressive) {
        _ if shared => VERSION_MAJOR_SHARED,
        (true, ..) => VERSION_MAJOR_NEIGHBOURS,
        (false, true, ..) => VERSION_MAJOR,
        (false, false, true, _) => VERSION_MAJOR_CODEBOOKS,
        (false, false, false, true) => VERSION_MAJOR_LEVELS,
        (false, false, false, false) => VERSION_MAJOR_UNIFORM,
    };
    let header = Header { version_major, version_minor: VERSION_MINOR, gaussians: n as u32, sh_degree: q.sh_degree };
    let bytes = write_padded(&header, &sections);
    report.file_bytes = bytes.len();
    report.container_bytes = bytes.len() - report.groups.iter().map(|g| g.table_bytes + g.stream_bytes).sum::<usize>();
    (bytes, report)
}

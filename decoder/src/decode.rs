//! The decoding core behind [`crate::Decoder`]: a checked container to a scene — parameter
//! sections, then the (group, chunk, channel range) jobs in parallel, then the assembler.

use std::ops::Range;
use std::sync::{Arc, Mutex};

use crate::bitstream::anchors::{expand, read_anchors, ANCHORS_KIND};
use crate::bitstream::assemble::{assemble, scatter_sh, Piece};
use crate::bitstream::layout::Group;
use crate::bitstream::levels::Layout;
use crate::bitstream::params::{read_group_params, GroupParams};
use crate::bitstream::stream::decode_data_section;
use crate::bitstream::Container;
use crate::error::{DecodeError, SectionId};
use crate::par;
use crate::Splats;

/// SH bands are decoded in jobs of about this many channels (a band has 9, 15 or 21).
const JOB_CHANNELS: usize = 8;

/// Runs `f` on a pool of `threads` threads (0 = rayon's global pool; 1 = on the calling thread,
/// its loops sequential, [`par::one_thread`]). A pool is built the first time a thread count is
/// asked for and kept for later decodes.
pub(crate) fn in_pool<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> T {
    static POOLS: Mutex<Vec<(usize, Arc<rayon::ThreadPool>)>> = Mutex::new(Vec::new());
    let threads = threads.min(256);
    match threads {
        0 => return f(),
        1 => return par::one_thread(f),
        _ => {}
    }
    let pool = {
        let mut pools = POOLS.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
        match pools.iter().find(|(t, _)| *t == threads) {
            Some((_, p)) => Some(p.clone()),
            None => rayon::ThreadPoolBuilder::new().num_threads(threads).build().ok().map(|p| {
                let p = Arc::new(p);
                pools.push((threads, p.clone()));
                p
            }),
        }
    };
    match pool {
        Some(p) => p.install(f),
        None => f(), // no threads could be started: decode on the global pool
    }
}

/// Decodes the groups up to SH degree `degree` of a checked container into `out` (unchanged on
/// error): its layout (SPEC §3.1), then [`decode_chunks`] of every chunk.
pub(crate) fn decode_container(c: &Container<'_>, degree: u8, out: &mut Splats) -> Result<(), DecodeError> {
    if c.header.is_anchor() {
        return decode_anchors(c, degree, out);
    }
    let layout = c.layout()?;
    decode_chunks(c, &layout, layout.chunks(), degree, out)
}

/// Decodes an anchor-profile file (SPEC §12) into `out` (unchanged on error): its anchor
/// section, then the MLP's Gaussians.
fn decode_anchors(c: &Container<'_>, degree: u8, out: &mut Splats) -> Result<(), DecodeError> {
    let h = c.header;
    let n = h.gaussians as usize;
    if n == 0 {
        *out = Splats::new(degree);
        return Ok(());
    }
    if c.section(ANCHORS_KIND, 0).is_none() {
        return Err(c.missing(SectionId { kind: ANCHORS_KIND, chunk: 0 }, "anchors"));
    }
    let set = read_anchors(&mut c.reader(ANCHORS_KIND, 0), n, h.sh_degree)?;
    expand(&set, h.sh_degree, degree, out).map_err(|what| c.reader(ANCHORS_KIND, 0).corrupt(what))
}

/// Decodes the first `chunks` chunks of `layout` (the Gaussians they hold, in file order) with
/// the groups up to SH degree `degree` into `out` (unchanged on error). Chunk indices fit the
/// table's `u16` (at most 65,536 chunks, SPEC §3, §3.1).
///
/// One parallel job per group reads the group's parameter sections (and codebook) and then
/// decodes its data sections in nested jobs, so that a small scene pays for one hand-over to the
/// pool rather than one per phase, and one group's streams decode while another's tables are read.
pub(crate) fn decode_chunks(c: &Container<'_>, layout: &Layout, chunks: usize, degree: u8, out: &mut Splats) -> Result<(), DecodeError> {
    let ranges = &layout.chunk_ranges()[..chunks];
    let n = ranges.last().map_or(0, |r| r.end);
    if n == 0 {
        assemble(0, degree, &[], out);
        return Ok(());
    }
    // Each chunk's parameter chunk: its level's (SPEC §4).
    let levels = layout.level_ranges();
    let level_of = levels.iter().enumerate().flat_map(|(l, r)| r.clone().map(move |_| l));
    let params_of: Vec<usize> = level_of.take(chunks).map(|l| c.header.params_chunk(l)).collect();
    let params_chunks = params_of.last().map_or(0, |&p| p + 1);
    // The base groups decode straight into the scene's arrays (each chunk its run of rows); an SH
    // job decodes its channels (a codebook band: its row indices) into a buffer of its own,
    // scattered into the rows afterwards. The scene is new and replaces `out` only when every job
    // succeeded.
    let mut s = Splats::new(degree);
    s.positions = vec![[0.0; 3]; n];
    s.log_scales = vec![[0.0; 3]; n];
    s.rotations = vec![[0.0; 4]; n];
    s.opacity_logits = vec![0.0; n];
    s.sh_dc = vec![[0.0; 3]; n];
    let Splats { positions, log_scales, rotations, opacity_logits, sh_dc, sh_rest, .. } = &mut s;
    let mut base = [
        (Group::Position, by_chunk(positions.as_flattened_mut(), ranges, 3)),
        (Group::Scale, by_chunk(log_scales.as_flattened_mut(), ranges, 3)),
        (Group::Rotation, by_chunk(rotations.as_flattened_mut(), ranges, 4)),
        (Group::Opacity, by_chunk(opacity_logits, ranges, 1)),
        (Group::ShDc, by_chunk(sh_dc.as_flattened_mut(), ranges, 3)),
    ];
    let groups: Vec<(Group, Option<Vec<&mut [f32]>>)> =
        Group::present(degree).map(|g| (g, base.iter_mut().find(|(b, _)| *b == g).map(|(_, runs)| std::mem::take(runs)))).collect();
    // Per group: the group, its parameters and, for an SH band, its decoded pieces (chunk,
    // channels, values).
    type Decoded = (Group, Vec<GroupParams>, Vec<(usize, Range<usize>, Vec<f32>)>);
    let decoded: Vec<Decoded> = par::try_map(groups, |(g, runs)| {
        let params = read_group_params(c, g, params_chunks)?;
        let section = |ch: usize, channels: Range<usize>, dst: &mut [f32]| {
            let mut r = c.reader(g.data_kind(), ch as u16);
            decode_data_section(g, &params[params_of[ch]], &mut r, channels, dst)
        };
        let pieces = match runs {
            Some(runs) => {
                par::try_map(runs.into_iter().enumerate().collect(), |(ch, dst)| section(ch, 0..g.channels(), dst))?;
                Vec::new()
            }
            None => {
                // SH bands are split further into channel ranges of about JOB_CHANNELS so
                // that the work balances over the threads even for a one-chunk scene; a
                // codebook band's one job (all its channels) decodes one row index per Gaussian
                // (none for a band that shares the index of the band below: its data
                // sections are only checked to be empty).
                let codebook = params[0].codebook.is_some();
                let k = if params[0].shares_index() { 0 } else { g.channels() };
                let split = if codebook { 1 } else { k.div_ceil(JOB_CHANNELS) };
                let jobs: Vec<(usize, Range<usize>)> =
                    (0..chunks).flat_map(|ch| (0..split).map(move |i| (ch, i * k / split..(i + 1) * k / split))).collect();
                par::try_map(jobs, |(ch, channels)| {
                    // A codebook band: one index per Gaussian (a shared index: none).
                    let width = if codebook { usize::from(k > 0) } else { channels.len() };
                    let mut buf = vec![0.0; ranges[ch].len() * width];
                    section(ch, channels.clone(), &mut buf).map(|()| (ch, channels, buf))
                })?
            }
        };
        Ok::<_, DecodeError>((g, params, pieces))
    })?;
    // A band that shares the index of the band below takes the indices of the nearest band below
    // that has its own (SPEC §3.2), and looks them up in its own rows.
    let own_index = |group: Group| {
        let mut b = group.sh_band();
        while decoded.iter().any(|d| d.0.sh_band() == b && d.1[0].shares_index()) {
            b -= 1;
        }
        &decoded.iter().find(|d| d.0.sh_band() == b).expect("checked: a shared index has a band below with a codebook").2
    };
    let pieces: Vec<Piece> = decoded
        .iter()
        .flat_map(|&(group, ref params, ref pieces)| {
            let codebook = params[0].codebook.as_deref().map(|cb| &cb.values[..]);
            let pieces = if params[0].shares_index() { own_index(group) } else { pieces };
            pieces.iter().map(move |(ch, columns, values)| Piece {
                group,
                first: ranges[*ch].start,
                columns: if codebook.is_some() { 0..group.channels() } else { columns.clone() },
                values,
                codebook,
            })
        })
        .collect();
    scatter_sh(n, degree, &pieces, sh_rest);
    *out = s;
    Ok(())
}

/// `values` (`width` values per Gaussian) cut into the runs of rows of the chunks `ranges`.
fn by_chunk<'a>(mut values: &'a mut [f32], ranges: &[Range<usize>], width: usize) -> Vec<&'a mut [f32]> {
    ranges
        .iter()
        .map(|r| {
            let (run, rest) = std::mem::take(&mut values).split_at_mut(r.len() * width);
            values = rest;
            run
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// One thread decodes on the caller, its loops sequential; more go to a pool of their own.
    #[test]
    fn a_one_thread_decode_stays_on_the_calling_thread() {
        let me = std::thread::current().id();
        assert_eq!(in_pool(1, || (std::thread::current().id(), par::sequential())), (me, true));
        assert!(!par::sequential());
        let (on, threads, sequential) = in_pool(3, || (std::thread::current().id(), rayon::current_num_threads(), par::sequential()));
        assert_ne!(on, me);
        assert_eq!((threads, sequential), (3, false));
    }
}

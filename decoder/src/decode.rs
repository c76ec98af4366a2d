//! The decoding core behind [`crate::Decoder`]: a checked container to a scene — parameter
//! sections, then the (group, chunk, channel range) jobs in parallel, then the assembler.

use std::ops::Range;
use std::sync::{Arc, Mutex};

use rayon::prelude::*;

use crate::bitstream::assemble::{assemble, Piece};
use crate::bitstream::layout::Group;
use crate::bitstream::levels::Layout;
use crate::bitstream::params::read_all_params;
use crate::bitstream::stream::decode_data_section;
use crate::bitstream::Container;
use crate::error::DecodeError;
use crate::Splats;

/// SH bands are decoded in jobs of about this many channels (a band has 9, 15 or 21).
const JOB_CHANNELS: usize = 8;

/// Runs `f` on a pool of `threads` threads (0 = rayon's global pool). A pool is built
/// the first time a thread count is asked for and kept for later decodes.
pub(crate) fn in_pool<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> T {
    static POOLS: Mutex<Vec<(usize, Arc<rayon::ThreadPool>)>> = Mutex::new(Vec::new());
    let threads = threads.min(256);
    if threads == 0 {
        return f();
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
    let layout = c.layout()?;
    decode_chunks(c, &layout, layout.chunks(), degree, out)
}

/// Decodes the first `chunks` chunks of `layout` (the Gaussians they hold, in file order) with
/// the groups up to SH degree `degree` into `out` (unchanged on error). Chunk indices fit the
/// table's `u16` (at most 65,536 chunks, SPEC §3, §3.1).
pub(crate) fn decode_chunks(c: &Container<'_>, layout: &Layout, chunks: usize, degree: u8, out: &mut Splats) -> Result<(), DecodeError> {
    let ranges = &layout.chunk_ranges()[..chunks];
    let n = ranges.last().map_or(0, |r| r.end);
    if n == 0 {
        assemble(0, degree, &[], out);
        return Ok(());
    }
    // The level of each chunk: its data sections use that level's parameters (SPEC §4).
    let level_of: Vec<usize> = layout.level_ranges().iter().enumerate().flat_map(|(l, r)| r.clone().map(move |_| l)).take(chunks).collect();
    let params = read_all_params(c, degree, level_of.last().map_or(0, |l| l + 1))?;
    // One job per (group, chunk); SH bands are split further into channel ranges of about
    // JOB_CHANNELS so that the work balances over the threads even for a one-chunk scene.
    let mut jobs: Vec<(usize, usize, Range<usize>)> = Vec::new();
    for ch in 0..chunks {
        for (gi, (g, p)) in params.of_level(level_of[ch]).iter().enumerate() {
            let c = g.channels();
            let pieces = if g.sh_band() > 0 && p.codebook.is_none() { c.div_ceil(JOB_CHANNELS) } else { 1 };
            jobs.extend((0..pieces).map(|i| (gi, ch, i * c / pieces..(i + 1) * c / pieces)));
        }
    }
    let results: Vec<Vec<f32>> = jobs
        .par_iter()
        .map(|(gi, ch, channels)| {
            let (g, p) = &params.of_level(level_of[*ch])[*gi];
            decode_data_section(*g, p, &mut c.reader(g.data_kind(), *ch as u16), ranges[*ch].len(), channels.clone())
        })
        .collect::<Result<_, _>>()?;
    let pieces: Vec<Piece> = jobs
        .iter()
        .zip(&results)
        .map(|((gi, ch, channels), values)| {
            let group = params.of_level(level_of[*ch])[*gi].0;
            let columns = match group {
                Group::Position => 0..3,
                Group::Rotation => 0..4,
                _ => channels.clone(),
            };
            Piece { group, first: ranges[*ch].start, columns, values }
        })
        .collect();
    assemble(n, degree, &pieces, out);
    Ok(())
}

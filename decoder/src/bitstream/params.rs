//! Parameter sections (SPEC §4): per group, the dequantisation steps and one channel table per
//! channel; for positions, the grid and the table of Morton-delta lengths. And the codebook
//! sections of SH bands coded by vector quantisation (SPEC §3.2): the band's rows, coded like a
//! parameter section and a data section of K "Gaussians", and then the band's parameter section
//! holds one channel, the row index.

use std::sync::Arc;

use rayon::prelude::*;

use super::header::Header;
use super::layout::{Group, MAX_CODEBOOK_ROWS, MAX_POSITION_BITS};
use super::sections::Container;
use super::tables::ChannelTable;
use super::{ByteReader, ByteWriter};
use crate::error::{DecodeError, SectionId};

/// The position grid: origin and step per axis, and bits per axis (SPEC §4, §6.1).
pub type Grid = ([f32; 3], [f32; 3], u8);

/// The parsed parameter section of one group.
#[derive(Debug, Clone, PartialEq)]
pub struct GroupParams {
    /// Per channel dequantisation step (position: empty).
    pub steps: Vec<f32>,
    /// One table per channel (position: the length table).
    pub tables: Vec<ChannelTable>,
    /// Position only: the grid.
    pub grid: Option<Grid>,
    /// SH bands coded by vector quantisation (SPEC §3.2): the codebook (one per band, shared by
    /// the parameter sections of every level); `steps` and `tables` then hold the one index
    /// channel.
    pub codebook: Option<Arc<Codebook>>,
}

impl GroupParams {
    /// Whether this SH band shares the row index of the band below (SPEC §3.2, format 9): a
    /// band with a codebook whose parameter section holds no channel, so its data sections hold
    /// no stream.
    pub fn shares_index(&self) -> bool {
        self.codebook.is_some() && self.tables.is_empty()
    }
}

/// A decoded codebook (SPEC §3.2): `rows` rows of the band's channels, dequantised, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct Codebook {
    /// Rows K.
    pub rows: usize,
    /// `K × channels` dequantised values.
    pub values: Vec<f32>,
}

/// `u8 C` (which must be `channels`), then C × (f32 step, channel table) (SPEC §4). Tables of
/// mode 3 only with `neighbours` (a file of format 8, SPEC §4.3), and never with thresholds on
/// the value below for channel 0.
pub(crate) fn read_channel_tables(
    r: &mut ByteReader<'_>,
    channels: usize,
    p: &mut GroupParams,
    neighbours: bool,
) -> Result<(), DecodeError> {
    let at = r.place();
    let n = r.u8("channel count")? as usize;
    if n != channels {
        return Err(at.corrupt("wrong channel count"));
    }
    for j in 0..n {
        p.steps.push(r.f32("channel step")?);
        let at = r.place();
        let t = ChannelTable::read(r)?;
        if let ChannelTable::Neighbour(nb) = &t {
            if !neighbours {
                return Err(at.corrupt("neighbour-context table before format 8.0"));
            }
            if j == 0 && nb.uses_lower() {
                return Err(at.corrupt("channel 0 with thresholds on a channel below"));
            }
        }
        p.tables.push(t);
    }
    Ok(())
}

/// Reads the codebook section of SH group `g` in a file of `n` Gaussians (SPEC §3.2): `varint K`
/// (1 ≤ K ≤ min(N, 65536)), the codebook's channel tables as a parameter section, then its K
/// rows as the streams of a data section; it must be consumed exactly. The rows are
/// dequantised with the codebook's steps (SPEC §8) and must be finite.
pub fn read_codebook(g: Group, r: &mut ByteReader<'_>, n: usize, neighbours: bool) -> Result<Codebook, DecodeError> {
    let at = r.place();
    let k = r.varint("codebook rows")? as usize;
    if k == 0 || k > MAX_CODEBOOK_ROWS || k > n {
        return Err(at.corrupt("codebook rows outside 1..=min(N, 65536)"));
    }
    let mut p = GroupParams { steps: Vec::new(), tables: Vec::new(), grid: None, codebook: None };
    read_channel_tables(r, g.channels(), &mut p, neighbours)?;
    let mut values = vec![0.0; k * g.channels()];
    super::stream::decode_channels(&p, r, &p.steps, 0..g.channels(), &mut values)?;
    if r.remaining() != 0 {
        return Err(r.corrupt("trailing bytes in a codebook section"));
    }
    Ok(Codebook { rows: k, values })
}

/// Writes a codebook section: `varint K`, the codebook's parameter section
/// ([`write_channel_params`]) and its data section ([`super::stream::write_channel_streams`]).
pub fn write_codebook(rows: usize, params: &[u8], streams: &[u8]) -> Vec<u8> {
    let mut w = ByteWriter::new();
    w.varint(rows as u32);
    w.bytes(params);
    w.bytes(streams);
    w.buf
}

/// Reads the parameter section of group `g`; it must be consumed exactly. With `codebook` (an SH
/// band coded by vector quantisation, SPEC §3.2) it holds one channel, the row index, whose
/// step is ignored, or — with `shared`, a band above 1 in a file of format 9 — no channel (the
/// band shares the index of the band below, [`GroupParams::shares_index`]). `neighbours`:
/// mode-3 tables are allowed (formats 8 and 9).
pub fn read_params(
    g: Group,
    r: &mut ByteReader<'_>,
    codebook: Option<Arc<Codebook>>,
    neighbours: bool,
    shared: bool,
) -> Result<GroupParams, DecodeError> {
    let channels = if codebook.is_some() { 1 } else { g.channels() };
    let shares = shared && codebook.is_some() && r.clone().u8("channel count").is_ok_and(|c| c == 0);
    let mut p = GroupParams { steps: Vec::new(), tables: Vec::new(), grid: None, codebook };
    if g == Group::Position {
        p = read_position_params(r)?;
    } else if shares {
        r.u8("channel count")?;
    } else {
        read_channel_tables(r, channels, &mut p, neighbours)?;
    }
    if r.remaining() != 0 {
        return Err(r.corrupt("trailing bytes in a parameter section"));
    }
    Ok(p)
}

/// The position grid and length table (SPEC §4, g = 0), read up to the table's end (the caller
/// checks what follows).
pub(crate) fn read_position_params(r: &mut ByteReader<'_>) -> Result<GroupParams, DecodeError> {
    let origin = [r.f32("grid origin")?, r.f32("grid origin")?, r.f32("grid origin")?];
    let step = [r.f32("grid step")?, r.f32("grid step")?, r.f32("grid step")?];
    let at = r.place();
    let bits = r.u8("grid bits")?;
    if bits > MAX_POSITION_BITS {
        return Err(at.corrupt("position grid above 21 bits per axis"));
    }
    let at = r.place();
    let lengths = ChannelTable::read(r)?;
    if !matches!(lengths, ChannelTable::Constant(_) | ChannelTable::Coded { .. }) {
        return Err(at.corrupt("context-coded position lengths"));
    }
    Ok(GroupParams { steps: Vec::new(), tables: vec![lengths], grid: Some((origin, step, bits)), codebook: None })
}

/// Writes the position parameter section: the grid, then the serialised length table.
pub fn write_position_params(grid: &Grid, length_table: &[u8]) -> Vec<u8> {
    let mut w = ByteWriter::new();
    let (origin, step, bits) = grid;
    origin.iter().for_each(|&v| w.f32(v));
    step.iter().for_each(|&v| w.f32(v));
    w.u8(*bits);
    w.bytes(length_table);
    w.buf
}

/// Writes the parameter section of a group other than position: the channel count, then per
/// channel its step and serialised table.
pub fn write_channel_params<'t>(steps: &[f32], tables: impl ExactSizeIterator<Item = &'t [u8]>) -> Vec<u8> {
    let mut w = ByteWriter::new();
    w.u8(tables.len() as u8);
    for (s, t) in steps.iter().zip(tables) {
        w.f32(*s);
        w.bytes(t);
    }
    w.buf
}

/// The parameter sections of a file's first levels: one set per parameter chunk (SPEC §4: before
/// 6.0 one set, chunk 0, for every level; in 6.0 one per level).
#[derive(Debug, Clone, PartialEq)]
pub struct ParamSets {
    /// Per parameter chunk, the present groups' parameters in group order.
    pub sets: Vec<Vec<(Group, GroupParams)>>,
    header: Header,
}

impl ParamSets {
    /// The parameters level `level`'s data sections are decoded with.
    pub fn of_level(&self, level: usize) -> &[(Group, GroupParams)] {
        &self.sets[self.header.params_chunk(level)]
    }
}

/// The parameter sections of the groups present up to SH degree `degree` for the first `levels`
/// levels (none for N = 0), with the codebooks of the SH bands that have one (read once, shared by
/// every level), read in parallel; a missing one is an error.
pub fn read_all_params(c: &Container<'_>, degree: u8, levels: usize) -> Result<ParamSets, DecodeError> {
    let header = c.header;
    if header.gaussians == 0 {
        return Ok(ParamSets { sets: Vec::new(), header });
    }
    let groups: Vec<Group> = Group::present(degree).collect();
    // The parameter chunks those levels use: 0 … that of the last level.
    let chunks = levels.checked_sub(1).map_or(0, |l| header.params_chunk(l) + 1);
    let read = groups.par_iter().map(|&g| read_group_params(c, g, chunks)).collect::<Result<Vec<_>, DecodeError>>()?;
    // Group-major to chunk-major.
    let mut read: Vec<_> = read.into_iter().map(Vec::into_iter).collect();
    let sets = (0..chunks).map(|_| groups.iter().zip(&mut read).filter_map(|(&g, p)| Some((g, p.next()?))).collect()).collect();
    Ok(ParamSets { sets, header })
}

/// Group `g`'s parameter sections `0..chunks`, read in parallel, each with the group's codebook
/// when it has one (read first); a missing section is an error.
pub fn read_group_params(c: &Container<'_>, g: Group, chunks: usize) -> Result<Vec<GroupParams>, DecodeError> {
    let header = c.header;
    let codebook = match c.codebook(g)? {
        Some(mut r) => Some(Arc::new(read_codebook(g, &mut r, header.gaussians as usize, header.has_neighbours())?)),
        None => None,
    };
    let shared = header.has_shared_index() && g.sh_band() >= 2;
    let read = |chunk: u16| {
        if c.section(g.params_kind(), chunk).is_none() {
            return Err(c.missing(SectionId { kind: g.params_kind(), chunk }, g.params_name()));
        }
        read_params(g, &mut c.reader(g.params_kind(), chunk), codebook.clone(), header.has_neighbours(), shared)
    };
    let params: Vec<GroupParams> = crate::par::try_map((0..chunks as u16).collect(), read)?;
    // A band that shares the index of the band below does so in every level, and the band
    // below has a codebook of as many rows (SPEC §3.2).
    if let Some(cb) = params.iter().find(|p| p.shares_index()).and_then(|p| p.codebook.as_ref()) {
        if let Some(l) = params.iter().position(|p| !p.shares_index()) {
            return Err(c.reader(g.params_kind(), l as u16).corrupt("a band that shares the index of the band below in some levels only"));
        }
        let below = match c.codebook(Group::for_band(g.sh_band() - 1))? {
            Some(mut r) => r.varint("codebook rows")? as usize,
            None => 0,
        };
        if below != cb.rows {
            return Err(c.reader(g.params_kind(), 0).corrupt("a shared row index whose band below has no codebook of as many rows"));
        }
    }
    Ok(params)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn written_params_read_back() {
        let mut t = ByteWriter::new();
        ChannelTable::write_coded(&mut t, 0, &[3, 1, 1]);
        let grid = ([1.0, -2.0, 0.5], [0.25, 0.25, 0.125], 7);
        let bytes = write_position_params(&grid, &t.buf);
        let p = read_params(Group::Position, &mut ByteReader::new(&bytes), None, false, false).unwrap();
        assert_eq!(p.grid, Some(grid));
        assert_eq!(p.tables.len(), 1);
        let mut c = ByteWriter::new();
        ChannelTable::write_constant(&mut c, 4);
        let bytes = write_channel_params(&[0.5, 0.25, -1.0], [&c.buf[..], &t.buf, &c.buf].into_iter());
        let p = read_params(Group::Scale, &mut ByteReader::new(&bytes), None, false, false).unwrap();
        assert_eq!((p.steps, p.tables[0].clone()), (vec![0.5, 0.25, -1.0], ChannelTable::Constant(4)));
        // Scale has 3 channels, not 1; and a parameter section must be consumed exactly.
        assert_eq!(read_params(Group::Opacity, &mut ByteReader::new(&bytes), None, false, false).unwrap_err().class(), "format");
        let mut longer = bytes.clone();
        longer.push(0);
        assert_eq!(read_params(Group::Scale, &mut ByteReader::new(&longer), None, false, false).unwrap_err().class(), "format");
    }
}

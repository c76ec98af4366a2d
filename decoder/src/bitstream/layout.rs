//! What the sections of a `.gsc` file hold (SPEC §3): attribute groups, their channels and
//! section kinds, and chunking.

/// Most Gaussians of a chunk (each (group, chunk) is an independent stream): every chunk of a
/// 3.0 file but the last has this many; a 4.0 file lists its chunk sizes (SPEC §3.1).
pub const CHUNK: usize = 1 << 16;
/// Largest position grid resolution in bits per axis (3 × 21 = 63-bit Morton codes).
pub const MAX_POSITION_BITS: u8 = 21;

/// An attribute group: one parameter section and one data stream per chunk.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Group {
    /// Positions on a grid, Morton-ordered (one length channel plus raw bits).
    Position = 0,
    /// Log standard deviations x y z.
    Scale = 1,
    /// Rotation in smallest-three form (index of the largest component, three others).
    Rotation = 2,
    /// Opacity logit.
    Opacity = 3,
    /// SH DC colour r g b.
    ShDc = 4,
    /// SH band 1 (3 coefficients × 3 colours).
    Sh1 = 5,
    /// SH band 2 (5 × 3).
    Sh2 = 6,
    /// SH band 3 (7 × 3).
    Sh3 = 7,
}

impl Group {
    /// Every group, in group-index order.
    pub const ALL: [Group; 8] =
        [Group::Position, Group::Scale, Group::Rotation, Group::Opacity, Group::ShDc, Group::Sh1, Group::Sh2, Group::Sh3];

    /// Section kind of this group's parameter (tables + steps) section.
    pub fn params_kind(self) -> u16 {
        0x10 + self as u16
    }

    /// Section kind of this group's per-chunk data streams.
    pub fn data_kind(self) -> u16 {
        0x20 + self as u16
    }

    /// The group's name as SPEC §3 spells it (`position`, …, `sh_band3`).
    pub fn name(self) -> &'static str {
        ["position", "scale", "rotation", "opacity", "sh_dc", "sh_band1", "sh_band2", "sh_band3"][self as usize]
    }

    /// The name of the group's parameter section, e.g. `scale parameters`.
    pub fn params_name(self) -> &'static str {
        [
            "position parameters",
            "scale parameters",
            "rotation parameters",
            "opacity parameters",
            "sh_dc parameters",
            "sh_band1 parameters",
            "sh_band2 parameters",
            "sh_band3 parameters",
        ][self as usize]
    }

    /// SH band of an SH-rest group (1..=3); 0 for the others.
    pub fn sh_band(self) -> u8 {
        match self {
            Group::Sh1 => 1,
            Group::Sh2 => 2,
            Group::Sh3 => 3,
            _ => 0,
        }
    }

    /// The group holding SH band `b` (1..=3).
    pub fn for_band(b: u8) -> Group {
        [Group::Sh1, Group::Sh2, Group::Sh3][b as usize - 1]
    }

    /// Channels coded per Gaussian (for Position: the one Morton-delta length channel).
    pub fn channels(self) -> usize {
        match self {
            Group::Position => 1,
            Group::Scale | Group::ShDc => 3,
            Group::Rotation => 4,
            Group::Opacity => 1,
            Group::Sh1 => 9,
            Group::Sh2 => 15,
            Group::Sh3 => 21,
        }
    }

    /// The group whose parameter or data sections have `kind`, if any.
    pub fn of_kind(kind: u16) -> Option<Group> {
        Group::ALL.into_iter().find(|g| g.params_kind() == kind || g.data_kind() == kind)
    }

    /// Groups present in a file of SH degree `d`.
    pub fn present(d: u8) -> impl Iterator<Item = Group> {
        Group::ALL.into_iter().filter(move |g| g.sh_band() <= d)
    }
}

/// Required section of a 4.0 file with N > 0: the chunk sizes and levels (SPEC §3.1,
/// [`super::levels::Layout`]).
pub const LEVELS_KIND: u16 = 0x01;
/// Section of a 5.0 file, chunk = SH band 1..=3: that band's codebook (SPEC §3.2,
/// [`super::params::read_codebook`]).
pub const CODEBOOK_KIND: u16 = 0x02;
/// Most rows of a codebook (SPEC §3.2).
pub const MAX_CODEBOOK_ROWS: usize = 1 << 16;
/// Optional section: encoder information (`u32` Gaussians before pruning, `u8` SH degree of the input).
pub const INFO_KIND: u16 = 0x100;
/// Optional section: padding (ignored).
pub const PADDING_KIND: u16 = 0x101;

/// Number of chunks for `n` Gaussians in a 3.0 file.
pub fn chunk_count(n: usize) -> usize {
    n.div_ceil(CHUNK)
}

//! Quantisation: a scene to integer channels (positions on a Morton-ordered grid fitted to the
//! bounds, smallest-three rotations, per-channel uniform steps) and back.

use gscodec_decoder::bitstream::assemble::{assemble, dequantise_channels, Piece};
use gscodec_decoder::bitstream::layout::{Group, MAX_POSITION_BITS};
use gscodec_decoder::bitstream::levels::Layout;
use gscodec_decoder::bitstream::params::Grid;
use gscodec_decoder::bitstream::positions::{morton_encode, position_of};
use gscodec_decoder::math::{sigmoid, MAX_ALPHA};
use gscodec_decoder::Splats;

use super::group::{layout, values, values_mut};
use super::CoarseTail;

/// Step sizes (quantisation bins) of every stored attribute.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Steps {
    /// Position grid bits per axis; `None` = chosen from the scene (see [`position_bits`]).
    pub position_bits: Option<u8>,
    /// Largest position step, relative to the 10th-percentile Gaussian size, when bits are automatic.
    pub position_rel: f32,
    pub scale: f32,
    pub rotation: f32,
    pub opacity: f32,
    pub sh_dc: f32,
    /// Per SH band 1..=3.
    pub sh_rest: [f32; 3],
    /// Dead zone of the SH rest quantiser, in steps (0 = plain rounding, < 0.5): a value is
    /// rounded as `sign(v)·⌊|v|/s + ½ − deadzone⌋`, so small coefficients go to zero. An
    /// encoder-only choice (the decoder sees integers); it lowers the entropy of the Laplacian
    /// SH coefficients for a small distortion cost, and the RD search picks it.
    pub rest_deadzone: f32,
}

impl Default for Steps {
    fn default() -> Self {
        Steps {
            position_bits: None,
            position_rel: 0.15,
            scale: 0.04,
            rotation: 0.006,
            opacity: 0.08,
            sh_dc: 0.01,
            sh_rest: [0.03, 0.04, 0.05],
            rest_deadzone: 0.0,
        }
    }
}

impl Steps {
    /// All steps multiplied by `m` (coarser for `m > 1`).
    pub fn scaled(&self, m: f32) -> Steps {
        Steps {
            position_bits: self.position_bits,
            position_rel: self.position_rel * m,
            scale: self.scale * m,
            rotation: self.rotation * m,
            opacity: self.opacity * m,
            sh_dc: self.sh_dc * m,
            sh_rest: self.sh_rest.map(|s| s * m),
            rest_deadzone: self.rest_deadzone,
        }
    }
}

/// A scene in quantised form, Gaussians in file order (by level, then Morton order within each
/// level): exactly what the file holds.
#[derive(Debug, Clone, PartialEq)]
pub struct Quantised {
    pub sh_degree: u8,
    /// Grid origin, step and bits per axis.
    pub grid: ([f32; 3], [f32; 3], u8),
    /// Gaussians of each importance level (SPEC §3.1), in file order; empty for a file without
    /// levels (format 3.0: one level).
    pub levels: Vec<usize>,
    /// Morton codes of the grid positions, sorted within each level.
    pub morton: Vec<u64>,
    /// For every group except Position: dequantisation steps and channel values (`[channel][gaussian]`).
    /// An SH band with a codebook holds the rows its codebook restores.
    pub groups: Vec<(Group, Vec<f32>, Vec<Vec<i32>>)>,
    /// SH bands coded by vector quantisation (SPEC §3.2, format 5.0): the band's codebook, whose
    /// rows at its indices are the band's channels in [`Quantised::groups`].
    pub codebooks: Vec<(Group, super::vq::Codebook)>,
    /// The SH bands above 1 share band 1's row index (one joint codebook split by band, SPEC
    /// §3.2, format 9.0): their codebooks have band 1's K and its index.
    pub shared_index: bool,
    /// Importance classes (SPEC §4, format 6.0: each level has its own parameter sections): per
    /// level, the factor its steps are [`Quantised::groups`]' steps multiplied by
    /// ([`Quantised::level_steps`]). Empty: every level uses those steps, and the file has one
    /// set of parameter sections.
    pub level_factors: Vec<f32>,
    /// Per group, the multiplier of a level factor other than 1 ([`super::CoarseTail::groups`]).
    pub tail_groups: [f32; 8],
    /// Per level, its position grid ([`quantise_coarser_grids`]; [`Quantised::level_grid`]);
    /// empty: [`Quantised::grid`] for every level.
    pub level_grids: Vec<Grid>,
}

impl Quantised {
    pub fn len(&self) -> usize {
        self.morton.len()
    }

    pub fn is_empty(&self) -> bool {
        self.morton.is_empty()
    }

    /// The Gaussians of each level, in file order (one level of all of them without levels).
    pub fn level_ranges(&self) -> Vec<std::ops::Range<usize>> {
        let sizes = if self.levels.is_empty() { vec![self.len()] } else { self.levels.clone() };
        let mut start = 0;
        sizes
            .into_iter()
            .map(|k| {
                start += k;
                start - k..start
            })
            .collect()
    }

    /// The position grid of level `level`.
    pub fn level_grid(&self, level: usize) -> Grid {
        self.level_grids.get(level).copied().unwrap_or(self.grid)
    }

    /// The steps of group `gi` (an index into [`Quantised::groups`]) in level `level`: the
    /// group's steps times the level's factor (and the group's multiplier of it,
    /// [`super::CoarseTail::group_factor`]), except the rotation index (step 1) and an SH band
    /// coded by a codebook, whose rows are shared by every level.
    pub fn level_steps(&self, gi: usize, level: usize) -> Vec<f32> {
        let (g, steps, _) = &self.groups[gi];
        let f = CoarseTail::group_factor(&self.tail_groups, *g, self.level_factors.get(level).copied().unwrap_or(1.0));
        if f == 1.0 || self.codebooks.iter().any(|c| c.0 == *g) {
            return steps.clone();
        }
        let scaled = |(c, &s): (usize, &f32)| if *g == Group::Rotation && c == 0 { s } else { s * f };
        steps.iter().enumerate().map(scaled).collect()
    }

    /// Per Gaussian (file order), its level's factor ([`Quantised::level_factors`]; 1 without
    /// importance classes), before a group's multiplier ([`Quantised::tail_groups`]).
    pub fn row_factors(&self) -> Vec<f32> {
        let ranges = self.level_ranges();
        ranges
            .iter()
            .enumerate()
            .flat_map(|(l, r)| std::iter::repeat_n(self.level_factors.get(l).copied().unwrap_or(1.0), r.len()))
            .collect()
    }

    /// The file's chunks and levels.
    pub fn layout(&self) -> Layout {
        if self.levels.is_empty() {
            Layout::uniform(self.len())
        } else {
            Layout::from_levels(&self.levels)
        }
    }
}

/// Chooses grid bits so the step is at most `rel` × the 10th-percentile Gaussian size
/// (largest axis), at most 21 bits.
pub fn position_bits(splats: &Splats, rel: f32) -> u8 {
    let Some((lo, hi)) = splats.bounds() else { return 0 };
    let extent = (0..3).map(|a| f64::from(hi[a]) - f64::from(lo[a])).fold(0.0, f64::max);
    if extent <= 0.0 {
        return 0;
    }
    let mut sizes: Vec<f32> = splats.log_scales.iter().map(|s| s[0].max(s[1]).max(s[2]).exp()).collect();
    sizes.sort_by(f32::total_cmp);
    let reference = f64::from(sizes[sizes.len() / 10]).max(extent * 1e-7);
    let step = reference * f64::from(rel);
    let bits = ((extent / step) + 1.0).log2().ceil();
    bits.clamp(1.0, f64::from(MAX_POSITION_BITS)) as u8
}

fn q(v: f32, step: f32) -> i32 {
    // `as` saturates: no wrap-around for any value.
    (v / step).round() as i32
}

/// Dead-zone quantiser (see [`Steps::rest_deadzone`]); `dz = 0` is [`q`]. Training renders
/// the SH rest bands through it ([`super::term::RateTerm::render_params`]).
pub(crate) fn q_dz(v: f32, step: f32, dz: f32) -> i32 {
    if dz <= 0.0 {
        return q(v, step);
    }
    let t = (v / step).abs() + 0.5 - dz;
    (t.floor().max(0.0) * v.signum()) as i32
}

/// Quantises `splats` (already pruned and validated) with `steps`, reordering to Morton order.
/// With `level` (one entry per Gaussian, e.g. [`super::importance::levels`]), Gaussians are
/// ordered by level first and [`Quantised::levels`] holds the level sizes; empty = one level.
pub fn quantise(splats: &Splats, steps: &Steps, level: &[u8]) -> Quantised {
    quantise_ordered(splats, steps, level).0
}

/// [`quantise`], with the file order: Gaussian `i` of the result is `splats`' Gaussian `order[i]`.
pub fn quantise_ordered(splats: &Splats, steps: &Steps, level: &[u8]) -> (Quantised, Vec<usize>) {
    quantise_coarser_grids(splats, steps, level, &[])
}

/// The position grid of `bits` bits per axis over the bounds `lo..hi`: (origin, step, bits).
pub(crate) fn grid(lo: [f32; 3], hi: [f32; 3], bits: u8) -> Grid {
    let cells = ((1u64 << bits) - 1) as f64;
    let mut step = [1.0f32; 3];
    for a in 0..3 {
        let ext = f64::from(hi[a]) - f64::from(lo[a]);
        if ext > 0.0 && bits > 0 {
            // Round the step up so the far corner stays inside the grid after f32 rounding.
            step[a] = ((ext / cells) * (1.0 + 1e-6)) as f32;
        }
    }
    (lo, step, bits)
}

/// [`quantise_ordered`] with the positions of level value `l` on a grid of `coarser[l]` fewer
/// bits per axis (importance classes, SPEC §4: each level has its own position grid; missing
/// entries are 0). [`Quantised::level_grids`] then holds each level's grid.
pub fn quantise_coarser_grids(splats: &Splats, steps: &Steps, level: &[u8], coarser: &[u8]) -> (Quantised, Vec<usize>) {
    let Quantisation { q, order, .. } = quantise_classes(splats, steps, level, &Classes { coarser, ..Classes::NONE });
    (q, order)
}

/// How [`quantise_classes`] quantises the Gaussians' levels and groups.
pub struct Classes<'a> {
    /// Per level value, how many fewer position bits its grid has (missing entries are 0).
    pub coarser: &'a [u8],
    /// Importance classes (SPEC §4, format 6.0): per level value, the factor its steps are
    /// the base steps multiplied by (position excepted: it has its grids). `None`: one set of
    /// steps for every level.
    pub factors: Option<&'a [f32]>,
    /// Per group, the multiplier of a factor other than 1 ([`super::CoarseTail::groups`]).
    pub groups: [f32; 8],
    /// The groups quantised with the base steps whatever `factors` say: the SH bands to be
    /// coded by codebooks ([`apply_codebooks`]: their rows are shared by every level).
    pub at_base: &'a dyn Fn(Group) -> bool,
    /// The groups whose values before rounding [`Quantisation::targets`] returns.
    pub targets: &'a [Group],
}

impl Classes<'_> {
    /// No coarser grids, no step factors, no targets.
    pub const NONE: Classes<'static> = Classes { coarser: &[], factors: None, groups: [1.0; 8], at_base: &|_| false, targets: &[] };
}

/// What [`quantise_classes`] makes: the quantised scene, its file order (`q`'s Gaussian `j` is
/// the scene's Gaussian `order[j]`) and the values before rounding of the groups asked for.
pub struct Quantisation {
    pub q: Quantised,
    pub order: Vec<usize>,
    /// Per group asked for and present, its channels in steps before rounding ([`group_targets`]
    /// with the steps each row is rounded with), file order.
    pub targets: Vec<(Group, Vec<Vec<f32>>)>,
}

/// Quantises `splats` (already pruned and validated) with `steps`: positions on each level's
/// grid in Morton order within each level ([`quantise_ordered`], `level` as there), every other
/// group rounded to nearest (SH rest bands with their dead zone) with the steps of `classes`.
/// The SH bands whose coefficients all round to zero at the base steps are left out.
pub fn quantise_classes(splats: &Splats, steps: &Steps, level: &[u8], classes: &Classes) -> Quantisation {
    let n = splats.len();
    let bits = steps.position_bits.unwrap_or_else(|| position_bits(splats, steps.position_rel)).min(MAX_POSITION_BITS);
    let (lo, hi) = splats.bounds().unwrap_or(([0.0; 3], [0.0; 3]));
    let base = grid(lo, hi, bits);
    let grids: Vec<Grid> = (0..=level.iter().copied().max().unwrap_or(0))
        .map(|l| classes.coarser.get(usize::from(l)).map_or(base, |&c| grid(lo, hi, bits.saturating_sub(c))))
        .collect();
    let level_of = |i: usize| level.get(i).copied().unwrap_or(0);
    let mut keyed: Vec<(u8, u64, usize)> = (0..n)
        .map(|i| {
            let (origin, step, bits) = grids[usize::from(level_of(i))];
            let max_q = (1u64 << bits) - 1;
            let qs: [u32; 3] = std::array::from_fn(|a| {
                let t = (f64::from(splats.positions[i][a]) - f64::from(origin[a])) / f64::from(step[a]);
                t.round().clamp(0.0, max_q as f64) as u32
            });
            (level_of(i), morton_encode(qs, bits), i)
        })
        .collect();
    keyed.sort_unstable();
    let order: Vec<usize> = keyed.iter().map(|&(_, _, i)| i).collect();
    let mut levels = Vec::new();
    if !level.is_empty() {
        for &(l, ..) in &keyed {
            levels.resize(levels.len().max(l as usize + 1), 0);
            levels[l as usize] += 1;
        }
    }
    // The grids of the levels that have Gaussians, in order (none without coarser grids).
    let level_grids = if classes.coarser.iter().any(|&c| c > 0) {
        (0..levels.len()).filter(|&l| levels[l] > 0).map(|l| grids[l]).collect()
    } else {
        Vec::new()
    };
    // The step factors of the levels that have Gaussians, and of each file row.
    let level_factors: Vec<f32> =
        classes.factors.map_or(Vec::new(), |f| levels.iter().enumerate().filter(|x| *x.1 > 0).map(|(l, _)| f[l]).collect());
    let row_factor: Vec<f32> = classes.factors.map_or(Vec::new(), |f| keyed.iter().map(|&(l, ..)| f[usize::from(l)]).collect());
    levels.retain(|&k| k > 0);

    // Leave out SH bands whose coefficients all quantise to zero.
    let mut sh_degree = splats.sh_degree;
    while sh_degree > 0 && band_rounds_to_zero(splats, sh_degree, steps) {
        sh_degree -= 1;
    }
    let mut targets = Vec::new();
    let groups = Group::present(sh_degree)
        .skip(1)
        .map(|g| {
            let factor = |j: usize| {
                if row_factor.is_empty() || (classes.at_base)(g) {
                    1.0
                } else {
                    CoarseTail::group_factor(&classes.groups, g, row_factor[j])
                }
            };
            let t = group_targets(splats, &order, g, steps, &factor);
            let values = rounded(g, &t, steps.rest_deadzone);
            if classes.targets.contains(&g) {
                targets.push((g, t));
            }
            (g, group_steps(g, steps), values)
        })
        .collect();
    let q = Quantised {
        sh_degree,
        grid: base,
        levels,
        morton: keyed.iter().map(|&(_, m, _)| m).collect(),
        groups,
        codebooks: Vec::new(),
        shared_index: false,
        level_factors,
        tail_groups: classes.groups,
        level_grids,
    };
    Quantisation { q, order, targets }
}

/// Whether every coefficient of SH band `band` (1..=3) of `splats` rounds to zero at the base
/// steps (with the dead zone).
fn band_rounds_to_zero(splats: &Splats, band: u8, steps: &Steps) -> bool {
    let (g, b) = (Group::for_band(band), usize::from(band));
    let (k, first, s) = (splats.rest_coeffs(), b * b - 1, steps.sh_rest[b - 1]);
    let row = |i: usize| &splats.sh_rest[(i * k + first) * 3..(i * k + first + 2 * b + 1) * 3];
    (0..splats.len()).all(|i| row(i).iter().all(|&v| rounded_one(g, v / s, steps.rest_deadzone) == 0))
}

/// The base steps of group `g` (not position), one per channel.
fn group_steps(g: Group, steps: &Steps) -> Vec<f32> {
    match g {
        Group::Rotation => vec![1.0, steps.rotation, steps.rotation, steps.rotation],
        Group::Scale => vec![steps.scale; 3],
        Group::Opacity => vec![steps.opacity],
        Group::ShDc => vec![steps.sh_dc; 3],
        _ => vec![steps.sh_rest[usize::from(g.sh_band()) - 1]; g.channels()],
    }
}

/// A value of group `g` `t` steps from zero, rounded to nearest (SH rest bands with the dead
/// zone `dz`).
fn rounded_one(g: Group, t: f32, dz: f32) -> i32 {
    if g.sh_band() > 0 && dz > 0.0 {
        q_dz(t, 1.0, dz)
    } else {
        t.round() as i32 // `as` saturates: no wrap-around for any value
    }
}

/// Group `g`'s channels of targets (in steps) rounded ([`rounded_one`]).
fn rounded(g: Group, targets: &[Vec<f32>], dz: f32) -> Vec<Vec<i32>> {
    targets.iter().map(|c| c.iter().map(|&t| rounded_one(g, t, dz)).collect()).collect()
}

/// The values of group `g` (not position) of `splats`' Gaussians `order` (file order) in units
/// of their steps (the base steps times `factor(j)` for file row j), before rounding; the
/// rotation's index channel holds the index of its omitted component.
fn group_targets(splats: &Splats, order: &[usize], g: Group, steps: &Steps, factor: &dyn Fn(usize) -> f32) -> Vec<Vec<f32>> {
    // One pass over the rows, each row's channels in turn (a row's values lie together).
    fn rows<F: Fn(usize, usize, f32) -> f32>(order: &[usize], channels: usize, factor: &dyn Fn(usize) -> f32, f: F) -> Vec<Vec<f32>> {
        let mut out: Vec<Vec<f32>> = (0..channels).map(|_| Vec::with_capacity(order.len())).collect();
        for (j, &i) in order.iter().enumerate() {
            let m = factor(j);
            out.iter_mut().enumerate().for_each(|(c, ch)| ch.push(f(i, c, m)));
        }
        out
    }
    match g {
        Group::Scale => rows(order, 3, factor, |i, c, m| splats.log_scales[i][c] / (steps.scale * m)),
        Group::Rotation => {
            let mut ch: Vec<Vec<f32>> = (0..4).map(|_| Vec::with_capacity(order.len())).collect();
            for (j, &i) in order.iter().enumerate() {
                let (largest, t) = smallest_three_targets(splats.rotations[i], steps.rotation * factor(j));
                ch[0].push(largest as f32);
                (0..3).for_each(|c| ch[c + 1].push(t[c]));
            }
            ch
        }
        Group::Opacity => rows(order, 1, factor, |i, _, m| splats.opacity_logits[i] / (steps.opacity * m)),
        Group::ShDc => rows(order, 3, factor, |i, c, m| splats.sh_dc[i][c] / (steps.sh_dc * m)),
        _ => {
            let b = usize::from(g.sh_band());
            let (k, first, s) = (splats.rest_coeffs(), b * b - 1, steps.sh_rest[b - 1]);
            rows(order, g.channels(), factor, |i, j, m| splats.sh_rest[(i * k + first) * 3 + j] / (s * m))
        }
    }
}

/// Whether SH band `g` is coded by a codebook under the codebook sizes `ks` (per band, 0 =
/// per coefficient) and `joint` ([`apply_codebooks`]).
pub fn coded_by_codebook(g: Group, ks: [u32; 3], joint: bool) -> bool {
    let b = usize::from(g.sh_band());
    b > 0 && if joint { ks[0] > 0 } else { ks[b - 1] > 0 }
}

/// Codes SH band b (1..=3) of `q` by vector quantisation where `ks[b − 1] > 0`: a codebook of at
/// most that many rows ([`super::vq::band_codebook`]: a k-means, from `memo` when it holds it,
/// or the rows `memo` pins the band to), and the band's
/// channels become the rows the codebook restores. k-means sees the rows in the order of the
/// scene `q` was quantised from (`order[i]`: the scene index of file row `i`) with `weights[j]`
/// the weight of scene row `j`, so the codebook does not depend on the file order (levels,
/// importance classes).
///
/// With `joint` (and `ks[0] > 0`), all of `q`'s SH bands together: one k-means of at most
/// `ks[0]` rows over rows that hold every band's channels (band 1's first, the codebook of
/// "band 1" to `memo`), split into one codebook per band with the same index
/// ([`Quantised::shared_index`] when there is more than one band).
///
/// # Panics
/// If `order` or `weights` is not one value per Gaussian of `q`.
pub fn apply_codebooks(q: &mut Quantised, order: &[usize], weights: &[f32], ks: [u32; 3], joint: bool, memo: Option<&super::vq::Memo>) {
    assert_eq!((order.len(), weights.len()), (q.len(), q.len()), "one order entry and weight per Gaussian");
    // File rows in scene order.
    let mut by_scene: Vec<usize> = (0..order.len()).collect();
    by_scene.sort_unstable_by_key(|&i| order[i]);
    let in_file_order = |cb: &super::vq::Codebook| {
        let mut index = vec![0; cb.index.len()];
        by_scene.iter().zip(&cb.index).for_each(|(&i, &k)| index[i] = k);
        index
    };
    if joint && ks[0] > 0 {
        let bands: Vec<usize> = (0..q.groups.len()).filter(|&gi| q.groups[gi].0.sh_band() > 0).collect();
        let rows: Vec<Vec<i32>> =
            bands.iter().flat_map(|&gi| q.groups[gi].2.iter().map(|c| by_scene.iter().map(|&i| c[i]).collect())).collect();
        if rows.is_empty() {
            return;
        }
        // Each channel in its dequantised units: an SH coefficient's error moves the colour
        // alike in every band (orthonormal basis), and the bands' steps differ.
        let scale: Vec<f32> = bands.iter().flat_map(|&gi| q.groups[gi].1.iter().copied()).collect();
        let cb = super::vq::band_codebook(memo, 1, &rows, &scale, weights, ks[0] as usize);
        let index = in_file_order(&cb);
        let mut first = 0;
        for &gi in &bands {
            let (g, _, chans) = &mut q.groups[gi];
            let part = cb.columns(first..first + chans.len(), index.clone());
            first += chans.len();
            *chans = part.decoded_channels();
            q.codebooks.push((*g, part));
        }
        q.shared_index = bands.len() > 1;
        return;
    }
    for (g, _, chans) in q.groups.iter_mut() {
        if !coded_by_codebook(*g, ks, false) {
            continue;
        }
        let b = usize::from(g.sh_band());
        let rows: Vec<Vec<i32>> = chans.iter().map(|c| by_scene.iter().map(|&i| c[i]).collect()).collect();
        let cb = super::vq::band_codebook(memo, b, &rows, &vec![1.0; rows.len()], weights, ks[b - 1] as usize);
        let cb = super::vq::Codebook { channels: cb.channels, rows: cb.rows.clone(), index: in_file_order(&cb) };
        *chans = cb.decoded_channels();
        q.codebooks.push((*g, cb));
    }
}

/// The 24 rotations that map the coordinate axes onto themselves (the octahedral group), as
/// unit quaternions `(w, x, y, z)` (one of each ± pair), each with the axis permutation it
/// makes: column `k` of its matrix is `±e[perm[k]]`. The identity comes first.
fn axis_symmetries() -> Vec<([f64; 4], [usize; 3])> {
    let h = std::f64::consts::FRAC_1_SQRT_2;
    let mut quats: Vec<[f64; 4]> = vec![[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]];
    for s in 0..8u8 {
        let sign = |bit: u8| if s >> bit & 1 == 1 { -0.5 } else { 0.5 };
        quats.push([0.5, sign(0), sign(1), sign(2)]);
    }
    for a in 0..4 {
        for b in a + 1..4 {
            for sb in [h, -h] {
                let mut q = [0.0; 4];
                (q[a], q[b]) = (h, sb);
                quats.push(q);
            }
        }
    }
    quats
        .into_iter()
        .map(|[w, x, y, z]| {
            let m = [
                [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)],
                [2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)],
                [2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)],
            ];
            let perm = std::array::from_fn(|k| (0..3).max_by(|&r, &t| m[r][k].abs().total_cmp(&m[t][k].abs())).expect("three rows"));
            ([w, x, y, z], perm)
        })
        .collect()
}

/// Relabels every Gaussian's axes so that its rotation is the smallest of the 24 that draw the
/// same ellipsoid: a Gaussian is unchanged by permuting its axes (scales with them) and flipping
/// their signs, so `q` and `q ⊗ p`, with the scales permuted as `p` permutes the axes, are the
/// same Gaussian for every `p` of [`axis_symmetries`]. Of these the one with the largest `|w|`
/// is kept (`|w| ≥ cos 31.4°` ≈ 0.853 for every rotation), so the smallest-three index is `w`
/// (ties aside) and the other three components are small: a cheaper rotation group. The
/// identity wins ties, so a Gaussian already in this form keeps its exact values, and the
/// function is idempotent. Encoder-side only: the file format is unchanged.
pub fn canonical_axes(splats: &mut Splats) {
    use rayon::prelude::*;
    use std::f64::consts::FRAC_1_SQRT_2;
    static SYMMETRIES: std::sync::LazyLock<Vec<([f64; 4], [usize; 3])>> = std::sync::LazyLock::new(axis_symmetries);
    let symmetries = &*SYMMETRIES;
    splats.rotations.par_iter_mut().zip(splats.log_scales.par_iter_mut()).for_each(|(r, s)| {
        let q = r.map(f64::from);
        // The largest |w| among the others, from the sorted magnitudes (every sign combination
        // of each kind of symmetry is in the group): clearly below |w|, the identity wins
        // without trying them (most Gaussians of a scene trained from identity rotations).
        let (w, mut m) = (q[0].abs(), [q[1].abs(), q[2].abs(), q[3].abs()]);
        m.sort_unstable_by(|a, b| b.total_cmp(a));
        let others = m[0].max((w + m[0]) * FRAC_1_SQRT_2).max((m[0] + m[1]) * FRAC_1_SQRT_2).max(0.5 * (w + m[0] + m[1] + m[2]));
        if w > others * (1.0 + 1e-9) {
            return;
        }
        let w_of = |p: &[f64; 4]| (q[0] * p[0] - q[1] * p[1] - q[2] * p[2] - q[3] * p[3]).abs();
        let (mut best, mut best_w) = (0, w_of(&symmetries[0].0));
        for (k, (p, _)) in symmetries.iter().enumerate().skip(1) {
            let v = w_of(p);
            if v > best_w {
                (best, best_w) = (k, v);
            }
        }
        if best == 0 {
            return;
        }
        let ([pw, px, py, pz], perm) = symmetries[best];
        let [w, x, y, z] = q;
        let product = [
            w * pw - x * px - y * py - z * pz,
            w * px + x * pw + y * pz - z * py,
            w * py - x * pz + y * pw + z * px,
            w * pz + x * py - y * px + z * pw,
        ];
        *r = product.map(|v| v as f32);
        *s = perm.map(|k| s[k]);
    });
}

/// The largest opacity logit worth coding at opacity step `step` (logit units):
/// `max(logit MAX_ALPHA, ln(8/step − 1))`. Lowering an opacity `o > σ(ℓ)` to `σ(ℓ)` changes any
/// pixel's α (`min(MAX_ALPHA, o·G)`, DESIGN §3) by at most `1 − σ(ℓ)`, which here is
/// `min(0.01, step/8)`: never more than the largest α error of rounding a logit to the step
/// (`step/8`: `σ′ = ¼` at α = ½, half a step off), nor than the renderer's own margin above its
/// α cap. Above it the logits of trained scenes spread far (lego trained here: 15 % above 6, up
/// to 19), and each distinct value costs bits for an α change the step already exceeds.
pub fn opacity_logit_cap(step: f32) -> f32 {
    let cap = (MAX_ALPHA / (1.0 - MAX_ALPHA)).ln();
    if step > 0.0 {
        cap.max((8.0 / step - 1.0).max(1.0).ln())
    } else {
        cap
    }
}

/// Lowers every opacity logit above [`opacity_logit_cap`] of `step` to it (encoder-side: the
/// format is unchanged).
pub fn cap_opacities(splats: &mut Splats, step: f32) {
    let cap = opacity_logit_cap(step);
    splats.opacity_logits.iter_mut().for_each(|o| *o = o.min(cap));
}

/// Normalises, makes the largest component positive and quantises the other three.
pub fn smallest_three(r: [f32; 4], step: f32) -> (usize, [i32; 3]) {
    let (largest, t) = smallest_three_targets(r, step);
    (largest, t.map(|t| t.round() as i32))
}

/// [`smallest_three`] before rounding: the index of the largest component and the other three
/// in units of `step`.
fn smallest_three_targets(r: [f32; 4], step: f32) -> (usize, [f32; 3]) {
    let norm = r.iter().map(|x| f64::from(*x).powi(2)).sum::<f64>().sqrt();
    let u: [f64; 4] = std::array::from_fn(|i| f64::from(r[i]) / norm);
    let mut largest = 0;
    for i in 1..4 {
        if u[i].abs() > u[largest].abs() {
            largest = i;
        }
    }
    let sign = if u[largest] < 0.0 { -1.0 } else { 1.0 };
    let mut c = [0f32; 3];
    let mut j = 0;
    for (i, &x) in u.iter().enumerate() {
        if i != largest {
            c[j] = (x * sign) as f32 / step;
            j += 1;
        }
    }
    (largest, c)
}

/// Drops Gaussians whose opacity is below `min_opacity` (they draw nothing visible: alpha is
/// opacity × a Gaussian ≤ 1, and alpha < 1/255 is skipped by the renderer).
pub fn prune(splats: &Splats, min_opacity: f32) -> Splats {
    let mut out = splats.clone();
    out.retain_indices(|i| sigmoid(splats.opacity_logits[i]) >= min_opacity);
    out
}

/// How much colour band `b` (1..=3) of Gaussian `i` adds to the views: `weight · ‖c_{i,b}‖₂`,
/// where `c_{i,b}` are the band's rest coefficients (all three colour channels). For the real
/// orthonormal SH basis, `‖c_{i,b}‖₂² / 4π` is the mean over view directions of the squared
/// colour the band adds, so the norm is its RMS colour up to one constant for every band;
/// `weight` says how much of the views the Gaussian covers (its significance).
pub fn band_contribution(splats: &Splats, i: usize, b: u8, weight: f32) -> f32 {
    let (stride, r) = layout(Group::for_band(b), splats.sh_degree);
    weight * values(splats, Group::for_band(b))[i * stride..][r].iter().map(|x| x * x).sum::<f32>().sqrt()
}

/// Per-Gaussian SH band dropping: zeroes the rest coefficients of band `b` of every Gaussian
/// whose [`band_contribution`] (with `weights[i]`) is below `thresholds[b − 1]` (0 keeps all).
/// Zeros are cheap under the context tables, and a band that ends up all zero is left out.
///
/// # Panics
/// If `weights` is not one value per Gaussian.
pub fn drop_sh_bands(splats: &mut Splats, weights: &[f32], thresholds: [f32; 3]) {
    assert_eq!(weights.len(), splats.len(), "one weight per Gaussian");
    for b in 1..=splats.sh_degree.min(3) {
        let t = thresholds[usize::from(b) - 1];
        if t <= 0.0 {
            continue;
        }
        let g = Group::for_band(b);
        let (stride, r) = layout(g, splats.sh_degree);
        let drop: Vec<bool> = (0..splats.len()).map(|i| band_contribution(splats, i, b, weights[i]) < t).collect();
        for (v, _) in values_mut(splats, g).chunks_exact_mut(stride).zip(&drop).filter(|x| *x.1) {
            v[r.clone()].fill(0.0);
        }
    }
}

/// The DC shift `Σ_k (c_k − ĉ_k)·view_basis[k] / Y₀` that takes back, over the views a Gaussian
/// is seen from, the mean colour a change of its SH rest coefficients from `c` (`k_c` of them,
/// `[k][channel]`) to `ĉ` (`coded(k, channel)`, k from 0) moves: for that Gaussian alone, the
/// DC change of least squared colour error summed over its views, each weighted by its
/// blending weight there (the zero clamp aside; [`super::Importance::view_basis`]).
fn dc_shift(c: &[f32], k_c: usize, coded: impl Fn(usize, usize) -> f32, basis: &[f32; 15]) -> [f32; 3] {
    std::array::from_fn(|ch| {
        let s: f64 = (0..k_c).map(|k| f64::from(c[k * 3 + ch] - coded(k, ch)) * f64::from(basis[k])).sum();
        (s / f64::from(gscodec_decoder::math::SH_C0)) as f32
    })
}

/// The DC of every Gaussian of `splats` takes back the mean colour its SH rest lost from
/// `before` (the rest coefficients it had at SH degree `degree`, e.g. before band dropping and
/// the degree cut) to what it holds now ([`dc_shift`]; `view_basis` one per Gaussian).
///
/// # Panics
/// If `before` or `view_basis` does not describe every Gaussian of `splats`.
pub fn fit_dc(splats: &mut Splats, before: &[f32], degree: u8, view_basis: &[[f32; 15]]) {
    let (k_before, k_now) = (gscodec_decoder::math::sh_rest_coeffs(degree), splats.rest_coeffs());
    assert_eq!((before.len(), view_basis.len()), (splats.len() * k_before * 3, splats.len()), "one reference per Gaussian");
    for (i, basis) in view_basis.iter().enumerate() {
        let now = &splats.sh_rest[i * k_now * 3..][..k_now * 3];
        let shift =
            dc_shift(&before[i * k_before * 3..][..k_before * 3], k_before, |k, ch| if k < k_now { now[k * 3 + ch] } else { 0.0 }, basis);
        splats.sh_dc[i].iter_mut().zip(shift).for_each(|(d, s)| *d += s);
    }
}

/// Group `g` of `splats` rounded in place to multiples of `step`, with dead zone `dz` ([`q_dz`]):
/// what the decoder restores from a value coded at that step.
pub(crate) fn round_group(splats: &mut Splats, g: Group, step: f32, dz: f32) {
    let (stride, r) = layout(g, splats.sh_degree);
    for v in values_mut(splats, g).chunks_exact_mut(stride).flat_map(|c| &mut c[r.clone()]) {
        *v = q_dz(*v, step, dz) as f32 * step;
    }
}

/// `splats` with its SH rest as a scene trained for `steps` renders it (each band rounded at
/// its step with the dead zone, [`super::term::RateTerm::render_params`]): the reference
/// [`compensate_dc`] takes back from for such a scene ([`super::EncodeConfig::dc_fit_trained`]).
pub fn rest_as_trained(splats: &Splats, steps: &Steps) -> Splats {
    let mut out = splats.clone();
    for b in 1..=splats.sh_degree {
        round_group(&mut out, Group::for_band(b), steps.sh_rest[usize::from(b) - 1], steps.rest_deadzone);
    }
    out
}

/// [`fit_dc`] for what quantisation changes: every Gaussian of `q` (`splats` quantised, `order`
/// its file order, [`quantise_ordered`]) gets the DC of `splats` plus the [`dc_shift`] from
/// `splats`' SH rest to the coded one (codebook rows, rounding with the dead zone), quantised
/// with its level's DC step. `view_basis` has one entry per Gaussian of `splats`. The decoder
/// is unchanged: these are the encoder's choice of DC values. Returns the DC channels before
/// rounding, in units of each row's DC steps, file order (none without a DC group).
///
/// # Panics
/// If `view_basis` is not one entry per Gaussian of `splats`.
pub fn compensate_dc(q: &mut Quantised, splats: &Splats, order: &[usize], view_basis: &[[f32; 15]]) -> Vec<Vec<f32>> {
    assert_eq!(view_basis.len(), splats.len(), "one view basis per Gaussian");
    let Some(dc) = q.groups.iter().position(|g| g.0 == Group::ShDc) else { return Vec::new() };
    let k_c = splats.rest_coeffs();
    let bands: Vec<usize> = (0..q.groups.len()).filter(|&gi| q.groups[gi].0.sh_band() > 0).collect();
    let mut targets: Vec<Vec<f32>> = (0..3).map(|_| Vec::with_capacity(q.len())).collect();
    for (l, r) in q.level_ranges().into_iter().enumerate() {
        // The coded rest of this level's Gaussians, indexed by band (none: a band not coded).
        let mut coded: [Option<Vec<f32>>; 4] = Default::default();
        for &gi in &bands {
            let (g, _, ch) = &q.groups[gi];
            let ch: Vec<&[i32]> = ch.iter().map(|c| &c[r.clone()]).collect();
            coded[usize::from(g.sh_band())] = Some(dequantise_channels(*g, &q.level_steps(gi, l), &ch).expect("an SH band"));
        }
        let steps = q.level_steps(dc, l);
        for (t, j) in r.enumerate() {
            let i = order[j];
            let coded_at = |k: usize, ch: usize| {
                let b = (k + 1).isqrt();
                let m = k + 1 - b * b;
                coded[b].as_ref().map_or(0.0, |v| v[t * 3 * (2 * b + 1) + 3 * m + ch])
            };
            let shift = dc_shift(&splats.sh_rest[i * k_c * 3..][..k_c * 3], k_c, coded_at, &view_basis[i]);
            for (ch, col) in q.groups[dc].2.iter_mut().enumerate() {
                let t = (splats.sh_dc[i][ch] + shift[ch]) / steps[ch];
                targets[ch].push(t);
                col[j] = t.round() as i32; // `as` saturates: no wrap-around for any value
            }
        }
    }
    targets
}

/// The scene a decoder will restore from `q`: the decoder's dequantisation and assembler.
pub fn dequantise(q: &Quantised) -> Splats {
    // Each level with its own grid and steps (SPEC §4).
    let mut positions: Vec<f32> = Vec::with_capacity(3 * q.len());
    let mut values: Vec<(Group, usize, Vec<f32>)> = Vec::new();
    for (l, r) in q.level_ranges().into_iter().enumerate() {
        let g = q.level_grid(l);
        positions.extend(q.morton[r.clone()].iter().flat_map(|&m| position_of(m, &g)));
        for (gi, (g, _, ch)) in q.groups.iter().enumerate() {
            let ch: Vec<&[i32]> = ch.iter().map(|c| &c[r.clone()]).collect();
            let v = dequantise_channels(*g, &q.level_steps(gi, l), &ch).expect("the quantiser writes rotation indices 0..=3");
            values.push((*g, r.start, v));
        }
    }
    let mut pieces = vec![Piece { group: Group::Position, first: 0, columns: 0..3, values: &positions, codebook: None }];
    pieces.extend(values.iter().map(|(g, first, v)| {
        let columns = if *g == Group::Rotation { 0..4 } else { 0..g.channels() };
        Piece { group: *g, first: *first, columns, values: v, codebook: None }
    }));
    let mut s = Splats::new(q.sh_degree);
    assemble(q.len(), q.sh_degree, &pieces, &mut s);
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The 24 axis symmetries are distinct rotations, each permuting the axes.
    #[test]
    fn axis_symmetries_are_the_octahedral_group() {
        let g = axis_symmetries();
        assert_eq!(g.len(), 24);
        for (i, (p, perm)) in g.iter().enumerate() {
            assert!((p.iter().map(|v| v * v).sum::<f64>() - 1.0).abs() < 1e-12, "unit quaternion");
            let mut sorted = *perm;
            sorted.sort_unstable();
            assert_eq!(sorted, [0, 1, 2], "a permutation");
            for (r, _) in &g[..i] {
                let dot: f64 = p.iter().zip(r).map(|(a, b)| a * b).sum();
                assert!(dot.abs() < 1.0 - 1e-9, "{p:?} and {r:?} are the same rotation");
            }
        }
        assert_eq!(g[0], ([1.0, 0.0, 0.0, 0.0], [0, 1, 2]), "the identity first");
    }

    /// Relabelling the axes keeps every Gaussian's covariance (to f32 rounding), leaves `w` the
    /// largest component with `|w| ≥ cos 31.4°` of the norm, keeps Gaussians already in that
    /// form bit for bit (rotations near the identity, the extreme scene) and is idempotent.
    #[test]
    fn canonical_axes_keeps_every_gaussian_and_makes_w_largest() {
        use gscodec_decoder::math::covariance_3d;
        let mut s = gscodec_decoder::testkit::random_splats(2000, 1, 7);
        // Scales of very different sizes per axis, so a wrong permutation shows.
        s.log_scales.iter_mut().enumerate().for_each(|(i, l)| *l = [-3.0, -1.0, 0.5].map(|v| v + 0.001 * (i % 97) as f32));
        s.rotations.iter_mut().enumerate().for_each(|(i, r)| *r = r.map(|v| v * (0.5 + (i % 5) as f32)));
        // Gaussian i of `a` and of `b` have the same covariance to f32 rounding.
        let same_covariance = |a: &Splats, b: &Splats, i: usize| {
            let (ca, cb) = (covariance_3d(a.log_scales[i], a.rotations[i]), covariance_3d(b.log_scales[i], b.rotations[i]));
            let scale = ca.to_cols_array().iter().fold(0.0f32, |m, v| m.max(v.abs()));
            (ca - cb).to_cols_array().iter().all(|v| v.abs() <= 1e-5 * scale)
        };
        let mut c = s.clone();
        canonical_axes(&mut c);
        let mut moved = 0;
        for i in 0..s.len() {
            assert!(same_covariance(&s, &c, i), "Gaussian {i}: covariance moved");
            let r = c.rotations[i];
            let norm = r.iter().map(|v| v * v).sum::<f32>().sqrt();
            assert!(r.iter().all(|v| v.abs() <= r[0].abs()), "Gaussian {i}: w is not the largest in {r:?}");
            assert!(r[0].abs() >= 0.853 * norm, "Gaussian {i}: |w| = {} of {norm}", r[0].abs());
            moved += usize::from(r != s.rotations[i]);
        }
        assert!(moved > s.len() / 2, "uniform rotations mostly change: {moved}");
        let mut again = c.clone();
        canonical_axes(&mut again);
        assert_eq!(again, c, "idempotent");
        let mut near_identity = s.clone();
        near_identity.rotations.iter_mut().enumerate().for_each(|(i, r)| *r = [1.0, 0.01 * (i % 7) as f32, -0.02, 0.005]);
        let mut n = near_identity.clone();
        canonical_axes(&mut n);
        assert_eq!(n, near_identity, "rotations near the identity stay bit for bit");
        // DESIGN §8's extreme Gaussians: all but the needle (4) are in that form already and keep
        // their values (the nearly zero-norm quaternion included); the needle, scales e^−20 on
        // two axes, keeps its covariance.
        let extreme = gscodec_decoder::testkit::extreme_splats(2);
        let mut e = extreme.clone();
        canonical_axes(&mut e);
        for i in 0..e.len() {
            let kept = (e.rotations[i], e.log_scales[i]) == (extreme.rotations[i], extreme.log_scales[i]);
            assert_eq!(kept, i != 4, "extreme Gaussian {i}");
        }
        assert!(same_covariance(&extreme, &e, 4), "the needle's covariance");
    }

    /// A band's codebook is computed from the rows in the scene's order: a file order changed by
    /// levels gives every Gaussian the same decoded row, and a memo hands the second call the
    /// first call's codebook.
    #[test]
    fn codebooks_do_not_depend_on_the_file_order() {
        let s = crate::sample::scene(600, 3);
        let w: Vec<f32> = (0..s.len()).map(|i| (i % 7) as f32).collect();
        let memo = crate::rate::vq::Memo::default();
        let rows_by_scene = |level: &[u8]| {
            let (mut q, order) = quantise_ordered(&s, &Steps::default(), level);
            apply_codebooks(&mut q, &order, &w, [16, 0, 0], false, Some(&memo));
            let (_, _, chans) = q.groups.iter().find(|g| g.0 == Group::Sh1).expect("band 1");
            let mut rows = vec![Vec::new(); s.len()];
            order.iter().enumerate().for_each(|(f, &i)| rows[i] = chans.iter().map(|c| c[f]).collect::<Vec<i32>>());
            (rows, q.codebooks[0].1.rows.clone())
        };
        let plain = rows_by_scene(&[]);
        let levels: Vec<u8> = (0..s.len()).map(|i| (i % 3 == 0) as u8).collect();
        assert_eq!(rows_by_scene(&levels), plain);
        assert_eq!(memo.len(), 1, "the second call reused the first codebook");
        let distinct: std::collections::HashSet<&Vec<i32>> = plain.0.iter().collect();
        assert!(distinct.len() > 1 && distinct.len() <= 16, "{} rows", distinct.len());
    }

    /// Importance classes: a level's rows are its targets at the base steps divided by the
    /// level's factor (times the group's multiplier of it: rotation's ×2 here), rounded to
    /// nearest, and the level's steps are the base steps times the same; the groups kept at the
    /// base steps and the file order are those of a quantisation without classes, and the
    /// targets returned are the ones the values were rounded from.
    #[test]
    fn class_factors_divide_their_levels_targets_and_spare_the_groups_at_base_steps() {
        let s = crate::sample::scene(400, 5);
        let level: Vec<u8> = (0..s.len()).map(|i| u8::from(i % 3 == 0)).collect();
        let asked = [Group::Scale, Group::Rotation, Group::Sh1];
        let plain = quantise_classes(&s, &Steps::default(), &level, &Classes { targets: &asked, ..Classes::NONE });
        let mut groups = [1.0; 8];
        groups[Group::Rotation as usize] = 2.0;
        let classes = Classes { factors: Some(&[1.0, 2.5]), groups, at_base: &|g| g == Group::Sh2, targets: &asked, ..Classes::NONE };
        let coarse = quantise_classes(&s, &Steps::default(), &level, &classes);
        assert_eq!(coarse.order, plain.order);
        assert_eq!(coarse.q.level_factors, vec![1.0, 2.5]);
        assert_eq!(coarse.q.row_factors().iter().filter(|&&f| f == 2.5).count(), level.iter().filter(|&&l| l == 1).count());
        let group = |q: &Quantised, g: Group| q.groups.iter().find(|x| x.0 == g).expect("present").2.clone();
        assert_eq!(group(&coarse.q, Group::Sh2), group(&plain.q, Group::Sh2));
        let gi = |g: Group| coarse.q.groups.iter().position(|x| x.0 == g).expect("present");
        let base = |g: Group| plain.q.level_steps(gi(g), 0);
        assert_eq!(coarse.q.level_steps(gi(Group::Scale), 1), base(Group::Scale).iter().map(|s| s * 2.5).collect::<Vec<_>>());
        let rotation = coarse.q.level_steps(gi(Group::Rotation), 1);
        assert_eq!(rotation[0], 1.0, "the index is never scaled");
        assert_eq!(rotation[1..], base(Group::Rotation)[1..].iter().map(|s| s * 5.0).collect::<Vec<_>>());
        assert_eq!(coarse.q.level_steps(gi(Group::Rotation), 0), base(Group::Rotation));
        let mut moved = 0;
        for ((g, t), (g0, t0)) in coarse.targets.iter().zip(&plain.targets) {
            assert_eq!(g, g0);
            let (values, before) = (group(&coarse.q, *g), group(&plain.q, *g));
            let first = usize::from(*g == Group::Rotation); // the index of the omitted component
            assert_eq!(t[..first], t0[..first]);
            let factor: Vec<f32> = coarse.q.row_factors().iter().map(|&f| CoarseTail::group_factor(&groups, *g, f)).collect();
            for c in first..t.len() {
                for j in 0..factor.len() {
                    assert!((t[c][j] - t0[c][j] / factor[j]).abs() <= 1e-5 * (1.0 + t[c][j].abs()), "{g:?} channel {c} row {j}");
                    assert_eq!(values[c][j], t[c][j].round() as i32);
                    moved += usize::from(values[c][j] != before[c][j]);
                }
            }
        }
        assert!(moved > 0, "the coarser level's values changed");
    }

    #[test]
    fn dead_zone_rounds_small_values_to_zero_symmetrically() {
        for v in [-1.26f32, -0.74, -0.2, 0.0, 0.3, 0.51, 0.74, 1.26, 3.49] {
            assert_eq!(q_dz(v, 0.5, 0.0), q(v, 0.5), "dz=0 is plain rounding at {v}");
            assert_eq!(q_dz(v, 0.5, 0.25), -q_dz(-v, 0.5, 0.25), "symmetric at {v}");
        }
        // |v|/s = 1.4: plain rounding gives 1; a dead zone of 0.25 needs 1.75 for 2 and 0.75 for 1.
        assert_eq!(q_dz(0.7, 0.5, 0.25), 1);
        assert_eq!(q_dz(0.35, 0.5, 0.25), 0); // 0.7 steps < 0.75
        assert_eq!(q_dz(-0.4, 0.5, 0.25), -1); // 0.8 steps
        assert_eq!(q_dz(0.85, 0.5, 0.25), 1); // 1.7 steps < 1.75
    }

    /// After the degree cut to 1 and rounding, each Gaussian's mean colour over its views (the
    /// view basis) is the input's to within the DC's rounding; without the compensation it is
    /// not, and the compensated file's squared error on the views is lower.
    #[test]
    fn the_dc_takes_back_the_mean_colour_the_coded_rest_lost() {
        let s = gscodec_decoder::testkit::random_splats(300, 3, 11);
        let m = super::super::Importance::of(&s);
        let cut = s.with_sh_degree(1);
        let steps = Steps { sh_rest: [0.05; 3], ..Steps::default() };
        let (plain, order) = quantise_ordered(&cut, &steps, &[]);
        let mut fitted = cut.clone();
        fit_dc(&mut fitted, &s.sh_rest, 3, &m.view_basis);
        let (mut comp, same_order) = quantise_ordered(&fitted, &steps, &[]);
        assert_eq!(order, same_order);
        compensate_dc(&mut comp, &fitted, &order, &m.view_basis);
        let mean_colour = |dc: [f32; 3], rest: &[f32], vb: &[f32; 15], ch: usize| {
            gscodec_decoder::math::SH_C0 * dc[ch] + rest.chunks_exact(3).zip(vb).map(|(c, b)| c[ch] * b).sum::<f32>()
        };
        let worst = |q: &Quantised| {
            let dec = dequantise(q);
            let mut worst = 0.0f32;
            for (j, &i) in order.iter().enumerate() {
                for ch in 0..3 {
                    let input = mean_colour(s.sh_dc[i], s.rest_of(i), &m.view_basis[i], ch);
                    worst = worst.max((mean_colour(dec.sh_dc[j], dec.rest_of(j), &m.view_basis[i], ch) - input).abs());
                }
            }
            worst
        };
        let half_step = 0.5 * gscodec_decoder::math::SH_C0 * steps.sh_dc;
        assert!(worst(&comp) <= half_step * 1.001 + 1e-5, "{} > {half_step}", worst(&comp));
        assert!(worst(&plain) > 4.0 * half_step, "the cut moves some mean colour: {}", worst(&plain));
        let ev = super::super::rd::Evaluator::new(&s);
        let (d_plain, d_comp) = (ev.distortion(&dequantise(&plain)), ev.distortion(&dequantise(&comp)));
        assert!(d_comp < 0.9 * d_plain, "D {d_comp} against {d_plain} without");
        // Only the DC changed.
        let others = |q: &Quantised| q.groups.iter().filter(|g| g.0 != Group::ShDc).cloned().collect::<Vec<_>>();
        assert_eq!((others(&comp), &comp.morton), (others(&plain), &plain.morton));
    }

    /// A scene trained for its steps was rendered with its rest rounded (with the dead zone):
    /// coded by that rounding alone, the DC takes back nothing from the rest as trained, while
    /// from the float rest it would take back the rounding a second time.
    #[test]
    fn a_trained_scene_s_dc_takes_back_only_what_training_did_not_see() {
        let s = gscodec_decoder::testkit::random_splats(300, 3, 11);
        let m = super::super::Importance::of(&s);
        let steps = Steps { sh_rest: [0.05, 0.08, 0.1], rest_deadzone: 0.2, ..Steps::default() };
        let (plain, order) = quantise_ordered(&s, &steps, &[]);
        let trained = rest_as_trained(&s, &steps);
        assert_eq!(trained.sh_dc, s.sh_dc);
        let (same, _) = quantise_ordered(&trained, &steps, &[]);
        assert_eq!(same, plain, "the rest as trained is on the steps' grid");
        let mut comp = plain.clone();
        compensate_dc(&mut comp, &trained, &order, &m.view_basis);
        assert_eq!(comp, plain, "nothing to take back");
        let mut twice = plain.clone();
        compensate_dc(&mut twice, &s, &order, &m.view_basis);
        assert_ne!(twice, plain, "from the float rest the rounding moves the DC");
    }

    #[test]
    fn sh_band_dropping_zeroes_only_weak_bands_and_threshold_zero_is_the_identity() {
        let s = gscodec_decoder::testkit::random_splats(200, 3, 5);
        let w: Vec<f32> = (0..s.len()).map(|i| 1.0 + (i % 7) as f32).collect();
        let mut same = s.clone();
        drop_sh_bands(&mut same, &w, [0.0; 3]);
        assert_eq!(same, s, "threshold 0 changes nothing");
        // Band 2 only, at its median contribution: about half its rows zeroed, nothing else touched.
        let mut c: Vec<f32> = (0..s.len()).map(|i| band_contribution(&s, i, 2, w[i])).collect();
        c.sort_by(f32::total_cmp);
        let t = c[c.len() / 2];
        let mut d = s.clone();
        drop_sh_bands(&mut d, &w, [0.0, t, 0.0]);
        let k = s.rest_coeffs();
        let mut zeroed = 0;
        for i in 0..s.len() {
            for j in 0..k {
                let (a, b) = (&s.sh_rest[(i * k + j) * 3..][..3], &d.sh_rest[(i * k + j) * 3..][..3]);
                let band2 = (3..8).contains(&j);
                if band2 && band_contribution(&s, i, 2, w[i]) < t {
                    assert_eq!(b, [0.0; 3]);
                } else {
                    assert_eq!(a, b, "Gaussian {i} coefficient {j} changed");
                }
            }
            zeroed += usize::from(band_contribution(&s, i, 2, w[i]) < t);
        }
        assert_eq!(zeroed, s.len() / 2);
        assert_eq!((d.positions.clone(), d.sh_dc.clone()), (s.positions.clone(), s.sh_dc.clone()));
    }

    /// The cap lowers α by at most the step's largest α rounding error (`step/8`) and at most the
    /// renderer's margin above its α cap (0.01), and is no higher than that needs: `1 − σ(cap)`
    /// is the smaller of the two.
    #[test]
    fn the_opacity_cap_changes_alpha_by_at_most_the_steps_rounding_error() {
        let logit_099 = (0.99f32 / 0.01).ln();
        for step in [1e-3f32, 0.01, 0.04, 0.08, 0.112, 0.5, 3.9, 4.0, 10.0, 0.0] {
            let cap = opacity_logit_cap(step);
            assert!(cap >= logit_099 - 1e-6, "step {step}: cap {cap}");
            let alpha_change = 1.0 / (1.0 + f64::from(cap).exp()); // 1 − σ(cap)
            let bound = if step > 0.0 { 0.01f64.min(f64::from(step) / 8.0) } else { 0.01 };
            assert!(alpha_change <= bound * (1.0 + 1e-4), "step {step}: 1 − σ(cap) = {alpha_change} > {bound}");
            assert!(alpha_change >= bound * (1.0 - 1e-3), "step {step}: a higher cap than needed: {alpha_change} < {bound}");
        }
        let mut s = gscodec_decoder::testkit::random_splats(50, 0, 3);
        s.opacity_logits.iter_mut().enumerate().for_each(|(i, o)| *o = -3.0 + 0.4 * i as f32);
        let before = s.opacity_logits.clone();
        cap_opacities(&mut s, 0.112);
        let cap = opacity_logit_cap(0.112);
        for (a, b) in before.iter().zip(&s.opacity_logits) {
            assert_eq!(*b, a.min(cap), "only logits above the cap move, to it");
        }
    }
}

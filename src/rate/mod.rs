//! Rate: quantisation, entropy-model tables and the encoder that writes `.gsc` files.
//!
//! * [`quantise`] — scene ⇄ integer channels (Morton-ordered position grid, smallest-three
//!   rotations, per-channel steps) and pruning.
//! * [`group`] — the one attribute-group type ([`group::Group`]) and per-group maps.
//! * [`importance`] — per-Gaussian significance (blending weight summed over the standard views).
//! * [`lambda`] — [`Lambda`], the one unit of the rate–distortion trade-off, and its conversions.
//! * [`tables`] — the integer tables written to the file and their exact cost.
//! * [`encode`] — streams per (group, chunk), levels, and the container.

pub mod encode;
pub mod group;
pub mod importance;
pub mod lambda;
pub mod model;
pub mod quantise;
pub mod rd;
pub mod rdoq;
pub mod tables;
pub mod term;
pub mod vq;

use gscodec_decoder::bitstream::layout::Group;
use gscodec_decoder::{SceneError, Splats};
pub use importance::Importance;

pub use encode::{EncodeReport, GroupReport};
pub use lambda::Lambda;
pub use quantise::{Quantised, Steps};

/// Everything the encoder decides besides the Gaussians themselves.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EncodeConfig {
    pub steps: Steps,
    /// Gaussians with opacity below this are pruned (1/255 is lossless: they never draw).
    pub min_opacity: f32,
    /// Gaussians whose removal error (the squared colour error that dropping each alone causes
    /// in the standard views, [`importance::Importance::removal`] of the input scene) is below
    /// this are pruned too (0 = off; the RD search sets it).
    pub min_removal_error: f32,
    /// Per SH band 1..=3: Gaussians whose band contribution ([`quantise::band_contribution`],
    /// weighted by their significance) is below this have that band's coefficients zeroed
    /// (0 = keep all; the RD search sets it).
    pub sh_drop: [f32; 3],
    /// Per SH band 1..=3: 0 = coded per coefficient; K > 0 = coded by vector quantisation with a
    /// codebook of at most K rows ([`vq`], SPEC §3.2, format 5.0; the RD search sets it).
    pub sh_vq: [u32; 3],
    /// With `sh_vq[0] > 0`: every SH band kept is coded by **one** codebook of at most
    /// `sh_vq[0]` rows, each row all the bands' coefficients, and one row index per Gaussian
    /// ([`quantise::apply_codebooks`]; the bands above 1 share band 1's index, SPEC §3.2, format
    /// 9.0); `sh_vq[1..]` are then not used. The RD search sets it.
    pub sh_joint: bool,
    /// SH bands above this degree are left out.
    pub max_sh_degree: u8,
    /// Also fit the learned density per channel and store it where it is cheaper than the
    /// static histogram (slower; the RD search turns it off for its trial encodes).
    pub learned_tables: bool,
    /// Also fit neighbour-context tables (table mode 3, SPEC §4.3) and store them where they are
    /// cheaper: such a file is format 8.0. Off: the file is what a 3.0–6.0 reader reads.
    pub neighbour_tables: bool,
    /// Write the Gaussians in importance levels ([`importance::levels`], SPEC §3.1, format 4.0)
    /// so that a player can draw the most important ones from a prefix of the file; off = one
    /// level (format 3.0).
    pub progressive: bool,
    /// Importance classes: the least significant Gaussians coded with coarser steps
    /// ([`CoarseTail`]; the RD search sets it).
    pub tail: CoarseTail,
    /// Each Gaussian's DC takes back the mean colour, over the views it is seen from, that
    /// coding its SH rest bands lost (band dropping and the degree cut: [`quantise::fit_dc`];
    /// codebooks and rounding: [`quantise::compensate_dc`]). Needs the input's importance (its
    /// view basis). The RD search sets it where it lowers `J`.
    pub dc_fit: bool,
    /// With `dc_fit`, for a scene trained rendering its SH rest rounded at `steps` with the dead
    /// zone ([`term::RateTerm::render_params`]): the DC takes back only what the file codes
    /// differently from that (codebook rows, the importance classes' coarser steps), not the
    /// rounding training already fitted the DC to ([`quantise::rest_as_trained`]).
    pub dc_fit_trained: bool,
    /// Rate-aware rounding ([`rdoq`]): a value may take the integer on the other side of its
    /// target where its channel's table makes that cheaper by more than the extra error is
    /// worth. Off: every value is rounded to nearest.
    pub rate_rounding: bool,
}

/// Importance classes (format 6.0, SPEC §4): the least significant `share` of the Gaussians kept
/// (by the input's significance, [`importance::significance`]) go into a level of their own,
/// coded with every step `factor` times the others' (each group's times its own multiplier,
/// [`CoarseTail::group_factor`]) and a position grid of [`CoarseTail::coarser_grid_bits`] fewer
/// bits per axis (its own parameter sections). With `--progressive`, the importance levels that
/// lie wholly within that share take the factor instead.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct CoarseTail {
    /// Share of the kept Gaussians, in (0, 1); 0 = off.
    pub share: f32,
    /// Step factor of the tail (1 = off).
    pub factor: f32,
    /// Per group (indexed by `Group as usize`), a multiplier of `factor` for that group's steps
    /// in the tail (position: of the factor its grid's bits follow); 1 = the common factor. The
    /// RD search sets them ([`rd`]'s stage after the classes).
    pub groups: [f32; 8],
}

impl CoarseTail {
    /// No tail: one set of steps for every Gaussian.
    pub const OFF: CoarseTail = CoarseTail::new(0.0, 1.0);

    /// The least significant `share` at `factor` times the steps, every group alike.
    pub const fn new(share: f32, factor: f32) -> CoarseTail {
        CoarseTail { share, factor, groups: [1.0; 8] }
    }

    /// The factor of group `g`'s steps (position: of its grid) in a level whose steps are
    /// `level_factor` times the base steps: that times the group's multiplier in a level of the
    /// tail (`level_factor ≠ 1`), 1 elsewhere.
    pub fn group_factor(groups: &[f32; 8], g: Group, level_factor: f32) -> f32 {
        if level_factor == 1.0 {
            1.0
        } else {
            level_factor * groups[g as usize]
        }
    }

    pub fn is_off(&self) -> bool {
        !(self.share > 0.0 && self.share < 1.0) || self.factor == 1.0
    }

    /// Per Gaussian of a scene ranked by `rank` ([`Importance::tail_rank`]): 1 for the
    /// ⌊share·n⌋ lowest (ties: the later index first), else 0. Empty when the tail is off or
    /// either level would be empty.
    pub fn levels(&self, rank: &[f32]) -> Vec<u8> {
        let n = rank.len();
        let cut = (f64::from(self.share) * n as f64) as usize;
        if self.is_off() || cut == 0 || cut >= n {
            return Vec::new();
        }
        let mut order: Vec<usize> = (0..n).collect();
        order.sort_by(|&a, &b| rank[a].total_cmp(&rank[b]).then(b.cmp(&a)));
        let mut level = vec![0u8; n];
        order[..cut].iter().for_each(|&i| level[i] = 1);
        level
    }

    /// Bits per axis fewer in the position grid of a level whose steps are `factor` times
    /// coarser: ⌊log₂ factor⌋ (1.5 → 0, 2 and 3 → 1, 4 and 6 → 2).
    pub fn coarser_grid_bits(factor: f32) -> u8 {
        factor.max(1.0).log2().floor() as u8
    }

    /// The factor of each of `levels` (Gaussian counts, most important first): `factor` for the
    /// levels that lie wholly within the least significant `share` of them, else 1. `None` when
    /// no level does (the tail changes nothing).
    pub fn level_factors(&self, levels: &[usize]) -> Option<Vec<f32>> {
        let n: usize = levels.iter().sum();
        let mut below = n; // Gaussians in this level and the ones after it
        let factors: Vec<f32> = levels
            .iter()
            .map(|&k| {
                let f = if !self.is_off() && below as f64 <= f64::from(self.share) * n as f64 { self.factor } else { 1.0 };
                below -= k;
                f
            })
            .collect();
        factors.iter().any(|&f| f != 1.0).then_some(factors)
    }
}

impl Default for EncodeConfig {
    fn default() -> Self {
        EncodeConfig {
            steps: Steps::default(),
            min_opacity: 1.0 / 255.0,
            min_removal_error: 0.0,
            sh_drop: [0.0; 3],
            sh_vq: [0; 3],
            sh_joint: false,
            max_sh_degree: 3,
            learned_tables: true,
            neighbour_tables: true,
            progressive: false,
            tail: CoarseTail::OFF,
            dc_fit: false,
            dc_fit_trained: false,
            rate_rounding: true,
        }
    }
}

impl EncodeConfig {
    /// The fixed ladder for trade-off `lambda` when there is no scene to search on (training
    /// from images): [`Lambda::ladder_step_multiplier`] and [`Lambda::ladder_min_opacity`].
    /// λ = 0 is the finest setting; a huge λ prunes everything (an empty, valid file).
    pub fn for_lambda(lambda: Lambda) -> EncodeConfig {
        EncodeConfig {
            steps: Steps::default().scaled(lambda.ladder_step_multiplier()),
            min_opacity: lambda.ladder_min_opacity(),
            ..EncodeConfig::default()
        }
    }

    /// Whether coding with this config needs the input's [`importance::Importance`] (pruning by
    /// removal error, SH band dropping, or SH vector quantisation, whose k-means weighs rows by
    /// significance).
    pub fn needs_importance(&self) -> bool {
        self.min_removal_error > 0.0
            || self.sh_drop.iter().any(|&t| t > 0.0)
            || self.sh_vq.iter().any(|&k| k > 0)
            || !self.tail.is_off()
            || self.dc_fit
    }
}

/// The Gaussians of `splats` that `config`'s pruning keeps (opacity, then removal error: each a
/// per-Gaussian test on the input), and their significance when `importance` is given. Without
/// `importance` the removal-error test is skipped ([`encode`] computes it when needed).
///
/// # Panics
/// If `importance` does not measure every Gaussian of `splats`.
pub fn pruned(splats: &Splats, config: &EncodeConfig, importance: Option<&Importance>) -> (Splats, Option<Vec<f32>>) {
    let (out, sig, _) = pruned_with_mask(splats, config, importance);
    (out, sig)
}

/// [`pruned`], and per Gaussian of `splats` whether it is kept.
fn pruned_with_mask(splats: &Splats, config: &EncodeConfig, importance: Option<&Importance>) -> (Splats, Option<Vec<f32>>, Vec<bool>) {
    let keep = kept(splats, config, importance);
    let mut out = splats.clone();
    out.retain_indices(|i| keep[i]);
    (out, importance.map(|m| kept_of(&m.significance, &keep)), keep)
}

/// The entries of `v` (one per Gaussian) that `keep` keeps.
fn kept_of<T: Copy>(v: &[T], keep: &[bool]) -> Vec<T> {
    v.iter().zip(keep).filter(|x| *x.1).map(|x| *x.0).collect()
}

/// Per Gaussian of `splats`, whether [`pruned`] keeps it.
fn kept(splats: &Splats, config: &EncodeConfig, importance: Option<&Importance>) -> Vec<bool> {
    assert!(importance.is_none_or(|m| m.len() == splats.len() && m.removal.len() == splats.len()), "one measure per Gaussian");
    (0..splats.len())
        .map(|i| {
            opaque_enough(splats, i, config)
                && (config.min_removal_error <= 0.0 || importance.is_none_or(|m| m.removal[i] >= config.min_removal_error))
        })
        .collect()
}

/// Whether Gaussian `i` of `splats` passes `config`'s opacity threshold, [`pruned`]'s first test.
fn opaque_enough(splats: &Splats, i: usize, config: &EncodeConfig) -> bool {
    gscodec_decoder::math::sigmoid(splats.opacity_logits[i]) >= config.min_opacity
}

/// What `config` codes of `splats`, before quantisation: [`pruned`], SH bands dropped
/// ([`quantise::drop_sh_bands`]), the degree cut and every Gaussian's axes relabelled for the
/// cheapest rotation ([`quantise::canonical_axes`]: the same Gaussians). `importance` is that
/// of `splats` ([`Importance::of`]; computed here when `config` needs it and it is `None`).
pub fn prepared(splats: &Splats, config: &EncodeConfig, importance: Option<&Importance>) -> Splats {
    prepared_with_measures(splats, config, importance).scene
}

/// [`prepared`]'s scene and, where the input's [`Importance`] was measured, its kept Gaussians'
/// measures.
struct Prepared {
    scene: Splats,
    /// [`Importance::significance`] of the kept Gaussians.
    significance: Option<Vec<f32>>,
    /// [`Importance::tail_rank`] of the kept Gaussians, where [`EncodeConfig::tail`] is on.
    tail_rank: Option<Vec<f32>>,
    /// [`Importance::view_basis`] of the kept Gaussians, with [`EncodeConfig::dc_fit`] and SH
    /// rest bands.
    view_basis: Option<Vec<[f32; 15]>>,
}

/// [`prepared`], the kept Gaussians' measures when there are some, and, with
/// [`EncodeConfig::dc_fit`] and SH rest bands, their view basis, with which their DC has taken
/// back the mean colour the dropped bands and the degree cut took away ([`quantise::fit_dc`])
/// and quantisation will take back what rounding and codebooks take
/// ([`quantise::compensate_dc`]).
fn prepared_with_measures(splats: &Splats, config: &EncodeConfig, importance: Option<&Importance>) -> Prepared {
    let own;
    let importance = match importance {
        None if config.needs_importance() => {
            own = Importance::of(splats);
            Some(&own)
        }
        m => m,
    };
    let (mut s, sig, keep) = pruned_with_mask(splats, config, importance);
    let basis = importance.filter(|m| config.dc_fit && !m.view_basis.is_empty()).map(|m| kept_of(&m.view_basis, &keep));
    let before = basis.as_ref().map(|_| (s.sh_rest.clone(), s.sh_degree));
    if let Some(w) = sig.as_ref().filter(|_| config.sh_drop.iter().any(|&t| t > 0.0)) {
        quantise::drop_sh_bands(&mut s, w, config.sh_drop);
    }
    if s.sh_degree > config.max_sh_degree {
        s = s.with_sh_degree(config.max_sh_degree);
    }
    if let (Some(basis), Some((rest, degree))) = (&basis, &before) {
        quantise::fit_dc(&mut s, rest, *degree, basis);
    }
    quantise::canonical_axes(&mut s);
    quantise::cap_opacities(&mut s, config.steps.opacity);
    let tail_rank = importance.filter(|_| !config.tail.is_off()).map(|m| kept_of(&m.tail_rank(), &keep));
    Prepared { scene: s, significance: sig, tail_rank, view_basis: basis }
}

/// Prunes, quantises and encodes a scene. Refuses scenes with NaN/Inf or invalid arrays.
pub fn encode(splats: &Splats, config: &EncodeConfig) -> Result<(Vec<u8>, EncodeReport, Quantised), SceneError> {
    encode_with(splats, config, None)
}

/// [`encode`] with the input's importance already measured ([`Importance::of`] `splats`;
/// computed here when `config` needs it and it is `None`).
pub fn encode_with(
    splats: &Splats,
    config: &EncodeConfig,
    importance: Option<&Importance>,
) -> Result<(Vec<u8>, EncodeReport, Quantised), SceneError> {
    encode_cached(splats, config, importance, None)
}

/// [`encode_with`], taking the coded groups `cache` holds from it and adding the others
/// ([`encode::write_cached`]): the same bytes, report and quantised scene.
pub fn encode_cached(
    splats: &Splats,
    config: &EncodeConfig,
    importance: Option<&Importance>,
    cache: Option<&encode::GroupCache>,
) -> Result<(Vec<u8>, EncodeReport, Quantised), SceneError> {
    splats.validate()?;
    let input = (splats.len(), splats.sh_degree);
    let Prepared { scene: s, significance: sig, tail_rank, view_basis } = prepared_with_measures(splats, config, importance);
    let level = match &tail_rank {
        _ if config.progressive => importance::levels(&importance::significance(&s)),
        Some(rank) => config.tail.levels(rank),
        None => Vec::new(),
    };
    // Importance classes: the step factor of each level value, and its coarser position grid.
    let mut counts = vec![0usize; level.iter().max().map_or(0, |&l| usize::from(l) + 1)];
    level.iter().for_each(|&l| counts[usize::from(l)] += 1);
    let factors = config.tail.level_factors(&counts);
    let coarser: Vec<u8> = factors
        .iter()
        .flatten()
        .map(|&f| CoarseTail::coarser_grid_bits(CoarseTail::group_factor(&config.tail.groups, Group::Position, f)))
        .collect();
    // Rate-aware rounding (rdoq) takes the groups rounded to nearest here, then the DC once it
    // has taken back what the coded SH rest lost.
    let mut rounds = vec![Group::Scale, Group::Rotation, Group::Opacity];
    if view_basis.is_none() {
        rounds.push(Group::ShDc);
    }
    if config.steps.rest_deadzone <= 0.0 {
        rounds.extend(
            [Group::Sh1, Group::Sh2, Group::Sh3].into_iter().filter(|&g| !quantise::coded_by_codebook(g, config.sh_vq, config.sh_joint)),
        );
    }
    let classes = quantise::Classes {
        coarser: &coarser,
        factors: factors.as_deref(),
        groups: config.tail.groups,
        at_base: &|g| quantise::coded_by_codebook(g, config.sh_vq, config.sh_joint),
        targets: if config.rate_rounding { &rounds } else { &[] },
    };
    let quantise::Quantisation { mut q, order, targets } = quantise::quantise_classes(&s, &config.steps, &level, &classes);
    if config.sh_vq.iter().any(|&k| k > 0) {
        let w = sig.clone().unwrap_or_else(|| vec![1.0; s.len()]);
        quantise::apply_codebooks(&mut q, &order, &w, config.sh_vq, config.sh_joint, cache.map(|c| &c.codebooks));
    }
    if config.rate_rounding {
        rdoq::round_groups(&mut q, &targets, config.neighbour_tables, cache);
    }
    drop(targets);
    if let Some(view_basis) = &view_basis {
        let trained = config.dc_fit_trained.then(|| quantise::rest_as_trained(&s, &config.steps));
        let dc = quantise::compensate_dc(&mut q, trained.as_ref().unwrap_or(&s), &order, view_basis);
        if config.rate_rounding && !dc.is_empty() {
            rdoq::round_groups(&mut q, &[(Group::ShDc, dc)], config.neighbour_tables, cache);
        }
    }
    let (bytes, report) = encode::write_cached(&q, input, config.learned_tables, config.neighbour_tables, cache);
    Ok((bytes, report, q))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Pruning keeps exactly the Gaussians whose removal error is at or above the threshold: it
    /// never drops a Gaussian whose removal costs more than one it keeps; the significance it
    /// returns is that of the Gaussians it keeps.
    #[test]
    fn pruning_keeps_the_gaussians_whose_removal_costs_most() {
        let s = crate::sample::scene(400, 7);
        let m = Importance::of(&s);
        let err = &m.removal;
        let mut sorted = err.clone();
        sorted.sort_by(f32::total_cmp);
        let t = sorted[sorted.len() / 3];
        let config = EncodeConfig { min_opacity: 0.0, min_removal_error: t, ..EncodeConfig::default() };
        let (kept, kept_sig) = pruned(&s, &config, Some(&m));
        let kept_sig = kept_sig.unwrap();
        assert_eq!(kept.len(), err.iter().filter(|&&v| v >= t).count());
        assert!(kept.len() < s.len() && !kept.is_empty());
        let order: Vec<usize> = (0..s.len()).filter(|&i| err[i] >= t).collect();
        let dropped_max = (0..s.len()).filter(|&i| err[i] < t).fold(f32::NEG_INFINITY, |a, i| a.max(err[i]));
        let kept_min = order.iter().fold(f32::INFINITY, |a, &i| a.min(err[i]));
        assert!(dropped_max < kept_min, "dropped {dropped_max} ≥ kept {kept_min}");
        assert_eq!(kept.positions, order.iter().map(|&i| s.positions[i]).collect::<Vec<_>>());
        assert_eq!(kept_sig, order.iter().map(|&i| m.significance[i]).collect::<Vec<_>>());
        // The two measures rank differently: coverage is not what pruning goes by.
        assert!((0..s.len()).any(|i| (0..s.len()).any(|j| m.significance[i] > m.significance[j] && err[i] < err[j])));
    }

    /// The tail is exactly the ⌊share·n⌋ lowest-ranked Gaussians (ties: later ones first), and
    /// takes its factor only in the levels wholly inside it.
    #[test]
    fn the_tail_is_the_lowest_ranked_share() {
        let sig = [5.0, 1.0, 3.0, 1.0, 9.0, 0.0, 2.0, 7.0];
        let tail = CoarseTail::new(0.5, 2.0);
        assert_eq!(tail.levels(&sig), vec![0, 1, 0, 1, 0, 1, 1, 0]);
        // ⌊0.25·8⌋ = 2: the 0.0 and, of the two 1.0, the later one.
        assert_eq!(CoarseTail { share: 0.25, ..tail }.levels(&sig), vec![0, 0, 0, 1, 0, 1, 0, 0]);
        for off in [CoarseTail::OFF, CoarseTail::new(0.5, 1.0), CoarseTail::new(1.0, 2.0)] {
            assert!(off.is_off() && off.levels(&sig).is_empty());
        }
        assert!(CoarseTail { share: 0.1, ..tail }.levels(&sig).is_empty(), "⌊0.8⌋ = 0: no tail");
        assert_eq!(tail.level_factors(&[4, 4]), Some(vec![1.0, 2.0]));
        // Progressive levels 1/16, 1/16, 1/8, 1/4, 1/2 of 64: a share of 3/4 covers the last two.
        let levels = [4, 4, 8, 16, 32];
        assert_eq!(CoarseTail { share: 0.75, ..tail }.level_factors(&levels), Some(vec![1.0, 1.0, 1.0, 2.0, 2.0]));
        assert_eq!(CoarseTail { share: 0.25, ..tail }.level_factors(&levels), None, "no level lies within the last quarter");
        assert_eq!(CoarseTail::OFF.level_factors(&levels), None);
    }

    /// `encode` measures the importance a config needs; given precomputed, the same bytes.
    #[test]
    fn encode_measures_the_importance_it_needs() {
        let s = crate::sample::scene(300, 8);
        let m = Importance::of(&s);
        let config = EncodeConfig { min_removal_error: 0.5, sh_drop: [0.1, 0.1, 0.1], ..EncodeConfig::default() };
        assert!(config.needs_importance() && !EncodeConfig::default().needs_importance());
        let (a, ra, _) = encode(&s, &config).unwrap();
        let (b, _, _) = encode_with(&s, &config, Some(&m)).unwrap();
        assert_eq!(a, b);
        assert!(ra.gaussians < encode(&s, &EncodeConfig::default()).unwrap().1.gaussians);
    }
}

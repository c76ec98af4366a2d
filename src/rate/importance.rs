//! Importance of each Gaussian: how much of the scene, seen from around it, it covers.
//!
//! [`significance`] renders [`views`] — the RD search's evaluation views
//! ([`super::rd::Evaluator`]: [`crate::views::orbit_cameras`], up −y, [`VIEWS`] views) **and** the
//! 24 views of [`crate::views::training_cameras`] (three rings of 8 at 10°, 25° and 40°
//! elevation, azimuths between the evaluation views), all at [`PRUNING_SIZE`]² pixels, the
//! evaluation's resolution (at the search's [`SIZE`]² until session 36: small Gaussians then
//! looked less important than the evaluation finds them, docs/codec.md §19) — and sums,
//! per Gaussian, its blending weight `α·T` over every pixel
//! ([`gscodec_decoder::render::contributions`]). The extra rings keep the measure from being the
//! evaluation's own: a Gaussian that the 8 evaluation views miss but a view a little higher,
//! lower or to the side sees still scores. The unit is pixels of those views: a Gaussian that
//! alone covers one pixel fully in one view scores 1; one that no view sees (culled, off-screen,
//! always under 1/255 alpha or behind opaque Gaussians) scores 0.
//!
//! A scene trained from a dataset is measured from the cameras it was trained for instead:
//! [`significance_on`] its [`dataset_views`] (every training camera, at most [`SIZE`] pixels on
//! its longer side), which the encoder uses for such a scene (`rd::RdViews::significance`).
//!
//! What pruning ranks by is another sum over the same views, [`Importance::removal`]: the squared
//! colour error that removing the Gaussian alone would cause, `Σ ‖T·α·(B − c)‖²` over the
//! pixels (`B` the colour behind it, the background included). A Gaussian in front of its own
//! colour covers much and costs nothing to drop; coverage alone would keep it. [`Importance`]
//! holds both measures of one scene.
//!
//! [`levels`] cuts the Gaussians, most significant first, into the importance levels of a
//! progressive file (SPEC §3.1): sizes doubling, 1/16, 1/16, 1/8, 1/4, 1/2 of them.

use gscodec_decoder::render::{contributions, contributions_and_removal_errors};
use gscodec_decoder::{RenderOptions, Splats};
use rayon::prelude::*;

use super::rd::{PRUNING_SIZE, SIZE, VIEWS};
use crate::views::{orbit_cameras, training_cameras, UpAxis};

/// The cameras [`significance`] sums over (see the module docs).
pub fn views(scene: &Splats) -> Vec<gscodec_decoder::Camera> {
    let up = UpAxis::NegY.vector();
    let mut cams = orbit_cameras(scene, VIEWS, PRUNING_SIZE, PRUNING_SIZE, up);
    cams.extend(training_cameras(scene, VIEWS, PRUNING_SIZE, PRUNING_SIZE, up));
    cams
}

/// The cameras a scene trained from `dataset` is significant from: every training camera, scaled
/// down to at most [`SIZE`] pixels on its longer side (at its own size when smaller). Held-out
/// cameras are not among them.
pub fn dataset_views(dataset: &crate::io::Dataset) -> Vec<gscodec_decoder::Camera> {
    dataset.split(crate::io::Split::Train).iter().map(|f| crate::views::fit_within(&f.camera, SIZE)).collect()
}

/// Per Gaussian, the sum over [`views`] of its blending weight `α·T` over all pixels (see the
/// module docs). Deterministic; the views are summed in order, in f64.
pub fn significance(scene: &Splats) -> Vec<f32> {
    significance_on(scene, &views(scene))
}

/// [`significance`] over the cameras `cams` (e.g. [`dataset_views`]).
pub fn significance_on(scene: &Splats, cams: &[gscodec_decoder::Camera]) -> Vec<f32> {
    // The weights do not depend on colour: skip the SH bands.
    let opts = RenderOptions { max_sh_degree: 0, ..RenderOptions::default() };
    let [significance] = sum_over(scene.len(), cams, |cam| [contributions(scene, cam, &opts)]);
    significance
}

/// `per_view` (`K` values per each of `n` Gaussians) of every camera, summed per Gaussian:
/// rendered in parallel, then summed in order in f64 (the same sums on any number of threads).
fn sum_over<const K: usize>(
    n: usize,
    cams: &[gscodec_decoder::Camera],
    per_view: impl Fn(&gscodec_decoder::Camera) -> [Vec<f32>; K] + Sync + Send,
) -> [Vec<f32>; K] {
    let views: Vec<[Vec<f32>; K]> = cams.par_iter().map(&per_view).collect();
    sums(n, &views)
}

/// The per-Gaussian sums of `views` (`K` vectors of `n` values each), in their order, in f64.
fn sums<const K: usize>(n: usize, views: &[[Vec<f32>; K]]) -> [Vec<f32>; K] {
    std::array::from_fn(|k| {
        let mut sum = vec![0.0f64; n];
        for view in views {
            for (s, &c) in sum.iter_mut().zip(&view[k]) {
                *s += c as f64;
            }
        }
        sum.into_iter().map(|v| v as f32).collect()
    })
}

/// [`Importance::view_basis`] of `scene` seen from `cams`, `weights` each camera's blending
/// weight per Gaussian ([`contributions`]). Each Gaussian sums its views in order, in f64.
fn view_basis<'a>(scene: &Splats, cams: &[gscodec_decoder::Camera], weights: impl Iterator<Item = &'a [f32]>) -> Vec<[f32; 15]> {
    let weights: Vec<&[f32]> = weights.collect();
    let centres: Vec<glam::Vec3> = cams.iter().map(gscodec_decoder::Camera::center).collect();
    (0..scene.len())
        .into_par_iter()
        .map(|i| {
            let p = glam::Vec3::from(scene.positions[i]);
            let (mut sum, mut total) = ([0.0f64; 15], 0.0f64);
            for (w, c) in weights.iter().map(|w| w[i]).zip(&centres).filter(|x| x.0 > 0.0) {
                let basis = gscodec_decoder::math::sh_basis(3, (p - *c).normalize_or_zero());
                sum.iter_mut().zip(&basis[1..]).for_each(|(s, &b)| *s += f64::from(w) * f64::from(b));
                total += f64::from(w);
            }
            if total > 0.0 {
                sum.map(|s| (s / total) as f32)
            } else {
                [0.0; 15]
            }
        })
        .collect()
}

/// Both measures of a scene's Gaussians from one set of views: `significance` (coverage, which
/// orders the importance classes and weights SH band dropping) and `removal` (what pruning
/// ranks by); and where each Gaussian is seen from, `view_basis`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Importance {
    /// [`significance_on`].
    pub significance: Vec<f32>,
    /// Per Gaussian, the sum over the views of the squared colour error its removal alone causes
    /// ([`gscodec_decoder::render::removal_errors`]).
    pub removal: Vec<f32>,
    /// Per Gaussian, the SH rest basis functions `Y_1 … Y_15` ([`gscodec_decoder::math::sh_basis`]
    /// at degree 3) at its view direction, averaged over the views with its blending weight in
    /// each as the weight; zeros for a Gaussian no view sees. The colour a change `Δc_k` of its
    /// rest coefficients adds is, in the least-squares sense over those views, the constant
    /// `Σ_k Δc_k · view_basis[k]`, which the DC can take back ([`super::quantise::compensate_dc`]).
    /// Empty for a scene without SH rest bands.
    pub view_basis: Vec<[f32; 15]>,
}

impl Importance {
    /// From the standard [`views`], on black (the orbit views' background).
    pub fn of(scene: &Splats) -> Self {
        Self::on(scene, &views(scene), [0.0; 3])
    }

    /// From the cameras `cams`, rendered on `background`: both measures from one pass over each
    /// view's pixels ([`contributions_and_removal_errors`]).
    pub fn on(scene: &Splats, cams: &[gscodec_decoder::Camera], background: [f32; 3]) -> Self {
        let opts = RenderOptions { background, ..RenderOptions::default() };
        let views: Vec<[Vec<f32>; 2]> = cams
            .par_iter()
            .map(|cam| {
                let (weights, errors) = contributions_and_removal_errors(scene, cam, &opts);
                [weights, errors]
            })
            .collect();
        let [significance, removal] = sums(scene.len(), &views);
        let view_basis = if scene.sh_degree == 0 { Vec::new() } else { view_basis(scene, cams, views.iter().map(|v| &v[0][..])) };
        Importance { significance, removal, view_basis }
    }

    /// Per Gaussian, what the importance classes' coarse tail ranks by ([`super::CoarseTail`]):
    /// `√(removal × significance)`, the geometric mean of the squared error its removal causes
    /// and its coverage. Quantisation noise on a Gaussian costs in proportion to neither alone:
    /// coverage is linear in the blending weight where a colour error's cost is quadratic, and
    /// the removal error is the largest change, not a step's (docs/codec.md §34 measured both
    /// and this mean).
    pub fn tail_rank(&self) -> Vec<f32> {
        self.removal.iter().zip(&self.significance).map(|(&r, &s)| (r.max(0.0) * s.max(0.0)).sqrt()).collect()
    }

    /// Gaussians measured.
    pub fn len(&self) -> usize {
        self.significance.len()
    }

    /// Whether no Gaussian is measured.
    pub fn is_empty(&self) -> bool {
        self.significance.is_empty()
    }
}

/// Number of importance levels of a progressive file.
pub const LEVELS: u32 = 5;

/// The importance level of every Gaussian given their `significance`: ranked by decreasing
/// significance (ties by index), level `l` holds the ranks below `⌈N / 2^(LEVELS−1−l)⌉` not in
/// an earlier level — the top 1/16, the next 1/16, then 1/8, 1/4 and the remaining 1/2.
pub fn levels(significance: &[f32]) -> Vec<u8> {
    let n = significance.len();
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| significance[b].total_cmp(&significance[a]).then(a.cmp(&b)));
    let end = |l: u32| n.div_ceil(1 << (LEVELS - 1 - l));
    let mut level = vec![0u8; n];
    let mut l = 0;
    for (rank, &i) in order.iter().enumerate() {
        while rank >= end(l) {
            l += 1;
        }
        level[i] = l as u8;
    }
    level
}

#[cfg(test)]
mod tests {
    use super::*;
    use gscodec_decoder::testkit::random_splats;

    /// The importance views begin with the evaluation's own cameras — the 8 orbit views at
    /// 256² that `eval --reference --orbit 8` and `--target-psnr` render — and every view is at
    /// that size, so a Gaussian ranks by what it adds where the file is judged.
    #[test]
    fn importance_is_measured_at_the_evaluations_resolution() {
        use crate::encoder::{ORBIT_SIZE, ORBIT_VIEWS};
        let s = random_splats(50, 1, 4);
        let cams = views(&s);
        let eval = orbit_cameras(&s, ORBIT_VIEWS, ORBIT_SIZE, ORBIT_SIZE, UpAxis::NegY.vector());
        assert_eq!(cams.len(), 32);
        assert_eq!(cams[..ORBIT_VIEWS], eval[..]);
        assert!(cams.iter().all(|c| (c.width, c.height) == (ORBIT_SIZE, ORBIT_SIZE)));
    }

    #[test]
    fn significance_sums_the_views_and_ignores_what_no_view_sees() {
        let mut s = random_splats(300, 1, 4);
        // Far along the up axis (−y): every camera looks 10–40° down, so none sees it.
        s.push([0.0, -1000.0, 0.0], [-1.0; 3], [1.0, 0.0, 0.0, 0.0], 4.0, [0.0; 3], &[0.0; 9]);
        let sig = significance(&s);
        assert_eq!(sig.len(), s.len());
        assert_eq!(sig[300], 0.0);
        // The total is the area the scene covers in the views: Σ_views Σ_pixels (1 − T_final),
        // read off renders of black Gaussians on white.
        let mut black = s.clone();
        black.sh_dc.iter_mut().for_each(|c| *c = [-10.0; 3]);
        let opts = RenderOptions { background: [1.0; 3], max_sh_degree: 0 };
        let covered: f64 = views(&s)
            .iter()
            .map(|c| gscodec_decoder::render::render(&black, c, &opts).data.iter().step_by(3).map(|&t| 1.0 - t as f64).sum::<f64>())
            .sum();
        let total: f64 = sig.iter().map(|&v| v as f64).sum();
        assert!(covered > 1000.0, "{covered}");
        assert!((total - covered).abs() < 1e-4 * covered, "Σ significance {total} vs covered {covered}");
    }

    /// A Gaussian at the orbit's centre is seen from every view at the same angle below the
    /// horizon, so its mean direction is straight down along the up axis and the band-1 basis
    /// averages to `(−C1·sin e, 0, 0)` (Y₁ = −C1·y); a Gaussian no view sees gets zeros.
    #[test]
    fn the_view_basis_is_the_basis_at_the_mean_view() {
        let mut s = Splats::new(1);
        s.push([0.0; 3], [-2.0; 3], [1.0, 0.0, 0.0, 0.0], 4.0, [0.0; 3], &[0.0; 9]);
        // Around it, far enough not to hide it, and seen: the orbit frames the robust extent.
        for p in [[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [0.0, 0.3, 0.0], [0.0, -0.3, 0.0]] {
            s.push(p, [-3.0; 3], [1.0, 0.0, 0.0, 0.0], 4.0, [0.0; 3], &[0.0; 9]);
        }
        let (centre, _) = crate::views::orbit_frame(&s);
        s.positions[0] = centre.into();
        let cams = orbit_cameras(&s, 8, 64, 64, UpAxis::NegY.vector());
        s.push([0.0, -1000.0, 0.0], [-1.0; 3], [1.0, 0.0, 0.0, 0.0], 4.0, [0.0; 3], &[0.0; 9]);
        let m = Importance::on(&s, &cams, [0.0; 3]);
        let c1 = gscodec_decoder::math::sh_basis(1, glam::Vec3::Y)[1].abs();
        let e = crate::views::ORBIT_ELEVATION;
        let vb = m.view_basis[0];
        assert!(m.significance[0] > 8.0, "every view sees it");
        assert!((vb[0] - (-c1 * e.sin())).abs() < 1e-4, "{vb:?}, elevation {e}");
        assert!(vb[1].abs() < 1e-3 && vb[2].abs() < 1e-3, "{vb:?}");
        assert_eq!(m.view_basis[7], [0.0; 15], "unseen");
        assert!(Importance::on(&Splats::new(0), &cams, [0.0; 3]).view_basis.is_empty(), "no rest bands, no basis");
    }

    /// The coarse tail takes a Gaussian that covers much but whose removal costs nothing (a
    /// large one the colour of the background, nothing behind it) before a small distinct one
    /// that covers less: coverage alone would take the small one first.
    #[test]
    fn the_tail_ranks_by_removal_error_and_coverage_together() {
        let mut s = Splats::new(0);
        // Colour 0.5 + C₀·dc clamps to black, the background of `Importance::of`. It lies 1.5
        // below the other along the up axis (−y): the views look 10–40° down, so no line of
        // sight meets both.
        s.push([0.0, 1.5, 0.0], [-1.5; 3], [1.0, 0.0, 0.0, 0.0], 6.0, [-2.0; 3], &[]);
        s.push([0.0; 3], [-3.0; 3], [1.0, 0.0, 0.0, 0.0], 6.0, [2.0, -1.0, -1.0], &[]);
        let m = Importance::of(&s);
        assert!(m.significance[0] > 4.0 * m.significance[1], "the black one covers more: {:?}", m.significance);
        assert!(m.removal[1] > 0.0 && m.removal[0] == 0.0, "only the red one's removal shows: {:?}", m.removal);
        let rank = m.tail_rank();
        assert!(rank[0] < rank[1], "{rank:?}");
        assert_eq!(rank[1], (m.removal[1] * m.significance[1]).sqrt());
        let tail = crate::rate::CoarseTail::new(0.5, 2.0);
        assert_eq!(tail.levels(&rank), vec![1, 0], "the red one keeps the fine steps");
        assert_eq!(tail.levels(&m.significance), vec![0, 1], "by coverage alone it would not");
    }

    #[test]
    fn levels_double_and_follow_significance() {
        let sig: Vec<f32> = (0..100).map(|i| ((i * 37) % 100) as f32).collect();
        let level = levels(&sig);
        let sizes: Vec<usize> = (0..LEVELS as u8).map(|l| level.iter().filter(|&&x| x == l).count()).collect();
        assert_eq!(sizes, vec![7, 6, 12, 25, 50]); // ends at ⌈100/16⌉, ⌈100/8⌉, 25, 50, 100
        for i in 0..100 {
            for j in 0..100 {
                if sig[i] > sig[j] {
                    assert!(level[i] <= level[j]);
                }
            }
        }
        assert_eq!(levels(&[1.0, 3.0, 2.0]), vec![4, 0, 3]); // ends 1, 1, 1, 2, 3: levels 1 and 2 empty
        assert!(levels(&[]).is_empty());
    }
}

//! Vector quantisation of SH band rows: a significance-weighted k-means codebook over the
//! quantised integer rows of one band (each row = the band's `C` channels of one Gaussian), so
//! that a band can be stored as a codebook plus one index per Gaussian.
//!
//! Deterministic: k-means++ seeding with the project's [`Rng`], at most [`ITERATIONS`] Lloyd
//! iterations (fewer only when the centres stop moving, which leaves the codebook as it is),
//! training on a deterministic subsample of at most [`TRAIN_ROWS`] rows; the
//! assignments run in parallel (rayon, each row independent) and the centroid sums are
//! accumulated sequentially in row order, so the codebook does not depend on the thread count.

use std::collections::HashMap;
use std::hash::Hash;
use std::sync::{Arc, Mutex};

use gscodec_decoder::rng::Rng;
use rayon::prelude::*;

/// Rows k-means trains on at most (a deterministic subsample beyond).
pub const TRAIN_ROWS: usize = 32_768;
/// Lloyd iterations.
pub const ITERATIONS: usize = 8;

/// A band's codebook and the index of every row.
#[derive(Debug, Clone, PartialEq)]
pub struct Codebook {
    /// Channels per row.
    pub channels: usize,
    /// `K × channels` integer values, row-major.
    pub rows: Vec<i32>,
    /// One index per input row, `< K`.
    pub index: Vec<u32>,
}

impl Codebook {
    pub fn len(&self) -> usize {
        self.rows.len() / self.channels.max(1)
    }

    pub fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }

    /// Row `i` of the codebook.
    pub fn row(&self, i: usize) -> &[i32] {
        &self.rows[i * self.channels..][..self.channels]
    }

    /// Channel `j` of the codebook rows (`K` values).
    pub fn column(&self, j: usize) -> Vec<i32> {
        (0..self.len()).map(|i| self.rows[i * self.channels + j]).collect()
    }

    /// The codebook of channels `cols` of these rows (every row kept, duplicates too), with
    /// `index`.
    pub fn columns(&self, cols: std::ops::Range<usize>, index: Vec<u32>) -> Codebook {
        let rows = self.rows.chunks_exact(self.channels.max(1)).flat_map(|r| r[cols.clone()].iter().copied()).collect();
        Codebook { channels: cols.len(), rows, index }
    }

    /// The rows of `parts` side by side (each part's channels after the previous part's), with
    /// the first part's index: the inverse of [`Codebook::columns`].
    ///
    /// # Panics
    /// If the parts do not have the same number of rows.
    pub fn beside(parts: &[&Codebook]) -> Codebook {
        let k = parts.first().map_or(0, |p| p.len());
        assert!(parts.iter().all(|p| p.len() == k), "parts of as many rows");
        let rows = (0..k).flat_map(|r| parts.iter().flat_map(move |p| p.row(r).iter().copied())).collect();
        Codebook { channels: parts.iter().map(|p| p.channels).sum(), rows, index: parts.first().map_or(Vec::new(), |p| p.index.clone()) }
    }

    /// The rows the codebook restores, channel-major like [`super::Quantised::groups`]:
    /// `[channel][row]`.
    pub fn decoded_channels(&self) -> Vec<Vec<i32>> {
        (0..self.channels).map(|j| self.index.iter().map(|&i| self.rows[i as usize * self.channels + j]).collect()).collect()
    }
}

/// The distinct rows of `chans`, sorted, with every row's index: a lossless codebook (a palette).
pub fn palette(chans: &[Vec<i32>]) -> Codebook {
    let c = chans.len();
    let n = chans.first().map_or(0, Vec::len);
    let all: Vec<i32> = (0..n).flat_map(|i| chans.iter().map(move |ch| ch[i])).collect();
    let row = |i: usize| &all[i * c..][..c];
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| row(a).cmp(row(b)));
    let mut rows: Vec<i32> = Vec::new();
    let mut index = vec![0u32; n];
    let mut last: Option<&[i32]> = None;
    for &i in &order {
        let r = row(i);
        if last != Some(r) {
            rows.extend_from_slice(r);
            last = Some(r);
        }
        index[i] = (rows.len() / c.max(1) - 1) as u32;
    }
    Codebook { channels: c, rows, index }
}

/// The squared distance of `a` and `b`, summed in order ([`dist2_below`] with no bound).
fn dist2(a: &[f32], b: &[f32]) -> f32 {
    dist2_below(a, b, f32::INFINITY)
}

/// `dist2(a, b)` when it is below `bound`, else some value ≥ `bound`: the sum stops as soon as
/// it reaches the bound (its terms are not negative, so it can only grow).
fn dist2_below(a: &[f32], b: &[f32], bound: f32) -> f32 {
    let mut d = 0.0f32;
    for (x, y) in a.iter().zip(b) {
        d += (x - y) * (x - y);
        if d >= bound {
            break;
        }
    }
    d
}

/// How many directions a [`Basis`] has: a point's coordinates along them are [`Coords`].
const AXES: usize = 6;

/// A point's coordinates along the directions of a [`Basis`], each summed in order in `f64`.
type Coords = [f64; AXES];

/// `AXES` orthonormal directions (zero vectors beyond the rows' `c` channels). The squared
/// distance of two points' [`Coords`] is at most their squared distance, which lets a search
/// pass over a centre for a few multiplications instead of `c`. The first direction is the one
/// [`Centres`] sorts along.
struct Basis {
    axes: [Vec<f64>; AXES],
}

impl Basis {
    /// The directions along which `rows` (`c` values each, those listed in `which`) vary most:
    /// principal components by power iteration on their covariance, each kept orthogonal to the
    /// ones before, sums in order (deterministic). The first starts from the channel of largest
    /// variance (its unit vector where the rows do not vary), each later one from the channel
    /// that the earlier directions leave most of, times its variance. The wider the centres
    /// spread along them, the fewer [`Centres::nearest`] measures.
    fn principal(rows: &[f32], c: usize, which: &[usize]) -> Basis {
        let m = which.len().max(1) as f64;
        let mut mean = vec![0.0f64; c];
        for &i in which {
            mean.iter_mut().zip(&rows[i * c..][..c]).for_each(|(s, &x)| *s += f64::from(x));
        }
        mean.iter_mut().for_each(|s| *s /= m);
        let mut cov = vec![0.0f64; c * c];
        for &i in which {
            let r = &rows[i * c..][..c];
            for a in 0..c {
                let da = f64::from(r[a]) - mean[a];
                for b in 0..c {
                    cov[a * c + b] += da * (f64::from(r[b]) - mean[b]);
                }
            }
        }
        let mut axes: [Vec<f64>; AXES] = std::array::from_fn(|_| vec![0.0; c]);
        for j in 0..AXES.min(c) {
            let (done, rest) = axes.split_at_mut(j);
            // The channel whose unit vector the earlier directions leave most of, by its variance
            // (for the first direction: the widest channel); by what is left alone where no
            // channel varies.
            let left: Vec<f64> = (0..c).map(|ch| norm(&orthogonal_to(channel(c, ch), done))).collect();
            let first_max = |score: &dyn Fn(usize) -> f64| (0..c).fold(0, |b, ch| if score(ch) > score(b) { ch } else { b });
            let widest = first_max(&|ch| left[ch] * cov[ch * c + ch]);
            let start = if left[widest] * cov[widest * c + widest] > 0.0 { widest } else { first_max(&|ch| left[ch]) };
            let s = orthogonal_to(channel(c, start), done);
            let n = norm(&s);
            let mut v: Vec<f64> = s.into_iter().map(|x| x / n).collect();
            for _ in 0..POWER_STEPS {
                let w = orthogonal_to((0..c).map(|a| (0..c).map(|b| cov[a * c + b] * v[b]).sum()).collect(), done);
                let n = norm(&w);
                if !(n > 0.0 && n.is_finite()) {
                    break;
                }
                v = w.into_iter().map(|x| x / n).collect();
            }
            rest[0] = v;
        }
        Basis { axes }
    }

    /// `axis` (a unit vector) first, completed by the channels' unit vectors made orthogonal to
    /// it and to one another (those that stay non-zero; zero vectors where too few do).
    #[cfg(test)]
    fn around(axis: &[f64]) -> Basis {
        let c = axis.len();
        let mut axes: [Vec<f64>; AXES] = std::array::from_fn(|_| vec![0.0; c]);
        axes[0] = axis.to_vec();
        let mut next = 1;
        for ch in 0..c {
            if next == AXES {
                break;
            }
            let v = orthogonal_to(channel(c, ch), &axes[..next]);
            let n = norm(&v);
            if n > 0.1 {
                axes[next] = v.into_iter().map(|x| x / n).collect();
                next += 1;
            }
        }
        Basis { axes }
    }

    /// `row`'s coordinates.
    fn coords(&self, row: &[f32]) -> Coords {
        std::array::from_fn(|j| project(row, &self.axes[j]))
    }
}

/// The unit vector of channel `ch` among `c`.
fn channel(c: usize, ch: usize) -> Vec<f64> {
    (0..c).map(|b| f64::from(u8::from(b == ch))).collect()
}

/// `v` less its components along the orthonormal `axes`, one after another (Gram–Schmidt).
fn orthogonal_to(mut v: Vec<f64>, axes: &[Vec<f64>]) -> Vec<f64> {
    for u in axes {
        let d: f64 = v.iter().zip(u).map(|(x, y)| x * y).sum();
        v.iter_mut().zip(u).for_each(|(x, y)| *x -= d * y);
    }
    v
}

fn norm(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum::<f64>().sqrt()
}

/// The squared distance of two points' coordinates: at most the points' squared distance.
fn below(a: &Coords, b: &Coords) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum()
}

/// Some of the centres `cen` (`K × c`, row-major), ordered along a [`Basis`]'s first direction,
/// for [`Centres::nearest`].
struct Centres<'a> {
    cen: &'a [f32],
    c: usize,
    /// The centres' indices by their first coordinate (ties by index), their coordinates in that
    /// order, and the centres in that order (so that the search reads them in sequence).
    order: Vec<u32>,
    keys: Vec<Coords>,
    sorted: Vec<f32>,
}

/// `row · axis`, summed in order in `f64`.
fn project(row: &[f32], axis: &[f64]) -> f64 {
    row.iter().zip(axis).map(|(&x, &u)| f64::from(x) * u).sum()
}

/// How much a coordinate gap may exceed the distance through rounding, as a share: the gap and
/// the unit axes are `f64` (relative error near 1e-15), the distance an `f32` sum of at most a
/// few dozen terms (relative error below 1e-5); a centre is passed over only when its squared
/// gap is this far above the best distance.
const SLACK: f64 = 1e-4;

impl<'a> Centres<'a> {
    /// The centres `which` of `cen`.
    fn new(cen: &'a [f32], c: usize, basis: &Basis, which: Vec<u32>) -> Centres<'a> {
        let mut keyed: Vec<(Coords, u32)> = which.into_iter().map(|k| (basis.coords(&cen[k as usize * c..][..c]), k)).collect();
        keyed.sort_by(|a, b| a.0[0].total_cmp(&b.0[0]).then(a.1.cmp(&b.1)));
        let (keys, order): (Vec<Coords>, Vec<u32>) = keyed.into_iter().unzip();
        let sorted = order.iter().flat_map(|&k| &cen[k as usize * c..][..c]).copied().collect();
        Centres { cen, c, order, keys, sorted }
    }

    fn centre(&self, k: u32) -> &[f32] {
        &self.cen[k as usize * self.c..][..self.c]
    }

    /// Index of the centre nearest to `row` among these and `hint` (any index of `cen`), the
    /// first of equals; `x` is `row`'s [`Coords`] in the basis the centres were ordered by.
    /// `hint` is measured first, so that its distance bounds the others' sums from the start.
    /// The centres are visited outwards from `row`'s first coordinate; a direction ends where
    /// the squared gap of the first coordinates — at most the squared distance — exceeds the
    /// best distance by more than rounding could ([`SLACK`]), and a centre whose squared
    /// coordinate distance does is passed over unmeasured. Over all the centres the answer does
    /// not depend on the hint or the basis, only the time.
    fn nearest(&self, row: &[f32], x: &Coords, hint: u32) -> u32 {
        let mut best = (dist2(row, self.centre(hint)), hint);
        let visit = |pos: usize, best: &mut (f32, u32)| {
            let key = &self.keys[pos];
            let gap = x[0] - key[0];
            if gap * gap * (1.0 - SLACK) > f64::from(best.0) {
                return false;
            }
            if below(x, key) * (1.0 - SLACK) > f64::from(best.0) {
                return true;
            }
            let k = self.order[pos];
            // An index below the best one also wins a tie.
            let bound = if k < best.1 { f32::from_bits(best.0.to_bits() + 1) } else { best.0 };
            let d = dist2_below(row, &self.sorted[pos * self.c..][..self.c], bound);
            if k != best.1 && (d < best.0 || (d == best.0 && k < best.1)) {
                *best = (d, k);
            }
            true
        };
        let start = self.keys.partition_point(|k| k[0] < x[0]);
        for pos in start..self.keys.len() {
            if !visit(pos, &mut best) {
                break;
            }
        }
        for pos in (0..start).rev() {
            if !visit(pos, &mut best) {
                break;
            }
        }
        best.1
    }
}

/// Power-iteration steps of [`Basis::principal`]: any orthonormal directions are a valid basis,
/// so directions short of converged cost time, never the result.
const POWER_STEPS: usize = 32;

/// The distinct rows (indices into `pal`, the palette of a band's rows) k-means trains on, and
/// their weights: those of a deterministic subsample of at most [`TRAIN_ROWS`] rows, drawn with
/// `rng` when there are more. k-means of rows of which some are equal is k-means of the
/// distinct rows, each weighted by the sum of its copies' weights (a seeding draw picks a value
/// with the same probability, and a centroid is the same weighted mean): quantised SH rows
/// repeat (a third to a half of a band's rows, the zero row most). A zero-weight row still
/// counts a little, so that unseen rows are not ignored.
fn training_rows(pal: &Codebook, weights: &[f32], rng: &mut Rng) -> (Vec<usize>, Vec<f64>) {
    let n = pal.index.len();
    let sample: Vec<usize> = if n > TRAIN_ROWS {
        let mut idx: Vec<usize> = (0..n).collect();
        rng.shuffle(&mut idx);
        idx.truncate(TRAIN_ROWS);
        idx.sort_unstable();
        idx
    } else {
        (0..n).collect()
    };
    let mut mass = vec![0.0f64; pal.len()];
    for &i in &sample {
        mass[pal.index[i] as usize] += f64::from(weights[i].max(0.0)) + 1e-6;
    }
    let train: Vec<usize> = (0..pal.len()).filter(|&d| mass[d] > 0.0).collect();
    let w = train.iter().map(|&d| mass[d]).collect();
    (train, w)
}

/// A codebook of at most `k` rows for the band rows `chans[channel][row]`, each row weighted by
/// `weights[row]` (significance: how much of the views the Gaussian covers): k-means on the
/// integer rows, centroids rounded to integers. When the band has at most `k` distinct rows the
/// codebook is exactly those rows ([`palette`], lossless).
///
/// # Panics
/// If `weights` is not one value per row, or `k` is 0.
pub fn kmeans(chans: &[Vec<i32>], weights: &[f32], k: usize, seed: u64) -> Codebook {
    kmeans_scaled(chans, &vec![1.0; chans.len()], weights, k, seed)
}

/// [`kmeans`] with the distance of channel `j` measured in units of `scale[j]` (a row's value
/// `x` counts as `x · scale[j]`): a codebook of channels quantised with different steps, in
/// the dequantised values' squared error. All scales 1: [`kmeans`].
///
/// # Panics
/// As [`kmeans`], and if `scale` is not one positive value per channel.
pub fn kmeans_scaled(chans: &[Vec<i32>], scale: &[f32], weights: &[f32], k: usize, seed: u64) -> Codebook {
    assert!(k > 0, "k ≥ 1");
    assert!(scale.len() == chans.len() && scale.iter().all(|&s| s > 0.0), "one positive scale per channel");
    let n = chans.first().map_or(0, Vec::len);
    assert_eq!(weights.len(), n, "one weight per row");
    let pal = palette(chans);
    if pal.len() <= k {
        return pal;
    }
    let c = chans.len();
    let mut rng = Rng::new(seed);
    let (train, w) = training_rows(&pal, weights, &mut rng);
    let rows = scaled(&pal.rows, scale);
    let row = |d: usize| &rows[d * c..][..c];
    // k-means++ seeding (weighted D² sampling), distances kept up to date per new centre.
    let mut centroids: Vec<f32> = Vec::with_capacity(k * c);
    // `p(j)` for j < `n` are the draw's weights, `total` their sum in order.
    let pick = |rng: &mut Rng, n: usize, total: f64, p: &dyn Fn(usize) -> f64| -> usize {
        let mut t = rng.uniform_f64() * total;
        for j in 0..n {
            let x = p(j);
            if t < x {
                return j;
            }
            t -= x;
        }
        (0..n).rposition(|j| p(j) > 0.0).unwrap_or(0)
    };
    let first = pick(&mut rng, w.len(), w.iter().sum(), &|j| w[j]);
    centroids.extend_from_slice(row(train[first]));
    let mut d2: Vec<f32> = train.par_iter().map(|&i| dist2(row(i), &centroids[..c])).collect();
    // The basis of the nearest-centre search; in the seeding, a row whose coordinates are
    // farther from the new centre's than its distance so far cannot come nearer (as in
    // `Centres::nearest`) and is passed over.
    let basis = Basis::principal(&rows, c, &train);
    let along: Vec<Coords> = train.iter().map(|&i| basis.coords(row(i))).collect();
    // Each training row's nearest centre so far, the first of equals.
    let mut assign = vec![0u32; train.len()];
    while centroids.len() < k * c {
        let p = |j: usize| f64::from(d2[j]) * w[j];
        // The weights are not negative: they sum to 0 only when all are 0.
        let total: f64 = (0..d2.len()).map(p).sum();
        if total <= 0.0 {
            break; // fewer distinct rows in the sample than k
        }
        let j = pick(&mut rng, d2.len(), total, &p);
        let start = centroids.len();
        centroids.extend_from_slice(row(train[j]));
        let (cen, at) = (&centroids[start..], (start / c) as u32);
        let key = basis.coords(cen);
        d2.par_iter_mut().zip(&mut assign).zip(&train).zip(&along).for_each(|(((d, a), &i), x)| {
            if below(x, &key) * (1.0 - SLACK) > f64::from(*d) {
                return;
            }
            let new = dist2_below(row(i), cen, *d);
            if new < *d {
                (*d, *a) = (new, at);
            }
        });
    }
    let kk = centroids.len() / c;
    // Lloyd iterations on the training rows; sums in row order (f64). Before each, `assign`
    // holds every row's nearest centre (the first of equals) as the centres stood before they
    // last moved — the seeding's is that for its centres — so a row whose centre did not move
    // can only go to a centre that did: it is measured against those alone, and the others
    // against all.
    let mut moved = vec![false; kk];
    for it in 0..ITERATIONS {
        if it > 0 {
            let all = Centres::new(&centroids, c, &basis, (0..kk as u32).collect());
            let some = Centres::new(&centroids, c, &basis, (0..kk as u32).filter(|&a| moved[a as usize]).collect());
            assign = train
                .par_iter()
                .zip(&along)
                .zip(&assign)
                .map(|((&i, x), &a)| {
                    let centres = if moved[a as usize] { &all } else { &some };
                    centres.nearest(row(i), x, a)
                })
                .collect();
        }
        let mut sum = vec![0.0f64; kk * c];
        let mut mass = vec![0.0f64; kk];
        for ((&i, &a), &wt) in train.iter().zip(&assign).zip(&w) {
            let a = a as usize;
            mass[a] += wt;
            for (s, &x) in sum[a * c..][..c].iter_mut().zip(row(i)) {
                *s += wt * f64::from(x);
            }
        }
        for a in 0..kk {
            moved[a] = false;
            if mass[a] > 0.0 {
                for j in 0..c {
                    let x = (sum[a * c + j] / mass[a]) as f32;
                    moved[a] |= x.to_bits() != centroids[a * c + j].to_bits();
                    centroids[a * c + j] = x;
                }
            }
        }
        if !moved.contains(&true) {
            break; // every later iteration would assign and move the same
        }
    }
    // Integer codebook, then every distinct row to its nearest integer centroid, and every row
    // to its distinct row's.
    let int_rows: Vec<i32> = centroids.iter().enumerate().map(|(i, &x)| (x / scale[i % c]).round() as i32).collect();
    // A training row's last assignment is its hint (the rounded centres moved little).
    let mut hints = vec![0u32; pal.len()];
    train.iter().zip(&assign).for_each(|(&d, &a)| hints[d] = a);
    coded_by(&pal, &rows, int_rows, scale, &basis, &hints)
}

/// Row-major integer rows of `scale.len()` channels as `f32`, channel `j` times `scale[j]`.
fn scaled(rows: &[i32], scale: &[f32]) -> Vec<f32> {
    rows.iter().zip(scale.iter().cycle()).map(|(&x, &s)| x as f32 * s).collect()
}

/// The codebook `rows` (integer, row-major) for the rows `pal` is the palette of, `values` its
/// rows as `f32` in units of `scale` (per channel): each distinct row to its nearest codebook row (searched in `basis`, starting
/// from `hints[d]`), every row to its distinct row's, rows no index uses dropped ([`compact`]).
fn coded_by(pal: &Codebook, values: &[f32], rows: Vec<i32>, scale: &[f32], basis: &Basis, hints: &[u32]) -> Codebook {
    let c = pal.channels;
    let cen = scaled(&rows, scale);
    let centres = Centres::new(&cen, c, basis, (0..(cen.len() / c.max(1)) as u32).collect());
    let nearest: Vec<u32> = (0..pal.len())
        .into_par_iter()
        .map(|d| {
            let row = &values[d * c..][..c];
            centres.nearest(row, &basis.coords(row), hints[d])
        })
        .collect();
    let index = pal.index.iter().map(|&d| nearest[d as usize]).collect();
    compact(Codebook { channels: c, rows, index })
}

/// Codebooks already computed, by their input ([`kmeans_memo`]): an RD-search trial that leaves
/// a band's rows, weights and K as they were (another group's step, the importance classes)
/// finds the band's codebook here instead of running k-means again. Entries are never evicted
/// (a search computes a few dozen).
///
/// A band may also be **pinned** to given rows ([`Memo::pin`]): while it is, a codebook asked
/// for that band is those rows, each row of the band coded by its nearest ([`nearest_rows`]),
/// instead of a k-means of the band's own rows.
#[derive(Default)]
pub struct Memo {
    codebooks: Mutex<HashMap<(u64, u64), Arc<Codebook>>>,
    /// Per SH band 1..=3: (channels, rows) of the band's pinned codebook.
    pinned: Mutex<[Option<Arc<(usize, Vec<i32>)>>; 3]>,
}

impl Memo {
    /// Codebooks held.
    pub fn len(&self) -> usize {
        self.codebooks.lock().expect("not poisoned").len()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Pins SH band `band` (1..=3) to the rows of `cb` (its index is not used), or unpins it.
    ///
    /// # Panics
    /// If `band` is not 1..=3.
    pub fn pin(&self, band: usize, cb: Option<&Codebook>) {
        self.pinned.lock().expect("not poisoned")[band - 1] = cb.map(|c| Arc::new((c.channels, c.rows.clone())));
    }

    /// The rows band `band` (1..=3) is pinned to, if it is.
    fn pinned(&self, band: usize) -> Option<Arc<(usize, Vec<i32>)>> {
        self.pinned.lock().expect("not poisoned")[band - 1].clone()
    }
}

/// The codebook of SH band `band` (1..=3) for its rows `chans[channel][row]`, channel `j` in
/// units of `scale[j]`: the rows `memo` pins the band to when it does ([`nearest_rows`]), else
/// [`kmeans_memo`].
///
/// # Panics
/// If a pinned codebook does not have one value per channel of `chans` in each row.
pub fn band_codebook(memo: Option<&Memo>, band: usize, chans: &[Vec<i32>], scale: &[f32], weights: &[f32], k: usize) -> Arc<Codebook> {
    match memo.and_then(|m| m.pinned(band)) {
        Some(p) => {
            assert_eq!(p.0, chans.len(), "a pinned codebook of the band's channels");
            Arc::new(nearest_rows(chans, scale, &p.1))
        }
        None => kmeans_memo(memo, chans, scale, weights, k, band as u64),
    }
}

/// `rows` (row-major integer rows of `chans.len()` values) as the codebook of `chans`: each row
/// indexes its nearest (the first of equals; channel `j` in units of `scale[j]`, as
/// [`kmeans_scaled`]), and rows no index uses are dropped ([`compact`]).
///
/// # Panics
/// If `rows` is empty while `chans` has rows.
pub fn nearest_rows(chans: &[Vec<i32>], scale: &[f32], rows: &[i32]) -> Codebook {
    let c = chans.len();
    let pal = palette(chans);
    assert!(pal.is_empty() || !rows.is_empty(), "rows to code the band with");
    let cen = scaled(rows, scale);
    let k: Vec<usize> = (0..rows.len() / c.max(1)).collect();
    let basis = Basis::principal(&cen, c, &k);
    coded_by(&pal, &scaled(&pal.rows, scale), rows.to_vec(), scale, &basis, &vec![0; pal.len()])
}

/// [`kmeans_scaled`] of the same arguments, taken from `memo` when it holds it (keyed by a
/// 128-bit hash of every row value, scale and weight bit pattern, `k` and `seed`) and added to
/// it otherwise.
pub fn kmeans_memo(memo: Option<&Memo>, chans: &[Vec<i32>], scale: &[f32], weights: &[f32], k: usize, seed: u64) -> Arc<Codebook> {
    let Some(memo) = memo else { return Arc::new(kmeans_scaled(chans, scale, weights, k, seed)) };
    let bits = |v: &[f32]| v.iter().map(|w| w.to_bits()).collect::<Vec<_>>();
    let key = super::encode::key128(|h| (chans, bits(scale), bits(weights), k, seed).hash(h));
    if let Some(cb) = memo.codebooks.lock().expect("not poisoned").get(&key) {
        return cb.clone();
    }
    let cb = Arc::new(kmeans_scaled(chans, scale, weights, k, seed));
    memo.codebooks.lock().expect("not poisoned").insert(key, cb.clone());
    cb
}

/// Drops the codebook rows no index uses and duplicate rows, renumbering the indices (rows kept
/// in first-use order of the sorted distinct rows, so the result is deterministic).
fn compact(cb: Codebook) -> Codebook {
    let c = cb.channels;
    let mut used = vec![false; cb.len()];
    for &i in &cb.index {
        used[i as usize] = true;
    }
    let mut kept: Vec<usize> = (0..cb.len()).filter(|&i| used[i]).collect();
    kept.sort_by(|&a, &b| cb.row(a).cmp(cb.row(b)).then(a.cmp(&b)));
    let mut new_of = vec![0u32; cb.len()];
    let mut rows: Vec<i32> = Vec::new();
    for &i in &kept {
        if rows.len() < c || rows[rows.len() - c..] != *cb.row(i) {
            rows.extend_from_slice(cb.row(i));
        }
        new_of[i] = (rows.len() / c - 1) as u32;
    }
    let index = cb.index.iter().map(|&i| new_of[i as usize]).collect();
    Codebook { channels: c, rows, index }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn band(n: usize, c: usize, seed: u64) -> (Vec<Vec<i32>>, Vec<f32>) {
        let mut rng = Rng::new(seed);
        let chans = (0..c).map(|_| (0..n).map(|_| (rng.normal() * 4.0).round() as i32).collect()).collect();
        let w = (0..n).map(|_| rng.uniform()).collect();
        (chans, w)
    }

    #[test]
    fn a_palette_is_lossless_and_kmeans_uses_it_when_k_suffices() {
        let chans = vec![vec![1, 2, 1, 3, 2], vec![0, 5, 0, 0, 5]];
        let p = palette(&chans);
        assert_eq!(p.len(), 3);
        assert_eq!(p.decoded_channels(), chans);
        assert_eq!(kmeans(&chans, &[1.0; 5], 3, 1), p);
        let k2 = kmeans(&chans, &[1.0; 5], 2, 1);
        assert!(k2.len() <= 2 && k2.index.iter().all(|&i| (i as usize) < k2.len()));
    }

    /// k-means trains on the distinct rows with their copies' summed weights, so it does not
    /// depend on the order of the rows (with equal weights every sum is exact), and a band
    /// whose rows repeat (as quantised SH rows do, the zero row most) gets the codebook of its
    /// values, each copy the same index.
    #[test]
    fn kmeans_depends_on_the_rows_not_their_order() {
        let mut rng = Rng::new(5);
        let n = 3000;
        // Nine channels of small values, a third of the rows zero: many repeats.
        let chans: Vec<Vec<i32>> =
            (0..9).map(|_| (0..n).map(|i| if i % 3 == 0 { 0 } else { (rng.normal() * 1.2).round() as i32 }).collect()).collect();
        let mut perm: Vec<usize> = (0..n).collect();
        rng.shuffle(&mut perm);
        let shuffled: Vec<Vec<i32>> = chans.iter().map(|c| perm.iter().map(|&i| c[i]).collect()).collect();
        assert!(palette(&chans).len() < n * 3 / 4, "the rows repeat");
        let (a, b) = (kmeans(&chans, &vec![0.5; n], 48, 3), kmeans(&shuffled, &vec![0.5; n], 48, 3));
        assert_eq!(a.rows, b.rows);
        for (j, &i) in perm.iter().enumerate() {
            assert_eq!(a.index[i], b.index[j], "row {i}");
        }
        let row = |i: usize| chans.iter().map(|c| c[i]).collect::<Vec<i32>>();
        for i in 0..n {
            for j in [0, 3, 6] {
                if row(i) == row(j) {
                    assert_eq!(a.index[i], a.index[j], "equal rows {i} and {j}");
                }
            }
        }
    }

    /// A band pinned to a codebook's rows is coded by them (each row by a nearest, unused rows
    /// dropped) whatever its own rows; unpinned, it gets its k-means again.
    #[test]
    fn a_pinned_band_is_coded_with_the_pinned_rows() {
        let (chans, w) = band(1500, 9, 11);
        let base = kmeans(&chans, &w, 64, 2);
        // A third of the rows, as a pruning candidate keeps them.
        let sub: Vec<Vec<i32>> = chans.iter().map(|c| c.iter().step_by(3).copied().collect()).collect();
        let wsub: Vec<f32> = w.iter().step_by(3).copied().collect();
        let ones = vec![1.0; sub.len()];
        let memo = Memo::default();
        memo.pin(2, Some(&base));
        let cb = band_codebook(Some(&memo), 2, &sub, &ones, &wsub, 64);
        assert!(cb.index.iter().all(|&i| (i as usize) < cb.len()));
        let base_rows: Vec<&[i32]> = (0..base.len()).map(|i| base.row(i)).collect();
        let d2 = |a: &[i32], b: &[i32]| a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum::<i32>();
        for i in 0..cb.len() {
            assert!(base_rows.contains(&cb.row(i)), "row {i} is one of the pinned rows");
        }
        for (i, &k) in cb.index.iter().enumerate() {
            let r: Vec<i32> = sub.iter().map(|c| c[i]).collect();
            let best = base_rows.iter().map(|b| d2(&r, b)).min().unwrap();
            assert_eq!(d2(&r, cb.row(k as usize)), best, "row {i} goes to a nearest pinned row");
        }
        // A pinned row no row is near is left out of the codebook.
        let mut far = base.clone();
        far.rows.extend([1000; 9]);
        memo.pin(2, Some(&far));
        let with_far = band_codebook(Some(&memo), 2, &sub, &ones, &wsub, 64);
        assert_eq!(with_far.decoded_channels(), cb.decoded_channels());
        assert!((0..with_far.len()).all(|i| with_far.row(i) != [1000; 9]));
        // Only the pinned band is pinned, and unpinning restores the k-means.
        assert_eq!(*band_codebook(Some(&memo), 1, &sub, &ones, &wsub, 64), kmeans(&sub, &wsub, 64, 1));
        memo.pin(2, None);
        assert_eq!(*band_codebook(Some(&memo), 2, &sub, &ones, &wsub, 64), kmeans(&sub, &wsub, 64, 2));
    }

    /// Channels of a larger scale are coded closer (their error counts more), and every row
    /// indexes a nearest codebook row in the scaled distance.
    #[test]
    fn scaled_channels_are_coded_in_their_units() {
        let (chans, w) = band(2000, 6, 5);
        let scale = [8.0, 8.0, 8.0, 1.0, 1.0, 1.0];
        let (plain, scaled) = (kmeans(&chans, &w, 64, 3), kmeans_scaled(&chans, &scale, &w, 64, 3));
        let err = |cb: &Codebook, js: std::ops::Range<usize>| -> f64 {
            let d = cb.decoded_channels();
            js.map(|j| chans[j].iter().zip(&d[j]).map(|(x, y)| f64::from(x - y).powi(2)).sum::<f64>()).sum()
        };
        assert!(err(&scaled, 0..3) < 0.5 * err(&plain, 0..3), "{} {}", err(&scaled, 0..3), err(&plain, 0..3));
        assert!(err(&scaled, 3..6) > err(&plain, 3..6));
        let d2 = |i: usize, r: &[i32]| -> f64 { (0..6).map(|j| (f64::from(chans[j][i] - r[j]) * f64::from(scale[j])).powi(2)).sum() };
        for (i, &k) in scaled.index.iter().enumerate() {
            let best = (0..scaled.len()).map(|r| d2(i, scaled.row(r))).fold(f64::INFINITY, f64::min);
            assert!(d2(i, scaled.row(k as usize)) <= best * (1.0 + 1e-6), "row {i}");
        }
    }

    #[test]
    fn kmeans_error_falls_as_k_grows_and_rows_go_to_a_nearest_centre() {
        let (chans, w) = band(2000, 9, 3);
        let err = |cb: &Codebook| -> f64 {
            let d = cb.decoded_channels();
            chans.iter().zip(&d).map(|(a, b)| a.iter().zip(b).map(|(x, y)| f64::from(x - y).powi(2)).sum::<f64>()).sum()
        };
        let e: Vec<f64> = [16, 64, 256].iter().map(|&k| err(&kmeans(&chans, &w, k, 7))).collect();
        assert!(e[0] > e[1] && e[1] > e[2], "{e:?}");
        let cb = kmeans(&chans, &w, 64, 7);
        let rows: Vec<f32> = (0..2000).flat_map(|i| chans.iter().map(move |c| c[i] as f32)).collect();
        let cen: Vec<f32> = cb.rows.iter().map(|&x| x as f32).collect();
        for i in 0..2000 {
            let r = &rows[i * 9..][..9];
            let basis = Basis::around(&[1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
            let best = Centres::new(&cen, 9, &basis, (0..cb.len() as u32).collect()).nearest(r, &basis.coords(r), 0) as usize;
            assert_eq!(dist2(r, &cen[cb.index[i] as usize * 9..][..9]), dist2(r, &cen[best * 9..][..9]), "row {i}");
        }
    }

    #[test]
    fn nearest_is_the_first_of_equals_whatever_the_hint_and_axis() {
        // Small integer rows: many centres at equal distance.
        let mut rng = Rng::new(3);
        let mut small = || (rng.uniform_f64() * 4.0).floor() as f32;
        let cen: Vec<f32> = (0..40 * 3).map(|_| small()).collect();
        // The channels, diagonals (centres tie along them too) and the principal axis.
        let s = 0.5f64.sqrt();
        let axes = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [s, s, 0.0], [s, -s, 0.0], [1.0 / 3f64.sqrt(); 3]];
        let mut bases: Vec<Basis> = axes.iter().map(|a| Basis::around(a)).collect();
        bases.push(Basis::principal(&cen, 3, &(0..40).collect::<Vec<_>>()));
        for _ in 0..300 {
            let r = [small(), small(), small()];
            let d: Vec<f32> = cen.chunks_exact(3).map(|c| dist2(&r, c)).collect();
            let first = d.iter().enumerate().fold(0, |b, (k, &x)| if x < d[b] { k } else { b });
            for (basis, hint) in bases.iter().flat_map(|b| (0..40).map(move |h| (b, h))) {
                let centres = Centres::new(&cen, 3, basis, (0..40).collect());
                assert_eq!(centres.nearest(&r, &basis.coords(&r), hint) as usize, first, "row {r:?} axis {:?} hint {hint}", basis.axes[0]);
            }
        }
    }

    #[test]
    fn nearest_matches_a_full_search_on_wide_rows_along_any_axis() {
        // Rows of 21 values up to thousands (f32 sums round), centres close to one another.
        let mut rng = Rng::new(9);
        let c = 21;
        let cen: Vec<f32> = (0..300 * c).map(|i| ((i % 7) as f64 * 900.0 + f64::from(rng.normal()) * 30.0).round() as f32).collect();
        let random: Vec<f64> = (0..c).map(|_| f64::from(rng.normal())).collect();
        let norm = random.iter().map(|x| x * x).sum::<f64>().sqrt();
        let unit: Vec<f64> = random.iter().map(|x| x / norm).collect();
        let bases = [Basis::principal(&cen, c, &(0..300).collect::<Vec<_>>()), Basis::around(&unit)];
        for _ in 0..200 {
            let r: Vec<f32> = (0..c).map(|j| ((j % 7) as f64 * 900.0 + f64::from(rng.normal()) * 40.0).round() as f32).collect();
            let d: Vec<f32> = cen.chunks_exact(c).map(|x| dist2(&r, x)).collect();
            let first = d.iter().enumerate().fold(0, |b, (k, &x)| if x < d[b] { k } else { b });
            for basis in &bases {
                let centres = Centres::new(&cen, c, basis, (0..300).collect());
                assert_eq!(centres.nearest(&r, &basis.coords(&r), 17) as usize, first);
            }
        }
    }

    #[test]
    fn the_principal_axis_is_the_direction_of_most_spread() {
        // Rows along (1, 1, 0)/√2 with a little noise in every channel.
        let mut rng = Rng::new(4);
        let rows: Vec<f32> = (0..500)
            .flat_map(|_| {
                let t = rng.normal() * 50.0;
                [t + rng.normal(), t + rng.normal(), rng.normal()]
            })
            .collect();
        let u = &Basis::principal(&rows, 3, &(0..500).collect::<Vec<_>>()).axes[0];
        assert!((u.iter().map(|x| x * x).sum::<f64>() - 1.0).abs() < 1e-12, "unit length: {u:?}");
        let s = 0.5f64.sqrt();
        assert!((u[0].abs() - s).abs() < 0.01 && (u[1].abs() - s).abs() < 0.01 && u[2].abs() < 0.01 && u[0] * u[1] > 0.0, "{u:?}");
        // No spread: the first channel's unit vector.
        assert_eq!(Basis::principal(&[2.0; 12], 3, &[0, 1, 2, 3]).axes[0], vec![1.0, 0.0, 0.0]);
    }

    #[test]
    fn kmeans_is_the_same_on_one_and_two_threads() {
        let (chans, w) = band(40_000, 15, 5); // more than TRAIN_ROWS: the subsample too
        let run = |t: usize| rayon::ThreadPoolBuilder::new().num_threads(t).build().unwrap().install(|| kmeans(&chans, &w, 128, 11));
        assert_eq!(run(1), run(2));
    }

    /// A basis is orthonormal (zero vectors past the channels), its first direction carries the
    /// most spread, and coordinate distances never exceed distances.
    #[test]
    fn basis_coordinates_bound_distances_from_below() {
        let mut rng = Rng::new(21);
        for c in [2, 3, 9, 21] {
            // Channels of falling spread, correlated through a shared term.
            let mut rows = Vec::with_capacity(400 * c);
            for _ in 0..400 {
                let t = rng.normal();
                for j in 0..c {
                    rows.push((t * 6.0 / (1 + j) as f32 + rng.normal() * 2.0).round());
                }
            }
            let all: Vec<usize> = (0..400).collect();
            let basis = Basis::principal(&rows, c, &all);
            for a in 0..AXES {
                for b in 0..AXES {
                    let dot: f64 = basis.axes[a].iter().zip(&basis.axes[b]).map(|(x, y)| x * y).sum();
                    let want = if a == b && a < c { 1.0 } else { 0.0 };
                    assert!((dot - want).abs() < 1e-9, "c {c}: axes {a}·{b} = {dot}");
                }
            }
            let coords: Vec<Coords> = rows.chunks_exact(c).map(|r| basis.coords(r)).collect();
            for i in 0..400 {
                let j = (i * 7 + 3) % 400;
                let d = f64::from(dist2(&rows[i * c..][..c], &rows[j * c..][..c]));
                assert!(below(&coords[i], &coords[j]) <= d * (1.0 + 1e-9), "c {c}: rows {i}, {j}");
            }
            let mean: Vec<f64> = (0..c).map(|j| rows.iter().skip(j).step_by(c).map(|&x| f64::from(x)).sum::<f64>() / 400.0).collect();
            let spread = |u: &[f64]| {
                rows.chunks_exact(c)
                    .map(|r| r.iter().zip(&mean).zip(u).map(|((&x, m), v)| (f64::from(x) - m) * v).sum::<f64>().powi(2))
                    .sum::<f64>()
            };
            for a in 1..AXES.min(c) {
                assert!(spread(&basis.axes[a - 1]) >= spread(&basis.axes[a]) * 0.999, "c {c}: direction {a} spreads more than {}", a - 1);
            }
        }
    }

    /// Among some of the centres, the nearest to a row is the nearest of those and the hint,
    /// the first of equals (what a Lloyd iteration asks of the centres that moved).
    #[test]
    fn nearest_among_some_centres_is_the_nearest_of_those_and_the_hint() {
        let mut rng = Rng::new(8);
        let c = 9;
        let cen: Vec<f32> = (0..120 * c).map(|_| (rng.normal() * 1.5).round()).collect();
        let basis = Basis::principal(&cen, c, &(0..120).collect::<Vec<_>>());
        for round in 0..200u32 {
            let some: Vec<u32> = (0..120).filter(|k| (k * 7 + round) % 5 < 2).collect();
            let hint = round * 13 % 120;
            let centres = Centres::new(&cen, c, &basis, some.clone());
            let r: Vec<f32> = (0..c).map(|_| (rng.normal() * 1.5).round()).collect();
            let mut candidates = some;
            candidates.push(hint);
            candidates.sort_unstable();
            let d = |k: u32| dist2(&r, &cen[k as usize * c..][..c]);
            let first = candidates.iter().copied().fold(candidates[0], |b, k| if d(k) < d(b) { k } else { b });
            assert_eq!(centres.nearest(&r, &basis.coords(&r), hint), first, "round {round}");
        }
    }

    /// k-means written as plainly as it can be: the same draws, every row measured against
    /// every centre, all [`ITERATIONS`] Lloyd iterations.
    fn plain_kmeans(chans: &[Vec<i32>], weights: &[f32], k: usize, seed: u64) -> Codebook {
        let pal = palette(chans);
        if pal.len() <= k {
            return pal;
        }
        let c = chans.len();
        let mut rng = Rng::new(seed);
        let (train, w) = training_rows(&pal, weights, &mut rng);
        let rows: Vec<f32> = pal.rows.iter().map(|&x| x as f32).collect();
        let row = |d: usize| &rows[d * c..][..c];
        let pick = |rng: &mut Rng, p: &[f64]| {
            let mut t = rng.uniform_f64() * p.iter().sum::<f64>();
            for (j, &x) in p.iter().enumerate() {
                if t < x {
                    return j;
                }
                t -= x;
            }
            p.iter().rposition(|&x| x > 0.0).unwrap_or(0)
        };
        let nearest = |r: &[f32], cen: &[f32]| {
            let d: Vec<f32> = cen.chunks_exact(c).map(|x| dist2(r, x)).collect();
            d.iter().enumerate().fold(0, |b, (k, &x)| if x < d[b] { k } else { b }) as u32
        };
        let mut cen: Vec<f32> = row(train[pick(&mut rng, &w)]).to_vec();
        let mut d2: Vec<f32> = train.iter().map(|&i| dist2(row(i), &cen)).collect();
        while cen.len() < k * c {
            let p: Vec<f64> = d2.iter().zip(&w).map(|(&d, &wt)| f64::from(d) * wt).collect();
            if p.iter().all(|&x| x <= 0.0) {
                break;
            }
            let j = pick(&mut rng, &p);
            cen.extend_from_slice(row(train[j]));
            for (d, &i) in d2.iter_mut().zip(&train) {
                *d = d.min(dist2(row(i), &cen[cen.len() - c..]));
            }
        }
        let kk = cen.len() / c;
        for _ in 0..ITERATIONS {
            let assign: Vec<u32> = train.iter().map(|&i| nearest(row(i), &cen)).collect();
            let (mut sum, mut m) = (vec![0.0f64; kk * c], vec![0.0f64; kk]);
            for ((&i, &a), &wt) in train.iter().zip(&assign).zip(&w) {
                m[a as usize] += wt;
                for (s, &x) in sum[a as usize * c..][..c].iter_mut().zip(row(i)) {
                    *s += wt * f64::from(x);
                }
            }
            for a in 0..kk {
                if m[a] > 0.0 {
                    (0..c).for_each(|j| cen[a * c + j] = (sum[a * c + j] / m[a]) as f32);
                }
            }
        }
        let int_rows: Vec<i32> = cen.iter().map(|&x| x.round() as i32).collect();
        let int_cen: Vec<f32> = int_rows.iter().map(|&x| x as f32).collect();
        let by_distinct: Vec<u32> = (0..pal.len()).map(|d| nearest(row(d), &int_cen)).collect();
        let index = pal.index.iter().map(|&d| by_distinct[d as usize]).collect();
        compact(Codebook { channels: c, rows: int_rows, index })
    }

    /// The search's shortcuts — coordinate bounds, measuring a row again only against the
    /// centres that moved, stopping when none moves — give exactly the plain k-means, ties
    /// included (small integer rows tie often), on a subsample too.
    #[test]
    fn kmeans_is_the_plain_kmeans() {
        for (n, c, k, scale, seed) in
            [(600, 3, 16, 1.0, 1), (2000, 9, 64, 1.5, 2), (3000, 15, 256, 2.0, 3), (1500, 21, 300, 0.7, 4), (40_000, 3, 24, 3.0, 5)]
        {
            let mut rng = Rng::new(seed);
            let chans: Vec<Vec<i32>> = (0..c).map(|_| (0..n).map(|_| (rng.normal() * scale).round() as i32).collect()).collect();
            let w: Vec<f32> = (0..n).map(|i| if i % 5 == 0 { 0.0 } else { rng.uniform() }).collect();
            assert_eq!(kmeans(&chans, &w, k, seed), plain_kmeans(&chans, &w, k, seed), "n {n} c {c} k {k}");
        }
    }
}

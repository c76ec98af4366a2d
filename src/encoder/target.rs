//! Encoding to a target instead of a λ: the smallest file that reaches a PSNR, or the best PSNR
//! within a size, found by a bracketing search on λ ([`Encoder::encode_scene_to`]).

use serde::Serialize;

use gscodec_decoder::Splats;

use std::time::Instant;

use rayon::prelude::*;

use super::{EncodeReport, EncodeStages, Encoded, Encoder, InvalidConfig, Lambda, Orbit, Profile};
use crate::io::{Dataset, Split};
use crate::rate::{self, rd, rd::Trials, EncodeConfig};
use crate::train::Progress;
use crate::Result;

/// What to aim for.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Target {
    /// The smallest file whose [`super::EncodeReport::orbit_psnr`] is at least this many dB.
    Psnr(f64),
    /// The best orbit PSNR among files of at most this many bytes.
    Bytes(u64),
}

/// Largest `--target-psnr` accepted, dB.
pub const MAX_TARGET_PSNR: f64 = 200.0;
/// The largest λ the search tries (every scene's file is nearly empty there).
pub const MAX_LAMBDA: f64 = 1e9;
/// Probes between the ends at most (bisection would resolve λ to within ≈8 % in 8).
const MAX_INNER_PROBES: usize = 8;
/// The search stops when the bracket is narrower than this in `ln(1+λ)` (λ within ≈8 %) ...
const RESOLUTION: f64 = 0.08;
/// ... or when a probe meets the target by less than this margin (dB of PSNR; for a size,
/// `ln` of the budget over the bytes: 0.5 %).
const CLOSE_PSNR: f64 = 0.05;
const CLOSE_BYTES: f64 = 0.005;
/// Rounds of configurations between the best probe and the nearest miss (`Encoder::fill`).
const FILL_ROUNDS: usize = 3;
/// Probes that step away from the first probe before the target is bracketed ([`outward`]).
const MAX_OUTWARD_PROBES: usize = 4;
/// Where the search on λ starts ([`start_lambda`]): λ times the scene's Gaussians. λ is per
/// megabit of file and a file's bits at a given quality grow with its Gaussians, so the λ of a
/// PSNR falls about as 1/N; this is the geometric mean of λ·N at SPZ's PSNR on k7000, fruit-drops,
/// lego trained here and playbot-lod3 (from 40,000 to 1,760,000).
const START_LAMBDA_GAUSSIANS: f64 = 2.3e5;
/// The first step assumes the margin changes this fast per unit of `ln(1+λ)` ([`Target::slope`]):
/// dB of PSNR, and `ln` of the bytes, measured around SPZ's PSNR on k7000, fruit-drops and lego
/// trained here (4.7–5.7 dB, 0.42–0.48).
const SLOPE_PSNR: f64 = 5.0;
const SLOPE_BYTES: f64 = 0.45;
/// Steps aim this much beyond where the margin is predicted to cross 0, so that the first
/// step usually brackets the target.
const OVERSHOOT: f64 = 1.25;
/// The first step away from the first phase's λ, in `ln(1+λ)`, when the first phase's curve
/// does not predict one.
const FIRST_STEP: f64 = 0.1;

/// One encode of the search.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Probe {
    /// λ tried.
    pub lambda: Lambda,
    /// File size.
    pub bytes: usize,
    /// Orbit PSNR, dB.
    pub psnr: f64,
    /// Whether this encode trained (fine-tuned a scene, retrained a dataset's scene); with
    /// fine-tuning, the first phase's encodes bracket λ without it ([`Encoder::encode_scene_to`]).
    pub trained: bool,
    /// Wall time of the encode (and, for a dataset, of measuring its held-out PSNR), seconds.
    pub seconds: f64,
}

/// A configuration tried between the best probe and the nearest one that missed
/// ([`rd::between`]): the knob changed (`+ knob`: added to the knobs kept before), file size
/// (without learned tables) and orbit PSNR.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Between {
    /// Round of `Encoder::fill`'s search (each starts from the best of the one before); 0: the
    /// nearest miss with one step nudged towards the target, tried beside the rounds.
    pub round: usize,
    pub change: String,
    pub bytes: usize,
    pub psnr: f64,
}

/// What a search for a target reports while it runs ([`Encoder::encode_scene_to`],
/// [`Encoder::encode_dataset_to`]).
#[derive(Debug, Clone, Copy)]
pub enum TargetEvent<'a> {
    /// A training iteration: a fine-tuned or retrained probe's, or a dataset's first training.
    Train(&'a Progress),
    /// An encode of the search on λ finished; `met`: whether it meets the target.
    Probe { probe: &'a Probe, met: bool },
    /// The configurations between the best probe and the nearest miss are being tried
    /// ([`TargetSearch::between`]).
    Mixing,
}

/// How a target was met: the target and every encode tried, in order.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TargetSearch {
    /// The target.
    pub target: Target,
    /// Every encode of the search.
    pub probes: Vec<Probe>,
    /// The configurations tried between the best probe and the nearest that missed (not for a
    /// dataset, nor for the anchor profile's fine-tuning); a fine-tuned probe's are tried on the
    /// scene it decodes to.
    pub between: Vec<Between>,
}

impl Target {
    /// Checks the target's value.
    ///
    /// # Errors
    /// A PSNR outside (0, [`MAX_TARGET_PSNR`]] or a size below an empty scene's file.
    pub fn validate(self) -> std::result::Result<(), InvalidConfig> {
        match self {
            Target::Psnr(v) if !(v > 0.0 && v <= MAX_TARGET_PSNR) => Err(InvalidConfig::TargetPsnr { value: v, max: MAX_TARGET_PSNR }),
            Target::Bytes(v) => {
                let min = empty_file_bytes();
                if v < min {
                    return Err(InvalidConfig::TargetBytes { value: v, min });
                }
                Ok(())
            }
            _ => Ok(()),
        }
    }

    fn met(self, (bytes, psnr): (usize, f64)) -> bool {
        match self {
            Target::Psnr(p) => psnr >= p,
            Target::Bytes(b) => bytes as u64 <= b,
        }
    }

    /// Whether `a` is better than `b` (bytes, PSNR), both meeting the target.
    fn better(self, a: (usize, f64), b: (usize, f64)) -> bool {
        match self {
            Target::Psnr(_) => a.0 < b.0,
            Target::Bytes(_) => a.1 > b.1,
        }
    }

    /// By how much (bytes, PSNR) meets the target (negative: misses it), in the unit the search
    /// interpolates: dB for a PSNR, `ln(budget / bytes)` for a size.
    fn margin(self, (bytes, psnr): (usize, f64)) -> f64 {
        match self {
            Target::Psnr(p) => psnr - p,
            Target::Bytes(b) => (b as f64).ln() - (bytes as f64).ln(),
        }
    }

    /// Whether `margin` meets the target closely enough to stop searching.
    fn met_closely(self, margin: f64) -> bool {
        (0.0..self.close()).contains(&margin)
    }

    /// The direction (±1 in `t = ln(1+λ)`) from a probe of margin `margin` towards the λs on the
    /// target's other side: a PSNR's margin falls as `t` grows, a size's rises.
    fn towards(self, margin: f64) -> f64 {
        if (margin >= 0.0) == matches!(self, Target::Psnr(_)) {
            1.0
        } else {
            -1.0
        }
    }

    /// How fast the margin usually changes per unit of `ln(1+λ)` (its magnitude).
    fn slope(self) -> f64 {
        match self {
            Target::Psnr(_) => SLOPE_PSNR,
            Target::Bytes(_) => SLOPE_BYTES,
        }
    }

    /// A margin close enough to the target to stop searching.
    fn close(self) -> f64 {
        match self {
            Target::Psnr(_) => CLOSE_PSNR,
            Target::Bytes(_) => CLOSE_BYTES,
        }
    }
}

/// Size of the file of an empty scene (the smallest `.gsc`).
fn empty_file_bytes() -> u64 {
    rate::encode(&Splats::new(0), &EncodeConfig::default()).map_or(0, |(b, _, _)| b.len() as u64)
}

/// The probes of a search on λ ([`search_lambda`]): every encode tried, the best that met the
/// target with its `t = ln(1+λ)` and PSNR, and the configurations and `t` of those that missed.
struct Searched {
    probes: Vec<Probe>,
    best: Option<(f64, Encoded, f64)>,
    /// With the scene a fine-tuned miss coded ([`Encoded::trained`]).
    missed: Vec<(f64, EncodeConfig, Option<Splats>)>,
}

impl Searched {
    /// The (bytes, PSNR) of the best probe that met the target.
    fn best_outcome(&self) -> Option<(usize, f64)> {
        self.best.as_ref().map(|b| (b.1.bytes.len(), b.2))
    }
}

/// A search on λ in progress: `encode(λ, progress)` makes one probe, reporting its training to
/// `progress`, and returns it with the PSNR the target reads; `trained` marks the probes
/// ([`Probe::trained`]); `events` hears of every probe and every training iteration.
struct Search<'e, F> {
    target: Target,
    trained: bool,
    encode: F,
    events: &'e mut dyn FnMut(TargetEvent),
    found: Searched,
}

/// One probe of a search: `encode(λ, progress)` ([`Search`]).
trait ProbeFn: FnMut(Lambda, &mut dyn FnMut(&Progress)) -> Result<(Encoded, f64)> {}
impl<F: FnMut(Lambda, &mut dyn FnMut(&Progress)) -> Result<(Encoded, f64)>> ProbeFn for F {}

impl<'e, F: ProbeFn> Search<'e, F> {
    fn new(target: Target, trained: bool, events: &'e mut dyn FnMut(TargetEvent), encode: F) -> Self {
        Search { target, trained, encode, events, found: Searched { probes: Vec::new(), best: None, missed: Vec::new() } }
    }

    /// Encodes at `t = ln(1+λ)` and returns the margin by which the target is met (≥ 0) or
    /// missed (< 0).
    fn probe(&mut self, t: f64) -> Result<f64> {
        let target = self.target;
        let lambda = Lambda::new(t.exp_m1().max(0.0)).unwrap_or(Lambda::ZERO);
        let events = &mut *self.events;
        let began = Instant::now();
        let (e, psnr) = (self.encode)(lambda, &mut |p| events(TargetEvent::Train(p)))?;
        let outcome = (e.bytes.len(), psnr);
        let probe = Probe { lambda, bytes: outcome.0, psnr, trained: self.trained, seconds: began.elapsed().as_secs_f64() };
        self.found.probes.push(probe);
        let met = target.met(outcome);
        (self.events)(TargetEvent::Probe { probe: &probe, met });
        let margin = target.margin(outcome);
        if !met {
            self.found.missed.push((t, e.config, e.trained));
        } else if self.found.best_outcome().is_none_or(|b| target.better(outcome, b)) {
            self.found.best = Some((t, e, psnr));
        }
        // `met` decides the side even where the margin rounds to 0.
        Ok(if met { margin.max(0.0) } else { margin.min(-f64::MIN_POSITIVE) })
    }
}

/// An encode's (bytes, PSNR), as a target reads it.
fn outcome(e: &Encoded) -> (usize, f64) {
    (e.bytes.len(), e.report.orbit_psnr)
}

/// The λ a search on λ starts at for a scene of `gaussians` Gaussians ([`START_LAMBDA_GAUSSIANS`]).
fn start_lambda(gaussians: usize) -> f64 {
    (START_LAMBDA_GAUSSIANS / gaussians.max(1) as f64).min(MAX_LAMBDA)
}

/// Brackets λ for `target` in `t = ln(1+λ)` over [0, [`MAX_LAMBDA`]]: the PSNR falls and the
/// size shrinks as λ grows, so the search keeps the boundary between λs that meet the target and
/// λs that do not. It starts at λ = `start` ([`start_lambda`]) and steps towards the other side
/// ([`outward`]: the first step where a curve of the usual slope ([`Target::slope`]) would
/// cross, later ones where the line through the last two probes does), then [`bracket`] (regula
/// falsi, Illinois) narrows the two. An end is probed only when the steps reach it: λ = 0 codes
/// the whole scene at the finest steps, the costliest encode of all. `encode(λ)` makes one probe
/// and returns it with the PSNR the target reads ([`Search`]); `trained` marks the probes.
fn search_lambda(target: Target, trained: bool, start: f64, events: &mut dyn FnMut(TargetEvent), encode: impl ProbeFn) -> Result<Searched> {
    let mut search = Search::new(target, trained, events, encode);
    let t0 = start.ln_1p();
    let m0 = search.probe(t0)?;
    if target.met_closely(m0) {
        return Ok(search.found);
    }
    let first = OVERSHOOT * m0.abs() / target.slope();
    let last = outward(&mut search, (t0, m0), first, MAX_OUTWARD_PROBES, |(ta, ma), (tb, mb), step| {
        // Where the line through the last two probes crosses (a little beyond), at most four
        // times the last step (a flat stretch of the curve says nothing about its slope).
        let slope = ((mb - ma) / (tb - ta)).abs();
        (OVERSHOOT * mb.abs() / slope).clamp(RESOLUTION, 4.0 * step)
    })?;
    // Still on the start's side: the end beyond the last probe.
    if let Some((t, m)) = last {
        let end = end_towards(target.towards(m0));
        let m_end = search.probe(end)?;
        if (m_end >= 0.0) != (m >= 0.0) {
            bracket(t, m, end, m_end, target.close(), |t| search.probe(t))?;
        }
    }
    Ok(search.found)
}

/// Steps away from the probe `(t0, m0)` towards the λs on the target's other side (a PSNR's
/// margin falls as `t` grows, a size's rises), by `step` first and then by `next(previous
/// probe, last probe, last step)`, until a probe lands on the other side — then [`bracket`]
/// narrows the two — or meets the target closely, or an end of [0, ln(1 + [`MAX_LAMBDA`])] is
/// probed. Returns the last probe when `max` steps did none of these.
fn outward<F: ProbeFn>(
    search: &mut Search<'_, F>,
    (t0, m0): (f64, f64),
    mut step: f64,
    max: usize,
    next: impl Fn((f64, f64), (f64, f64), f64) -> f64,
) -> Result<Option<(f64, f64)>> {
    let target = search.target;
    let (t_max, met, dir) = (MAX_LAMBDA.ln_1p(), m0 >= 0.0, target.towards(m0));
    let end = end_towards(dir);
    let mut near = (t0, m0);
    for i in 0..max {
        let t = near.0 + dir * step.max(RESOLUTION);
        // A step past an end goes halfway from where it predicts the crossing (without the
        // overshoot) to that end: an end is the costliest probe (λ = 0) or a useless one. Where
        // the crossing itself is predicted beyond the end, the first step (a guess at the slope)
        // goes halfway from here, a later one (the slope measured) to the end.
        let t = match near.0 + dir * step / OVERSHOOT {
            _ if (0.0..=t_max).contains(&t) => t,
            crossing if (0.0..=t_max).contains(&crossing) => 0.5 * (crossing + end),
            _ if i == 0 => 0.5 * (near.0 + end),
            _ => end,
        };
        let m = search.probe(t)?;
        if (m >= 0.0) != met {
            bracket(near.0, near.1, t, m, target.close(), |t| search.probe(t))?;
            return Ok(None);
        }
        if target.met_closely(m) || t == end {
            return Ok(None);
        }
        step = next(near, (t, m), step);
        near = (t, m);
    }
    Ok(Some(near))
}

/// The end of [0, ln(1 + [`MAX_LAMBDA`])] in the direction `dir` (±1) of `t`.
fn end_towards(dir: f64) -> f64 {
    if dir > 0.0 {
        MAX_LAMBDA.ln_1p()
    } else {
        0.0
    }
}

/// The second phase of a search whose encodes train: the first phase ([`search_lambda`] with
/// encodes that do not train, a fraction of the cost) found `first`, and the best `t` meeting
/// the target there; training moves each λ's file along the curve (fine-tuning: smaller and
/// better at the same λ), so the trained encodes start at that `t`, step away from it — the
/// first step where the first phase's curve, shifted by what training changed at that `t`,
/// meets the target, then doubling — until one lands on the other side of the target, and
/// [`bracket`] narrows the two. No trained encode runs at the ends (λ = 0: the whole scene
/// trained; λ = [`MAX_LAMBDA`]: an empty one) unless the first phase met the target nowhere:
/// then the trained encodes search on their own, as [`search_lambda`].
fn refine(target: Target, first: &Searched, start: f64, events: &mut dyn FnMut(TargetEvent), encode: impl ProbeFn) -> Result<Searched> {
    let Some((t0, _, _)) = first.best else { return search_lambda(target, true, start, events, encode) };
    let mut search = Search::new(target, true, events, encode);
    let curve: Vec<(f64, f64)> = first.probes.iter().map(|p| (p.lambda.get().ln_1p(), target.margin((p.bytes, p.psnr)))).collect();
    let m0 = search.probe(t0)?;
    if target.met_closely(m0) {
        return Ok(search.found);
    }
    let step = predicted_step(&curve, t0, m0, target.towards(m0)).unwrap_or(FIRST_STEP);
    // Each later step twice the last; no trained probe at an end unless the steps reach it.
    outward(&mut search, (t0, m0), step, MAX_OUTWARD_PROBES, |_, _, step| 2.0 * step)?;
    Ok(search.found)
}

/// How far from `t0`, in the direction `dir` (±1), the first phase's margins `curve` (points
/// `(t, margin)`), shifted by `m0 − margin(t0)` (what training changed at `t0`), cross 0: the
/// distance to where the piecewise-linear curve through the points reaches `margin(t0) − m0`.
/// `None` when the points do not reach it on that side.
fn predicted_step(curve: &[(f64, f64)], t0: f64, m0: f64, dir: f64) -> Option<f64> {
    let mut pts: Vec<(f64, f64)> = curve.iter().copied().filter(|p| p.1.is_finite()).collect();
    pts.sort_by(|a, b| a.0.total_cmp(&b.0));
    pts.dedup_by(|a, b| a.0 == b.0);
    let at = |t: f64| {
        let i = pts.partition_point(|p| p.0 < t);
        match (i.checked_sub(1).and_then(|j| pts.get(j)), pts.get(i)) {
            (_, Some(b)) if b.0 == t => Some(b.1),
            (Some(a), Some(b)) => Some(a.1 + (t - a.0) / (b.0 - a.0) * (b.1 - a.1)),
            _ => None,
        }
    };
    let want = at(t0)? - m0;
    pts.windows(2)
        .filter_map(|w| {
            let ((ta, ma), (tb, mb)) = (w[0], w[1]);
            let crosses = (ma - want) * (mb - want) <= 0.0 && ma != mb;
            crosses.then(|| ta + (want - ma) / (mb - ma) * (tb - ta))
        })
        .map(|t| (t - t0) * dir)
        .filter(|&d| d > 0.0)
        .min_by(f64::total_cmp)
}

/// The error of a target no probe met.
fn unreachable(target: Target, probes: &[Probe]) -> crate::Error {
    crate::Error::Input(match target {
        Target::Psnr(p) => {
            format!(
                "--target-psnr {p}: not reachable, the finest setting (λ = 0) gives {:.2} dB",
                probes.iter().find(|p| p.lambda == Lambda::ZERO).map_or(f64::NAN, |f| f.psnr)
            )
        }
        Target::Bytes(b) => {
            format!(
                "--target-bytes {b}: not reachable, the smallest file found has {} bytes",
                probes.iter().map(|p| p.bytes).min().unwrap_or(0)
            )
        }
    })
}

impl Encoder {
    /// Encodes `scene` to `target` by a search on λ ([`search_lambda`]) and returns the best
    /// encode that met it (the smallest file for a PSNR, the best PSNR for a size); its report's
    /// `target` lists every encode tried. Each probe is a full [`Encoder::encode_scene`] with
    /// this encoder's settings, and the PSNR is the report's `orbit_psnr`. `events` hears of
    /// each probe as it finishes, of the training iterations of fine-tuned probes, and of the
    /// mixing between probes when it starts ([`TargetEvent`]).
    ///
    /// # Errors
    /// An invalid target, a PSNR that even λ = 0 does not reach, or an encode's error.
    pub fn encode_scene_to(&self, scene: &Splats, target: Target, events: &mut dyn FnMut(TargetEvent)) -> Result<Encoded> {
        target.validate()?;
        // The probes share the RD search's trials: a configuration's size and distortion do not
        // depend on λ, so each is coded and rendered once for all probes.
        let mut trials = Trials::new(scene).map_err(|e| crate::Error::Input(e.to_string()))?;
        let orbit = Orbit::new(scene);
        // With fine-tuning (the explicit profile's), the RD search alone brackets λ first and
        // the fine-tuned encodes refine it ([`refine`]).
        let two_phase = self.config.iters_for(false) > 0 && self.config.profile == Profile::Explicit;
        let mut encode_at = |lambda: Lambda, iters: Option<usize>, progress: &mut dyn FnMut(&Progress)| -> Result<(Encoded, f64)> {
            let enc = Encoder { config: self.config.clone().with_lambda(lambda).with_iters(iters) };
            let e = enc.encode_scene_with(&mut trials, &orbit, progress)?;
            let psnr = e.report.orbit_psnr;
            Ok((e, psnr))
        };
        let first_iters = if two_phase { Some(0) } else { self.config.iters };
        let start = start_lambda(scene.len());
        let trained = !two_phase && self.config.iters_for(false) > 0;
        let mut first = search_lambda(target, trained, start, events, |lambda, p| encode_at(lambda, first_iters, p))?;
        let (probes, phases) = match two_phase {
            true => {
                let second = refine(target, &first, start, events, |lambda, p| encode_at(lambda, self.config.iters, p))?;
                let probes = first.probes.iter().chain(&second.probes).copied().collect();
                (probes, vec![first, second])
            }
            false => (std::mem::take(&mut first.probes), vec![first]),
        };
        // Each phase's best, mixed with its nearest miss; the better of them, the fine-tuned
        // where they tie. The search alone's is mixed too: it can end below the fine-tuned file
        // (docs/codec.md §30).
        let mix = two_phase || self.config.iters_for(false) == 0;
        let mut between = Vec::new();
        let mut out: Option<Encoded> = None;
        for phase in phases {
            let Some(e) = self.mixed(&trials, &orbit, target, phase, mix, &mut between, events)? else { continue };
            if out.as_ref().is_none_or(|o| !target.better(outcome(o), outcome(&e))) {
                out = Some(e);
            }
        }
        let Some(mut best) = out else { return Err(unreachable(target, &probes)) };
        best.report.target = Some(TargetSearch { target, probes, between });
        Ok(best)
    }

    /// Encodes a dataset to `target`, its PSNR the held-out views' (`gscodec eval OUTPUT
    /// DATASET`): the scene is trained from the images once, at this encoder's λ, or is `init`
    /// (`--init`); then each probe of the search on λ ([`search_lambda`]) runs the RD search,
    /// the retraining and the coding at its λ ([`Encoder::code_dataset`], [`Encoder::encode_trained`]).
    /// The report's `target` lists every probe; there is no search between probes. `events`
    /// hears of the training iterations and of each probe as it finishes ([`TargetEvent`]).
    ///
    /// # Errors
    /// As [`Encoder::encode_scene_to`], and a dataset without held-out views.
    pub fn encode_dataset_to(
        &self,
        dataset: &Dataset,
        init: Option<&Splats>,
        target: Target,
        events: &mut dyn FnMut(TargetEvent),
    ) -> Result<Encoded> {
        target.validate()?;
        let heldout = dataset.split(Split::Test);
        if heldout.is_empty() {
            return Err(crate::Error::Input(
                "--target-psnr / --target-bytes: the dataset has no held-out (test) views to measure the PSNR on".into(),
            ));
        }
        /// What every probe codes: the scene trained here, or the given one.
        enum Scene<'a> {
            Trained(&'a super::TrainedScene),
            Given(&'a Splats),
        }
        let trained;
        let scene = match init {
            Some(s) => Scene::Given(s),
            None => {
                trained = self.train_dataset(dataset, &mut |p| events(TargetEvent::Train(p)))?;
                Scene::Trained(&trained)
            }
        };
        let retrains = self.config.retrain_iters_of_dataset(init.is_some()) > 0;
        let gaussians = match &scene {
            Scene::Trained(t) => t.scene.len(),
            Scene::Given(s) => s.len(),
        };
        let Searched { probes, best, .. } = search_lambda(target, retrains, start_lambda(gaussians), events, |lambda, progress| {
            let enc = Encoder { config: self.config.clone().with_lambda(lambda) };
            let e = match &scene {
                Scene::Trained(t) => enc.resolved().code_trained_scene(dataset, t, progress)?,
                Scene::Given(s) => enc.encode_trained(dataset, s, progress)?,
            };
            let psnr = crate::metrics::view::mean_psnr_ssim(&e.decoded, &heldout, dataset.background)?.map_or(f64::NAN, |m| m.0);
            Ok((e, psnr))
        })?;
        let Some((_, mut best, _)) = best else { return Err(unreachable(target, &probes)) };
        best.report.target = Some(TargetSearch { target, probes, between: Vec::new() });
        Ok(best)
    }

    /// A search's best probe (`found`), or, where `mix`, the best of the configurations mixing
    /// its choices with its nearest miss's ([`Encoder::fill`]) when one is better; `None` when no
    /// probe met the target. Every mix tried goes into `between`.
    #[allow(clippy::too_many_arguments)]
    fn mixed(
        &self,
        trials: &Trials,
        orbit: &Orbit,
        target: Target,
        found: Searched,
        mix: bool,
        between: &mut Vec<Between>,
        events: &mut dyn FnMut(TargetEvent),
    ) -> Result<Option<Encoded>> {
        let Searched { best, missed, .. } = found;
        let Some((best_t, mut best, _)) = best else { return Ok(None) };
        // The RD curve has steps (the search's choices are discrete): between the best probe
        // and the nearest that missed, try configurations mixing their choices. A fine-tuned
        // probe's choices are tried on the scene its training left (coding it again with them
        // gives its file back), the best's mixes on the best's, the miss's nudges on the miss's.
        let nearest_miss = missed.iter().min_by(|a, b| (a.0 - best_t).abs().total_cmp(&(b.0 - best_t).abs()));
        if let Some((_, bad, bad_trained)) = nearest_miss.filter(|_| mix) {
            fn own(trained: &Option<Splats>) -> Result<Option<Trials<'_>>> {
                trained.as_ref().map(|s| Trials::new(s).map_err(|e| crate::Error::Input(e.to_string()))).transpose()
            }
            let (best_own, bad_own) = (own(&best.trained)?, own(bad_trained)?);
            let sides = [best_own.as_ref().unwrap_or(trials), bad_own.as_ref().unwrap_or(trials)];
            events(TargetEvent::Mixing);
            let filled = self.fill(sides, orbit, target, &best, bad, between)?;
            drop((best_own, bad_own));
            if let Some((filled, from_miss)) = filled.filter(|f| target.better(outcome(&f.0), outcome(&best))) {
                let trained = if from_miss { bad_trained.clone() } else { best.trained.take() };
                let r = best.report;
                // What made the scene it codes: the fine-tuning's, when it ran.
                let report = EncodeReport {
                    loss: r.loss,
                    wd_features: r.wd_features,
                    wd_sigma: r.wd_sigma,
                    wd_warmup: r.wd_warmup,
                    iters: r.iters,
                    backend: r.backend,
                    train: r.train,
                    fine_tuning_kept: r.fine_tuning_kept,
                    // The mixes count as search time (`fill`), the probe's training as its own.
                    stages: EncodeStages {
                        train_s: r.stages.train_s,
                        total_s: filled.report.stages.total_s + r.stages.train_s,
                        ..filled.report.stages
                    },
                    ..filled.report
                };
                best = Encoded { report, trained, ..filled };
            }
        }
        Ok(Some(best))
    }

    /// Between `good` (the best encode meeting `target`, of `sides[0]`'s scene: the input, or
    /// the scene a fine-tuned probe trained) and `bad` (the choices of the nearest probe that
    /// missed it, of `sides[1]`'s scene), up to [`FILL_ROUNDS`] rounds from the
    /// best so far: the best with each one of its knobs set as in `bad` ([`rd::between`]),
    /// with another choice of importance classes ([`rd::tail_variants`]) or with one group's
    /// step an eighth of an octave coarser (for a PSNR target) or finer (for a size target,
    /// [`rd::step_nudges`]); of
    /// those that meet the target and beat the best, the best one, then the others added one
    /// after another (most bytes saved, or PSNR gained, first), each kept if the result still
    /// meets the target and is better. A round that finds nothing better ends the search. Beside
    /// the rounds, `bad` with one group's step nudged the other way (finer for a PSNR target),
    /// kept where it meets the target and beats the rounds' best. Every configuration tried
    /// goes into `tried`, after the two it starts from (round 0, "best's choices" and "miss's
    /// choices"). Returns the encode of the best when it beats `good`, and whether it
    /// is a nudged miss (of `sides[1]`'s scene).
    fn fill(
        &self,
        sides: [&Trials; 2],
        orbit: &Orbit,
        target: Target,
        good: &Encoded,
        bad: &EncodeConfig,
        tried: &mut Vec<Between>,
    ) -> Result<Option<(Encoded, bool)>> {
        let [trials, miss_trials] = sides;
        let scene = trials.scene();
        let began = Instant::now();
        let eval_on = |trials: &Trials, c: &EncodeConfig| -> Result<(usize, f64)> {
            let c = EncodeConfig { learned_tables: false, ..self.file_config(c) };
            let (bytes, decoded) = trials.code(&c).map_err(|e| crate::Error::Input(e.to_string()))?;
            Ok((bytes, orbit.psnr(&decoded)))
        };
        let eval = |c: &EncodeConfig| eval_on(trials, c);
        // Compared like for like: without learned tables (as every trial), same PSNR.
        let start = (good.config, eval(&good.config)?);
        // Where the two sides start, as the trials code them (a fine-tuned probe's on its own
        // trained scene: its file's PSNR).
        let miss = eval_on(miss_trials, bad)?;
        for (change, o) in [("best's choices", start.1), ("miss's choices", miss)] {
            tried.push(Between { round: 0, change: change.into(), bytes: o.0, psnr: o.1 });
        }
        // Steps nudged the way that spends the best's margin: coarser for fewer bytes.
        let psnr_target = matches!(target, Target::Psnr(_));
        let nudges = |c: &EncodeConfig| rd::step_nudges(c, psnr_target, scene.sh_degree);
        // From the other side (round 0): the miss with one step nudged the way that gains what
        // it lacks. Where the curve steps, a miss can fall just short of the target while the
        // best lies far beyond it; the rounds below cannot cross such a step from the best.
        let miss_nudges = |c: &EncodeConfig| rd::step_nudges(c, !psnr_target, miss_trials.scene().sh_degree);
        let back = miss_nudges(bad);
        let outcomes = back.par_iter().map(|(_, c)| eval_on(miss_trials, c)).collect::<Result<Vec<_>>>()?;
        let mut from_miss: Option<(EncodeConfig, (usize, f64))> = None;
        for ((knob, c), &o) in back.iter().zip(&outcomes) {
            tried.push(Between { round: 0, change: format!("miss's {knob}"), bytes: o.0, psnr: o.1 });
            if target.met(o) && from_miss.is_none_or(|m| target.better(o, m.1)) {
                from_miss = Some((*c, o));
            }
        }
        // No nudge met the target alone: the nudges that moved towards it, one after another
        // (most PSNR per byte first for a PSNR target, most bytes saved per dB lost for a size
        // target), each kept where it moved further, until the miss meets the target.
        if from_miss.is_none() {
            let towards = |from: (usize, f64), o: (usize, f64)| if psnr_target { o.1 > from.1 } else { o.0 < from.0 };
            let rate = |o: (usize, f64)| match psnr_target {
                true => (o.1 - miss.1) / (o.0 as f64 - miss.0 as f64).max(1.0),
                false => (miss.0 as f64 - o.0 as f64) / (miss.1 - o.1).max(1e-6),
            };
            let mut order: Vec<_> = back.iter().zip(&outcomes).filter(|(_, &o)| towards(miss, o)).collect();
            order.sort_by(|a, b| rate(*b.1).total_cmp(&rate(*a.1)));
            if let Some(&((_, first), &o)) = order.first() {
                // The miss with the best nudge, then each further one on top.
                let mut at = (*first, o);
                for ((knob, _), _) in &order[1..] {
                    let Some((_, c)) = miss_nudges(&at.0).into_iter().find(|(name, _)| name == knob) else { continue };
                    let o = eval_on(miss_trials, &c)?;
                    tried.push(Between { round: 0, change: format!("+ miss's {knob}"), bytes: o.0, psnr: o.1 });
                    if towards(at.1, o) {
                        at = (c, o);
                    }
                    if target.met(at.1) {
                        from_miss = Some(at);
                        break;
                    }
                }
            }
        }
        let mut cur = start;
        for round in 1..=FILL_ROUNDS {
            // One knob as in the miss, another choice of importance classes or one step nudged
            // (all finer than the search's steps between the two).
            let mut alone = rd::between(&cur.0, bad);
            let others: Vec<_> =
                rd::tail_variants(&cur.0).into_iter().chain(nudges(&cur.0)).filter(|v| alone.iter().all(|a| a.1 != v.1)).collect();
            alone.extend(others);
            let outcomes = alone.par_iter().map(|(_, c)| eval(c)).collect::<Result<Vec<_>>>()?;
            let mut pays = Vec::new();
            for ((knob, c), &o) in alone.iter().zip(&outcomes) {
                tried.push(Between { round, change: knob.clone(), bytes: o.0, psnr: o.1 });
                if target.met(o) && target.better(o, cur.1) {
                    pays.push((knob.as_str(), *c, o));
                }
            }
            match target {
                Target::Psnr(_) => pays.sort_by_key(|p| p.2 .0),
                Target::Bytes(_) => pays.sort_by(|a, b| b.2 .1.total_cmp(&a.2 .1)),
            }
            let Some(&(_, c, o)) = pays.first() else { break };
            let from = cur;
            cur = (c, o);
            for &(knob, _, _) in &pays[1..] {
                let again = rd::between(&cur.0, bad).into_iter().chain(nudges(&cur.0));
                let Some((_, c)) = again.into_iter().find(|(name, _)| name == knob) else { continue };
                let o = eval(&c)?;
                tried.push(Between { round, change: format!("+ {knob}"), bytes: o.0, psnr: o.1 });
                if target.met(o) && target.better(o, cur.1) {
                    cur = (c, o);
                }
            }
            debug_assert!(target.better(cur.1, from.1));
        }
        let miss_won = from_miss.is_some_and(|m| target.better(m.1, cur.1));
        if let Some(m) = from_miss.filter(|_| miss_won) {
            cur = m;
        } else if cur.0 == start.0 {
            return Ok(None);
        }
        let config = cur.0;
        let side = if miss_won { miss_trials } else { trials };
        let enc = Encoder { config: self.config.clone().with_lambda(good.report.lambda) };
        // Its search: the best probe's RD search, then this one.
        let searched = good.report.stages.rd_search_s + began.elapsed().as_secs_f64();
        let stages = EncodeStages { rd_search_s: searched, ..EncodeStages::default() };
        let mut e = enc.finish(
            orbit,
            side.scene(),
            &config,
            0,
            Instant::now(),
            stages,
            good.report.series.clone(),
            None,
            None,
            Some(side.importance()),
        )?;
        e.report.stages.total_s += searched;
        // The decoded scene, hence the PSNR, is the trial's; learned tables only shrink the file.
        Ok(target.met(outcome(&e)).then_some((e, miss_won)))
    }
}

/// Narrows the bracket between `t0` and `t1`, whose margins `m0` and `m1` have opposite signs
/// (≥ 0: meets the target), by the Illinois variant of regula falsi: the next probe is where the
/// straight line between the ends' margins crosses 0, kept within the middle 80 % of the bracket
/// (bisection where a margin is not finite); an end kept twice in a row has its margin halved,
/// so both ends move. Stops when the bracket is narrower than [`RESOLUTION`], when a probe meets
/// the target by less than `close`, or after [`MAX_INNER_PROBES`] probes. The margin falls as
/// `t` grows for a PSNR target and rises for a size target; either way works.
fn bracket(t0: f64, m0: f64, t1: f64, m1: f64, close: f64, mut probe: impl FnMut(f64) -> Result<f64>) -> Result<()> {
    let (mut good, mut bad) = if m0 >= 0.0 { ((t0, m0), (t1, m1)) } else { ((t1, m1), (t0, m0)) };
    let mut last_met = None;
    for _ in 0..MAX_INNER_PROBES {
        if (good.0 - bad.0).abs() <= RESOLUTION {
            break;
        }
        let f = good.1 / (good.1 - bad.1);
        let f = if f.is_finite() { f.clamp(0.1, 0.9) } else { 0.5 };
        let t = good.0 + f * (bad.0 - good.0);
        let m = probe(t)?;
        let met = m >= 0.0;
        if met {
            good = (t, m);
            if last_met == Some(true) {
                bad.1 *= 0.5;
            }
            if m < close {
                break;
            }
        } else {
            bad = (t, m);
            if last_met == Some(false) {
                good.1 *= 0.5;
            }
        }
        last_met = Some(met);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::encoder::EncoderConfig;

    #[test]
    fn targets_out_of_range_are_refused_with_their_bound() {
        let e = Target::Psnr(-3.0).validate().unwrap_err();
        assert_eq!(e.to_string(), "--target-psnr -3: must be in (0, 200] dB");
        assert!(Target::Psnr(f64::NAN).validate().is_err());
        let min = empty_file_bytes();
        assert!(min > 0);
        assert_eq!(Target::Bytes(min - 1).validate(), Err(InvalidConfig::TargetBytes { value: min - 1, min }));
        assert_eq!(Target::Bytes(min).validate(), Ok(()));
    }

    #[test]
    fn psnr_and_size_targets_are_met_by_the_best_probe() {
        let scene = crate::sample::scene(200, 3);
        let enc = Encoder::new(EncoderConfig::default()).unwrap();
        // A PSNR between the finest and the default setting's.
        let fine = enc.encode_scene(&scene, &mut |_| {}).unwrap().report.orbit_psnr;
        let want = fine - 3.0;
        // Each probe is reported as it finishes, in order, and the mixing before it starts.
        let (mut heard, mut mixing) = (Vec::new(), None);
        let mut events = |e: TargetEvent| match e {
            TargetEvent::Probe { probe, met } => heard.push((*probe, met)),
            TargetEvent::Mixing => mixing = Some(heard.len()),
            TargetEvent::Train(_) => panic!("no training"),
        };
        let e = enc.encode_scene_to(&scene, Target::Psnr(want), &mut events).unwrap();
        let s = e.report.target.clone().unwrap();
        assert_eq!(heard, s.probes.iter().map(|p| (*p, p.psnr >= want)).collect::<Vec<_>>());
        assert!(mixing.is_none_or(|m| m == s.probes.len()) && (s.between.is_empty() || mixing.is_some()), "{s:?}");
        assert!(e.report.orbit_psnr >= want, "{} < {want}", e.report.orbit_psnr);
        // The smallest file that met it, and no probe that met it is smaller.
        assert!(s.probes.iter().filter(|p| p.psnr >= want).all(|p| p.bytes >= e.bytes.len()), "{s:?}");
        assert!(s.probes.iter().any(|p| p.psnr < want), "the search brackets the target: {s:?}");
        assert!(s.probes.len() <= 2 + MAX_OUTWARD_PROBES + MAX_INNER_PROBES, "{s:?}");
        // The file is what its configuration codes; one smaller than every probe's came from the
        // configurations tried between the best probe and the nearest miss, with that PSNR.
        assert_eq!(rate::encode(&scene, &e.config).unwrap().0, e.bytes);
        if s.probes.iter().all(|p| p.bytes > e.bytes.len()) {
            assert!(s.between.iter().any(|b| b.psnr == e.report.orbit_psnr && b.bytes >= e.bytes.len()), "{s:?}");
        }
        // The mixes come from both sides: the miss, too, with one step nudged finer (round 0).
        let from_miss = |s: &TargetSearch, dir: &str| {
            s.between.iter().any(|b| b.round == 0 && b.change.starts_with("miss's ") && b.change.ends_with(dir))
        };
        assert!(from_miss(&s, "step finer"), "{s:?}");
        // A size target: half the file the PSNR target gave.
        let budget = e.bytes.len() as u64 / 2;
        let f = enc.encode_scene_to(&scene, Target::Bytes(budget), &mut |_| {}).unwrap();
        let s = f.report.target.clone().unwrap();
        assert!(from_miss(&s, "step coarser"), "{s:?}");
        assert!(f.bytes.len() as u64 <= budget);
        assert!(s.probes.iter().filter(|p| p.bytes as u64 <= budget).all(|p| p.psnr <= f.report.orbit_psnr), "{s:?}");
        // Unreachable: more than the finest setting gives.
        let e = enc.encode_scene_to(&scene, Target::Psnr(199.0), &mut |_| {}).unwrap_err();
        assert!(e.to_string().contains("not reachable") && e.exit_code() == 2, "{e}");
    }

    /// With fine-tuning, the RD search alone brackets λ and the fine-tuned encodes start from
    /// its λ: none runs at the ends, and the file is the smallest probe that met the target, or
    /// a mix of a phase's best with its nearest miss that is smaller still.
    #[test]
    fn a_fine_tuned_target_is_bracketed_by_the_search_alone_first() {
        use crate::encoder::Backend;
        let scene = crate::sample::scene(200, 3);
        let config = EncoderConfig { iters: Some(4), backend: Backend::Cpu, ..EncoderConfig::default() };
        let plain = Encoder::new(EncoderConfig { iters: Some(0), ..config.clone() }).unwrap();
        let want = plain.encode_scene(&scene, &mut |_| {}).unwrap().report.orbit_psnr - 3.0;
        let e = Encoder::new(config).unwrap().encode_scene_to(&scene, Target::Psnr(want), &mut |_| {}).unwrap();
        let s = e.report.target.clone().unwrap();
        assert!(e.report.orbit_psnr >= want, "{} < {want}", e.report.orbit_psnr);
        // The first phase from its start, untrained; then the trained probes.
        let first = s.probes.iter().take_while(|p| !p.trained).count();
        let trained = &s.probes[first..];
        assert!(first >= 2 && (s.probes[0].lambda.get() - start_lambda(scene.len())).abs() < 1e-9, "{s:?}");
        assert!(trained.iter().all(|p| p.trained), "{s:?}");
        assert!((1..=1 + MAX_OUTWARD_PROBES + MAX_INNER_PROBES).contains(&trained.len()), "{s:?}");
        assert!(trained.iter().all(|p| p.lambda != Lambda::ZERO && p.lambda.get() < MAX_LAMBDA), "{s:?}");
        // The first trained probe is at the first phase's best λ.
        let best_first = s.probes[..first].iter().filter(|p| p.psnr >= want).min_by_key(|p| p.bytes).unwrap();
        assert_eq!(trained[0].lambda, best_first.lambda, "{s:?}");
        // The output is the smallest probe that met the target (a fine-tuned one where it ties),
        // or smaller, from the mixes between it and its nearest miss, at a mix's PSNR.
        let best = s.probes.iter().filter(|p| p.psnr >= want).min_by_key(|p| p.bytes).unwrap();
        assert!(e.bytes.len() <= best.bytes, "{s:?}");
        if e.bytes.len() < best.bytes {
            assert!(s.between.iter().any(|b| b.psnr == e.report.orbit_psnr && b.psnr >= want), "{s:?}");
        }
        if e.bytes.len() == best.bytes && trained.iter().any(|p| p.psnr >= want && p.bytes == best.bytes) {
            assert_eq!(e.report.iters, 4);
            assert!(e.report.train.is_some());
        }
        // The search alone's best, mixed as a target without fine-tuning mixes it, is a
        // candidate: the file is never larger than that target's.
        let alone = plain.encode_scene_to(&scene, Target::Psnr(want), &mut |_| {}).unwrap();
        assert!(e.bytes.len() <= alone.bytes.len(), "{} > {}", e.bytes.len(), alone.bytes.len());
    }

    #[test]
    fn the_first_step_follows_the_first_phase_shifted_by_the_training_gain() {
        // Margins falling as 5 − 2t; at t = 2 (margin 1) training gained 2 dB (margin 3): the
        // shifted curve 7 − 2t crosses 0 at 3.5.
        let curve: Vec<(f64, f64)> = [0.0, 1.0, 2.5, 4.0, 6.0].iter().map(|&t| (t, 5.0 - 2.0 * t)).collect();
        let step = predicted_step(&curve, 2.0, 3.0, 1.0).unwrap();
        assert!((step - 1.5).abs() < 1e-12, "{step}");
        // Not on the other side, nor beyond the points.
        assert_eq!(predicted_step(&curve, 2.0, 3.0, -1.0), None);
        assert_eq!(predicted_step(&curve, 2.0, 30.0, 1.0), None);
        // Training that lost 2 dB (margin −1): 3 − 2t crosses 0 at 1.5, below t = 2.
        let step = predicted_step(&curve, 2.0, -1.0, -1.0).unwrap();
        assert!((step - 0.5).abs() < 1e-12, "{step}");
    }

    #[test]
    fn the_start_falls_as_one_over_the_gaussians() {
        assert!((start_lambda(9_200) - 25.0).abs() < 1e-12);
        assert!((start_lambda(92_000) - 2.5).abs() < 1e-12);
        assert_eq!(start_lambda(0), start_lambda(1));
        assert!(start_lambda(1) <= MAX_LAMBDA && start_lambda(usize::MAX) > 0.0);
    }

    /// A fine-tuned probe's choices are mixed on the scene its training left: the mixing starts
    /// from the best probe's file (its PSNR exactly) and nudges the miss from the miss's file,
    /// each on its own trained scene, not on the input nor on what a file decodes to.
    #[test]
    fn fine_tuned_probes_are_mixed_on_the_scenes_their_training_left() {
        let input = crate::sample::scene(300, 3);
        let orbit = Orbit::new(&input);
        // Two "trained" scenes: the input with its colours and opacities moved, as training
        // would move them, each coded at its own λ.
        let enc = |lambda: f64| Encoder::new(EncoderConfig { lambda: Lambda::new(lambda).unwrap(), ..EncoderConfig::default() }).unwrap();
        let tuned = |k: f32, lambda: f64| {
            let mut s = input.clone();
            s.sh_dc.iter_mut().flatten().for_each(|c| *c += k);
            s.opacity_logits.iter_mut().for_each(|o| *o -= k);
            let mut e = enc(lambda).encode_scene(&s, &mut |_| {}).unwrap();
            e.report.orbit_psnr = orbit.psnr(&e.decoded);
            e.report.fine_tuning_kept = Some(true);
            e.trained = Some(s);
            e
        };
        let (best, miss) = (tuned(0.02, 5.0), tuned(-0.03, 60.0));
        let want = (best.report.orbit_psnr + miss.report.orbit_psnr) / 2.0;
        assert!(miss.report.orbit_psnr < want && want < best.report.orbit_psnr, "{want}");
        let (best_file, miss_file) = (outcome(&best), outcome(&miss));
        let found = Searched { probes: Vec::new(), best: Some((1.0, best, best_file.1)), missed: vec![(2.0, miss.config, miss.trained)] };
        let trials = Trials::new(&input).unwrap();
        let mut between = Vec::new();
        let out = enc(5.0).mixed(&trials, &orbit, Target::Psnr(want), found, true, &mut between, &mut |_| {}).unwrap().unwrap();
        let start = |name: &str| between.iter().find(|b| b.round == 0 && b.change == name).map(|b| b.psnr);
        assert_eq!(start("best's choices"), Some(best_file.1), "{between:?}");
        assert_eq!(start("miss's choices"), Some(miss_file.1), "{between:?}");
        // The file is the best probe's or one of the mixes, at or above the target.
        assert!(out.report.orbit_psnr >= want && out.bytes.len() <= best_file.0, "{:?}", outcome(&out));
        assert!(out.trained.is_some(), "the file codes a trained scene");
    }

    /// Where no single nudge of the miss meets the target, the nudges are stacked, the most
    /// PSNR per byte first (round 0, `+ miss's …`), until the miss meets it; where one meets it
    /// alone, none are.
    #[test]
    fn a_miss_short_of_every_single_nudge_is_nudged_step_by_step() {
        let scene = crate::sample::scene(300, 11);
        let orbit = Orbit::new(&scene);
        let trials = Trials::new(&scene).unwrap();
        let enc = |lambda: f64| Encoder::new(EncoderConfig { lambda: Lambda::new(lambda).unwrap(), ..EncoderConfig::default() }).unwrap();
        let (best, miss) = (enc(2.0).encode_scene(&scene, &mut |_| {}).unwrap(), enc(80.0).encode_scene(&scene, &mut |_| {}).unwrap());
        let psnr = |c: &EncodeConfig| orbit.psnr(&trials.code(&EncodeConfig { learned_tables: false, ..*c }).unwrap().1);
        let single = rd::step_nudges(&miss.config, false, scene.sh_degree).iter().map(|(_, c)| psnr(c)).fold(f64::MIN, f64::max);
        assert!(single < best.report.orbit_psnr - 0.01, "{single} {}", best.report.orbit_psnr);
        let stacked = |want: f64| {
            let found = Searched { probes: Vec::new(), best: Some((1.0, best.clone(), 0.0)), missed: vec![(2.0, miss.config, None)] };
            let mut between = Vec::new();
            enc(2.0).mixed(&trials, &orbit, Target::Psnr(want), found, true, &mut between, &mut |_| {}).unwrap().unwrap();
            let singles_met =
                between.iter().any(|b| b.round == 0 && b.change.starts_with("miss's ") && b.change.ends_with("finer") && b.psnr >= want);
            let stacked: Vec<f64> = between.iter().filter(|b| b.round == 0 && b.change.starts_with("+ miss's ")).map(|b| b.psnr).collect();
            (singles_met, stacked)
        };
        // Just above every single nudge: they are stacked.
        let (met, tried) = stacked(single + 1e-6);
        assert!(!met && !tried.is_empty(), "{tried:?}");
        // At the best single nudge's PSNR: it meets alone, nothing is stacked.
        let (met, tried) = stacked(single);
        assert!(met && tried.is_empty(), "{tried:?}");
    }

    /// Where the searches on synthetic curves start.
    const START: f64 = 25.0;

    /// Runs [`search_lambda`] for `target` from λ = [`START`] on a scene whose file at `t = ln(1+λ)` has
    /// `curve(t)` = (bytes, PSNR); returns the probes (t, bytes, PSNR) and the best's `t`.
    fn searched(target: Target, curve: impl Fn(f64) -> (usize, f64)) -> (Vec<(f64, usize, f64)>, Option<f64>) {
        let scene = crate::sample::scene(20, 0);
        let template = Encoder::new(EncoderConfig::default()).unwrap().encode_scene(&scene, &mut |_| {}).unwrap();
        let found = search_lambda(target, false, START, &mut |_| {}, |lambda, _| {
            let (bytes, psnr) = curve(lambda.get().ln_1p());
            Ok((Encoded { bytes: vec![0; bytes], ..template.clone() }, psnr))
        })
        .unwrap();
        let probes = found.probes.iter().map(|p| (p.lambda.get().ln_1p(), p.bytes, p.psnr)).collect();
        (probes, found.best.map(|b| b.0))
    }

    /// The search starts at its λ and brackets the target without probing λ = 0 (the
    /// whole scene at the finest steps) or the largest λ when the target lies between, at least
    /// one unit of `ln(1+λ)` from them: on curves of the README scenes' slope and steeper or
    /// flatter ones, targets on either side of the start, for a PSNR and for a size.
    #[test]
    fn the_search_brackets_from_its_start_without_the_ends() {
        let t_max = MAX_LAMBDA.ln_1p();
        for slope in [2.0, 5.0, 12.0] {
            // PSNR falling from 55 dB at λ = 0 to 10 dB; bytes falling as e^(−0.45 t).
            let psnr = |t: f64| 10.0 + 45.0 / (1.0 + t * slope / 22.5);
            let bytes = |t: f64| (2e5 * (-0.45 * t).exp()) as usize + 50;
            let curve = |t: f64| (bytes(t), psnr(t));
            for cross in [0.5, 1.8, 3.0, 4.0, 6.0, 9.0] {
                for target in [Target::Psnr(psnr(cross)), Target::Bytes(bytes(cross) as u64)] {
                    let (probes, best) = searched(target, curve);
                    assert!((probes[0].0 - START.ln_1p()).abs() < 1e-12);
                    if cross >= 1.0 {
                        assert!(probes.iter().all(|p| p.0 > 0.0 && p.0 < t_max), "{target:?} slope {slope}: {probes:?}");
                    }
                    let best = best.expect("met");
                    // The best is within the search's resolution of the crossing, on the right side.
                    let gap = match target {
                        Target::Psnr(_) => cross - best,
                        Target::Bytes(_) => best - cross,
                    };
                    let closely = target.met_closely(target.margin(curve(best)));
                    assert!((-1e-9..=RESOLUTION).contains(&gap) || closely, "{target:?} slope {slope}: best {best}, {probes:?}");
                    assert!(probes.len() <= 1 + MAX_OUTWARD_PROBES + MAX_INNER_PROBES, "{target:?} slope {slope}: {probes:?}");
                }
            }
        }
    }

    /// Targets beyond either end: λ = 0 is probed and misses (unreachable), or the largest λ
    /// still meets it (its file is the smallest); a target met closely at the start stops there.
    #[test]
    fn targets_beyond_the_ends_probe_the_ends() {
        let psnr = |t: f64| 12.0 + 40.0 / (1.0 + t / 2.0);
        let curve = |t: f64| ((1e5 * (-0.4 * t).exp()) as usize + 50, psnr(t));
        let (probes, best) = searched(Target::Psnr(60.0), curve);
        assert!(best.is_none() && probes.iter().any(|p| p.0 == 0.0), "{probes:?}");
        let (probes, best) = searched(Target::Psnr(5.0), curve);
        assert_eq!(best, Some(MAX_LAMBDA.ln_1p()), "{probes:?}");
        let (probes, _) = searched(Target::Psnr(psnr(START.ln_1p()) - 0.01), curve);
        assert_eq!(probes.len(), 1, "{probes:?}");
    }

    /// Runs [`bracket`] on `margin` over the ends' bracket; returns the probes (t, margin).
    fn probes_of(margin: impl Fn(f64) -> f64, close: f64) -> Vec<(f64, f64)> {
        let t1 = MAX_LAMBDA.ln_1p();
        let mut seen = Vec::new();
        bracket(0.0, margin(0.0), t1, margin(t1), close, |t| {
            seen.push((t, margin(t)));
            Ok(margin(t))
        })
        .unwrap();
        seen
    }

    /// The best probe meeting the target (the largest t for a falling margin) and the closest
    /// one missing it.
    fn bracket_of(probes: &[(f64, f64)]) -> (f64, f64) {
        let good = probes.iter().filter(|p| p.1 >= 0.0).map(|p| p.0).fold(0.0, f64::max);
        let bad = probes.iter().filter(|p| p.1 < 0.0).map(|p| p.0).fold(MAX_LAMBDA.ln_1p(), f64::min);
        (good, bad)
    }

    #[test]
    fn a_smooth_curve_is_resolved_in_fewer_probes_than_bisection() {
        // A PSNR-like margin: 52 dB at λ = 0 falling to 10 dB, crossing the target at t = 3.2.
        let psnr = |t: f64| 10.0 + 42.0 / (1.0 + (t / 2.0).powi(2));
        let target = psnr(3.2);
        let probes = probes_of(|t| psnr(t) - target, CLOSE_PSNR);
        let (good, bad) = bracket_of(&probes);
        assert!(good <= 3.2 && 3.2 < bad, "{probes:?}");
        let met_closely = probes.iter().any(|p| (0.0..CLOSE_PSNR).contains(&p.1));
        assert!(met_closely || bad - good <= RESOLUTION, "{probes:?}");
        assert!(probes.len() < MAX_INNER_PROBES, "{} probes: {probes:?}", probes.len());
    }

    #[test]
    fn a_step_curve_keeps_the_bracket_and_the_probe_budget() {
        // A stepped curve (the RD search's choices are discrete): met below t = 5.3, by 1 dB.
        let probes = probes_of(|t| if t < 5.3 { 1.0 } else { -1.0 }, CLOSE_PSNR);
        let (good, bad) = bracket_of(&probes);
        assert!(good < 5.3 && 5.3 <= bad, "{probes:?}");
        assert_eq!(probes.len(), MAX_INNER_PROBES, "a step is never met closely: {probes:?}");
        // Bisection's 8 halvings would give 20.7 / 256; the clamped steps give at most 2x that.
        assert!(bad - good <= 2.0 * MAX_LAMBDA.ln_1p() / 256.0, "{probes:?}");
    }

    #[test]
    fn a_rising_margin_is_bracketed_from_the_other_end() {
        // A size target: the margin ln(budget / bytes) rises with t; met above t = 7.
        let bytes = |t: f64| 1e6 * (-0.4 * t).exp() + 100.0;
        let budget = bytes(7.0);
        let probes = probes_of(|t| budget.ln() - bytes(t).ln(), CLOSE_BYTES);
        let lowest_met = probes.iter().filter(|p| p.1 >= 0.0).map(|p| p.0).fold(f64::INFINITY, f64::min);
        let highest_missed = probes.iter().filter(|p| p.1 < 0.0).map(|p| p.0).fold(0.0, f64::max);
        assert!(highest_missed < 7.0 && 7.0 <= lowest_met, "{probes:?}");
        assert!(probes.len() < MAX_INNER_PROBES, "{probes:?}");
    }
}

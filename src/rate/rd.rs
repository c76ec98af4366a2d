//! Rate–distortion search over the encoder's choices by rendering: per-group step sizes, the
//! pruning threshold and the SH degree, greedily coarsened while `J = D + λ·R` falls.
//!
//! * `D` = 255² × mean squared error (RGB, all pixels) of the scene's standard orbit views
//!   ([`crate::views::orbit_cameras`], up −y as `eval --orbit`, 8 views at 96×96) against the views of the input scene.
//! * `R` = file size in megabits (bits / 10⁶): λ is a [`Lambda`], whose docs hold the unit.

use gscodec_decoder::render::render;
use gscodec_decoder::{Image, RenderOptions, SceneError, Splats};
use serde::Serialize;

use super::group::Group;
use super::lambda::Lambda;
use super::quantise::{dequantise, Steps};
use super::{encode, EncodeConfig};
use crate::views::{orbit_cameras, UpAxis};

/// Views and resolution the search renders.
pub const VIEWS: usize = 8;
pub const SIZE: u32 = 96;

/// One trial of the search (a configuration it encoded and measured).
#[derive(Debug, Clone, Serialize)]
pub struct Trial {
    pub step: usize,
    pub change: String,
    pub bytes: usize,
    pub d: f64,
    pub psnr: f64,
    pub j: f64,
}

/// The D/R evaluation of a configuration.
pub struct Evaluator<'a> {
    scene: &'a Splats,
    cams: Vec<gscodec_decoder::Camera>,
    refs: Vec<Image>,
    opts: RenderOptions,
}

impl<'a> Evaluator<'a> {
    pub fn new(scene: &'a Splats) -> Self {
        let cams = orbit_cameras(scene, VIEWS, SIZE, SIZE, UpAxis::NegY.vector());
        let opts = RenderOptions::default();
        let refs = cams.iter().map(|c| render(scene, c, &opts)).collect();
        Evaluator { scene, cams, refs, opts }
    }

    /// (bytes, D) of `config`.
    pub fn eval(&self, config: &EncodeConfig) -> Result<(usize, f64), SceneError> {
        self.eval_report(config).map(|(b, d, _)| (b, d))
    }

    /// (bytes, D, encoder report) of `config`.
    pub fn eval_report(&self, config: &EncodeConfig) -> Result<(usize, f64, super::EncodeReport), SceneError> {
        let (bytes, report, q) = encode(self.scene, config)?;
        let dec = dequantise(&q);
        let mse = self.cams.iter().zip(&self.refs).map(|(c, r)| crate::metrics::mse(r, &render(&dec, c, &self.opts))).sum::<f64>()
            / self.cams.len() as f64;
        Ok((bytes.len(), mse * 255.0 * 255.0, report))
    }
}

const MULTIPLIERS: [f32; 6] = [1.0, 2.0, 4.0, 8.0, 16.0, 32.0];
/// Pruning thresholds tried, in units of 1/255 opacity.
const PRUNE_THRESHOLDS: [f32; 12] = [1.0, 2.0, 3.0, 4.0, 6.0, 8.0, 12.0, 16.0, 24.0, 32.0, 64.0, 512.0];
/// Fractions of the Gaussians (smallest footprints first) the footprint pruning tries.
const FOOTPRINT_QUANTILES: [f32; 7] = [0.05, 0.1, 0.15, 0.2, 0.3, 0.4, 0.5];
/// SH rest dead zones tried after the steps are chosen (see `Steps::rest_deadzone`).
const DEADZONES: [f32; 4] = [0.1, 0.2, 0.3, 0.4];
const REFINE: [f32; 3] = [std::f32::consts::FRAC_1_SQRT_2, 1.0, std::f32::consts::SQRT_2];
/// Quarter-octave moves of the last pass.
const REFINE_FINE: [f32; 3] = [0.840_896_4, 1.0, 1.189_207_1];

/// `c` with group `g`'s step multiplied by `m` (the knobs of the search: one per group).
fn with_knob(c: &EncodeConfig, g: Group, m: f32) -> EncodeConfig {
    let mut c = *c;
    *c.steps.of_mut(g) *= m;
    c
}

/// Rate–distortion allocation by rendering. Distortion is treated as additive over groups
/// (each group's coarsening is measured alone) and group rates as independent, so each group's
/// step is chosen separately: first the pruning threshold, then the SH degree, then per group
/// the multiplier of the fine step minimising `ΔD_g + λ·R_g`. `on_step` sees each trial.
pub fn search(scene: &Splats, lambda: Lambda, on_step: impl FnMut(&Trial)) -> Result<(EncodeConfig, Vec<Trial>), SceneError> {
    search_from(scene, lambda, Steps::default().scaled(0.7), on_step)
}

/// [`search`] with the per-group step multipliers applied to `fine` (e.g. steps learned in
/// training) instead of the default fine steps; multiplier 1 keeps a step as it is.
pub fn search_from(
    scene: &Splats,
    lambda: Lambda,
    fine: Steps,
    mut on_step: impl FnMut(&Trial),
) -> Result<(EncodeConfig, Vec<Trial>), SceneError> {
    scene.validate()?;
    let ev = Evaluator::new(scene);
    let j = |bytes: usize, d: f64| d + lambda.rate_cost(bytes);
    let mut path = Vec::new();
    let mut record = |change: String, bytes: usize, d: f64, path: &mut Vec<Trial>| {
        let p =
            Trial { step: path.len(), change, bytes, d, psnr: gscodec_decoder::render::psnr_of_mse(d / (255.0 * 255.0)), j: j(bytes, d) };
        on_step(&p);
        path.push(p);
    };
    let fine = EncodeConfig { steps: fine, learned_tables: false, ..EncodeConfig::default() };
    // 1. Pruning threshold (at fine steps), including "everything" (an empty file).
    let mut best = (f64::INFINITY, fine);
    for t in PRUNE_THRESHOLDS {
        let c = EncodeConfig { min_opacity: t / 255.0, ..fine };
        let (b, d) = ev.eval(&c)?;
        record(format!("prune<{t}/255"), b, d, &mut path);
        if j(b, d) < best.0 {
            best = (j(b, d), c);
        }
    }
    // 1b. Footprint pruning (small faint Gaussians) at quantiles of the kept Gaussians' footprints.
    let kept = super::quantise::prune(scene, best.1.min_opacity);
    let mut fp: Vec<f32> = (0..kept.len()).map(|i| super::quantise::footprint(&kept, i)).collect();
    fp.sort_by(f32::total_cmp);
    let start = best.1;
    for f in FOOTPRINT_QUANTILES {
        let Some(&t) = fp.get((fp.len() as f64 * f64::from(f)) as usize) else { continue };
        let c = EncodeConfig { min_footprint: t, ..start };
        let (b, d) = ev.eval(&c)?;
        record(format!("footprint<q{f}"), b, d, &mut path);
        if j(b, d) < best.0 {
            best = (j(b, d), c);
        }
    }
    let base = best.1;
    let (b0, _) = ev.eval(&base)?;
    if b0 < 200 {
        return Ok((EncodeConfig { learned_tables: true, ..base }, path)); // nothing (or almost nothing) left to allocate
    }
    // 2. SH degree (at fine steps): keep the degree with the lowest J.
    let mut best = (f64::INFINITY, base);
    for deg in (0..=scene.sh_degree.min(3)).rev() {
        let c = EncodeConfig { max_sh_degree: deg, ..base };
        let (b, d) = ev.eval(&c)?;
        record(format!("sh_degree={deg}"), b, d, &mut path);
        if j(b, d) < best.0 {
            best = (j(b, d), c);
        }
    }
    let base = best.1;
    let (b0, d0, r0) = ev.eval_report(&base)?;
    let group_bytes =
        |r: &super::EncodeReport, k: Group| r.groups.iter().find(|g| g.group == k.name()).map_or(0, |g| g.stream_bytes + g.table_bytes);
    // 3. Per group step multipliers: a coarse pass from the fine steps, then a refining pass
    //    (half-octave moves around the first choice), then quarter-octave moves.
    let mut chosen = base;
    for (pass, mults) in [(0, &MULTIPLIERS[..]), (1, &REFINE[..]), (2, &REFINE_FINE[..])] {
        let start = chosen;
        let (b0, d0, r0) = if pass == 0 { (b0, d0, r0.clone()) } else { ev.eval_report(&start)? };
        for k in Group::ALL {
            if group_bytes(&r0, k) == 0 {
                continue;
            }
            let mut best_k = (f64::INFINITY, 1.0f32);
            for &m in mults {
                let c = with_knob(&start, k, m);
                let (b, d, gb) = if m == 1.0 {
                    (b0, d0, group_bytes(&r0, k))
                } else {
                    let (b, d, r) = ev.eval_report(&c)?;
                    (b, d, group_bytes(&r, k))
                };
                record(format!("pass{pass} {}x{m}", k.name()), b, d, &mut path);
                let cost = (d - d0) + lambda.rate_cost(gb);
                if cost < best_k.0 {
                    best_k = (cost, m);
                }
            }
            chosen = with_knob(&chosen, k, best_k.1);
        }
    }
    // 4. SH rest dead zone (whole-file J: it changes only the SH band groups).
    if chosen.max_sh_degree > 0 && scene.sh_degree > 0 {
        let (b, d) = ev.eval(&chosen)?;
        let mut best = (j(b, d), chosen);
        for dz in DEADZONES {
            let mut c = chosen;
            c.steps.rest_deadzone = dz;
            let (b, d) = ev.eval(&c)?;
            record(format!("rest_deadzone={dz}"), b, d, &mut path);
            if j(b, d) < best.0 {
                best = (j(b, d), c);
            }
        }
        chosen = best.1;
    }
    Ok((EncodeConfig { learned_tables: true, ..chosen }, path))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// λ measured end to end: the search's chosen file shrinks and its distortion grows as λ
    /// grows (replaces a test that only checked the final multiply by λ).
    #[test]
    fn larger_lambda_gives_smaller_files_and_more_distortion() {
        let scene = crate::sample::scene(300, 1);
        let ev = Evaluator::new(&scene);
        let mut last: Option<(usize, f64)> = None;
        for l in [0.0, 20.0, 2000.0] {
            let (cfg, path) = search(&scene, Lambda::new(l).unwrap(), |_| {}).unwrap();
            let (bytes, d) = ev.eval(&cfg).unwrap();
            assert!(path.iter().all(|p| (p.j - (p.d + Lambda::new(l).unwrap().rate_cost(p.bytes))).abs() < 1e-9));
            if let Some((b0, d0)) = last {
                assert!(bytes < b0, "λ {l}: {bytes} bytes, not fewer than {b0}");
                assert!(d >= d0, "λ {l}: D {d} below {d0}");
            }
            last = Some((bytes, d));
        }
    }
}

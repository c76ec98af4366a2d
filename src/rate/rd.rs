//! Rate–distortion search over the encoder's choices by rendering: per-group step sizes, the
//! pruning threshold and the SH degree, greedily coarsened while `J = D + λ·R` falls.
//!
//! * `D` = 255² × mean squared error (RGB, all pixels) of the scene's standard orbit views
//!   ([`crate::io::scene_orbit`], 8 views at 192×192) against the views of the input scene.
//! * `R` = file size in megabits (bits / 10⁶): a fixed constant, so λ means the same everywhere.

use gscodec_decoder::render::render;
use gscodec_decoder::{Image, RenderOptions, SceneError, Splats};
use serde::Serialize;

use super::quantise::{dequantise, prune, quantise, Steps};
use super::{encode, EncodeConfig};
use crate::io::scene_orbit;

/// Views and resolution the search renders.
pub const VIEWS: usize = 8;
pub const SIZE: u32 = 192;

/// One accepted step of the search.
#[derive(Debug, Clone, Serialize)]
pub struct RdPoint {
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
        let cams = scene_orbit(scene, VIEWS, SIZE, SIZE);
        let opts = RenderOptions::default();
        let refs = cams.iter().map(|c| render(scene, c, &opts)).collect();
        Evaluator { scene, cams, refs, opts }
    }

    /// (bytes, D) of `config`.
    pub fn eval(&self, config: &EncodeConfig) -> Result<(usize, f64), SceneError> {
        let (bytes, _, q) = encode(self.scene, config)?;
        let dec = dequantise(&q);
        let mse = self.cams.iter().zip(&self.refs).map(|(c, r)| crate::metrics::mse(r, &render(&dec, c, &self.opts))).sum::<f64>() / self.cams.len() as f64;
        Ok((bytes.len(), mse * 255.0 * 255.0))
    }
}

fn psnr_of(d: f64) -> f64 {
    10.0 * (255.0f64 * 255.0 / d.max(1e-12)).log10()
}

/// Greedy search from a fine configuration; returns the best configuration and the path taken.
pub fn search(scene: &Splats, lambda: f64, mut on_step: impl FnMut(&RdPoint)) -> Result<(EncodeConfig, Vec<RdPoint>), SceneError> {
    scene.validate()?;
    let ev = Evaluator::new(scene);
    let j = |bytes: usize, d: f64| d + lambda * bytes as f64 * 8.0 / 1e6;
    let mut cur = EncodeConfig { steps: Steps::default().scaled(0.7), ..EncodeConfig::default() };
    let (b, d) = ev.eval(&cur)?;
    let mut best_j = j(b, d);
    let mut path = vec![RdPoint { step: 0, change: "start".into(), bytes: b, d, psnr: psnr_of(d), j: best_j }];
    on_step(&path[0]);
    let r2 = std::f32::consts::SQRT_2;
    for step in 1..=60 {
        let mut moves: Vec<(String, EncodeConfig)> = Vec::new();
        let mut push = |name: &str, f: &dyn Fn(&mut EncodeConfig)| {
            let mut c = cur;
            f(&mut c);
            moves.push((name.to_string(), c));
        };
        push("position", &|c| c.steps.position_rel *= r2);
        push("scale", &|c| c.steps.scale *= r2);
        push("rotation", &|c| c.steps.rotation *= r2);
        push("opacity", &|c| c.steps.opacity *= r2);
        push("sh_dc", &|c| c.steps.sh_dc *= r2);
        for b in 0..3 {
            push(&format!("sh_band{}", b + 1), &|c| c.steps.sh_rest[b] *= r2);
        }
        push("prune", &|c| c.min_opacity = (c.min_opacity * 1.5).min(1.5));
        if cur.max_sh_degree > 0 && scene.sh_degree >= cur.max_sh_degree {
            push("drop_band", &|c| c.max_sh_degree -= 1);
        }
        let mut best: Option<(String, EncodeConfig, usize, f64, f64)> = None;
        for (name, c) in moves {
            let (b, d) = ev.eval(&c)?;
            let jj = j(b, d);
            if jj < best_j && best.as_ref().is_none_or(|x| jj < x.4) {
                best = Some((name, c, b, d, jj));
            }
        }
        let Some((name, c, b, d, jj)) = best else { break };
        cur = c;
        best_j = jj;
        let p = RdPoint { step, change: name, bytes: b, d, psnr: psnr_of(d), j: jj };
        on_step(&p);
        path.push(p);
    }
    // Make sure the file is not worse than pruning everything (huge λ).
    let empty = EncodeConfig { min_opacity: 2.0, ..cur };
    let (b, d) = ev.eval(&empty)?;
    if j(b, d) < best_j {
        cur = empty;
        path.push(RdPoint { step: path.len(), change: "empty".into(), bytes: b, d, psnr: psnr_of(d), j: j(b, d) });
    }
    let _ = prune; // pruning itself happens inside `encode`
    Ok((cur, path))
}

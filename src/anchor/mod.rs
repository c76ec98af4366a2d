//! The anchor profile's encoder (`encode --profile anchor`, SPEC §12, format 7.0), in the spirit
//! of Comp-GS / Scaffold-GS. The Gaussians' positions are coded on a grid as in the explicit
//! profile; the grid's coarser cells are the anchors ([`fit::choose_shift`]), each with a feature
//! vector and a base log scale, and one small MLP shared by all anchors turns an anchor's
//! features and a Gaussian's cell inside it into that Gaussian's opacity, scale, rotation and
//! colour. The MLP and the features are distilled from the input's attributes
//! ([`fit::distill`]), fine-tuned against renders of the input or against the images it was
//! trained from ([`fit::fine_tune`], [`FitViews`]), then the MLP is turned into the fixed-point
//! one the decoder runs ([`fixed`]).

pub mod fit;
pub mod fixed;
pub mod model;

use std::sync::Arc;

use gscodec_decoder::{Camera, Image, Splats};
use serde::Serialize;

use crate::views::{training_cameras, UpAxis};

/// Choices of the anchor profile.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AnchorConfig {
    /// Position grid bits per axis; `None`: the explicit profile's choice for the scene
    /// ([`crate::rate::quantise::position_bits`] at its default step).
    pub position_bits: Option<u8>,
    /// Mean Gaussians per anchor the anchor cell size aims at.
    pub per_anchor: f32,
    /// Features per anchor, F.
    pub features: usize,
    /// Hidden units of the MLP, H.
    pub hidden: usize,
    /// Highest SH degree the MLP outputs (at most the input's).
    pub max_sh_degree: u8,
    /// Step of the base log scales.
    pub base_step: f32,
    /// Distillation steps (full batch).
    pub distill_iters: usize,
    /// Fine-tuning steps (one rendered view each).
    pub iters: usize,
    pub seed: u64,
}

impl Default for AnchorConfig {
    fn default() -> Self {
        AnchorConfig {
            position_bits: None,
            per_anchor: 6.0,
            features: 16,
            hidden: 32,
            max_sh_degree: 1,
            base_step: 0.25,
            distill_iters: 600,
            iters: 300,
            seed: 0,
        }
    }
}

/// The posed images the anchors are fine-tuned to.
pub struct FitViews {
    pub cameras: Vec<Camera>,
    /// One per camera, at its size.
    pub images: Vec<Arc<Image>>,
    /// What the images show behind the scene.
    pub background: [f32; 3],
    /// `images` for a dataset's training views, `renders` for renders of the input scene.
    pub kind: &'static str,
}

impl FitViews {
    /// Renders of `scene` from [`training_cameras`] at the orbit size, on black
    /// ([`render_targets`](crate::train::targets::render_targets)): what a `.ply` input is
    /// fine-tuned to.
    pub fn renders(scene: &Splats) -> FitViews {
        let size = crate::encoder::ORBIT_SIZE;
        let cameras = training_cameras(scene, 8, size, size, UpAxis::NegY.vector());
        let targets = crate::train::targets::render_targets(scene, &cameras, [0.0; 3]);
        Self::of_frames(targets.frames.iter(), targets.background, "renders").expect("rendered images are in memory")
    }

    /// The training views of `dataset` (its held-out views are left out), as loaded.
    ///
    /// # Errors
    /// An image that cannot be read (a dataset streamed from disk).
    pub fn training_views(dataset: &crate::io::dataset::Dataset) -> crate::Result<FitViews> {
        Self::of_frames(dataset.split(crate::io::dataset::Split::Train).into_iter(), dataset.background, "images")
    }

    fn of_frames<'a>(
        frames: impl Iterator<Item = &'a crate::io::dataset::Frame> + Clone,
        background: [f32; 3],
        kind: &'static str,
    ) -> crate::Result<FitViews> {
        let images = frames.clone().map(|f| f.image.get()).collect::<crate::Result<Vec<_>>>()?;
        Ok(FitViews { cameras: frames.map(|f| f.camera).collect(), images, background, kind })
    }
}

/// What an anchor encode did.
#[derive(Debug, Clone, Serialize)]
pub struct AnchorReport {
    pub anchors: usize,
    pub anchor_shift: u8,
    pub position_bits: u8,
    pub features: usize,
    pub hidden: usize,
    pub gaussians: usize,
    pub sh_degree: u8,
    pub distill_loss: f64,
    pub fine_tune_loss: f64,
    /// What the fine-tuning fitted: `renders` of the input scene, the dataset's training
    /// `images`, or `none` (no fine-tuning steps).
    pub fine_tuned_to: &'static str,
    /// PSNR of the float model (before the fixed-point MLP) against this encoder's input scene
    /// (for `encode`, the explicit search's pruned scene), `eval --orbit 8`'s measure.
    pub float_psnr: f64,
    pub bytes: fixed::AnchorBytes,
}

/// An anchor-profile file, its decoded scene and what was done.
pub struct AnchorEncoded {
    pub bytes: Vec<u8>,
    pub decoded: Splats,
    pub report: AnchorReport,
}

/// Encodes `scene` (validated, non-empty) in the anchor profile. `sig` is each Gaussian's
/// significance ([`crate::rate::importance::significance`]), the weight of its attributes in
/// the distillation; Gaussians the renderer never draws (opacity below 1/255) should be pruned
/// before. `input` (Gaussians, SH degree) is what the encoder's caller started from, for the
/// file's info section.
///
/// `views` are the images the fine-tuning fits; `None`: [`FitViews::renders`] of `scene`.
pub fn encode(scene: &Splats, sig: &[f32], cfg: &AnchorConfig, input: (usize, u8), views: Option<&FitViews>) -> AnchorEncoded {
    let degree = cfg.max_sh_degree.min(scene.sh_degree);
    let bits = cfg
        .position_bits
        .unwrap_or_else(|| crate::rate::quantise::position_bits(scene, crate::rate::quantise::Steps::default().position_rel));
    let placed = fit::place(scene, bits);
    let shift = fit::choose_shift(&placed.morton, bits, cfg.per_anchor);
    let mut model = fit::init(scene, &placed, shift, cfg.features, cfg.hidden, degree, cfg.seed);
    let mean = sig.iter().map(|&s| f64::from(s)).sum::<f64>() / sig.len().max(1) as f64;
    let weight: Vec<f32> = placed.order.iter().map(|&g| (f64::from(sig[g]) / mean.max(1e-12)).clamp(0.01, 100.0).sqrt() as f32).collect();
    let distill_loss = fit::distill(&mut model, scene, &placed.order, &weight, cfg.distill_iters);
    let (mut fine_tune_loss, mut fine_tuned_to) = (f64::NAN, "none");
    if cfg.iters > 0 {
        let own;
        let views = match views {
            Some(v) => v,
            None => {
                own = FitViews::renders(scene);
                &own
            }
        };
        fine_tune_loss = fit::fine_tune(&mut model, views, cfg.iters, cfg.base_step, cfg.seed);
        fine_tuned_to = views.kind;
    }
    // The float model's scene (base rounded as coded): how much the fixed-point MLP costs.
    let act = model.forward();
    let float_psnr = crate::encoder::orbit_psnr(scene, &model.gaussians(&act.out, &fit::rounded(&model.base, cfg.base_step)));
    let q = fixed::quantise(&model, &act, placed.grid, &placed.morton, shift, cfg.base_step);
    let (bytes, sizes) = fixed::write(&q, input);
    let report = AnchorReport {
        anchors: model.anchors(),
        anchor_shift: shift,
        position_bits: bits,
        features: cfg.features,
        hidden: cfg.hidden,
        gaussians: q.decoded.len(),
        sh_degree: degree,
        distill_loss,
        fine_tune_loss,
        fine_tuned_to,
        float_psnr,
        bytes: sizes,
    };
    AnchorEncoded { bytes, decoded: q.decoded, report }
}

#[cfg(test)]
mod tests {
    use super::*;
    use gscodec_decoder::bitstream::anchors::outputs_per_gaussian;

    fn tiny() -> Splats {
        crate::io::read_ply(&std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/tiny/truth.ply")).unwrap()
    }

    fn quick() -> AnchorConfig {
        AnchorConfig { features: 8, hidden: 16, distill_iters: 60, iters: 0, ..AnchorConfig::default() }
    }

    fn run(scene: &Splats, cfg: &AnchorConfig) -> AnchorEncoded {
        let sig = crate::rate::importance::significance(scene);
        encode(scene, &sig, cfg, (scene.len(), scene.sh_degree), None)
    }

    #[test]
    fn the_file_decodes_to_the_encoders_scene() {
        let scene = tiny();
        let e = run(&scene, &AnchorConfig { iters: 5, ..quick() });
        let h = gscodec_decoder::peek_header(&e.bytes).unwrap();
        assert_eq!((h.version_major, h.gaussians as usize, h.sh_degree), (7, scene.len(), 1));
        assert_eq!(gscodec_decoder::decode(&e.bytes).unwrap(), e.decoded);
        // Positions are the grid's: within half a grid step of the input's, in Morton order.
        let info = gscodec_decoder::inspect(&e.bytes).unwrap();
        let a = info.anchors.expect("an anchor file");
        assert_eq!((a.anchors, a.features, a.widths.clone()), (e.report.anchors, 8, vec![8 + 3, 16, outputs_per_gaussian(1)]));
        let mut input: Vec<[f32; 3]> = scene.positions.clone();
        let mut output = e.decoded.positions.clone();
        let key = |p: &[f32; 3]| (p[0].to_bits(), p[1].to_bits(), p[2].to_bits());
        input.sort_by_key(key);
        output.sort_by_key(key);
        let (lo, hi) = scene.bounds().unwrap();
        let step = (0..3).map(|i| hi[i] - lo[i]).fold(0.0f32, f32::max) / ((1u32 << e.report.position_bits) - 1) as f32;
        let nearest =
            |p: &[f32; 3]| output.iter().map(|q| (0..3).map(|i| (p[i] - q[i]).abs()).fold(0.0f32, f32::max)).fold(f32::MAX, f32::min);
        assert!(input.iter().all(|p| nearest(p) <= 0.51 * step), "every input Gaussian has a decoded one on its grid cell");
    }

    #[test]
    fn one_gaussian_and_a_flat_scene_code_too() {
        // One Gaussian: a grid of 0 bits, anchor cells of one cell. A flat scene: bounds of zero
        // extent on one axis.
        let scene = tiny();
        let one = {
            let mut s = scene.clone();
            s.retain_indices(|i| i == 0);
            s
        };
        let mut flat = scene.clone();
        flat.positions.iter_mut().for_each(|p| p[2] = 0.5);
        for (s, bits) in [(&one, 0u8), (&flat, 6)] {
            let e = run(s, &AnchorConfig { position_bits: Some(bits), ..quick() });
            assert_eq!(gscodec_decoder::decode(&e.bytes).unwrap(), e.decoded);
            assert_eq!(e.decoded.len(), s.len());
        }
    }

    #[test]
    fn encoding_does_not_depend_on_the_thread_count() {
        let scene = tiny();
        let cfg = AnchorConfig { iters: 3, ..quick() };
        let on = |threads: usize| rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(|| run(&scene, &cfg).bytes);
        assert_eq!(on(1), on(3));
    }

    #[test]
    fn the_fixed_point_mlp_follows_the_float_one() {
        let scene = tiny();
        let bits = crate::rate::quantise::position_bits(&scene, crate::rate::quantise::Steps::default().position_rel);
        let placed = fit::place(&scene, bits);
        let shift = fit::choose_shift(&placed.morton, bits, 6.0);
        let mut model = fit::init(&scene, &placed, shift, 8, 16, 1, 0);
        let weight = vec![1.0; scene.len()];
        fit::distill(&mut model, &scene, &placed.order, &weight, 100);
        let act = model.forward();
        let float = model.gaussians(&act.out, &model.base);
        let q = fixed::quantise(&model, &act, placed.grid, &placed.morton, shift, 1e-6);
        // The integer weights round each weight to about 2^-11 (first layer) and 2^-10 (last)
        // of the layer's largest: a value moves by about a hundredth on average (opacity
        // logits; a few thousandths for log scales and SH), at worst by a few hundredths.
        let errors = |a: &[f32], b: &[f32]| {
            let d: Vec<f32> = a.iter().zip(b).map(|(x, y)| (x - y).abs()).collect();
            (d.iter().sum::<f32>() / d.len() as f32, d.iter().fold(0.0f32, |m, &v| m.max(v)))
        };
        for (what, a, b) in [
            ("opacity", &float.opacity_logits[..], &q.decoded.opacity_logits[..]),
            ("log scale", float.log_scales.as_flattened(), q.decoded.log_scales.as_flattened()),
            ("rotation", float.rotations.as_flattened(), q.decoded.rotations.as_flattened()),
            ("DC", float.sh_dc.as_flattened(), q.decoded.sh_dc.as_flattened()),
            ("rest", &float.sh_rest[..], &q.decoded.sh_rest[..]),
        ] {
            let (mean, max) = errors(a, b);
            assert!(mean < 0.02 && max < 0.06, "{what}: mean {mean}, max {max}");
        }
        let (pf, pq) = (crate::encoder::orbit_psnr(&scene, &float), crate::encoder::orbit_psnr(&scene, &q.decoded));
        assert!((pf - pq).abs() < 0.2, "float {pf:.2} dB, fixed {pq:.2} dB");
        assert_eq!(float.positions, q.decoded.positions);
    }

    #[test]
    fn the_mlp_gradient_matches_finite_differences() {
        let scene = tiny();
        let placed = fit::place(&scene, 8);
        let mut model = fit::init(&scene, &placed, 3, 4, 6, 1, 7);
        // Hidden biases well above zero keep every ReLU on its linear side under the ±ε
        // perturbations (a kink inside [w − ε, w + ε] would spoil the central difference);
        // units 4 and 5 are left off (biases well below zero) so that their zero gradient is
        // checked too.
        let m = model.inputs();
        for (j, row) in model.w1.chunks_exact_mut(m + 1).enumerate() {
            row[m] = if j < 4 { 20.0 } else { -20.0 };
        }
        // L = Σ c_k · out_k with fixed random c: dL/dout = c.
        let mut rng = crate::rng::Rng::new(3);
        let act = model.forward();
        let c: Vec<f32> = (0..act.out.len()).map(|_| rng.normal()).collect();
        let loss = |m: &model::Model| -> f64 { m.forward().out.iter().zip(&c).map(|(o, c)| f64::from(o * c)).sum() };
        let (g1, g2, _) = model.backward(&act, &c);
        // w1 row j holds unit j's m weights and bias: indices in rows 0, 2 (on) and 5 (off).
        for (which, idx) in [(1, 0), (1, 2 * (m + 1) + 3), (1, 2 * (m + 1) + m), (1, 5 * (m + 1) + 1), (2, 0), (2, 9), (2, 30)] {
            let mut plus = model.clone();
            let mut minus = model.clone();
            let eps = 1e-2f32;
            let (p, m, g) = if which == 1 { (&mut plus.w1, &mut minus.w1, g1[idx]) } else { (&mut plus.w2, &mut minus.w2, g2[idx]) };
            p[idx] += eps;
            m[idx] -= eps;
            let fd = (loss(&plus) - loss(&minus)) / f64::from(2.0 * eps);
            assert!((fd - f64::from(g)).abs() <= 1e-2 * (1.0 + fd.abs()), "w{which}[{idx}]: analytic {g}, numeric {fd}");
        }
    }

    #[test]
    fn distillation_and_fine_tuning_bring_the_scene_closer() {
        let scene = tiny();
        let psnr = |cfg: &AnchorConfig| crate::encoder::orbit_psnr(&scene, &run(&scene, cfg).decoded);
        let raw = psnr(&AnchorConfig { distill_iters: 0, ..quick() });
        let distilled = psnr(&AnchorConfig { distill_iters: 200, ..quick() });
        let tuned = psnr(&AnchorConfig { distill_iters: 200, iters: 150, ..quick() });
        assert!(distilled > raw + 3.0, "distillation: {raw:.2} → {distilled:.2} dB");
        assert!(tuned > distilled + 0.5, "fine-tuning: {distilled:.2} → {tuned:.2} dB");
    }

    /// Fine-tuning fits the views it is given (a dataset's images), not renders of the scene:
    /// given views of the scene with its colours changed, the file moves towards them.
    #[test]
    fn fine_tuning_fits_the_given_views() {
        let scene = tiny();
        let mut other = scene.clone();
        other.sh_dc.iter_mut().for_each(|c| c[0] += 0.8);
        let views = FitViews { kind: "images", ..FitViews::renders(&other) };
        let sig = crate::rate::importance::significance(&scene);
        let cfg = AnchorConfig { distill_iters: 200, iters: 150, ..quick() };
        let to_views = encode(&scene, &sig, &cfg, (scene.len(), scene.sh_degree), Some(&views));
        let to_scene = run(&scene, &cfg);
        assert_eq!((to_views.report.fine_tuned_to, to_scene.report.fine_tuned_to), ("images", "renders"));
        let psnr = |e: &AnchorEncoded| crate::encoder::orbit_psnr(&other, &e.decoded);
        assert!(psnr(&to_views) > psnr(&to_scene) + 1.0, "{:.2} vs {:.2} dB", psnr(&to_views), psnr(&to_scene));
    }
}

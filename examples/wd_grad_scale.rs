//! Gradient magnitudes w.r.t. the Gaussian parameters of each part of the training objective, on a
//! mid-training scene: L1-SSIM, γ·d_WD, γ·β·L_orig (WD-R at the paper's γ), WD-R with the
//! normalised γ, and the rate term at a λ. Also the densification statistic (|dL/d mean2d| in
//! NDC units) against its threshold.
//!
//! `cargo run --release --example wd_grad_scale -- DATA [ITERS] [LAMBDA]`
//! (trains ITERS iterations of L1-SSIM first, then measures on 20 training views).

use gscodec::decoder::{RenderOptions, Splats};
use gscodec::io::{load_dataset, LoadOptions, Split};
use gscodec::loss::features::FeatureSpec;
use gscodec::loss::wdr::{self, WdDistortion};
use gscodec::loss::L1Ssim;
use gscodec::rate::group::{self, Group};
use gscodec::rate::term::RateTerm;
use gscodec::rate::{EncodeConfig, Lambda};
use gscodec::train::{train, TrainConfig};

fn norm(v: &[f32]) -> f64 {
    v.iter().map(|x| (*x as f64).powi(2)).sum::<f64>().sqrt()
}

/// Per group, the L2 norm of its values (each SH band alone, not the whole `sh_rest`).
fn group_norms(g: &Splats) -> Vec<(Group, f64)> {
    Group::ALL
        .into_iter()
        .map(|grp| (grp, group::per_gaussian(g, grp).flatten().map(|x| (*x as f64).powi(2)).sum::<f64>().sqrt()))
        .collect()
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let dir = std::path::PathBuf::from(args.get(1).expect("usage: wd_grad_scale DATA [ITERS] [LAMBDA]"));
    let iters: usize = args.get(2).map(|s| s.parse().unwrap()).unwrap_or(1000);
    let lambda = Lambda::new(args.get(3).map(|s| s.parse().unwrap()).unwrap_or(Lambda::DEFAULT.get())).unwrap();
    let ds = load_dataset(&dir, &LoadOptions::default()).expect("dataset");
    let cfg = TrainConfig { iters, eval_interval: 0, ..Default::default() };
    let (scene, _) = train(&ds, None, &cfg, Box::new(L1Ssim::default()), None, &mut |_| {}).expect("training");
    println!("scene after {iters} L1-SSIM iterations: {} Gaussians, SH degree {}", scene.len(), scene.sh_degree);
    let threshold = cfg.densify_grad_threshold as f64;

    let mut wd = WdDistortion::new(FeatureSpec::Pyramid.build().unwrap());
    let (gamma, beta) = (wdr::DEFAULT_GAMMA_WDR, wdr::BETA);
    let frames = ds.split(Split::Train);
    let names = ["l1ssim", "gamma*d_WD", "gamma*beta*L_orig", "wdr (paper gamma)", "wdr (normalised gamma)"];
    let mut param_norms = vec![vec![0.0f64; Group::ALL.len()]; names.len()];
    let mut image_norms = vec![0.0f64; names.len()];
    let mut densify_frac = vec![0.0f64; names.len()];
    let mut mean2d = vec![0.0f64; names.len()];
    let views: Vec<usize> = (0..frames.len()).step_by((frames.len() / 20).max(1)).take(20).collect();
    // Normalised γ (the fix in src/loss/wdr.rs): Σ‖∇L_orig‖ / Σ‖∇(d_WD + β·L_orig)‖ over the views.
    let (mut so, mut sc) = (0.0, 0.0);
    let mut per_view = Vec::new();
    for &v in &views {
        let f = frames[v];
        let opts = RenderOptions { background: ds.background, max_sh_degree: scene.sh_degree };
        let (img, state) = gscodec::raster::forward(&scene, &f.camera, &opts);
        let (_, g_l1) = L1Ssim::default().eval(&img, &f.image.get().unwrap());
        let (_, g_wd) = wd.value_and_grad(&img, &f.image.get().unwrap(), Some(v));
        let comb: Vec<f32> = g_wd.iter().zip(&g_l1).map(|(w, o)| w + beta as f32 * o).collect();
        so += norm(&g_l1);
        sc += norm(&comb);
        per_view.push((state, g_l1, g_wd));
    }
    let gamma_norm = so / sc;
    println!("normalised gamma = {gamma_norm:.5} (paper gamma {gamma})");
    for (state, g_l1, g_wd) in &per_view {
        let grads: Vec<Vec<f32>> = vec![
            g_l1.clone(),
            g_wd.iter().map(|w| gamma as f32 * w).collect(),
            g_l1.iter().map(|o| (gamma * beta) as f32 * o).collect(),
            g_wd.iter().zip(g_l1).map(|(w, o)| gamma as f32 * (w + beta as f32 * o)).collect(),
            g_wd.iter().zip(g_l1).map(|(w, o)| gamma_norm as f32 * (w + beta as f32 * o)).collect(),
        ];
        for (k, g) in grads.iter().enumerate() {
            image_norms[k] += norm(g) / views.len() as f64;
            let b = gscodec::raster::backward(&scene, state, g);
            for (j, (_, n)) in group_norms(&b.params).into_iter().enumerate() {
                param_norms[k][j] += n / views.len() as f64;
            }
            let drawn: Vec<f64> = b.mean2d_ndc_norm.iter().filter(|x| **x > 0.0).map(|x| *x as f64).collect();
            densify_frac[k] += drawn.iter().filter(|x| **x > threshold).count() as f64 / drawn.len().max(1) as f64 / views.len() as f64;
            mean2d[k] += drawn.iter().sum::<f64>() / drawn.len().max(1) as f64 / views.len() as f64;
        }
    }
    // Rate term at λ on this scene, with the steps the encoder starts training from.
    let cfg_e = EncodeConfig::for_lambda(lambda);
    let mut term = RateTerm::new(lambda, cfg_e.steps, cfg_e.min_opacity);
    let mut rg = scene.clone();
    for grp in Group::ALL {
        group::values_mut(&mut rg, grp).iter_mut().for_each(|x| *x = 0.0);
    }
    let rate = term.rate_and_grad(&scene, &mut rg, 1);
    println!("rate term at lambda {}: w*R = {rate:.4e} ({:.0} bits)", lambda.get(), term.last_bits);
    print!("{:<26} {:>10}", "per-view mean norms", "image");
    for g in Group::ALL {
        print!(" {:>10}", format!("{g:?}"));
    }
    println!(" {:>10} {:>9}", "mean2d", ">thresh");
    for (k, n) in names.iter().enumerate() {
        print!("{n:<26} {:>10.3e}", image_norms[k]);
        for j in 0..Group::ALL.len() {
            print!(" {:>10.3e}", param_norms[k][j]);
        }
        println!(" {:>10.3e} {:>8.1}%", mean2d[k], 100.0 * densify_frac[k]);
    }
    print!("{:<26} {:>10}", format!("rate (lambda {})", lambda.get()), "-");
    for (_, n) in group_norms(&rg) {
        print!(" {n:>10.3e}");
    }
    println!();
}

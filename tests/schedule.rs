//! The training schedule scaled to short runs: no collapse at 300 iterations on a scene with a
//! background, the reference values at 30k, and the pruning floor.

use gscodec::io::Dataset;
use gscodec::loss::L1Ssim;
use gscodec::rng::Rng;
use gscodec::testkit::{random_splats, rig_cameras};
use gscodec::train::adam::Adam;
use gscodec::train::densify::{densify_and_prune_keeping, DensifyParams, DensifyStats};
use gscodec::train::targets::render_targets;
use gscodec::train::{train, Schedule, TrainConfig, MIN_OPACITY_RESET_EVERY};
use gscodec_decoder::Splats;

#[test]
fn schedule_is_the_reference_at_30k_and_keeps_floors_when_short() {
    let s = Schedule::for_iters(30_000);
    assert_eq!((s.sh_up_every, s.densify_from, s.densify_until, s.densify_every, s.opacity_reset_every), (1000, 500, 15_000, 100, 3000));
    let s = Schedule::for_iters(5000);
    assert_eq!((s.densify_every, s.opacity_reset_every, s.densify_until), (50, MIN_OPACITY_RESET_EVERY, 2500));
    assert!(s.resets_opacity(1000, false) && s.resets_opacity(2000, false) && !s.resets_opacity(3000, false));
    for iters in [1, 10, 300, 1000, 1999] {
        let s = Schedule::for_iters(iters);
        assert_eq!(s.opacity_reset_every, usize::MAX, "{iters} iterations: no room for an opacity reset");
        assert!((1..=iters).all(|it| !s.resets_opacity(it, false) && !s.prunes_screen_size(it)));
        assert!(s.densify_every >= 50.min(iters));
        let json = serde_json::to_value(s).unwrap();
        assert!(json["opacity_reset_every"].is_null());
    }
    // White backgrounds keep the reference's extra reset at densify_from.
    assert!(Schedule::for_iters(300).resets_opacity(5, true));
}

/// An object in front of a textured shell that fills every view (a "photo" background).
fn scene_with_background() -> Splats {
    let mut s = random_splats(150, 1, 8);
    let mut rng = Rng::new(9);
    let rest = vec![0.0; s.rest_coeffs() * 3];
    for _ in 0..600 {
        let d = glam::Vec3::new(rng.normal(), rng.normal(), rng.normal()).normalize_or(glam::Vec3::Z) * 7.0;
        let c = [rng.uniform() - 0.5, rng.uniform() - 0.5, 0.3 * rng.normal()];
        s.push(d.to_array(), [-0.2; 3], [1.0, 0.0, 0.0, 0.0], 4.0, c.map(|v| v / 0.282_094_8), &rest);
    }
    s
}

#[test]
fn three_hundred_iterations_on_a_scene_with_a_background_do_not_collapse() {
    let cams = rig_cameras(16, 3.5, 48, 48);
    let ds: Dataset = render_targets(&scene_with_background(), &cams, [0.0; 3]);
    let cfg = TrainConfig { iters: 300, seed: 1, init_points: 2000, eval_interval: 100, ..Default::default() };
    let (s, report) = train(&ds, None, &cfg, Box::new(L1Ssim::default()), None, &mut |_| {}).unwrap();
    let peak = report.points.iter().map(|p| p.gaussians).max().unwrap();
    let psnr: Vec<f64> = report.points.iter().filter_map(|p| p.test_psnr).collect();
    eprintln!("300 iterations: peak {peak}, final {} Gaussians, held-out PSNR {psnr:?}", s.len());
    assert!(s.len() * 10 >= peak, "ended with {} of a peak {peak} Gaussians", s.len());
    assert!(report.test_psnr.unwrap() > 15.0, "held-out PSNR {:?}", report.test_psnr);
}

#[test]
fn pruning_keeps_the_most_opaque_down_to_the_floor() {
    let mut p = Splats::new(0);
    for i in 0..10 {
        // All below the 0.005 opacity threshold; Gaussian i has logit -10 + i·0.1.
        p.push([i as f32, 0.0, 0.0], [-3.0; 3], [1.0, 0.0, 0.0, 0.0], -10.0 + i as f32 * 0.1, [0.0; 3], &[]);
    }
    let dp = DensifyParams {
        grad_threshold: 1.0,
        percent_dense: 0.01,
        extent: 1.0,
        min_opacity: 0.005,
        max_screen_radius: None,
        max_world_fraction: 0.1,
        max_gaussians: 100,
    };
    let (mut a, mut b) = (p.clone(), p.clone());
    let (mut adam_a, mut adam_b) = (Adam::new(&a), Adam::new(&b));
    let stats = DensifyStats::new(10);
    let (_, _, pruned) = densify_and_prune_keeping(&mut a, &mut adam_a, &stats, &dp, &mut Rng::new(0), 0);
    assert_eq!((pruned, a.len()), (10, 0));
    let (_, _, pruned) = densify_and_prune_keeping(&mut b, &mut adam_b, &stats, &dp, &mut Rng::new(0), 3);
    assert_eq!((pruned, b.len(), adam_b.m.len()), (7, 3, 3));
    assert_eq!(b.positions.iter().map(|q| q[0]).collect::<Vec<_>>(), [7.0, 8.0, 9.0]);
}

/// `max_gaussians` (`encode --max-gaussians`): when the budget is short, the Gaussians with the
/// largest gradients grow first, and a split (two halves in place of one) counts as one more.
#[test]
fn densification_stops_at_the_budget_largest_gradients_first() {
    let mut p = Splats::new(0);
    for i in 0..10 {
        // Gaussian 9 is large (split), the others small (cloned); all opaque.
        let log_scale = if i == 9 { -1.0 } else { -5.0 };
        p.push([i as f32, 0.0, 0.0], [log_scale; 3], [1.0, 0.0, 0.0, 0.0], 0.0, [0.0; 3], &[]);
    }
    let mut stats = DensifyStats::new(10);
    for i in 0..10 {
        (stats.grad_accum[i], stats.count[i]) = ((i + 1) as f32, 1);
    }
    let dp = DensifyParams {
        grad_threshold: 0.5,
        percent_dense: 0.01,
        extent: 1.0,
        min_opacity: 0.005,
        max_screen_radius: None,
        max_world_fraction: 0.1,
        max_gaussians: 13,
    };
    let mut adam = Adam::new(&p);
    let (cloned, split, pruned) = densify_and_prune_keeping(&mut p, &mut adam, &stats, &dp, &mut Rng::new(0), 0);
    assert_eq!((cloned, split, pruned, p.len(), adam.m.len()), (2, 1, 0, 13, 13));
    let xs: Vec<f32> = p.positions.iter().map(|q| q[0]).collect();
    assert_eq!(xs[..11], [0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 8.0, 7.0], "9 split, then 8 and 7 cloned");
    // Without room nothing grows; with room for all, every one does.
    let mut full = p.clone();
    let mut adam = Adam::new(&full);
    let stats = DensifyStats { grad_accum: vec![1.0; 13], count: vec![1; 13], max_radius: vec![0.0; 13] };
    assert_eq!(densify_and_prune_keeping(&mut full, &mut adam, &stats, &dp, &mut Rng::new(0), 0), (0, 0, 0));
    assert_eq!(full.len(), 13);
    let roomy = DensifyParams { max_gaussians: 100, ..dp };
    assert_eq!(densify_and_prune_keeping(&mut full, &mut adam, &stats, &roomy, &mut Rng::new(0), 0), (11, 2, 0));
    assert_eq!(full.len(), 13 + 11 + 2, "11 small cloned, the 2 large halves split again");
}

/// The learning rates: the reference's constants by default; with `anneal_to` every group but
/// the positions keeps its rate through the first half and falls log-linearly to that share of
/// it at the end, and the position rate is unchanged.
#[test]
fn learning_rates_anneal_over_the_second_half_when_asked() {
    use gscodec::rate::group::Group;
    use gscodec::train::{learning_rate, LR_OPACITY, LR_SH_REST};
    let plain = TrainConfig { iters: 400, ..TrainConfig::default() };
    let annealed = TrainConfig { anneal_to: 0.3, ..plain.clone() };
    let extent = 2.5;
    for it in [1, 100, 200, 300, 400] {
        assert_eq!(learning_rate(Group::Opacity, it, &plain, extent), LR_OPACITY, "constant at {it}");
        assert_eq!(learning_rate(Group::Position, it, &annealed, extent), learning_rate(Group::Position, it, &plain, extent));
    }
    let rel = |g: Group, it: usize| f64::from(learning_rate(g, it, &annealed, extent)) / f64::from(learning_rate(g, it, &plain, extent));
    for g in [Group::Scale, Group::Rotation, Group::Opacity, Group::ShDc, Group::Sh1, Group::Sh3] {
        assert_eq!(rel(g, 1), 1.0);
        assert_eq!(rel(g, 200), 1.0, "{g:?}: full rate until half way");
        assert!((rel(g, 300) - 0.3f64.sqrt()).abs() < 1e-6, "{g:?}: the geometric mean three quarters in");
        assert!((rel(g, 400) - 0.3).abs() < 1e-6, "{g:?}: the share at the end");
    }
    assert!((f64::from(learning_rate(Group::Sh2, 400, &annealed, extent)) - 0.3 * f64::from(LR_SH_REST)).abs() < 1e-9);
}

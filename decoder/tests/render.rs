//! CPU renderer: analytic cases and the f32 tile renderer against the f64 brute-force reference,
//! including the extreme Gaussians of DESIGN §8.

use glam::{Mat3, Vec3};
use gscodec_decoder::math::SH_C0;
use gscodec_decoder::render::{contributions, contributions_and_removal_errors, reference::render_f64, removal_errors, render};
use gscodec_decoder::testkit::{random_splats_in, SceneRanges};
use gscodec_decoder::{Camera, Image, RenderOptions, Splats};

/// Random scenes of the tests: centres in the unit ball, log-scales in [-4.0, −1.5].
const SCENE: SceneRanges = SceneRanges { extent: [1.0; 3], log_scale: [-4.0, -1.5], opacity: [-3.0, 4.0], sh_dc: 1.5, sh_rest: 0.3 };

fn front_camera(w: u32, h: u32) -> Camera {
    Camera::look_at(Vec3::new(0.3, -0.4, -3.5), Vec3::ZERO, Vec3::new(0.0, -1.0, 0.0), w, h, 0.9)
}

fn max_abs_diff(a: &Image, b: &Image) -> f32 {
    a.data.iter().zip(&b.data).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max)
}

fn mean_abs_diff(a: &Image, b: &Image) -> f32 {
    a.data.iter().zip(&b.data).map(|(x, y)| (x - y).abs()).sum::<f32>() / a.data.len() as f32
}

#[test]
fn unit_gaussian_head_on_has_analytic_peak_and_width() {
    let mut s = Splats::new(0);
    let dc = 0.5 / SH_C0; // colour 1.0
    s.push([0.0; 3], [0.0; 3], [1.0, 0.0, 0.0, 0.0], 100.0, [dc; 3], &[]);
    let (f, z) = (32.0, 4.0);
    let cam = Camera::new(64, 64, f, f, Mat3::IDENTITY, Vec3::new(0.0, 0.0, z));
    let img = render(&s, &cam, &RenderOptions::default());
    // σ in pixels = f/z = 8; the dilation adds 0.3 px² to the variance. The mean projects to
    // (32, 32), the corner shared by pixels 31 and 32, so pixel (i, j) is at offset (i+0.5-32, j+0.5-32).
    let var = (f / z) * (f / z) + 0.3;
    for (i, j) in [(31u32, 31u32), (31, 35), (40, 31), (24, 44), (31, 20)] {
        let (dx, dy) = (i as f32 + 0.5 - 32.0, j as f32 + 0.5 - 32.0);
        let expect = 0.99f32.min((-0.5 * (dx * dx + dy * dy) / var).exp());
        let got = img.pixel(i, j)[1];
        assert!((got - expect).abs() < 2e-6, "pixel ({i},{j}): {got} vs analytic {expect}");
    }
}

#[test]
fn background_shows_through_by_transmittance() {
    let mut s = Splats::new(0);
    s.push([0.0; 3], [0.0; 3], [1.0, 0.0, 0.0, 0.0], 0.0, [0.0; 3], &[]); // opacity 0.5, colour 0.5
    let cam = Camera::new(32, 32, 16.0, 16.0, Mat3::IDENTITY, Vec3::new(0.0, 0.0, 4.0));
    let opts = RenderOptions { background: [1.0, 0.0, 0.25], ..Default::default() };
    let img = render(&s, &cam, &opts);
    let a = 0.5 * (-0.5f32 * 0.5 / (16.0 + 0.3)).exp();
    let p = img.pixel(15, 15);
    let expect = [0.5 * a + (1.0 - a), 0.5 * a, 0.5 * a + (1.0 - a) * 0.25];
    for c in 0..3 {
        assert!((p[c] - expect[c]).abs() < 1e-6, "{p:?} vs {expect:?}");
    }
    // Far corner: nothing but background.
    assert_eq!(img.pixel(0, 0), [1.0, 0.0, 0.25]);
}

#[test]
fn f32_matches_f64_reference_on_random_sh3_scene() {
    let s = random_splats_in(600, 3, 7, &SCENE);
    let cam = front_camera(80, 60);
    let opts = RenderOptions { background: [0.1, 0.2, 0.3], ..Default::default() };
    let (a, b) = (render(&s, &cam, &opts), render_f64(&s, &cam, &opts));
    // f32 rounding in projection and compositing is ~1e-6 relative; the discrete decisions
    // (alpha < 1/255, T < 1e-4) may flip for a contribution at the threshold, which changes a pixel
    // by at most ~alpha*T < 1/255. The mean error stays at rounding level.
    assert!(max_abs_diff(&a, &b) < 4e-3, "max {}", max_abs_diff(&a, &b));
    assert!(mean_abs_diff(&a, &b) < 2e-5, "mean {}", mean_abs_diff(&a, &b));
    assert!(a.data.iter().all(|v| v.is_finite()));
}

#[test]
fn max_sh_degree_option_ignores_higher_bands() {
    let s = random_splats_in(200, 3, 11, &SCENE);
    let cam = front_camera(48, 48);
    let low = RenderOptions { max_sh_degree: 1, ..Default::default() };
    let a = render(&s, &cam, &low);
    let b = render(&s.with_sh_degree(1), &cam, &RenderOptions::default());
    assert_eq!(a, b);
}

/// One Gaussian per extreme case of DESIGN §8, seen by `cam`.
fn extreme_scene() -> Splats {
    let mut s = Splats::new(1);
    let rest = [0.1f32; 9];
    let q = [1.0, 0.0, 0.0, 0.0];
    let cases: [([f32; 3], [f32; 3], [f32; 4], f32); 11] = [
        ([0.0, 0.0, 0.0], [-20.0; 3], q, 2.0),                              // sub-pixel
        ([0.2, 0.1, 0.5], [10.0; 3], q, -1.0),                              // view-filling, contains the camera
        ([0.3, -0.2, 0.0], [0.0, -20.0, -20.0], q, 3.0),                    // degenerate: a line
        ([-0.3, 0.2, 0.0], [-1.5, -1.5, -20.0], [0.3, 0.9, 0.1, 0.2], 3.0), // degenerate: a disc, tilted
        ([0.0, 0.0, -4.0], [-2.0; 3], q, 2.0),                              // at the camera centre
        ([0.0, 0.0, -3.995], [-2.0; 3], q, 2.0),                            // at the near plane
        ([0.0, 0.0, -6.0], [-2.0; 3], q, 2.0),                              // behind the camera
        ([0.1, 0.1, 0.2], [-2.0; 3], q, 100.0),                             // saturated opacity
        ([-0.1, 0.1, 0.2], [-2.0; 3], q, -100.0),                           // invisible
        ([9.0, 0.0, 0.0], [-1.0; 3], q, 2.0),                               // far outside the frustum (clamp)
        ([0.0, 0.0, 0.3], [-2.0; 3], [0.0, 0.0, 0.0, 0.0], 2.0),            // zero quaternion -> identity
    ];
    for (p, ls, r, o) in cases {
        s.push(p, ls, r, o, [0.4, -0.2, 0.1], &rest);
    }
    s
}

fn scaled(s: &Splats, k: f32) -> Splats {
    let mut out = s.clone();
    out.positions.iter_mut().for_each(|p| p.iter_mut().for_each(|v| *v *= k));
    out.log_scales.iter_mut().for_each(|l| l.iter_mut().for_each(|v| *v += k.ln()));
    out
}

#[test]
fn extreme_gaussians_render_finite_and_match_f64() {
    let s = extreme_scene();
    let base = Camera::new(64, 48, 40.0, 40.0, Mat3::IDENTITY, Vec3::new(0.0, 0.0, 4.0));
    let opts = RenderOptions { background: [0.0, 0.5, 1.0], ..Default::default() };
    for k in [1.0f32, 1e-4, 1e5] {
        let (scene, cam) = (scaled(&s, k), base.scaled(k));
        let a = render(&scene, &cam, &opts);
        let b = render_f64(&scene, &cam, &opts);
        assert!(a.data.iter().all(|v| v.is_finite()), "non-finite pixel at scale {k}");
        assert!(max_abs_diff(&a, &b) < 1e-4, "scale {k}: max diff {}", max_abs_diff(&a, &b));
        if k != 1.0 {
            // The same scene at another scale renders the same picture (up to f32 rounding).
            let c = render(&s, &base, &opts);
            assert!(max_abs_diff(&a, &c) < 4e-3, "scale {k} vs 1: {}", max_abs_diff(&a, &c));
        }
    }
}

#[test]
fn empty_scene_renders_background() {
    let cam = front_camera(20, 10);
    let img = render(&Splats::new(3), &cam, &RenderOptions { background: [0.2, 0.4, 0.6], ..Default::default() });
    assert_eq!(img, Image::filled(20, 10, [0.2, 0.4, 0.6]));
}

#[test]
fn render_is_deterministic_across_thread_counts() {
    let s = random_splats_in(2000, 2, 3, &SCENE);
    let cam = front_camera(96, 96);
    let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    let four = rayon::ThreadPoolBuilder::new().num_threads(4).build().unwrap();
    let a = one.install(|| render(&s, &cam, &RenderOptions::default()));
    let b = four.install(|| render(&s, &cam, &RenderOptions::default()));
    assert_eq!(a, b);
}

/// Camera at z = −4 looking along +z (depth = z + 4).
fn axis_camera(w: u32, h: u32) -> Camera {
    Camera::new(w, h, 32.0, 32.0, Mat3::IDENTITY, Vec3::new(0.0, 0.0, 4.0))
}

#[test]
fn contributions_favour_the_front_of_two_opaque_gaussians() {
    let mut s = Splats::new(0);
    // Index 0 behind, index 1 in front (same size, opacity 0.99 at the centre): the back one shows
    // only through the front one's translucent skirt and its 1 % at the centre.
    s.push([0.0, 0.0, 1.0], [-1.0; 3], [1.0, 0.0, 0.0, 0.0], 8.0, [0.0; 3], &[]);
    s.push([0.0, 0.0, 0.0], [-1.0; 3], [1.0, 0.0, 0.0, 0.0], 8.0, [0.0; 3], &[]);
    let c = contributions(&s, &axis_camera(64, 64), &RenderOptions::default());
    assert_eq!(c.len(), 2);
    assert!(c[1] > 2.0 * c[0] && c[0] > 0.0, "front {} back {}", c[1], c[0]);
    // Alone, the back one covers more than behind the front one.
    let mut back = s.clone();
    back.retain_indices(|i| i == 0);
    let alone = contributions(&back, &axis_camera(64, 64), &RenderOptions::default());
    assert!(alone[0] > c[0], "alone {} behind {}", alone[0], c[0]);
}

#[test]
fn contributions_sum_to_the_covered_area() {
    // With black Gaussians (colour clamped to 0) on a white background, each pixel is T_final.
    let mut s = random_splats_in(1500, 0, 11, &SCENE);
    s.sh_dc.iter_mut().for_each(|c| *c = [-10.0; 3]);
    let cam = front_camera(80, 64);
    let opts = RenderOptions { background: [1.0; 3], max_sh_degree: 0 };
    let img = render(&s, &cam, &opts);
    let covered: f64 = img.data.iter().step_by(3).map(|&t| 1.0 - t as f64).sum();
    let c = contributions(&s, &cam, &opts);
    assert_eq!(c.len(), s.len());
    assert!(c.iter().all(|v| v.is_finite() && *v >= 0.0));
    let total: f64 = c.iter().map(|&v| v as f64).sum();
    assert!(covered > 500.0, "the scene covers too little of the frame to test: {covered}");
    assert!((total - covered).abs() < 1e-4 * covered, "Σ contributions {total} vs Σ (1 − T) {covered}");
    // Some Gaussians are hidden or under 1/255 everywhere, and score exactly 0.
    assert!(c.contains(&0.0));
}

#[test]
fn contributions_are_zero_outside_the_view() {
    let mut s = Splats::new(0);
    s.push([0.0; 3], [-1.0; 3], [1.0, 0.0, 0.0, 0.0], 2.0, [0.0; 3], &[]); // seen
    s.push([50.0, 0.0, 0.0], [-1.0; 3], [1.0, 0.0, 0.0, 0.0], 2.0, [0.0; 3], &[]); // off-screen
    s.push([0.0, 0.0, -6.0], [-1.0; 3], [1.0, 0.0, 0.0, 0.0], 2.0, [0.0; 3], &[]); // behind the camera
    s.push([0.3, 0.0, 0.0], [-1.0; 3], [1.0, 0.0, 0.0, 0.0], -9.0, [0.0; 3], &[]); // alpha < 1/255
    let c = contributions(&s, &axis_camera(64, 64), &RenderOptions::default());
    assert!(c[0] > 1.0, "{c:?}");
    assert_eq!(&c[1..], &[0.0; 3]);
    assert!(contributions(&Splats::new(3), &axis_camera(8, 8), &RenderOptions::default()).is_empty());
}

#[test]
fn contributions_are_deterministic_across_thread_counts() {
    let s = random_splats_in(2000, 1, 5, &SCENE);
    let cam = front_camera(96, 80);
    let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    let four = rayon::ThreadPoolBuilder::new().num_threads(4).build().unwrap();
    let a = one.install(|| contributions(&s, &cam, &RenderOptions::default()));
    let b = four.install(|| contributions(&s, &cam, &RenderOptions::default()));
    assert_eq!(a, b);
}

/// `removal_errors` is, per Gaussian, what removing it alone changes in the render: the sum over
/// the pixels of the squared colour difference (the background included in what shows through).
#[test]
fn removal_errors_are_what_removing_each_gaussian_changes() {
    let s = random_splats_in(40, 1, 3, &SCENE);
    let cam = front_camera(48, 40);
    let opts = RenderOptions { background: [0.2, 0.5, 0.8], max_sh_degree: 1 };
    let img = render(&s, &cam, &opts);
    let err = removal_errors(&s, &cam, &opts);
    assert_eq!(err.len(), s.len());
    let mut seen = 0;
    for i in 0..s.len() {
        let mut without = s.clone();
        without.retain_indices(|j| j != i);
        let other = render(&without, &cam, &opts);
        let want: f64 = img.data.iter().zip(&other.data).map(|(a, b)| ((a - b) as f64).powi(2)).sum();
        let got = err[i] as f64;
        assert!((got - want).abs() <= 1e-4 + 2e-3 * want, "Gaussian {i}: {got} against {want} re-rendered");
        seen += usize::from(want > 1e-2);
    }
    assert!(seen > 10, "only {seen} Gaussians change the image: the test sees too little");
}

/// A Gaussian in front of its own colour covers pixels but costs nothing to remove: coverage
/// (`contributions`) and removal error rank it differently.
#[test]
fn removal_costs_nothing_where_a_gaussian_matches_what_is_behind_it() {
    let mut s = Splats::new(0);
    let grey = (0.5 - 0.5) / SH_C0; // colour 0.5 after the +0.5 offset
    s.push([0.0; 3], [-1.0; 3], [1.0, 0.0, 0.0, 0.0], 2.0, [grey; 3], &[]);
    let cam = axis_camera(64, 64);
    let on_grey = RenderOptions { background: [0.5; 3], max_sh_degree: 0 };
    assert!(contributions(&s, &cam, &on_grey)[0] > 1.0);
    assert!(removal_errors(&s, &cam, &on_grey)[0] < 1e-9);
    let on_black = RenderOptions { background: [0.0; 3], max_sh_degree: 0 };
    assert!(removal_errors(&s, &cam, &on_black)[0] > 0.1);
}

/// The one-pass measure gives both values exactly: its weights are `contributions` (with or
/// without the SH bands: weights do not depend on colour) and its errors `removal_errors`.
#[test]
fn one_pass_gives_the_contributions_and_the_removal_errors() {
    let s = random_splats_in(300, 2, 9, &SCENE);
    let cam = front_camera(70, 52);
    let opts = RenderOptions { background: [0.1, 0.6, 0.3], max_sh_degree: 2 };
    let (weights, errors) = contributions_and_removal_errors(&s, &cam, &opts);
    assert_eq!(weights, contributions(&s, &cam, &opts));
    assert_eq!(weights, contributions(&s, &cam, &RenderOptions { max_sh_degree: 0, ..opts }));
    assert_eq!(errors, removal_errors(&s, &cam, &opts));
    assert!(weights.iter().filter(|&&w| w > 0.0).count() > 100);
    assert!(errors.iter().filter(|&&e| e > 0.0).count() > 100);
}

//! Cost at 200×200 of (1) one loss + gradient evaluation: the original 3DGS loss (`l1ssim`)
//! against WD-R in both feature spaces (VGG-16 with random weights of the real shapes), and
//! (2) one whole training iteration (forward, loss, backward, Adam; 10k Gaussians) with `l1ssim`
//! and with `wdr` (pyramid). Reference statistics are cached as in training.

use criterion::{criterion_group, criterion_main, Criterion};
use gscodec::decoder::Image;
use gscodec::loss::features::pyramid::Pyramid;
use gscodec::loss::features::vgg16::{Vgg16, VGG16_CHANNELS};
use gscodec::loss::wdr::{self, WdrLoss};
use gscodec::loss::ImageLoss;

/// A smooth, textured test image and a slightly different "rendering" of it.
fn images(w: u32, h: u32) -> (Image, Image) {
    let make = |phase: f32| {
        let mut data = Vec::with_capacity((3 * w * h) as usize);
        for y in 0..h {
            for x in 0..w {
                let (fx, fy) = (x as f32 / w as f32, y as f32 / h as f32);
                for c in 0..3 {
                    let v = 0.5 + 0.25 * (13.0 * fx + 7.0 * fy + c as f32 + phase).sin() + 0.15 * (61.0 * fx * fy + phase).cos();
                    data.push(v.clamp(0.0, 1.0));
                }
            }
        }
        Image { width: w, height: h, data }
    };
    (make(0.3), make(0.0))
}

fn bench(c: &mut Criterion) {
    gscodec::cli::keep_freed_memory(); // as the CLI runs
    let (rendered, target) = images(200, 200);
    let mut g = c.benchmark_group("loss_and_grad_200x200");
    g.sample_size(10);
    g.bench_function("l1ssim", |b| b.iter(|| wdr::l_orig(&rendered, &target)));
    // Iteration 1 (1-based) of a run without warm-up, so WD-R itself is timed.
    let mut pyr = WdrLoss::new(Box::new(Pyramid::LUMA), 0);
    pyr.loss_and_grad(&rendered, &target, 0, 1);
    g.bench_function("wdr_pyramid", |b| b.iter(|| pyr.loss_and_grad(&rendered, &target, 0, 1)));
    let mut colour = WdrLoss::new(Box::new(Pyramid::COLOUR), 0);
    colour.loss_and_grad(&rendered, &target, 0, 1);
    g.bench_function("wdr_pyramid_colour", |b| b.iter(|| colour.loss_and_grad(&rendered, &target, 0, 1)));
    let mut vgg = WdrLoss::new(Box::new(Vgg16::<f32>::random(&VGG16_CHANNELS, 1)), 0);
    vgg.loss_and_grad(&rendered, &target, 0, 1);
    g.bench_function("wdr_vgg16", |b| b.iter(|| vgg.loss_and_grad(&rendered, &target, 0, 1)));
    g.finish();
}

fn bench_iteration(c: &mut Criterion) {
    gscodec::cli::keep_freed_memory(); // as the CLI runs
    use gscodec::raster;
    use gscodec::rate::group::Group;
    use gscodec::testkit::{random_splats, rig_cameras};
    use gscodec::train::adam::Adam;
    use gscodec::train::targets::render_targets;
    use gscodec_decoder::RenderOptions;
    let n = 10_000;
    let shrink = (n as f32 / 120.0).cbrt().ln();
    let mut truth = random_splats(n, 1, 1).with_sh_degree(3);
    truth.log_scales.iter_mut().for_each(|l| *l = l.map(|v| v - shrink));
    let ds = render_targets(&truth, &rig_cameras(2, 4.0, 200, 200), [1.0; 3]);
    let opts = RenderOptions { background: [1.0; 3], max_sh_degree: 3 };
    let frame = &ds.frames[0];
    let mut group = c.benchmark_group("train_iteration_200x200_10k");
    group.sample_size(10);
    let losses: Vec<(&str, Box<dyn ImageLoss>)> = vec![
        ("l1ssim", Box::new(gscodec::loss::L1Ssim::default())),
        ("wdr_pyramid", Box::new(WdrLoss::new(Box::new(Pyramid::LUMA), 0))),
        ("wdr_pyramid_colour", Box::new(WdrLoss::new(Box::new(Pyramid::COLOUR), 0))),
    ];
    for (name, mut loss) in losses {
        let mut params = random_splats(n, 1, 2).with_sh_degree(3);
        params.log_scales.iter_mut().for_each(|l| *l = l.map(|v| v - shrink));
        let mut adam = Adam::new(&params);
        group.bench_function(name, |b| {
            b.iter(|| {
                let (img, st) = raster::forward(&params, &frame.camera, &opts);
                let (_, dl) = loss.loss_and_grad(&img, &frame.image.get().unwrap(), 0, 1);
                let g = raster::backward(&params, &st, &dl);
                adam.step(&mut params, &g.params, |grp| if grp == Group::Position { 1e-5 } else { 1e-4 });
            })
        });
    }
    group.finish();
}

criterion_group!(benches, bench, bench_iteration);
criterion_main!(benches);

//! Cost of one loss + gradient evaluation at 200×200: the original 3DGS loss (`l1ssim`) against
//! WD-R in both feature spaces (VGG-16 with random weights of the real shapes). The reference
//! statistics are cached as in training (one warm-up call per view).

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
    let (rendered, target) = images(200, 200);
    let mut g = c.benchmark_group("loss_and_grad_200x200");
    g.sample_size(10);
    g.bench_function("l1ssim", |b| b.iter(|| wdr::l_orig(&rendered, &target)));
    let mut pyr = WdrLoss::new(Box::new(Pyramid), 0);
    pyr.loss_and_grad(&rendered, &target, 0, 0);
    g.bench_function("wdr_pyramid", |b| b.iter(|| pyr.loss_and_grad(&rendered, &target, 0, 0)));
    let mut vgg = WdrLoss::new(Box::new(Vgg16::<f32>::random(&VGG16_CHANNELS, 1)), 0);
    vgg.loss_and_grad(&rendered, &target, 0, 0);
    g.bench_function("wdr_vgg16", |b| b.iter(|| vgg.loss_and_grad(&rendered, &target, 0, 0)));
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);

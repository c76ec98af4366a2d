//! Times the parts of one WD-R evaluation at 200×200 (`cargo run --release --example wd_profile`).

use std::time::Instant;

use gscodec::loss::features::pyramid::Pyramid;
use gscodec::loss::features::FeatureSpace;
use gscodec::loss::tensor::Tensor;
use gscodec::loss::wd::{self, Reference, Sigma};

fn main() {
    let (h, w) = (200, 200);
    let img = |p: f32| Tensor::<f32>::from_vec(3, h, w, (0..3 * h * w).map(|i| 0.5 + 0.3 * ((i as f32) * 0.37 + p).sin()).collect());
    let (a, b) = (img(0.0), img(0.5));
    let r = Reference::new(&Pyramid.features(&a), &Sigma::Constant(4.0), h, w);
    let n = 20;
    let t = Instant::now();
    for _ in 0..n {
        std::hint::black_box(Pyramid.extract(&b));
    }
    println!("pyramid extract: {:.2} ms", t.elapsed().as_secs_f64() * 1e3 / n as f64);
    let ex = Pyramid.extract(&b);
    let t = Instant::now();
    for _ in 0..n {
        std::hint::black_box(wd::distortion_and_grad(&r, &ex.arrays));
    }
    println!("wd value+grad: {:.2} ms", t.elapsed().as_secs_f64() * 1e3 / n as f64);
    let (_, grads) = wd::distortion_and_grad(&r, &ex.arrays);
    let t = Instant::now();
    for _ in 0..n {
        let ex = Pyramid.extract(&b);
        std::hint::black_box(ex.tape.backward(&grads));
    }
    println!("pyramid extract+backward: {:.2} ms", t.elapsed().as_secs_f64() * 1e3 / n as f64);
    let t = Instant::now();
    for _ in 0..n {
        std::hint::black_box(gscodec::loss::wdr::l_orig(
            &gscodec::decoder::Image { width: w as u32, height: h as u32, data: a.to_interleaved_f32() },
            &gscodec::decoder::Image { width: w as u32, height: h as u32, data: b.to_interleaved_f32() },
        ));
    }
    println!("l_orig: {:.2} ms", t.elapsed().as_secs_f64() * 1e3 / n as f64);
}

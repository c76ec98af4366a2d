//! Times the parts of one WD-R evaluation at 200×200, with freed memory kept as the CLI does:
//!
//! ```text
//! cargo run --release --example wd_profile [SIGMA] [PART]
//! ```
//!
//! SIGMA is WD's pooling scale (default 4); PART (`extract`, `wd`, `backward`, `lorig`) times
//! only that part, 400 times, for `perf record`.

use std::time::Instant;

use gscodec::loss::features::pyramid::Pyramid;
use gscodec::loss::features::FeatureSpace;
use gscodec::loss::tensor::Tensor;
use gscodec::loss::wd::{self, Reference, Sigma};

fn main() {
    gscodec::cli::keep_freed_memory();
    let args: Vec<String> = std::env::args().skip(1).collect();
    let sigma: f64 = args.first().map_or(4.0, |s| s.parse().expect("SIGMA is a number"));
    let only = args.get(1).map(String::as_str);
    let (h, w) = (200, 200);
    let img = |p: f32| Tensor::<f32>::from_vec(3, h, w, (0..3 * h * w).map(|i| 0.5 + 0.3 * ((i as f32) * 0.37 + p).sin()).collect());
    let (a, b) = (img(0.0), img(0.5));
    let r = Reference::new(&Pyramid::LUMA.features(&a), &Sigma::Constant(sigma), h, w);
    let ex = Pyramid::LUMA.extract(&b);
    let (_, grads) = wd::distortion_and_grad(&r, &ex.arrays);
    let to_image = |t: &Tensor<f32>| gscodec::decoder::Image { width: w as u32, height: h as u32, data: t.to_interleaved_f32() };
    let (ia, ib) = (to_image(&a), to_image(&b));
    let parts: [(&str, &dyn Fn()); 4] = [
        ("extract", &|| {
            std::hint::black_box(Pyramid::LUMA.extract(&b));
        }),
        ("wd", &|| {
            std::hint::black_box(wd::distortion_and_grad(&r, &ex.arrays));
        }),
        ("backward", &|| {
            std::hint::black_box(Pyramid::LUMA.extract(&b).tape.backward(&grads));
        }),
        ("lorig", &|| {
            std::hint::black_box(gscodec::loss::wdr::l_orig(&ia, &ib));
        }),
    ];
    let n = if only.is_some() { 400 } else { 40 };
    for (name, f) in parts {
        if only.is_some_and(|o| o != name) {
            continue;
        }
        f(); // warm the allocator
        let t = Instant::now();
        for _ in 0..n {
            f();
        }
        let label = if name == "backward" { "extract+backward" } else { name };
        println!("σ {sigma}: {label}: {:.2} ms", t.elapsed().as_secs_f64() * 1e3 / n as f64);
    }
}

//! Measures, on real views, how d_WD's gradient compares with β·L_orig's (the paper reports a
//! mean ratio ‖∇d_WD‖ / ‖∇(β·L_orig)‖ ≈ 1.6 during training) for a blurred "rendering" of each
//! view, in a feature space.
//!
//! `cargo run --release --example wd_calibrate -- ../shared/data/lego-200 [pyramid-colour|pyramid|vgg16=PATH]`

use gscodec::decoder::Image;
use gscodec::loss::features::FeatureSpec;
use gscodec::loss::tensor::Tensor;
use gscodec::loss::wdr::{self, WdDistortion};

fn load(path: &std::path::Path) -> Image {
    let img = image::open(path).expect("readable PNG").to_rgba32f();
    let (w, h) = img.dimensions();
    let mut data = Vec::with_capacity((3 * w * h) as usize);
    for p in img.pixels() {
        let a = p[3];
        for c in 0..3 {
            data.push(p[c] * a + (1.0 - a)); // white background
        }
    }
    Image { width: w, height: h, data }
}

fn blurred(img: &Image, times: usize) -> Image {
    let mut t = Tensor::<f32>::from_image(img);
    for _ in 0..times {
        t = t.blur();
    }
    let mut ones = Tensor::<f32>::from_vec(3, t.h, t.w, vec![1.0; t.data.len()]);
    for _ in 0..times {
        ones = ones.blur();
    }
    t.data.iter_mut().zip(&ones.data).for_each(|(v, o)| *v /= o);
    Image { width: img.width, height: img.height, data: t.to_interleaved_f32() }
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let dir = std::path::PathBuf::from(args.get(1).expect("usage: wd_calibrate DATA [FEATURES]"));
    let spec: FeatureSpec = args.get(2).map(|s| s.parse().unwrap()).unwrap_or_default();
    let mut d = WdDistortion::new(spec.build().unwrap());
    let norm = |g: &[f32]| g.iter().map(|v| (*v as f64).powi(2)).sum::<f64>().sqrt();
    for blur in [1, 3, 8] {
        let (mut ratios, mut values) = (Vec::new(), Vec::new());
        for i in (1..100).step_by(10) {
            let target = load(&dir.join(format!("train/r_{i}.png")));
            let render = blurred(&target, blur);
            let (v, gw) = d.value_and_grad(&render, &target, None);
            let (lo, go) = wdr::l_orig(&render, &target);
            ratios.push(norm(&gw) / (wdr::BETA * norm(&go)));
            values.push((v, wdr::BETA * lo));
        }
        let mean = ratios.iter().sum::<f64>() / ratios.len() as f64;
        let (v, o) = values.iter().fold((0.0, 0.0), |a, b| (a.0 + b.0, a.1 + b.1));
        println!(
            "{spec} blur x{blur}: mean |grad d_WD| / |grad beta*L_orig| = {mean:.3}; mean d_WD = {:.4}, beta*L_orig = {:.4}",
            v / ratios.len() as f64,
            o / ratios.len() as f64
        );
    }
}

//! Finite-difference checks of the L1, SSIM and L1+SSIM gradients, and SSIM reference values.
//!
//! SSIM and L1 are computed in f64 internally, so central differences with h = 1e-4 on f32 pixel
//! values are accurate to ~1e-9 relative; the analytic gradient is rounded to f32 at the end. The
//! tolerance `1e-4·max|g| + 1e-3·|g|` covers that rounding.

use gscodec::loss::ssim::{ssim, ssim_and_grad, ssim_map};
use gscodec::loss::{l1_and_grad, ImageLoss, L1Ssim};
use gscodec::rng::Rng;
use gscodec_decoder::Image;

fn image(w: u32, h: u32, seed: u64, smooth: bool) -> Image {
    let mut rng = Rng::new(seed);
    let data = (0..w * h * 3)
        .map(|i| {
            let (x, y) = (((i / 3) % w) as f64, ((i / 3) / w) as f64);
            let base = if smooth { 0.5 + 0.3 * (0.3 * x + 0.2 * y + i as f64 % 3.0).sin() } else { 0.0 };
            (base + 0.4 * rng.uniform_f64()).clamp(0.0, 1.0) as f32
        })
        .collect();
    Image { width: w, height: h, data }
}

fn fd_check(name: &str, f: impl Fn(&Image) -> f64, g: &[f32], a: &Image) {
    let h = 1e-3f32;
    let scale = g.iter().fold(0.0f32, |m, v| m.max(v.abs())) as f64;
    assert!(scale > 0.0);
    // Every 7th entry keeps it quick while touching borders, interior and all channels.
    for i in (0..a.data.len()).step_by(7) {
        let mut p = a.clone();
        p.data[i] += h;
        let fp = f(&p);
        p.data[i] -= 2.0 * h;
        let fm = f(&p);
        let d = (fp - fm) / (2.0 * h as f64);
        let err = (g[i] as f64 - d).abs();
        assert!(err <= 1e-4 * scale + 1e-3 * d.abs(), "{name}: entry {i}: analytic {} vs finite difference {d}", g[i]);
    }
}

#[test]
fn ssim_gradient_matches_finite_differences() {
    for (w, h, smooth) in [(23u32, 17u32, true), (12, 30, false), (5, 4, true)] {
        let a = image(w, h, 1, smooth);
        let b = image(w, h, 2, smooth);
        let (s, g) = ssim_and_grad(&a, &b);
        assert!((s - ssim(&a, &b)).abs() < 1e-12);
        fd_check("ssim", |x| ssim(x, &b), &g, &a);
    }
}

#[test]
fn ssim_of_constant_images_is_finite() {
    let a = Image::filled(20, 20, [0.5; 3]);
    let b = Image::filled(20, 20, [0.25; 3]);
    let (s, g) = ssim_and_grad(&a, &b);
    assert!(s.is_finite() && g.iter().all(|v| v.is_finite()));
    let (s2, _) = ssim_and_grad(&a, &a);
    assert!((s2 - 1.0).abs() < 1e-12);
}

/// Direct 2-D windowed SSIM (no separability) as an independent reference.
fn ssim_direct(x: &[f64], y: &[f64], w: usize, h: usize) -> f64 {
    let taps = gscodec::loss::ssim::gaussian_taps();
    let r = 5isize;
    let mut total = 0.0;
    for py in 0..h as isize {
        for px in 0..w as isize {
            let (mut mx, mut my, mut sxx, mut syy, mut sxy) = (0.0, 0.0, 0.0, 0.0, 0.0);
            for dy in -r..=r {
                for dx in -r..=r {
                    let (qx, qy) = (px + dx, py + dy);
                    if qx < 0 || qy < 0 || qx >= w as isize || qy >= h as isize {
                        continue;
                    }
                    let wt = taps[(dx + r) as usize] * taps[(dy + r) as usize];
                    let (a, b) = (x[qy as usize * w + qx as usize], y[qy as usize * w + qx as usize]);
                    mx += wt * a;
                    my += wt * b;
                    sxx += wt * a * a;
                    syy += wt * b * b;
                    sxy += wt * a * b;
                }
            }
            let (c1, c2) = (1e-4, 9e-4);
            total +=
                ((2.0 * mx * my + c1) * (2.0 * (sxy - mx * my) + c2)) / ((mx * mx + my * my + c1) * (sxx - mx * mx + syy - my * my + c2));
        }
    }
    total / (w * h) as f64
}

#[test]
fn separable_ssim_matches_direct_window() {
    let (w, h) = (19usize, 14usize);
    let a = image(w as u32, h as u32, 5, true);
    let b = image(w as u32, h as u32, 6, true);
    for c in 0..3 {
        let x: Vec<f64> = a.data.chunks_exact(3).map(|p| p[c] as f64).collect();
        let y: Vec<f64> = b.data.chunks_exact(3).map(|p| p[c] as f64).collect();
        let fast = ssim_map(&x, &y, w, h).iter().sum::<f64>() / (w * h) as f64;
        assert!((fast - ssim_direct(&x, &y, w, h)).abs() < 1e-12);
    }
}

#[test]
fn l1_and_combined_gradients() {
    let a = image(16, 11, 3, true);
    let b = image(16, 11, 4, true);
    let (l, g) = l1_and_grad(&a, &b);
    let manual: f64 = a.data.iter().zip(&b.data).map(|(x, y)| (x - y).abs() as f64).sum::<f64>() / a.data.len() as f64;
    assert!((l - manual).abs() < 1e-12);
    fd_check("l1", |x| l1_and_grad(x, &b).0, &g, &a);
    let mut loss = L1Ssim::default();
    let (v, g) = loss.loss_and_grad(&a, &b, 0, 0);
    assert!((v - (0.8 * l + 0.2 * (1.0 - ssim(&a, &b)))).abs() < 1e-12);
    fd_check("l1ssim", |x| L1Ssim::default().eval(x, &b).0, &g, &a);
    assert_eq!(loss.name(), "l1ssim");
}

//! Image metrics against analytic cases and independently computed references
//! (`scripts/metrics_reference.py`: a numpy port of pytorch_msssim cross-checked with scikit-image,
//! and NVIDIA's `flip-evaluator` package).

use gscodec::decoder::Image;
use gscodec::loss::ssim::{channel, luminance_cs_maps, ssim_map};
use gscodec::metrics::{flip, ms_ssim, psnr, ssim};

/// The analytic test images of `scripts/metrics_reference.py` (`pattern`).
fn pattern(w: u32, h: u32, shift: bool) -> Image {
    let mut data = Vec::with_capacity((w * h * 3) as usize);
    for y in 0..h {
        for x in 0..w {
            for c in 0..3 {
                let (xf, yf, cf) = (x as f64, y as f64, c as f64);
                let mut v = 0.5 + 0.4 * (0.09 * xf + 0.5 * cf).sin() * (0.07 * yf).cos();
                if shift {
                    let n = ((x * 73 + y * 151 + c * 37) % 101) as f64 / 101.0 - 0.5;
                    v += 0.1 * (0.31 * xf + 0.23 * yf + cf).sin() + 0.1 * n;
                }
                data.push(v.clamp(0.0, 1.0) as f32);
            }
        }
    }
    Image { width: w, height: h, data }
}

fn constant(w: u32, h: u32, v: f32) -> Image {
    Image { width: w, height: h, data: vec![v; (w * h * 3) as usize] }
}

#[test]
fn psnr_of_known_mse() {
    let a = constant(8, 8, 0.5);
    let b = constant(8, 8, 0.6);
    // MSE = 0.01 -> 20 dB
    assert!((psnr(&a, &b) - 20.0).abs() < 1e-5);
    assert_eq!(psnr(&a, &a), 100.0);
}

#[test]
fn luminance_cs_multiply_to_the_ssim_map() {
    let (a, b) = (pattern(40, 30, false), pattern(40, 30, true));
    let (x, y) = (channel(&a, 1), channel(&b, 1));
    let (l, cs) = luminance_cs_maps(&x, &y, 40, 30);
    for ((l, cs), s) in l.iter().zip(&cs).zip(ssim_map(&x, &y, 40, 30)) {
        assert!((l * cs - s).abs() < 1e-12);
    }
    assert!(ssim(&a, &b) < 0.9);
}

#[test]
fn ms_ssim_of_identical_images_is_one() {
    let a = pattern(192, 176, false);
    assert!((ms_ssim(&a, &a).unwrap() - 1.0).abs() < 1e-12);
}

#[test]
fn ms_ssim_of_constant_images_is_the_luminance_term() {
    // Constant images: σ = 0 so cs = C2/C2 = 1 at every scale; even sides keep them constant
    // through the pooling, so MS-SSIM = l^w5 with l = (2ab + C1)/(a² + b² + C1).
    let (a, b) = (0.3f32, 0.7f32);
    let v = ms_ssim(&constant(256, 176, a), &constant(256, 176, b)).unwrap();
    let (a, b) = (a as f64, b as f64);
    let l = (2.0 * a * b + 1e-4) / (a * a + b * b + 1e-4);
    assert!((v - l.powf(0.1333)).abs() < 1e-9, "{v} vs {}", l.powf(0.1333));
}

#[test]
fn ms_ssim_matches_the_pytorch_msssim_port() {
    // Reference values: scripts/metrics_reference.py (even sides; odd sides with padded pooling).
    for (w, h, want) in [(192, 176, 0.822706946732), (167, 181, 0.822550282052)] {
        let got = ms_ssim(&pattern(w, h, false), &pattern(w, h, true)).unwrap();
        assert!((got - want).abs() < 1e-7, "{w}x{h}: {got} vs {want}");
    }
}

#[test]
fn ms_ssim_refuses_images_too_small_for_five_scales() {
    let a = pattern(200, 160, false);
    let err = ms_ssim(&a, &a).unwrap_err();
    assert_eq!((err.width, err.height), (200, 160));
    assert!(err.to_string().contains("161"), "{err}");
    assert!(ms_ssim(&pattern(161, 161, false), &pattern(161, 161, true)).is_ok());
}

#[test]
fn flip_of_identical_images_is_zero() {
    let a = pattern(64, 48, false);
    assert_eq!(flip(&a, &a), 0.0);
}

#[test]
fn flip_matches_nvidia_flip_evaluator() {
    // Reference values: NVIDIA's flip-evaluator 1.7 (LDR, 67 ppd) via scripts/metrics_reference.py.
    // nv-flip vendors an older FLIP C++ release; the means agree to 2e-5 (relative 6e-5).
    for (w, h, want) in [(192, 176, 0.354040027), (167, 181, 0.353574336)] {
        let got = flip(&pattern(w, h, false), &pattern(w, h, true));
        assert!((got - want).abs() < 1e-4, "{w}x{h}: {got} vs {want}");
    }
}

#[test]
fn flip_grows_with_the_distortion() {
    let a = pattern(64, 64, false);
    let small = Image { data: a.data.iter().map(|v| (v + 0.02).min(1.0)).collect(), ..a.clone() };
    let large = Image { data: a.data.iter().map(|v| (v + 0.2).min(1.0)).collect(), ..a.clone() };
    let (fs, fl) = (flip(&a, &small), flip(&a, &large));
    assert!(0.0 < fs && fs < fl && fl <= 1.0, "{fs} {fl}");
}

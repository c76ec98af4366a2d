//! WD: invariants, the texture property, an independent naive implementation, f64
//! finite-difference gradient checks (raw arrays, pyramid, VGG-16 with random weights, WD-R),
//! stability on constant images, and cache exactness.

use gscodec::decoder::Image;
use gscodec::loss::features::pyramid::Pyramid;
use gscodec::loss::features::vgg16::{Vgg16, CONV_INDICES, VGG16_CHANNELS};
use gscodec::loss::features::FeatureSpace;
use gscodec::loss::tensor::{Real, Tensor};
use gscodec::loss::wd::{self, Plan, Reference, Sigma};
use gscodec::loss::wdr::{self, WdDistortion, WdrLoss};
use gscodec::loss::ImageLoss;
use gscodec::rng::Rng;

fn random_tensor<T: Real>(rng: &mut Rng, c: usize, h: usize, w: usize) -> Tensor<T> {
    Tensor::from_vec(c, h, w, (0..c * h * w).map(|_| T::c(f64::from(rng.normal()))).collect())
}

fn random_image<T: Real>(rng: &mut Rng, h: usize, w: usize) -> Tensor<T> {
    Tensor::from_vec(3, h, w, (0..3 * h * w).map(|_| T::c(0.1 + 0.8 * rng.uniform_f64())).collect())
}

fn to_image(t: &Tensor<f64>) -> Image {
    let n = t.h * t.w;
    let mut data = vec![0.0f32; 3 * n];
    for i in 0..n {
        for c in 0..3 {
            data[3 * i + c] = t.data[c * n + i] as f32;
        }
    }
    Image { width: t.w as u32, height: t.h as u32, data }
}

fn wd_of(space: &dyn FeatureSpace<f64>, a: &Tensor<f64>, b: &Tensor<f64>, sigma: &Sigma) -> f64 {
    let r = Reference::new(&space.features(a), sigma, a.h, a.w);
    wd::distortion(&r, &space.features(b))
}

// ---------------------------------------------------------------- naive reference formula

fn naive_blur(x: &[f64], h: usize, w: usize) -> Vec<f64> {
    let k = [0.25, 0.5, 0.25];
    let mut out = vec![0.0; h * w];
    for y in 0..h {
        for i in 0..w {
            let mut s = 0.0;
            for (a, ka) in k.iter().enumerate() {
                for (b, kb) in k.iter().enumerate() {
                    let (yy, xx) = (y as isize + a as isize - 1, i as isize + b as isize - 1);
                    if yy >= 0 && xx >= 0 && (yy as usize) < h && (xx as usize) < w {
                        s += ka * kb * x[yy as usize * w + xx as usize];
                    }
                }
            }
            out[y * w + i] = s;
        }
    }
    out
}

/// The [`Tensor`] blurs against [`naive_blur`] and the adjoints against the inner-product
/// identity ⟨A x, y⟩ = ⟨x, Aᵀ y⟩, on odd, even and one-sample sizes (the WD gradient tests
/// reach them only through whole level plans).
#[test]
fn tensor_blurs_match_their_definition_and_adjoints() {
    let mut rng = Rng::new(7);
    let dot = |a: &Tensor<f64>, b: &Tensor<f64>| -> f64 { a.data.iter().zip(&b.data).map(|(x, y)| x * y).sum() };
    for (h, w) in [(1usize, 1usize), (1, 6), (5, 1), (2, 3), (7, 8), (8, 7), (6, 6), (9, 11)] {
        let (h2, w2) = (h.div_ceil(2), w.div_ceil(2));
        let x = random_tensor::<f64>(&mut rng, 2, h, w);
        let b = x.blur();
        for c in 0..2 {
            let n = naive_blur(x.plane(c), h, w);
            assert!(b.plane(c).iter().zip(&n).all(|(a, b)| (a - b).abs() < 1e-14), "blur {h}×{w}");
        }
        // The fused blur + subsample computes the same sums as the two steps.
        assert_eq!(x.blur_subsample(), b.subsample(0, 0), "blur_subsample {h}×{w}");
        let (y, y2) = (random_tensor::<f64>(&mut rng, 2, h, w), random_tensor::<f64>(&mut rng, 2, h2, w2));
        let close = |a: f64, b: f64, what: &str| assert!((a - b).abs() < 1e-12, "{what} {h}×{w}: {a} vs {b}");
        close(dot(&x.blur(), &y), dot(&x, &y.blur()), "blur");
        close(dot(&x.blur_subsample(), &y2), dot(&x, &y2.blur_subsample_adjoint(h, w)), "blur_subsample");
        close(dot(&x.subsample(0, 0), &y2), dot(&x, &y2.subsample_adjoint(h, w, 0, 0)), "subsample");
        close(dot(&x.lowpass2(), &y2), dot(&x, &y2.lowpass2_adjoint(h, w)), "lowpass2");
    }
}

fn naive_sub(x: &[f64], h: usize, w: usize, oy: usize, ox: usize) -> (Vec<f64>, usize, usize) {
    let (h2, w2) = (h.div_ceil(2), w.div_ceil(2));
    let mut o = vec![0.0; h2 * w2];
    for j in 0..h2 {
        for i in 0..w2 {
            o[j * w2 + i] = x[(oy + 2 * j) * w + ox + 2 * i];
        }
    }
    (o, h2, w2)
}

/// Every level computed, weights applied afterwards: the reference's formula without shortcuts.
fn naive_wd(a: &Tensor<f64>, b: &Tensor<f64>, ls: &[f64]) -> f64 {
    let (c, h0, w0) = (a.c, a.h, a.w);
    let mut ls = ls.to_vec();
    let (mut lh, mut lw) = (h0, w0);
    let mut total = 0.0;
    // level 0
    let wt = |l: f64, i: usize| (1.0 - (l - i as f64).abs()).max(0.0);
    let mut s0 = 0.0;
    for ch in 0..c {
        for p in 0..h0 * w0 {
            let d = a.data[ch * h0 * w0 + p] - b.data[ch * h0 * w0 + p];
            s0 += wt(ls[p], 0) * d * d;
        }
    }
    total += s0 / (c * h0 * w0) as f64;
    let mut xs: Vec<Vec<f64>> = (0..c).map(|ch| a.plane(ch).to_vec()).collect();
    let mut ys: Vec<Vec<f64>> = (0..c).map(|ch| b.plane(ch).to_vec()).collect();
    let mut qx: Vec<Vec<f64>> = xs.iter().map(|p| p.iter().map(|v| v * v).collect()).collect();
    let mut qy: Vec<Vec<f64>> = ys.iter().map(|p| p.iter().map(|v| v * v).collect()).collect();
    let (mut h, mut w) = (h0, w0);
    for k in 1..=5 {
        let mut s = 0.0;
        for ch in 0..c {
            let (mx, px) = (naive_blur(&xs[ch], h, w), naive_blur(&qx[ch], h, w));
            let (my, py) = (naive_blur(&ys[ch], h, w), naive_blur(&qy[ch], h, w));
            for p in 0..h * w {
                let sx = (px[p] - mx[p] * mx[p]).max(0.0).sqrt();
                let sy = (py[p] - my[p] * my[p]).max(0.0).sqrt();
                s += wt(ls[p], k) * ((mx[p] - my[p]).powi(2) + (sx - sy).powi(2));
            }
            xs[ch] = naive_sub(&mx, h, w, 0, 0).0;
            qx[ch] = naive_sub(&px, h, w, 0, 0).0;
            ys[ch] = naive_sub(&my, h, w, 0, 0).0;
            qy[ch] = naive_sub(&py, h, w, 0, 0).0;
        }
        total += s / (c * h * w) as f64;
        if k >= 1 {
            // stride-2 "SAME" low-pass of ℓ: centred on odd samples for even sizes.
            let (oy, ox) = (if lh % 2 == 0 { 1 } else { 0 }, if lw % 2 == 0 { 1 } else { 0 });
            let (n, nh, nw) = naive_sub(&naive_blur(&ls, lh, lw), lh, lw, oy, ox);
            ls = n;
            lh = nh;
            lw = nw;
        }
        h = h.div_ceil(2);
        w = w.div_ceil(2);
    }
    total
}

#[test]
fn matches_naive_formula_with_all_levels_computed() {
    let mut rng = Rng::new(7);
    for &(c, h, w) in &[(2, 16, 16), (3, 13, 10), (1, 9, 24)] {
        let a = random_tensor::<f64>(&mut rng, c, h, w);
        let b = random_tensor::<f64>(&mut rng, c, h, w);
        for sigma in [4.0f64, 2.0, 2.5, 1.0, 5.7, 32.0] {
            let ls = vec![sigma.log2(); h * w];
            let got = wd::wd(std::slice::from_ref(&a), std::slice::from_ref(&b), &Sigma::Constant(sigma), h, w);
            let want = naive_wd(&a, &b, &ls);
            assert!((got - want).abs() <= 1e-12 * want.abs().max(1.0), "σ={sigma} {c}x{h}x{w}: {got} vs {want}");
        }
        // a per-pixel σ map at the array's own resolution (no resize involved)
        let sig: Vec<f64> = (0..h * w).map(|_| 2f64.powf(4.0 * rng.uniform_f64())).collect();
        let got = wd::wd(std::slice::from_ref(&a), std::slice::from_ref(&b), &Sigma::map(h, w, &sig), h, w);
        let want = naive_wd(&a, &b, &sig.iter().map(|s| s.log2()).collect::<Vec<_>>());
        assert!((got - want).abs() <= 1e-12 * want.abs().max(1.0), "σ map: {got} vs {want}");
    }
}

/// WD runs plane by plane over every array at once: the arrays' values and gradients do not
/// depend on which other arrays are in the list (an array without pixels included).
#[test]
fn arrays_are_independent_and_empty_arrays_add_nothing() {
    let mut rng = Rng::new(11);
    let shapes = [(3, 20, 17), (2, 0, 5), (4, 10, 9)];
    let a: Vec<Tensor<f64>> = shapes.iter().map(|&(c, h, w)| random_tensor(&mut rng, c, h, w)).collect();
    let b: Vec<Tensor<f64>> = shapes.iter().map(|&(c, h, w)| random_tensor(&mut rng, c, h, w)).collect();
    let sigma = Sigma::Constant(4.0);
    let (value, grads) = wd::distortion_and_grad(&Reference::new(&a, &sigma, 20, 17), &b);
    let mut sum = 0.0;
    for i in [0, 2] {
        let (v, g) = wd::distortion_and_grad(&Reference::new(&a[i..=i], &sigma, 20, 17), &b[i..=i]);
        assert_eq!(g[0], grads[i], "array {i}'s gradient");
        sum += v;
    }
    assert!(grads[1].data.is_empty());
    assert!((value - sum).abs() <= 1e-14 * sum, "{value} vs {sum}");
    assert_eq!(wd::distortion(&Reference::new(&a, &sigma, 20, 17), &b), value);
}

#[test]
fn downscaled_arrays_get_smaller_sigma_and_zero_levels_are_skipped() {
    // On a 64×64 image, ℓ = log2 σ less each array's log2 downscale factor, relu'd. σ = 4: the
    // full-resolution arrays use level 2 only, a ½ array level 1, a ¼ and an ⅛ array level 0;
    // σ = 2: the full-resolution arrays level 1, every smaller array level 0. 5 of 30 levels.
    let expected = [(4.0, [2, 2, 1, 0, 0]), (2.0, [1, 1, 0, 0, 0])];
    let mut rng = Rng::new(3);
    let img = random_image::<f64>(&mut rng, 64, 64);
    let feats = Pyramid::LUMA.features(&img);
    let other = random_image::<f64>(&mut rng, 64, 64);
    let fo = Pyramid::LUMA.features(&other);
    for (sigma, want_levels) in expected {
        let r = Reference::new(&feats, &Sigma::Constant(sigma), 64, 64);
        assert_eq!(feats.len(), 5);
        assert_eq!(r.active_levels(), 5);
        let levels: Vec<Vec<usize>> = r.arrays.iter().map(|a| (0..=5).filter(|&i| a.plan.weights[i].is_some()).collect()).collect();
        assert_eq!(levels, want_levels.map(|l| vec![l]).to_vec(), "σ = {sigma}");
        // The skipped computation equals the full naive one with the reduced ℓ per array.
        let got = wd::distortion(&r, &fo);
        let want: f64 = feats
            .iter()
            .zip(&fo)
            .map(|(a, b)| {
                let l = (sigma.log2() - (64.0 / a.h as f64).log2()).max(0.0);
                naive_wd(a, b, &vec![l; a.h * a.w])
            })
            .sum();
        assert!((got - want).abs() <= 1e-12 * want, "σ = {sigma}: {got} vs {want}");
    }
}

#[test]
fn level_weights_follow_the_design_formula() {
    // w_i = relu(1 − |ℓ_i − i|), ℓ_0 = ℓ_1 = ℓ, ℓ_{i+1} = lowpass2(ℓ_i) (zero padding attenuates
    // the border). Uniform σ on a 12×10 array of a 12×10 image, by hand:
    // σ = 2 (ℓ = 1): w_1 = 1 everywhere (ℓ_1 is not low-passed), every other level 0;
    // σ = 4 (ℓ = 2): w_2 = relu(1 − |ℓ_2 − 2|) with ℓ_2 = 2·(the low-pass of 1), sampled on the
    //   odd rows and columns ("SAME" for even sizes), so only the last row and column touch the
    //   padding: 1 inside and at (0, 0), ¾·2 − 1 = ½ on the last column, (¾)²·2 − 1 = ⅛ in the
    //   last corner; w_1 = w_3 = 0;
    // σ = 2√2 (ℓ = 1.5): w_1 = ½ everywhere, w_2 = relu(1 − |ℓ_2 − 2|): ½ inside, ⅛ on the last column.
    let (h, w) = (12, 10);
    let weights = |sigma: f64| Plan::<f64>::new(&Sigma::Constant(sigma), h, w, h, w).weights;
    let at = |t: &Option<Tensor<f64>>, y: usize, x: usize| t.as_ref().map_or(0.0, |t| t.data[y * t.w + x]);
    let p2 = weights(2.0);
    assert!(p2[1].as_ref().unwrap().data.iter().all(|&v| v == 1.0));
    assert_eq!(p2.iter().enumerate().filter(|(i, t)| *i != 1 && t.is_some()).count(), 0, "σ = 2 weights level 1 only");
    let p4 = weights(4.0);
    assert!(p4[0].is_none() && p4[1].is_none() && p4[3].is_none());
    let w2 = &p4[2];
    let (lh, lw) = (w2.as_ref().unwrap().h, w2.as_ref().unwrap().w);
    assert_eq!((lh, lw), (6, 5), "level 2 lives at the resolution of x_1");
    for ((y, x), want) in [((2, 2), 1.0), ((0, 0), 1.0), ((2, 4), 0.5), ((5, 2), 0.5), ((5, 4), 0.125)] {
        assert!((at(w2, y, x) - want).abs() < 1e-12, "σ = 4, w_2 at ({y}, {x}): {} vs {want}", at(w2, y, x));
    }
    let p3 = weights(2.0 * 2f64.sqrt());
    assert!(p3[1].as_ref().unwrap().data.iter().all(|&v| (v - 0.5).abs() < 1e-12));
    for ((y, x), want) in [((2, 2), 0.5), ((2, 4), 0.125)] {
        assert!((at(&p3[2], y, x) - want).abs() < 1e-12, "σ = 2√2, w_2 at ({y}, {x}): {} vs {want}", at(&p3[2], y, x));
    }
}

#[test]
fn identity_nonnegativity_and_pointwise_limit() {
    let mut rng = Rng::new(11);
    let a = random_image::<f64>(&mut rng, 24, 20);
    let b = random_image::<f64>(&mut rng, 24, 20);
    for sigma in [Sigma::Constant(4.0), Sigma::Constant(1.5), Sigma::map(3, 2, &[1.0, 2.0, 4.0, 8.0, 3.0, 0.5])] {
        assert_eq!(wd_of(&Pyramid::LUMA, &a, &a, &sigma), 0.0);
        assert!(wd_of(&Pyramid::LUMA, &a, &b, &sigma) > 0.0);
    }
    for seed in 0..20 {
        let mut r = Rng::new(100 + seed);
        let x = random_tensor::<f64>(&mut r, 2, 7 + seed as usize % 5, 9);
        let y = random_tensor::<f64>(&mut r, 2, x.h, 9);
        assert!(wd::wd(std::slice::from_ref(&x), &[y], &Sigma::Constant(1.0 + r.uniform_f64() * 20.0), x.h, 9) >= 0.0);
    }
    // σ → 0: the pointwise mean squared feature difference, summed over arrays.
    let (fa, fb) = (Pyramid::LUMA.features(&a), Pyramid::LUMA.features(&b));
    let pointwise: f64 = fa
        .iter()
        .zip(&fb)
        .map(|(x, y)| x.data.iter().zip(&y.data).map(|(p, q)| (p - q) * (p - q)).sum::<f64>() / x.data.len() as f64)
        .sum();
    for tiny in [1e-6, 0.0] {
        let got = wd::distortion(&Reference::new(&fa, &Sigma::Constant(tiny), 24, 20), &fb);
        assert!((got - pointwise).abs() < 1e-12 * pointwise, "{got} vs {pointwise}");
    }
}

/// Stripes of period 4 (or a noise texture), its half-period shift, and its blurred copy.
fn textures(h: usize, w: usize, stripes: bool) -> (Tensor<f64>, Tensor<f64>, Tensor<f64>) {
    let mut rng = Rng::new(5);
    let mut rng2 = Rng::new(999);
    let period = 4.0;
    let make = |shift: f64, rng: &mut Rng| -> Tensor<f64> {
        let mut t = Tensor::zeros(3, h, w);
        for y in 0..h {
            for x in 0..w {
                let v = if stripes {
                    0.5 + 0.35 * (2.0 * std::f64::consts::PI * (x as f64 + shift) / period).sin().signum()
                } else {
                    0.5 + 0.15 * f64::from(rng.normal()).clamp(-2.5, 2.5)
                };
                for c in 0..3 {
                    t.data[c * h * w + y * w + x] = v * [1.0, 0.9, 0.7][c];
                }
            }
        }
        t
    };
    let a = make(0.0, &mut rng);
    let shifted = make(period / 2.0, &mut rng2);
    // Blurred copy: 5× the 3×3 binomial per channel.
    let mut blurred = a.clone();
    for _ in 0..5 {
        blurred = blurred.blur();
    }
    // undo the border darkening of zero padding so the copy only differs in sharpness
    let mut ones = Tensor::<f64>::from_vec(3, h, w, vec![1.0; 3 * h * w]);
    for _ in 0..5 {
        ones = ones.blur();
    }
    blurred.data.iter_mut().zip(&ones.data).for_each(|(v, o)| *v /= o);
    (a, shifted, blurred)
}

#[test]
fn texture_property_phase_shift_is_close_blur_is_far() {
    for stripes in [true, false] {
        let (a, shifted, blurred) = textures(48, 48, stripes);
        let mse = |x: &Tensor<f64>, y: &Tensor<f64>| {
            x.data.iter().zip(&y.data).map(|(p, q)| (p - q) * (p - q)).sum::<f64>() / x.data.len() as f64
        };
        let sigma = Sigma::Constant(4.0);
        let (l2_shift, l2_blur) = (mse(&a, &shifted), mse(&a, &blurred));
        let (wd_shift, wd_blur) = (wd_of(&Pyramid::LUMA, &a, &shifted, &sigma), wd_of(&Pyramid::LUMA, &a, &blurred, &sigma));
        // Pixel-wise, the shifted texture is the worse copy; WD ranks it the better one.
        assert!(l2_shift > 2.0 * l2_blur, "stripes={stripes}: L2 shift {l2_shift} blur {l2_blur}");
        assert!(wd_shift < 0.5 * wd_blur, "stripes={stripes}: WD shift {wd_shift} blur {wd_blur}");
        // And the shifted texture is far pointwise (σ → 0) but close under WD.
        let pointwise = wd_of(&Pyramid::LUMA, &a, &shifted, &Sigma::Constant(0.0));
        assert!(wd_shift < 0.25 * pointwise, "stripes={stripes}: WD {wd_shift} vs pointwise {pointwise}");
    }
}

// ---------------------------------------------------------------- gradients

/// Central differences of `f` at the given flat indices of `x` against `grad`.
fn check_grad(x: &Tensor<f64>, grad: &Tensor<f64>, idx: &[usize], eps: f64, tol: f64, f: &dyn Fn(&Tensor<f64>) -> f64) {
    let scale = grad.data.iter().map(|g| g.abs()).fold(0.0, f64::max);
    assert!(scale > 0.0, "zero gradient");
    for &i in idx {
        let (mut p, mut m) = (x.clone(), x.clone());
        p.data[i] += eps;
        m.data[i] -= eps;
        let fd = (f(&p) - f(&m)) / (2.0 * eps);
        let an = grad.data[i];
        assert!((fd - an).abs() <= tol * scale, "index {i}: finite difference {fd} vs analytic {an} (max |g| {scale})");
    }
}

fn some_indices(rng: &mut Rng, n: usize, k: usize) -> Vec<usize> {
    (0..k).map(|_| (rng.uniform_f64() * n as f64) as usize % n).collect()
}

#[test]
fn gradient_of_raw_wd_matches_finite_differences() {
    let mut rng = Rng::new(21);
    let sigmas = [
        Sigma::Constant(4.0),
        Sigma::Constant(2.0),
        Sigma::Constant(2.7),
        Sigma::Constant(1.0),
        Sigma::map(4, 3, &(0..12).map(|i| 1.0 + i as f64 * 1.3).collect::<Vec<_>>()),
    ];
    for (s, sigma) in sigmas.iter().enumerate() {
        let (c, h, w) = (2, 11 + s, 14);
        let refs = vec![random_tensor::<f64>(&mut rng, c, h, w), random_tensor::<f64>(&mut rng, 3, 6, 7)];
        let x = vec![random_tensor::<f64>(&mut rng, c, h, w), random_tensor::<f64>(&mut rng, 3, 6, 7)];
        let r = Reference::new(&refs, sigma, h, w);
        let (_, grads) = wd::distortion_and_grad(&r, &x);
        for a in 0..2 {
            let idx = some_indices(&mut rng, x[a].data.len(), 12);
            check_grad(&x[a], &grads[a], &idx, 1e-6, 1e-6, &|t| {
                let mut y = x.clone();
                y[a] = t.clone();
                wd::distortion(&r, &y)
            });
        }
    }
}

#[test]
fn gradient_through_pyramid_matches_finite_differences() {
    let mut rng = Rng::new(33);
    let (h, w) = (21, 18);
    let target = random_image::<f64>(&mut rng, h, w);
    let x = random_image::<f64>(&mut rng, h, w);
    for bank in [Pyramid::LUMA, Pyramid::COLOUR] {
        for sigma in [Sigma::Constant(4.0), Sigma::Constant(2.0)] {
            let r = Reference::new(&bank.features(&target), &sigma, h, w);
            let ex = bank.extract(&x);
            let (_, grads) = wd::distortion_and_grad(&r, &ex.arrays);
            let g = ex.tape.backward(&grads);
            let idx = some_indices(&mut rng, x.data.len(), 16);
            check_grad(&x, &g, &idx, 1e-6, 1e-6, &|t| wd::distortion(&r, &bank.features(t)));
        }
    }
}

/// `pyramid-colour` is `pyramid`'s arrays, bit for bit, then 16 oriented channels of each
/// opponent signal at the ½, ¼ and ⅛ stages: those of the red–green signal are zero on an image
/// whose normalised red and green channels are equal, and respond to an edge between two
/// colours of equal luminance, which `pyramid` cannot see.
#[test]
fn pyramid_colour_adds_opponent_signals_after_the_luminance() {
    let (h, w) = (32, 30);
    let mut rng = Rng::new(8);
    let img = random_image::<f64>(&mut rng, h, w);
    let (luma, colour) = (Pyramid::LUMA.features(&img), Pyramid::COLOUR.features(&img));
    assert_eq!(colour.len(), 5 + 6);
    for (a, b) in luma.iter().zip(&colour) {
        assert_eq!(a.data, b.data);
    }
    let shapes: Vec<(usize, usize, usize)> = colour[5..].iter().map(|t| (t.c, t.h, t.w)).collect();
    let stages = [(16, 16, 15), (16, 8, 8), (16, 4, 4)];
    assert_eq!(shapes, [stages, stages].concat());
    let name = |p: Pyramid| FeatureSpace::<f64>::name(&p);
    assert_eq!((name(Pyramid::LUMA), name(Pyramid::COLOUR)), ("pyramid", "pyramid-colour"));

    // Normalised red = green (sRGB g = m_g + s_g·(r − m_r)/s_r, to rounding): no red–green
    // response.
    let std = gscodec::loss::features::IMAGENET_STD;
    let mean = gscodec::loss::features::IMAGENET_MEAN;
    let mut equal = img.clone();
    let n = h * w;
    for i in 0..n {
        equal.data[n + i] = mean[1] + std[1] * (equal.data[i] - mean[0]) / std[0];
    }
    let f = Pyramid::COLOUR.features(&equal);
    assert!(f[5..8].iter().all(|t| t.data.iter().all(|&v| v < 1e-12)));
    assert!(f[8..].iter().any(|t| t.data.iter().any(|&v| v > 0.0)));

    // Left half one colour, right half another, at equal normalised luminance (the mean of the
    // normalised channels): the luminance bank sees a flat image, the colour bank an edge.
    let mut edge = Tensor::<f64>::zeros(3, h, w);
    let (left, right) = ([0.2, 0.0, -0.2], [-0.2, 0.0, 0.2]);
    for y in 0..h {
        for x in 0..w {
            let v = if x < w / 2 { left } else { right };
            for c in 0..3 {
                edge.data[c * n + y * w + x] = mean[c] + std[c] * v[c];
            }
        }
    }
    let f = Pyramid::COLOUR.features(&edge);
    let energy = |t: &Tensor<f64>| t.data.iter().map(|v| v * v).sum::<f64>();
    assert!(f[1..5].iter().all(|t| energy(t) < 1e-20), "{:?}", f[1..5].iter().map(energy).collect::<Vec<_>>());
    assert!(f[5..].iter().all(|t| energy(t) > 1e-3), "{:?}", f[5..].iter().map(energy).collect::<Vec<_>>());
}

/// A safetensors file of VGG-16 layout with the given output widths and random weights.
fn vgg_bytes(widths: &[usize; 13], seed: u64) -> Vec<u8> {
    let mut rng = Rng::new(seed);
    let mut bufs: Vec<(String, Vec<usize>, Vec<u8>)> = Vec::new();
    let mut cin = 3;
    for (l, &idx) in CONV_INDICES.iter().enumerate() {
        let cout = widths[l];
        let std = (2.0 / (cin * 9) as f64).sqrt();
        let wv: Vec<u8> = (0..cout * cin * 9).flat_map(|_| ((f64::from(rng.normal()) * std) as f32).to_le_bytes()).collect();
        let bv: Vec<u8> = (0..cout).flat_map(|_| ((f64::from(rng.normal()) * 0.05) as f32).to_le_bytes()).collect();
        bufs.push((format!("features.{idx}.weight"), vec![cout, cin, 3, 3], wv));
        bufs.push((format!("features.{idx}.bias"), vec![cout], bv));
        cin = cout;
    }
    let views: Vec<(String, safetensors::tensor::TensorView)> = bufs
        .iter()
        .map(|(n, s, d)| (n.clone(), safetensors::tensor::TensorView::new(safetensors::Dtype::F32, s.clone(), d).unwrap()))
        .collect();
    safetensors::serialize(views, None).unwrap()
}

const NARROW: [usize; 13] = [4, 4, 6, 6, 8, 8, 8, 8, 8, 8, 8, 8, 8];

#[test]
fn gradient_through_vgg16_matches_finite_differences() {
    let net = Vgg16::<f64>::from_safetensors(&vgg_bytes(&NARROW, 5)).unwrap();
    assert!(!net.is_full_size());
    let mut rng = Rng::new(44);
    let (h, w) = (34, 36);
    let target = random_image::<f64>(&mut rng, h, w);
    let x = random_image::<f64>(&mut rng, h, w);
    let sigma = Sigma::Constant(4.0);
    let ft = net.features(&target);
    // 1 + 5 (34×36) + 5 (17×18) + 4 (9×9: relu5_3 would be 0×0)
    assert_eq!(ft.len(), 15);
    let r = Reference::new(&ft, &sigma, h, w);
    let ex = net.extract(&x);
    let (_, grads) = wd::distortion_and_grad(&r, &ex.arrays);
    let g = ex.tape.backward(&grads);
    let idx = some_indices(&mut rng, x.data.len(), 10);
    check_grad(&x, &g, &idx, 1e-6, 1e-5, &|t| wd::distortion(&r, &net.features(t)));
}

#[test]
fn vgg16_full_shapes_load_from_file_and_give_16_arrays() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("vgg16.safetensors");
    std::fs::write(&path, vgg_bytes(&VGG16_CHANNELS, 9)).unwrap();
    let net = Vgg16::<f32>::load(&path).unwrap();
    assert!(net.is_full_size());
    let mut rng = Rng::new(1);
    let img = random_image::<f32>(&mut rng, 64, 64);
    let f = net.features(&img);
    let shapes: Vec<(usize, usize, usize)> = f.iter().map(|t| (t.c, t.h, t.w)).collect();
    let mut want = vec![(3, 64, 64)];
    for s in [64, 32, 16] {
        for (b, c) in [64, 128, 256, 512, 512].into_iter().enumerate() {
            want.push((c, s >> b, s >> b));
        }
    }
    assert_eq!(shapes, want);
    assert!(f.iter().all(|t| t.data.iter().all(|v| v.is_finite())));
    // bad files: one clear input error naming the file
    std::fs::write(&path, b"not safetensors").unwrap();
    let e = Vgg16::<f32>::load(&path).unwrap_err();
    assert_eq!(e.exit_code(), 2);
    assert!(e.to_string().contains("vgg16.safetensors"), "{e}");
    let mut narrow = NARROW;
    narrow[3] = 0;
    std::fs::write(&path, vgg_bytes(&narrow, 1)).unwrap();
    assert!(Vgg16::<f32>::load(&path).is_err());
}

#[test]
fn wdr_gradient_matches_finite_differences_and_composition() {
    let mut rng = Rng::new(55);
    let (h, w) = (20, 22);
    // keep |rendered − target| ≥ 0.05 so the L1 kink is never crossed
    let target = random_image::<f64>(&mut rng, h, w);
    let mut x = target.clone();
    x.data
        .iter_mut()
        .for_each(|v| *v += if rng.uniform_f64() < 0.5 { -0.05 - 0.04 * rng.uniform_f64() } else { 0.05 + 0.04 * rng.uniform_f64() });
    // make every value exactly representable in f32 so the f32 and f64 paths see the same image
    x.data.iter_mut().for_each(|v| *v = *v as f32 as f64);
    let target: Tensor<f64> = Tensor::from_vec(3, h, w, target.data.iter().map(|v| *v as f32 as f64).collect());

    // the default σ (4) and `--wd-sigma 2`
    for sigma in [None, Some(2.0)] {
        wdr_matches_its_formula(&mut rng, &x, &target, sigma);
    }
}

/// WD-R at σ (None: the default) against f64 finite differences of γ(d_WD + β L_orig) at `x`.
fn wdr_matches_its_formula(rng: &mut Rng, x: &Tensor<f64>, target: &Tensor<f64>, sigma: Option<f64>) {
    let (h, w) = (x.h, x.w);
    let (ti, xi) = (to_image(target), to_image(x));
    let total = 1000;
    let mut loss = WdrLoss::new(Box::new(Pyramid::LUMA), total).with_fixed_gamma(wdr::DEFAULT_GAMMA_WDR);
    if let Some(s) = sigma {
        loss = loss.with_sigma(Sigma::Constant(s));
    }
    assert_eq!(loss.warmup, 300, "three tenths of the run (wdr::WARMUP_FRACTION)");
    // warm-up: L_orig alone
    let (lw, gw) = loss.loss_and_grad(&xi, &ti, 0, 300);
    let (lo, go) = wdr::l_orig(&xi, &ti);
    assert_eq!((lw, &gw), (lo, &go));
    // after: γ(d_WD + β L_orig), checked against f64 finite differences of that formula
    let (l, g) = loss.loss_and_grad(&xi, &ti, 0, 301);
    let sigma = Sigma::Constant(sigma.unwrap_or(wd::DEFAULT_SIGMA));
    let r = Reference::new(&Pyramid::LUMA.features(target), &sigma, h, w);
    let f = |t: &Tensor<f64>| {
        let d = wd::distortion(&r, &Pyramid::LUMA.features(t));
        wdr::DEFAULT_GAMMA_WDR * (d + wdr::BETA * wdr::l_orig(&to_image(t), &ti).0)
    };
    assert!((l - f(x)).abs() < 1e-5 * l, "{sigma:?}: {l} vs {}", f(x));
    let gt = Tensor::<f64>::from_vec(3, h, w, {
        let n = h * w;
        let mut d = vec![0.0; 3 * n];
        for i in 0..n {
            for c in 0..3 {
                d[c * n + i] = g[3 * i + c] as f64;
            }
        }
        d
    });
    let idx = some_indices(rng, x.data.len(), 12);
    // eps 2^-10 keeps the perturbed values exact in f32
    check_grad(x, &gt, &idx, 1.0 / 1024.0, 2e-3, &f);
}

#[test]
fn wdr_normalised_gamma_matches_the_l1ssim_gradient_scale_then_freezes() {
    let mut rng = Rng::new(77);
    let (h, w) = (24, 20);
    let views: Vec<(Image, Image)> = (0..wdr::NORMALISE_VIEWS + 3)
        .map(|_| {
            let t = random_image::<f64>(&mut rng, h, w);
            let mut x = t.clone();
            x.data.iter_mut().for_each(|v| *v = (*v + 0.3 * (rng.uniform_f64() - 0.5)).clamp(0.0, 1.0));
            (to_image(&x), to_image(&t))
        })
        .collect();
    let l2 = |g: &[f32]| g.iter().map(|v| (*v as f64).powi(2)).sum::<f64>().sqrt();
    let mut loss = WdrLoss::new(Box::new(Pyramid::LUMA), 100);
    assert!(loss.normalise && !loss.gamma_settled());
    // warm-up iterations do not touch γ
    loss.loss_and_grad(&views[0].0, &views[0].1, 0, 0);
    assert_eq!(loss.gamma, wdr::DEFAULT_GAMMA_WDR);
    // first WD iteration: the gradient has exactly the norm of L_orig's (= L1-SSIM's)
    let (x, t) = &views[0];
    let (l, g) = loss.loss_and_grad(x, t, 0, loss.warmup + 1);
    let (lo, go) = wdr::l_orig(x, t);
    assert!((l2(&g) / l2(&go) - 1.0).abs() < 1e-5, "{} vs {}", l2(&g), l2(&go));
    let mut plain = WdDistortion::new(Box::new(Pyramid::LUMA));
    let (d, gd) = plain.value_and_grad(x, t, None);
    assert!((l - loss.gamma * (d + wdr::BETA * lo)).abs() < 1e-9 * l);
    // γ is the ratio of the summed norms over NORMALISE_VIEWS views, then frozen
    let (mut so, mut sc) = (l2(&go), l2(&gd.iter().zip(&go).map(|(a, b)| a + wdr::BETA as f32 * b).collect::<Vec<_>>()));
    for (i, (x, t)) in views.iter().enumerate().skip(1) {
        let before = loss.gamma;
        let settled = loss.gamma_settled();
        let (_, g) = loss.loss_and_grad(x, t, i, loss.warmup + 1 + i);
        let (_, go) = wdr::l_orig(x, t);
        let (_, gd) = plain.value_and_grad(x, t, None);
        let comb: Vec<f32> = gd.iter().zip(&go).map(|(a, b)| a + wdr::BETA as f32 * b).collect();
        if settled {
            assert_eq!(loss.gamma, before, "γ changed after {} views", wdr::NORMALISE_VIEWS);
        } else {
            so += l2(&go);
            sc += l2(&comb);
            assert!((loss.gamma - so / sc).abs() < 1e-6 * loss.gamma);
        }
        assert!((l2(&g) - loss.gamma * l2(&comb)).abs() < 1e-4 * l2(&g));
    }
    assert!(loss.gamma_settled());
    // a fixed γ is never changed
    let mut fixed = WdrLoss::new(Box::new(Pyramid::LUMA), 100).with_fixed_gamma(0.5);
    fixed.loss_and_grad(x, t, 0, 50);
    assert_eq!(fixed.gamma, 0.5);
}

#[test]
fn constant_images_and_flat_regions_give_finite_gradients() {
    let (h, w) = (24, 24);
    let flat = |v: f32| Image { width: w, height: h, data: vec![v; (3 * w * h) as usize] };
    let mut rng = Rng::new(66);
    let textured = to_image(&random_image::<f64>(&mut rng, h as usize, w as usize));
    let mut half = textured.clone();
    half.data[..(3 * w * h / 2) as usize].iter_mut().for_each(|v| *v = 0.3);
    let net = Vgg16::<f32>::from_safetensors(&vgg_bytes(&NARROW, 2)).unwrap();
    let spaces: Vec<Box<dyn FeatureSpace<f32>>> = vec![Box::new(Pyramid::LUMA), Box::new(Pyramid::COLOUR), Box::new(net)];
    for space in spaces {
        let mut d = WdDistortion::new(space);
        for (a, b) in [
            (flat(0.5), flat(0.5)),
            (flat(0.2), flat(0.7)),
            (flat(0.5), textured.clone()),
            (half.clone(), textured.clone()),
            (textured.clone(), half.clone()),
        ] {
            let (v, g) = d.value_and_grad(&a, &b, None);
            assert!(v.is_finite() && v >= 0.0);
            assert!(g.iter().all(|x| x.is_finite()), "non-finite gradient");
        }
        assert_eq!(d.value_and_grad(&flat(0.5), &flat(0.5), None).0, 0.0);
    }
}

#[test]
fn cached_equals_uncached_exactly() {
    let mut rng = Rng::new(77);
    let target = to_image(&random_image::<f64>(&mut rng, 30, 26));
    let other_target = to_image(&random_image::<f64>(&mut rng, 30, 26));
    let x = to_image(&random_image::<f64>(&mut rng, 30, 26));
    let net = Vgg16::<f32>::from_safetensors(&vgg_bytes(&NARROW, 3)).unwrap();
    let spaces: Vec<Box<dyn FeatureSpace<f32>>> = vec![Box::new(Pyramid::LUMA), Box::new(Pyramid::COLOUR), Box::new(net)];
    for space in spaces {
        let mut d = WdDistortion::new(space);
        let uncached = d.value_and_grad(&x, &target, None);
        assert_eq!(d.cached_views(), 0);
        let first = d.value_and_grad(&x, &target, Some(3));
        let second = d.value_and_grad(&x, &target, Some(3));
        assert_eq!(d.cached_views(), 1);
        for r in [&first, &second] {
            assert_eq!(r.0.to_bits(), uncached.0.to_bits());
            assert!(r.1.iter().zip(&uncached.1).all(|(a, b)| a.to_bits() == b.to_bits()));
        }
        // the same view id with a different target is recomputed, not served stale
        let fresh = d.value(&x, &other_target, None);
        assert_eq!(d.value(&x, &other_target, Some(3)), fresh);
        // and a zero budget disables caching
        let mut d = d.with_cache_budget(0);
        d.value(&x, &target, Some(1));
        assert_eq!(d.cached_views(), 0);
    }
}

#[test]
fn loss_options_parse_and_fail_cleanly() {
    use clap::Parser;
    use gscodec::loss::{build_loss, FeatureSpec, LossArgs, LossKind};
    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        loss: LossArgs,
    }
    let c = Cli::try_parse_from(["x", "--loss", "wdr", "--features", "vgg16=/nonexistent/w.safetensors"]).unwrap();
    assert_eq!(c.loss.loss, Some(LossKind::Wdr));
    assert_eq!(c.loss.features, FeatureSpec::Vgg16("/nonexistent/w.safetensors".into()));
    let e = build_loss(&c.loss, 100, LossKind::L1ssim).err().expect("missing weights file");
    assert_eq!(e.exit_code(), 2);
    assert!(e.to_string().contains("/nonexistent/w.safetensors"), "{e}");
    assert!(Cli::try_parse_from(["x", "--features", "alexnet"]).is_err());
    let c = Cli::try_parse_from(["x", "--features", "pyramid-colour"]).unwrap();
    assert_eq!(c.loss.features, FeatureSpec::PyramidColour);
    assert_eq!(c.loss.features.build().unwrap().name(), "pyramid-colour");
    assert!(Cli::try_parse_from(["x", "--features", "vgg16="]).is_err());
    assert!(Cli::try_parse_from(["x", "--loss", "lpips"]).is_err());
    let d = Cli::try_parse_from(["x"]).unwrap();
    assert_eq!((d.loss.loss, d.loss.features.clone()), (None, FeatureSpec::PyramidColour));
    assert_eq!(d.loss.features.build().unwrap().name(), "pyramid-colour");
    assert_eq!(build_loss(&d.loss, 10, LossKind::L1ssim).unwrap().name(), "l1ssim");
    assert_eq!(build_loss(&d.loss, 10, LossKind::Wdr).unwrap().name(), "wdr");
    let g = Cli::try_parse_from(["x", "--loss", "wd", "--wd-gamma=-1"]).unwrap();
    assert_eq!(build_loss(&g.loss, 10, LossKind::L1ssim).err().unwrap().exit_code(), 2);
    let ok = Cli::try_parse_from(["x", "--loss", "wd", "--wd-gamma", "0.5"]).unwrap();
    assert_eq!(build_loss(&ok.loss, 10, LossKind::L1ssim).unwrap().name(), "wd");
    // --wd-sigma: [1, 32] (ℓ in [0, NUM_LEVELS]); outside, or NaN, is bad input naming the bound
    for bad in ["0.5", "33", "NaN", "-4"] {
        let c = Cli::try_parse_from(["x", "--loss", "wdr", &format!("--wd-sigma={bad}")]).unwrap();
        let e = build_loss(&c.loss, 10, LossKind::L1ssim).err().expect("σ out of range");
        assert_eq!(e.exit_code(), 2);
        assert!(e.to_string().contains(&format!("--wd-sigma {bad}: must be in [1, 32]")), "{e}");
    }
    // the σ given is the σ trained with: `wd` at γ = 1 past its warm-up is d_WD at that σ (in
    // the default features)
    let mut rng = Rng::new(12);
    let (a, b) = (to_image(&random_image::<f64>(&mut rng, 24, 20)), to_image(&random_image::<f64>(&mut rng, 24, 20)));
    let d = |s: f64| WdDistortion::new(Box::new(Pyramid::COLOUR)).with_sigma(Sigma::Constant(s)).value(&a, &b, None);
    for (args, sigma) in
        [(vec!["x", "--loss", "wd", "--wd-gamma", "1", "--wd-sigma", "2"], 2.0), (vec!["x", "--loss", "wd", "--wd-gamma", "1"], 4.0)]
    {
        let c = Cli::try_parse_from(args).unwrap();
        let got = build_loss(&c.loss, 10, LossKind::L1ssim).unwrap().loss_and_grad(&a, &b, 0, 5).0;
        assert!((got - d(sigma)).abs() <= 1e-6 * got, "σ {sigma}: {got} vs {}", d(sigma));
    }
    assert!((d(2.0) - d(4.0)).abs() > 1e-3 * d(4.0), "σ changes the value");
    // --wd-warmup: [0, 1]; outside, or NaN, is bad input naming the range
    for bad in ["1.01", "-0.1", "NaN", "2"] {
        let c = Cli::try_parse_from(["x", "--loss", "wdr", &format!("--wd-warmup={bad}")]).unwrap();
        let e = build_loss(&c.loss, 10, LossKind::L1ssim).err().expect("warm-up out of range");
        assert_eq!(e.exit_code(), 2);
        assert!(e.to_string().contains(&format!("--wd-warmup {bad}: must be in [0, 1]")), "{e}");
    }
    // the share given is the warm-up trained with: over 100 iterations (numbered from 1), `wd`
    // is L_orig (the L1-SSIM loss) up to iteration 100·F and γ·d_WD after it; at 1, never WD
    let l_orig = build_loss(&Cli::try_parse_from(["x"]).unwrap().loss, 100, LossKind::L1ssim).unwrap().loss_and_grad(&a, &b, 0, 1).0;
    for (args, warmup) in [
        (vec!["x", "--loss", "wd", "--wd-gamma", "1", "--wd-warmup", "0.1"], 10),
        (vec!["x", "--loss", "wd", "--wd-gamma", "1", "--wd-warmup", "0"], 0),
        (vec!["x", "--loss", "wd", "--wd-gamma", "1"], 30),
        (vec!["x", "--loss", "wd", "--wd-gamma", "1", "--wd-warmup", "1"], 100),
    ] {
        let c = Cli::try_parse_from(args).unwrap();
        let mut loss = build_loss(&c.loss, 100, LossKind::L1ssim).unwrap();
        for it in (1..=warmup).filter(|&it| it == 1 || it == warmup) {
            assert_eq!(loss.loss_and_grad(&a, &b, 0, it).0, l_orig, "warm-up {warmup}, iteration {it}");
        }
        if warmup < 100 {
            let got = loss.loss_and_grad(&a, &b, 0, warmup + 1).0;
            assert!((got - d(4.0)).abs() <= 1e-6 * got, "warm-up {warmup}: {got} vs {}", d(4.0));
        }
    }
}

#[test]
fn sigma_maps_resize_like_the_reference() {
    // a constant map at any resolution is the constant σ
    let mut rng = Rng::new(88);
    let a = random_image::<f64>(&mut rng, 40, 30);
    let b = random_image::<f64>(&mut rng, 40, 30);
    let c = wd_of(&Pyramid::LUMA, &a, &b, &Sigma::Constant(4.0));
    for (h, w) in [(40, 30), (7, 5), (80, 61)] {
        let m = wd_of(&Pyramid::LUMA, &a, &b, &Sigma::map(h, w, &vec![4.0; h * w]));
        assert!((m - c).abs() < 1e-12 * c, "{h}x{w}: {m} vs {c}");
    }
    // linear, antialiased resize: halving averages pairs with weights ¼ ¾ ¾ ¼ (triangle of
    // radius 2), upsampling interpolates between sample centres
    let ramp: Vec<f64> = (0..8).map(|i| i as f64).collect();
    let down = wd::resize_linear_antialias(&ramp, 1, 8, 1, 4);
    let want = [0.0 * 0.0 + (0.0 * 0.75 + 1.0 * 0.75 + 2.0 * 0.25) / 1.75, 2.5, 4.5, (5.0 * 0.25 + 6.0 * 0.75 + 7.0 * 0.75) / 1.75];
    for (d, w) in down.iter().zip(want) {
        assert!((d - w).abs() < 1e-12, "{down:?}");
    }
    let up = wd::resize_linear_antialias(&[0.0, 4.0], 1, 2, 1, 4);
    assert_eq!(up, vec![0.0, 1.0, 3.0, 4.0]);
}

#[test]
fn train_cli_runs_wdr_on_the_tiny_sample() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("tiny-wdr.ply");
    let root = env!("CARGO_MANIFEST_DIR");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_gscodec"))
        .args(["train", &format!("{root}/samples/tiny"), "-o", out.to_str().unwrap()])
        .args(["--loss", "wdr", "--iters", "40", "--eval-every", "0", "--quiet"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(std::fs::metadata(&out).unwrap().len() > 0);
    // a bad --features file: exit 2, one error line naming it, no output
    let bad = dir.path().join("bad.ply");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_gscodec"))
        .args(["train", &format!("{root}/samples/tiny"), "-o", bad.to_str().unwrap()])
        .args(["--loss", "wdr", "--features", "vgg16=/nonexistent/vgg.safetensors", "--quiet"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.starts_with("error: /nonexistent/vgg.safetensors"), "{err}");
    assert!(!bad.exists());
}

#[test]
fn wd_sigma_or_warmup_out_of_range_is_bad_input_on_every_command() {
    let dir = tempfile::tempdir().unwrap();
    let root = env!("CARGO_MANIFEST_DIR");
    let tiny = format!("{root}/samples/tiny");
    let out = |name: &str| dir.path().join(name).to_str().unwrap().to_string();
    let runs: [Vec<String>; 3] = [
        vec!["train".into(), tiny.clone(), "-o".into(), out("t.ply"), "--loss".into(), "wdr".into()],
        vec!["encode".into(), tiny.clone(), "-o".into(), out("e.gsc")],
        vec!["sweep".into(), tiny.clone(), "-o".into(), out("sw")],
    ];
    for (flag, value, message) in
        [("--wd-sigma", "0.5", "--wd-sigma 0.5: must be in [1, 32]"), ("--wd-warmup", "1.5", "--wd-warmup 1.5: must be in [0, 1]")]
    {
        for args in &runs {
            let o = std::process::Command::new(env!("CARGO_BIN_EXE_gscodec"))
                .args(args)
                .args(["--iters", "5", flag, value, "--quiet"])
                .output()
                .unwrap();
            let err = String::from_utf8_lossy(&o.stderr);
            assert_eq!(o.status.code(), Some(2), "{} {flag}: {err}", args[0]);
            assert_eq!(err.lines().count(), 1, "{} {flag}: {err}", args[0]);
            assert!(err.starts_with("error: ") && err.contains(message), "{} {flag}: {err}", args[0]);
        }
    }
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0, "no partial output");
}

/// `encode DATASET --loss wdr` with no `--wd-warmup` trains WD-R only in the retraining after the
/// RD search (docs/wd.md §23): its run from the images is L1-SSIM's bit for bit (the CPU trainer
/// is deterministic), its retraining is not, and the report records the share 1. Without
/// retraining (`--retrain-iters 0`) the share is 0.3 and WD-R trains the run from the images.
#[test]
fn a_dataset_encode_trains_wdr_only_in_retraining_by_default() {
    let dir = tempfile::tempdir().unwrap();
    let tiny = format!("{}/samples/tiny", env!("CARGO_MANIFEST_DIR"));
    let iters = 40;
    let encode = |name: &str, extra: &[&str]| -> (serde_json::Value, Vec<u8>) {
        let (out, report) = (dir.path().join(format!("{name}.gsc")), dir.path().join(format!("{name}.json")));
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_gscodec"))
            .args(["encode", &tiny, "-o", out.to_str().unwrap(), "--report", report.to_str().unwrap()])
            .args(["--iters", &iters.to_string(), "--lambda", "20", "--backend", "cpu", "--quiet"])
            .args(extra)
            .output()
            .unwrap();
        assert!(o.status.success(), "{name}: {}", String::from_utf8_lossy(&o.stderr));
        (serde_json::from_str(&std::fs::read_to_string(report).unwrap()).unwrap(), std::fs::read(out).unwrap())
    };
    // held-out PSNR along the run from the images (the retraining's points come after `iters`)
    let main_run = |r: &serde_json::Value| -> Vec<(u64, f64)> {
        let series = r["series"].as_array().unwrap().iter();
        let train = series.filter(|p| p["trial"] == "train" && p["iteration"].as_u64().unwrap() <= iters);
        train.map(|p| (p["iteration"].as_u64().unwrap(), p["heldout_psnr"].as_f64().unwrap())).collect()
    };
    let (l1, l1_file) = encode("l1", &["--loss", "l1ssim"]);
    let (wdr, wdr_file) = encode("wdr", &["--loss", "wdr"]);
    assert_eq!((l1["wd_warmup"].as_f64(), wdr["wd_warmup"].as_f64(), wdr["retrain_iters"].as_u64()), (None, Some(1.0), Some(13)));
    assert!(main_run(&l1).len() >= 5, "{}", l1["series"]);
    assert_eq!(main_run(&wdr), main_run(&l1), "the run from the images is L1-SSIM's");
    assert_ne!(wdr_file, l1_file, "the retraining trains with WD-R");
    let (early, _) = encode("early", &["--loss", "wdr", "--retrain-iters", "0"]);
    assert_eq!(early["wd_warmup"].as_f64(), Some(0.3));
    let (given, _) = encode("given", &["--loss", "wdr", "--wd-warmup", "0.3"]);
    assert_eq!(given["wd_warmup"].as_f64(), Some(0.3));
    let (a, b) = (main_run(&given), main_run(&l1));
    assert_eq!(a[..2], b[..2], "the warm-up (iterations 1 to 12) is L1-SSIM's");
    assert_ne!(a, b, "WD-R from iteration 13");
}

/// `l1ssim` and `wdr` with WD-R only in retraining train the same scene from the images, so a
/// sweep trains it once: coding one trained scene with each encoder gives each encoder's own
/// file, byte for byte, and an encoder that trains otherwise refuses it.
#[test]
fn encoders_that_train_alike_share_one_training() {
    use gscodec::encoder::{Backend, Encoder, EncoderConfig, Lambda, LossSpec};
    use gscodec::loss::LossKind;
    let tiny = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("samples/tiny");
    let ds = gscodec::io::load_dataset(&tiny, &Default::default()).unwrap();
    let base = EncoderConfig::default().with_iters(Some(40)).with_lambda(Lambda::new(20.0).unwrap()).with_backend(Backend::Cpu);
    let loss = |kind, wd_warmup| LossSpec { kind, wd_sigma: Some(2.0), wd_warmup, ..LossSpec::default() };
    let encoder = |c: EncoderConfig| Encoder::new(c).unwrap();
    let l1 = encoder(base.clone().with_loss(loss(LossKind::L1ssim, None)));
    let wdr = encoder(base.clone().with_loss(loss(LossKind::Wdr, None)));
    let wdr_other_length = encoder(base.clone().with_loss(loss(LossKind::Wdr, None)).with_retrain_iters(Some(20)));
    let wdr_03 = encoder(base.clone().with_loss(loss(LossKind::Wdr, Some(0.3))));
    // without retraining the default share is 0.3: WD-R acts in the run from the images
    let wdr_no_retrain = encoder(base.clone().with_loss(loss(LossKind::Wdr, None)).with_retrain_iters(Some(0)));
    let other_seed = encoder(base.clone().with_loss(loss(LossKind::L1ssim, None)).with_seed(1));
    assert!(l1.trains_like(&wdr) && wdr.trains_like(&l1) && wdr.trains_like(&wdr_other_length));
    assert!(l1.trains_like(&encoder(base.clone().with_loss(loss(LossKind::Wdr, Some(1.0))))));
    assert!(!l1.trains_like(&wdr_03) && !wdr.trains_like(&wdr_no_retrain) && !l1.trains_like(&other_seed));

    let trained = l1.train_dataset(&ds, &mut |_| {}).unwrap();
    let shared = wdr.code_dataset(&ds, &trained, &mut |_| {}).unwrap();
    let alone = wdr.encode_dataset(&ds, &mut |_| {}).unwrap();
    assert_eq!(shared.bytes, alone.bytes, "WD-R's retraining of the shared scene is WD-R's own encode");
    assert_eq!((shared.report.retrain_iters, shared.report.wd_warmup), (13, Some(1.0)));
    assert!(shared.report.stages.total_s >= trained.elapsed().as_secs_f64(), "the shared training counts in its time");
    let other = wdr_other_length.code_dataset(&ds, &trained, &mut |_| {}).unwrap();
    assert_eq!(other.report.retrain_iters, 20);
    assert_ne!(other.bytes, shared.bytes);
    assert!(wdr_03.code_dataset(&ds, &trained, &mut |_| {}).is_err());
}

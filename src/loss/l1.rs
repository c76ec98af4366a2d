//! Mean absolute error and the reference 3DGS loss `0.8·L1 + 0.2·(1 − SSIM)`.

use super::{ssim, ImageLoss};
use gscodec_decoder::Image;

/// Mean absolute error over channels and pixels, and its (sub)gradient w.r.t. `a` (0 where equal).
pub fn l1_and_grad(a: &Image, b: &Image) -> (f64, Vec<f32>) {
    assert_eq!((a.width, a.height), (b.width, b.height), "L1 of images of different sizes");
    let n = a.data.len().max(1) as f64;
    let inv = (1.0 / n) as f32;
    let mut sum = 0.0f64;
    let grad = a
        .data
        .iter()
        .zip(&b.data)
        .map(|(x, y)| {
            let d = x - y;
            sum += d.abs() as f64;
            if d > 0.0 {
                inv
            } else if d < 0.0 {
                -inv
            } else {
                0.0
            }
        })
        .collect();
    (sum / n, grad)
}

/// The original 3DGS loss `(1 − λ)·L1 + λ·(1 − SSIM)` with `λ = 0.2`.
#[derive(Debug, Clone, Copy)]
pub struct L1Ssim {
    pub ssim_weight: f64,
}

impl Default for L1Ssim {
    fn default() -> Self {
        L1Ssim { ssim_weight: 0.2 }
    }
}

impl L1Ssim {
    /// The loss value alone (what [`L1Ssim::eval`] returns with the gradient).
    pub fn value(&self, rendered: &Image, target: &Image) -> f64 {
        assert_eq!((rendered.width, rendered.height), (target.width, target.height), "L1 of images of different sizes");
        let l1 =
            rendered.data.iter().zip(&target.data).map(|(x, y)| f64::from((x - y).abs())).sum::<f64>() / rendered.data.len().max(1) as f64;
        let lam = self.ssim_weight;
        (1.0 - lam) * l1 + lam * (1.0 - ssim::ssim(rendered, target))
    }

    /// The loss value and its gradient w.r.t. `rendered`.
    pub fn eval(&self, rendered: &Image, target: &Image) -> (f64, Vec<f32>) {
        let lam = self.ssim_weight;
        let (l1, mut g) = l1_and_grad(rendered, target);
        let (s, gs) = ssim::ssim_and_grad(rendered, target);
        let (a, b) = ((1.0 - lam) as f32, lam as f32);
        for (gi, si) in g.iter_mut().zip(&gs) {
            *gi = a * *gi - b * si;
        }
        ((1.0 - lam) * l1 + lam * (1.0 - s), g)
    }
}

impl ImageLoss for L1Ssim {
    fn loss_and_grad(&mut self, rendered: &Image, target: &Image, _view: usize, _iter: usize) -> (f64, Vec<f32>) {
        self.eval(rendered, target)
    }

    fn name(&self) -> &'static str {
        "l1ssim"
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn value_is_the_evaluated_loss() {
        let (w, h) = (23, 17);
        let img = |k: u32| Image { width: w, height: h, data: (0..3 * w * h).map(|i| ((i * k) % 97) as f32 / 97.0).collect() };
        let (a, b) = (img(7), img(13));
        let loss = L1Ssim::default();
        let (v, e) = (loss.value(&a, &b), loss.eval(&a, &b).0);
        assert!(v > 0.1 && (v - e).abs() < 1e-12, "{v} against {e}");
        assert_eq!(loss.value(&a, &a), 0.0);
    }
}

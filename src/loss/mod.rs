//! Image losses with analytic gradients: L1, SSIM, WD, WD-R.

pub mod features;
pub mod ssim;
pub mod tensor;
pub mod wd;
pub mod wdr;

use gscodec_decoder::Image;

/// A distortion between a rendered image and its target, with its gradient.
///
/// The trainer calls this once per iteration per rendered view. `view` identifies the training
/// view (stable across iterations) so implementations may cache per-target data (e.g. reference
/// features); `iter` lets a loss follow a schedule (e.g. WD-R's warm-up).
pub trait ImageLoss: Send {
    /// Returns the loss and `dL/d(rendered)` in the image's interleaved RGB layout.
    fn loss_and_grad(&mut self, rendered: &Image, target: &Image, view: usize, iter: usize) -> (f64, Vec<f32>);

    /// Short name for reports (`l1ssim`, `wd`, `wdr`).
    fn name(&self) -> &'static str;
}

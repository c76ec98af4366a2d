//! Every metric of one rendered view against its reference, and their mean over views: what
//! `gscodec eval` reports; and the cheap held-out score that training reports.

use crate::io::Frame;
use gscodec_decoder::render::render;
use gscodec_decoder::{Image, RenderOptions, Splats};
use serde::Serialize;

use super::{flip, ms_ssim, psnr, ssim};

/// All metrics of one view. Optional ones are `None` when not computable (MS-SSIM of views
/// smaller than 161 px) or not computed.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ViewMetrics {
    /// PSNR in dB (peak 1).
    pub psnr: f64,
    /// SSIM (reference-3DGS window).
    pub ssim: f64,
    /// MS-SSIM (5 scales).
    pub ms_ssim: Option<f64>,
    /// Mean LDR-ꟻLIP error.
    pub flip: f64,
    /// Wasserstein Distortion in the pyramid feature space.
    pub wd: Option<f64>,
}

/// Evaluates `test` against `reference` on every metric.
///
/// # Panics
/// If the images differ in size.
pub fn evaluate(reference: &Image, test: &Image) -> ViewMetrics {
    ViewMetrics {
        psnr: psnr(reference, test),
        ssim: ssim(reference, test),
        ms_ssim: ms_ssim(reference, test).ok(),
        flip: flip(reference, test),
        wd: Some(wd(reference, test)),
    }
}

/// Wasserstein Distortion of `test` against `reference` in the encoder's default `pyramid`
/// feature space with σ = 4 (`crate::loss::wd`); 0 for identical images, lower is better.
///
/// # Panics
/// If the images differ in size.
pub fn wd(reference: &Image, test: &Image) -> f64 {
    crate::loss::wdr::wd_metric(test, reference)
}

/// Mean of each metric over views (an optional metric only when every view has it); `None` for
/// no views.
pub fn mean(views: &[ViewMetrics]) -> Option<ViewMetrics> {
    if views.is_empty() {
        return None;
    }
    let n = views.len() as f64;
    let avg = |f: fn(&ViewMetrics) -> f64| views.iter().map(f).sum::<f64>() / n;
    let avg_opt = |f: fn(&ViewMetrics) -> Option<f64>| views.iter().map(f).sum::<Option<f64>>().map(|s| s / n);
    Some(ViewMetrics {
        psnr: avg(|v| v.psnr),
        ssim: avg(|v| v.ssim),
        ms_ssim: avg_opt(|v| v.ms_ssim),
        flip: avg(|v| v.flip),
        wd: avg_opt(|v| v.wd),
    })
}

/// Mean PSNR and SSIM of `splats` rendered (full SH, on `background`) at each frame's camera
/// against the frame's image: the held-out score of training and of an encode report, cheaper
/// than [`evaluate`]'s every metric. `None` without frames.
///
/// # Errors
/// A frame's image that cannot be read (streamed datasets read them here).
pub fn mean_psnr_ssim(splats: &Splats, frames: &[&Frame], background: [f32; 3]) -> crate::Result<Option<(f64, f64)>> {
    if frames.is_empty() {
        return Ok(None);
    }
    let opts = RenderOptions { background, max_sh_degree: 3 };
    let (mut p, mut s) = (0.0, 0.0);
    for f in frames {
        let img = render(splats, &f.camera, &opts);
        let target = f.image.get()?;
        p += psnr(&img, &target);
        s += ssim(&img, &target);
    }
    let n = frames.len() as f64;
    Ok(Some((p / n, s / n)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identical_views_are_perfect_and_means_average() {
        let img = Image { width: 170, height: 165, data: (0..170 * 165 * 3).map(|i| (i % 97) as f32 / 96.0).collect() };
        let v = evaluate(&img, &img);
        assert_eq!((v.psnr, v.flip, v.wd), (100.0, 0.0, Some(0.0)));
        assert!((v.ssim - 1.0).abs() < 1e-12 && (v.ms_ssim.unwrap() - 1.0).abs() < 1e-12);
        let small = Image { width: 20, height: 20, data: vec![0.5; 1200] };
        let w = evaluate(&small, &Image { data: vec![0.6; 1200], ..small.clone() });
        assert_eq!(w.ms_ssim, None);
        assert!(w.wd.unwrap() > 0.0);
        let m = mean(&[v, w]).unwrap();
        assert!((m.psnr - 60.0).abs() < 1e-4, "{}", m.psnr);
        assert_eq!(m.ms_ssim, None);
        assert!(mean(&[]).is_none());
    }
}

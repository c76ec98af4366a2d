//! ꟻLIP (Andersson et al. 2020, "FLIP: A Difference Evaluator for Alternating Images"), the LDR
//! variant, through NVIDIA's C++ implementation (the `nv-flip` crate). Images are sRGB in [0, 1];
//! they are rounded to 8 bits on the way in, as ꟻLIP's own tool does when it reads PNGs.
//! The viewing condition is ꟻLIP's default of 67 pixels per degree (a 0.7 m distance to a 0.7 m
//! wide 4K monitor).

use gscodec_decoder::Image;

/// ꟻLIP's default observer: pixels per degree of visual angle.
pub const DEFAULT_PIXELS_PER_DEGREE: f32 = nv_flip::DEFAULT_PIXELS_PER_DEGREE;

/// Per-pixel ꟻLIP error map (row-major, values in [0, 1]) of `test` against `reference`.
///
/// # Panics
/// If the two images differ in size.
pub fn flip_map(reference: &Image, test: &Image, pixels_per_degree: f32) -> Vec<f32> {
    assert_eq!((reference.width, reference.height), (test.width, test.height), "FLIP of images of different sizes");
    let to_flip = |img: &Image| {
        let bytes: Vec<u8> = img.data.iter().map(|v| (v.clamp(0.0, 1.0) * 255.0).round() as u8).collect();
        nv_flip::FlipImageRgb8::with_data(img.width, img.height, &bytes)
    };
    nv_flip::flip(to_flip(reference), to_flip(test), pixels_per_degree).to_vec()
}

/// Mean ꟻLIP error over the image (the single number the ꟻLIP authors recommend), at the default
/// 67 pixels per degree. 0 for identical images; lower is better.
///
/// # Panics
/// If the two images differ in size.
pub fn flip(reference: &Image, test: &Image) -> f64 {
    let map = flip_map(reference, test, DEFAULT_PIXELS_PER_DEGREE);
    map.iter().map(|v| *v as f64).sum::<f64>() / map.len().max(1) as f64
}

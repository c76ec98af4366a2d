use glam::{Mat3, Vec3};
use gscodec_decoder::{render, Camera, RenderOptions, Splats};

#[test]
fn unit_gaussian_head_on_peak() {
    let mut s = Splats::new(0);
    // colour = C0*dc + 0.5 = 1 => dc = 0.5/C0
    let dc = 0.5 / gscodec_decoder::math::SH_C0;
    s.push([0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], 100.0, [dc; 3], &[]);
    let cam = Camera::new(64, 64, 32.0, 32.0, Mat3::IDENTITY, Vec3::new(0.0, 0.0, 4.0));
    let img = render::render(&s, &cam, &RenderOptions::default());
    let reference = render::reference::render_f64(&s, &cam, &RenderOptions::default());
    // the mean projects to (32, 32): between four pixels
    let p = img.pixel(31, 31)[0];
    // sigma in pixels = f/z = 8, var = 64 + 0.3; offset (0.5,0.5)
    let expect = 0.99f32.min((-0.5f32 * 0.5 / 64.3).exp());
    assert!((p - expect).abs() < 1e-5, "{p} vs {expect}");
    let max_err = img.data.iter().zip(&reference.data).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
    assert!(max_err < 1e-5, "{max_err}");
}

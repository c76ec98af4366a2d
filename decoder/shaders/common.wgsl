// Shared declarations of the gscodec GPU renderer (prepended to every kernel by gpu.rs).
// The math mirrors gscodec_decoder::math exactly (same order of operations where it matters).

struct Frame {
    rot0: vec4<f32>,        // columns of the world-to-camera rotation
    rot1: vec4<f32>,
    rot2: vec4<f32>,
    trans: vec4<f32>,       // world-to-camera translation (xyz)
    center: vec4<f32>,      // camera centre in world space (xyz)
    focal: vec4<f32>,       // fx, fy, cx, cy
    background: vec4<f32>,  // rgb
    znear: f32,
    width: u32,
    height: u32,
    tiles_x: u32,
    tiles_y: u32,
    degree: u32,            // SH degree used for colour
    stride: u32,            // floats per input record
    n: u32,                 // Gaussians in the scene
}

// A projected Gaussian: (mean.x, mean.y, depth, radius), (conic A, B, C, opacity), (r, g, b, -).
struct Projected {
    a: vec4<f32>,
    b: vec4<f32>,
    c: vec4<f32>,
}

const TILE: u32 = 16u;
const MAX_ALPHA: f32 = 0.99;
const MIN_ALPHA: f32 = 0.003921569; // 1/255
const MIN_TRANSMITTANCE: f32 = 1e-4;
const COV2D_DILATION: f32 = 0.3;

fn is_finite(x: f32) -> bool {
    return (bitcast<u32>(x) & 0x7f800000u) != 0x7f800000u;
}

// Linear workgroup index of a (possibly 2D) dispatch.
fn linear_wg(wid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return wid.y * nwg.x + wid.x;
}

// Tile rectangle [x0, y0, x1, y1) of a Gaussian (math::tile_rect).
fn tile_rect(mean: vec2<f32>, radius: f32, f: Frame) -> vec4<u32> {
    let gx = f32(f.tiles_x);
    let gy = f32(f.tiles_y);
    let t = f32(TILE);
    let p = mean - vec2<f32>(0.5, 0.5);
    let lo = clamp((p - vec2<f32>(radius)) / t, vec2<f32>(0.0), vec2<f32>(gx, gy));
    let hi = clamp((p + vec2<f32>(radius + t - 1.0)) / t, vec2<f32>(0.0), vec2<f32>(gx, gy));
    return vec4<u32>(u32(lo.x), u32(lo.y), u32(hi.x), u32(hi.y));
}

// The 3DGS image loss (1-λ)·L1 + λ·(1 - SSIM) and its gradient w.r.t. the rendered image, as
// gscodec::loss (the CPU oracle, f64 there, f32 here): SSIM with the 11×11 Gaussian window σ=1.5
// (TAPS, prepended from gscodec::loss::ssim::gaussian_taps), zero-padded "same" separable blurs,
// C1 = 0.01², C2 = 0.03², mean over channels and pixels. The backward blurs three per-pixel
// gradient maps (the zero-padded symmetric blur is self-adjoint).
// Images are interleaved RGB; planes are [quantity][channel][pixel].

struct LossParams {
    width: u32,
    height: u32,
    lambda: f32,    // SSIM weight
    slot: u32,      // loss accumulator index
}

@group(0) @binding(0) var<uniform> lp: LossParams;
@group(0) @binding(1) var<storage, read> rendered: array<f32>;
@group(0) @binding(2) var<storage, read> target_img: array<f32>;
@group(0) @binding(3) var<storage, read_write> planes: array<f32>;    // 15 planes: h-blurred x, y, xx, yy, xy
@binding(4) @group(0) var<storage, read_write> gplanes: array<f32>;   // 9 planes: dS/dμx-ish, dS/dσxx, dS/dσxy
@group(0) @binding(5) var<storage, read_write> gblur: array<f32>;     // 9 planes, h-blurred gplanes
@group(0) @binding(6) var<storage, read_write> dl: array<f32>;        // dL/d(rendered), interleaved
@group(0) @binding(7) var<storage, read_write> loss_acc: array<atomic<u32>>;

const C1: f32 = 0.0001;
const C2: f32 = 0.0009;
const R: i32 = 5;

var<workgroup> red: array<f32, 256>;

fn pixel_index(gid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return gid.y * nwg.x * 256u + gid.x;
}

@compute @workgroup_size(256)
fn ssim_h(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let n = lp.width * lp.height;
    let i = pixel_index(gid, nwg);
    if (i >= n) {
        return;
    }
    let w = i32(lp.width);
    let x = i32(i % lp.width);
    let row = i - u32(x);
    for (var c = 0u; c < 3u; c++) {
        var s = array<f32, 5>(0.0, 0.0, 0.0, 0.0, 0.0);
        for (var k = -R; k <= R; k++) {
            let xx = x + k;
            if (xx < 0 || xx >= w) {
                continue;
            }
            let t = TAPS[k + R];
            let j = (row + u32(xx)) * 3u + c;
            let a = rendered[j];
            let b = target_img[j];
            s[0] += t * a;
            s[1] += t * b;
            s[2] += t * a * a;
            s[3] += t * b * b;
            s[4] += t * a * b;
        }
        for (var q = 0u; q < 5u; q++) {
            planes[(q * 3u + c) * n + i] = s[q];
        }
    }
}

// Vertical blur of plane `q` of `src`-like storage at pixel (x, y).
fn vblur_planes(q: u32, i: u32, n: u32) -> f32 {
    let h = i32(lp.height);
    let y = i32(i / lp.width);
    var s = 0.0;
    for (var k = -R; k <= R; k++) {
        let yy = y + k;
        if (yy < 0 || yy >= h) {
            continue;
        }
        s += TAPS[k + R] * planes[q * n + u32(i32(i) + k * i32(lp.width))];
    }
    return s;
}

fn atomic_add_loss(i: u32, v: f32) {
    var old = atomicLoad(&loss_acc[i]);
    loop {
        let r = atomicCompareExchangeWeak(&loss_acc[i], old, bitcast<u32>(bitcast<f32>(old) + v));
        if (r.exchanged) {
            break;
        }
        old = r.old_value;
    }
}

@compute @workgroup_size(256)
fn ssim_v(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>, @builtin(local_invocation_index) li: u32) {
    let n = lp.width * lp.height;
    let i = pixel_index(gid, nwg);
    var part = 0.0;
    if (i < n) {
        for (var c = 0u; c < 3u; c++) {
            let mx = vblur_planes(c, i, n);
            let my = vblur_planes(3u + c, i, n);
            let sxx = vblur_planes(6u + c, i, n);
            let syy = vblur_planes(9u + c, i, n);
            let sxy = vblur_planes(12u + c, i, n);
            let vx = sxx - mx * mx;
            let vy = syy - my * my;
            let cxy = sxy - mx * my;
            let a1 = 2.0 * mx * my + C1;
            let a2 = 2.0 * cxy + C2;
            let b1 = mx * mx + my * my + C1;
            let b2 = vx + vy + C2;
            let s = (a1 * a2) / (b1 * b2);
            let ds_dm = 2.0 * my * a2 / (b1 * b2) - s * 2.0 * mx / b1;
            let ds_dv = -s / b2;
            let ds_dc = 2.0 * a1 / (b1 * b2);
            gplanes[c * n + i] = ds_dm - 2.0 * mx * ds_dv - my * ds_dc;
            gplanes[(3u + c) * n + i] = ds_dv;
            gplanes[(6u + c) * n + i] = ds_dc;
            let d = abs(rendered[i * 3u + c] - target_img[i * 3u + c]);
            part += (1.0 - lp.lambda) * d + lp.lambda * (1.0 - s);
        }
    }
    red[li] = part;
    workgroupBarrier();
    for (var off = 128u; off > 0u; off = off >> 1u) {
        if (li < off) {
            red[li] += red[li + off];
        }
        workgroupBarrier();
    }
    if (li == 0u) {
        atomic_add_loss(lp.slot, red[0] / f32(3u * n));
    }
}

@compute @workgroup_size(256)
fn ssim_bh(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let n = lp.width * lp.height;
    let i = pixel_index(gid, nwg);
    if (i >= n) {
        return;
    }
    let w = i32(lp.width);
    let x = i32(i % lp.width);
    for (var q = 0u; q < 9u; q++) {
        var s = 0.0;
        for (var k = -R; k <= R; k++) {
            let xx = x + k;
            if (xx < 0 || xx >= w) {
                continue;
            }
            s += TAPS[k + R] * gplanes[q * n + u32(i32(i) + k)];
        }
        gblur[q * n + i] = s;
    }
}

@compute @workgroup_size(256)
fn ssim_bv(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let n = lp.width * lp.height;
    let i = pixel_index(gid, nwg);
    if (i >= n) {
        return;
    }
    let h = i32(lp.height);
    let y = i32(i / lp.width);
    let inv = 1.0 / f32(3u * n);
    for (var c = 0u; c < 3u; c++) {
        var bm = 0.0;
        var bxx = 0.0;
        var bxy = 0.0;
        for (var k = -R; k <= R; k++) {
            let yy = y + k;
            if (yy < 0 || yy >= h) {
                continue;
            }
            let j = u32(i32(i) + k * i32(lp.width));
            let t = TAPS[k + R];
            bm += t * gblur[c * n + j];
            bxx += t * gblur[(3u + c) * n + j];
            bxy += t * gblur[(6u + c) * n + j];
        }
        let xv = rendered[i * 3u + c];
        let yv = target_img[i * 3u + c];
        let g_ssim = bm + 2.0 * xv * bxx + yv * bxy;
        let d = xv - yv;
        var g_l1 = 0.0;
        if (d > 0.0) {
            g_l1 = 1.0;
        } else if (d < 0.0) {
            g_l1 = -1.0;
        }
        dl[i * 3u + c] = ((1.0 - lp.lambda) * g_l1 - lp.lambda * g_ssim) * inv;
    }
}

// Wasserstein Distortion (WD) with the built-in `pyramid` feature bank, forward and backward, and
// its combination into `wd` / `wdr` training gradients: formula by formula as
// gscodec::loss::{wd, wdr, features::pyramid} (the CPU oracle; f32 in both).
//
// Every kernel is one elementwise op over planes in one f32 `arena` (offsets in floats, given by
// the op's uniform), so the host lays out features, statistics and gradients once per image
// size. `refs` holds the reference view's cached statistics. Prepended by the host (from the
// CPU code): TG / TD1 / TD2 (7 taps of g, g', g''), ODD / EVEN (steering), SIG (the signals'
// channel weights), GAIN, MEAN / STD (ImageNet), NORMALISE_VIEWS, SUMS_AT / SUMS / STRIPES (the
// layout of acc's sums).
//
// acc: [0] d_WD of this iteration, [1] Σ(∇L_orig)², [2] Σ(∇d_WD + β∇L_orig)², [3] γ,
// [4] Σ‖∇L_orig‖, [5] Σ‖∇(d_WD + β L_orig)‖, [6] views measured (f32 bit patterns); from [SUMS_AT],
// STRIPES partial sums for each of [0], [1], [2], which workgroups add into by their index and
// scalars() folds in order.

struct Op {
    c: u32,
    h: u32,
    w: u32,
    oh: u32,
    ow: u32,
    src: u32,
    src2: u32,
    dst: u32,
    dst2: u32,
    aux: u32,
    aux2: u32,
    aux3: u32,
    aux4: u32,
    aux5: u32,
    flags: u32,
    fscale: f32,
    oy: u32,
    ox: u32,
    count: u32,
    pad: u32,
}

@group(0) @binding(0) var<storage, read_write> arena: array<f32>;
@group(0) @binding(1) var<storage, read_write> refs: array<f32>;
@group(0) @binding(2) var<storage, read_write> image: array<f32>;    // interleaved RGB
@group(0) @binding(3) var<storage, read_write> dl: array<f32>;       // dL/d(rendered), interleaved
@group(0) @binding(4) var<storage, read_write> acc: array<atomic<u32>>;
@group(0) @binding(5) var<storage, read_write> loss_acc: array<atomic<u32>>;
@group(1) @binding(0) var<uniform> op: Op;

const SQ: u32 = 1u;         // moments: the q input is the x input squared
const WEIGHTED: u32 = 2u;   // moments: the level counts (write m, p at full level resolution)
const NEXT: u32 = 4u;       // moments: write the subsampled running arrays for the next level
const UP: u32 = 8u;         // a gradient arrives from the next level / coarser stage
const HAS0: u32 = 16u;      // array_grad: level 0 counts
const WDR: u32 = 32u;       // scalars / combine: γ·(d_WD + β·L_orig), else γ·d_WD
const NORMALISE: u32 = 64u; // scalars: measure γ over the first NORMALISE_VIEWS views
const R: i32 = 3;           // filter radius of the bank

var<workgroup> red: array<vec2<f32>, 256>;

fn index(gid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return gid.y * nwg.x * 256u + gid.x;
}

fn has(f: u32) -> bool {
    return (op.flags & f) != 0u;
}

fn finite(x: f32) -> bool {
    return (bitcast<u32>(x) & 0x7f800000u) != 0x7f800000u;
}

// Workgroup sum (call from uniform control flow); the total is valid in every invocation.
fn reduce(li: u32, v: vec2<f32>) -> vec2<f32> {
    red[li] = v;
    workgroupBarrier();
    for (var off = 128u; off > 0u; off = off >> 1u) {
        if (li < off) {
            red[li] += red[li + off];
        }
        workgroupBarrier();
    }
    return red[0];
}

// Adds v to sum `slot` (below SUMS) in the stripe of workgroup `wg` (scalars() folds the stripes).
fn acc_add(slot: u32, wg: u32, v: f32) {
    let w = SUMS_AT + slot * STRIPES + wg % STRIPES;
    var old = atomicLoad(&acc[w]);
    loop {
        let r = atomicCompareExchangeWeak(&acc[w], old, bitcast<u32>(bitcast<f32>(old) + v));
        if (r.exchanged) {
            break;
        }
        old = r.old_value;
    }
}

fn accf(slot: u32) -> f32 {
    return bitcast<f32>(atomicLoad(&acc[slot]));
}

fn at(base: u32, i: u32, sq: bool) -> f32 {
    let v = arena[base + i];
    return select(v, v * v, sq);
}

// [¼ ½ ¼] along x at (y, x) of an h × w plane, zero padding.
fn hrow(base: u32, w: u32, y: u32, x: u32, sq: bool) -> f32 {
    let r = base + y * w;
    var s = 0.0;
    if (x > 0u) {
        s += at(r, x - 1u, sq);
    }
    if (x + 1u < w) {
        s += at(r, x + 1u, sq);
    }
    return 0.5 * at(r, x, sq) + 0.25 * s;
}

// The 3×3 binomial K at (y, x) (tensor.rs blur_into: rows first, then columns).
fn blur_at(base: u32, h: u32, w: u32, y: u32, x: u32, sq: bool) -> f32 {
    var s = 0.0;
    if (y > 0u) {
        s += hrow(base, w, y - 1u, x, sq);
    }
    if (y + 1u < h) {
        s += hrow(base, w, y + 1u, x, sq);
    }
    return 0.5 * hrow(base, w, y, x, sq) + 0.25 * s;
}

// ---- features (pyramid.rs), forward ----

// Normalised image (3 planes at dst) and its luminance (dst2).
@compute @workgroup_size(256)
fn feat_input(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = index(gid, nwg);
    let n = op.count;
    if (i >= n) {
        return;
    }
    var l = 0.0;
    for (var c = 0u; c < 3u; c++) {
        let v = (image[3u * i + c] - MEAN[c]) / STD[c];
        arena[op.dst + c * n + i] = v;
        l += v;
    }
    arena[op.dst2 + i] = (1.0 / 3.0) * l;
}

// Stride-2 "SAME" low-pass (tensor.rs lowpass2): h × w at src → oh × ow at dst from (oy, ox).
@compute @workgroup_size(256)
fn lowpass2(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = index(gid, nwg);
    if (i >= op.count) {
        return;
    }
    let y = op.oy + 2u * (i / op.ow);
    let x = op.ox + 2u * (i % op.ow);
    arena[op.dst + i] = blur_at(op.src, op.h, op.w, y, x, false);
}

// Horizontal pass of the bank: the luminance at src correlated with g, g', g'' (3 planes at dst).
@compute @workgroup_size(256)
fn basis_h(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = index(gid, nwg);
    let n = op.count;
    if (i >= n) {
        return;
    }
    let x = i32(i % op.w);
    let row = i - u32(x);
    var a = vec3<f32>(0.0);
    for (var k = 0; k < 7; k++) {
        let xx = x + k - R;
        if (xx < 0 || xx >= i32(op.w)) {
            continue;
        }
        a += vec3<f32>(TG[k], TD1[k], TD2[k]) * arena[op.src + row + u32(xx)];
    }
    arena[op.dst + i] = a.x;
    arena[op.dst + n + i] = a.y;
    arena[op.dst + 2u * n + i] = a.z;
}

// Vertical pass (Gx, Gy, Gxx, Gxy, Gyy), steering and rectification: 16 channels at dst.
@compute @workgroup_size(256)
fn basis_v(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = index(gid, nwg);
    let n = op.count;
    if (i >= n) {
        return;
    }
    let x = i % op.w;
    let y = i32(i / op.w);
    var gx = 0.0;
    var gy = 0.0;
    var gxx = 0.0;
    var gxy = 0.0;
    var gyy = 0.0;
    for (var k = 0; k < 7; k++) {
        let yy = y + k - R;
        if (yy < 0 || yy >= i32(op.h)) {
            continue;
        }
        let j = u32(yy) * op.w + x;
        let t0 = arena[op.src + j];
        let t1 = arena[op.src + n + j];
        let t2 = arena[op.src + 2u * n + j];
        gx += TG[k] * t1;
        gy += TD1[k] * t0;
        gxx += TG[k] * t2;
        gxy += TD1[k] * t1;
        gyy += TD2[k] * t0;
    }
    for (var o = 0u; o < 4u; o++) {
        let r_odd = ODD[o].x * gx + ODD[o].y * gy;
        let r_even = EVEN[o].x * gxx + EVEN[o].y * gxy + EVEN[o].z * gyy;
        let b = op.dst + 4u * o * n + i;
        arena[b] = max(GAIN * r_odd, 0.0);
        arena[b + n] = max(-GAIN * r_odd, 0.0);
        arena[b + 2u * n] = max(GAIN * r_even, 0.0);
        arena[b + 3u * n] = max(-GAIN * r_even, 0.0);
    }
}

// ---- WD statistics (wd.rs moments) ----

// Level k of one array: m = K*x, p = K*q on the c × h × w inputs (src, src2 or src², with SQ);
// WEIGHTED writes m, p (dst, dst2) everywhere, NEXT writes their even samples (aux, aux2,
// c × oh × ow). Without WEIGHTED only the even samples are computed.
@compute @workgroup_size(256)
fn moments(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = index(gid, nwg);
    if (i >= op.count) {
        return;
    }
    let weighted = has(WEIGHTED);
    let gw = select(op.ow, op.w, weighted);
    let gh = select(op.oh, op.h, weighted);
    let step = select(2u, 1u, weighted);
    let ch = i / (gh * gw);
    let r = i % (gh * gw);
    let y = (r / gw) * step;
    let x = (r % gw) * step;
    let n = op.h * op.w;
    let m = blur_at(op.src + ch * n, op.h, op.w, y, x, false);
    var p: f32;
    if (has(SQ)) {
        p = blur_at(op.src + ch * n, op.h, op.w, y, x, true);
    } else {
        p = blur_at(op.src2 + ch * n, op.h, op.w, y, x, false);
    }
    if (weighted) {
        let e = ch * n + y * op.w + x;
        arena[op.dst + e] = m;
        arena[op.dst2 + e] = p;
    }
    if (has(NEXT) && y % 2u == 0u && x % 2u == 0u) {
        let j = ch * op.oh * op.ow + (y / 2u) * op.ow + x / 2u;
        arena[op.aux + j] = m;
        arena[op.aux2 + j] = p;
    }
}

// Reference side: mean and √max(v, 0) of a level (src = m, src2 = p → refs dst, dst2).
@compute @workgroup_size(256)
fn export_stats(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = index(gid, nwg);
    if (i >= op.count) {
        return;
    }
    let m = arena[op.src + i];
    let v = arena[op.src2 + i] - m * m;
    refs[op.dst + i] = m;
    refs[op.dst2 + i] = sqrt(max(v, 0.0));
}

// Reference side: the features themselves (level 0).
@compute @workgroup_size(256)
fn export_copy(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = index(gid, nwg);
    if (i >= op.count) {
        return;
    }
    refs[op.dst + i] = arena[op.src + i];
}

// ---- WD value and backward (wd.rs array_value_and_grad) ----

// A weighted level k at its c × h × w resolution: value (into acc[0], times fscale = 1/(c·h·w))
// and dL/dm, dL/dp (dst, dst2), plus the gradient arriving from level k+1 (aux2, aux3, c × oh × ow,
// at even samples) when UP. aux = weight map, refs aux4 / aux5 = reference mean / sd.
@compute @workgroup_size(256)
fn level_grad(
    @builtin(global_invocation_id) gid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    let i = index(gid, nwg);
    var part = 0.0;
    if (i < op.count) {
        let n = op.h * op.w;
        let ch = i / n;
        let r = i % n;
        let y = r / op.w;
        let x = r % op.w;
        var gm = 0.0;
        var gp = 0.0;
        if (has(UP) && y % 2u == 0u && x % 2u == 0u) {
            let j = ch * op.oh * op.ow + (y / 2u) * op.ow + x / 2u;
            gm = arena[op.aux2 + j];
            gp = arena[op.aux3 + j];
        }
        let wi = arena[op.aux + r];
        if (wi > 0.0) {
            let m = arena[op.src + i];
            let v = arena[op.src2 + i] - m * m;
            let s = sqrt(max(v, 0.0));
            let dm = m - refs[op.aux4 + i];
            let ds = s - refs[op.aux5 + i];
            part = wi * (dm * dm + ds * ds);
            let scale = 2.0 * op.fscale;
            let g_s = scale * wi * ds;
            // min(½/√v, 1e6) = ½ / max(√v, 5e-7)
            let g_vc = g_s * (0.5 / max(s, 5e-7));
            // The clamp at 0 passes the gradient where inactive or where it is negative.
            var g_v = 0.0;
            if (v >= 0.0 || g_vc < 0.0) {
                g_v = g_vc;
            }
            gm += scale * wi * dm - 2.0 * m * g_v;
            gp += g_v;
        }
        arena[op.dst + i] = gm;
        arena[op.dst2 + i] = gp;
    }
    let t = reduce(li, vec2<f32>(part, 0.0));
    if (li == 0u && t.x != 0.0) {
        acc_add(0u, i >> 8u, t.x * op.fscale);
    }
}

// Adjoint of the stride-1 low-pass (K is self-adjoint): dst = K*src, dst2 = K*src2 (c × h × w).
@compute @workgroup_size(256)
fn blur_pair(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = index(gid, nwg);
    if (i >= op.count) {
        return;
    }
    let n = op.h * op.w;
    let ch = i / n;
    let r = i % n;
    let y = r / op.w;
    let x = r % op.w;
    arena[op.dst + i] = blur_at(op.src + ch * n, op.h, op.w, y, x, false);
    arena[op.dst2 + i] = blur_at(op.src2 + ch * n, op.h, op.w, y, x, false);
}

// Coarse row spread of tensor.rs blur_subsample_adjoint_into at fine row y, coarse column i.
fn spread_rows(base: u32, y: u32, i: u32) -> f32 {
    if (y % 2u == 0u) {
        return 0.5 * arena[base + (y / 2u) * op.ow + i];
    }
    var b = 0.0;
    if ((y + 1u) / 2u < op.oh) {
        b = arena[base + ((y + 1u) / 2u) * op.ow + i];
    }
    return 0.25 * (arena[base + ((y - 1u) / 2u) * op.ow + i] + b);
}

fn spread(base: u32, y: u32, x: u32) -> f32 {
    if (x % 2u == 0u) {
        return 0.5 * spread_rows(base, y, x / 2u);
    }
    var b = 0.0;
    if ((x + 1u) / 2u < op.ow) {
        b = spread_rows(base, y, (x + 1u) / 2u);
    }
    return 0.25 * (spread_rows(base, y, (x - 1u) / 2u) + b);
}

// A level that only fed the next one: adjoint of blur + subsample, c × oh × ow → c × h × w.
@compute @workgroup_size(256)
fn blur_sub_adj_pair(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = index(gid, nwg);
    if (i >= op.count) {
        return;
    }
    let n = op.h * op.w;
    let ch = i / n;
    let r = i % n;
    let y = r / op.w;
    let x = r % op.w;
    let cn = ch * op.oh * op.ow;
    arena[op.dst + i] = spread(op.src + cn, y, x);
    arena[op.dst2 + i] = spread(op.src2 + cn, y, x);
}

// The gradient w.r.t. one feature array (src, c × h × w) into dst: aux + 2x·aux2 (level 1's
// input gradients, UP) + level 0 (HAS0: weight map aux3, reference refs aux4), level 0's value.
@compute @workgroup_size(256)
fn array_grad(
    @builtin(global_invocation_id) gid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    let i = index(gid, nwg);
    var part = 0.0;
    if (i < op.count) {
        let x = arena[op.src + i];
        var g = 0.0;
        if (has(UP)) {
            g = arena[op.aux + i] + 2.0 * x * arena[op.aux2 + i];
        }
        if (has(HAS0)) {
            let wi = arena[op.aux3 + i % (op.h * op.w)];
            let d = x - refs[op.aux4 + i];
            g += 2.0 * op.fscale * wi * d;
            part = wi * d * d;
        }
        arena[op.dst + i] = g;
    }
    // Only level 0 has a value here (the flag is uniform, so the barriers stay in uniform control).
    if (has(HAS0)) {
        let t = reduce(li, vec2<f32>(part, 0.0));
        if (li == 0u && t.x != 0.0) {
            acc_add(0u, i >> 8u, t.x * op.fscale);
        }
    }
}

// ---- features (pyramid.rs), backward ----

fn relu_grad(o: u32, g: u32, n: u32, i: u32) -> f32 {
    return select(0.0, arena[g + o * n + i], arena[op.src + o * n + i] > 0.0);
}

// Rectification adjoint: 16 channels (src = outputs, src2 = their gradients) → the 5 basis
// responses' gradients (5 planes at dst).
@compute @workgroup_size(256)
fn rectify_adj(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = index(gid, nwg);
    let n = op.count;
    if (i >= n) {
        return;
    }
    var b0 = 0.0;
    var b1 = 0.0;
    var b2 = 0.0;
    var b3 = 0.0;
    var b4 = 0.0;
    for (var o = 0u; o < 4u; o++) {
        let odd = GAIN * (relu_grad(4u * o, op.src2, n, i) - relu_grad(4u * o + 1u, op.src2, n, i));
        let even = GAIN * (relu_grad(4u * o + 2u, op.src2, n, i) - relu_grad(4u * o + 3u, op.src2, n, i));
        b0 += ODD[o].x * odd;
        b1 += ODD[o].y * odd;
        b2 += EVEN[o].x * even;
        b3 += EVEN[o].y * even;
        b4 += EVEN[o].z * even;
    }
    arena[op.dst + i] = b0;
    arena[op.dst + n + i] = b1;
    arena[op.dst + 2u * n + i] = b2;
    arena[op.dst + 3u * n + i] = b3;
    arena[op.dst + 4u * n + i] = b4;
}

// Horizontal adjoint (reversed taps) of the 5 basis gradients, grouped by their vertical filter:
// g (Gx, Gxx), g' (Gy, Gxy), g'' (Gyy): 3 planes at dst.
@compute @workgroup_size(256)
fn basis_adj_h(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = index(gid, nwg);
    let n = op.count;
    if (i >= n) {
        return;
    }
    let x = i32(i % op.w);
    let row = i - u32(x);
    var a = vec3<f32>(0.0);
    for (var k = 0; k < 7; k++) {
        let xx = x + R - k;
        if (xx < 0 || xx >= i32(op.w)) {
            continue;
        }
        let j = op.src + row + u32(xx);
        a.x += TD1[k] * arena[j] + TD2[k] * arena[j + 2u * n];
        a.y += TG[k] * arena[j + n] + TD1[k] * arena[j + 3u * n];
        a.z += TG[k] * arena[j + 4u * n];
    }
    arena[op.dst + i] = a.x;
    arena[op.dst + n + i] = a.y;
    arena[op.dst + 2u * n + i] = a.z;
}

// The (zero-padded) scatter of the coarser stage's gradient (aux, oh × ow) onto the h × w grid at
// offsets (oy, ox): the first half of tensor.rs lowpass2_adjoint.
fn scat(y: i32, x: i32) -> f32 {
    if (y < 0 || x < 0 || y >= i32(op.h) || x >= i32(op.w)) {
        return 0.0;
    }
    let a = y - i32(op.oy);
    let b = x - i32(op.ox);
    if (a < 0 || b < 0 || a % 2 != 0 || b % 2 != 0) {
        return 0.0;
    }
    let j = u32(a / 2);
    let k = u32(b / 2);
    if (j >= op.oh || k >= op.ow) {
        return 0.0;
    }
    return arena[op.aux + j * op.ow + k];
}

fn scat_row(y: i32, x: i32) -> f32 {
    return 0.5 * scat(y, x) + 0.25 * (scat(y, x - 1) + scat(y, x + 1));
}

// Vertical adjoint, summed into the luminance gradient of the stage (dst), plus the coarser
// stage's gradient through the stride-2 low-pass (UP).
@compute @workgroup_size(256)
fn basis_adj_v(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = index(gid, nwg);
    let n = op.count;
    if (i >= n) {
        return;
    }
    let x = i % op.w;
    let y = i32(i / op.w);
    var g = 0.0;
    if (has(UP)) {
        let xi = i32(x);
        g = 0.5 * scat_row(y, xi) + 0.25 * (scat_row(y - 1, xi) + scat_row(y + 1, xi));
    }
    for (var k = 0; k < 7; k++) {
        let yy = y + R - k;
        if (yy < 0 || yy >= i32(op.h)) {
            continue;
        }
        let j = op.src + u32(yy) * op.w + x;
        g += TG[k] * arena[j] + TD1[k] * arena[j + n] + TD2[k] * arena[j + 2u * n];
    }
    arena[op.dst + i] = g;
}

// The image gradient (interleaved, dst) from the normalised image's (src) and the luminance's
// (src2) gradients.
@compute @workgroup_size(256)
fn input_adj(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = index(gid, nwg);
    let n = op.count;
    if (i >= n) {
        return;
    }
    let gy = (1.0 / 3.0) * arena[op.src2 + i];
    for (var c = 0u; c < 3u; c++) {
        arena[op.dst + 3u * i + c] = (arena[op.src + c * n + i] + gy) / STD[c];
    }
}

// An opponent colour signal SIG[c] (pyramid.rs SIGNALS) of the normalised image (3 planes at src)
// into dst.
@compute @workgroup_size(256)
fn feat_signal(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = index(gid, nwg);
    let n = op.count;
    if (i >= n) {
        return;
    }
    let k = SIG[op.c];
    arena[op.dst + i] = k.x * arena[op.src + i] + k.y * arena[op.src + n + i] + k.z * arena[op.src + 2u * n + i];
}

// A stage without oriented responses: the coarser stage's gradient (aux, UP) through the stride-2
// low-pass alone, into dst.
@compute @workgroup_size(256)
fn lowpass2_adj(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = index(gid, nwg);
    if (i >= op.count) {
        return;
    }
    let x = i32(i % op.w);
    let y = i32(i / op.w);
    arena[op.dst + i] = 0.5 * scat_row(y, x) + 0.25 * (scat_row(y - 1, x) + scat_row(y + 1, x));
}

// Adds signal SIG[c]'s gradient (src2) to the image gradient (dst, interleaved; after input_adj).
@compute @workgroup_size(256)
fn input_adj_signal(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = index(gid, nwg);
    let n = op.count;
    if (i >= n) {
        return;
    }
    let k = SIG[op.c];
    let g = arena[op.src2 + i];
    for (var c = 0u; c < 3u; c++) {
        arena[op.dst + 3u * i + c] += k[c] * g / STD[c];
    }
}

// ---- the training loss (wdr.rs) ----

// ‖∇L_orig‖² and ‖∇d_WD + β∇L_orig‖² (src = ∇d_WD interleaved, fscale = β) for γ's measurement.
@compute @workgroup_size(256)
fn norms(
    @builtin(global_invocation_id) gid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    let i = index(gid, nwg);
    var a = vec2<f32>(0.0);
    if (i < op.count) {
        let go = dl[i];
        let t = arena[op.src + i] + op.fscale * go;
        a = vec2<f32>(go * go, t * t);
    }
    let t = reduce(li, a);
    if (li == 0u) {
        acc_add(1u, i >> 8u, t.x);
        acc_add(2u, i >> 8u, t.y);
    }
}

// One invocation: γ's measurement (NORMALISE, as WdrLoss) and the loss value into word c of loss_acc
// (the session's scalar ring).
@compute @workgroup_size(1)
fn scalars() {
    // The sums d_WD, Σ(∇L_orig)², Σ(∇d_WD + β∇L_orig)²: their stripes, in order.
    for (var k = 0u; k < SUMS; k++) {
        var t = 0.0;
        for (var j = 0u; j < STRIPES; j++) {
            t += bitcast<f32>(atomicLoad(&acc[SUMS_AT + k * STRIPES + j]));
        }
        atomicStore(&acc[k], bitcast<u32>(t));
    }
    var gamma = accf(3u);
    if (has(NORMALISE) && accf(6u) < f32(NORMALISE_VIEWS)) {
        let no = sqrt(accf(1u));
        let nc = sqrt(accf(2u));
        if (nc > 0.0 && finite(no) && finite(nc)) {
            let s0 = accf(4u) + no;
            let s1 = accf(5u) + nc;
            gamma = s0 / s1;
            atomicStore(&acc[4u], bitcast<u32>(s0));
            atomicStore(&acc[5u], bitcast<u32>(s1));
            atomicStore(&acc[6u], bitcast<u32>(accf(6u) + 1.0));
            atomicStore(&acc[3u], bitcast<u32>(gamma));
        }
    }
    let v = accf(0u);
    var l = gamma * v;
    if (has(WDR)) {
        l = gamma * (v + op.fscale * bitcast<f32>(atomicLoad(&loss_acc[op.c])));
    }
    atomicStore(&loss_acc[op.c], bitcast<u32>(l));
}

// The training gradient into dl: γ·(∇d_WD + β·∇L_orig) (WDR) or γ·∇d_WD; src = ∇d_WD.
@compute @workgroup_size(256)
fn combine(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = index(gid, nwg);
    if (i >= op.count) {
        return;
    }
    let g = accf(3u);
    if (has(WDR)) {
        dl[i] = g * (arena[op.src + i] + op.fscale * dl[i]);
    } else {
        dl[i] = g * arena[op.src + i];
    }
}

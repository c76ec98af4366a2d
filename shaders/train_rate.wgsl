// The rate term of training on the GPU (prepended with common.wgsl). The oracle is
// gscodec::rate::term::RateTerm, whose docs give every formula; the density of each channel is
// gscodec::rate::model::LearnedChannel (a Laplace on quantisation bins), evaluated here in f32
// with the bin mass computed without cancellation (1 − e^{−x} by its series for small x).
//
// Per iteration, in this order:
// - `quantise`: the render records, learned groups rounded to their step (`quantised`;
//   straight-through: the image gradient computed at these values is applied to the raw ones);
// - `rate_reduce` (after the image backward, before the rate gradient is added): one workgroup
//   per channel sums over the Gaussians what the model and step updates need (Σ ∂bits/∂μ,
//   Σ ∂bits/∂ln b, Σ keep·bits, Σ keep·∂bits/∂s·s, and the LSQ term Σ ∂D/∂q·(Q(v/s) − v/s)·s);
//   one more workgroup sums the fixed bits Σ keep·FIXED_BITS;
// - `rate_grads`: per Gaussian, w·keep·∂bits/∂v into each learned value's gradient and
//   w·bits·∂keep/∂logit into the opacity gradient;
// - `rate_update`: R, w·R into the iteration's loss word, one normalised gradient step on each
//   channel's density, ∂(D + w·R)/∂ln s per group and one Adam step on the log steps.
//
// `state` (f32): [0..8) step per group (index = gscodec_decoder::Group), [8..16) and [16..24)
// Adam moments of the log steps, [24..32) ∂(D + w·R)/∂ln s of the last update, [32] bits of the
// last update, then (μ, ln b) per channel from [STATE_MODELS].

struct RateParams {
    n: u32,
    stride: u32,
    channels: u32,
    learn: u32,          // learn the steps
    weight: f32,         // w: loss units per bit
    logit_min: f32,      // logit of the pruning opacity
    step_size: f32,      // Adam: lr / (1 − β1^t)
    sqrt_bc2: f32,       // Adam: √(1 − β2^t)
    loss_word: u32,      // index of this iteration's loss in `loss`
    total: u32,          // n · stride
    learned: u32,        // bit mask of the learned groups
    fixed_bits: f32,     // bits per Gaussian the channels do not model
    bits_word: u32,      // index of this iteration's R in `loss`
    rest_deadzone: f32,  // dead zone of the SH rest bands, in steps (RateTerm::deadzone)
    _p1: u32,
    _p2: u32,
    start: array<vec4<f32>, 2>,   // starting step per group
    adam: vec4<f32>,     // β1, β2, ε, ln(step range)
}

@group(0) @binding(0) var<uniform> rp: RateParams;
@group(0) @binding(1) var<storage, read> params: array<f32>;
@group(0) @binding(2) var<storage, read_write> grads: array<f32>;
@group(0) @binding(3) var<storage, read_write> state: array<f32>;
@group(0) @binding(4) var<storage, read> chan: array<vec2<u32>>;      // (record offset, group) per channel
@group(0) @binding(5) var<storage, read_write> sums: array<f32>;      // SUMS per channel (+ the fixed bits)
@group(0) @binding(6) var<storage, read_write> render: array<f32>;
@group(0) @binding(7) var<storage, read_write> loss: array<f32>;        // the trainer's per-iteration scalars
@group(0) @binding(8) var<storage, read> qgroup: array<u32>;          // group of each record offset, or NONE

const STATE_BITS: u32 = 32u;
const STATE_MODELS: u32 = 40u;
const SUMS: u32 = 5u;
const NONE: u32 = 0xffffffffu;
const OPACITY: u32 = 10u;          // record offset of the opacity logit
const SH1: u32 = 5u;               // gscodec_decoder::Group::Sh1: the SH rest bands are 5..=7
const LIKELIHOOD_FLOOR: f32 = 1e-9;
const LN2: f32 = 0.6931472;

// The quantiser's integer of x = v/s for group g: Rust's f32::round (halves away from zero;
// WGSL's round() rounds halves to even), with the dead zone for the SH rest bands
// (gscodec::rate::quantise::q_dz: sign(x)·⌊max(|x| + ½ − dz, 0)⌋).
fn quantised(x: f32, g: u32) -> f32 {
    var dz = 0.0;
    if (g >= SH1) {
        dz = rp.rest_deadzone;
    }
    return sign(x) * floor(max(abs(x) + 0.5 - dz, 0.0));
}

fn keep_of(logit: f32) -> f32 {
    return 1.0 / (1.0 + exp(-((logit - rp.logit_min) / 0.5)));
}

// 1 − e^{−x} for x ≥ 0, accurate for small x.
fn one_minus_exp(x: f32) -> f32 {
    if (x < 0.1) {
        return x * (1.0 - x * (0.5 - x * (1.0 / 6.0 - x * (1.0 / 24.0 - x * (1.0 / 120.0 - x / 720.0)))));
    }
    return 1.0 - exp(-x);
}

struct Bits {
    bits: f32,
    d_value: f32,
    d_mu: f32,
    d_log_b: f32,
    d_step: f32,
}

// LearnedChannel::bits: bits of the bin [y − s/2, y + s/2] under Laplace(μ, b) and derivatives.
fn bits_of(y: f32, step: f32, mu: f32, log_b: f32) -> Bits {
    let b = exp(log_b);
    let hi = y + 0.5 * step;
    let lo = y - 0.5 * step;
    let zh = (hi - mu) / b;
    let zl = (lo - mu) / b;
    let eh = exp(-abs(zh));
    let el = exp(-abs(zl));
    let ph = 0.5 * eh / b;
    let pl = 0.5 * el / b;
    var p: f32;
    if (zl >= 0.0) {
        p = 0.5 * el * one_minus_exp(zh - zl);
    } else if (zh <= 0.0) {
        p = 0.5 * eh * one_minus_exp(zh - zl);
    } else {
        p = 0.5 * one_minus_exp(zh) + 0.5 * one_minus_exp(-zl);
    }
    if (!(p > LIKELIHOOD_FLOOR)) {
        return Bits(-log2(LIKELIHOOD_FLOOR), 0.0, 0.0, 0.0, 0.0);
    }
    let k = -1.0 / (p * LN2);
    let dp_dy = ph - pl;
    let dp_dlogb = -ph * (hi - mu) + pl * (lo - mu);
    return Bits(-log2(p), k * dp_dy, -k * dp_dy, k * dp_dlogb, k * 0.5 * (ph + pl));
}

fn start_step(g: u32) -> f32 {
    return rp.start[g / 4u][g % 4u];
}

@compute @workgroup_size(256)
fn quantise(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = gid.y * nwg.x * 256u + gid.x;
    if (i >= rp.total) {
        return;
    }
    let g = qgroup[i % rp.stride];
    var v = params[i];
    if (g != NONE) {
        let s = state[g];
        v = quantised(v / s, g) * s;
    }
    render[i] = v;
}

var<workgroup> red: array<array<f32, 256>, SUMS>;

@compute @workgroup_size(256)
fn rate_reduce(@builtin(local_invocation_index) li: u32, @builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let k = linear_wg(wid, nwg);
    var acc: array<f32, SUMS>;
    if (k < rp.channels) {
        let ch = chan[k];
        let s = state[ch.y];
        let mu = state[STATE_MODELS + 2u * k];
        let log_b = state[STATE_MODELS + 2u * k + 1u];
        for (var i = li; i < rp.n; i += 256u) {
            let base = i * rp.stride;
            let v = params[base + ch.x];
            let keep = keep_of(params[base + OPACITY]);
            let b = bits_of(v, s, mu, log_b);
            acc[0] += b.d_mu;
            acc[1] += b.d_log_b;
            acc[2] += keep * b.bits;
            acc[3] += keep * b.d_step * s;
            if (rp.learn != 0u) {
                let x = v / s;
                acc[4] += grads[base + ch.x] * ((quantised(x, ch.y) - x) * s);
            }
        }
    } else if (k == rp.channels) {
        for (var i = li; i < rp.n; i += 256u) {
            acc[2] += keep_of(params[i * rp.stride + OPACITY]) * rp.fixed_bits;
        }
    }
    for (var j = 0u; j < SUMS; j++) {
        red[j][li] = acc[j];
    }
    workgroupBarrier();
    for (var off = 128u; off > 0u; off = off >> 1u) {
        if (li < off) {
            for (var j = 0u; j < SUMS; j++) {
                red[j][li] += red[j][li + off];
            }
        }
        workgroupBarrier();
    }
    if (li == 0u && k <= rp.channels) {
        for (var j = 0u; j < SUMS; j++) {
            sums[k * SUMS + j] = red[j][0];
        }
    }
}

@compute @workgroup_size(256)
fn rate_grads(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = gid.y * nwg.x * 256u + gid.x;
    if (i >= rp.n) {
        return;
    }
    let base = i * rp.stride;
    let keep = keep_of(params[base + OPACITY]);
    var bits = rp.fixed_bits;
    for (var k = 0u; k < rp.channels; k++) {
        let ch = chan[k];
        let b = bits_of(params[base + ch.x], state[ch.y], state[STATE_MODELS + 2u * k], state[STATE_MODELS + 2u * k + 1u]);
        bits += b.bits;
        grads[base + ch.x] += rp.weight * keep * b.d_value;
    }
    let d_keep = keep * (1.0 - keep) / 0.5;
    grads[base + OPACITY] += rp.weight * bits * d_keep;
}

@compute @workgroup_size(1)
fn rate_update() {
    var total = sums[rp.channels * SUMS + 2u];
    var d_log_step: array<f32, 8>;
    let n = f32(max(rp.n, 1u));
    for (var k = 0u; k < rp.channels; k++) {
        let o = k * SUMS;
        total += sums[o + 2u];
        let g = chan[k].y;
        d_log_step[g] += sums[o + 4u] + rp.weight * sums[o + 3u];
        let m = STATE_MODELS + 2u * k;
        state[m] -= 0.1 * exp(state[m + 1u]) * sums[o] / n;
        state[m + 1u] -= 0.1 * sums[o + 1u] / n;
    }
    state[STATE_BITS] = total;
    loss[rp.loss_word] += rp.weight * total;
    loss[rp.bits_word] = total;
    for (var g = 0u; g < 8u; g++) {
        state[24u + g] = d_log_step[g];
        if (rp.learn == 0u || (rp.learned & (1u << g)) == 0u) {
            continue;
        }
        let b1 = rp.adam.x;
        let b2 = rp.adam.y;
        let gr = d_log_step[g];
        let m = b1 * state[8u + g] + (1.0 - b1) * gr;
        let v = b2 * state[16u + g] + (1.0 - b2) * gr * gr;
        state[8u + g] = m;
        state[16u + g] = v;
        let start = log(start_step(g));
        let log_s = log(state[g]) - rp.step_size * m / (sqrt(v) / rp.sqrt_bc2 + rp.adam.z);
        state[g] = exp(clamp(log_s, start - rp.adam.w, start + rp.adam.w));
    }
}

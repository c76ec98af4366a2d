// Adam over the flat parameter records (stride floats per Gaussian, groups by offset:
// position 0..3, log-scale 3..6, rotation 6..10, opacity 10, dc 11..14, rest 14..), with the
// CPU trainer's update `p -= lr/(1-β1^t) · m / (sqrt(v)/sqrt(1-β2^t) + ε)`
// (gscodec::train::adam::Adam::step), and the opacity reset. A non-finite gradient or value
// records its first flat index in `bad` (read back with the iteration's scalars).

struct AdamStep {
    s0: vec4<f32>,   // step sizes: position, scale, rotation, opacity
    s1: vec4<f32>,   // dc, rest, sqrt(1 - β2^t), β1
    s2: vec4<f32>,   // β2, ε, opacity cap, -
    u: vec4<u32>,    // total floats, stride, Gaussians, -
}

@group(0) @binding(0) var<uniform> st: AdamStep;
@group(0) @binding(1) var<storage, read_write> params: array<f32>;
@group(0) @binding(2) var<storage, read> grads: array<f32>;
@group(0) @binding(3) var<storage, read_write> m: array<f32>;
@group(0) @binding(4) var<storage, read_write> v: array<f32>;
@group(0) @binding(5) var<storage, read_write> bad: array<atomic<u32>>;   // [first bad gradient, first bad value]

@compute @workgroup_size(256)
fn adam(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = gid.y * nwg.x * 256u + gid.x;
    if (i >= st.u.x) {
        return;
    }
    let k = i % st.u.y;
    var lr = st.s1.y;
    if (k < 3u) {
        lr = st.s0.x;
    } else if (k < 6u) {
        lr = st.s0.y;
    } else if (k < 10u) {
        lr = st.s0.z;
    } else if (k == 10u) {
        lr = st.s0.w;
    } else if (k < 14u) {
        lr = st.s1.x;
    }
    let b1 = st.s1.w;
    let b2 = st.s2.x;
    let g = grads[i];
    if (!is_finite(g)) {
        atomicMin(&bad[0], i);
    }
    let mi = b1 * m[i] + (1.0 - b1) * g;
    let vi = b2 * v[i] + (1.0 - b2) * g * g;
    m[i] = mi;
    v[i] = vi;
    let p = params[i] - lr * mi / (sqrt(vi) / st.s1.z + st.s2.y);
    if (!is_finite(p)) {
        atomicMin(&bad[1], i);
    }
    params[i] = p;
}

@compute @workgroup_size(256)
fn reset_opacity(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = gid.y * nwg.x * 256u + gid.x;
    if (i >= st.u.z) {
        return;
    }
    let o = i * st.u.y + 10u;
    params[o] = min(params[o], st.s2.z);
    m[o] = 0.0;
    v[o] = 0.0;
}

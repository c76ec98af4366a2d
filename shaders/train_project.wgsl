// Projection / covariance / SH backward, one thread per Gaussian (prepended with common.wgsl):
// the screen-space gradient (9 per Gaussian, from train_raster.wgsl's backward) to the raw
// parameters through the EWA projection with its Jacobian clamp, the 3D covariance, the quaternion
// normalisation, the sigmoid and the SH colour with its clamp at 0. Formulas of
// gscodec::raster::backward (the CPU oracle). Also accumulates the densification statistics.
// Parameter records: [pos3, log_scale3, rot4 (wxyz), opacity_logit, dc3, rest 3K] (stride floats).

struct Bwd {
    n: u32,
    stats: u32,      // accumulate densification statistics
    r_scale: f32,    // radius → 800-pixel-image equivalent
    _p: u32,
}

@group(0) @binding(0) var<uniform> frame: Frame;
@group(0) @binding(1) var<uniform> bw: Bwd;
@group(0) @binding(2) var<storage, read> params: array<f32>;
@group(0) @binding(3) var<storage, read> projected: array<Projected>;
@group(0) @binding(4) var<storage, read> grad2d: array<f32>;
@group(0) @binding(5) var<storage, read_write> grads: array<f32>;
@group(0) @binding(6) var<storage, read_write> stats: array<f32>;   // 3 per Gaussian: Σ|dL/dmean2d| (NDC), count, max radius

const SH_C0: f32 = 0.2820948;
const SH_C1: f32 = 0.48860252;
const C2_0: f32 = 1.0925484;
const C2_1: f32 = -1.0925484;
const C2_2: f32 = 0.31539157;
const C2_3: f32 = -1.0925484;
const C2_4: f32 = 0.5462742;
const C3_0: f32 = -0.5900436;
const C3_1: f32 = 2.8906114;
const C3_2: f32 = -0.4570458;
const C3_3: f32 = 0.37317634;
const C3_4: f32 = -0.4570458;
const C3_5: f32 = 1.4453057;
const C3_6: f32 = -0.5900436;

fn p(base: u32, k: u32) -> f32 {
    return params[base + k];
}

fn normalize_quat(q: vec4<f32>) -> vec4<f32> {
    let n = sqrt(dot(q, q));
    if (n > 0.0 && is_finite(n)) {
        return q / n;
    }
    return vec4<f32>(1.0, 0.0, 0.0, 0.0);
}

fn rot_of(qn: vec4<f32>) -> mat3x3<f32> {
    let w = qn.x; let x = qn.y; let y = qn.z; let z = qn.w;
    return mat3x3<f32>(
        vec3<f32>(1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y)),
        vec3<f32>(2.0 * (x * y - w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z + w * x)),
        vec3<f32>(2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y)),
    );
}

fn sh_basis(degree: u32, d: vec3<f32>) -> array<f32, 16> {
    var b: array<f32, 16>;
    b[0] = SH_C0;
    if (degree == 0u) {
        return b;
    }
    let x = d.x; let y = d.y; let z = d.z;
    b[1] = -SH_C1 * y;
    b[2] = SH_C1 * z;
    b[3] = -SH_C1 * x;
    if (degree == 1u) {
        return b;
    }
    let xx = x * x; let yy = y * y; let zz = z * z;
    b[4] = C2_0 * x * y;
    b[5] = C2_1 * y * z;
    b[6] = C2_2 * (2.0 * zz - xx - yy);
    b[7] = C2_3 * x * z;
    b[8] = C2_4 * (xx - yy);
    if (degree == 2u) {
        return b;
    }
    b[9] = C3_0 * y * (3.0 * xx - yy);
    b[10] = C3_1 * x * y * z;
    b[11] = C3_2 * y * (4.0 * zz - xx - yy);
    b[12] = C3_3 * z * (2.0 * zz - 3.0 * xx - 3.0 * yy);
    b[13] = C3_4 * x * (4.0 * zz - xx - yy);
    b[14] = C3_5 * z * (xx - yy);
    b[15] = C3_6 * x * (xx - 3.0 * yy);
    return b;
}

// Σ_k g[k] · d(basis_k)/d(dir).
fn sh_basis_backward(degree: u32, d: vec3<f32>, g: array<f32, 16>) -> vec3<f32> {
    let x = d.x; let y = d.y; let z = d.z;
    var o = vec3<f32>(-SH_C1 * g[3], -SH_C1 * g[1], SH_C1 * g[2]);
    if (degree >= 2u) {
        o.x += C2_0 * y * g[4] - 2.0 * C2_2 * x * g[6] + C2_3 * z * g[7] + 2.0 * C2_4 * x * g[8];
        o.y += C2_0 * x * g[4] + C2_1 * z * g[5] - 2.0 * C2_2 * y * g[6] - 2.0 * C2_4 * y * g[8];
        o.z += C2_1 * y * g[5] + 4.0 * C2_2 * z * g[6] + C2_3 * x * g[7];
    }
    if (degree >= 3u) {
        let xx = x * x; let yy = y * y; let zz = z * z;
        o.x += C3_0 * 6.0 * x * y * g[9] + C3_1 * y * z * g[10] - C3_2 * 2.0 * x * y * g[11] - C3_3 * 6.0 * x * z * g[12]
            + C3_4 * (4.0 * zz - 3.0 * xx - yy) * g[13] + C3_5 * 2.0 * x * z * g[14] + C3_6 * 3.0 * (xx - yy) * g[15];
        o.y += C3_0 * 3.0 * (xx - yy) * g[9] + C3_1 * x * z * g[10] + C3_2 * (4.0 * zz - xx - 3.0 * yy) * g[11]
            - C3_3 * 6.0 * y * z * g[12] - C3_4 * 2.0 * x * y * g[13] - C3_5 * 2.0 * y * z * g[14] - C3_6 * 6.0 * x * y * g[15];
        o.z += C3_1 * x * y * g[10] + C3_2 * 8.0 * y * z * g[11] + C3_3 * (6.0 * zz - 3.0 * xx - 3.0 * yy) * g[12]
            + C3_4 * 8.0 * x * z * g[13] + C3_5 * (xx - yy) * g[14];
    }
    return o;
}

fn outer(u: vec3<f32>, v: vec3<f32>) -> mat3x3<f32> {
    return mat3x3<f32>(u * v.x, u * v.y, u * v.z);
}

@compute @workgroup_size(256)
fn project_backward(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = gid.y * nwg.x * 256u + gid.x;
    if (i >= bw.n) {
        return;
    }
    let base = i * frame.stride;
    for (var k = 0u; k < frame.stride; k++) {
        grads[base + k] = 0.0;
    }
    let pr = projected[i];
    if (!(pr.a.w > 0.0)) {
        return;
    }
    let gb = i * 9u;
    let g_mean = vec2<f32>(grad2d[gb], grad2d[gb + 1u]);
    let g_conic = vec3<f32>(grad2d[gb + 2u], grad2d[gb + 3u], grad2d[gb + 4u]);
    let g_op = grad2d[gb + 5u];
    let g_col = vec3<f32>(grad2d[gb + 6u], grad2d[gb + 7u], grad2d[gb + 8u]);

    if (bw.stats != 0u) {
        let hw = f32(frame.width) / 2.0;
        let hh = f32(frame.height) / 2.0;
        let norm = sqrt((g_mean.x * hw) * (g_mean.x * hw) + (g_mean.y * hh) * (g_mean.y * hh));
        stats[i * 3u] += norm;
        stats[i * 3u + 1u] += 1.0;
        stats[i * 3u + 2u] = max(stats[i * 3u + 2u], pr.a.w * bw.r_scale);
    }

    let pos = vec3<f32>(p(base, 0u), p(base, 1u), p(base, 2u));
    let rot = mat3x3<f32>(frame.rot0.xyz, frame.rot1.xyz, frame.rot2.xyz);
    let t = rot * pos + frame.trans.xyz;
    let fx = frame.focal.x;
    let fy = frame.focal.y;
    let iz = 1.0 / t.z;
    let iz2 = iz * iz;
    var dl_dt = vec3<f32>(g_mean.x * fx * iz, g_mean.y * fy * iz, -(g_mean.x * fx * t.x + g_mean.y * fy * t.y) * iz * iz);

    // 3D covariance and the dilated 2D covariance [a b; b c]
    let q = vec4<f32>(p(base, 6u), p(base, 7u), p(base, 8u), p(base, 9u));
    let qn = normalize_quat(q);
    let r = rot_of(qn);
    let s = exp(vec3<f32>(p(base, 3u), p(base, 4u), p(base, 5u)));
    let m = mat3x3<f32>(r[0] * s.x, r[1] * s.y, r[2] * s.z);
    let cov3d = m * transpose(m);
    let lim_x = 1.3 * (f32(frame.width) / (2.0 * fx));
    let lim_y = 1.3 * (f32(frame.height) / (2.0 * fy));
    let ux = t.x / t.z;
    let uy = t.y / t.z;
    let free_x = ux > -lim_x && ux < lim_x;
    let free_y = uy > -lim_y && uy < lim_y;
    let uxc = clamp(ux, -lim_x, lim_x);
    let uyc = clamp(uy, -lim_y, lim_y);
    let j0 = vec3<f32>(fx * iz, 0.0, -fx * (uxc * t.z) * iz2);
    let j1 = vec3<f32>(0.0, fy * iz, -fy * (uyc * t.z) * iz2);
    let wt = transpose(rot);
    let t0 = wt * j0;
    let t1 = wt * j1;
    let s_t0 = cov3d * t0;
    let s_t1 = cov3d * t1;
    let a = dot(t0, s_t0) + COV2D_DILATION;
    let b = dot(t0, s_t1);
    let c = dot(t1, s_t1) + COV2D_DILATION;
    // conic = inverse of [a b; b c]
    let det = a * c - b * b;
    let id = 1.0 / det;
    let id2 = id * id;
    let ga = g_conic.x; let gbb = g_conic.y; let gc = g_conic.z;
    let dl_da = ga * (-c * c * id2) + gbb * (b * c * id2) + gc * (-b * b * id2);
    let dl_db = ga * (2.0 * b * c * id2) + gbb * (-id - 2.0 * b * b * id2) + gc * (2.0 * a * b * id2);
    let dl_dc = ga * (-b * b * id2) + gbb * (a * b * id2) + gc * (-a * a * id2);

    let dl_dt0 = 2.0 * dl_da * s_t0 + dl_db * s_t1;
    let dl_dt1 = dl_db * s_t0 + 2.0 * dl_dc * s_t1;
    let dl_dj0 = rot * dl_dt0;
    let dl_dj1 = rot * dl_dt1;
    if (free_x) {
        dl_dt.x += dl_dj0.z * (-fx * iz2);
        dl_dt.z += dl_dj0.z * (fx * uxc * iz2 + fx * iz * t.x * iz2);
    } else {
        dl_dt.z += dl_dj0.z * (fx * uxc * iz2);
    }
    dl_dt.z += dl_dj0.x * (-fx * iz2);
    if (free_y) {
        dl_dt.y += dl_dj1.z * (-fy * iz2);
        dl_dt.z += dl_dj1.z * (fy * uyc * iz2 + fy * iz * t.y * iz2);
    } else {
        dl_dt.z += dl_dj1.z * (fy * uyc * iz2);
    }
    dl_dt.z += dl_dj1.y * (-fy * iz2);
    var dl_dpos = transpose(rot) * dl_dt;

    // Σ = M Mᵀ, M = R S: dL/dM = (G + Gᵀ) M
    let gs = outer(t0, t0) * (2.0 * dl_da) + (outer(t0, t1) + outer(t1, t0)) * dl_db + outer(t1, t1) * (2.0 * dl_dc);
    let dm = gs * m;
    grads[base + 3u] = dot(dm[0], r[0]) * s.x;
    grads[base + 4u] = dot(dm[1], r[1]) * s.y;
    grads[base + 5u] = dot(dm[2], r[2]) * s.z;
    let g0 = dm[0] * s.x;
    let g1 = dm[1] * s.y;
    let g2 = dm[2] * s.z;
    let nq = sqrt(dot(q, q));
    if (nq > 0.0 && is_finite(nq)) {
        let w = qn.x; let x = qn.y; let y = qn.z; let z = qn.w;
        let dq = vec4<f32>(
            2.0 * (z * g0.y - y * g0.z - z * g1.x + x * g1.z + y * g2.x - x * g2.y),
            2.0 * (y * g0.y + z * g0.z + y * g1.x - 2.0 * x * g1.y + w * g1.z + z * g2.x - w * g2.y - 2.0 * x * g2.z),
            2.0 * (-2.0 * y * g0.x + x * g0.y - w * g0.z + x * g1.x + z * g1.z + w * g2.x + z * g2.y - 2.0 * y * g2.z),
            2.0 * (-2.0 * z * g0.x + w * g0.y + x * g0.z - w * g1.x - 2.0 * z * g1.y + y * g1.z + x * g2.x + y * g2.y),
        );
        let gq = (dq - qn * dot(qn, dq)) / nq;
        grads[base + 6u] = gq.x;
        grads[base + 7u] = gq.y;
        grads[base + 8u] = gq.z;
        grads[base + 9u] = gq.w;
    }

    // opacity through the sigmoid
    grads[base + 10u] = g_op * pr.b.w * (1.0 - pr.b.w);

    // SH colour, clamped at 0, and through the view direction to the position
    let degree = frame.degree;
    let diff = pos - frame.center.xyz;
    let len = length(diff);
    var dir = vec3<f32>(0.0, 0.0, 1.0);
    let dir_ok = len > 0.0 && is_finite(len);
    if (dir_ok) {
        dir = diff / len;
    }
    let basis = sh_basis(degree, dir);
    let k_used = (degree + 1u) * (degree + 1u) - 1u;
    var v = basis[0] * vec3<f32>(p(base, 11u), p(base, 12u), p(base, 13u)) + vec3<f32>(0.5);
    for (var k = 0u; k < k_used; k++) {
        let o = base + 14u + 3u * k;
        v += basis[k + 1u] * vec3<f32>(params[o], params[o + 1u], params[o + 2u]);
    }
    let dcol = select(vec3<f32>(0.0), g_col, v >= vec3<f32>(0.0));
    grads[base + 11u] = basis[0] * dcol.x;
    grads[base + 12u] = basis[0] * dcol.y;
    grads[base + 13u] = basis[0] * dcol.z;
    var dl_dbasis: array<f32, 16>;
    for (var k = 0u; k < k_used; k++) {
        let o = base + 14u + 3u * k;
        grads[o] = basis[k + 1u] * dcol.x;
        grads[o + 1u] = basis[k + 1u] * dcol.y;
        grads[o + 2u] = basis[k + 1u] * dcol.z;
        dl_dbasis[k + 1u] = dot(vec3<f32>(params[o], params[o + 1u], params[o + 2u]), dcol);
    }
    if (degree > 0u && dir_ok) {
        let dl_ddir = sh_basis_backward(degree, dir, dl_dbasis);
        dl_dpos += (dl_ddir - dir * dot(dir, dl_ddir)) / len;
    }
    grads[base] = dl_dpos.x;
    grads[base + 1u] = dl_dpos.y;
    grads[base + 2u] = dl_dpos.z;
}

// Per-Gaussian preprocess: projection, 2D covariance, SH colour and tile count (one chunk of the
// scene per dispatch; input records are [pos3, log_scale3, rot4 (wxyz), opacity_logit, dc3, rest 3K]).

struct Chunk {
    base: u32,   // index of the chunk's first Gaussian in the scene
    count: u32,  // Gaussians in this chunk
    _p0: u32,
    _p1: u32,
}

@group(0) @binding(0) var<uniform> frame: Frame;
@group(0) @binding(1) var<uniform> chunk: Chunk;
@group(0) @binding(2) var<storage, read> records: array<f32>;
@group(0) @binding(3) var<storage, read_write> projected: array<Projected>;
@group(0) @binding(4) var<storage, read_write> tile_counts: array<u32>;

const SH_C0: f32 = 0.2820948;
const SH_C1: f32 = 0.48860252;

fn quat_to_mat3(q_in: vec4<f32>) -> mat3x3<f32> {
    // q_in = (w, x, y, z); normalise, zero -> identity (math::normalize_quat)
    let n = sqrt(dot(q_in, q_in));
    var q = vec4<f32>(1.0, 0.0, 0.0, 0.0);
    if (n > 0.0 && is_finite(n)) {
        q = q_in / n;
    }
    let w = q.x; let x = q.y; let y = q.z; let z = q.w;
    return mat3x3<f32>(
        vec3<f32>(1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y)),
        vec3<f32>(2.0 * (x * y - w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z + w * x)),
        vec3<f32>(2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y)),
    );
}

fn rec(base: u32, k: u32) -> f32 {
    return records[base + k];
}

fn sh_color(base: u32, dir: vec3<f32>, degree: u32) -> vec3<f32> {
    var col = SH_C0 * vec3<f32>(rec(base, 11u), rec(base, 12u), rec(base, 13u)) + vec3<f32>(0.5);
    if (degree == 0u) {
        return max(col, vec3<f32>(0.0));
    }
    var b: array<f32, 15>;
    let x = dir.x; let y = dir.y; let z = dir.z;
    b[0] = -SH_C1 * y;
    b[1] = SH_C1 * z;
    b[2] = -SH_C1 * x;
    var k = 3u;
    if (degree >= 2u) {
        let xx = x * x; let yy = y * y; let zz = z * z;
        let xy = x * y; let yz = y * z; let xz = x * z;
        b[3] = 1.0925484 * xy;
        b[4] = -1.0925484 * yz;
        b[5] = 0.31539157 * (2.0 * zz - xx - yy);
        b[6] = -1.0925484 * xz;
        b[7] = 0.5462742 * (xx - yy);
        k = 8u;
        if (degree >= 3u) {
            b[8] = -0.5900436 * y * (3.0 * xx - yy);
            b[9] = 2.8906114 * xy * z;
            b[10] = -0.4570458 * y * (4.0 * zz - xx - yy);
            b[11] = 0.37317634 * z * (2.0 * zz - 3.0 * xx - 3.0 * yy);
            b[12] = -0.4570458 * x * (4.0 * zz - xx - yy);
            b[13] = 1.4453057 * z * (xx - yy);
            b[14] = -0.5900436 * x * (xx - 3.0 * yy);
            k = 15u;
        }
    }
    for (var j = 0u; j < k; j++) {
        let o = base + 14u + 3u * j;
        col += b[j] * vec3<f32>(records[o], records[o + 1u], records[o + 2u]);
    }
    return max(col, vec3<f32>(0.0));
}

@compute @workgroup_size(256)
fn project(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let local_i = gid.y * nwg.x * 256u + gid.x;
    if (local_i >= chunk.count) {
        return;
    }
    let g = chunk.base + local_i;
    var out: Projected;
    out.a = vec4<f32>(0.0);
    out.b = vec4<f32>(0.0);
    out.c = vec4<f32>(0.0);
    projected[g] = out;
    tile_counts[g] = 0u;

    let base = local_i * frame.stride;
    let pos = vec3<f32>(rec(base, 0u), rec(base, 1u), rec(base, 2u));
    let rot = mat3x3<f32>(frame.rot0.xyz, frame.rot1.xyz, frame.rot2.xyz);
    let t = rot * pos + frame.trans.xyz;
    if (!(t.z > frame.znear)) {
        return;
    }
    // 3D covariance R S Sᵀ Rᵀ
    let r = quat_to_mat3(vec4<f32>(rec(base, 6u), rec(base, 7u), rec(base, 8u), rec(base, 9u)));
    let s = exp(vec3<f32>(rec(base, 3u), rec(base, 4u), rec(base, 5u)));
    let m = mat3x3<f32>(r[0] * s.x, r[1] * s.y, r[2] * s.z);
    let cov3d = m * transpose(m);
    // EWA projection (math::project_cov2d)
    let fx = frame.focal.x; let fy = frame.focal.y;
    let lim_x = 1.3 * (f32(frame.width) / (2.0 * fx));
    let lim_y = 1.3 * (f32(frame.height) / (2.0 * fy));
    let tx = clamp(t.x / t.z, -lim_x, lim_x) * t.z;
    let ty = clamp(t.y / t.z, -lim_y, lim_y) * t.z;
    let iz = 1.0 / t.z;
    let iz2 = 1.0 / (t.z * t.z);
    let j0 = vec3<f32>(fx * iz, 0.0, -fx * tx * iz2);
    let j1 = vec3<f32>(0.0, fy * iz, -fy * ty * iz2);
    let wt = transpose(rot);
    let t0 = wt * j0;
    let t1 = wt * j1;
    let ca = dot(t0, cov3d * t0) + COV2D_DILATION;
    let cb = dot(t0, cov3d * t1);
    let cc = dot(t1, cov3d * t1) + COV2D_DILATION;
    // conic and radius (math::conic_and_radius)
    let det = ca * cc - cb * cb;
    if (!(det > 0.0) || !is_finite(det)) {
        return;
    }
    let inv = 1.0 / det;
    let mid = 0.5 * (ca + cc);
    let lambda1 = mid + sqrt(max(mid * mid - det, 0.1));
    let radius = ceil(3.0 * sqrt(lambda1));
    if (!is_finite(radius)) {
        return;
    }
    let mean = vec2<f32>(fx * t.x / t.z + frame.focal.z, fy * t.y / t.z + frame.focal.w);
    if (!is_finite(mean.x) || !is_finite(mean.y)) {
        return;
    }
    let rect = tile_rect(mean, radius, frame);
    if (rect.z <= rect.x || rect.w <= rect.y) {
        return;
    }
    let d = pos - frame.center.xyz;
    let len = length(d);
    var dir = vec3<f32>(0.0, 0.0, 1.0);
    if (len > 0.0 && is_finite(len)) {
        dir = d / len;
    }
    let color = sh_color(base, dir, frame.degree);
    let opacity = 1.0 / (1.0 + exp(-rec(base, 10u)));
    out.a = vec4<f32>(mean, t.z, radius);
    out.b = vec4<f32>(cc * inv, -cb * inv, ca * inv, opacity);
    out.c = vec4<f32>(color, 0.0);
    projected[g] = out;
    tile_counts[g] = (rect.z - rect.x) * (rect.w - rect.y);
}

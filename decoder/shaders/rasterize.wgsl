// Per-tile ranges of the sorted key list, and the tile rasterizer: one 16x16 workgroup per tile,
// Gaussians staged through workgroup memory in batches, front-to-back compositing per pixel with
// the semantics of gscodec_decoder::render::render (alpha = min(0.99, o·exp(power)), skip
// alpha < 1/255, stop before transmittance drops below 1e-4).

struct RangeParams {
    n: u32,          // keys the buffers hold (an upper bound)
    count_at: u32,   // the number of sorted keys is min(n, range_count[count_at])
    _p1: u32,
    _p2: u32,
}

@group(0) @binding(0) var<uniform> frame: Frame;
@group(0) @binding(1) var<uniform> rp: RangeParams;
@group(0) @binding(2) var<storage, read> key_tile: array<u32>;
@group(0) @binding(3) var<storage, read> key_id: array<u32>;
@group(0) @binding(4) var<storage, read_write> ranges: array<vec2<u32>>;
@group(0) @binding(5) var<storage, read> projected: array<Projected>;
@group(0) @binding(6) var<storage, read_write> image: array<f32>;
@group(0) @binding(7) var<storage, read> range_count: array<u32>;

@compute @workgroup_size(256)
fn tile_ranges(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = gid.y * nwg.x * 256u + gid.x;
    let n = min(rp.n, range_count[rp.count_at]);
    if (i >= n) {
        return;
    }
    let t = key_tile[i];
    if (i == 0u || key_tile[i - 1u] != t) {
        ranges[t].x = i;
    }
    if (i + 1u == n || key_tile[i + 1u] != t) {
        ranges[t].y = i + 1u;
    }
}

var<workgroup> batch_a: array<vec4<f32>, 256>;
var<workgroup> batch_b: array<vec4<f32>, 256>;
var<workgroup> batch_c: array<vec4<f32>, 256>;
var<workgroup> done_count: atomic<u32>;
var<workgroup> wg_range: vec2<u32>;
var<workgroup> wg_done: u32;

@compute @workgroup_size(16, 16)
fn rasterize(@builtin(local_invocation_index) li: u32, @builtin(local_invocation_id) lid: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>) {
    let tile = wid.y * frame.tiles_x + wid.x;
    let px = wid.x * TILE + lid.x;
    let py = wid.y * TILE + lid.y;
    let inside = px < frame.width && py < frame.height;
    let fx = f32(px);
    let fy = f32(py);
    var c = vec3<f32>(0.0);
    var t = 1.0;
    var done = !inside;
    if (li == 0u) {
        atomicStore(&done_count, 0u);
        wg_range = ranges[tile];
    }
    workgroupBarrier();
    if (done) {
        atomicAdd(&done_count, 1u);
    }
    // Uniform copies (every thread sees the same values) so the barriers below stay uniform.
    let range = workgroupUniformLoad(&wg_range);
    var start = range.x;
    loop {
        workgroupBarrier();
        if (li == 0u) {
            wg_done = atomicLoad(&done_count);
        }
        let finished = workgroupUniformLoad(&wg_done);
        if (start >= range.y || finished == 256u) {
            break;
        }
        // stage up to 256 Gaussians
        let k = start + li;
        if (k < range.y) {
            let p = projected[key_id[k]];
            batch_a[li] = p.a;
            batch_b[li] = p.b;
            batch_c[li] = p.c;
        }
        workgroupBarrier();
        let count = min(256u, range.y - start);
        if (!done) {
            for (var j = 0u; j < count; j++) {
                let a = batch_a[j];
                let b = batch_b[j];
                let dx = a.x - 0.5 - fx;
                let dy = a.y - 0.5 - fy;
                let power = -0.5 * (b.x * dx * dx + b.z * dy * dy) - b.y * dx * dy;
                if (power > 0.0) {
                    continue;
                }
                let alpha = min(MAX_ALPHA, b.w * exp(power));
                if (alpha < MIN_ALPHA) {
                    continue;
                }
                let next_t = t * (1.0 - alpha);
                if (next_t < MIN_TRANSMITTANCE) {
                    done = true;
                    atomicAdd(&done_count, 1u);
                    break;
                }
                c += batch_c[j].xyz * alpha * t;
                t = next_t;
            }
        }
        start += 256u;
    }
    if (inside) {
        let o = (py * frame.width + px) * 3u;
        let rgb = c + t * frame.background.xyz;
        image[o] = rgb.x;
        image[o + 1u] = rgb.y;
        image[o + 2u] = rgb.z;
    }
}

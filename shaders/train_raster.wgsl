// Training rasterizer (prepended with common.wgsl and, when the adapter has subgroups, with
// `enable subgroups;` and SUBGROUPS = true). Semantics of gscodec::raster (CPU oracle):
// `forward` composites front to back exactly like the decoder's `rasterize` and also saves, per
// pixel, the final transmittance and the end of the visited part of its tile list; `backward`
// walks each pixel's list back to front from there, recovering transmittances by division.
//
// Backward reduction: a tile's Gaussians are processed in batches of BATCH staged in workgroup
// memory; per Gaussian, every pixel's contribution is summed over the subgroup (subgroupAdd, when
// available) and added into a workgroup-memory accumulator (float add by compare-exchange on the
// u32 bit pattern); after the batch, one global atomic add per gradient component per Gaussian.

@group(0) @binding(0) var<uniform> frame: Frame;
@group(0) @binding(1) var<storage, read> ranges: array<vec2<u32>>;
@group(0) @binding(2) var<storage, read> key_id: array<u32>;
@group(0) @binding(3) var<storage, read> projected: array<Projected>;
@group(0) @binding(4) var<storage, read_write> image: array<f32>;      // forward: out (RGB); backward: dL/dpixel
@group(0) @binding(5) var<storage, read_write> final_t: array<f32>;
@group(0) @binding(6) var<storage, read_write> last: array<u32>;       // end of the visited list entries
@group(0) @binding(7) var<storage, read_write> grad2d: array<atomic<u32>>; // 9 per Gaussian (backward)

const BATCH: u32 = 128u;
// Components of a screen-space gradient: mean x, y; conic A, B, C; opacity; colour r, g, b.
const G2: u32 = 9u;

var<workgroup> sh_a: array<vec4<f32>, BATCH>;   // mean.x - 0.5, mean.y - 0.5, opacity, -
var<workgroup> sh_b: array<vec4<f32>, BATCH>;   // conic A, B, C, -
var<workgroup> sh_c: array<vec4<f32>, BATCH>;   // colour
var<workgroup> sh_id: array<u32, BATCH>;
var<workgroup> acc: array<atomic<u32>, 1152>;  // BATCH * G2
var<workgroup> wg_range: vec2<u32>;
var<workgroup> wg_count: atomic<u32>;
var<workgroup> wg_u32: u32;

fn wg_add(i: u32, v: f32) {
    var old = atomicLoad(&acc[i]);
    loop {
        let r = atomicCompareExchangeWeak(&acc[i], old, bitcast<u32>(bitcast<f32>(old) + v));
        if (r.exchanged) {
            break;
        }
        old = r.old_value;
    }
}

fn global_add(i: u32, v: f32) {
    var old = atomicLoad(&grad2d[i]);
    loop {
        let r = atomicCompareExchangeWeak(&grad2d[i], old, bitcast<u32>(bitcast<f32>(old) + v));
        if (r.exchanged) {
            break;
        }
        old = r.old_value;
    }
}

// One 256-thread workgroup per 16×16 tile (1-D, as subgroup builtins require).
@compute @workgroup_size(256)
fn forward(@builtin(local_invocation_index) li: u32, @builtin(workgroup_id) wid: vec3<u32>) {
    let lid = vec2<u32>(li % TILE, li / TILE);
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
        atomicStore(&wg_count, 0u);
        wg_range = ranges[tile];
    }
    workgroupBarrier();
    if (done) {
        atomicAdd(&wg_count, 1u);
    }
    let range = workgroupUniformLoad(&wg_range);
    var end = range.y;
    var start = range.x;
    loop {
        workgroupBarrier();
        if (li == 0u) {
            wg_u32 = atomicLoad(&wg_count);
        }
        let finished = workgroupUniformLoad(&wg_u32);
        if (start >= range.y || finished == 256u) {
            break;
        }
        let k = start + li;
        if (li < BATCH && k < range.y) {
            let p = projected[key_id[k]];
            sh_a[li] = vec4<f32>(p.a.x - 0.5, p.a.y - 0.5, p.b.w, 0.0);
            sh_b[li] = vec4<f32>(p.b.xyz, 0.0);
            sh_c[li] = p.c;
        }
        workgroupBarrier();
        let count = min(BATCH, range.y - start);
        if (!done) {
            for (var j = 0u; j < count; j++) {
                let a = sh_a[j];
                let b = sh_b[j];
                let dx = a.x - fx;
                let dy = a.y - fy;
                let power = -0.5 * (b.x * dx * dx + b.z * dy * dy) - b.y * dx * dy;
                if (power > 0.0) {
                    continue;
                }
                let alpha = min(MAX_ALPHA, a.z * exp(power));
                if (alpha < MIN_ALPHA) {
                    continue;
                }
                let next_t = t * (1.0 - alpha);
                if (next_t < MIN_TRANSMITTANCE) {
                    done = true;
                    end = start + j;
                    atomicAdd(&wg_count, 1u);
                    break;
                }
                c += sh_c[j].xyz * alpha * t;
                t = next_t;
            }
        }
        start += BATCH;
    }
    if (inside) {
        let p = py * frame.width + px;
        let rgb = c + t * frame.background.xyz;
        image[p * 3u] = rgb.x;
        image[p * 3u + 1u] = rgb.y;
        image[p * 3u + 2u] = rgb.z;
        final_t[p] = t;
        last[p] = end;
    }
}

@compute @workgroup_size(256)
fn backward(@builtin(local_invocation_index) li: u32, @builtin(workgroup_id) wid: vec3<u32>SUBGROUP_ARGS) {
    let lid = vec2<u32>(li % TILE, li / TILE);
    let tile = wid.y * frame.tiles_x + wid.x;
    let px = wid.x * TILE + lid.x;
    let py = wid.y * TILE + lid.y;
    let inside = px < frame.width && py < frame.height;
    let fx = f32(px);
    let fy = f32(py);
    var end = 0u;
    var t = 1.0;
    var t_final = 1.0;
    var dl = vec3<f32>(0.0);
    if (li == 0u) {
        atomicStore(&wg_count, 0u);
        wg_range = ranges[tile];
    }
    workgroupBarrier();
    let range = workgroupUniformLoad(&wg_range);
    if (inside) {
        let p = py * frame.width + px;
        end = last[p];
        t_final = final_t[p];
        t = t_final;
        dl = vec3<f32>(image[p * 3u], image[p * 3u + 1u], image[p * 3u + 2u]);
        atomicMax(&wg_count, end);
    }
    let bg_dot = dot(frame.background.xyz, dl);
    workgroupBarrier();
    if (li == 0u) {
        wg_u32 = atomicLoad(&wg_count);
    }
    // No pixel visited entries at or past the largest end.
    let max_end = workgroupUniformLoad(&wg_u32);
    var accum = vec3<f32>(0.0);
    var last_alpha = 0.0;
    var last_color = vec3<f32>(0.0);
    var hi = min(range.y, max_end);
    loop {
        if (hi <= range.x) {
            break;
        }
        let lo = max(range.x, select(0u, hi - BATCH, hi >= BATCH));
        let count = hi - lo;
        // stage entries lo..hi, and clear the accumulators
        if (li < count) {
            let id = key_id[lo + li];
            let p = projected[id];
            sh_a[li] = vec4<f32>(p.a.x - 0.5, p.a.y - 0.5, p.b.w, 0.0);
            sh_b[li] = vec4<f32>(p.b.xyz, 0.0);
            sh_c[li] = p.c;
            sh_id[li] = id;
        }
        for (var k = li; k < BATCH * G2; k += 256u) {
            atomicStore(&acc[k], 0u);
        }
        workgroupBarrier();
        for (var jj = 0u; jj < count; jj++) {
            let j = count - 1u - jj;
            var g_mean = vec2<f32>(0.0);
            var g_conic = vec3<f32>(0.0);
            var g_op = 0.0;
            var g_col = vec3<f32>(0.0);
            var hit = false;
            if (lo + j < end) {
                let a = sh_a[j];
                let b = sh_b[j];
                let dx = a.x - fx;
                let dy = a.y - fy;
                let power = -0.5 * (b.x * dx * dx + b.z * dy * dy) - b.y * dx * dy;
                let gauss = exp(power);
                let raw = a.z * gauss;
                let alpha = min(MAX_ALPHA, raw);
                if (power <= 0.0 && alpha >= MIN_ALPHA) {
                    hit = true;
                    let one_minus = 1.0 - alpha;
                    t = t / one_minus;
                    let weight = alpha * t;
                    g_col = weight * dl;
                    accum = last_alpha * last_color + (1.0 - last_alpha) * accum;
                    last_alpha = alpha;
                    last_color = sh_c[j].xyz;
                    let dl_dalpha = dot(sh_c[j].xyz - accum, dl) * t - t_final / one_minus * bg_dot;
                    if (raw <= MAX_ALPHA) {
                        g_op = gauss * dl_dalpha;
                        let dl_dpower = a.z * gauss * dl_dalpha;
                        g_mean = dl_dpower * vec2<f32>(-b.x * dx - b.y * dy, -b.z * dy - b.y * dx);
                        g_conic = dl_dpower * vec3<f32>(-0.5 * dx * dx, -dx * dy, -0.5 * dy * dy);
                    }
                }
            }
            ACCUMULATE
        }
        workgroupBarrier();
        // one global atomic add per component per Gaussian of the batch
        for (var k = li; k < count * G2; k += 256u) {
            let v = bitcast<f32>(atomicLoad(&acc[k]));
            if (v != 0.0) {
                global_add(sh_id[k / G2] * G2 + k % G2, v);
            }
        }
        workgroupBarrier();
        hi = lo;
    }
}

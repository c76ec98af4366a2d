// Stable LSD radix sort of (tile, depth, id) triples, 4 bits per pass, using workgroup-shared
// prefix sums only. `radix_count` histograms each 1024-key block into counts[digit * blocks + block];
// after an exclusive scan of `counts`, `radix_scatter` ranks every key within its block (thread
// order, then item order: stable) and writes it to its final place. The number of keys sorted is
// min(n, counts[16 · blocks]): the host copies it there from a GPU buffer (the renderer's scan
// total, the trainer's clamped pair count), so it need not be read back.

struct SortParams {
    n: u32,        // keys the buffers hold (an upper bound)
    shift: u32,    // bit offset of the digit
    word: u32,     // 0 = depth word, 1 = tile word
    blocks: u32,   // number of 1024-key blocks
}

@group(0) @binding(0) var<uniform> sp: SortParams;
@group(0) @binding(1) var<storage, read> src_tile: array<u32>;
@group(0) @binding(2) var<storage, read> src_depth: array<u32>;
@group(0) @binding(3) var<storage, read> src_id: array<u32>;
@group(0) @binding(4) var<storage, read_write> counts: array<u32>;
@group(0) @binding(5) var<storage, read_write> dst_tile: array<u32>;
@group(0) @binding(6) var<storage, read_write> dst_depth: array<u32>;
@group(0) @binding(7) var<storage, read_write> dst_id: array<u32>;

const SORT_WG: u32 = 128u;
const SORT_ITEMS: u32 = 8u;
const RADIX: u32 = 16u;

var<workgroup> hist: array<atomic<u32>, 16>;
var<workgroup> ranks: array<u32, 2048>;   // [digit * SORT_WG + thread]
var<workgroup> thread_sums: array<u32, 128>;
var<workgroup> digit_start: array<u32, 16>;

fn digit_of(i: u32) -> u32 {
    if (i >= min(sp.n, counts[sp.blocks * RADIX])) {
        return RADIX;
    }
    var k = src_depth[i];
    if (sp.word == 1u) {
        k = src_tile[i];
    }
    return (k >> sp.shift) & (RADIX - 1u);
}

@compute @workgroup_size(128)
fn radix_count(@builtin(local_invocation_id) lid: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let block = linear_wg(wid, nwg);
    if (lid.x < RADIX) {
        atomicStore(&hist[lid.x], 0u);
    }
    workgroupBarrier();
    let start = block * SORT_WG * SORT_ITEMS + lid.x * SORT_ITEMS;
    for (var j = 0u; j < SORT_ITEMS; j++) {
        let d = digit_of(start + j);
        if (d < RADIX) {
            atomicAdd(&hist[d], 1u);
        }
    }
    workgroupBarrier();
    if (lid.x < RADIX && block < sp.blocks) {
        counts[lid.x * sp.blocks + block] = atomicLoad(&hist[lid.x]);
    }
}

@compute @workgroup_size(128)
fn radix_scatter(@builtin(local_invocation_id) lid: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let block = linear_wg(wid, nwg);
    let t = lid.x;
    let start = block * SORT_WG * SORT_ITEMS + t * SORT_ITEMS;
    var digits: array<u32, 8>;
    var local: array<u32, 16>;
    for (var d = 0u; d < RADIX; d++) {
        local[d] = 0u;
    }
    for (var j = 0u; j < SORT_ITEMS; j++) {
        let d = digit_of(start + j);
        digits[j] = d;
        if (d < RADIX) {
            local[d] += 1u;
        }
    }
    for (var d = 0u; d < RADIX; d++) {
        ranks[d * SORT_WG + t] = local[d];
    }
    workgroupBarrier();
    // Exclusive scan of the flat 2048-entry array: each thread scans 16 consecutive entries,
    // then a Hillis–Steele scan over the 128 thread totals.
    var run: array<u32, 16>;
    var total = 0u;
    for (var j = 0u; j < 16u; j++) {
        run[j] = total;
        total += ranks[t * 16u + j];
    }
    thread_sums[t] = total;
    workgroupBarrier();
    for (var off = 1u; off < SORT_WG; off = off << 1u) {
        var add = 0u;
        if (t >= off) {
            add = thread_sums[t - off];
        }
        workgroupBarrier();
        thread_sums[t] += add;
        workgroupBarrier();
    }
    let before = thread_sums[t] - total;
    workgroupBarrier();
    for (var j = 0u; j < 16u; j++) {
        ranks[t * 16u + j] = before + run[j];
    }
    workgroupBarrier();
    if (t < RADIX) {
        digit_start[t] = ranks[t * SORT_WG];
    }
    workgroupBarrier();
    // ranks[d * SORT_WG + t] - digit_start[d] = keys of digit d in threads < t; `local` now
    // counts this thread's own earlier keys of each digit.
    for (var d = 0u; d < RADIX; d++) {
        local[d] = 0u;
    }
    for (var j = 0u; j < SORT_ITEMS; j++) {
        let d = digits[j];
        if (d < RADIX) {
            let within = ranks[d * SORT_WG + t] - digit_start[d] + local[d];
            local[d] += 1u;
            let dst = counts[d * sp.blocks + block] + within;
            let i = start + j;
            dst_tile[dst] = src_tile[i];
            dst_depth[dst] = src_depth[i];
            dst_id[dst] = src_id[i];
        }
    }
}

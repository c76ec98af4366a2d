// Exclusive prefix sum in workgroup-shared memory (no subgroup operations): `scan_blocks` scans
// each 1024-element block in place and writes the block total to `sums`; after `sums` itself is
// scanned (recursively), `scan_add` adds each block's offset back.

struct ScanParams {
    n: u32,
    _p0: u32,
    _p1: u32,
    _p2: u32,
}

@group(0) @binding(0) var<uniform> params: ScanParams;
@group(0) @binding(1) var<storage, read_write> data: array<u32>;
@group(0) @binding(2) var<storage, read_write> sums: array<u32>;

const SCAN_WG: u32 = 256u;
const SCAN_ITEMS: u32 = 4u;
var<workgroup> partial: array<u32, 256>;

@compute @workgroup_size(256)
fn scan_blocks(@builtin(local_invocation_id) lid: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let block = linear_wg(wid, nwg);
    let start = block * SCAN_WG * SCAN_ITEMS + lid.x * SCAN_ITEMS;
    var v: array<u32, 4>;
    var total = 0u;
    for (var j = 0u; j < SCAN_ITEMS; j++) {
        var x = 0u;
        if (start + j < params.n) {
            x = data[start + j];
        }
        v[j] = total;
        total += x;
    }
    partial[lid.x] = total;
    workgroupBarrier();
    // Hillis–Steele inclusive scan of the per-thread totals.
    for (var off = 1u; off < SCAN_WG; off = off << 1u) {
        var add = 0u;
        if (lid.x >= off) {
            add = partial[lid.x - off];
        }
        workgroupBarrier();
        partial[lid.x] += add;
        workgroupBarrier();
    }
    let before = partial[lid.x] - total;
    for (var j = 0u; j < SCAN_ITEMS; j++) {
        if (start + j < params.n) {
            data[start + j] = before + v[j];
        }
    }
    if (lid.x == SCAN_WG - 1u && block * SCAN_WG * SCAN_ITEMS < params.n) {
        sums[block] = partial[lid.x];
    }
}

@compute @workgroup_size(256)
fn scan_add(@builtin(local_invocation_id) lid: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let block = linear_wg(wid, nwg);
    let start = block * SCAN_WG * SCAN_ITEMS + lid.x * SCAN_ITEMS;
    let add = sums[block];
    for (var j = 0u; j < SCAN_ITEMS; j++) {
        if (start + j < params.n) {
            data[start + j] += add;
        }
    }
}

// Writes one (tile, depth) key per tile a Gaussian overlaps, at its exclusive-scan offset, so the
// key list is in Gaussian order (the stable sort then breaks depth ties by index, like the CPU).
// Keys past the end of the key buffers are dropped (the trainer's buffers have a capacity that the
// host grows from counts it reads every few iterations; the renderer's are exact).

@group(0) @binding(0) var<uniform> frame: Frame;
@group(0) @binding(1) var<storage, read> projected: array<Projected>;
@group(0) @binding(2) var<storage, read> offsets: array<u32>;
@group(0) @binding(3) var<storage, read_write> key_tile: array<u32>;
@group(0) @binding(4) var<storage, read_write> key_depth: array<u32>;
@group(0) @binding(5) var<storage, read_write> key_id: array<u32>;

@compute @workgroup_size(256)
fn emit(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let g = gid.y * nwg.x * 256u + gid.x;
    if (g >= frame.n) {
        return;
    }
    let p = projected[g];
    if (!(p.a.w > 0.0)) {
        return;
    }
    let rect = tile_rect(p.a.xy, p.a.w, frame);
    var o = offsets[g];
    let cap = arrayLength(&key_tile);
    // depth > znear > 0, so the float bits order like the values
    let depth_bits = bitcast<u32>(p.a.z);
    for (var ty = rect.y; ty < rect.w && o < cap; ty++) {
        for (var tx = rect.x; tx < rect.z && o < cap; tx++) {
            key_tile[o] = ty * frame.tiles_x + tx;
            key_depth[o] = depth_bits;
            key_id[o] = g;
            o++;
        }
    }
}

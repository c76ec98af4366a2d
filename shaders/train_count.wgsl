// After the projection's scan (prepended with common.wgsl): the number of (tile, Gaussian) pairs,
// clamped to what the key buffers hold, for the sort and the tile ranges, which read it from the
// GPU (so the host never waits for it); their indirect dispatch sizes; and the unclamped total
// into the iteration's scalar slot, which the host reads every few iterations to grow the key
// buffers (a frame with more pairs than they hold renders the pairs that fit, in Gaussian order).

struct CountParams {
    n: u32,           // Gaussians: the scan left the total at counts[n]
    cap: u32,         // keys the key buffers hold
    pairs_word: u32,  // index of this iteration's pair count in `scalars`
    _p: u32,
}

@group(0) @binding(0) var<uniform> cp: CountParams;
@group(0) @binding(1) var<storage, read> counts: array<u32>;
@group(0) @binding(2) var<storage, read_write> sort_n: array<u32>;   // [pairs to sort]
@group(0) @binding(3) var<storage, read_write> args: array<u32>;     // indirect sizes: sort blocks (3), tile-range groups (3)
@group(0) @binding(4) var<storage, read_write> scalars: array<u32>;

const MAX_GROUPS: u32 = 65535u;

// `groups` workgroups as (x, y, 1) with x ≤ 65535, like the host's `dims`.
fn write_dims(at: u32, groups: u32) {
    if (groups <= MAX_GROUPS) {
        args[at] = groups;
        args[at + 1u] = 1u;
    } else {
        args[at] = MAX_GROUPS;
        args[at + 1u] = (groups + MAX_GROUPS - 1u) / MAX_GROUPS;
    }
    args[at + 2u] = 1u;
}

@compute @workgroup_size(1)
fn count_pairs() {
    let total = counts[cp.n];
    let pairs = min(total, cp.cap);
    sort_n[0] = pairs;
    write_dims(0u, (pairs + 1023u) / 1024u);
    write_dims(3u, (pairs + 255u) / 256u);
    scalars[cp.pairs_word] = total;
}

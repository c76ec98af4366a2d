#!/usr/bin/env python3
"""Would the SH codebook indices (SPEC §3.2) code cheaper with more context? (docs/codec.md §24)

For an 8.0 file whose SH bands are coded by codebooks, per band: the order-0 entropy of the
index (bits per Gaussian), the cost with a move-to-front cache of the last K distinct indices
(the cache position or an escape, then the index), and the cost conditioned on which earlier
bands took their most frequent row (the zero row: a band the search dropped), chained over the
bands in decode order. Ideal code lengths, no table costs.

    python3 scripts/probes/vq_index_contexts.py FILE.gsc
"""
import collections
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "..", "bitstream-spec"))
import specdec as S  # noqa: E402


def entropy(counts):
    c = np.array([v for v in counts.values() if v > 0], dtype=float)
    return float(-(c * np.log2(c / c.sum())).sum())


def entropy_given(x, ctx):
    return sum(entropy(collections.Counter(x[ctx == c].tolist())) for c in np.unique(ctx))


def move_to_front_bits(idx, k):
    recent, positions, escaped = [], collections.Counter(), collections.Counter()
    for v in idx.tolist():
        if v in recent:
            i = recent.index(v)
            positions[i] += 1
            recent.pop(i)
        else:
            positions["escape"] += 1
            escaped[v] += 1
            if len(recent) == k:
                recent.pop()
        recent.insert(0, v)
    return entropy(positions) + entropy(escaped)


def main():
    data = open(sys.argv[1], "rb").read()
    major, n, degree, sections = S.parse_container(data)
    known, groups, sizes, params_of = S.classify_sections(major, n, degree, sections)
    nb = major == S.NEIGHBOUR_MAJOR
    idx = {}
    for g in range(5, 5 + degree):
        band = g - 4
        if (S.KIND_CODEBOOK, band) not in known:
            continue
        parts = []
        for chunk, k in enumerate(sizes):
            params = S.parse_group_params(g, known[(0x10 + g, params_of[chunk])], 1, nb)
            parts.append(S.decode_channels(known.get((0x20 + g, chunk), b""), k, params, "data")[:, 0].astype(np.int64))
        idx[band] = np.concatenate(parts)
    if not idx:
        print("no band is coded by a codebook")
        return
    chain, ctx = 0.0, np.zeros(n, dtype=np.int64)
    for band in sorted(idx):
        x = idx[band]
        h0 = entropy(collections.Counter(x.tolist())) / n
        mtf = " ".join(f"{k}: {move_to_front_bits(x, k) / n:.3f}" for k in (1, 4, 16))
        given = entropy_given(x, ctx) / n
        chain += given
        top = np.bincount(x).argmax()
        print(f"band {band}: {x.max() + 1} rows, order-0 {h0:.3f} b/G; move-to-front {mtf}; given the earlier bands' zero rows {given:.3f}")
        ctx = ctx * 2 + (x == top)
    total = sum(entropy(collections.Counter(idx[b].tolist())) for b in idx) / n
    print(f"all bands: order-0 {total:.3f} b/G, chained {chain:.3f} b/G")


if __name__ == "__main__":
    main()

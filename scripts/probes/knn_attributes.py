#!/usr/bin/env python3
"""Attribute prediction probe (docs/codec.md §18): would predicting a Gaussian's attributes from
its nearest already-decoded neighbours in space pay, beside the previous Gaussian in Morton order?

For one chunk of an 8.0 file, per coded channel (integer values as the file holds them): the
order-0 entropy of the values (H0), of the difference from the previous value in file order
(prev-diff), and of the difference from the median of the 1, 4 or 8 nearest earlier Gaussians
(Euclidean distance on the integer position grid; only Gaussians before it in the file, as a
decoder would have them). Empirical entropies in bits per value, no table costs.

    python3 scripts/probes/knn_attributes.py FILE.gsc [CHUNK]
"""
import collections
import math
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "..", "bitstream-spec"))
import specdec as S  # noqa: E402

NAMES = {1: "scale", 2: "rotation", 3: "opacity", 4: "sh_dc", 5: "sh_band1", 6: "sh_band2", 7: "sh_band3"}


def entropy(values):
    c = collections.Counter(values)
    n = len(values)
    return -sum(v / n * math.log2(v / n) for v in c.values())


def main():
    data = open(sys.argv[1], "rb").read()
    chunk = int(sys.argv[2]) if len(sys.argv) > 2 else 0
    major, n, degree, sections = S.parse_container(data)
    known, groups, sizes, params_of = S.classify_sections(major, n, degree, sections)
    nb = major == S.NEIGHBOUR_MAJOR
    books = {g: S.parse_codebook(g, known[(S.KIND_CODEBOOK, g - 4)], n, nb) for g in range(5, groups) if (S.KIND_CODEBOOK, g - 4) in known}
    p = params_of[chunk]
    _, _, bits, ltable = S.parse_position_params(known[(0x10, p)])
    params = {g: S.parse_group_params(g, known[(0x10 + g, p)], 1 if g in books else None, nb) for g in range(1, groups)}
    k = sizes[chunk]
    q, _ = S.decode_position_stream(S.split_streams(known[(0x20, chunk)], 1, "position")[0], k, bits, ltable, "position")
    ints = {g: S.decode_channels(known.get((0x20 + g, chunk), b""), k, params[g], "data") for g in range(1, groups)}
    q = q.astype(np.float64)
    near = []  # per Gaussian: earlier Gaussians, nearest first (at most 8)
    for i in range(k):
        d = ((q[:i] - q[i]) ** 2).sum(1)
        m = min(8, i)
        idx = np.argpartition(d, m - 1)[:m] if i > m else np.arange(i)
        near.append(idx[np.argsort(d[idx], kind="stable")])
    print(f"chunk {chunk}: {k} Gaussians, grid {bits} bits")
    total = collections.defaultdict(float)
    for g in range(1, groups):
        for j in range(ints[g].shape[1]):
            col = ints[g][:, j]
            if len(set(col.tolist())) == 1:
                continue  # a constant channel costs nothing
            row = {"H0": entropy(col.tolist()), "prev-diff": entropy((col[1:] - col[:-1]).tolist())}
            for kk in (1, 4, 8):
                pred = np.array([np.round(np.median(col[near[i][:kk]])) if len(near[i]) else 0 for i in range(k)])
                row[f"knn{kk}"] = entropy((col - pred).tolist())
            print(f"{NAMES[g]}/{j}: " + "  ".join(f"{a} {b:.2f}" for a, b in row.items()))
            for a, b in row.items():
                total[a] += b
    print("sum over channels: " + "  ".join(f"{a} {b:.1f}" for a, b in total.items()))


if __name__ == "__main__":
    main()

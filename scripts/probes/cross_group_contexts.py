#!/usr/bin/env python3
"""Cross-group contexts probe (docs/codec.md §25): would conditioning a group's first channel --
scale x, the first rotation component, opacity, DC red, the channels with no value below them in
SPEC §4.3 -- on a channel of another group of the same Gaussian pay?

For every chunk of an 8.0 file, per such channel (integer values as the file holds them): a
mode-3-like model (8 quantile classes of the previous value, each with its median as centre, the
best of the five mixes, a two-sided geometric fitted per context) against the same model with 2, 4
or 8 quantile classes of a candidate from another group (any of its channels, or the sum, largest
or spread of the three log-scales), each extra context charged 3 bytes of table (mix, centre,
ratio). Bits per value; the best candidate and the two next.

    python3 scripts/probes/cross_group_contexts.py FILE.gsc
"""
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "..", "bitstream-spec"))
sys.path.insert(0, os.path.dirname(__file__))
import specdec as S  # noqa: E402
from linear_from_below import context_bits  # noqa: E402

NAMES = {1: "scale", 2: "rotation", 3: "opacity", 4: "sh_dc"}

data = open(sys.argv[1], "rb").read()
major, n, degree, sections = S.parse_container(data)
known, groups, sizes, params_of = S.classify_sections(major, n, degree, sections)
nb = major == S.NEIGHBOUR_MAJOR
tot_now = tot_best = tot_gross = 0.0
for chunk, k in enumerate(sizes):
    p = params_of[chunk]
    X = {}
    for g in (1, 2, 3, 4):
        params = S.parse_group_params(g, known[(0x10 + g, p)], None, nb)
        X[g] = S.decode_channels(known.get((0x20 + g, chunk), b""), k, params, "data").astype(np.int64)
    cands = {}
    for g in X:
        for j in range(X[g].shape[1]):
            cands[f"{NAMES[g]}/{j}"] = X[g][:, j]
    s = X[1]
    cands["scale_sum"], cands["scale_max"], cands["scale_spread"] = s.sum(1), s.max(1), s.max(1) - s.min(1)
    print(f"chunk {chunk}: {k} Gaussians")
    for g, j in ((1, 0), (2, 1), (3, 0), (4, 0)):  # rotation: channel 0 is the dropped component's index
        v = X[g][:, j]
        if len(set(v.tolist())) == 1:
            continue
        prev = np.concatenate([[v[0]], v[:-1]])
        now = context_bits(v, prev, None)
        net, gross = [], []
        for name, c in cands.items():
            if name.startswith(NAMES[g]) or len(set(c.tolist())) < 2:
                continue
            for lp in (2, 4, 8):
                b = context_bits(v, prev, c, lp)
                gross.append((b, f"{name}×{lp}"))
                # Net of table bytes: about 3 bytes a context, 8·(lp − 1) more contexts.
                net.append((b + 8 * 3 * 8 * (lp - 1) / k, f"{name}×{lp}"))
        net.sort()
        gross.sort()
        tot_now += now * k
        tot_best += net[0][0] * k
        tot_gross += gross[0][0] * k
        print(f"  {NAMES[g]}/{j}: {now:.3f} bits/value; with tables best {net[0][1]} {net[0][0]:.3f} ({(net[0][0] - now) * k / 8:+.0f} B), "
              f"next {net[1][1]} {net[1][0]:.3f}, {net[2][1]} {net[2][0]:.3f}; without table costs {gross[0][1]} {gross[0][0]:.3f}")
print(f"first channels, {len(data)} B file: {(tot_gross - tot_now) / 8:+.0f} B without table costs "
      f"({(tot_gross - tot_now) / 8 / len(data) * 100:+.2f} %), {(tot_best - tot_now) / 8:+.0f} B with them "
      f"({(tot_best - tot_now) / 8 / len(data) * 100:+.2f} %)")

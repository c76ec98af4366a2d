#!/usr/bin/env python3
"""Linear prediction from the channels below (docs/codec.md §20): would a colour or scale
transform pay beside the format's neighbour tables (SPEC §4.3)?

For every chunk of an 8.0 file and every multi-channel group (scale, rotation, SH DC), per
channel j > 0 (integer values as the file holds them): the cost of a mode-3-like model (8 × 8
contexts on quantiles of the previous value and of the value below, each with its median as
centre and the best of the five mixes, a two-sided geometric fitted per context) against the same
model on the residual after a least-squares linear prediction from channels 0 … j − 1 of the same
Gaussian. Bits per value, no table costs.

    python3 scripts/probes/linear_from_below.py FILE.gsc
"""
import math
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "..", "bitstream-spec"))
import specdec as S  # noqa: E402

NAMES = {1: "scale", 2: "rotation", 4: "sh_dc"}


def geometric_bits(r):
    """Bits per value of integers r under a two-sided geometric fitted to their mean |r|."""
    m = np.abs(np.asarray(r, dtype=np.float64)).mean() if len(r) else 0.0
    if m == 0:
        return 0.0
    theta = (math.sqrt(1 + m * m) - 1) / m  # E|d| = 2θ / (1 − θ²)
    return float(np.mean(np.abs(r)) * -math.log2(theta) + math.log2((1 + theta) / (1 - theta)))


def classes(x, parts=8):
    return np.searchsorted(np.quantile(x, np.linspace(0, 1, parts + 1)[1:-1]), x, side="right")


def context_bits(v, prev, lower, lower_parts=8):
    """Bits per value under 8 classes of `prev` × `lower_parts` classes of `lower` (None: one)."""
    cp = classes(prev)
    cl = classes(lower, lower_parts) if lower is not None else np.zeros_like(cp)
    total = 0.0
    for c in set(zip(cp.tolist(), cl.tolist())):
        m = (cp == c[0]) & (cl == c[1])
        vv, pp, centre = v[m], prev[m], np.median(v[m])
        total += m.sum() * min(geometric_bits(vv - np.floor((mix * pp + (4 - mix) * centre + 2) / 4)) for mix in range(5))
    return total / len(v)


def main():
    data = open(sys.argv[1], "rb").read()
    major, n, degree, sections = S.parse_container(data)
    known, groups, sizes, params_of = S.classify_sections(major, n, degree, sections)
    nb = major == S.NEIGHBOUR_MAJOR
    for chunk, k in enumerate(sizes):
        p = params_of[chunk]
        print(f"chunk {chunk}: {k} Gaussians")
        for g in (1, 2, 4):
            params = S.parse_group_params(g, known[(0x10 + g, p)], None, nb)
            x = S.decode_channels(known.get((0x20 + g, chunk), b""), k, params, "data").astype(np.int64)
            first = 2 if g == 2 else 1  # rotation: channel 0 is the index, channel 1 has no component below
            for j in range(first, x.shape[1]):
                v, lower = x[:, j], x[:, j - 1]
                if len(set(v.tolist())) == 1:
                    continue
                prev = np.concatenate([[v[0]], v[:-1]])
                now = context_bits(v, prev, lower)
                a = np.c_[x[:, (2 if g == 2 else 0):j].astype(np.float64), np.ones(k)]
                coef = np.linalg.lstsq(a, v, rcond=None)[0]
                w = v - np.round(a @ coef - coef[-1]).astype(np.int64)  # the constant stays in the centres
                linear = context_bits(w, np.concatenate([[w[0]], w[:-1]]), lower)
                print(f"  {NAMES[g]}/{j}: {now:.3f} → {linear:.3f} bits/value ({(linear - now) * k / 8:+.0f} B), coefficients {np.round(coef[:-1], 3)}")


if __name__ == "__main__":
    main()

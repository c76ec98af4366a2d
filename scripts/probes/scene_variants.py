#!/usr/bin/env python3
"""Variants of a 3DGS `.ply` unlike the test scenes (docs/codec.md §21), to check the codec's
ratio to SPZ and that nothing breaks where a captured scene differs from ours:

    shift     every position moved by (1000, −500, 2000)
    big       the scene ×1000 (positions and sizes)
    small     the scene ×0.001
    floaters  1 % more Gaussians, copies of random ones ten times larger, 5–50 extents out
    sh0, sh1, sh2   the SH rest cut to that degree (a scene trained at that degree codes alike)

    python3 scripts/probes/scene_variants.py IN.ply OUT.ply KIND

Binary little-endian `.ply` of float properties only (what `gscodec decode` and the usual 3DGS
trainers write).
"""
import sys

import numpy as np


def main():
    src, dst, kind = sys.argv[1], sys.argv[2], sys.argv[3]
    data = open(src, "rb").read()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode().splitlines()
    props = [line.split()[-1] for line in header if line.startswith("property")]
    n = int(next(line for line in header if line.startswith("element vertex")).split()[-1])
    a = np.frombuffer(data[end:], dtype="<f4", count=n * len(props)).reshape(n, len(props)).copy()
    at = {p: i for i, p in enumerate(props)}
    xyz = [at["x"], at["y"], at["z"]]
    scales = [at["scale_0"], at["scale_1"], at["scale_2"]]
    names = props
    if kind == "shift":
        a[:, xyz] += np.array([1000.0, -500.0, 2000.0], dtype=np.float32)
    elif kind in ("big", "small"):
        f = 1e3 if kind == "big" else 1e-3
        a[:, xyz] *= np.float32(f)
        a[:, scales] += np.float32(np.log(f))
    elif kind == "floaters":
        rng = np.random.default_rng(1)
        m = n // 100
        extra = a[rng.choice(n, m)].copy()
        centre = a[:, xyz].mean(0)
        extent = np.abs(a[:, xyz] - centre).max()
        d = rng.normal(size=(m, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        extra[:, xyz] = centre + d * extent * rng.uniform(5, 50, size=(m, 1))
        extra[:, scales] += np.float32(np.log(10.0))
        a = np.concatenate([a, extra])
    elif kind in ("sh0", "sh1", "sh2"):
        keep_coeffs = (int(kind[2]) + 1) ** 2 - 1
        per = sum(p.startswith("f_rest_") for p in props) // 3  # f_rest is colour-major: f_rest_{c·per + m}
        keep = [i for i, p in enumerate(props) if not p.startswith("f_rest_") or int(p[7:]) % per < keep_coeffs]
        a = a[:, keep]
        rest = iter(range(3 * keep_coeffs))
        names = [f"f_rest_{next(rest)}" if props[i].startswith("f_rest_") else props[i] for i in keep]
    else:
        sys.exit(f"error: {kind}: not a variant (shift, big, small, floaters, sh0, sh1, sh2)")
    body = [line for line in header if not line.startswith("property")]
    body = [f"element vertex {a.shape[0]}" if line.startswith("element vertex") else line for line in body]
    cut = body.index("end_header")
    body = body[:cut] + [f"property float {p}" for p in names] + body[cut:]
    with open(dst, "wb") as f:
        f.write(("\n".join(body) + "\n").encode())
        f.write(np.ascontiguousarray(a, dtype="<f4").tobytes())


main()

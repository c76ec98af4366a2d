#!/usr/bin/env python3
"""A textured dataset that is not made of Gaussians (docs/wd.md §21): a gravel-and-moss ground
disk, a marbled sphere and a brick box, ray-cast with 3x3 supersampling and Lambert shading,
RGBA on transparent (the NeRF-synthetic convention: the loader composites on white), in the
Blender/NeRF camera convention (z up, `transform_matrix` = OpenGL camera-to-world), lego's field
of view, cameras on the golden angle at elevations 15-65 degrees.  Needs only numpy.

    python3 scripts/textured_dataset.py OUT [VIEWS=100] [SIZE=200]
    HARD=1 python3 scripts/textured_dataset.py OUT   # textures at the pixel's scale
"""
import json, math, os, sys
import numpy as np
import struct, zlib


def save_rgba(fn, a):
    h, w, _ = a.shape
    raw = b"".join(b"\x00" + a[y].tobytes() for y in range(h))
    chunk = lambda t, c: struct.pack(">I", len(c)) + t + c + struct.pack(">I", zlib.crc32(t + c) & 0xFFFFFFFF)
    open(fn, "wb").write(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 6, 0, 0, 0))
                         + chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b""))

OUT = sys.argv[1]
VIEWS = int(sys.argv[2]) if len(sys.argv) > 2 else 100
SIZE = int(sys.argv[3]) if len(sys.argv) > 3 else 200
FOV = 0.6911112070083618  # lego's camera_angle_x
SS = 3
HARD = os.environ.get("HARD") == "1"  # textures at the pixel's scale: what 3000 steps cannot reproduce
RADIUS, TARGET = 4.0, np.array([0.0, 0.0, 0.3])


def hash3(i, j, k, seed):
    h = (i * 73856093) ^ (j * 19349663) ^ (k * 83492791) ^ (seed * 2654435761)
    h = (h ^ (h >> 13)) * 1274126177
    h = h ^ (h >> 16)
    return (h & 0xFFFF).astype(np.float64) / 65535.0


def value_noise(p, freq, seed):
    q = p * freq
    f = np.floor(q)
    t = q - f
    t = t * t * (3 - 2 * t)
    i, j, k = (f[:, 0].astype(np.int64), f[:, 1].astype(np.int64), f[:, 2].astype(np.int64))
    acc = 0.0
    for dx in (0, 1):
        for dy in (0, 1):
            for dz in (0, 1):
                w = (t[:, 0] if dx else 1 - t[:, 0]) * (t[:, 1] if dy else 1 - t[:, 1]) * (t[:, 2] if dz else 1 - t[:, 2])
                acc = acc + w * hash3(i + dx, j + dy, k + dz, seed)
    return acc


def fbm(p, freq, octaves, seed, gain=0.55):
    s, a, tot = 0.0, 1.0, 0.0
    for o in range(octaves):
        s = s + a * value_noise(p, freq * 2**o, seed + o)
        tot += a
        a *= gain
    return s / tot


def ground_colour(p):
    n = fbm(p, 40.0, 4, 1, 0.9) if HARD else fbm(p, 10.0, 5, 1, 0.85)  # gravel: fine octaves strong
    m = value_noise(p, 3.0, 7)        # patches of moss
    base = np.stack([0.55 + 0.35 * n, 0.45 + 0.30 * n, 0.33 + 0.25 * n], 1)
    moss = np.stack([0.25 + 0.2 * n, 0.45 + 0.3 * n, 0.18 + 0.1 * n], 1)
    w = np.clip((m - 0.55) * 4, 0, 1)[:, None]
    return base * (1 - w) + moss * w


def sphere_colour(p):
    n = fbm(p, 4.0, 5, 11)
    v = 0.5 + 0.5 * np.sin(18.0 * p[:, 2] + 9.0 * n)
    if HARD:
        v = np.clip(v + 0.6 * (fbm(p, 60.0, 3, 31, 0.9) - 0.5), 0, 1)
    return np.stack([0.85 - 0.45 * v, 0.8 - 0.5 * v, 0.9 - 0.3 * v], 1)


def box_colour(p, normal):
    # Bricks on the faces: 2D coordinates of the face, mortar lines, per-brick tint and grain.
    ax = np.argmax(np.abs(normal), 1)
    u = np.where(ax == 0, p[:, 1], p[:, 0])
    v = np.where(ax == 2, p[:, 1], p[:, 2])
    bh, bw = (0.045, 0.1) if HARD else (0.08, 0.17)
    row = np.floor(v / bh)
    uu = u / bw + 0.5 * (row % 2)
    col = np.floor(uu)
    mortar = (np.abs(v / bh - row - 0.5) > 0.42) | (np.abs(uu - col - 0.5) > 0.45)
    tint = hash3(col.astype(np.int64), row.astype(np.int64), ax.astype(np.int64), 5)
    grain = fbm(p, 80.0, 3, 21, 0.9) if HARD else fbm(p, 30.0, 3, 21)
    brick = np.stack([0.55 + 0.25 * tint, 0.22 + 0.1 * tint, 0.15 + 0.05 * tint], 1) * (0.75 + 0.5 * grain[:, None])
    return np.where(mortar[:, None], np.array([0.8, 0.78, 0.72]) * (0.8 + 0.3 * grain[:, None]), brick)


LIGHT = np.array([0.5, 0.3, 0.8]) / np.linalg.norm([0.5, 0.3, 0.8])
SPHERE_C, SPHERE_R = np.array([-0.45, 0.25, 0.45]), 0.45
BOX_LO, BOX_HI = np.array([0.05, -0.75, 0.0]), np.array([0.85, -0.05, 0.55])
DISK_R = 1.25


def trace(o, d):
    n = len(d)
    t_best = np.full(n, np.inf)
    kind = np.zeros(n, np.int8)
    normal = np.zeros((n, 3))
    # ground disk z = 0
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -o[2] / d[:, 2]
    p = o + t[:, None] * d
    ok = (t > 1e-6) & (p[:, 0] ** 2 + p[:, 1] ** 2 < DISK_R**2)
    t_best = np.where(ok, t, t_best); kind[ok] = 1; normal[ok] = [0, 0, 1]
    # sphere
    oc = o - SPHERE_C
    b = d @ oc
    c = oc @ oc - SPHERE_R**2
    disc = b * b - c
    t = -b - np.sqrt(np.maximum(disc, 0))
    ok = (disc > 0) & (t > 1e-6) & (t < t_best)
    t_best = np.where(ok, t, t_best); kind[ok] = 2
    normal[ok] = (o + t[ok, None] * d[ok] - SPHERE_C) / SPHERE_R
    # box (slabs)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        t0 = (BOX_LO - o) * inv
        t1 = (BOX_HI - o) * inv
    tmin = np.minimum(t0, t1)
    tmax = np.maximum(t0, t1)
    tn = tmin.max(1)
    tf = tmax.min(1)
    ok = (tn <= tf) & (tn > 1e-6) & (tn < t_best)
    axis = tmin.argmax(1)
    t_best = np.where(ok, tn, t_best); kind[ok] = 3
    nb = np.zeros((n, 3)); nb[np.arange(n), axis] = -np.sign(d[np.arange(n), axis])
    normal[ok] = nb[ok]
    return t_best, kind, normal


def render(c2w):
    s = SIZE * SS
    f = 0.5 * s / math.tan(0.5 * FOV)
    ys, xs = np.mgrid[0:s, 0:s]
    dirs_cam = np.stack([(xs + 0.5 - 0.5 * s) / f, -(ys + 0.5 - 0.5 * s) / f, -np.ones_like(xs, float)], -1).reshape(-1, 3)
    d = dirs_cam @ c2w[:3, :3].T
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    o = c2w[:3, 3]
    t, kind, normal = trace(o, d)
    p = o + np.where(np.isfinite(t), t, 0)[:, None] * d
    col = np.zeros((len(d), 3))
    for k, fn in ((1, ground_colour), (2, sphere_colour)):
        m = kind == k
        if m.any():
            col[m] = fn(p[m])
    m = kind == 3
    if m.any():
        col[m] = box_colour(p[m], normal[m])
    shade = 0.35 + 0.65 * np.clip(normal @ LIGHT, 0, 1)
    rgb = np.clip(col * shade[:, None], 0, 1)
    a = (kind > 0).astype(float)
    rgba = np.concatenate([rgb * a[:, None], a[:, None]], 1).reshape(SIZE, SS, SIZE, SS, 4).mean((1, 3))
    out = rgba.copy()
    out[..., :3] = np.where(rgba[..., 3:] > 0, rgba[..., :3] / np.maximum(rgba[..., 3:], 1e-9), 0)  # straight alpha
    return (np.clip(out, 0, 1) * 255 + 0.5).astype(np.uint8)


def c2w_for(i):
    az = i * math.pi * (3 - math.sqrt(5))
    el = math.radians(15 + 50 * ((i * 0.618033988749895) % 1.0))
    pos = TARGET + RADIUS * np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    back = (pos - TARGET) / np.linalg.norm(pos - TARGET)
    right = np.cross([0, 0, 1.0], back); right /= np.linalg.norm(right)
    up = np.cross(back, right)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, up, back, pos
    return m


os.makedirs(f"{OUT}/train", exist_ok=True)
frames = []
for i in range(VIEWS):
    m = c2w_for(i)
    save_rgba(f"{OUT}/train/r_{i}.png", render(m))
    frames.append({"file_path": f"./train/r_{i}", "transform_matrix": m.tolist()})
json.dump({"camera_angle_x": FOV, "frames": frames}, open(f"{OUT}/transforms_train.json", "w"), indent=1)

#!/usr/bin/env python3
"""Independent reference values for tests/metrics.rs.

MS-SSIM: a line-by-line numpy port of the `pytorch_msssim` package (valid Gaussian convolution,
avg_pool2d(kernel 2, padding = side % 2, count_include_pad) between scales, relu'd cs / ssim,
weights [0.0448, 0.2856, 0.3001, 0.2363, 0.1333]). Its scale-0 SSIM is checked against
scikit-image's structural_similarity (gaussian_weights, sigma 1.5, population covariance), an
independent published implementation.
FLIP: NVIDIA's official Python package `flip-evaluator` (LDR, 67 ppd) on the same images
quantised to 8 bits, as our wrapper does.

Usage: pip install numpy scikit-image flip-evaluator && python3 scripts/metrics_reference.py
The test images are defined analytically here and in tests/metrics.rs (`pattern`).
"""
import numpy as np
from skimage.metrics import structural_similarity

WEIGHTS = np.array([0.0448, 0.2856, 0.3001, 0.2363, 0.1333])
C1, C2 = 0.01 ** 2, 0.03 ** 2


def pattern(w, h, shift):
    """HxWx3 float32 image; `shift` perturbs the test image. Mirrors tests/metrics.rs."""
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    out = np.zeros((h, w, 3))
    for c in range(3):
        v = 0.5 + 0.4 * np.sin(0.09 * x + 0.5 * c) * np.cos(0.07 * y)
        if shift:
            n = ((x * 73 + y * 151 + c * 37) % 101) / 101.0 - 0.5
            v = v + 0.1 * np.sin(0.31 * x + 0.23 * y + c) + 0.1 * n
        out[..., c] = np.clip(v, 0.0, 1.0)
    return out.astype(np.float32).astype(np.float64)


def taps():
    t = np.exp(-((np.arange(11) - 5.0) ** 2) / (2 * 1.5 ** 2))
    return t / t.sum()


def valid_blur(p):
    t = taps()
    h, w = p.shape
    tmp = sum(t[k] * p[:, k:w - 10 + k] for k in range(11))
    return sum(t[k] * tmp[k:h - 10 + k, :] for k in range(11))


def ssim_cs(x, y):
    mx, my = valid_blur(x), valid_blur(y)
    sxx = valid_blur(x * x) - mx * mx
    syy = valid_blur(y * y) - my * my
    sxy = valid_blur(x * y) - mx * my
    cs = (2 * sxy + C2) / (sxx + syy + C2)
    ssim = (2 * mx * my + C1) / (mx * mx + my * my + C1) * cs
    return ssim.mean(), cs.mean()


def avg_pool(p):
    h, w = p.shape
    ph, pw = h % 2, w % 2
    q = np.pad(p, ((ph, ph), (pw, pw)))
    H, W = q.shape[0] // 2 * 2, q.shape[1] // 2 * 2
    q = q[:H, :W]
    return (q[0::2, 0::2] + q[1::2, 0::2] + q[0::2, 1::2] + q[1::2, 1::2]) / 4


def ms_ssim(a, b):
    vals = []
    for c in range(3):
        x, y = a[..., c], b[..., c]
        mcs = []
        for i in range(5):
            s, cs = ssim_cs(x, y)
            if i < 4:
                mcs.append(max(cs, 0.0))
                x, y = avg_pool(x), avg_pool(y)
        vals.append(np.prod(np.array(mcs + [max(s, 0.0)]) ** WEIGHTS))
    return float(np.mean(vals))


def main():
    import flip_evaluator as flip
    for (w, h) in [(192, 176), (167, 181)]:
        a, b = pattern(w, h, False), pattern(w, h, True)
        s0 = np.mean([ssim_cs(a[..., c], b[..., c])[0] for c in range(3)])
        sk = structural_similarity(a, b, gaussian_weights=True, sigma=1.5, use_sample_covariance=False,
                                   data_range=1.0, channel_axis=2)
        assert abs(s0 - sk) < 1e-9, (s0, sk)
        q = lambda im: (np.round(np.clip(im, 0, 1) * 255) / 255).astype(np.float32)
        _, mean_flip, _ = flip.evaluate(q(a), q(b), "LDR", applyMagma=False)
        print(f"{w}x{h}: ms_ssim = {ms_ssim(a, b):.12f}  ssim_valid = {s0:.12f}  flip = {mean_flip:.9f}")


if __name__ == "__main__":
    main()

"""Throughput of rectangle images, patch extraction/sampling, standardisation and ZCA (JSON).

Peers in the same run:
* rectangle images with ``fill="griddata"`` (the reference's hole filling) and a whole-image
  rotation per rectangle (``cv2.warpAffine`` of the full view, then an axis-aligned cut: the
  approach the batched sampler avoids) on a subset;
* a per-patch Python loop for the group standardisation.

Usage: python scripts/bench_preprocess.py [--n-rects 2000] [--depth stereo]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import cv2
import numpy as np
from PIL import Image

from dlsr.patches import extract_patches, sample_patches
from dlsr.preprocess import rectangle_images
from dlsr.whitening import CHANNEL_GROUPS, apply_zca, fit_zca, standardize_patches

REPO = Path(__file__).resolve().parents[1]
VIEW = (REPO.parent / "shared" / "data" / "jacquard_samples" / "1a9fa4c269cfcc1b738e43095496b061"
        / "0_1a9fa4c269cfcc1b738e43095496b061")


def _timed(f, *a, **k):
    t = time.perf_counter()
    out = f(*a, **k)
    return out, time.perf_counter() - t


def _whole_image_rotation(rgb, rect):
    """Peer: rotate the whole view about the rectangle centre, then cut the axis-aligned crop."""
    x, y, theta, w, h = rect
    R = cv2.getRotationMatrix2D((float(x), float(y)), -np.degrees(theta), 1.0)
    rot = cv2.warpAffine(rgb, R, (rgb.shape[1], rgb.shape[0]), flags=cv2.INTER_LINEAR)
    c0, r0 = int(round(x - w / 2)), int(round(y - h / 2))
    return rot[max(r0, 0):r0 + int(round(h)), max(c0, 0):c0 + int(round(w))]


def _loop_standardize(X, M, eps=1e-4):
    out = np.zeros(X.shape, np.float32)
    for i in range(len(X)):
        x = X[i].reshape(-1, 8)
        m = M[i].reshape(-1, 8)
        o = out[i].reshape(-1, 8)
        for chans in CHANNEL_GROUPS:
            v = x[:, chans][m[:, chans]]
            if v.size:
                var = v.var(ddof=1) if v.size > 1 else 0.0
                o[:, chans] = np.where(m[:, chans], (x[:, chans] - v.mean()) / np.sqrt(var + eps),
                                       0)
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-rects", type=int, default=2000)
    ap.add_argument("--depth", choices=("perfect", "stereo"), default="stereo")
    ap.add_argument("--n-patches", type=int, default=100_000)
    args = ap.parse_args(argv)

    prefix = str(VIEW)
    rgb = np.array(Image.open(prefix + "_RGB.png").convert("RGB"))
    depth = np.array(Image.open(prefix + f"_{args.depth}_depth.tiff"), dtype=np.float32)
    valid = np.isfinite(depth) & (depth > 0)
    depth = np.where(valid, depth, 0).astype(np.float32)
    g = np.loadtxt(prefix + "_grasps.txt", delimiter=";", ndmin=2)
    base = np.column_stack([g[:, 0], g[:, 1], -np.radians(g[:, 2]), g[:, 3], g[:, 4]])
    rng = np.random.default_rng(0)
    rects = base[rng.integers(0, len(base), args.n_rects)].copy()
    rects[:, :2] += rng.normal(0, 15, (len(rects), 2))
    rects[:, 2] = rng.uniform(-np.pi / 2, np.pi / 2, len(rects))

    res = {"view": Path(prefix).name, "depth": args.depth, "n_rects": len(rects),
           "mean_rect_wh_px": [float(rects[:, 3].mean()), float(rects[:, 4].mean())]}
    rectangle_images(rgb, depth, valid, rects[:20])  # warm-up (qhull, caches)
    (im, mk), dt = _timed(rectangle_images, rgb, depth, valid, rects)
    res["rectangle_images_per_s"] = len(rects) / dt
    k = min(200, len(rects))
    _, dt_g = _timed(rectangle_images, rgb, depth, valid, rects[:k], fill="griddata")
    res["rectangle_images_griddata_fill_per_s"] = k / dt_g
    _, dt_b = _timed(rectangle_images, rgb, depth, valid, rects[:k])
    res["rectangle_images_same_subset_per_s"] = k / dt_b
    k2 = min(50, len(rects))
    _, dt_w = _timed(lambda: [_whole_image_rotation(rgb, r) for r in rects[:k2]])
    res["whole_image_rotation_rgb_only_per_s"] = k2 / dt_w
    res["speedup_vs_griddata_fill_same_subset"] = res[
        "rectangle_images_same_subset_per_s"] / res["rectangle_images_griddata_fill_per_s"]

    (P, PM), dt = _timed(extract_patches, im, mk)
    res["extract_patches_per_s"] = P.shape[0] * P.shape[1] / dt
    (X, M), dt = _timed(sample_patches, im, mk, n_patches=args.n_patches, random_state=0)
    res["sample_patches_per_s"] = len(X) / dt
    Z, dt = _timed(standardize_patches, X, M)
    res["standardize_patches_per_s"] = len(X) / dt
    k3 = 5000
    Zl, dt_l = _timed(_loop_standardize, X[:k3], M[:k3])
    res["standardize_loop_peer_per_s"] = k3 / dt_l
    res["standardize_max_abs_diff_vs_loop"] = float(np.abs(Zl - Z[:k3]).max())
    res["standardize_speedup_vs_loop"] = res["standardize_patches_per_s"] / res[
        "standardize_loop_peer_per_s"]
    (mean, Pz), dt = _timed(fit_zca, Z, M)
    res["fit_zca_s"] = dt
    Y, dt = _timed(apply_zca, Z, M, mean, Pz)
    res["apply_zca_per_s"] = len(X) / dt
    res["fully_valid_patch_fraction"] = float(M.all(axis=1).mean())
    print(json.dumps({k: (round(v, 4) if isinstance(v, float) else v) for k, v in res.items()},
                     indent=1))
    return res


if __name__ == "__main__":
    main()

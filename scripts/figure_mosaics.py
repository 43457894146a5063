"""Dictionary mosaics (paper Figures 2 and 6) from real Jacquard samples.

Learns the six dictionaries on 6x6x8 patches of the positive rectangles of the real samples in
``../shared/data/jacquard_samples``, once on whitened patches (standardisation + ZCA, the
pipeline's input) and once on standardised but not whitened patches, and writes one PNG per
learner and setting: ``<out>/mosaic_<method>_<whitened|standardised>.png`` (K, RGB, D and
normals panels), plus the dictionaries in ``<out>/dictionaries.npz``.

Usage: python scripts/figure_mosaics.py [--out runs/figures] [--rect-step 4]
       [--n-patches 100000] [--n-batches 1000] [--methods SC NKM ...]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from dlsr.datasets import load_jacquard
from dlsr.dictionaries import METHODS, learn_dictionary
from dlsr.mosaic import plot_dictionary_mosaic
from dlsr.patches import sample_patches
from dlsr.preprocess import rectangle_images
from dlsr.rectangles import rects_to_array
from dlsr.whitening import apply_zca, fit_zca, standardize_patches

REPO = Path(__file__).resolve().parents[1]
JACQUARD = REPO.parent / "shared" / "data" / "jacquard_samples"


def real_patches(n_patches=100_000, rect_step=4, random_state=0, depth="stereo"):
    """Standardised and whitened patches of the real samples' positive rectangles.

    Every ``rect_step``-th positive rectangle of every view is cropped; patches are drawn with
    replacement among the accepted (>= 20 % valid) positions of those crops.

    Returns
    -------
    Xs, Xw : ndarray of shape (n_patches, 288), float32
        Standardised, and standardised + ZCA-whitened (re-masked).
    M : ndarray of shape (n_patches, 288), bool
    info : dict
    """
    if not JACQUARD.exists():
        raise FileNotFoundError(f"real samples not found: {JACQUARD}")
    samples = load_jacquard(JACQUARD, depth=depth)
    images, masks = [], []
    for s in samples:
        rects = rects_to_array(s.positives)[::rect_step]
        if len(rects):
            im, m = rectangle_images(s, rects)
            images.append(im)
            masks.append(m)
    images = np.concatenate(images)
    masks = np.concatenate(masks)
    X, M = sample_patches(images, masks, n_patches, 0.2, random_state)
    Xs = standardize_patches(X, M)
    mean, P = fit_zca(Xs, M)
    Xw = apply_zca(Xs, M, mean, P)
    info = {"views": len(samples), "rectangles": int(len(images)), "patches": int(len(X)),
            "candidate_positions": int(len(images) * 19 * 19),
            "drawn_with_replacement": True, "depth": depth}
    return Xs.astype(np.float32), Xw.astype(np.float32), M, info


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=REPO / "runs" / "figures")
    ap.add_argument("--rect-step", type=int, default=4)
    ap.add_argument("--n-patches", type=int, default=100_000)
    ap.add_argument("--n-batches", type=int, default=1000, help="SC / OMP mini-batches")
    ap.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    ap.add_argument("--settings", nargs="+", default=["whitened", "standardised"],
                    choices=["whitened", "standardised"])
    ap.add_argument("--n-jobs", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    Xs, Xw, M, info = real_patches(args.n_patches, args.rect_step, args.seed)
    info["patch_seconds"] = round(time.perf_counter() - t0, 1)
    args.out.mkdir(parents=True, exist_ok=True)
    store_path = args.out / "dictionaries.npz"
    store = dict(np.load(store_path)) if store_path.exists() else {}
    timings = {}
    for setting, X in (("whitened", Xw), ("standardised", Xs)):
        if setting not in args.settings:
            continue
        for method in args.methods:
            t = time.perf_counter()
            n_iter = args.n_batches if method in ("SC", "OMP") else None
            D = learn_dictionary(X, method, 300, args.seed, n_iter=n_iter, n_jobs=args.n_jobs)
            timings[f"{method}_{setting}"] = round(time.perf_counter() - t, 1)
            store[f"{method}_{setting}"] = D
            title = f"{method} dictionary, {setting} patches ({len(X)} real patches)"
            path = args.out / f"mosaic_{method}_{setting}.png"
            fig = plot_dictionary_mosaic(D, title=title, path=path, max_atoms=300)
            import matplotlib.pyplot as plt

            plt.close(fig)
            print(json.dumps({"figure": str(path), "seconds": timings[f"{method}_{setting}"]}),
                  flush=True)
            np.savez(store_path, **store)
    print(json.dumps({"patches": info, "learn_seconds": timings, "n_batches": args.n_batches}))


if __name__ == "__main__":
    main()

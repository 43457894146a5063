"""GG-CNN's maps on held-out views of an offline benchmark: docs/ggcnn_jacquard_maps.png.

For the first test view of every fold of a finished ``graspsim benchmark detection --detector
ggcnn`` run (``OUT/ggcnn.json`` and ``OUT/models/``), one row: the network's input (the depth
crop), its quality map Q with the top rectangle (red) and the labelled positives (green,
their centre thirds as GG-CNN's labels draw them), and the width map. It shows where the
network puts its peaks on objects it has not seen.

    .venv/bin/python scripts/ggcnn_maps_figure.py --run runs/jacquard-ggcnn \\
        [--data ../shared/data/jacquard_samples --format jacquard] [--out docs/...png]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np


def _to_input(rects, box):
    """Rectangles from image pixels into the network's input pixels (crop ``box``)."""
    row0, col0, scale = box
    a = np.array(rects, dtype=float).reshape(-1, 5).copy()
    a[:, 0] = (a[:, 0] - col0) * scale
    a[:, 1] = (a[:, 1] - row0) * scale
    a[:, 3:] *= scale
    return a


def draw(run, data, fmt, out) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from dlsr.detection import sample_observation
    from dlsr.rectangles import corners_from_array, rects_to_array
    from graspsim.data.samples import load_samples
    from graspsim.detectors.ggcnn.detector import GGCNNDetector, crop_input
    from graspsim.eval.offline.ggcnn import config_key

    run = Path(run)
    summary = json.loads((run / "ggcnn.json").read_text())
    c = summary["config"]
    samples = {s.image_id: s for s in load_samples(data, fmt, c["scale"], None)}
    key = config_key(c)
    firsts = {}
    for r in summary["per_image"]:
        firsts.setdefault(r["fold"], r)
    fig, axes = plt.subplots(len(firsts), 3, figsize=(9, 3 * len(firsts)), squeeze=False)
    for ax, (k, rec) in zip(axes, sorted(firsts.items()), strict=True):
        s = samples[rec["image_id"]]
        det = GGCNNDetector(run / "models" / f"ggcnn_{key}_fold{k}", top_k=1)
        obs = sample_observation(s)
        maps, (row0, col0, scale) = det.maps(obs)
        x, _ = crop_input(obs["depth"], obs.get("depth_valid"), int(det.meta_["crop"]),
                          int(det.meta_["input_size"]), det.meta_.get("crop_method", "object"))
        rects, _ = det.predict(obs)

        ax[0].imshow(x, cmap="viridis")
        ax[0].set_title(f"fold {k}: depth input", fontsize=9)
        ax[1].imshow(maps[0], cmap="magma", vmin=0, vmax=1)
        box = (row0, col0, scale)
        pos = _to_input(rects_to_array(s.positives), box)
        pos[:, 3] /= 3  # the centre third along the opening: the Q label
        for p in corners_from_array(pos):
            ax[1].plot(*np.r_[p, p[:1]].T, color="lime", lw=0.6)
        for p in corners_from_array(_to_input(rects[:1], box)):
            ax[1].plot(*np.r_[p, p[:1]].T, color="red", lw=1.5)
        ax[1].set_xlim(-0.5, maps.shape[2] - 0.5)
        ax[1].set_ylim(maps.shape[1] - 0.5, -0.5)
        ok = "correct" if rec["success"] else "wrong"
        ax[1].set_title(f"Q, top rectangle ({ok}), positives", fontsize=9)
        ax[2].imshow(maps[3], cmap="magma")
        ax[2].set_title("width map", fontsize=9)
        for a in ax:
            a.set_axis_off()
    fig.tight_layout()
    out = Path(out)
    fig.savefig(out, dpi=55)
    plt.close(fig)
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--run", required=True, help="a finished benchmark detection --detector "
                   "ggcnn folder")
    p.add_argument("--data", default="../shared/data/jacquard_samples")
    p.add_argument("--format", default="jacquard", choices=("cornell", "jacquard"))
    p.add_argument("--out", default="docs/ggcnn_jacquard_maps.png")
    args = p.parse_args(argv)
    try:
        print(draw(args.run, args.data, args.format, args.out))
    except (FileNotFoundError, KeyError, ValueError) as exc:
        print(f"ggcnn_maps_figure: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Which simulation settings matter for sim -> real detection: the variants of the simulator
(one setting of :class:`graspsim.sim.profiles.SimProfile` changed at a time) and the image
statistics that compare them with the real samples (``scripts/sim_settings_study.py``,
``docs/sim_settings.md``).

Variants (:data:`VARIANTS`):

- ``default``: the simulator's defaults;
- ``closer``: the camera 0.40-0.50 m above the table instead of 0.6-0.8 m (objects about
  1.5x larger in pixels);
- ``farther``: the camera 1.0-1.3 m above the table (labelled grasp openings about as wide in
  pixels as Jacquard's at the scale the detector reads them);
- ``clean_depth``: no depth noise or dropout (``DepthNoise.off()``; the ``jacquard`` profile);
- ``no_material_dropout``: the Kinect model without its dropout on dark, specular and
  transparent objects (``DepthNoise(materials=False)``);
- ``jacquard_look``: Jacquard's appearance: light grey table, even light without cast
  shadows;
- ``grey_table``: the grey table alone (default lights).
"""

from __future__ import annotations

import json
import logging
from dataclasses import replace
from pathlib import Path

import numpy as np

from dlsr.datasets import load_cornell, load_jacquard, read_depth_image
from dlsr.records import write_text_atomic

from ..labels.graspability import resolve_objects
from ..sim.bullet import worker_sim
from ..sim.camera import DepthNoise, LightRanges
from ..sim.observe import observe_scene
from ..sim.profiles import PROFILES, SimProfile

__all__ = ["VARIANTS", "DEFAULT_VARIANTS", "SOFT_LIGHT", "image_stats", "percentile_summary",
           "measure_settings", "grasp_sizes", "study_markdown"]

log = logging.getLogger(__name__)

DEFAULT = PROFILES["default"]
# Jacquard's look: even light from high above, no cast shadows (with the grey table).
SOFT_LIGHT = LightRanges(elevation=(60.0, 90.0), tint=(0.0, 0.05), ambient=(0.6, 0.75),
                         diffuse=(0.2, 0.35), specular=(0.0, 0.1), shadow=0.0)
#: The simulator's variants, by name.
VARIANTS: dict[str, SimProfile] = {
    "default": DEFAULT,
    "closer": replace(DEFAULT, name="closer", camera_height=(0.40, 0.50)),
    "farther": replace(DEFAULT, name="farther", camera_height=(1.0, 1.3)),
    "clean_depth": replace(DEFAULT, name="clean_depth", depth_noise=DepthNoise.off()),
    "no_material_dropout": replace(DEFAULT, name="no_material_dropout",
                                   depth_noise=DepthNoise(materials=False)),
    "jacquard_look": replace(DEFAULT, name="jacquard_look", table="grey", lighting=SOFT_LIGHT),
    "grey_table": replace(DEFAULT, name="grey_table", table="grey"),
}


#: The variants a study runs unless told otherwise.
DEFAULT_VARIANTS = ("default", "closer", "farther", "clean_depth", "jacquard_look")


def image_stats(rgb, depth, valid, mask) -> dict:
    """Per-image figures: object area and bounding box (px), depth of the object and of the
    rest (m, medians), missing depth on the object and elsewhere (fractions), background
    brightness and saturation (0-255, medians).

    Parameters
    ----------
    rgb : ndarray of shape (H, W, 3)
    depth : ndarray of shape (H, W)
        Metres.
    valid : ndarray of shape (H, W), bool
    mask : ndarray of shape (H, W), bool
        The object.

    Returns
    -------
    dict
        ``object_px``, ``bbox_long_px``, ``object_depth_m``, ``table_depth_m`` (None without
        valid depth there), ``missing_object`` (None without object), ``missing_elsewhere``,
        ``background_gray``, ``background_saturation``.
    """
    ys, xs = np.nonzero(mask)
    rest = ~mask
    rgbf = np.asarray(rgb, float)
    sat = rgbf.max(axis=2) - rgbf.min(axis=2)
    return {
        "object_px": int(mask.sum()),
        "bbox_long_px": int(max(np.ptp(xs), np.ptp(ys)) + 1) if len(xs) else 0,
        "object_depth_m": float(np.median(depth[mask & valid])) if (mask & valid).any() else None,
        "table_depth_m": float(np.median(depth[rest & valid])) if (rest & valid).any() else None,
        "missing_object": float(1 - valid[mask].mean()) if mask.any() else None,
        "missing_elsewhere": float(1 - valid[rest].mean()),
        "background_gray": float(np.median(rgbf[rest].mean(axis=1))),
        "background_saturation": float(np.median(sat[rest])),
    }


def percentile_summary(rows: list[dict]) -> dict:
    """The 10th, 50th and 90th percentiles of every figure of :func:`image_stats` rows (those
    that are not None).

    Parameters
    ----------
    rows : list of dict

    Returns
    -------
    dict
        ``images`` and, per figure, ``[p10, p50, p90]``.
    """
    if not rows:
        raise ValueError("no image to summarise")
    out = {"images": len(rows)}
    for k in rows[0]:
        v = np.array([r[k] for r in rows if r[k] is not None], float)
        out[k] = [round(float(q), 4) for q in np.percentile(v, [10, 50, 90])]
    return out


def measure_settings(data, cornell, variants=DEFAULT_VARIANTS, n_scenes: int = 20,
                     seed: int = 1, out=None) -> dict:
    """Image statistics of the real samples and of simulated scenes under each variant.

    The Jacquard sample views at the scale the detector reads them (stereo and perfect depth),
    the missing depth of the Cornell images, and ``n_scenes`` scenes of the train objects per
    variant, rendered without labelling (the same seed, so the same objects at the same
    poses).

    Parameters
    ----------
    data : str or Path
        A Jacquard folder.
    cornell : str or Path
        A folder of Cornell ``pcd*d.tiff`` depth images.
    variants : sequence of str
        Keys of :data:`VARIANTS`.
    n_scenes, seed : int
    out : str or Path or None
        Writes ``out/measure.json`` when given.

    Returns
    -------
    dict
        ``jacquard_<depth>_scale0.5``, ``cornell`` and ``sim_<variant>``
        (:func:`percentile_summary`).
    """
    unknown = [v for v in variants if v not in VARIANTS]
    if unknown:
        raise ValueError(f"unknown variants {unknown}; choose from {list(VARIANTS)}")
    res = {"percentiles": [10, 50, 90]}
    for depth in ("stereo", "perfect"):
        rows = [image_stats(s.rgb, s.depth, s.depth_valid, s.mask)
                for s in load_jacquard(data, depth=depth, scale=0.5)]
        res[f"jacquard_{depth}_scale0.5"] = percentile_summary(rows)
    cornell = {}
    for path in sorted(Path(cornell).glob("pcd*d.tiff")):
        d = np.asarray(read_depth_image(path), np.float32)
        ok = np.isfinite(d) & (d > 0)
        cornell[path.name] = {"missing": float(1 - ok.mean()),
                              "depth_m_p5_p50_p95": np.percentile(d[ok], [5, 50, 95]).round(3)
                              .tolist()}
    res["cornell"] = cornell
    sim = worker_sim()
    specs = resolve_objects("train")
    for name in variants:
        rows = []
        for i in range(n_scenes):
            _, bodies, frame, _ = observe_scene(sim, specs, seed, i,
                                                    profile=VARIANTS[name])
            mask = np.isin(frame.segmentation, bodies.objects)
            rows.append(image_stats(frame.rgb, frame.depth, frame.depth_valid, mask))
        res[f"sim_{name}"] = percentile_summary(rows)
        log.info("%s: %s", name, json.dumps(res[f"sim_{name}"]))
    if out is not None:
        Path(out).mkdir(parents=True, exist_ok=True)
        write_text_atomic(Path(out) / "measure.json", json.dumps(res, indent=1))
    return res


def grasp_sizes(ds) -> dict:
    """How many positives a Cornell-format dataset has and their median opening (px).

    Parameters
    ----------
    ds : str or Path

    Returns
    -------
    dict
        ``positives``, ``opening_px_median`` (None without positives).
    """
    w = [r.w for s in load_cornell(ds) for r in s.positives]
    return {"positives": len(w), "opening_px_median": round(float(np.median(w)), 1) if w else None}


def study_markdown(info: dict, tests: dict, n_images: dict) -> str:
    """The study's table: each variant's sim -> real accuracy and its paired test against
    ``default``.

    Parameters
    ----------
    info : dict
        Per variant: ``accuracy``, ``n_correct``, ``positives``, ``opening_px_median``.
    tests : dict
        Per variant other than ``default``:
        :func:`graspsim.eval.stats.paired_detection_test` against it.
    n_images : dict
        Per variant, the real images it was tested on.

    Returns
    -------
    str
    """
    lines = ["| variant | sim -> real (%) | images won alone vs default (variant / default) | "
             "exact McNemar p | positives (median opening, px) |", "|---|---|---|---|---|"]
    for name, s in info.items():
        t = tests.get(name)
        lines.append(f"| {name} | {100 * s['accuracy']:.1f} ({s['n_correct']}/"
                     f"{n_images[name]}) | "
                     + (f"{t['a_only']} / {t['b_only']} | {t['p_value']:.3g}" if t else " | ")
                     + f" | {s['positives']} ({s['opening_px_median']}) |")
    return "\n".join(lines) + "\n"

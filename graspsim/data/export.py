"""``graspsim export``: a dataset's copy that the CNN peers' own Cornell loaders read unchanged.

A ``graspsim dataset`` folder keeps every scene: an image where no labelled candidate lifted
the object has an empty ``pcdXXXXcpos.txt`` (its negatives still train DLSR, and
``graspsim score`` rebuilds every scene of the manifest), and missing depth stays 0 in
``pcdXXXXd.tiff`` (the project's convention). The published Cornell loaders of GG-CNN
(``dougsm/ggcnn``) and GR-ConvNet (``skumra/robotic-grasping``) expect what real Cornell and its
preprocessing give: at least one positive rectangle per image (their loader centres its crop on
the mean of the positives' corners and fails on an empty file) and depth filled by their
``generate_cornell_depth.py`` (OpenCV Navier-Stokes inpainting, metres, float32 TIFF), which
reads point clouds a graspsim dataset does not write.

:func:`export_cornell` writes that folder from any Cornell-layout folder (a graspsim dataset,
or real Cornell with its point clouds):

* only images with at least one positive rectangle (``keep_empty=True`` keeps the others);
  every image left out is logged and listed in ``export.json``;
* ``NN/pcdXXXXd.tiff``: float32 metres, every missing pixel filled by
  :func:`dlsr.datasets.inpaint_depth` (the peers' computation); ``inpaint=False`` keeps 0;
* ``NN/pcdXXXXr.png``, ``NN/pcdXXXXcpos.txt``, ``NN/pcdXXXXcneg.txt`` (four ``x y`` corner
  lines per rectangle, Cornell order) and ``image_objects.txt``, written by
  :func:`dlsr.datasets.write_cornell_image`; ``NN/pcdXXXXcamera.json`` copied when present;
* images keep their numbers, so predictions made on the export are scored on the source
  dataset (``graspsim score --data SOURCE``) without renaming;
* ``export.json``: the source folder and its fingerprint (sha256 of its ``scenes.json``, when it
  has one), the settings, the images written and the images left out with the reason.

The source dataset is never modified: its scenes, manifest and fingerprint stay as written.
"""

from __future__ import annotations

import dataclasses
import hashlib
import logging
import shutil
from pathlib import Path

import numpy as np

from dlsr.datasets import (
    inpaint_depth,
    iter_cornell,
    write_cornell_image,
    write_cornell_mapping,
)
from dlsr.records import read_json, write_json_atomic

from .datagen import MANIFEST

__all__ = ["EXPORT_FORMAT", "export_cornell"]

log = logging.getLogger(__name__)

EXPORT_FORMAT = "graspsim-cornell-export/1"
"""The ``format`` of an export's ``export.json``."""


def export_cornell(data, out, keep_empty: bool = False, inpaint: bool = True) -> dict:
    """Write a copy of a Cornell-layout folder that the peers' Cornell loaders read unchanged.

    Parameters
    ----------
    data : str or Path
        The source: a ``graspsim dataset`` folder or any Cornell-layout folder
        (:func:`dlsr.datasets.load_cornell` reads it, point clouds or ``d.tiff``).
    out : str or Path
        The export folder (made when missing). It must not be ``data`` nor hold another
        export's images: an existing export is rewritten only when it was made from the same
        source.
    keep_empty : bool
        Also write the images without a positive rectangle (real Cornell has none; the peers'
        loaders fail on them). Default: left out, logged and listed.
    inpaint : bool
        Fill missing depth as the peers' preprocessing does (:func:`dlsr.datasets.
        inpaint_depth`). False keeps 0 where the sensor gave no depth.

    Returns
    -------
    dict
        What ``export.json`` holds: ``format``, ``source``, ``source_fingerprint`` (or None),
        ``keep_empty``, ``depth`` (how it was written), ``images`` (ids written),
        ``skipped`` (``{"image", "reason"}`` per image left out), ``positives`` and
        ``negatives`` (rectangles written) and ``path`` (of ``export.json``).

    Raises
    ------
    FileNotFoundError
        ``data`` is missing or holds no Cornell image.
    ValueError
        ``out`` is ``data`` (or inside it), or holds an export of another source.
    """
    src, dst = Path(data), Path(out)
    if not src.is_dir():
        raise FileNotFoundError(f"dataset folder not found: {src}")
    if dst.resolve() == src.resolve() or src.resolve() in dst.resolve().parents:
        raise ValueError(f"--out {dst} is the dataset folder {src} or inside it; the export "
                         "goes to a folder of its own (the source stays as written)")
    record_path = dst / "export.json"
    if record_path.exists():
        old = read_json(record_path, "export record")
        if old.get("source") != str(src.resolve()):
            raise ValueError(f"{dst} holds an export of {old.get('source')} ({record_path}); "
                             "use a new folder")
        for folder in dst.iterdir():  # rewritten from scratch: no image of another setting
            if folder.is_dir() and folder.name.isdigit():
                shutil.rmtree(folder)
    elif dst.is_dir() and any(dst.iterdir()):
        raise ValueError(f"{dst} is not empty and holds no export.json; use a new folder")
    manifest = src / MANIFEST
    fingerprint = (hashlib.sha256(manifest.read_bytes()).hexdigest()
                   if manifest.is_file() else None)
    dst.mkdir(parents=True, exist_ok=True)
    written, skipped, lines = [], [], []
    n_pos = n_neg = 0
    for sample in iter_cornell(src):
        image = sample.image_id
        if not sample.positives and not keep_empty:
            log.info("image %s (%s) left out: no positive rectangle", image,
                     sample.source)
            skipped.append({"image": image, "reason": "no positive rectangle"})
            continue
        depth, valid = sample.depth, sample.depth_valid
        if inpaint:
            try:
                depth = inpaint_depth(sample.depth, sample.depth_valid)
            except ValueError as exc:  # no valid pixel: nothing to fill from
                log.warning("image %s (%s) left out: %s", image, sample.source, exc)
                skipped.append({"image": image, "reason": f"depth: {exc}"})
                continue
            valid = np.ones(depth.shape, bool)
        line = write_cornell_image(dataclasses.replace(sample, depth=depth, depth_valid=valid),
                                   dst, int(image))
        if line is not None:
            lines.append(line)
        camera = Path(sample.source).with_name(f"pcd{image}camera.json")
        if camera.is_file():
            shutil.copyfile(camera, dst / f"{int(image) // 100:02d}" / camera.name)
        written.append(image)
        n_pos += len(sample.positives)
        n_neg += len(sample.negatives)
    if not written and not skipped:
        raise FileNotFoundError(f"{src}: no Cornell image (NN/pcdXXXXr.png) found")
    write_cornell_mapping(dst, lines)
    record = {
        "format": EXPORT_FORMAT,
        "source": str(src.resolve()),
        "source_fingerprint": fingerprint,
        "keep_empty": bool(keep_empty),
        "depth": ("float32 metres; missing pixels filled by OpenCV Navier-Stokes inpainting "
                  "as the peers' generate_cornell_depth.py (dlsr.datasets.inpaint_depth)"
                  if inpaint else "float32 metres, 0 where missing (not inpainted)"),
        "images": written,
        "skipped": skipped,
        "positives": n_pos,
        "negatives": n_neg,
    }
    write_json_atomic(record_path, record, indent=1)
    if skipped:
        log.info("%d of %d images left out (listed in %s)", len(skipped),
                 len(skipped) + len(written), record_path)
    return {**record, "path": str(record_path)}

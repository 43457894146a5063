"""Detection in one RGB-D image read from files (:func:`detect_files`, the ``graspsim detect``
command).

Part of :mod:`dlsr.detection`.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from ..records import atomic_write
from .model import DLSRDetector


def detect_files(model, rgb, depth, mask=None, background=None, depth_units: float = 1.0,
                 detector: str | None = None, top_k: int = 5, out=None,
                 clear_jaws: bool | None = None, K=None, build=None, **options):
    """Detect grasps in one RGB-D image read from files (the ``graspsim detect`` command).

    Parameters
    ----------
    model : DLSRDetector or path
        A model or the path of a saved one.
    rgb : path
        Colour image (PNG, ...).
    depth : path
        Depth image (float TIFF in metres along the optical axis, or ``.npy``); values <= 0 or
        non-finite are missing. Or a Cornell point cloud ``pcdXXXX.txt`` in any frame. A
        Cornell image's depth is read as :func:`dlsr.datasets.read_cornell_depth` reads it
        (the cloud's ``z`` in the fitted camera frame; a ``pcdXXXXd.tiff``, the range, converted
        where the camera is known from its cloud or camera file), so ``graspsim detect`` sees
        what :func:`dlsr.datasets.load_cornell` gives.
    mask, background : path or None
        Object mask (non-zero = object) or background image for the object region. With
        neither, the object is found from depth alone (:func:`~dlsr.detection.table_plane_mask`).
    depth_units : float
        Multiplies the depth file's values to give metres (e.g. 0.001 for millimetres). A
        median valid depth outside 0.05 to 20 m after it is an error naming the file (wrong
        units would silently break the table fit, whose thresholds are in metres).
    detector : {"dense", "exact", "lattice"} or None
        None: the model's saved choice.
    top_k : int
    out : path or None
        Overlay PNG with the detections (best drawn last).
    clear_jaws : bool or None
        Override the model's ``SearchGrid.clear_jaws`` (only candidates whose jaws come down
        beside the object); None keeps the model's saved grid. The lattice detector's
        candidates always span the object (False is refused).
    K : array-like of shape (3, 3), path or None
        The camera matrix, or a camera file (``pcdXXXXcamera.json``,
        :func:`dlsr.datasets.read_camera_matrix`): needed by a model trained with physical
        features (``train_detector(physical=True)``, the default of ``graspsim run``). None:
        for a Cornell image (``pcdXXXXr.png``) the matrix fitted to its point cloud, cached
        or the Kinect estimate (:func:`dlsr.intrinsics.cornell_camera_matrix`), else none.
    build : callable or None
        ``build(model, top_k=, background=, obs=)`` returns the detector to run (e.g.
        :func:`graspsim.detector_options.build_real_detector` with the command's options);
        None: ``model.detector(detector, ...)`` with ``options`` and ``clear_jaws``.
    **options :
        Passed to the detector (``coarse_to_fine``, ``rescore``, ``region``).

    Returns
    -------
    Detection
    """
    if not isinstance(model, DLSRDetector):
        model = DLSRDetector.load(model)
    from ..datasets import clean_depth, read_cornell_depth, read_depth_image, read_gray, read_rgb

    rgb_arr = read_rgb(rgb)
    cornell = next((p for p in (Path(rgb), Path(depth))
                    if p.name.startswith("pcd") and p.name[3:7].isdigit()), None)
    camera = None
    if cornell is not None:
        d, valid, camera = read_cornell_depth(cornell, depth, rgb_arr.shape[:2])
    elif Path(depth).suffix == ".txt":
        raise ValueError(f"point cloud {depth}: a Cornell point cloud needs a Cornell file name "
                         "(pcdXXXX.txt, or the image's pcdXXXXr.png) to find its camera")
    else:
        d, valid = clean_depth(read_depth_image(depth))
    if d.shape != rgb_arr.shape[:2]:
        raise ValueError(f"depth {depth} has shape {d.shape}, the image {rgb} "
                         f"{rgb_arr.shape[:2]}")
    obs = {"rgb": rgb_arr, "depth": d * np.float32(depth_units), "depth_valid": valid}
    if valid.any():
        median = float(np.median(obs["depth"][valid]))
        if not 0.05 <= median <= 20.0:
            raise ValueError(f"depth {depth}: median valid depth {median:.4g} m after "
                             f"--depth-units {depth_units:g} is not a camera's range (0.05 to "
                             "20 m); millimetres need --depth-units 0.001")
    if mask is not None:
        obs["mask"] = read_gray(mask) > 0
    if K is None and cornell is not None:
        from ..intrinsics import cornell_camera

        K = (camera if camera is not None else cornell_camera(cornell)).K
    if K is not None:
        from ..datasets import check_camera_matrix, read_camera_matrix

        obs["K"] = (read_camera_matrix(K) if isinstance(K, str | Path)
                    else check_camera_matrix(K))
    elif model.physical:
        raise ValueError("this model weighs physical features (opening in metres, heights "
                         "above the table): give the camera intrinsics (graspsim detect "
                         "--intrinsics FX FY CX CY, or --camera pcdXXXXcamera.json)")
    bg = None if background is None else read_rgb(background)
    if build is not None:
        det = build(model, top_k=top_k, background=bg, obs=obs).detect(obs)
        _write_overlay(out, rgb_arr, det)
        return det
    search = model.detector(detector, top_k=top_k, background=bg, **options)
    if clear_jaws is not None:
        if hasattr(search, "grid"):
            search.grid = dataclasses.replace(search.grid, clear_jaws=bool(clear_jaws))
        elif not clear_jaws:
            raise ValueError("the lattice detector's candidates always span the object: "
                             "--no-clear-jaws needs the grid search (--detector dense)")
    det = search.detect(obs)
    _write_overlay(out, rgb_arr, det)
    return det


def _write_overlay(out, rgb_arr, det) -> None:
    """The overlay PNG of :func:`detect_files` (best drawn last), when ``out`` is a path."""
    if out is None:
        return
    from PIL import Image

    from ..viz import draw_rectangles

    img = draw_rectangles(rgb_arr, det.rects[:1], negatives=det.rects[1:][::-1])
    kind = Image.registered_extensions().get(Path(out).suffix.lower(), "PNG")
    with atomic_write(out, "wb") as fh:  # never a half-written overlay
        Image.fromarray(img).save(fh, format=kind)

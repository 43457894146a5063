"""Grasp datasets: a common sample type, Cornell and Jacquard readers, a Cornell writer, splits.

Conventions (see :mod:`dlsr.rectangles` and CONTRIBUTING.md): rectangles in pixels and radians,
depth float32 metres with 0 where missing plus a bool validity mask, never NaN.

Problems with single items that can be skipped safely (a rectangle with ``NaN`` corners, an image
without rectangle files, an image missing from the mapping file) are reported with
:mod:`logging` warnings on the ``dlsr.datasets`` logger naming the file and line, not with
:mod:`warnings`: real Cornell files contain such rectangles, and pytest (warnings as errors)
would otherwise fail every test that reads them. Anything that would give wrong numbers (a
rectangle file whose line count is not a multiple of 4, an unreadable image, a missing depth
source, inconsistent object ids) raises ``ValueError`` / ``FileNotFoundError`` naming the file.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import re
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from PIL import Image, UnidentifiedImageError

from .intrinsics import (  # noqa: F401  (check_camera_matrix: importable from here too)
    CornellCamera,
    check_camera_matrix,
    cornell_camera,
    jacquard_camera_matrix,
    pcd_points_and_pixels,
    range_to_depth,
    read_camera_matrix,
    read_pcd_points,
)
from .metrics import rectangle_metric_many
from .records import CorruptFileError, check_magic, file_errors, write_text_atomic
from .rectangles import GraspRectangle, array_to_rects, rects_to_array

__all__ = [
    "GraspSample",
    "normalize_image_id",
    "CORNELL_WIDTH",
    "MAPPING_FILENAMES",
    "load_cornell",
    "load_jacquard",
    "write_cornell",
    "write_cornell_image",
    "write_cornell_mapping",
    "read_mapping",
    "read_cornell_rectangles",
    "read_jacquard_grasps",
    "read_pcd_depth",
    "pcd_depth",
    "read_cornell_depth",
    "read_rgb",
    "read_gray",
    "read_depth_image",
    "clean_depth",
    "inpaint_depth",
    "iter_cornell",
    "resize_sample",
    "sample_negatives",
    "groups",
    "image_wise_folds",
    "object_wise_folds",
]

logger = logging.getLogger(__name__)

# What Pillow raises on unreadable images beyond the common parser errors (and its warning on a
# truncated TIFF, made an error by _reading_image).
_IMAGE_ERRORS = (UnidentifiedImageError, Image.DecompressionBombError, UserWarning)


@contextlib.contextmanager
def _reading_image(path, what: str):
    """:func:`dlsr.records.file_errors` for Pillow: a truncated image is an error too."""
    with warnings.catch_warnings(), file_errors(path, what, _IMAGE_ERRORS):
        warnings.filterwarnings("error", message="Truncated File Read", category=UserWarning)
        yield

CORNELL_WIDTH = 640
"""Row length used by the Cornell point-cloud pixel index (``index = row * 640 + col``)."""

MAPPING_FILENAMES = ("image_objects.txt", "objectClasses.txt")
"""Mapping files :func:`load_cornell` looks for in the dataset root when ``mapping`` is None;
:func:`write_cornell` writes the first."""


@dataclass
class GraspSample:
    """One RGB-D image with its labelled grasp rectangles.

    Attributes
    ----------
    image_id : str
        Unique within a dataset (Cornell: ``"0100"``; Jacquard: ``"<view>_<hash>"``).
    object_id : str or None
        Object identity for object-wise splits; None when unknown.
    rgb : ndarray of shape (H, W, 3), uint8
    depth : ndarray of shape (H, W), float32
        Metres; 0 where missing (never NaN).
    depth_valid : ndarray of shape (H, W), bool
    positives, negatives : list of GraspRectangle
    source : Path or None
        The file (or folder) the sample came from, for error messages.
    mask : ndarray of shape (H, W), bool, or None
        Object mask when the dataset has one (Jacquard, simulation).
    K : ndarray of shape (3, 3) or None
        Camera matrix when the dataset records it (graspsim datasets: ``pcdXXXXcamera.json``);
        needed to measure rectangles in metres (:mod:`dlsr.detection.physical`).
    """

    image_id: str
    object_id: str | None
    rgb: np.ndarray
    depth: np.ndarray
    depth_valid: np.ndarray
    positives: list[GraspRectangle] = field(default_factory=list)
    negatives: list[GraspRectangle] = field(default_factory=list)
    source: Path | None = None
    mask: np.ndarray | None = None
    K: np.ndarray | None = None


# --------------------------------------------------------------------------------------------
# Small readers


def read_rgb(path: Path) -> np.ndarray:
    """An image file as (H, W, 3) uint8 RGB; clear errors naming the file."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"image file not found: {path}")
    with _reading_image(path, "cannot read image"):
        with Image.open(path) as im:
            return np.array(im.convert("RGB"), dtype=np.uint8)


def read_gray(path: Path) -> np.ndarray:
    """An image file as (H, W) uint8 gray; clear errors naming the file."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"image file not found: {path}")
    with _reading_image(path, "cannot read image"):
        with Image.open(path) as im:
            return np.array(im.convert("L"))


def read_depth_image(path: Path) -> np.ndarray:
    """A single-channel depth image as float32: a float TIFF (Pillow reads the real
    LZW-compressed files) or a ``.npy`` array."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"depth file not found: {path}")
    with _reading_image(path, "cannot read depth image"):
        if path.stat().st_size == 0:
            raise CorruptFileError(f"cannot read depth image {path}: empty file")
        if path.suffix == ".npy":
            with open(path, "rb") as fh:
                check_magic(fh, path, "cannot read depth image", (b"\x93NUMPY",),
                            "a .npy array")
                arr = np.load(fh, allow_pickle=False)
        else:
            with Image.open(path) as im:
                arr = np.array(im)
    if arr.ndim != 2:
        raise ValueError(f"depth image {path} must have one channel, got shape {arr.shape}")
    if not (np.issubdtype(arr.dtype, np.number) or arr.dtype == bool):
        raise ValueError(f"depth image {path} must hold numbers, got dtype {arr.dtype}")
    return arr.astype(np.float32)


def clean_depth(raw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Depth with 0 where missing (non-finite or <= 0, e.g. Jacquard's -1) and its validity."""
    valid = np.isfinite(raw) & (raw > 0)
    depth = np.where(valid, raw, 0).astype(np.float32)
    return depth, valid


def inpaint_depth(depth, valid=None) -> np.ndarray:
    """Missing depth filled as the Cornell preprocessing of the CNN peers fills it.

    The published GG-CNN and GR-ConvNet code (``DepthImage.inpaint``, called by their
    ``generate_cornell_depth.py``) pads the depth image by one pixel (OpenCV's default border,
    a reflection), divides it by its largest absolute value (OpenCV inpaints float32 images in
    [-1, 1]), fills the pixels equal to 0 with OpenCV's Navier-Stokes inpainting
    (``cv2.inpaint(..., 1, cv2.INPAINT_NS)``, radius 1) and scales back. This does the same
    computation; the readings themselves are kept exactly (scaling them there and back changes
    them by up to one float32 step).

    Parameters
    ----------
    depth : ndarray of shape (H, W)
        Metres, 0 (or non-finite) where missing.
    valid : ndarray of shape (H, W), bool, or None
        Readings; default ``depth > 0`` and finite.

    Returns
    -------
    ndarray of shape (H, W), float32
        Metres; every pixel filled (a copy when nothing is missing).

    Raises
    ------
    ValueError
        A depth image that is not 2-D, or has no valid pixel.
    """
    import cv2

    depth = np.asarray(depth, dtype=np.float32)
    if depth.ndim != 2:
        raise ValueError(f"depth must be a 2-D image, got shape {depth.shape}")
    ok = np.isfinite(depth) & (depth > 0)
    if valid is not None:
        valid = np.asarray(valid).astype(bool)
        if valid.shape != depth.shape:
            raise ValueError(f"depth_valid has shape {valid.shape}, depth {depth.shape}")
        ok &= valid
    if not ok.any():
        raise ValueError("the depth image has no valid pixel (all masked)")
    d = np.where(ok, depth, 0.0).astype(np.float32)
    if ok.all():
        return d
    pad = cv2.copyMakeBorder(d, 1, 1, 1, 1, cv2.BORDER_DEFAULT)
    missing = cv2.copyMakeBorder((~ok).astype(np.uint8), 1, 1, 1, 1, cv2.BORDER_DEFAULT)
    scale = float(np.abs(pad).max())
    filled = cv2.inpaint(pad / scale, missing, 1, cv2.INPAINT_NS)
    d = (filled[1:-1, 1:-1] * scale).astype(np.float32)
    return np.where(ok, depth, d).astype(np.float32)


def _check_shape(path: Path, arr: np.ndarray, shape: tuple[int, int], what: str):
    if arr.shape[:2] != shape:
        raise ValueError(f"{what} {path} has shape {arr.shape[:2]}, but the image is {shape}")


def read_pcd_depth(path, shape: tuple[int, int],
                   camera: CornellCamera | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Depth image from a Cornell PCD v0.7 ASCII point cloud (:func:`pcd_depth` of the file).

    Parameters
    ----------
    path : path-like
        ``pcdXXXX.txt`` with fields including ``x y z`` and ``index`` (``row * W + col``).
    shape : (H, W)
        Image size; ``W`` is the row length of the index (640 in Cornell).
    camera : CornellCamera or None
        None: the range, as the common preprocessing computes it; else the depth along the
        optical axis (see :func:`pcd_depth`).

    Returns
    -------
    depth : ndarray of shape (H, W), float32
    valid : ndarray of shape (H, W), bool
    """
    path = Path(path)
    fields, data = read_pcd_points(path)
    return pcd_depth(fields, data, shape, camera, what=f"point cloud {path}")


def pcd_depth(fields, data, shape: tuple[int, int], camera: CornellCamera | None = None,
              what: str = "point cloud") -> tuple[np.ndarray, np.ndarray]:
    """Depth image of a parsed Cornell point cloud (:func:`dlsr.intrinsics.read_pcd_points`).

    Without ``camera``, a pixel's depth is the Euclidean norm of its point ``(x, y, z)``
    (millimetres) divided by 1000: the range, as the common preprocessing
    (``pcdXXXXd.tiff``) computes it. With ``camera``, the depth along its optical axis, the
    pipeline's convention (:mod:`dlsr.intrinsics`): the points' ``z`` in the camera frame when
    the camera was fitted to the cloud (``camera.T_cam_cloud``), else the range converted with
    ``camera.K`` (:func:`dlsr.intrinsics.range_to_depth`). Pixels without a point (or with a
    non-finite one) are not inpainted: their depth is 0 and their validity False.

    Parameters
    ----------
    fields : list of str
    data : ndarray of shape (n, len(fields))
    shape : (H, W)
    camera : CornellCamera or None
    what : str
        Names the cloud in errors.

    Returns
    -------
    depth : ndarray of shape (H, W), float32
    valid : ndarray of shape (H, W), bool
    """
    h, w = shape
    depth = np.zeros((h, w), dtype=np.float32)
    valid = np.zeros((h, w), dtype=bool)
    xyz, pixels = pcd_points_and_pixels(fields, data, w, what)
    if len(data) == 0:
        return depth, valid
    index = data[:, fields.index("index")]
    if np.any(index < 0) or np.any(index >= h * w) or np.any(index != np.round(index)):
        raise ValueError(f"{what}: pixel index outside an image of shape {shape}")
    T = None if camera is None else camera.T_cam_cloud
    with np.errstate(invalid="ignore"):
        dist = (np.sqrt(np.sum(xyz**2, axis=1)) if T is None
                else xyz @ T[2, :3] + T[2, 3]) / 1000.0
    ok = np.isfinite(dist) & (dist > 0)
    cols, rows = pixels[ok].astype(np.int64).T
    depth[rows, cols] = dist[ok].astype(np.float32)
    valid[rows, cols] = True
    if camera is not None and T is None:
        depth = np.where(valid, range_to_depth(depth, camera.K), 0).astype(np.float32)
    return depth, valid


def read_cornell_depth(image, depth_path, shape: tuple[int, int]):
    """A Cornell image's depth along the optical axis and its camera, from its point cloud
    (``pcdXXXX.txt``) or TIFF (``pcdXXXXd.tiff``).

    The camera is :func:`dlsr.intrinsics.cornell_camera`'s when the image has a camera file or
    a point cloud, else None (the Kinect estimate is not taken for a TIFF alone). A cloud's
    depth is :func:`pcd_depth`'s; a TIFF holding the range (real Cornell beside its cloud or
    fitted camera: ``camera.tiff_depth``) is converted with the camera's matrix, one holding
    ``z`` (graspsim's datasets) or without camera is used as read.

    Parameters
    ----------
    image : path-like
        Any of the image's files, with a Cornell name (``pcdXXXXr.png``).
    depth_path : path-like
        The point cloud (``.txt``) or depth image to read.
    shape : (H, W)

    Returns
    -------
    depth : ndarray of shape (H, W), float32
    valid : ndarray of shape (H, W), bool
    camera : CornellCamera or None
    """
    depth_path = Path(depth_path)
    p = Path(image)
    stem = p.parent / p.name[:7]
    cloud = read_pcd_points(depth_path) if depth_path.suffix == ".txt" else None
    known = (cloud is not None or Path(f"{stem}camera.json").is_file()
             or Path(f"{stem}.txt").is_file())
    camera = cornell_camera(p, cloud=cloud) if known else None
    if cloud is not None:
        depth, valid = pcd_depth(*cloud, shape, camera, what=f"point cloud {depth_path}")
        return depth, valid, camera
    depth, valid = clean_depth(read_depth_image(depth_path))
    _check_shape(depth_path, depth, shape, "depth image")
    if camera is not None and camera.tiff_depth == "range":
        depth = np.where(valid, range_to_depth(depth, camera.K), 0).astype(np.float32)
    return depth, valid, camera


def read_cornell_rectangles(path) -> list[GraspRectangle]:
    """Rectangles from a Cornell ``pcdXXXXcpos.txt`` / ``cneg.txt`` file.

    Four lines ``x y`` per rectangle, corners in Cornell order (``p0 -> p1`` along the closing
    direction). Blank lines are ignored. A rectangle with a non-finite corner (real files have
    ``NaN NaN`` lines) or with zero size is dropped with a logged warning naming the file and
    lines.

    Raises
    ------
    ValueError
        If the number of corner lines is not a multiple of 4, or a line is not two numbers.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"rectangle file not found: {path}")
    corners, lines = [], []
    with file_errors(path, "rectangle file"), open(path, encoding="utf-8") as fh:
        for lineno, line in enumerate(fh, start=1):
            s = line.strip()
            if not s:
                continue
            parts = s.split()
            try:
                if len(parts) != 2:
                    raise ValueError
                corners.append((float(parts[0]), float(parts[1])))
            except ValueError:
                raise CorruptFileError(f"{path}:{lineno}: expected 'x y', got {s[:60]!r}") \
                    from None
            lines.append(lineno)
    if len(corners) % 4:
        raise ValueError(
            f"{path}: {len(corners)} corner lines, not a multiple of 4 (4 lines per rectangle)"
        )
    rects = []
    for i in range(0, len(corners), 4):
        pts = np.array(corners[i : i + 4])
        where = f"{path}:{lines[i]}-{lines[i + 3]}"
        if not np.all(np.isfinite(pts)):
            logger.warning("%s: dropped rectangle with non-finite corners %s", where, pts.tolist())
            continue
        try:
            rects.append(GraspRectangle.from_corners(pts))
        except ValueError as exc:
            logger.warning("%s: dropped degenerate rectangle: %s", where, exc)
    return rects


def read_mapping(path) -> dict[str, str]:
    """Read an image-to-object mapping file.

    Format: whitespace-separated lines ``image_number object_id [anything else]``; blank lines
    and lines starting with ``#`` are ignored. Two layouts are accepted: one line per image
    (``image_number object_id [description]``, as :func:`write_cornell` writes) and the
    published ``objectClasses.txt`` (one line per labelled rectangle, ``image_number object_id
    object_name background_name``, so an image repeats). Numeric image numbers are normalised to
    4 digits (``100`` and ``0100`` are image ``"0100"``).

    Returns
    -------
    dict
        ``image_id -> object_id`` (strings).

    Raises
    ------
    ValueError
        If a line has fewer than two fields, or one image is given two different object ids.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"mapping file not found: {path}")
    mapping: dict[str, str] = {}
    first_line: dict[str, int] = {}
    with file_errors(path, "mapping file"), open(path, encoding="utf-8") as fh:
        for lineno, line in enumerate(fh, start=1):
            s = line.strip()
            if not s or s.startswith("#"):
                continue
            parts = s.split()
            if len(parts) < 2:
                raise CorruptFileError(
                    f"{path}:{lineno}: expected 'image_number object_id ...', got {s[:60]!r}"
                )
            image_id, object_id = normalize_image_id(parts[0]), parts[1]
            if image_id in mapping and mapping[image_id] != object_id:
                raise CorruptFileError(
                    f"{path}:{lineno}: image {image_id} has object id {object_id!r}, but line "
                    f"{first_line[image_id]} gave {mapping[image_id]!r}"
                )
            mapping.setdefault(image_id, object_id)
            first_line.setdefault(image_id, lineno)
    return mapping


def normalize_image_id(token: str) -> str:
    """A Cornell image id as :func:`load_cornell` gives it: digits padded to four (``"7"`` is
    ``"0007"``), anything else unchanged.

    Parameters
    ----------
    token : str

    Returns
    -------
    str
    """
    return f"{int(token):04d}" if token.isdigit() else token


# --------------------------------------------------------------------------------------------
# Resizing


def resize_sample(sample: GraspSample, scale: float) -> GraspSample:
    """A copy of ``sample`` with images and rectangles resized by ``scale``.

    The RGB image is resized with ``cv2.INTER_AREA``; depth, validity and mask with
    nearest-neighbour (``cv2.INTER_NEAREST_EXACT``), so missing pixels are never blended with
    valid ones. The new size is ``round(W * scale) x round(H * scale)``. Rectangle centres map
    like the pixel grid (pixel centres at integer coordinates, ``x' = (x + 0.5) * sx - 0.5``
    with ``sx = W' / W``, see :meth:`GraspRectangle.scaled`); sizes scale by ``sx``.
    """
    if not (np.isfinite(scale) and scale > 0):
        raise ValueError(f"scale must be a positive number, got {scale}")
    if scale == 1.0:
        return dataclasses.replace(sample)
    h, w = sample.rgb.shape[:2]
    nw, nh = max(1, int(round(w * scale))), max(1, int(round(h * scale)))
    sx, sy = nw / w, nh / h
    near = cv2.INTER_NEAREST_EXACT

    def rz(a, interp):
        return cv2.resize(a, (nw, nh), interpolation=interp)

    def rr(rects):
        return [r.scaled(sx, sy) for r in rects]

    return dataclasses.replace(
        sample,
        rgb=rz(sample.rgb, cv2.INTER_AREA),
        depth=rz(sample.depth, near),
        depth_valid=rz(sample.depth_valid.astype(np.uint8), near).astype(bool),
        mask=None if sample.mask is None else rz(sample.mask.astype(np.uint8), near).astype(bool),
        positives=rr(sample.positives),
        negatives=rr(sample.negatives),
        K=None if sample.K is None else _scaled_K(sample.K, sx, sy),
    )


def _scaled_K(K, sx: float, sy: float) -> np.ndarray:
    """The camera matrix of an image resized by ``(sx, sy)`` (pixel centres map as
    :meth:`GraspRectangle.scaled`: ``x' = (x + 0.5) sx - 0.5``)."""
    K = np.array(K, dtype=float)
    K[0, 0] *= sx
    K[1, 1] *= sy
    K[0, 2] = (K[0, 2] + 0.5) * sx - 0.5
    K[1, 2] = (K[1, 2] + 0.5) * sy - 0.5
    return K


# --------------------------------------------------------------------------------------------
# Cornell

_CORNELL_RGB = re.compile(r"^pcd(\d+)r\.png$")


def _cornell_images(root: Path) -> list[Path]:
    """``pcdXXXXr.png`` files directly in ``root`` and in its numbered folders (``01``..``10``)."""
    found = [p for p in root.iterdir() if p.is_file() and _CORNELL_RGB.match(p.name)]
    for sub in root.iterdir():
        if sub.is_dir() and sub.name.isdigit():
            found += [p for p in sub.iterdir() if p.is_file() and _CORNELL_RGB.match(p.name)]
    return sorted(found, key=lambda p: (_CORNELL_RGB.match(p.name).group(1), str(p)))


def load_cornell(
    root, mapping=None, scale: float = 1.0, depth_source: str = "auto"
) -> list[GraspSample]:
    """Load a Cornell grasping dataset.

    Layout: either the original folders ``01``..``10`` or a flat folder, each image ``pcdXXXX``
    with

    * ``pcdXXXXr.png``: 640x480 RGB;
    * depth, one of ``pcdXXXX.txt`` (PCD v0.7 ASCII point cloud, fields ``x y z rgb index`` in
      millimetres in any frame, ``index = row * 640 + col``) or ``pcdXXXXd.tiff`` (float32
      metres from the common preprocessing, the range; 0, negative or non-finite means
      missing); :func:`read_cornell_depth` gives the depth along the optical axis where the
      camera is known (:mod:`dlsr.intrinsics`);
    * ``pcdXXXXcpos.txt`` / ``pcdXXXXcneg.txt``: positive / negative rectangles (see
      :func:`read_cornell_rectangles`). An image without them loads with no rectangles (logged).
    * optionally ``pcdXXXXcamera.json`` (graspsim datasets, or the cache of a fit): the camera
      matrix, ``sample.K``; without it, an image with its point cloud gets the camera fitted
      to the cloud in whatever frame its points are (:func:`dlsr.intrinsics.cornell_camera`,
      cached beside it; a cloud that fits no camera gets the Kinect estimate and a logged
      warning), one with only the TIFF ``K=None``.

    Parameters
    ----------
    root : path-like
    mapping : path-like, dict or None
        Image-to-object mapping (see :func:`read_mapping`), or a dict ``image_id -> object_id``.
        When None, the first of :data:`MAPPING_FILENAMES` found in ``root`` is used; with none,
        every ``object_id`` is None (object-wise splits then raise). Images absent from a mapping
        get ``object_id=None`` with a logged warning.
    scale : float
        Resize images and rectangles together (see :func:`resize_sample`).
    depth_source : {"auto", "pcd", "tiff"}
        Which depth file to read; ``"auto"`` prefers the point cloud (it keeps missing pixels
        missing, whereas the preprocessed TIFFs are usually inpainted) and falls back to the TIFF.

    Returns
    -------
    list of GraspSample
        Sorted by image number; ``image_id`` is the 4-digit number (``"0100"``), ``source`` the
        RGB file.

    Raises
    ------
    FileNotFoundError
        If ``root`` or an image's depth source is missing.
    ValueError
        Unreadable image, bad rectangle file, inconsistent mapping.
    """
    samples = list(iter_cornell(root, mapping, scale, depth_source))
    ids = [s.image_id for s in samples]
    if len(set(ids)) != len(ids):
        dup = sorted({i for i in ids if ids.count(i) > 1})
        raise ValueError(f"{root}: image numbers appear in more than one folder: {dup}")
    return samples


def iter_cornell(root, mapping=None, scale: float = 1.0, depth_source: str = "auto"):
    """The images of a Cornell folder one at a time, as :func:`load_cornell` reads them.

    For folders too large to hold in memory at once (a writer that handles one image at a
    time). Takes :func:`load_cornell`'s parameters; image numbers repeated in two folders are
    not detected here.

    Yields
    ------
    GraspSample
        In image-number order.
    """
    root = Path(root)
    if not root.is_dir():
        raise FileNotFoundError(f"Cornell dataset folder not found: {root}")
    if depth_source not in ("auto", "pcd", "tiff"):
        raise ValueError(f"depth_source must be 'auto', 'pcd' or 'tiff', got {depth_source!r}")
    if mapping is None:
        for name in MAPPING_FILENAMES:
            if (root / name).is_file():
                mapping = root / name
                break
    if mapping is not None and not isinstance(mapping, dict):
        mapping = read_mapping(mapping)
    elif isinstance(mapping, dict):
        mapping = {normalize_image_id(str(k)): str(v) for k, v in mapping.items()}

    for rgb_path in _cornell_images(root):
        stem = rgb_path.name[:-len("r.png")]  # pcdXXXX
        image_id = normalize_image_id(_CORNELL_RGB.match(rgb_path.name).group(1))
        folder = rgb_path.parent
        rgb = read_rgb(rgb_path)
        shape = rgb.shape[:2]
        pcd, tiff = folder / f"{stem}.txt", folder / f"{stem}d.tiff"
        if depth_source in ("auto", "pcd") and pcd.is_file():
            depth, valid, camera = read_cornell_depth(rgb_path, pcd, shape)
        elif depth_source in ("auto", "tiff") and tiff.is_file():
            depth, valid, camera = read_cornell_depth(rgb_path, tiff, shape)
        else:
            wanted = {"auto": f"{pcd.name} or {tiff.name}", "pcd": pcd.name, "tiff": tiff.name}
            raise FileNotFoundError(
                f"no depth for {rgb_path}: expected {wanted[depth_source]} in {folder}"
            )
        rects = {}
        for kind in ("cpos", "cneg"):
            p = folder / f"{stem}{kind}.txt"
            if p.is_file():
                rects[kind] = read_cornell_rectangles(p)
            else:
                logger.warning("%s: no %s; loading image %s with no %s rectangles",
                               folder, p.name, image_id, kind)
                rects[kind] = []
        object_id = None
        if mapping is not None:
            object_id = mapping.get(image_id)
            if object_id is None:
                logger.warning("image %s (%s) is not in the object mapping; object_id is None",
                               image_id, rgb_path)
        sample = GraspSample(
            image_id=image_id,
            object_id=object_id,
            rgb=rgb,
            depth=depth,
            depth_valid=valid,
            positives=rects["cpos"],
            negatives=rects["cneg"],
            source=rgb_path,
            K=None if camera is None else camera.K,
        )
        yield resize_sample(sample, scale) if scale != 1.0 else sample


def _format_corners(rects) -> str:
    if not rects:
        return ""
    corners = np.concatenate([r.corners() for r in rects])
    return "".join(f"{x:.10f} {y:.10f}\n" for x, y in corners)


def write_cornell(samples: Sequence[GraspSample], root) -> Path:
    """Write samples in the Cornell layout (the ``d.tiff`` depth variant) plus a mapping file.

    For each sample ``pcdXXXX`` in folder ``NN = XXXX // 100`` (as the real dataset:
    ``pcd0100`` to ``pcd0199`` in ``01``, ..., ``pcd1000`` to ``pcd1034`` in ``10``):
    ``pcdXXXXr.png`` (RGB), ``pcdXXXXd.tiff`` (uncompressed float32 depth in metres, **0 where
    ``depth_valid`` is False**, so validity round-trips), ``pcdXXXXcpos.txt`` and
    ``pcdXXXXcneg.txt`` (four ``x y`` corner lines per rectangle, Cornell order, 10 decimals).
    ``root/image_objects.txt`` holds one line per image ``image_number object_id image_id``
    (images with ``object_id=None`` are left out, so they load back as None).

    Image numbers are the sample ids when all are digit strings; otherwise samples are numbered
    ``0000``, ``0001``, ... in order and the original id is kept in the mapping file's third
    column. Masks are not part of the Cornell format and are not written.

    Returns
    -------
    Path
        ``root``, so ``load_cornell(write_cornell(samples, root))`` reads them back.

    Raises
    ------
    ValueError
        Duplicate ids, an object id containing whitespace, or a valid pixel with depth <= 0
        (it could not round-trip).
    """
    root = Path(root)
    samples = list(samples)
    ids = [str(s.image_id) for s in samples]
    if len(set(ids)) != len(ids):
        raise ValueError("write_cornell: duplicate image ids")
    if all(i.isdigit() for i in ids):
        numbers = [int(i) for i in ids]
        if len(set(numbers)) != len(numbers):
            raise ValueError(f"write_cornell: image ids {ids} collide as numbers")
    else:
        numbers = list(range(len(samples)))
        logger.info("write_cornell: image ids are not all numbers; numbering images from 0000")
    root.mkdir(parents=True, exist_ok=True)
    lines = [write_cornell_image(s, root, num) for num, s in zip(numbers, samples, strict=True)]
    write_cornell_mapping(root, [ln for ln in lines if ln is not None])
    return root


def write_cornell_image(sample: GraspSample, root, number: int) -> str | None:
    """Write one image of the Cornell layout as ``pcd{number:04d}`` (see :func:`write_cornell`).

    Returns
    -------
    str or None
        Its mapping-file line (``image_number object_id image_id``), None without an object id.
    """
    import tifffile

    s = sample
    root = Path(root)
    stem = f"pcd{number:04d}"
    folder = root / f"{number // 100:02d}"
    folder.mkdir(parents=True, exist_ok=True)
    depth = np.asarray(s.depth, dtype=np.float32)
    valid = np.asarray(s.depth_valid, dtype=bool)
    if depth.shape != s.rgb.shape[:2] or valid.shape != depth.shape:
        raise ValueError(f"write_cornell: image {s.image_id}: rgb, depth and validity shapes "
                         f"differ ({s.rgb.shape}, {depth.shape}, {valid.shape})")
    if np.any(valid & ~(np.isfinite(depth) & (depth > 0))):
        raise ValueError(f"write_cornell: image {s.image_id}: some valid pixels have depth "
                         "<= 0 or non-finite; they cannot be written")
    Image.fromarray(np.asarray(s.rgb, dtype=np.uint8)).save(folder / f"{stem}r.png")
    tifffile.imwrite(folder / f"{stem}d.tiff", np.where(valid, depth, np.float32(0)))
    (folder / f"{stem}cpos.txt").write_text(_format_corners(s.positives))
    (folder / f"{stem}cneg.txt").write_text(_format_corners(s.negatives))
    if s.object_id is None:
        return None
    oid = str(s.object_id)
    if not oid or any(c.isspace() for c in oid):
        raise ValueError(f"write_cornell: image {s.image_id}: object id {oid!r} must be "
                         "one non-empty word")
    return f"{number:04d} {oid} {s.image_id}\n"


def write_cornell_mapping(root, lines: Sequence[str]) -> Path:
    """Write the image-to-object mapping file of a Cornell-layout folder."""
    path = Path(root) / MAPPING_FILENAMES[0]
    return write_text_atomic(path, "# image_number object_id original_image_id\n"
                             + "".join(lines))


# --------------------------------------------------------------------------------------------
# Jacquard


def read_jacquard_grasps(path) -> list[GraspRectangle]:
    """Grasps from a Jacquard ``*_grasps.txt`` file (lines ``x;y;theta_deg;opening;jaw_size``).

    **Angle convention.** Jacquard's ``theta_deg`` is measured *clockwise as the image is
    displayed* (the usual ``atan2(drow, dcol)`` of a y-down image frame), the opposite sign of
    ours, so ``theta = -radians(theta_deg)``. This was determined by drawing the grasps of the
    real sample views in ``../shared/data/jacquard_samples`` both ways: with the sign flipped the
    opening edges (red) cross the ladder rails and chair legs with the jaw plates (blue) along
    their sides; with the sign kept, most rectangles lie at a mirrored angle across the
    background. It agrees with the Jacquard loader of GG-CNN (Morrison et al. 2018), which builds
    its grasps with angle ``-theta / 180 * pi``. ``opening`` is ``w`` (along the closing
    direction) and ``jaw_size`` is ``h``. Lines with non-finite values or a zero size are dropped
    with a logged warning.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"grasp file not found: {path}")
    rects = []
    with file_errors(path, "grasp file"), open(path, encoding="utf-8") as fh:
        for lineno, line in enumerate(fh, start=1):
            s = line.strip()
            if not s:
                continue
            parts = s.split(";")
            try:
                if len(parts) != 5:
                    raise ValueError
                x, y, t, w, h = (float(p) for p in parts)
            except ValueError:
                raise CorruptFileError(
                    f"{path}:{lineno}: expected 'x;y;theta_deg;opening;jaw_size', "
                    f"got {s[:60]!r}"
                ) from None
            try:
                rects.append(GraspRectangle(x, y, -np.deg2rad(t), w, h))
            except ValueError as exc:
                logger.warning("%s:%d: dropped grasp: %s", path, lineno, exc)
    return rects


def load_jacquard(root, depth: str = "stereo", scale: float = 1.0) -> list[GraspSample]:
    """Load Jacquard views found anywhere under ``root``.

    Each view is a set of files ``<view>_<hash>_{RGB.png, mask.png, perfect_depth.tiff,
    stereo_depth.tiff, grasps.txt}`` (1024x1024). The ``image_id`` is ``"<view>_<hash>"``, the
    ``object_id`` the hash, ``mask`` the object mask (``mask.png > 0``), ``positives`` the grasps,
    ``negatives`` empty (use :func:`sample_negatives`) and ``K`` the estimated camera matrix
    (:func:`dlsr.intrinsics.jacquard_camera_matrix`; Jacquard ships none). Jacquard angles
    are clockwise as displayed, so ``theta = -radians(theta_deg)``, ``w = opening``,
    ``h = jaw_size`` (found by drawing the real sample views; see :func:`read_jacquard_grasps`).

    Parameters
    ----------
    root : path-like
    depth : {"stereo", "perfect"}
        Which depth image to read. Stereo depth marks missing pixels with -1; those (and any
        non-finite or non-positive value) become 0 with ``depth_valid`` False.
    scale : float
        Resize images and rectangles together; 0.5 brings views close to Cornell's scale.

    Returns
    -------
    list of GraspSample, sorted by (hash, view).
    """
    root = Path(root)
    if not root.is_dir():
        raise FileNotFoundError(f"Jacquard dataset folder not found: {root}")
    if depth not in ("stereo", "perfect"):
        raise ValueError(f"depth must be 'stereo' or 'perfect', got {depth!r}")
    found = []
    for rgb_path in root.rglob("*_RGB.png"):
        prefix = rgb_path.name[: -len("_RGB.png")]
        view, sep, obj = prefix.partition("_")
        if not sep or not obj:
            raise ValueError(f"{rgb_path}: expected a name '<view>_<hash>_RGB.png'")
        found.append((obj, int(view) if view.isdigit() else view, prefix, rgb_path))
    found.sort(key=lambda t: (t[0], str(t[1]).zfill(8)))
    samples = []
    for obj, _view, prefix, rgb_path in found:
        folder = rgb_path.parent
        rgb = read_rgb(rgb_path)
        shape = rgb.shape[:2]
        depth_path = folder / f"{prefix}_{depth}_depth.tiff"
        d, valid = clean_depth(read_depth_image(depth_path))
        _check_shape(depth_path, d, shape, "depth image")
        mask_path = folder / f"{prefix}_mask.png"
        mask = read_gray(mask_path) > 0
        _check_shape(mask_path, mask, shape, "mask")
        grasps = read_jacquard_grasps(folder / f"{prefix}_grasps.txt")
        if not grasps:
            logger.warning("%s: no grasps", folder / f"{prefix}_grasps.txt")
        sample = GraspSample(
            image_id=prefix,
            object_id=obj,
            rgb=rgb,
            depth=d,
            depth_valid=valid,
            positives=grasps,
            source=rgb_path,
            mask=mask,
            K=jacquard_camera_matrix(shape),
        )
        samples.append(resize_sample(sample, scale) if scale != 1.0 else sample)
    return samples


# --------------------------------------------------------------------------------------------
# Negatives


def sample_negatives(
    sample: GraspSample,
    n: int,
    rng,
    max_rounds: int = 50,
    size_jitter: float = 0.2,
) -> list[GraspRectangle]:
    """Random negative rectangles for a sample labelled with positives only (Jacquard).

    Candidates are drawn in rounds: size ``(w, h)`` of a random positive times a factor uniform in
    ``[1 - size_jitter, 1 + size_jitter]``; angle uniform; centre on a random object pixel when
    ``sample.mask`` has any (plus sub-pixel jitter), otherwise a random positive's centre plus a
    normal offset of standard deviation the mean positive size. Candidates whose centre is
    outside the image are discarded; the rest are kept when they **fail** the rectangle metric
    (:func:`dlsr.metrics.rectangle_metric_many`) against every positive. The sample is not
    modified.

    Parameters
    ----------
    sample : GraspSample
        Needs at least one positive.
    n : int
        Number of negatives (>= 0).
    rng : numpy.random.Generator or int or None
        Resolved with ``numpy.random.default_rng``.
    max_rounds : int
        Rounds of ``max(4 n, 64)`` candidates each before giving up.
    size_jitter : float
        Relative size spread, in ``[0, 1)``.

    Returns
    -------
    list of GraspRectangle, length ``n``.

    Raises
    ------
    ValueError
        No positives, bad arguments, or fewer than ``n`` negatives found after ``max_rounds``
        (an error rather than a short list so a training set never silently shrinks).
    """
    if int(n) != n or n < 0:
        raise ValueError(f"n must be a non-negative integer, got {n}")
    n = int(n)
    if not 0 <= size_jitter < 1:
        raise ValueError(f"size_jitter must be in [0, 1), got {size_jitter}")
    if n == 0:
        return []
    if not sample.positives:
        raise ValueError(f"sample_negatives: image {sample.image_id} has no positives to size "
                         "and place negatives from")
    rng = np.random.default_rng(rng)
    pos = rects_to_array(sample.positives)
    h_img, w_img = sample.rgb.shape[:2]
    mask_pts = None
    if sample.mask is not None and np.any(sample.mask):
        rows, cols = np.nonzero(sample.mask)
        mask_pts = np.column_stack([cols, rows]).astype(float)
    spread = float(np.mean(pos[:, 3:5]))
    batch = max(4 * n, 64)
    found: list[np.ndarray] = []
    count = 0
    for _ in range(max_rounds):
        pick = rng.integers(len(pos), size=batch)
        sizes = pos[pick, 3:5] * rng.uniform(1 - size_jitter, 1 + size_jitter, size=(batch, 2))
        if mask_pts is not None:
            centres = mask_pts[rng.integers(len(mask_pts), size=batch)]
            centres = centres + rng.uniform(-0.5, 0.5, size=(batch, 2))
        else:
            centres = pos[rng.integers(len(pos), size=batch), :2]
            centres = centres + rng.normal(0, spread, size=(batch, 2))
        theta = rng.uniform(-np.pi / 2, np.pi / 2, size=batch)
        cand = np.column_stack([centres, theta, sizes])
        inside = (
            (cand[:, 0] >= 0) & (cand[:, 0] <= w_img - 1)
            & (cand[:, 1] >= 0) & (cand[:, 1] <= h_img - 1)
        )
        cand = cand[inside]
        cand = cand[~rectangle_metric_many(cand, pos)]
        found.append(cand)
        count += len(cand)
        if count >= n:
            break
    if count < n:
        raise ValueError(
            f"sample_negatives: found only {count} of {n} negatives for image {sample.image_id} "
            f"after {max_rounds} rounds of {batch} candidates"
        )
    return array_to_rects(np.concatenate(found)[:n])


# --------------------------------------------------------------------------------------------
# Splits


def groups(samples: Sequence[GraspSample], by: str = "image") -> np.ndarray:
    """Group labels for scikit-learn's group-aware splitters (``GroupKFold(...).split(X, y, g)``).

    Parameters
    ----------
    samples : sequence of GraspSample
    by : {"image", "object"}

    Returns
    -------
    ndarray of shape (n_samples,), object (strings)

    Raises
    ------
    ValueError
        ``by="object"`` and some sample has no ``object_id`` (e.g. Cornell loaded without a
        mapping file).
    """
    if by == "image":
        return np.array([str(s.image_id) for s in samples], dtype=object)
    if by == "object":
        missing = [s.image_id for s in samples if s.object_id is None]
        if missing:
            raise ValueError(
                f"object-wise split needs object ids, but {len(missing)} image(s) have none "
                f"(first: {missing[0]}); load Cornell with a mapping file"
            )
        return np.array([str(s.object_id) for s in samples], dtype=object)
    raise ValueError(f"by must be 'image' or 'object', got {by!r}")


def _group_folds(g: np.ndarray, k: int, seed) -> list[tuple[np.ndarray, np.ndarray]]:
    if int(k) != k or k < 2:
        raise ValueError(f"k must be an integer >= 2, got {k}")
    k = int(k)
    uniq, inverse, counts = np.unique(g.astype(str), return_inverse=True, return_counts=True)
    if len(uniq) < k:
        raise ValueError(f"cannot make {k} folds from {len(uniq)} groups")
    rng = np.random.default_rng(seed)
    order = rng.permutation(len(uniq))
    order = order[np.argsort(-counts[order], kind="stable")]  # largest first, random ties
    fold_of_group = np.empty(len(uniq), dtype=int)
    load = np.zeros(k, dtype=int)
    for gi in order:
        f = int(np.argmin(load))
        fold_of_group[gi] = f
        load[f] += counts[gi]
    fold = fold_of_group[inverse]
    idx = np.arange(len(g))
    return [(idx[fold != f], idx[fold == f]) for f in range(k)]


def image_wise_folds(samples: Sequence[GraspSample], k: int = 5, seed=0):
    """``k`` folds with every image in exactly one test fold.

    Returns
    -------
    list of (train_idx, test_idx)
        Sorted int index arrays; usable directly as scikit-learn's ``cv=`` argument.
    """
    return _group_folds(groups(samples, "image"), k, seed)


def object_wise_folds(samples: Sequence[GraspSample], k: int = 5, seed=0):
    """``k`` folds with no object in two folds (all images of an object test together).

    Objects are assigned largest first (random order among equal sizes, from ``seed``) to the
    fold with the fewest images, so folds are balanced in images.

    Returns
    -------
    list of (train_idx, test_idx)
        Sorted int index arrays; usable directly as scikit-learn's ``cv=`` argument.

    Raises
    ------
    ValueError
        A sample without ``object_id``, or fewer objects than folds.
    """
    return _group_folds(groups(samples, "object"), k, seed)

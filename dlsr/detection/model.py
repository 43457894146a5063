"""The trained detection model: :class:`DLSRDetector` (representation, encoder, linear SVM and
the rectangle-image settings), its scores and its files (``.npz`` + ``.json``).

Part of :mod:`dlsr.detection`.
"""

from __future__ import annotations

import hashlib
import io
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..features import ENCODERS, LEARNERS, Representation, rectangle_features
from ..records import CorruptFileError, atomic_write, load_npz, read_json, write_text_atomic
from ..rectangles import GraspRectangle
from .grid import SearchGrid
from .registry import DETECTOR_KINDS, build_detector

SIZE = 24
PATCH = 6
GRID = SIZE - PATCH + 1  # 19 patch positions per side
SPLIT = 10  # quadrant split of the 19 x 19 code map (10 | 9)
PATCHES_PER_RECTANGLE = GRID * GRID
FORMAT_VERSION = 1


def _default_preprocess() -> dict:
    """The keyword defaults of :func:`dlsr.preprocess.rectangle_images` (recognition's)."""
    import inspect

    from ..preprocess import rectangle_images

    out = {"size": SIZE}
    for name, par in inspect.signature(rectangle_images).parameters.items():
        if par.kind is inspect.Parameter.KEYWORD_ONLY and par.default is not inspect._empty:
            out[name] = par.default
    return out


def _jsonable(x):
    if isinstance(x, np.generic):
        return x.item()
    return x


@dataclass
class DLSRDetector:
    """A trained DLSR grasp model: representation, feature standardisation and linear SVM.

    ``predict(obs)`` runs the dense detector (``detector="dense"``) or the exact grid search
    (``"exact"``) with ``grid``; build either explicitly with :meth:`detector`.

    Attributes
    ----------
    representation : Representation
    encoder : str
    encoder_param : float or int or None
    polarity : bool
    scaler_mean, scaler_scale : ndarray of shape (n_features,)
    coef : ndarray of shape (n_features,)
    intercept : float
    preprocess : dict
        Keyword options of :func:`dlsr.preprocess.rectangle_images`.
    config : dict
        Training information and detector options (``detector``, ``grid``, ``top_k``,
        ``rescore``, ``region``) saved with the model.
    physical_edges : tuple of ndarray or None
        Bin edges of the physical features (:class:`dlsr.detection.physical.PhysicalEncoder`)
        when the SVM was trained with them (``train_detector(physical=True)``), else None.
    physical_coef : ndarray of shape (n_indicators,) or None
        The SVM's weights on those indicators, feature standardisation folded in (its constant
        is in ``intercept``): a rectangle's score is its DLSR score plus
        :meth:`physical_scores`.
    """

    representation: Representation
    encoder: str
    encoder_param: object
    polarity: bool
    scaler_mean: np.ndarray
    scaler_scale: np.ndarray
    coef: np.ndarray
    intercept: float
    preprocess: dict = field(default_factory=_default_preprocess)
    config: dict = field(default_factory=dict)
    physical_edges: tuple | None = None
    physical_coef: np.ndarray | None = None

    # -- scores ------------------------------------------------------------------------------
    @property
    def n_codes(self) -> int:
        return len(self.coef) // 4

    def quadrant_weights(self):
        """The SVM folded with the feature standardisation.

        Returns
        -------
        V : ndarray of shape (k, 4), float64
            Per-quadrant weights on the codes (TL, TR, BL, BR).
        const : float
            ``score = const + sum_q V[:, q] . pooled_q``.
        """
        k = self.n_codes
        w = np.asarray(self.coef, dtype=np.float64) / np.asarray(self.scaler_scale, np.float64)
        const = float(self.intercept - w @ np.asarray(self.scaler_mean, np.float64))
        return w.reshape(4, k).T.copy(), const

    def features(self, images, masks, chunk_size: int = 64) -> np.ndarray:
        return rectangle_features(images, masks, self.representation, self.encoder,
                                  self.encoder_param, polarity=self.polarity,
                                  chunk_size=chunk_size)

    def image_scores(self, images, masks, chunk_size: int = 64) -> np.ndarray:
        """SVM decision values of rectangle images (the recognition model's scores)."""
        F = self.features(images, masks, chunk_size)
        Z = ((F - self.scaler_mean) / self.scaler_scale).astype(F.dtype, copy=False)
        return Z @ np.asarray(self.coef, np.float64) + float(self.intercept)

    def rectangle_scores(self, obs, rects, batch_size: int = 256) -> np.ndarray:
        """Exact scores of rectangles of an observation (rectangle images, features, SVM).

        The DLSR part only: a model trained with physical features adds
        :meth:`physical_scores` (the detectors do).
        """
        from ..preprocess import rectangle_images

        rects = np.asarray(rects, dtype=float).reshape(-1, 5)
        out = np.empty(len(rects))
        for s in range(0, len(rects), batch_size):
            im, mk = rectangle_images(obs["rgb"], obs["depth"], obs.get("depth_valid"),
                                      rects[s:s + batch_size], **self.preprocess)
            out[s:s + batch_size] = self.image_scores(im, mk)
        return out

    @property
    def physical(self) -> bool:
        """Whether the SVM weighs physical features (:mod:`dlsr.detection.physical`)."""
        return self.physical_coef is not None

    def physical_scores(self, obs, rects, region=None, table=None) -> np.ndarray:
        """The physical term of the rectangles' scores (zeros for a model without one).

        Parameters
        ----------
        obs : dict
            ``depth``, ``depth_valid``, ``K`` (needed by a physical model), ``rgb`` and
            optional ``mask``.
        rects : ndarray of shape (n, 5)
        region : ndarray of shape (H, W), bool, or None
            The object region; None finds it as the detectors do by default
            (:func:`dlsr.detection.object_region`, ``method="auto"``).
        table : ndarray of shape (H, W) or None
            The table surface (:func:`dlsr.detection.table_surface`); None fits it.

        Returns
        -------
        ndarray of shape (n,), float64
        """
        rects = np.asarray(rects, dtype=float).reshape(-1, 5)
        if not self.physical or len(rects) == 0:
            return np.zeros(len(rects))
        from .grid import object_region, table_surface
        from .physical import PhysicalEncoder, physical_features

        if obs.get("K") is None:
            raise ValueError("this model weighs physical features (trained with "
                             "physical=True): the observation needs its camera matrix 'K'")
        if region is None:
            region, _ = object_region(obs)
        if table is None:
            table = table_surface(obs["depth"], obs.get("depth_valid"))
        F = physical_features(obs, rects, region, table)
        enc = PhysicalEncoder()
        enc.edges_ = [np.asarray(e, dtype=float) for e in self.physical_edges]
        return enc.transform(F).astype(np.float64) @ np.asarray(self.physical_coef, np.float64)

    # -- detectors ---------------------------------------------------------------------------
    def detector(self, kind: str | None = None, **options):
        """The detector of ``kind`` on this model (:func:`dlsr.detection.build_detector`).

        Parameters
        ----------
        kind : {"dense", "exact", "lattice"} or None, default None
            None takes the saved ``config["detector"]``, else ``"dense"``.
        **options
            Keyword options of the detector; they default to the saved ``config`` (``grid``,
            ``top_k``, ``rescore``, ``region``); the lattice detector ignores the grid
            search's (``grid``, ``coarse_to_fine``, ``rescore``).

        Returns
        -------
        DenseDetector or ExactGridDetector or LatticeDetector
        """
        return build_detector(self, kind, **options)

    def predict(self, obs) -> list[GraspRectangle]:
        """Rectangles best first (see :meth:`detector`)."""
        if not hasattr(self, "_detector"):
            self._detector = self.detector()
        return self._detector.predict(obs)

    # -- persistence -------------------------------------------------------------------------
    @staticmethod
    def _paths(path):
        p = Path(path)
        if p.suffix in (".npz", ".json"):
            p = p.with_suffix("")
        return p.with_name(p.name + ".npz"), p.with_name(p.name + ".json")

    def save(self, path) -> tuple[Path, Path]:
        """Write ``<path>.npz`` (arrays) and ``<path>.json`` (everything else); never pickle.

        ``path`` may end in ``.npz`` or ``.json`` (the suffix is replaced). Each file is
        written to a temporary file and renamed, so a kill or an error never leaves a
        half-written one; the JSON records the SHA-256 of the arrays, so :meth:`load` also
        refuses an ``.npz`` and ``.json`` of two different saves.
        """
        npz, js = self._paths(path)
        arrays = self.representation.to_arrays(prefix="rep_")
        arrays.update(scaler_mean=np.asarray(self.scaler_mean),
                      scaler_scale=np.asarray(self.scaler_scale),
                      coef=np.asarray(self.coef), intercept=np.asarray([self.intercept]))
        if self.physical:
            arrays["physical_coef"] = np.asarray(self.physical_coef, dtype=np.float64)
            for j, e in enumerate(self.physical_edges):
                arrays[f"physical_edges_{j}"] = np.asarray(e, dtype=np.float64)
        buf = io.BytesIO()
        np.savez(buf, **{k: np.asarray(v) for k, v in arrays.items()})
        data = buf.getvalue()
        meta = {
            "format": "dlsr-detector",
            "version": FORMAT_VERSION,
            "arrays": npz.name,
            "arrays_sha256": hashlib.sha256(data).hexdigest(),
            "learner": self.representation.learner,
            "natural_param": _jsonable(self.representation.natural_param),
            "encoder": self.encoder,
            "encoder_param": _jsonable(self.encoder_param),
            "polarity": bool(self.polarity),
            "preprocess": self.preprocess,
            "config": self.config,
        }
        if self.physical:
            from .physical import PHYSICAL_FEATURES

            meta["physical"] = {"features": list(PHYSICAL_FEATURES),
                                "n_columns": len(self.physical_edges)}
        text = json.dumps(meta, indent=2)  # before any file is touched: fails on bad config
        with atomic_write(npz, "wb") as fh:
            fh.write(data)
        write_text_atomic(js, text)
        return npz, js

    @classmethod
    def load(cls, path) -> DLSRDetector:
        """Read a model written by :meth:`save` (``path`` with or without suffix).

        Raises
        ------
        FileNotFoundError
            One of the two files is missing.
        ValueError
            A file is truncated, empty, not JSON / npz, of another save than its partner, or
            holds values a model cannot have (unknown learner or encoder, arrays of
            inconsistent shapes or non-finite values, a bad search grid); the message names
            the file and what is wrong.
        """
        npz, js = cls._paths(path)
        for p in (js, npz):
            if not p.is_file():
                raise FileNotFoundError(f"detector model file not found: {p}")
        meta = read_json(js, "model file")
        if meta.get("format") != "dlsr-detector":
            raise CorruptFileError(f"model file {js}: not a DLSR detector model (format "
                                   f"{meta.get('format')!r})")
        _check_meta(meta, js)
        digest = meta.get("arrays_sha256")
        if digest is not None and hashlib.sha256(npz.read_bytes()).hexdigest() != digest:
            raise CorruptFileError(f"model file {npz}: not the arrays {js.name} was saved with "
                                   "(changed, truncated or from another save)")
        arrays = load_npz(npz, ("scaler_mean", "scaler_scale", "coef", "intercept",
                                "rep_dictionary"), what="model file")
        _check_arrays(arrays, bool(meta["polarity"]), npz)
        edges, pcoef = _physical_arrays(arrays, meta, npz)
        rep = Representation.from_arrays(arrays, meta["learner"], meta.get("natural_param"),
                                         prefix="rep_")
        return cls(representation=rep, encoder=meta["encoder"],
                   encoder_param=meta.get("encoder_param"), polarity=bool(meta["polarity"]),
                   scaler_mean=arrays["scaler_mean"], scaler_scale=arrays["scaler_scale"],
                   coef=arrays["coef"], intercept=float(arrays["intercept"][0]),
                   preprocess=dict(meta.get("preprocess") or _default_preprocess()),
                   config=dict(meta.get("config") or {}), physical_edges=edges,
                   physical_coef=pcoef)


def _physical_arrays(arrays: dict, meta: dict, npz: Path):
    """``(edges, coef)`` of a model's physical term, or ``(None, None)`` without one."""
    phys = meta.get("physical")
    if phys is None:
        return None, None
    from .physical import PHYSICAL_FEATURES

    def bad(what):
        raise CorruptFileError(f"model file {npz}: {what}")

    if not isinstance(phys, dict) or phys.get("features") != list(PHYSICAL_FEATURES):
        bad(f"physical features {phys!r} are not this dlsr's {list(PHYSICAL_FEATURES)}"[:300])
    edges = tuple(arrays.get(f"physical_edges_{j}") for j in range(len(PHYSICAL_FEATURES)))
    coef = arrays.get("physical_coef")
    if coef is None or any(e is None or e.ndim != 1 for e in edges):
        bad("a physical model needs physical_coef and one physical_edges_<j> per feature")
    if coef.shape != (sum(len(e) + 1 for e in edges),):
        bad(f"physical_coef has shape {coef.shape}, the bins {sum(len(e) + 1 for e in edges)}")
    return edges, coef


def _check_meta(meta: dict, js: Path) -> None:
    """Refuse a model description a detector could not run with (message naming ``js``)."""

    def bad(what):
        raise CorruptFileError(f"model file {js}: {what}")

    version = meta.get("version")
    if not isinstance(version, int) or version > FORMAT_VERSION:
        bad(f"format version {version!r}; this dlsr reads versions up to {FORMAT_VERSION}")
    if meta.get("learner") not in LEARNERS:
        bad(f"learner must be one of {LEARNERS}, got {meta.get('learner')!r}")
    if meta.get("encoder") not in ENCODERS:
        bad(f"encoder must be one of {ENCODERS}, got {meta.get('encoder')!r}")
    if not isinstance(meta.get("polarity"), bool):
        bad(f"polarity must be true or false, got {meta.get('polarity')!r}")
    for key in ("encoder_param", "natural_param"):
        v = meta.get(key)
        if v is not None and (isinstance(v, bool) or not isinstance(v, int | float)
                              or not np.isfinite(v)):
            bad(f"{key} must be a number or null, got {v!r}")
    pre = meta.get("preprocess")
    if pre is not None:
        known = _default_preprocess()
        if not isinstance(pre, dict) or set(pre) - set(known):
            bad(f"preprocess must be a table of {sorted(known)}, got {pre!r}"[:300])
    config = meta.get("config")
    if config is None:
        return
    if not isinstance(config, dict):
        bad(f"config must be a table, got {type(config).__name__}")
    if config.get("detector", "dense") not in DETECTOR_KINDS:
        bad(f"config detector must be one of {DETECTOR_KINDS}, got {config['detector']!r}")
    if "grid" in config:
        g = config["grid"]
        try:
            grid = SearchGrid.from_dict(g)
            values = [*grid.angles_deg, *grid.openings, *grid.jaws, grid.step,
                      grid.min_coverage]
            ok = (all(isinstance(v, int | float) and np.isfinite(v) for v in values)
                  and grid.openings and grid.jaws and grid.angles_deg and grid.step > 0
                  and isinstance(grid.dilate, int) and grid.dilate >= 0
                  and 0 <= grid.min_coverage <= 1
                  and grid.coverage_on in ("dilated", "object"))
        except (TypeError, ValueError):
            ok = False
        if not ok:
            bad(f"config grid is not a search grid: {g!r}"[:300])


def _check_arrays(arrays: dict, polarity: bool, npz: Path) -> None:
    """Refuse arrays of inconsistent shapes or non-finite values (message naming ``npz``)."""

    def bad(what):
        raise CorruptFileError(f"model file {npz}: {what}")

    dim = PATCH * PATCH * 8
    D = arrays["rep_dictionary"]
    if D.ndim != 2 or D.shape[1] != dim or len(D) == 0:
        bad(f"rep_dictionary must have shape (n_atoms, {dim}), got {D.shape}")
    shapes = {"rep_centroids": D.shape, "rep_zca_mean": (dim,), "rep_zca_matrix": (dim, dim),
              "intercept": (1,)}
    n_features = 4 * len(D) * (2 if polarity else 1)
    shapes.update(dict.fromkeys(("coef", "scaler_mean", "scaler_scale"), (n_features,)))
    for key, shape in shapes.items():
        a = arrays.get(key)
        if a is None:
            continue
        if a.shape != shape:
            bad(f"{key} must have shape {shape} for {len(D)} atoms"
                f"{' with polarity' if polarity else ''}, got {a.shape}")
    if ("rep_zca_mean" in arrays) != ("rep_zca_matrix" in arrays):
        bad("rep_zca_mean and rep_zca_matrix go together")
    for key, a in arrays.items():
        if not np.issubdtype(a.dtype, np.number) or not np.all(np.isfinite(a)):
            bad(f"{key} must hold finite numbers")
    if np.any(arrays["scaler_scale"] <= 0):
        bad("scaler_scale must be positive")

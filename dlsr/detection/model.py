"""The trained detection model: :class:`DLSRDetector` (representation, encoder, linear SVM and
the rectangle-image settings), its scores and its files (``.npz`` + ``.json``).

Part of :mod:`dlsr.detection`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..features import Representation, rectangle_features
from ..rectangles import GraspRectangle
from .grid import SearchGrid

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
        """Exact scores of rectangles of an observation (rectangle images, features, SVM)."""
        from ..preprocess import rectangle_images

        rects = np.asarray(rects, dtype=float).reshape(-1, 5)
        out = np.empty(len(rects))
        for s in range(0, len(rects), batch_size):
            im, mk = rectangle_images(obs["rgb"], obs["depth"], obs.get("depth_valid"),
                                      rects[s:s + batch_size], **self.preprocess)
            out[s:s + batch_size] = self.image_scores(im, mk)
        return out

    # -- detectors ---------------------------------------------------------------------------
    def detector(self, kind: str | None = None, **options):
        """An :class:`~dlsr.detection.ExactGridDetector` or :class:`~dlsr.detection.DenseDetector`
        on this model.

        Options default to the saved ``config`` (``grid``, ``top_k``, ``rescore``, ``region``).
        """
        from .dense import DenseDetector
        from .exact import ExactGridDetector

        kind = kind or self.config.get("detector", "dense")
        opts = {}
        if "grid" in self.config:
            opts["grid"] = SearchGrid.from_dict(self.config["grid"])
        for key in ("top_k", "region"):
            if key in self.config:
                opts[key] = self.config[key]
        if kind == "dense" and "rescore" in self.config:
            opts["rescore"] = self.config["rescore"]
        opts.update(options)
        if kind == "exact":
            return ExactGridDetector(self, **opts)
        if kind == "dense":
            return DenseDetector(self, **opts)
        raise ValueError(f"unknown detector {kind!r}; choose 'dense' or 'exact'")

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

        ``path`` may end in ``.npz`` or ``.json`` (the suffix is replaced).
        """
        npz, js = self._paths(path)
        npz.parent.mkdir(parents=True, exist_ok=True)
        arrays = self.representation.to_arrays(prefix="rep_")
        arrays.update(scaler_mean=np.asarray(self.scaler_mean),
                      scaler_scale=np.asarray(self.scaler_scale),
                      coef=np.asarray(self.coef), intercept=np.asarray([self.intercept]))
        np.savez(npz, **{k: np.asarray(v) for k, v in arrays.items()})
        meta = {
            "format": "dlsr-detector",
            "version": FORMAT_VERSION,
            "arrays": npz.name,
            "learner": self.representation.learner,
            "natural_param": _jsonable(self.representation.natural_param),
            "encoder": self.encoder,
            "encoder_param": _jsonable(self.encoder_param),
            "polarity": bool(self.polarity),
            "preprocess": self.preprocess,
            "config": self.config,
        }
        js.write_text(json.dumps(meta, indent=2))
        return npz, js

    @classmethod
    def load(cls, path) -> DLSRDetector:
        """Read a model written by :meth:`save` (``path`` with or without suffix)."""
        npz, js = cls._paths(path)
        for p in (js, npz):
            if not p.is_file():
                raise FileNotFoundError(f"detector model file not found: {p}")
        try:
            meta = json.loads(js.read_text())
        except json.JSONDecodeError as exc:
            raise ValueError(f"{js}: not a JSON detector description: {exc}") from exc
        if meta.get("format") != "dlsr-detector":
            raise ValueError(f"{js}: not a DLSR detector model (format {meta.get('format')!r})")
        with np.load(npz, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
        for key in ("scaler_mean", "scaler_scale", "coef", "intercept", "rep_dictionary"):
            if key not in arrays:
                raise ValueError(f"{npz}: missing array {key!r}")
        rep = Representation.from_arrays(arrays, meta["learner"], meta.get("natural_param"),
                                         prefix="rep_")
        return cls(representation=rep, encoder=meta["encoder"],
                   encoder_param=meta.get("encoder_param"), polarity=bool(meta["polarity"]),
                   scaler_mean=arrays["scaler_mean"], scaler_scale=arrays["scaler_scale"],
                   coef=arrays["coef"], intercept=float(arrays["intercept"][0]),
                   preprocess=dict(meta.get("preprocess") or _default_preprocess()),
                   config=dict(meta.get("config") or {}))

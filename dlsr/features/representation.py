"""What unsupervised learning produces from rectangle images: patch whitening and a dictionary
(:class:`Representation`, :func:`fit_representation`), and the patch preprocessing every
encoder reads (:func:`preprocess_patches`)."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from sklearn.utils import check_random_state

from .. import dictionaries, patches, whitening
from .base import LEARNERS

__all__ = ["Representation", "fit_representation", "preprocess_patches", "whitening_groups"]


@dataclass
class Representation:
    """What unsupervised learning produces: whitening and a dictionary.

    Attributes
    ----------
    learner : str
    dictionary : ndarray of shape (n_atoms, 288)
        Atoms as rows (unit norm except for SC/OMP, whose atoms have norm <= 1).
    centroids : ndarray of shape (n_atoms, 288) or None
        Un-normalised k-means centroids (NKM only; used by its natural triangle encoder).
    zca_mean : ndarray of shape (288,) or None
        None when whitening is off.
    zca_matrix : ndarray of shape (288, 288) or None
    natural_param : float or int or None
        The dictionary's own coding parameter (SC's lambda, OMP's L), used by "Natural".
    """

    learner: str
    dictionary: np.ndarray
    centroids: np.ndarray | None
    zca_mean: np.ndarray | None
    zca_matrix: np.ndarray | None
    natural_param: float | None = None

    def to_arrays(self, prefix: str = "") -> dict[str, np.ndarray]:
        out = {f"{prefix}dictionary": self.dictionary}
        if self.centroids is not None:
            out[f"{prefix}centroids"] = self.centroids
        if self.zca_mean is not None:
            out[f"{prefix}zca_mean"] = self.zca_mean
            out[f"{prefix}zca_matrix"] = self.zca_matrix
        return out

    @classmethod
    def from_arrays(cls, arrays, learner: str, natural_param=None, prefix: str = ""):
        def get(name):
            key = f"{prefix}{name}"
            return np.asarray(arrays[key]) if key in arrays else None

        return cls(
            learner=learner,
            dictionary=get("dictionary"),
            centroids=get("centroids"),
            zca_mean=get("zca_mean"),
            zca_matrix=get("zca_matrix"),
            natural_param=natural_param,
        )


def preprocess_patches(X, M, rep_or_zca):
    """Standardise and (optionally) whiten flattened patches; masked entries end at 0."""
    X = whitening.standardize_patches(X, M)
    mean, P = rep_or_zca
    if mean is not None:
        X = whitening.apply_zca(X, M, mean, P)
    return X


class _StageClock:
    """Adds the wall seconds since the previous lap to ``seconds[stage]`` (nothing when
    ``seconds`` is None)."""

    def __init__(self, seconds: dict | None):
        self.seconds = seconds
        self.t = time.perf_counter()

    def lap(self, stage: str) -> None:
        now = time.perf_counter()
        if self.seconds is not None:
            self.seconds[stage] = self.seconds.get(stage, 0.0) + now - self.t
        self.t = now


def fit_representation(
    images,
    masks,
    learner: str,
    n_atoms: int = 300,
    whiten: bool = True,
    n_patches: int = 100_000,
    min_valid: float = 0.2,
    extra=None,
    random_state=None,
    dictionary_params: dict | None = None,
    rows=None,
    seconds: dict | None = None,
) -> Representation:
    """Learn whitening and a dictionary from random patches of the training rectangles.

    Parameters
    ----------
    images, masks : ndarray of shape (n, 24, 24, 8)
        Training rectangle images only (fold hygiene is the caller's business).
    learner : {"SC", "OMP", "GSVQ", "NKM", "RP", "R"}
    n_atoms : int
    whiten : bool
        ZCA whitening (epsilon 0.1) after per-patch standardisation.
    n_patches : int
        Random patches drawn across the rectangles (100,000 in the paper).
    min_valid : float
        A patch is accepted when at least this fraction of its entries is valid.
    extra : tuple (patches, masks) or None
        Extra unlabelled patches (self-taught learning), each ``(m, 6, 6, 8)``.
    random_state : int, Generator, RandomState or None
    dictionary_params : dict or None
        Further keyword arguments of :func:`dlsr.dictionaries.learn_dictionary`.
    rows : array-like of int or None
        Learn from these rectangles only (positions in ``images``): the same representation as
        from ``images[rows]`` and ``masks[rows]``, without copying them. None uses all.
    seconds : dict or None
        When given, the wall seconds of each stage are added under ``"patches"`` (sampling),
        ``"whitening"`` (standardisation and ZCA) and ``"dictionary"`` (learning).

    Returns
    -------
    Representation
    """
    if learner not in LEARNERS:
        raise ValueError(f"unknown learner {learner!r}; choose from {LEARNERS}")
    rs = check_random_state(random_state)
    seeds = rs.randint(0, 2**31 - 1, size=2)
    clock = _StageClock(seconds)
    X, M = patches.sample_patches(
        images, masks, n_patches=n_patches, min_valid=min_valid,
        random_state=int(seeds[0]), extra=extra, rows=rows,
    )
    clock.lap("patches")
    Xs = whitening.standardize_patches(X, M)
    if whiten:
        mean, P = whitening.fit_zca(Xs, M)
        Xw = whitening.apply_zca(Xs, M, mean, P)
    else:
        mean, P = None, None
        Xw = Xs
    clock.lap("whitening")
    learned = dictionaries.learn_dictionary(
        Xw, learner, n_atoms=n_atoms, random_state=int(seeds[1]), **(dictionary_params or {})
    )
    clock.lap("dictionary")
    centroids = None
    natural_param = None
    if isinstance(learned, dictionaries.LearnedDictionary):
        D = learned.components
        centroids = learned.centroids
        natural_param = learned.natural_param
    else:
        D = learned
    return Representation(learner, np.asarray(D, np.float32), centroids, mean, P, natural_param)


def whitening_groups(reps) -> list[list[int]]:
    """Positions of ``reps`` grouped by their whitening: equal ZCA mean and matrix, or none for
    all of a group; groups in order of their first member.

    The representations of one training set drawn from one seed whiten alike whatever their
    learner (they sample the same patches), so a patch whitened for one of a group is
    whitened for all of them, bit for bit.
    """
    groups: list[list[int]] = []
    for i, rep in enumerate(reps):
        for g in groups:
            first = reps[g[0]]
            if first is rep or (
                    (first.zca_matrix is None) == (rep.zca_matrix is None)
                    and (rep.zca_matrix is None
                         or (np.array_equal(first.zca_matrix, rep.zca_matrix)
                             and np.array_equal(first.zca_mean, rep.zca_mean)))):
                g.append(i)
                break
        else:
            groups.append([i])
    return groups

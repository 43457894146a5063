"""The DLSR representation as a scikit-learn transformer (:class:`DLSRFeatures`), and the packed
2-D layout in which rectangle images travel through scikit-learn (:func:`pack_images`)."""

from __future__ import annotations

import numpy as np
from sklearn.base import BaseEstimator, TransformerMixin
from sklearn.utils.validation import check_is_fitted, validate_data

from .base import IMAGE_SIZE, N_CHANNELS, default_encoder_param
from .pooling import rectangle_features
from .representation import fit_representation

__all__ = ["pack_images", "unpack_images", "DLSRFeatures"]


def pack_images(images, masks) -> np.ndarray:
    """Pack rectangle images and masks into one 2-D array for scikit-learn.

    Parameters
    ----------
    images : ndarray of shape (n, 24, 24, 8)
    masks : ndarray of shape (n, 24, 24, 8), bool

    Returns
    -------
    ndarray of shape (n, 9216), float32
    """
    images = np.asarray(images, dtype=np.float32)
    masks = np.asarray(masks, dtype=bool)
    if images.shape != masks.shape or images.ndim != 4:
        raise ValueError(
            f"images and masks must both be (n, H, W, C), got {images.shape} and {masks.shape}"
        )
    n = images.shape[0]
    return np.concatenate([images.reshape(n, -1), masks.reshape(n, -1).astype(np.float32)], 1)


def unpack_images(X, size: int = IMAGE_SIZE, channels: int = N_CHANNELS):
    """Inverse of :func:`pack_images`: ``(images float32, masks bool)``, each (n, size, size, C)."""
    X = np.asarray(X)
    per = size * size * channels
    if X.ndim != 2 or X.shape[1] != 2 * per:
        raise ValueError(
            f"packed rectangle images must have shape (n, {2 * per}) "
            f"(values then masks of {size}x{size}x{channels}), got {X.shape}"
        )
    n = X.shape[0]
    images = X[:, :per].reshape(n, size, size, channels).astype(np.float32, copy=False)
    masks = X[:, per:].reshape(n, size, size, channels) > 0.5
    return images, masks


class DLSRFeatures(TransformerMixin, BaseEstimator):
    """The DLSR representation as a scikit-learn transformer.

    ``fit`` learns whitening and a dictionary from random patches of the training rectangles;
    ``transform`` encodes every patch and pools. Input is packed rectangle images
    (:func:`pack_images`).

    Parameters
    ----------
    learner : {"SC", "OMP", "GSVQ", "NKM", "RP", "R"}, default="NKM"
    encoder : {"SC", "mSC", "OMP", "mOMP", "ST", "Natural"}, default="SC"
    encoder_param : float or int or None
        lambda (SC, mSC, ST) or number of non-zeros (OMP, mOMP); None takes the middle of the
        reference grid.
    n_atoms : int, default=300
    whiten : bool, default=True
    n_patches : int, default=100_000
    min_valid : float, default=0.2
    polarity : bool, default=True
    extra_patches : tuple (patches, masks) or None
        Self-taught learning: unlabelled patches joined to dictionary learning.
    chunk_size : int, default=64
    random_state : int, RandomState instance or None

    Attributes
    ----------
    representation_ : Representation
    n_features_out_ : int
    """

    def __init__(
        self,
        learner="NKM",
        encoder="SC",
        encoder_param=None,
        n_atoms=300,
        whiten=True,
        n_patches=100_000,
        min_valid=0.2,
        polarity=True,
        extra_patches=None,
        chunk_size=64,
        random_state=None,
    ):
        self.learner = learner
        self.encoder = encoder
        self.encoder_param = encoder_param
        self.n_atoms = n_atoms
        self.whiten = whiten
        self.n_patches = n_patches
        self.min_valid = min_valid
        self.polarity = polarity
        self.extra_patches = extra_patches
        self.chunk_size = chunk_size
        self.random_state = random_state

    def _param(self):
        return default_encoder_param(self.encoder, self.encoder_param)

    def fit(self, X, y=None):
        X = validate_data(self, X, dtype=np.float32)
        images, masks = unpack_images(X)
        self._param()
        self.representation_ = fit_representation(
            images, masks, self.learner, n_atoms=self.n_atoms, whiten=self.whiten,
            n_patches=self.n_patches, min_valid=self.min_valid, extra=self.extra_patches,
            random_state=self.random_state,
        )
        self.n_features_out_ = self.transform(X[:1]).shape[1]
        return self

    def transform(self, X):
        check_is_fitted(self, "representation_")
        X = validate_data(self, X, dtype=np.float32, reset=False)
        images, masks = unpack_images(X)
        return rectangle_features(
            images, masks, self.representation_, self.encoder, self._param(),
            polarity=self.polarity, chunk_size=self.chunk_size,
        )

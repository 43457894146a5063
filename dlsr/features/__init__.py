"""From rectangle images to the paper's feature vectors.

rectangle image (24x24x8 + masks) -> all 19x19 stride-1 6x6x8 patches -> per-patch group
standardisation -> ZCA whitening -> encoding against a learned dictionary -> polarity splitting
-> quadrant sum pooling (rows and columns split 10 | 9) -> one vector per rectangle
(4 * 2 * n_atoms = 2,400 for 300 atoms; 4 * n_atoms = 1,200 for NKM-Natural, which has no
polarity split).

Rectangle images travel through scikit-learn as one 2-D array (see :func:`pack_images`):
``(n, 24 * 24 * 8 * 2)`` float32, the values followed by the masks (1.0 valid, 0.0 masked),
so that ``Pipeline``, ``GridSearchCV``, ``cross_val_score`` and group splitters work unchanged.

The package, one concept per module:

* :mod:`~dlsr.features.base`: the learners, the encoders and their grids, the sizes;
* :mod:`~dlsr.features.representation`: whitening and the dictionary learnt from patches
  (:func:`fit_representation`);
* :mod:`~dlsr.features.encoding`: the codes of patches for one or many encoders, each shared
  computation once (:func:`encode_patches_multi`);
* :mod:`~dlsr.features.pooling`: polarity splitting, quadrant pooling, and the whole pipeline
  over many rectangles, streamed in chunks (:func:`rectangle_features_multi`);
* :mod:`~dlsr.features.estimator`: the scikit-learn transformer (:class:`DLSRFeatures`) and
  the packed layout.
"""

from __future__ import annotations

from .base import ENCODER_GRIDS, ENCODERS, LEARNERS, default_encoder_param
from .encoding import encode_patches, encode_patches_grid, encode_patches_multi
from .estimator import DLSRFeatures, pack_images, unpack_images
from .pooling import (
    quadrant_pool,
    rectangle_features,
    rectangle_features_grid,
    rectangle_features_many,
    rectangle_features_multi,
)
from .representation import Representation, fit_representation

__all__ = [
    "LEARNERS",
    "ENCODERS",
    "ENCODER_GRIDS",
    "default_encoder_param",
    "pack_images",
    "unpack_images",
    "quadrant_pool",
    "Representation",
    "fit_representation",
    "encode_patches",
    "encode_patches_grid",
    "encode_patches_multi",
    "rectangle_features",
    "rectangle_features_grid",
    "rectangle_features_many",
    "rectangle_features_multi",
    "DLSRFeatures",
]

"""The features' shared vocabulary: the learners and encoders of the paper's Table 1, the
encoders' inner-CV grids, and the sizes of rectangle images, patches and pooling quadrants."""

from __future__ import annotations

__all__ = ["LEARNERS", "ENCODERS", "ENCODER_GRIDS", "IMAGE_SIZE", "N_CHANNELS", "PATCH_SIZE",
           "POOL_SPLIT"]

LEARNERS = ("SC", "OMP", "GSVQ", "NKM", "RP", "R")
# Encoders in the column order of the paper's Table 1.
ENCODERS = ("SC", "mSC", "OMP", "mOMP", "ST", "Natural")
# Inner-CV grids of the encoder's parameter (reference facts); natural encoders have none.
ENCODER_GRIDS = {
    "SC": (0.5, 1.0, 1.5, 2.0),
    "mSC": (1.0, 2.0, 3.0, 4.0),
    "OMP": (1, 5, 10, 15),
    "mOMP": (1, 5, 10, 15),
    "ST": (0.5, 1.0, 1.5, 2.0),
    "Natural": (None,),
}

IMAGE_SIZE = 24
N_CHANNELS = 8
PATCH_SIZE = 6
POOL_SPLIT = 10

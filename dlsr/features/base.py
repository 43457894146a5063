"""The features' shared vocabulary: the learners and encoders of the paper's Table 1, the
encoders' inner-CV grids, and the sizes of rectangle images, patches and pooling quadrants."""

from __future__ import annotations

__all__ = ["LEARNERS", "ENCODERS", "ENCODER_GRIDS", "IMAGE_SIZE", "N_CHANNELS", "PATCH_SIZE",
           "POOL_SPLIT", "default_encoder_param"]

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


def default_encoder_param(encoder: str, param=None):
    """``param``, or when None the middle of ``encoder``'s grid (its second value of four);
    Natural keeps None (its parameter is the dictionary's)."""
    if encoder not in ENCODERS:
        raise ValueError(f"unknown encoder {encoder!r}; choose from {ENCODERS}")
    if param is not None or encoder == "Natural":
        return param
    grid = ENCODER_GRIDS[encoder]
    return grid[len(grid) // 2 - 1]

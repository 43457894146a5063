"""PyTorch for the networks of :mod:`graspsim.detectors.ggcnn`, imported only when asked for.

Without torch (the optional ``cnn`` extra) every other part of the toolkit works; asking for a
network gives the one-line :data:`INSTALL_HINT`.
"""

from __future__ import annotations

__all__ = ["INSTALL_HINT", "require_torch"]

INSTALL_HINT = ("the CNN detectors (GG-CNN, GR-ConvNet) need PyTorch: install it with "
                "`pip install -e .[cnn]`")


def require_torch():
    """``torch``, or a one-line ``ValueError`` saying how to install it.

    Returns
    -------
    module
    """
    try:
        # deferred, optional: PyTorch (the cnn extra)
        import torch
    except ImportError:
        raise ValueError(INSTALL_HINT) from None
    return torch

"""Dictionary mosaics like the paper's Figures 2 and 6.

Each atom is a 6x6x8 patch (flattened row-major from ``(6, 6, 8)``, channel fastest) shown as
four panels: K (gray), RGB, D (depth, gray) and the normals (Nx, Ny, Nz as RGB). Each panel of
each atom is scaled on its own, symmetrically about 0 (0 maps to mid-gray), like the usual
dictionary displays.
"""

from __future__ import annotations

import numpy as np

__all__ = ["PANELS", "atom_panels", "mosaic_image", "plot_dictionary_mosaic"]

PANELS = {"K": (0,), "RGB": (1, 2, 3), "D": (4,), "normals": (5, 6, 7)}


def atom_panels(D, patch_size=6, n_channels=8):
    """Atoms as images per panel, each scaled to [0, 1] about 0.

    Parameters
    ----------
    D : array-like of shape (n_atoms, patch_size * patch_size * n_channels)

    Returns
    -------
    dict of str -> ndarray of shape (n_atoms, patch_size, patch_size, 1 or 3), float64
    """
    D = np.asarray(D, dtype=np.float64)
    p = patch_size * patch_size * n_channels
    if D.ndim != 2 or D.shape[1] != p:
        raise ValueError(f"atoms must have shape (n_atoms, {p}), got {D.shape}")
    P = D.reshape(-1, patch_size, patch_size, n_channels)
    out = {}
    for name, ch in PANELS.items():
        v = P[..., list(ch)]
        scale = np.abs(v).reshape(len(v), -1).max(axis=1)
        scale = np.where(scale > 0, scale, 1.0)
        out[name] = 0.5 + 0.5 * v / scale[:, None, None, None]
    return out


def mosaic_image(tiles, n_cols=20, pad=1, zoom=1, background=1.0):
    """Tile ``(n, h, w, c)`` images into one ``(H, W, c)`` image with ``pad``-pixel gaps."""
    tiles = np.asarray(tiles, dtype=np.float64)
    if zoom > 1:
        tiles = tiles.repeat(zoom, axis=1).repeat(zoom, axis=2)
    n, h, w, c = tiles.shape
    n_cols = max(1, min(n_cols, n))
    n_rows = -(-n // n_cols)
    H = n_rows * (h + pad) + pad
    W = n_cols * (w + pad) + pad
    img = np.full((H, W, c), background)
    for i in range(n):
        r, q = divmod(i, n_cols)
        y, x = pad + r * (h + pad), pad + q * (w + pad)
        img[y : y + h, x : x + w] = tiles[i]
    return img


def plot_dictionary_mosaic(D, title=None, path=None, n_cols=20, zoom=4, max_atoms=None):
    """One figure with the four panels of a dictionary's atoms.

    Parameters
    ----------
    D : array-like of shape (n_atoms, 288)
    title : str, optional
    path : str or Path, optional
        Save as PNG there (parent folders are created).
    n_cols : int
        Atoms per mosaic row.
    zoom : int
        Pixel repetition of each atom pixel.
    max_atoms : int, optional
        Show only the first atoms.

    Returns
    -------
    matplotlib.figure.Figure
    """
    from pathlib import Path

    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    D = np.asarray(D)
    if max_atoms is not None:
        D = D[:max_atoms]
    panels = atom_panels(D)
    fig, axes = plt.subplots(2, 2, figsize=(12, 12 * (D.shape[0] / n_cols) / n_cols + 1.5))
    for ax, (name, tiles) in zip(axes.ravel(), panels.items(), strict=True):
        img = mosaic_image(tiles, n_cols=n_cols, zoom=zoom)
        if img.shape[2] == 1:
            ax.imshow(img[..., 0], cmap="gray", vmin=0, vmax=1, interpolation="nearest")
        else:
            ax.imshow(np.clip(img, 0, 1), interpolation="nearest")
        ax.set_title(name)
        ax.axis("off")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    if path is not None:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=100)
    return fig

"""Randomised appearance of a scene: lights (TinyRenderer's model) and the table's colour and
texture.
"""

from __future__ import annotations

import atexit
import hashlib
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

__all__ = ["Lights", "LightRanges", "random_lights", "random_table_rgba", "table_texture_image",
           "random_table_texture"]


@dataclass(frozen=True)
class Lights:
    """TinyRenderer lighting: one directional light plus ambient (pybullet's model)."""

    direction: tuple[float, float, float] = (0.3, 0.2, 1.0)
    color: tuple[float, float, float] = (1.0, 1.0, 1.0)
    distance: float = 2.0
    ambient: float = 0.6
    diffuse: float = 0.35
    specular: float = 0.05
    shadow: bool = False

    def kwargs(self) -> dict:
        return dict(lightDirection=list(self.direction), lightColor=list(self.color),
                    lightDistance=self.distance, shadow=int(self.shadow),
                    lightAmbientCoeff=self.ambient, lightDiffuseCoeff=self.diffuse,
                    lightSpecularCoeff=self.specular)


@dataclass(frozen=True)
class LightRanges:
    """Ranges :func:`random_lights` draws a light from (uniformly within each).

    The defaults are the simulator's usual lighting. Every field is a ``(low, high)`` range,
    except ``shadow``, the probability of cast shadows. Changing a range never changes how many
    values are drawn, so the draws after the lights (the depth noise) stay the same.

    Attributes
    ----------
    elevation : (float, float)
        Elevation of the light direction above the table plane, degrees.
    tint : (float, float)
        Per-channel reduction of the white light colour (0 = white).
    distance : (float, float)
        Light distance, metres (TinyRenderer's shading parameter).
    ambient, diffuse, specular : (float, float)
        TinyRenderer's lighting coefficients.
    shadow : float
        Probability that the light casts shadows.
    """

    elevation: tuple[float, float] = (30.0, 90.0)
    tint: tuple[float, float] = (0.0, 0.15)
    distance: tuple[float, float] = (1.5, 3.0)
    ambient: tuple[float, float] = (0.45, 0.7)
    diffuse: tuple[float, float] = (0.25, 0.5)
    specular: tuple[float, float] = (0.0, 0.2)
    shadow: float = 0.5

    def __post_init__(self):
        for name in ("elevation", "tint", "distance", "ambient", "diffuse", "specular"):
            lo, hi = getattr(self, name)
            if not (np.isfinite(lo) and np.isfinite(hi) and lo <= hi):
                raise ValueError(f"LightRanges.{name} must be a finite (low, high) with "
                                 f"low <= high, got {(lo, hi)}")
        if not 0.0 <= self.shadow <= 1.0:
            raise ValueError(f"LightRanges.shadow is a probability, got {self.shadow}")


def random_lights(rng: np.random.Generator, ranges: LightRanges | None = None) -> Lights:
    """Light from a random direction of the upper hemisphere, slightly tinted, with random
    ambient/diffuse/specular coefficients and cast shadows at random.

    Parameters
    ----------
    rng : numpy.random.Generator
        Eleven values are drawn, whatever the ranges.
    ranges : LightRanges or None
        None: ``LightRanges()`` (elevation 30-90 deg, shadows half the time).

    Returns
    -------
    Lights
    """
    r = LightRanges() if ranges is None else ranges
    az = rng.uniform(0, 2 * np.pi)
    el = rng.uniform(np.deg2rad(r.elevation[0]), np.deg2rad(r.elevation[1]))
    d = (np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el))
    tint = 1.0 - rng.uniform(r.tint[0], r.tint[1], size=3)
    return Lights(direction=tuple(float(x) for x in d), color=tuple(float(x) for x in tint),
                  distance=float(rng.uniform(*r.distance)),
                  ambient=float(rng.uniform(*r.ambient)),
                  diffuse=float(rng.uniform(*r.diffuse)),
                  specular=float(rng.uniform(*r.specular)),
                  shadow=bool(rng.random() < r.shadow))


def random_table_rgba(rng: np.random.Generator) -> tuple[float, float, float, float]:
    """A plausible table colour: wood, grey, white or a muted colour."""
    kind = rng.integers(4)
    if kind == 0:  # wood
        base = np.array([0.55, 0.38, 0.22]) * rng.uniform(0.7, 1.2)
    elif kind == 1:  # grey
        base = np.full(3, rng.uniform(0.3, 0.7))
    elif kind == 2:  # white-ish
        base = np.full(3, rng.uniform(0.8, 0.95))
    else:
        base = rng.uniform(0.2, 0.7, size=3)
    return (*(float(c) for c in np.clip(base, 0, 1)), 1.0)


_TEXTURE_DIR: Path | None = None


def _texture_dir() -> Path:
    global _TEXTURE_DIR
    if _TEXTURE_DIR is None:
        _TEXTURE_DIR = Path(tempfile.mkdtemp(prefix="graspsim_textures_"))
        atexit.register(shutil.rmtree, _TEXTURE_DIR, True)
    return _TEXTURE_DIR


def table_texture_image(rng: np.random.Generator, size: int = 128) -> np.ndarray:
    """(size, size, 3) uint8 table texture: wood grain, checker, speckle or plain + noise."""
    base = np.array(random_table_rgba(rng)[:3])
    kind = rng.integers(4)
    y, x = np.mgrid[0:size, 0:size] / size
    if kind == 0:  # wood grain
        f = rng.uniform(8, 20)
        wave = 0.3 * np.sin(2 * np.pi * rng.uniform(1, 3) * y)
        t = 0.5 + 0.5 * np.sin(2 * np.pi * (f * x + wave))
        shade = 0.8 + 0.25 * t
    elif kind == 1:  # checker
        n = int(rng.integers(2, 8))
        shade = np.where(((x * n).astype(int) + (y * n).astype(int)) % 2 == 0, 1.0, 0.75)
    elif kind == 2:  # speckle
        shade = 0.85 + 0.3 * rng.random((size, size))
    else:
        shade = np.ones((size, size))
    shade = shade + 0.04 * rng.standard_normal((size, size))
    img = np.clip(shade[..., None] * base[None, None, :], 0, 1)
    return (img * 255).astype(np.uint8)


def random_table_texture(client, rng: np.random.Generator, body: int | None = None,
                         link: int = -1) -> int:
    """Make a random table texture, load it into ``client`` and, if ``body`` is given, apply it.

    Returns
    -------
    int
        The pybullet texture id (apply with ``changeVisualShape(body, -1, textureUniqueId=id,
        rgbaColor=[1, 1, 1, 1])``).
    """
    img = table_texture_image(rng)
    # pybullet caches textures by file name, so every image gets its own name (its content hash);
    # the file is deleted once loaded, so nothing piles up over thousands of scenes. Textures
    # live in the client until resetSimulation.
    digest = hashlib.sha1(img.tobytes()).hexdigest()[:16]
    path = _texture_dir() / f"table_{digest}.png"
    cv2.imwrite(str(path), img[..., ::-1])
    try:
        tex = client.loadTexture(str(path))
    finally:
        path.unlink(missing_ok=True)
    if body is not None:
        client.changeVisualShape(body, link, textureUniqueId=tex, rgbaColor=[1, 1, 1, 1])
    return tex

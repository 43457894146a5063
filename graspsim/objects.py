"""Object sets for the simulator: the built-in set, pybullet_data's random URDFs, user folders."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from importlib.resources import files
from pathlib import Path

__all__ = ["ObjectSpec", "builtin_objects", "load_object", "assets_dir"]


def assets_dir() -> Path:
    """Folder of the built-in object set (the repository's ``objects/``, installed as a package)."""
    return Path(str(files("graspsim.assets")))


@dataclass(frozen=True)
class ObjectSpec:
    """One graspable object.

    Attributes
    ----------
    name : str
    urdf : Path
        URDF file (visual and collision meshes referenced relative to it).
    split : {"train", "test"}
    mass : float
        kg.
    friction : float
        Lateral friction coefficient.
    size : tuple of 3 floats
        Axis-aligned extent of the mesh in its own frame, metres.
    material : {"matte", "dark", "specular", "transparent"}
        Drives the depth-dropout model of the camera.
    graspable : bool
        False for objects wider than the gripper's opening in every direction.
    scale : float
        Global scaling passed to ``loadURDF``.
    """

    name: str
    urdf: Path
    split: str = "train"
    mass: float = 0.1
    friction: float = 0.8
    size: tuple[float, float, float] = (0.05, 0.05, 0.05)
    material: str = "matte"
    graspable: bool = True
    scale: float = 1.0
    tags: tuple[str, ...] = field(default_factory=tuple)


def builtin_objects(split: str = "all") -> list[ObjectSpec]:
    """The built-in object set from ``objects/manifest.json``.

    Parameters
    ----------
    split : {"train", "test", "all"}
    """
    if split not in ("train", "test", "all"):
        raise ValueError(f"split must be 'train', 'test' or 'all', got {split!r}")
    root = assets_dir()
    manifest = root / "manifest.json"
    if not manifest.exists():
        raise FileNotFoundError(f"object manifest not found: {manifest}")
    entries = json.loads(manifest.read_text()).get("objects", [])
    specs = [
        ObjectSpec(
            name=e["name"],
            urdf=root / e["urdf"],
            split=e.get("split", "train"),
            mass=float(e.get("mass", 0.1)),
            friction=float(e.get("friction", 0.8)),
            size=tuple(e.get("size", (0.05, 0.05, 0.05))),
            material=e.get("material", "matte"),
            graspable=bool(e.get("graspable", True)),
            scale=float(e.get("scale", 1.0)),
            tags=tuple(e.get("tags", ())),
        )
        for e in entries
    ]
    return [s for s in specs if split == "all" or s.split == split]


def load_object(client, spec: ObjectSpec, position, orientation=(0.0, 0.0, 0.0, 1.0)) -> int:
    """Load ``spec`` into a pybullet client and set its mass and friction.

    Parameters
    ----------
    client : pybullet_utils.bullet_client.BulletClient
    spec : ObjectSpec
    position : sequence of 3 floats
        Metres, world frame.
    orientation : sequence of 4 floats
        Quaternion (x, y, z, w).

    Returns
    -------
    int
        The body id.
    """
    if not Path(spec.urdf).exists():
        raise FileNotFoundError(f"URDF for object {spec.name!r} not found: {spec.urdf}")
    body = client.loadURDF(
        str(spec.urdf), list(position), list(orientation), globalScaling=spec.scale
    )
    client.changeDynamics(
        body, -1, mass=spec.mass, lateralFriction=spec.friction,
        spinningFriction=0.002, rollingFriction=0.0005,
    )
    return body

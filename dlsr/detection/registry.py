"""Which detector a saved model builds: the registry of detector kinds.

The detector modules (:mod:`~dlsr.detection.dense`, :mod:`~dlsr.detection.exact`,
:mod:`~dlsr.detection.lattice`) each register their class here when they are imported, and
:func:`build_detector` (which :meth:`dlsr.detection.DLSRDetector.detector` calls) looks the kind
up. So the model (:mod:`dlsr.detection.model`), which every detector imports, imports none of
them: the dependency runs one way, from the detectors to the model and this registry.
Importing :mod:`dlsr.detection` (or any of its modules, which imports the package first)
registers the three built-in kinds.

Part of :mod:`dlsr.detection`.
"""

from __future__ import annotations

from dataclasses import dataclass

from .grid import SearchGrid

#: The built-in kinds: the paper's grid searched densely or exactly, or candidates fitted to
#: the object (:class:`dlsr.detection.LatticeDetector`).
DETECTOR_KINDS = ("dense", "exact", "lattice")

#: Options that only the grid search takes; a kind registered with ``grid_search=False`` is
#: built without them even when the model's saved configuration has them.
GRID_SEARCH_OPTIONS = ("grid", "coarse_to_fine", "rescore")


@dataclass(frozen=True)
class _Entry:
    cls: type
    grid_search: bool


_REGISTRY: dict[str, _Entry] = {}


def register_detector(kind: str, cls: type, *, grid_search: bool = True) -> None:
    """Make ``model.detector(kind)`` build ``cls(model, **options)``.

    Parameters
    ----------
    kind : str
        The name a model's ``config["detector"]`` or :func:`build_detector` uses.
    cls : type
        Called as ``cls(model, **options)`` with the model and keyword options.
    grid_search : bool, default True
        Whether the detector searches the grid; when False the options in
        :data:`GRID_SEARCH_OPTIONS` are not passed to it.

    Raises
    ------
    ValueError
        When ``kind`` is already registered to another class.
    """
    old = _REGISTRY.get(kind)
    if old is not None and old.cls is not cls:
        raise ValueError(f"detector kind {kind!r} is already registered to "
                         f"{old.cls.__module__}.{old.cls.__qualname__}")
    _REGISTRY[kind] = _Entry(cls, grid_search)


def registered_kinds() -> tuple[str, ...]:
    """The registered detector kinds, in registration order.

    Returns
    -------
    tuple of str
    """
    return tuple(_REGISTRY)


def build_detector(model, kind: str | None = None, **options):
    """The detector of ``kind`` on a trained model.

    Parameters
    ----------
    model : DLSRDetector
        The trained model (:class:`dlsr.detection.DLSRDetector`).
    kind : {"dense", "exact", "lattice"} or None, default None
        Any registered kind; None takes the model's saved ``config["detector"]``, else
        ``"dense"``.
    **options
        Keyword options of the detector's class. They default to the model's saved ``config``
        (``grid``, ``top_k``, ``region``; ``rescore`` for the dense detector); the lattice
        detector ignores the grid search's.

    Returns
    -------
    DenseDetector or ExactGridDetector or LatticeDetector

    Raises
    ------
    ValueError
        For an unknown kind.
    """
    kind = kind or model.config.get("detector", "dense")
    entry = _REGISTRY.get(kind)
    if entry is None:
        known = DETECTOR_KINDS + tuple(k for k in _REGISTRY if k not in DETECTOR_KINDS)
        raise ValueError(f"unknown detector {kind!r}; choose one of {known}")
    opts = {}
    if "grid" in model.config:
        opts["grid"] = SearchGrid.from_dict(model.config["grid"])
    for key in ("top_k", "region"):
        if key in model.config:
            opts[key] = model.config[key]
    if kind == "dense" and "rescore" in model.config:
        opts["rescore"] = model.config["rescore"]
    opts.update(options)
    if not entry.grid_search:
        for key in GRID_SEARCH_OPTIONS:
            opts.pop(key, None)
    return entry.cls(model, **opts)

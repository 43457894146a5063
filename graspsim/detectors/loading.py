"""Detectors by name: the built-in ones, plug-ins, entry points and saved models.

A detector is any object with ``predict(obs)`` (:class:`graspsim.detectors.base.GraspDetector`).
Built-in names (:data:`DETECTORS`): ``random``, ``mask-pca`` and ``oracle``
(:mod:`graspsim.detectors.baselines`); a name ending in ``+aware`` is the gripper-aware
version of the detector it names (:mod:`graspsim.detectors.gripper_aware`).

Plug-ins (:func:`load_detector`): ``"package.module:NAME"`` imports ``NAME`` (a class or a
factory, called with the detector options as keyword arguments -- none by default --, or an
object with ``predict``) from a module on ``sys.path`` or in the current folder; installed
packages can register names in the entry-point group ``graspsim.detectors`` (see
:data:`ENTRY_POINT_GROUP`). Options come from ``--detector-option KEY=VALUE``
(:func:`parse_detector_options`) or a run configuration's ``detector_options`` table; a
detector's recorded name says them (:func:`detector_label`).
"""

from __future__ import annotations

import importlib
import inspect
import json
import os
import re
import sys
from collections.abc import Mapping
from importlib.metadata import entry_points

from dlsr.detection import (
    DLSRDetector,
)

from .base import one_line
from .baselines import MaskPCADetector, OracleDetector, RandomDetector
from .ggcnn.detector import GGCNNDetector
from .ggcnn.model import is_ggcnn_model, require_torch
from .gripper_aware import gripper_aware

__all__ = [
    "PluginDetector",
    "ENTRY_POINT_GROUP",
    "AWARE_SUFFIX",
    "DETECTORS",
    "load_detector",
    "check_detector",
    "check_detector_options",
    "detector_label",
    "parse_detector_options",
    "plugin_names",
]


DETECTORS = {
    "random": RandomDetector,
    "mask-pca": MaskPCADetector,
    "oracle": OracleDetector,
}


ENTRY_POINT_GROUP = "graspsim.detectors"
"""Entry-point group in which installed packages register detector names: in a package's
``pyproject.toml``, ``[project.entry-points."graspsim.detectors"]`` then
``mynet = "mypkg.detect:MyDetector"``; ``--detector mynet`` then loads it."""

# ``package.module:NAME`` (NAME may be dotted: ``module:Class.factory``), as entry points write it.
_SPEC = re.compile(r"^[A-Za-z_]\w*(\.[A-Za-z_]\w*)*:[A-Za-z_]\w*(\.[A-Za-z_]\w*)*$")


class PluginDetector:
    """A detector loaded from a plug-in (``module:NAME`` or an entry-point name).

    It predicts with the loaded object and pickles as its name and the folder its module came
    from, so a worker process (loky, Ray) imports the plug-in again, once per process, even
    when that folder is not on the worker's ``sys.path``.

    Parameters
    ----------
    spec : str
        What was asked for (``"mydet:Detector"`` or an entry-point name).
    detector : object with ``predict(obs)``
    path : str or None
        Folder to put on ``sys.path`` before importing in another process.
    options : dict or None
        The keyword arguments NAME was called with (JSON values), passed again in another
        process.
    """

    def __init__(self, spec, detector, path=None, options=None):
        self.spec = spec
        self.detector = detector
        self.path = path
        self.options = options

    @property
    def label(self) -> str:
        """The name runs record: the spec with its options (:func:`detector_label`)."""
        return detector_label(self.spec, self.options)

    @property
    def requires_labels(self) -> bool:
        return bool(getattr(self.detector, "requires_labels", False))

    def predict(self, obs):
        return self.detector.predict(obs)

    def __repr__(self):
        return f"PluginDetector({self.label!r})"

    def __reduce__(self):
        return (_plugin_in_worker, (self.spec, self.path, self.options))


_WORKER_PLUGINS: dict = {}


def _plugin_in_worker(spec, path, options=None):
    """Unpickling a :class:`PluginDetector`: import it (once per process) from ``path`` too."""
    key = (spec, path, json.dumps(options, sort_keys=True), os.getpid())
    det = _WORKER_PLUGINS.get(key)
    if det is None:
        if path is not None and path not in sys.path:
            sys.path.append(path)
            importlib.invalidate_caches()
        det = load_detector(spec, options)
        _WORKER_PLUGINS[key] = det
    return det


def parse_detector_options(items) -> dict:
    """``["KEY=VALUE", ...]`` (``--detector-option``, repeatable) as a dict of options.

    A value is read as JSON where it parses (``5`` an int, ``0.5`` a float, ``true``, ``null``,
    ``[1, 2]``, ``{"a": 1}``, ``"quoted"`` a string), else kept as the text given
    (``model=runs/net/model.pt``).

    Parameters
    ----------
    items : sequence of str

    Returns
    -------
    dict
        Keys in the order given.

    Raises
    ------
    ValueError
        An item without ``=``, a key that is not an identifier, or a key given twice.
    """
    out = {}
    for item in items or ():
        key, eq, text = str(item).partition("=")
        key = key.strip()
        if not eq or not key.isidentifier():
            raise ValueError(f"--detector-option {item!r}: expected KEY=VALUE with KEY a "
                             "Python identifier (the keyword the detector takes)")
        if key in out:
            raise ValueError(f"--detector-option {key!r} is given twice")
        try:
            out[key] = json.loads(text)
        except ValueError:
            out[key] = text
    return out


def check_detector_options(options, where: str = "detector options") -> dict:
    """``options`` as a plain dict of JSON values with identifier keys (a copy), or an error.

    Parameters
    ----------
    options : dict or None
    where : str
        What the options are, for the message.

    Returns
    -------
    dict
        Empty for None.
    """
    if options is None:
        return {}
    if not isinstance(options, Mapping):
        raise ValueError(f"{where} must be a table of KEY = VALUE, got {options!r}")
    for key in options:
        if not isinstance(key, str) or not key.isidentifier():
            raise ValueError(f"{where}: option name {key!r} is not a Python identifier")
    try:
        return json.loads(json.dumps(dict(options), allow_nan=False))
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{where}: values must be JSON (numbers, strings, booleans, lists, "
                         f"tables): {exc}") from None


#: Longest option value a :func:`detector_label` shows in full.
LABEL_VALUE_WIDTH = 24


def _label_value(value) -> str:
    if isinstance(value, str):
        text = value.rstrip("/\\")
        if "/" in text or os.sep in text:  # a path: its last part says which file or folder
            text = text.replace(os.sep, "/").rsplit("/", 1)[-1] or text
    else:
        text = json.dumps(value, separators=(",", ":"))
    return text if len(text) <= LABEL_VALUE_WIDTH else text[: LABEL_VALUE_WIDTH - 3] + "..."


def detector_label(name, options=None) -> str:
    """A detector's name with its options, as runs record and print it.

    ``name`` alone without options; else ``name(key=value,...)`` with the keys sorted, a path
    shortened to its last part (``model=runs/net/ggcnn.pt`` gives ``model=ggcnn.pt``) and a
    value longer than :data:`LABEL_VALUE_WIDTH` characters cut. The full options are recorded
    beside it (``detector_options`` in ``config.json``).

    Parameters
    ----------
    name : str
    options : dict or None

    Returns
    -------
    str
    """
    if not options:
        return str(name)
    return f"{name}(" + ",".join(f"{k}={_label_value(options[k])}"
                                 for k in sorted(options)) + ")"


def _module_folder(module) -> str | None:
    """The ``sys.path`` entry a top-level module or package was imported from."""
    top = sys.modules.get(module.__name__.split(".")[0], module)
    origin = getattr(top, "__file__", None)
    if origin is None:
        return None
    folder = os.path.dirname(os.path.abspath(origin))
    return os.path.dirname(folder) if hasattr(top, "__path__") else folder


def _import_module(spec: str, module_name: str):
    """Import ``module_name``, retrying with the current folder on ``sys.path``."""
    def missing(exc):  # the plug-in's own module is absent (not one of its imports)
        return exc.name is not None and (module_name == exc.name
                                         or module_name.startswith(exc.name + "."))

    for attempt in (0, 1):
        try:
            return importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            if not missing(exc):  # a package the plug-in imports is missing
                raise ValueError(f"plug-in {spec!r}: importing {module_name} failed: "
                                 f"{_missing_text(exc)}") from exc
            cwd = os.getcwd()
            if attempt or cwd in sys.path:
                raise ValueError(
                    f"detector {spec!r}: no module named {exc.name!r} (looked in the current "
                    f"folder {cwd} and on sys.path)"
                ) from exc
            sys.path.append(cwd)  # like `python -m`, but installed modules keep precedence
            importlib.invalidate_caches()
        except Exception as exc:
            raise ValueError(f"plug-in {spec!r}: importing {module_name} failed: "
                             f"{one_line(exc)}") from exc
    raise AssertionError("unreachable")  # pragma: no cover


def _missing_text(exc: ImportError) -> str:
    """``No module named 'x'`` and what to do about it, on one line."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    if isinstance(exc, ModuleNotFoundError) and exc.name:
        return f"{text} (install it in the environment graspsim runs in)"
    return text


def _instantiate(spec: str, obj, what: str, options=None):
    """A class or factory is called with ``options`` as keyword arguments; an object with
    ``predict`` is used as it is (and takes no options)."""
    options = options or {}
    call = f"{what}({', '.join(f'{k}={v!r}' for k, v in options.items())})"
    if isinstance(obj, type) or (callable(obj) and not hasattr(obj, "predict")):
        try:
            obj = obj(**options)
        except ImportError as exc:  # the constructor imports a missing package
            raise ValueError(f"plug-in {spec!r}: {call} failed importing "
                             f"{exc.name or 'a module'}: {_missing_text(exc)}") from exc
        except TypeError as exc:
            hint = ("" if options else "; give its arguments with --detector-option KEY=VALUE "
                    "(a run configuration: its detector_options table)")
            raise ValueError(f"plug-in {spec!r}: calling {call} failed: {one_line(exc)}"
                             f"{hint}") from exc
        except Exception as exc:
            raise ValueError(f"plug-in {spec!r}: calling {call} failed: "
                             f"{one_line(exc)}") from exc
    elif options:
        raise ValueError(f"plug-in {spec!r}: {what} is a {type(obj).__name__} object, not a "
                         f"class or factory, and takes no options (given: "
                         f"{', '.join(options)})")
    if not callable(getattr(obj, "predict", None)):
        raise ValueError(f"detector {spec!r}: {what} gave a {type(obj).__name__} with no "
                         "predict(obs) method")
    return obj


def _resolve_spec(spec: str):
    """Import ``module`` of ``module:NAME`` and return ``(NAME's object, module)``."""
    module_name, _, attr = spec.partition(":")
    module = _import_module(spec, module_name)
    obj = module
    for part in attr.split("."):
        if not hasattr(obj, part):
            where = getattr(module, "__file__", None) or module_name
            raise ValueError(f"detector {spec!r}: module {module_name!r} ({where}) has no "
                             f"attribute {attr!r}")
        obj = getattr(obj, part)
    return obj, module


def _load_spec(spec: str, options=None) -> PluginDetector:
    obj, module = _resolve_spec(spec)
    return PluginDetector(spec, _instantiate(spec, obj, spec.partition(":")[2], options),
                          _module_folder(module), options or None)


def plugin_names() -> dict:
    """Installed detector plug-ins: ``{name: "module:NAME"}`` of the entry-point group."""
    return {ep.name: ep.value for ep in entry_points(group=ENTRY_POINT_GROUP)}


def _load_entry_point(name: str, options=None) -> PluginDetector | None:
    eps = [ep for ep in entry_points(group=ENTRY_POINT_GROUP) if ep.name == name]
    if not eps:
        return None
    ep = eps[0]
    try:
        obj = ep.load()
    except ImportError as exc:
        raise ValueError(f"plug-in {name!r}: importing {ep.value.partition(':')[0].strip()} "
                         f"(entry point {ep.value!r} of {ENTRY_POINT_GROUP}) failed: "
                         f"{_missing_text(exc)}") from exc
    except Exception as exc:
        raise ValueError(f"detector {name!r}: loading the entry point {ep.value!r} "
                         f"({ENTRY_POINT_GROUP}) failed: {one_line(exc)}") from exc
    module = sys.modules.get(ep.value.partition(":")[0].strip())
    return PluginDetector(name, _instantiate(name, obj, ep.value, options),
                          None if module is None else _module_folder(module), options or None)


#: Appended to a detector's name: the same detector made gripper-aware (:func:`load_detector`).
AWARE_SUFFIX = "+aware"


def load_detector(name_or_path, options=None):
    """A detector from a built-in name, a plug-in, or a saved DLSR model.

    Parameters
    ----------
    name_or_path : str or Path
        Any of the following with ``"+aware"`` appended is that detector made gripper-aware
        (:func:`gripper_aware`, as ``graspsim trials --gripper-aware``), so that run configs
        can list both. In this order: ``"random"``, ``"mask-pca"``, ``"oracle"``;
        ``"package.module:NAME"``
        (a class or a no-argument factory, or an object with ``predict``; the module is looked
        up on ``sys.path``, then in the current folder); a name registered by an installed
        package in the entry-point group ``graspsim.detectors``; the path of a model saved by
        :meth:`dlsr.detection.DLSRDetector.save` (``.npz`` + ``.json``, with or without the
        suffix), which detects with the options saved in the model; the path of a GG-CNN
        model (``MODEL.pt`` + ``MODEL.json``, :mod:`graspsim.detectors.ggcnn`).
    options : dict or None
        Keyword arguments for a plug-in's class or factory, or a built-in detector's class
        (:func:`parse_detector_options` reads them from ``KEY=VALUE`` text). A saved model
        detects with the options saved in it and takes none.

    Returns
    -------
    object with ``predict(obs)``
        Plug-ins come wrapped in a :class:`PluginDetector` (which re-imports them in worker
        processes).

    Raises
    ------
    ValueError
        A plug-in that cannot be imported (the message names the missing module), lacks the
        attribute, has no ``predict`` or does not take the options.
    FileNotFoundError
        If it is none of the above.
    """
    key = str(name_or_path)
    options = check_detector_options(options, f"detector {key!r}: options")
    if key in DETECTORS:
        try:
            return DETECTORS[key](**options)
        except TypeError as exc:
            raise ValueError(f"detector {key!r}: {one_line(exc)}") from exc
    if key.endswith(AWARE_SUFFIX) and key != AWARE_SUFFIX:
        return gripper_aware(load_detector(key[: -len(AWARE_SUFFIX)], options))
    if _SPEC.match(key):
        return _load_spec(key, options)
    det = _load_entry_point(key, options)
    if det is not None:
        return det
    if options:
        raise ValueError(f"detector {key!r}: options ({', '.join(options)}) are for plug-ins "
                         "and the built-in detectors; a saved model detects with the options "
                         "saved in it")

    if is_ggcnn_model(key):
        det = GGCNNDetector(key)
        det._loaded()  # one line naming a broken file, or how to install torch
        return det

    npz, js = DLSRDetector._paths(key)
    if npz.exists() or js.exists():
        return DLSRDetector.load(key).detector()  # names the missing or broken file
    installed = ", ".join(sorted(plugin_names())) or "none installed"
    raise FileNotFoundError(
        f"unknown detector {key!r}: not one of {', '.join(DETECTORS)}, not a plug-in "
        f"(package.module:NAME, or an entry point of {ENTRY_POINT_GROUP}: {installed}) and no "
        f"saved model ({npz} + {js})"
    )


def _check_signature(spec: str, obj, options: dict) -> None:
    """The options bind to the class's or factory's parameters (checked without calling it)."""
    if not (isinstance(obj, type) or (callable(obj) and not hasattr(obj, "predict"))):
        if options:
            raise ValueError(f"plug-in {spec!r}: a {type(obj).__name__} object, not a class or "
                             f"factory, takes no options (given: {', '.join(options)})")
        return
    try:
        signature = inspect.signature(obj)
    except (TypeError, ValueError):  # a builtin without a signature: called as it is
        return
    try:
        signature.bind(**options)
    except TypeError as exc:
        hint = ("" if options else "; give its arguments with --detector-option KEY=VALUE (a "
                "run configuration: its detector_options table)")
        raise ValueError(f"plug-in {spec!r}: {spec.partition(':')[2]}{signature} does not take "
                         f"the options given ({', '.join(options) or 'none'}): {exc}"
                         f"{hint}") from None


def check_detector(name_or_path, options=None) -> None:
    """Raise the error :func:`load_detector` would give for ``name_or_path``, without loading it.

    A plug-in's module is imported and NAME looked up (a class must have ``predict``), but no
    factory or class is called and no model is read, so checking costs no checkpoint load; use
    it to reject a bad name before a long run starts. ``options`` are checked to be JSON
    values with identifier names, and refused for a saved model.
    """
    key = str(name_or_path)
    options = check_detector_options(options, f"detector {key!r}: options")
    if key in DETECTORS:
        return
    if key.endswith(AWARE_SUFFIX) and key != AWARE_SUFFIX:
        check_detector(key[: -len(AWARE_SUFFIX)], options)
        return
    if _SPEC.match(key):
        obj, _ = _resolve_spec(key)
        if isinstance(obj, type) and not callable(getattr(obj, "predict", None)):
            raise ValueError(f"detector {key!r}: class {obj.__name__} has no predict(obs) "
                             "method")
        if not callable(obj) and not callable(getattr(obj, "predict", None)):
            raise ValueError(f"detector {key!r}: {type(obj).__name__} object is neither a "
                             "class, a factory nor a detector with predict(obs)")
        _check_signature(key, obj, options)
        return
    if key in plugin_names():
        return
    if options:
        raise ValueError(f"detector {key!r}: options ({', '.join(options)}) are for plug-ins "
                         "and the built-in detectors; a saved model detects with the options "
                         "saved in it")

    if is_ggcnn_model(key):
        require_torch()
        return

    npz, js = DLSRDetector._paths(key)
    if npz.exists() or js.exists():
        return
    load_detector(key)  # raises the full message

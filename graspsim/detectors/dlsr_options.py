"""The DLSR detector's options: one set of names for ``graspsim benchmark detection``,
``graspsim detect`` and ``graspsim run`` (its configuration file's settings of the same names).

Four departures from the paper, each chosen on validation data in simulation (README, "Making
DLSR grasp") and on real training folds (``docs/experiments/2026-12-03-real-defaults.md``):

``detector``
    ``"lattice"``: rectangles fitted to the object region (:class:`dlsr.detection.
    LatticeDetector`); ``"dense"`` / ``"exact"``: the paper's grid search.
``complete_region``
    The candidates are laid on the object region with its unseen surface added (the missing
    depth inside its convex hull, :func:`dlsr.detection.complete_region`).
``physical``
    Training: the SVM also weighs the rectangles' physical features (opening in metres,
    heights above the table, ...; :mod:`dlsr.detection.physical`, which needs the camera
    matrix: :mod:`dlsr.intrinsics`). Detection: the model's physical term is added (``False``
    drops it).
``gripper_aware``
    Only rectangles the built-in gripper can execute, judged from the depth image at the
    image's scale through the camera matrix (:func:`graspsim.detectors.gripper_aware`: jaws
    beside the object, opening within :data:`graspsim.sim.gripper.MAX_OPENING`, fingers landing
    on no seen surface).
``clear_jaws``
    The grid search keeps only rectangles whose jaws come down beside the object region
    (:attr:`dlsr.detection.SearchGrid.clear_jaws`; the lattice's candidates always do).

:data:`PRESETS` names three configurations: ``"real"`` (the real-data default,
:data:`REAL_DEFAULT`: the rectangles fitted to the object region, nothing else, which the nested
object-wise cross-validation on the Jacquard samples chose), ``"all"`` (every departure, as
``graspsim run`` uses them in simulation) and ``"paper"`` (the paper's: grid search, nothing
else).
"""

from __future__ import annotations

import argparse
import dataclasses
from dataclasses import dataclass

from .gripper_aware import gripper_aware

__all__ = [
    "DetectorOptions",
    "OPTION_NAMES",
    "PRESETS",
    "REAL_DEFAULT",
    "add_detector_arguments",
    "build_real_detector",
    "candidate_options",
    "options_from_args",
]


@dataclass(frozen=True)
class DetectorOptions:
    """A DLSR detector configuration (see the module notes for each option).

    Parameters
    ----------
    detector : {"lattice", "dense", "exact"}
    complete_region, physical, gripper_aware, clear_jaws : bool
    """

    detector: str = "lattice"
    complete_region: bool = True
    physical: bool = True
    gripper_aware: bool = True
    clear_jaws: bool = True

    def departures(self) -> list[str]:
        """The options in which this configuration departs from the paper's."""
        paper = PRESETS["paper"]
        return [f.name for f in dataclasses.fields(self)
                if getattr(self, f.name) != getattr(paper, f.name)]

    def name(self) -> str:
        """``"paper"``, ``"all"``, or ``"paper+<departure>+..."``."""
        d = self.departures()
        if not d:
            return "paper"
        if self == PRESETS["all"]:
            return "all"
        return "paper+" + "+".join("lattice" if n == "detector" else n for n in d)


#: The option names (the settings' and, with dashes, the flags').
OPTION_NAMES = tuple(f.name for f in dataclasses.fields(DetectorOptions))

_PAPER = DetectorOptions(detector="dense", complete_region=False, physical=False,
                         gripper_aware=False, clear_jaws=False)
PRESETS = {
    "real": dataclasses.replace(_PAPER, detector="lattice"),
    "all": DetectorOptions(),
    "paper": _PAPER,
}
#: The real-data default of ``graspsim benchmark detection`` and ``graspsim detect``: the
#: configuration the nested object-wise cross-validation on the Jacquard samples chose
#: (``paper+lattice``, in 3 of the 5 outer folds; ``docs/experiments/2026-12-03-real-defaults.md``).
REAL_DEFAULT = "real"

# What each departure of issue 39 sets, from the paper's configuration. (``clear_jaws`` is
# not one: the lattice's candidates always clear the object, and ``gripper_aware`` implies it
# for the grid search.)
_DEPARTURES = {"lattice": {"detector": "lattice"}, "complete_region": {"complete_region": True},
               "physical": {"physical": True}, "gripper_aware": {"gripper_aware": True}}


def candidate_options() -> dict[str, DetectorOptions]:
    """The configurations the real-data defaults are chosen among: the paper's, each
    departure alone, and all of them (keys as :meth:`DetectorOptions.name`)."""
    paper = PRESETS["paper"]
    out = {"paper": paper}
    for changes in _DEPARTURES.values():
        o = dataclasses.replace(paper, **changes)
        out[o.name()] = o
    out["all"] = PRESETS["all"]
    return out


def add_detector_arguments(parser: argparse.ArgumentParser, kinds=("dense", "exact",
                           "lattice"), preset: bool = True) -> None:
    """Add ``--preset``, ``--detector``, ``--[no-]complete-region``, ``--[no-]physical``,
    ``--[no-]gripper-aware`` and ``--[no-]clear-jaws`` to ``parser``.

    Each defaults to None (not given): :func:`options_from_args` fills it from the preset.

    Parameters
    ----------
    parser : argparse.ArgumentParser
    kinds : sequence of str
        The ``--detector`` choices.
    preset : bool
        Also add ``--preset`` (``graspsim run`` takes its presets from its config files).
    """
    if preset:
        parser.add_argument("--preset", choices=sorted(PRESETS), default=None,
                            help=f"detector configuration the options below start from "
                                 f"(default {REAL_DEFAULT}: rectangles fitted to the object "
                                 "region, the choice of the real-data cross-validation; all: "
                                 "every departure, as in simulation; paper: the paper's grid "
                                 "search)")
    parser.add_argument("--detector", choices=list(kinds), default=None,
                        help="lattice: rectangles fitted to the object region (not in the "
                             "paper); dense / exact: the paper's grid search")
    flags = {
        "complete_region": "lay candidates on the object region with its unseen surface "
                           "(missing depth inside its hull) added",
        "physical": "physical features in the SVM (training) and their term in the score "
                    "(detection); need the camera matrix",
        "gripper_aware": "keep only rectangles the built-in gripper can execute, judged from "
                         "the depth at the image's scale",
        "clear_jaws": "grid search: only rectangles whose jaws come down beside the object",
    }
    for name, text in flags.items():
        parser.add_argument("--" + name.replace("_", "-"), dest=name,
                            action=argparse.BooleanOptionalAction, default=None,
                            help=text + " (not in the paper)")


def options_from_args(args, preset: str | None = None) -> DetectorOptions:
    """The :class:`DetectorOptions` of parsed arguments: the preset (``args.preset``, else
    ``preset``, else :data:`REAL_DEFAULT`) with every option given overriding it."""
    name = getattr(args, "preset", None) or preset or REAL_DEFAULT
    base = PRESETS[name]
    given = {k: getattr(args, k) for k in OPTION_NAMES if getattr(args, k, None) is not None}
    return dataclasses.replace(base, **given)


def build_real_detector(model, options: DetectorOptions, top_k: int = 5, region: str = "auto",
                        background=None, rescore: int = 300, coarse_to_fine: bool = False,
                        hand: str = "builtin"):
    """The detector ``options`` describe on a trained model, for real (or any) RGB-D images.

    Parameters
    ----------
    model : dlsr.detection.DLSRDetector
    options : DetectorOptions
        ``physical=False`` drops a physical model's physical term; ``True`` keeps it (a model
        trained without physical features has none).
    top_k : int
        Rectangles the detector returns.
    region, background :
        The object region's method and background image (:func:`dlsr.detection.
        object_region`).
    rescore, coarse_to_fine :
        Dense grid search only.
    hand : {"builtin", "franka", "wsg50", "robotiq-2f85"}
        The gripper whose geometry the gripper-aware check uses
        (:func:`graspsim.detectors.gripper_aware`).

    Returns
    -------
    object with ``detect(obs)`` and ``predict(obs)``
        A DLSR detector, wrapped by :class:`graspsim.detectors.GripperAwareDetector` with
        ``gripper_aware``.
    """
    if not options.physical and model.physical:
        model = dataclasses.replace(model, physical_coef=None, physical_edges=None)
    if options.detector == "lattice":
        det = model.detector("lattice", top_k=top_k, region=region, background=background,
                             complete=options.complete_region)
    else:
        kw = {"rescore": rescore, "coarse_to_fine": coarse_to_fine} \
            if options.detector == "dense" else {}
        det = model.detector(options.detector, top_k=top_k, region=region,
                             background=background, **kw)
        det.grid = dataclasses.replace(det.grid, clear_jaws=options.clear_jaws,
                                       complete_region=options.complete_region)
    if options.gripper_aware:
        det = gripper_aware(det, keep=top_k, hand=hand)
    return det

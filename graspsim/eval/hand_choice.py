"""DLSR's training data for each hand, chosen on validation scenes of the train objects.

A detector compared with several hands (``scripts/hands_ycb.py``) is trained once; this module
asks, hand by hand, whether DLSR does better trained on data labelled with that hand, or on
the object set's own train objects, and chooses without looking at the test objects.

Every candidate is DLSR in ``graspsim run``'s default configuration (lattice detector,
physical features, 200 atoms, 50,000 patches, no grid negatives), made aware of the hand's
geometry (:func:`graspsim.detectors.gripper_aware` with ``hand``); the candidates differ only in
their training data:

* ``curve``: the data-efficiency curve's model (300 scenes of the built-in train objects,
  labelled with the built-in hand), what the hands table's DLSR row runs;
* ``train-builtin``: ``n_train`` scenes of the object set's train objects, labelled with the
  built-in hand;
* ``train-HAND``: the same scenes (same seed: same objects, poses and cameras) labelled with
  the hand itself (not a separate candidate for the built-in hand).

Each candidate runs ``n_val`` trials on validation scenes of the train objects (a seed the
datasets do not use) with that hand, beside mask-pca on the same scenes; the candidate with
the most successes is chosen, ties going to the earlier one in the order above (the less
specialised). The test objects are never seen.

Output folder: ``datasets/<hand>`` (:func:`graspsim.data.datagen.make_dataset`, resumable),
``models/dlsr-<data>`` (+ ``.seconds.json``), ``validation/<hand>/<candidate>`` (trial
folders, resumable), ``choice.json`` and ``choice.md`` (rewritten after every hand).
"""

from __future__ import annotations

import logging
from pathlib import Path

from dlsr.datasets import load_cornell
from dlsr.detection import DLSRDetector
from dlsr.records import read_json, write_json_atomic, write_text_atomic

from ..data.datagen import make_dataset
from ..detectors.gripper_aware import gripper_aware
from ..runtime.executor import Executor, task_seeds
from ..sim.execution import ExecutionParams
from ..sim.hands import HAND_NAMES
from .compare import compare_outcomes
from .data_efficiency import train_timed
from .stats import wilson_interval
from .trials import TrialConfig, run_trials

log = logging.getLogger(__name__)

__all__ = ["CANDIDATE_ORDER", "hand_candidates", "choose_per_hand", "chosen_detector",
           "choice_markdown"]

#: The candidates' order: ties in validation go to the earlier one.
CANDIDATE_ORDER = ("curve", "train-builtin", "train-{hand}")

#: ``graspsim run``'s default DLSR training (:class:`graspsim.pipeline.RunConfig`); the
#: dictionary's size and patches are parameters.
_DLSR = {"n_atoms": 200, "n_patches": 50_000, "detector": "lattice", "physical": True,
         "grid_negatives": 0.0}


def hand_candidates(hand: str) -> list[str]:
    """The candidates for ``hand``, in :data:`CANDIDATE_ORDER` (``train-builtin`` once for
    the built-in hand)."""
    names = [c.format(hand=hand) for c in CANDIDATE_ORDER]
    return list(dict.fromkeys(names))


def _model_path(out: Path, cfg: dict, name: str) -> Path:
    """Where candidate ``name``'s model is: the curve's as configured, the others in
    ``out/models``."""
    return Path(cfg["curve_model"]) if name == "curve" else out / "models" / f"dlsr-{name}"


def _detector(model: Path, hand: str):
    return gripper_aware(DLSRDetector.load(model).detector(_DLSR["detector"]), hand=hand)


def choose_per_hand(out, hands, curve_model, objects: str = "ycb:train", n_train: int = 300,
                    n_val: int = 100, candidates: int = 64, seed: int = 0, n_atoms: int = 200,
                    n_patches: int = 50_000, executor=None, progress: bool = False) -> dict:
    """Choose DLSR's training data for each hand (see the module docstring); resumable.

    Parameters
    ----------
    out : str or Path
        The study's folder.
    hands : sequence of str
        Hand names (:data:`graspsim.sim.hands.HAND_NAMES`).
    curve_model : str or Path
        The ``curve`` candidate's saved DLSR model.
    objects : str
        The train objects (an object set, :func:`graspsim.labels.graspability.resolve_objects`) of
        the
        training and validation scenes; never the objects reported on.
    n_train : int
        Training scenes per labelling hand.
    n_val : int
        Validation trials per candidate (and for mask-pca).
    candidates : int
        Physics labels per training scene (dense sampler, as the data-efficiency curve).
    seed : int
    n_atoms, n_patches : int
        DLSR's dictionary size and patches (``graspsim run``'s defaults).
    executor : graspsim.runtime.executor.Executor or None
    progress : bool

    Returns
    -------
    dict
        Hand to ``candidates`` (name to successes, n, Wilson interval, ``vs_mask_pca``),
        ``mask-pca`` (successes, n) and ``chosen``; plus ``config``. Written to
        ``out/choice.json`` and ``out/choice.md``.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    train = str(objects)
    dlsr = {**_DLSR, "n_atoms": int(n_atoms), "n_patches": int(n_patches)}
    s_data, s_val, s_model = task_seeds(seed, 3)
    ex = executor or Executor("sequential", progress=progress)
    # The hands are a selection, not a setting: each hand's choice is independent, so a later
    # run may add hands to the folder.
    cfg = {"objects": train, "n_train": int(n_train),
           "n_val": int(n_val), "candidates": int(candidates), "seed": int(seed),
           "curve_model": str(curve_model), "dlsr": dlsr}
    path = out / "choice.json"
    result = read_json(path, "hand choice") if path.exists() else {}
    if result.get("config", cfg) != cfg:
        raise ValueError(f"{path} was written with other settings; use another folder")
    result["config"] = cfg
    models: dict[str, Path] = {"curve": Path(curve_model)}

    def model_for(name: str) -> Path:
        if name not in models:
            label_hand = name.split("-", 1)[1]
            data = out / "datasets" / label_hand
            make_dataset(n_scenes=n_train, objects=train, out=data, seed=s_data,
                         n_candidates=candidates, sampler="dense", executor=ex,
                         progress=progress, params=ExecutionParams.with_hand(label_hand))
            samples = sorted(load_cornell(data), key=lambda s: s.image_id)
            models[name] = _model_path(out, cfg, name)
            train_timed(samples, models[name], s_model, **dlsr)
        return models[name]

    for hand in hands:
        params = ExecutionParams.with_hand(hand)

        def trials(det, name, hand=hand, params=params):
            return run_trials(det, objects=train, n=n_val, seed=s_val,
                              out=out / "validation" / hand / name,
                              config=TrialConfig(n_candidates=0), params=params,
                              executor=ex, progress=progress, detector_name=name)

        ref = trials("mask-pca", "mask-pca")
        ref_ok = [bool(r["success"]) for r in ref["records"]]
        entry: dict = {"mask-pca": {"successes": ref["successes"], "n": ref["n"]},
                       "candidates": {}}
        for name in hand_candidates(hand):
            t = trials(_detector(model_for(name), hand), name)
            ok = [bool(r["success"]) for r in t["records"]]
            c = compare_outcomes(ok, ref_ok, names=(name, "mask-pca"))
            entry["candidates"][name] = {
                "successes": t["successes"], "n": t["n"],
                "ci95": list(wilson_interval(t["successes"], t["n"])),
                "vs_mask_pca": {"p": c["mcnemar_p"], "better": c["better"]}}
        order = hand_candidates(hand)
        chosen = max(order, key=lambda c: (entry["candidates"][c]["successes"],
                                           -order.index(c)))
        entry["chosen"] = chosen
        result[hand] = entry
        write_json_atomic(path, result)
        write_text_atomic(out / "choice.md", choice_markdown(result))
        log.info("%s: chose %s (%s)", hand, chosen,
                 {k: v["successes"] for k, v in entry["candidates"].items()})
    return result


def chosen_detector(folder, hand: str):
    """The DLSR detector :func:`choose_per_hand` chose for ``hand`` (gripper-aware with it).

    Raises
    ------
    ValueError
        When the folder holds no choice for ``hand`` (run the choice first).
    """
    path = Path(folder) / "choice.json"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: not found (run the hand choice first)")
    result = read_json(path, "hand choice")
    if "chosen" not in result.get(hand, {}):
        raise ValueError(f"{path}: no choice for the hand {hand!r} (run the hand choice "
                         "with it first)")
    return _detector(_model_path(Path(folder), result["config"], result[hand]["chosen"]), hand)


def choice_markdown(result: dict) -> str:
    """The choice as Markdown: per hand, each candidate's validation successes with its
    Wilson interval and paired verdict against mask-pca, and the one chosen."""
    cfg = result.get("config", {})
    lines = [f"# DLSR's training data per hand, chosen on validation scenes of "
             f"`{cfg.get('objects')}`", "",
             f"{cfg.get('n_val')} validation trials per candidate (exact McNemar against "
             f"mask-pca on the same scenes); training sets of {cfg.get('n_train')} scenes. "
             "Ties go to the earlier candidate.", "",
             "| hand | candidate | validation success | 95 % (Wilson) | vs mask-pca (p) | "
             "chosen |", "|---|---|---|---|---|---|"]
    for hand in HAND_NAMES:
        e = result.get(hand)
        if not e:
            continue
        ref = e["mask-pca"]
        lines.append(f"| {hand} | mask-pca | {ref['successes']}/{ref['n']} | | | |")
        for name, c in e["candidates"].items():
            lo, hi = c["ci95"]
            lines.append(f"| {hand} | {name} | {c['successes']}/{c['n']} | "
                         f"{100 * lo:.0f}-{100 * hi:.0f} % | {c['vs_mask_pca']['p']:.3g} | "
                         f"{'yes' if name == e['chosen'] else ''} |")
    return "\n".join(lines) + "\n"

"""The data-efficiency curve: DLSR (default and the paper's) against GG-CNN at growing numbers
of training scenes, measured by physical success on the same trial scenes.

:func:`data_efficiency` grows one physics-labelled dataset of the train objects and trains,
on its first ``n`` scenes for every ``n`` of ``sizes`` (nested subsets, smallest first):

* ``dlsr``: the default configuration of ``graspsim run`` (lattice detector, physical
  features, gripper-aware search), ``dlsr-paper``: the paper's (dense grid, appearance only);
* GG-CNN, saved at every sample-step budget of ``budgets``; the budget is chosen by physical
  success on validation scenes of the *train* objects (never the test objects; ties go to the
  smaller budget), which gives the validation curve.

Every chosen model then runs on the same ``test_trials`` scenes of the test objects (same
seed), GG-CNN raw and gripper-aware, both also at DLSR's training wall time
(:func:`equal_time_model`), beside mask-pca (no training; its trials once); DLSR is compared
with GG-CNN scene by scene (exact McNemar), and the rectangle metric is measured on held-out
labelled images of the test objects.
Everything is written as it is finished and a rerun resumes (datasets per scene, trials per
trial, models per file, GG-CNN training from its checkpoint).
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path

import numpy as np

from dlsr.datasets import load_cornell
from dlsr.detection import DLSRDetector, sample_observation, train_detector
from dlsr.metrics import rectangle_metric
from dlsr.records import read_json, write_text_atomic

from ..data.datagen import make_dataset
from ..detectors.base import check_detections
from ..detectors.ggcnn.detector import GGCNNDetector
from ..detectors.ggcnn.model import budget_path, model_paths, timed_path
from ..detectors.ggcnn.train import train_ggcnn, trainer
from ..detectors.gripper_aware import gripper_aware
from ..detectors.loading import load_detector
from ..runtime.executor import Executor, task_seeds
from .compare import compare_outcomes
from .stats import wilson_interval
from .trials import TrialConfig, run_trials

log = logging.getLogger(__name__)

__all__ = ["data_efficiency", "train_dlsr_models", "train_timed", "equal_time_model",
           "chosen_budget", "catch_up", "curve_markdown", "curve_figure"]

#: GG-CNN's rows at every size: the budget chosen on validation scenes, and the model trained
#: for as long as DLSR's default took to train (equal training wall time), raw and
#: gripper-aware.
GGCNN_ROWS = ("ggcnn", "ggcnn+aware", "ggcnn@dlsr-time", "ggcnn+aware@dlsr-time")


def _rect_accuracy(det, samples) -> dict:
    ok = []
    for s in samples:
        rects, _ = check_detections(det.predict(dict(sample_observation(s), seed=0)))
        ok.append(bool(rects) and bool(rectangle_metric(rects[0], s.positives)))
    return {"correct": int(sum(ok)), "n": len(ok)}


def train_dlsr_models(samples, folder, n: int, seed: int, n_atoms: int = 200,
                      n_patches: int = 50_000, hand: str = "builtin") -> dict:
    """DLSR's two rows of a training size, trained once (timed) and loaded.

    ``dlsr``: ``graspsim run``'s default (lattice detector, physical features, gripper-aware
    with ``hand``); ``dlsr-paper``: the paper's (dense grid, appearance only). Saved as
    ``folder/<name>_<n>`` with the training wall time in ``<name>_<n>.seconds.json``; a saved
    model is loaded, not trained again.

    Returns
    -------
    dict
        Row name to ``(detector, training seconds)``.
    """
    models = {}
    for name, physical, kind in (("dlsr", True, "lattice"), ("dlsr-paper", False, "dense")):
        mpath = Path(folder) / f"{name}_{n}"
        seconds = train_timed(samples, mpath, seed, n_atoms=n_atoms, n_patches=n_patches,
                              detector=kind, physical=physical, grid_negatives=0.0)
        det = DLSRDetector.load(mpath).detector(kind)
        models[name] = (gripper_aware(det, hand=hand) if name == "dlsr" else det, seconds)
    return models


def train_timed(samples, path, seed: int, **options) -> float:
    """DLSR trained on ``samples`` (:func:`dlsr.detection.train_detector` with ``options``)
    and saved as ``path``, with its training wall time in ``<path>.seconds.json``; a model
    already saved there is not trained again.

    Returns
    -------
    float
        The training wall time (seconds), as recorded.
    """
    path = Path(path)
    timing = path.with_name(path.name + ".seconds.json")
    if not timing.exists():
        t0 = time.perf_counter()
        train_detector(samples, random_state=seed, **options).save(path)
        write_text_atomic(timing, json.dumps({"seconds": time.perf_counter() - t0}))
    return read_json(timing, "timing")["seconds"]


def chosen_budget(validation: dict, budgets) -> int:
    """The GG-CNN budget a size's validation chooses among ``budgets``: the most validation
    successes, ties to the smaller budget.

    Parameters
    ----------
    validation : dict
        Budget (sample-steps, as a string) to ``{"successes": int, "n": int}``: a size's entry
        of ``curve.json``'s ``validation``, holding every one of ``budgets``.
    budgets : iterable of int
    """
    return max((int(b) for b in budgets), key=lambda b: (validation[str(b)]["successes"], -b))


def equal_time_model(gpath, seconds: float, samples, seed: int, device: str = "cpu",
                     progress: bool = True, network: str = "ggcnn", **arch):
    """GG-CNN trained for ``seconds`` of wall time: the snapshot the full run saved then
    (``snapshot_seconds``), else, when the full run took no longer, the full model, else a
    model trained for the sample-steps that fit at the full run's rate (same seed and batches:
    the full run's weights at that step). Returns its path.

    Parameters
    ----------
    gpath : Path
        The full run's ``MODEL``.
    seconds : float
        The training wall time to match (DLSR's).
    samples, seed, device, progress :
        As the full run (:func:`graspsim.detectors.ggcnn.train.train_ggcnn`), for the fallback.
    network : str
        The full run's network (:func:`graspsim.detectors.ggcnn.train.trainer`); ``arch``, its
        architecture options as the full run took them (e.g. ``channels``).
    """
    snap = timed_path(gpath, seconds)
    if model_paths(snap)[1].is_file():
        taken = read_json(model_paths(snap)[1], "GG-CNN model")["training"]
        if taken.get("snapshot_seconds") == round(seconds, 2):
            return snap
    full = read_json(model_paths(gpath)[1], "GG-CNN model")["training"]
    if full["seconds"] <= seconds:
        return gpath
    rate = full["seconds"] / full["sample_steps"]
    batch = int(full["batch_size"])
    steps = max(batch, int(seconds / rate) // batch * batch)
    epath = gpath.with_name(f"{gpath.name}_eq{steps}")
    if not model_paths(epath)[1].is_file():
        log.info("GG-CNN: %s has no snapshot at %.0f s; training %d sample-steps", gpath,
                 seconds, steps)
        trainer(network)(samples, epath, steps=steps, seed=seed, device=device,
                         progress=progress, **arch)
    return epath


def data_efficiency(out, sizes=(10, 30, 100, 300), budgets=(2000, 5000, 10000, 20000),
                    test_trials: int = 200, val_trials: int = 50, heldout_images: int = 50,
                    candidates: int = 64, seed: int = 0, device: str = "cpu",
                    n_jobs: int = 2, n_atoms: int = 200, n_patches: int = 50_000,
                    progress: bool = True) -> dict:
    """Run (or resume) the data-efficiency study; write ``curve.json``, ``curve.md`` and
    ``curve.png`` into ``out`` after every training size.

    Parameters
    ----------
    out : str or Path
        Folder of everything (datasets, models, trials, tables).
    sizes : sequence of int
        Training scenes, nested subsets of one dataset of the train objects.
    budgets : sequence of int
        GG-CNN sample-step budgets validated (models saved at each).
    test_trials, val_trials : int
        Trials per model on the test objects and, for GG-CNN's budget, on the train objects.
    heldout_images : int
        Labelled images of the test objects for the rectangle metric.
    candidates : int
        Physics labels per training scene (dense sampler).
    seed : int
    device : str
        GG-CNN's device.
    n_jobs : int
        Parallel trial workers.
    n_atoms, n_patches : int
        DLSR's dictionary size and patches (``graspsim run``'s defaults).
    progress : bool

    Returns
    -------
    dict
        ``rows``: per size and detector, trials, successes, Wilson interval, planning seconds,
        training seconds, rectangle metric; ``validation``: GG-CNN's success per budget;
        ``comparisons``: DLSR against GG-CNN (exact McNemar) per size.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    sizes, budgets = sorted(int(s) for s in sizes), sorted(int(b) for b in budgets)
    s_data, s_held, s_val, s_test, s_model = task_seeds(seed, 5)
    ex = Executor("loky" if n_jobs > 1 else "sequential", n_jobs=n_jobs, progress=progress)
    no_labels = TrialConfig(n_candidates=0)
    make_dataset(n_scenes=heldout_images, objects="test", out=out / "heldout", seed=s_held,
                 n_candidates=candidates, sampler="dense", executor=ex)
    heldout = [s for s in load_cornell(out / "heldout") if s.positives]
    path = out / "curve.json"
    result = read_json(path, "curve") if path.exists() else {}
    result.setdefault("rows", {})
    result.setdefault("validation", {})
    result.setdefault("comparisons", {})
    result["config"] = {"sizes": sizes, "budgets": budgets, "test_trials": test_trials,
                        "val_trials": val_trials, "heldout_images": len(heldout),
                        "candidates": candidates, "seed": seed, "device": device,
                        "n_atoms": n_atoms, "n_patches": n_patches}

    def trials(det, name, folder, objects, n, s):
        t = run_trials(det, objects=objects, n=n, seed=s, out=folder, config=no_labels,
                       executor=ex, progress=progress, detector_name=name)
        return t

    for n in sizes:
        make_dataset(n_scenes=n, objects="train", out=out / "dataset", seed=s_data,
                     n_candidates=candidates, sampler="dense", executor=ex)
        samples = load_cornell(out / "dataset")
        samples = sorted(samples, key=lambda s: s.image_id)[:n]
        key = str(n)
        rows = result["rows"].setdefault(key, {})
        models = train_dlsr_models(samples, out / "models", n, s_model, n_atoms, n_patches)
        gpath = out / "models" / f"ggcnn_{n}"
        dlsr_seconds = models["dlsr"][1]
        if not model_paths(gpath)[1].is_file():
            train_ggcnn(samples, gpath, steps=budgets[-1], seed=s_model, device=device,
                        snapshots=budgets[:-1], snapshot_seconds=[dlsr_seconds],
                        progress=progress)
        val = result["validation"].setdefault(key, {})
        for b in budgets:
            bpath = budget_path(gpath, b, budgets[-1])
            if str(b) not in val:
                t = trials(GGCNNDetector(bpath, device=device), f"ggcnn_{n}_{b}",
                           out / "validation" / f"ggcnn_{n}_{b}", "train", val_trials, s_val)
                val[str(b)] = {"successes": t["successes"], "n": t["n"]}
                write_text_atomic(path, json.dumps(result, indent=2))
        best = chosen_budget(val, budgets)
        bpath = budget_path(gpath, best, budgets[-1])
        meta = read_json(model_paths(bpath)[1], "GG-CNN model")
        g = GGCNNDetector(bpath, device=device)
        models["ggcnn"] = (g, meta["training"]["seconds"])
        models["ggcnn+aware"] = (gripper_aware(g), meta["training"]["seconds"])
        epath = equal_time_model(gpath, dlsr_seconds, samples, seed=s_model, device=device,
                                 progress=progress)
        emeta = read_json(model_paths(epath)[1], "GG-CNN model")
        e = GGCNNDetector(epath, device=device)
        models["ggcnn@dlsr-time"] = (e, emeta["training"]["seconds"])
        models["ggcnn+aware@dlsr-time"] = (gripper_aware(e), emeta["training"]["seconds"])
        steps_of = {"ggcnn": meta["training"]["sample_steps"],
                    "ggcnn@dlsr-time": emeta["training"]["sample_steps"]}
        # the same model twice (equal time reached the chosen budget): its trials once
        same = ({"ggcnn@dlsr-time": "ggcnn", "ggcnn+aware@dlsr-time": "ggcnn+aware"}
                if epath == bpath else {})
        models["mask-pca"] = (load_detector("mask-pca"), 0.0)  # trains on nothing: same trials
        outcomes = {}
        for name, (det, train_s) in models.items():
            tname = same.get(name, name)
            folder = out / "trials" / (tname if name == "mask-pca" else f"{tname}_{n}")
            t = trials(det, tname, folder, "test", test_trials, s_test)
            outcomes[name] = [bool(r["success"]) for r in sorted(t["records"],
                                                                 key=lambda r: r["index"])]
            lo, hi = wilson_interval(t["successes"], t["n"])
            row = rows.setdefault(name, {})
            row.update(successes=t["successes"], n=t["n"], ci95=[lo, hi],
                       train_seconds=train_s,
                       planning_seconds=(t.get("planning_seconds") or {}).get("median"))
            if "rect" not in row:  # the gripper check needs the camera pose: ranking alone
                row["rect"] = _rect_accuracy(getattr(det, "detector", det), heldout)
            if name.startswith("ggcnn"):
                row["budget"] = steps_of[name.replace("+aware", "")]
            write_text_atomic(path, json.dumps(result, indent=2))
        result["comparisons"][key] = {
            f"{a} vs {b}": compare_outcomes(outcomes[a], outcomes[b], names=(a, b))
            for a in ("dlsr", "dlsr-paper") for b in GGCNN_ROWS}
        for a in ("dlsr", "ggcnn", "ggcnn+aware"):
            result["comparisons"][key][f"{a} vs mask-pca"] = compare_outcomes(
                outcomes[a], outcomes["mask-pca"], names=(a, "mask-pca"))
        write_text_atomic(path, json.dumps(result, indent=2, default=float))
        write_text_atomic(out / "curve.md", curve_markdown(result))
        curve_figure(result, out / "curve.png")
    return result


def catch_up(result: dict, dlsr: str = "dlsr", ggcnn: str = "ggcnn+aware",
             alpha: float = 0.05) -> dict:
    """Where GG-CNN catches up with DLSR along the curve, for one pair fixed beforehand.

    The default pair is DLSR's default (gripper-aware) against GG-CNN gripper-aware at the
    budget chosen on validation scenes: both filtered by the same gripper check, and chosen
    before the test trials (taking the better of GG-CNN's forms per size would choose on the
    test scenes).

    Returns
    -------
    dict
        ``sizes`` measured (ascending); ``level``: the first size at which GG-CNN succeeds at
        least as often as DLSR (None if none); ``not_separated``: the first size from which on
        DLSR is never better at level ``alpha`` (exact McNemar; None if it is at the last);
        ``sentence``: the answer in words.
    """
    sizes = sorted((int(k) for k, r in result.get("rows", {}).items()
                    if "n" in r.get(dlsr, {}) and "n" in r.get(ggcnn, {})))
    level = next((n for n in sizes if result["rows"][str(n)][ggcnn]["successes"]
                  >= result["rows"][str(n)][dlsr]["successes"]), None)

    def dlsr_better(n):
        c = result.get("comparisons", {}).get(str(n), {}).get(f"{dlsr} vs {ggcnn}")
        return c is None or (c["mcnemar_p"] < alpha
                             and c["counts"]["only_a"] > c["counts"]["only_b"])

    not_sep = None
    for n in reversed(sizes):
        if dlsr_better(n):
            break
        not_sep = n
    if not sizes:
        sentence = "no size measured yet"
    elif level is not None:
        sentence = (f"{ggcnn} catches up with {dlsr} at {level} training scenes (as many "
                    f"successes on the same test scenes)")
    elif not_sep is not None:
        sentence = (f"{ggcnn} stays below {dlsr} up to {sizes[-1]} scenes, but from "
                    f"{not_sep} scenes on the two are not separated (exact McNemar, "
                    f"p >= {alpha:g})")
    else:
        sentence = (f"{ggcnn} does not catch up with {dlsr} up to {sizes[-1]} training "
                    f"scenes: {dlsr} is better at every size measured")
    return {"sizes": sizes, "level": level, "not_separated": not_sep, "sentence": sentence}


def curve_markdown(result: dict) -> str:
    """The table of :func:`data_efficiency` (Markdown): one row per size and detector, the
    paired comparisons, GG-CNN's validation curve and :func:`catch_up`'s answer."""
    lines = ["| training scenes | detector | success | 95 % CI (Wilson) | rectangle metric "
             "(held-out images) | training s | planning s/grasp | GG-CNN budget |",
             "|---|---|---|---|---|---|---|---|"]
    for key in sorted(result["rows"], key=int):
        for name, r in result["rows"][key].items():
            if "n" not in r:
                continue
            lo, hi = r["ci95"]
            rect = r.get("rect") or {}
            plan = r.get("planning_seconds")
            plan = "" if plan is None else f"{plan:.2f}"
            lines.append(
                f"| {key} | {name} | {r['successes']}/{r['n']} | "
                f"{100 * lo:.1f}-{100 * hi:.1f} % | {rect.get('correct', '')}/"
                f"{rect.get('n', '')} | {r['train_seconds']:.0f} | {plan}"
                f" | {r.get('budget', '')} |")
    lines += ["", "| training scenes | comparison | only first | only second | exact McNemar p |",
              "|---|---|---|---|---|"]
    for key in sorted(result["comparisons"], key=int):
        for name, c in result["comparisons"][key].items():
            k = c["counts"]
            lines.append(f"| {key} | {name} | {k['only_a']} | {k['only_b']} | "
                         f"{c['mcnemar_p']:.3g} |")
    lines += ["", "GG-CNN validation (train objects): success per sample-step budget", "",
              "| training scenes | " + " | ".join(map(str, result["config"]["budgets"])) + " |",
              "|---|" + "---|" * len(result["config"]["budgets"])]
    for key in sorted(result["validation"], key=int):
        v = result["validation"][key]
        lines.append(f"| {key} | " + " | ".join(
            f"{v[str(b)]['successes']}/{v[str(b)]['n']}" if str(b) in v else ""
            for b in result["config"]["budgets"]) + " |")
    lines += ["", f"Catching up: {catch_up(result)['sentence']}."]
    return "\n".join(lines) + "\n"


def curve_figure(result: dict, path) -> None:
    """Left: success against training scenes, one line per detector, Wilson intervals. Right:
    GG-CNN's validation curve, success on validation scenes of the train objects against
    sample-steps, one line per training size (PNG)."""
    # deferred, heavy and rarely used: matplotlib, for figures only
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, av) = plt.subplots(1, 2, figsize=(11, 4.2))
    names = sorted({n for r in result["rows"].values() for n in r})
    for name in names:
        pts = [(int(k), r[name]) for k, r in result["rows"].items() if "n" in r.get(name, {})]
        if not pts:
            continue
        pts.sort()
        x = np.array([p[0] for p in pts])
        y = np.array([p[1]["successes"] / p[1]["n"] for p in pts])
        lo = np.array([p[1]["ci95"][0] for p in pts])
        hi = np.array([p[1]["ci95"][1] for p in pts])
        err = 100 * np.clip([y - lo, hi - y], 0, None)
        ax.errorbar(x, 100 * y, yerr=err, marker="o", capsize=3, label=name,
                    linestyle="--" if name.endswith("@dlsr-time") else "-")
    sizes = sorted(int(k) for k in result["rows"])
    ax.set_xscale("log")
    ax.set_xticks(sizes, [str(s) for s in sizes])
    ax.minorticks_off()
    ax.set_xlabel("training scenes (train objects)")
    ax.set_ylabel("physical success on test objects (%)")
    ax.set_ylim(0, 100)
    # above the highest interval (DLSR's, about 75 %), not over the lines
    ax.legend(fontsize=7, ncol=3, loc="upper center")
    for key in sorted(result.get("validation", {}), key=int):
        v = result["validation"][key]
        steps = sorted(int(b) for b in v)
        if not steps:
            continue
        k = np.array([v[str(b)]["successes"] for b in steps])
        n = np.array([v[str(b)]["n"] for b in steps])
        ci = np.array([wilson_interval(int(a), int(b)) for a, b in zip(k, n, strict=True)])
        y = k / np.maximum(n, 1)
        err = 100 * np.clip([y - ci[:, 0], ci[:, 1] - y], 0, None)
        av.errorbar(steps, 100 * y, yerr=err, marker="o", capsize=3, label=f"{key} scenes")
    budgets = sorted(int(b) for b in result.get("config", {}).get("budgets", []))
    av.set_xscale("log")
    if budgets:
        av.set_xticks(budgets, [f"{b:,}" for b in budgets])
        av.minorticks_off()
    av.set_xlabel("GG-CNN sample-steps")
    av.set_ylabel("success on validation scenes, train objects (%)")
    av.set_ylim(0, 100)
    if result.get("validation"):
        av.legend(fontsize=7, ncol=2, loc="upper center")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)

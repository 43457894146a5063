"""Campaigns of the default job's detectors beyond its own trial stage.

* :func:`object_set_campaign` (``scripts/object_sets.py``): paired grasp trials of DLSR,
  dlsr-paper, mask-pca and the oracle on an object set, as the default job's trial stage runs
  them (32 dense labelling candidates per scene, DLSR's lattice search with the gripper-aware
  check, dlsr-paper the paper's grid search), every detector on the same scenes, and the table
  of each detector's success, its paired difference to mask-pca and its trials on objects
  that physics marks not graspable.
* :func:`peer_protocol_campaign` (``scripts/scenes_franka.py``): the same detectors in the
  peers' protocols (:data:`PEER_ROWS`: clutter-removal rounds of 5 objects in a pile and
  packed, single-object trials with the Franka hand), grown in steps
  (:func:`graspsim.eval.comparison_grid.grow`).

Both use the default job's models (:func:`default_models`), trained by
:func:`graspsim.pipeline.job.run_job` with the default configuration without the offline
benchmarks (which do not change the models); nothing is chosen on the trial scenes.
"""

from __future__ import annotations

import json
from pathlib import Path

from dlsr.records import read_jsonl, write_text_atomic

from ..eval.compare import compare_outcomes
from ..eval.comparison_grid import Row, grow
from ..eval.stats import wilson_interval
from ..eval.trials import TrialConfig, run_trials
from ..labels.graspability import graspability_flags
from ..runtime.executor import Executor
from ..sim.object_sets import parse_object_set
from .config import RunConfig
from .job import run_job, trial_detector

__all__ = ["DETECTORS", "PEER_ROWS", "PEER_CANDIDATES", "default_models", "campaign_folder",
           "object_set_campaign", "trial_table", "table_markdown", "table_only",
           "peer_protocol_campaign"]

#: The detectors of both campaigns.
DETECTORS = ("dlsr", "dlsr-paper", "mask-pca", "oracle")
#: The peers' protocols: pile and packed clutter-removal rounds, the Franka hand.
PEER_ROWS = {"pile": Row("pile", scene="pile"), "packed": Row("packed", scene="packed"),
             "franka": Row("franka", hand="franka")}
#: Labels per observation for the oracle (the default job's ``trial_candidates``).
PEER_CANDIDATES = 32


def default_models(folder, jobs: int | None = None, progress: bool = True):
    """Train (or find) the default job's models in ``folder``.

    Parameters
    ----------
    folder : str or Path
        The run folder (resumed when it holds the same run).
    jobs : int or None
        Parallel workers (an execution setting: the folder is the same for any).
    progress : bool

    Returns
    -------
    model_path : Path
        The DLSR model (``folder/model/dlsr``; dlsr-paper's beside it).
    config : RunConfig
    """
    config = RunConfig(offline=False, trials=1, baselines=[],
                       **({} if jobs is None else {"jobs": jobs}))
    run_job(config, out=Path(folder), progress=progress)
    return Path(folder) / "model" / "dlsr", config


def campaign_folder(out, objects: str) -> Path:
    """Where :func:`object_set_campaign` keeps the trials of an object set.

    Parameters
    ----------
    out : str or Path
    objects : str

    Returns
    -------
    Path
    """
    return Path(out) / objects.replace(":", "-").replace("/", "_")


def object_set_campaign(objects: str = "random_urdfs:test", n: int = 200, seed: int = 0,
                        out="runs/object-sets", detectors=DETECTORS, model_run=None,
                        jobs: int = 2, graspability: bool = False,
                        progress: bool = True) -> dict:
    """Paired trials of ``detectors`` on an object set and their table (see the module
    docstring); resumed trial by trial.

    Parameters
    ----------
    objects : str
        The object set (:func:`graspsim.sim.object_sets.parse_object_set`).
    n : int
        Trials per detector.
    seed : int
    out : str or Path
        ``out/<objects>/<detector>/`` holds the trials, ``out/<objects>/table.{json,md}`` the
        table.
    detectors : sequence of str
        Names of :func:`graspsim.pipeline.job.trial_detector`.
    model_run : str or Path or None
        The run folder of the default job's models (default ``out/model``), trained when a
        DLSR detector is asked for.
    jobs : int
        Parallel workers of the trials.
    graspability : bool
        Compute the physics graspability flags that are not cached.
    progress : bool

    Returns
    -------
    dict
        :func:`trial_table`'s.
    """
    names = list(detectors)
    config = RunConfig(offline=False, trials=1, baselines=[])
    model_run = Path(out) / "model" if model_run is None else Path(model_run)
    model_path = model_run / "model" / "dlsr"
    if any(name.startswith("dlsr") for name in names):
        model_path, config = default_models(model_run, progress=progress)
    oset = parse_object_set(objects)
    folder = campaign_folder(out, objects)
    executor = Executor(backend="loky" if jobs != 1 else "sequential", n_jobs=jobs,
                        progress=progress)
    trial_cfg = TrialConfig(n_candidates=config.trial_candidates, sampler=config.label_sampler)
    for name in names:
        run_trials(trial_detector(name, model_path, config), objects=oset, n=n, seed=seed,
                   out=folder / name, config=trial_cfg, executor=executor, progress=progress,
                   detector_name=name, labels=folder / "labels")
    table = trial_table(folder, names, oset, graspability)
    _write_table(folder, table)
    return table


def trial_table(folder: Path, names, oset, compute: bool) -> dict:
    """Success, intervals, paired verdicts against mask-pca and the not-graspable check, on
    the trial indices every detector has finished (all of them once the runs are complete).

    Parameters
    ----------
    folder : Path
        The campaign folder (:func:`campaign_folder`), one trial folder per detector.
    names : sequence of str
        The detectors.
    oset : ObjectSet
        The trials' objects.
    compute : bool
        Compute the physics graspability flags that are not cached
        (:func:`graspsim.labels.graspability.graspability_flags`); otherwise the cached ones
        only.

    Returns
    -------
    dict
        ``objects``, ``fingerprint``, ``indices`` (paired trials), ``rows`` (per detector:
        ``successes``, ``n``, ``rate``, ``ci95``, ``vs_mask_pca``, and the trials and successes
        on objects not graspable by physics) and ``flags``.
    """
    flags = graspability_flags(oset, compute=compute, partial=not compute)
    recs = {}
    for name in names:
        path = folder / name / "trials.jsonl"
        if not path.is_file():
            raise FileNotFoundError(f"{path}: not found (no trials of detector {name!r})")
        recs[name] = {r["index"]: r for r in read_jsonl(path, required=("index",))}
    common = sorted(set.intersection(*(set(r) for r in recs.values())))
    rows = []
    for name in names:
        out = [bool(recs[name][i]["success"]) for i in common]
        k, n = sum(out), len(out)
        row = {"detector": name, "successes": k, "n": n, "rate": k / n if n else None,
               "ci95": list(wilson_interval(k, n))}
        if name != "mask-pca" and "mask-pca" in recs and n:
            c = compare_outcomes(out, [bool(recs["mask-pca"][i]["success"]) for i in common],
                                 names=(name, "mask-pca"))
            row["vs_mask_pca"] = {k_: c[k_] for k_ in ("n", "counts", "difference",
                                                       "difference_ci", "mcnemar_p", "better")}
        objs = [recs[name][i]["object"] for i in common]
        known = [i for i, o in zip(common, objs, strict=True)
                 if flags is not None and all(x in flags for x in o)]
        bad = [i for i in known if not all(flags[x] for x in recs[name][i]["object"])]
        row["trials_with_flags"] = len(known)
        row["not_graspable_trials"] = len(bad)
        row["not_graspable_successes"] = sum(bool(recs[name][i]["success"]) for i in bad)
        rows.append(row)
    return {"objects": oset.text, "fingerprint": oset.fingerprint(), "indices": len(common),
            "rows": rows, "flags": None if flags is None else {
                "n_objects": len(flags), "graspable": sum(flags.values())}}


def table_markdown(t: dict) -> str:
    """:func:`trial_table`'s table as Markdown.

    Parameters
    ----------
    t : dict

    Returns
    -------
    str
    """
    lines = [f"Object set `{t['objects']}` (fingerprint {t['fingerprint'][:12]}), "
             f"{t['indices']} paired trials", "",
             "| detector | success | 95 % interval | vs mask-pca (paired, Newcombe 95 %, exact "
             "McNemar) | successes on objects not graspable by physics |",
             "|---|---|---|---|---|"]
    for r in t["rows"]:
        lo, hi = r["ci95"]
        v = r.get("vs_mask_pca")
        verdict = "" if v is None else (
            f"{100 * v['difference']:+.1f} [{100 * v['difference_ci'][0]:+.1f}, "
            f"{100 * v['difference_ci'][1]:+.1f}], p = {v['mcnemar_p']:.2g}")
        ng = (f"{r['not_graspable_successes']}/{r['not_graspable_trials']} "
              f"({r['trials_with_flags']} trials with a flag)")
        lines.append(f"| {r['detector']} | {r['successes']}/{r['n']} = {100 * r['rate']:.1f} % "
                     f"| [{100 * lo:.1f}, {100 * hi:.1f}] | {verdict} | {ng} |")
    return "\n".join(lines) + "\n"


def table_only(out, objects: str, names) -> dict:
    """The table of the trials finished so far (no new trial), written beside them.

    Parameters
    ----------
    out : str or Path
    objects : str
        The object-set text.
    names : sequence of str
        The detectors.

    Returns
    -------
    dict
        :func:`trial_table`'s.
    """
    folder = campaign_folder(out, objects)
    table = trial_table(folder, names, parse_object_set(objects), False)
    _write_table(folder, table)
    return table


def _write_table(folder: Path, table: dict) -> None:
    write_text_atomic(folder / "table.json", json.dumps(table, indent=1) + "\n")
    write_text_atomic(folder / "table.md", table_markdown(table))


def peer_protocol_campaign(out, rows=tuple(PEER_ROWS), detectors=DETECTORS, jobs: int = 2,
                           steps: int | None = None) -> None:
    """The detectors in the peers' protocols (:data:`PEER_ROWS`), grown in steps.

    Every cell grows to 25 trials or 6 rounds, then 50 / 12, ... so that whatever has finished
    when it is stopped covers every cell; a rerun resumes every campaign where it stopped.
    After each step ``out/results.json`` and ``out/results.md`` are written
    (:func:`graspsim.eval.comparison_grid.grow`).

    Parameters
    ----------
    out : str or Path
    rows : sequence of str
        Keys of :data:`PEER_ROWS`.
    detectors : sequence of str
    jobs : int
    steps : int or None
        Growth steps to run (None: all).
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    model_path, cfg = ((default_models(out / "model-run", jobs, progress=False))
                       if {"dlsr", "dlsr-paper"} & set(detectors) else (None, None))
    ex = Executor(backend="loky" if jobs != 1 else "sequential", n_jobs=jobs, progress=False)
    grow([PEER_ROWS[r] for r in rows], list(detectors),
         lambda name, row: trial_detector(name, model_path, cfg, hand=row.hand),
         out, executor=ex, steps=steps, candidates=PEER_CANDIDATES)

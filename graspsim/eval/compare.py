"""Paired comparisons of two detectors run on the same scenes.

Trial ``i`` of a ``graspsim trials`` run with seed ``s`` depends only on ``(s, i)`` (see
:mod:`graspsim.eval.trials`), and ``graspsim score`` runs every image of a dataset in that image's
rebuilt scene. Two detectors run with the same seed and objects (or scored on the same dataset)
therefore meet exactly the same scenes, and their outcomes are **paired**: the question is not
whether two Wilson intervals overlap, but on how many scenes one detector succeeded where the
other failed. For each pair of folders this module gives

* the 2x2 table of paired outcomes: both succeeded, only A, only B, neither;
* the difference in success rate, ``(only A - only B) / n``, with Newcombe's score interval
  for the difference of paired proportions (method 10 of R. G. Newcombe, *Improved confidence
  intervals for the difference between binomial proportions based on paired data*, Statistics
  in Medicine 17:2635-2650, 1998; the "square-and-add" interval of Fagerland, Lydersen and
  Laake, *Statistical Analysis of Contingency Tables*, 2017, ch. 8): the Wilson intervals of the
  two success rates combined with the estimated correlation between them;
* the exact (conditional) McNemar p-value: under "no difference" the discordant scenes split
  between A and B like fair coin flips, so ``p`` is the two-sided binomial test of
  ``only A`` successes in ``only A + only B`` trials with probability 1/2 (McNemar,
  Psychometrika 12:153-157, 1947; the ``exact=True`` test of statsmodels'
  ``statsmodels.stats.contingency_tables.mcnemar``, which doubles the smaller binomial tail);
* a verdict: which detector is better at the 5 % level (by the McNemar test), or that the two
  are not separated. The interval is an approximation and the exact test is conservative, so
  with few discordant scenes they can disagree (an interval just excluding 0 with p above 5 %);
  the verdict follows the test and then says so. (Fagerland, Lydersen and Laake, BMC Medical
  Research Methodology 13:91, 2013, find the exact conditional test conservative and prefer
  its mid-p version; the exact test is kept here because a verdict should not overstate.)

Folders
-------
Trial folders (``config.json`` with ``seed``, ``objects`` and ``config.n_objects``, and
``trials.jsonl`` records keyed by ``index`` with ``object`` and ``success``) pair when seed,
objects, objects per scene and scene protocol (``config.scene``, :mod:`graspsim.sim.layouts`)
agree and every shared index holds the same objects. Score
folders (``config.json`` with ``dataset_fingerprint``, ``scores.jsonl`` records keyed by
``image`` with ``success``) pair when the fingerprints agree. Anything else is refused with a
one-line ``ValueError`` naming both folders and what differs.

Clutter-round folders (``graspsim trials --declutter``: ``config.json`` and ``rounds.jsonl``
records keyed by ``index`` with ``objects``, ``attempts`` and ``removed``) pair as trial folders
do (round ``i`` starts from the same scene in both). Later grasps of a round see what the
earlier ones left, so only the **first grasp** of each round is a paired outcome: it is the
``success`` compared above. Beside it, a sign test on the objects each round removed: the rounds
where A removed more against those where B did (ties dropped), the same exact binomial test
(``removed``).

Object-wise validation folders (``objectwise.json``, written by
:func:`graspsim.pipeline.objectwise_validation`) hold one run per object fold; two of them
pair when their folds hold the same objects and each fold's DLSR trial folders pair as above.
Their DLSR trials are pooled over the folds, keyed by (fold, trial index): this compares two
configurations on train objects their models never saw.

Trial folders whose records mark scenes as graspable (``graspable``, the manifest's flag) and
hold both kinds are also compared on the graspable scenes alone (``graspable``): the success
"on graspable objects" that the trial summaries and the README report. Two trial folders run
with different execution parameters (``config.json``'s ``execution``) still pair -- that is
how a harness setting is compared on fixed scenes -- but the comparison names the parameters
that differ (``execution``) and says that its difference mixes detector and harness.

Folders of different lengths (a 100-trial and a 200-trial run of the same seed, or a run still
going) are paired on the trials or images present in both: trial ``i`` is the same scene in
both, so the shared part is a valid paired sample. How many were left out of each folder is
recorded (``unpaired``) and logged; folders that share nothing are refused.
"""

from __future__ import annotations

import itertools
import json
import logging
from pathlib import Path

from dlsr.records import read_json, read_jsonl

from ..detectors.loading import detector_label
from ..sim.execution import describe_changes, execution_changes, execution_params_from_dict
from .stats import (
    CI_METHOD,
    TEST_METHOD,
    mcnemar_exact,
    paired_counts,
    paired_difference_ci,
    removed_sign_test,
    wilson_interval,
)

log = logging.getLogger(__name__)

__all__ = [
    "compare_outcomes",
    "load_folder",
    "pooled_fold_trials",
    "compare_pair",
    "compare_folders",
    "comparison_text",
    "short_labels",
    "first_grasp",
]

#: The summary file that marks an object-wise validation folder.
OBJECTWISE = "objectwise.json"

def _level(alpha: float) -> str:
    return f"{100 * alpha:g} %"


def compare_outcomes(a, b, names=("A", "B"), alpha: float = 0.05, unit: str = "trials") -> dict:
    """Paired comparison of two outcome sequences on the same scenes.

    Parameters
    ----------
    a, b : array-like of bool, shape (n,)
        Successes of the two detectors, scene by scene.
    names : (str, str)
        How the verdict names the detectors.
    alpha : float
        Test level and 1 - interval level.
    unit : str
        What a scene is called in the verdict (``"trials"``, ``"images"``).

    Returns
    -------
    dict
        ``n``, ``counts`` (:func:`paired_counts`), ``success_a``/``success_b`` (counts),
        ``difference`` (``p_A - p_B``, a fraction), ``difference_ci`` (``[lower, upper]``,
        level ``1 - alpha``), ``ci_method``, ``mcnemar_p``, ``test``, ``alpha``, ``better``
        (``"a"``, ``"b"`` or None) and ``verdict`` (a sentence).
    """
    counts = paired_counts(a, b)
    n = sum(counts.values())
    if n == 0:
        raise ValueError("no paired outcomes to compare")
    na, nb = names
    x, y = counts["only_a"], counts["only_b"]
    p = mcnemar_exact(x, y)
    lo, hi = paired_difference_ci(**counts, alpha=alpha)
    better = None
    if p < alpha:
        better = "a" if x > y else "b"
        win, lose = (na, nb) if better == "a" else (nb, na)
        wx, lx = (x, y) if better == "a" else (y, x)
        verdict = (f"{win} is better than {lose} at the {_level(alpha)} level (exact McNemar "
                   f"p = {p:.2g}): of the {n} paired {unit}, {win} alone succeeded on {wx} and "
                   f"{lose} alone on {lx}.")
    else:
        verdict = (f"{na} and {nb} are not separated at the {_level(alpha)} level (exact "
                   f"McNemar p = {p:.2g}): of the {n} paired {unit}, {na} alone succeeded on "
                   f"{x} and {nb} alone on {y}.")
    if (lo > 0 or hi < 0) != (better is not None):
        verdict += (f" (The {100 * (1 - alpha):g} % interval, an approximation, "
                    f"{'excludes' if lo > 0 or hi < 0 else 'includes'} 0 here: with few "
                    f"discordant {unit} the exact test is the more conservative of the two, "
                    "and the verdict follows the test.)")
    return {
        "n": n, "counts": counts,
        "success_a": counts["both"] + x, "success_b": counts["both"] + y,
        "difference": (x - y) / n, "difference_ci": [lo, hi], "ci_method": CI_METHOD,
        "mcnemar_p": p, "test": TEST_METHOD, "alpha": alpha, "better": better,
        "verdict": verdict,
    }


def load_folder(folder) -> dict:
    """A trial, score or object-wise validation folder's configuration and outcome records.

    Parameters
    ----------
    folder : str or Path
        A ``graspsim trials`` folder (``config.json``, ``trials.jsonl``), a clutter-round
        folder (``config.json``, ``rounds.jsonl``; each round's first grasp is its
        ``success``), a ``graspsim score`` folder (``config.json`` with
        ``dataset_fingerprint``, ``scores.jsonl``) or a finished object-wise validation
        (``objectwise.json``; its DLSR trials).

    Returns
    -------
    dict
        ``folder`` (Path), ``kind`` (``"trials"``, ``"rounds"``, ``"scores"`` or
        ``"objectwise"``),
        ``config`` (dict), ``name`` (the detector recorded in the configuration, else the
        folder's name; the configuration's name for an object-wise validation), ``file`` (the
        JSONL path, or ``objectwise.json``) and ``records`` (dict: trial index (int), image id
        (str) or (fold, trial index) -> record; the scenes that could not be made are left
        out and counted in ``skipped``); an object-wise validation also has ``folds``
        (each fold's loaded DLSR trial folder).
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: no such folder")
    if (folder / OBJECTWISE).exists():
        return _load_objectwise(folder)
    cfg_path = folder / "config.json"
    if not cfg_path.exists() and (folder / "fold0").is_dir():
        raise FileNotFoundError(f"{folder / OBJECTWISE} is missing: {folder} looks like an "
                                "unfinished object-wise validation; run it to the end first")
    if not cfg_path.exists():
        raise FileNotFoundError(f"{cfg_path} is missing: {folder} is not a trials or score folder")
    config = read_json(cfg_path, "configuration")
    if "dataset_fingerprint" in config:
        kind, jsonl, key = "scores", folder / "scores.jsonl", "image"
    elif (folder / "rounds.jsonl").exists():
        kind, jsonl, key = "rounds", folder / "rounds.jsonl", "index"
    else:
        kind, jsonl, key = "trials", folder / "trials.jsonl", "index"
    if not jsonl.exists():
        raise FileNotFoundError(f"{jsonl} is missing: {folder} holds no {kind}")
    records: dict = {}
    skipped = 0
    for number, rec in enumerate(read_jsonl(jsonl), start=1):
        if "skipped" in rec:  # a scene that could not be made: no outcome to pair
            skipped += 1
            continue
        if kind == "rounds":
            rec = _first_grasp(rec, jsonl, number)
        if key not in rec or "success" not in rec:
            raise ValueError(f"{jsonl}: record {number} has no '{key}' or no 'success'")
        if rec["success"] not in (True, False, 0, 1):
            raise ValueError(f"{jsonl}: record {number} has success {rec['success']!r}, "
                             "expected true or false")
        try:
            k = int(rec[key]) if kind == "trials" else str(rec[key])
        except (TypeError, ValueError):
            raise ValueError(f"{jsonl}: record {number} has {key} {rec[key]!r}") from None
        if k in records:
            if bool(records[k]["success"]) != bool(rec["success"]):
                raise ValueError(f"{jsonl}: {key} {k!r} appears twice with different outcomes")
            continue
        records[k] = rec
    if not records:
        raise ValueError(f"{jsonl}: no records")
    name = str(config.get("detector") or config.get("name") or folder.name)
    return {"folder": folder, "kind": kind, "config": config, "name": name, "file": jsonl,
            "records": records, "skipped": skipped}


def first_grasp(record: dict) -> bool:
    """Whether a clutter round's first grasp lifted an object (False when nothing was
    proposed): the paired outcome of two detectors' rounds."""
    attempts = record.get("attempts") or []
    return bool(attempts and attempts[0].get("success"))


def _first_grasp(rec, jsonl: Path, number: int) -> dict:
    """A clutter round's record with its first grasp's outcome as ``success`` (False when
    nothing was proposed) and its objects as ``object``."""
    attempts, removed = rec.get("attempts"), rec.get("removed")
    if not isinstance(attempts, list) or isinstance(removed, bool) \
            or not isinstance(removed, int):
        raise ValueError(f"{jsonl}: round record {number} has no 'attempts' list or no "
                         "'removed' count")
    return {**rec, "success": first_grasp(rec), "object": rec.get("objects")}


def pooled_fold_trials(folder, n_folds: int, detector: str = "dlsr") -> tuple[list, dict]:
    """One detector's trials in the fold runs of an object-wise validation, pooled.

    Parameters
    ----------
    folder : str or Path
        The validation's folder (fold runs ``fold0``, ``fold1``, ...).
    n_folds : int
    detector : str
        Its trial folder in each run (``fold<k>/trials/<detector>``).

    Returns
    -------
    folds : list of dict
        Each fold's loaded trial folder (:func:`load_folder`).
    records : dict
        ``(fold, trial index) -> record`` over every fold, the key by which two validations'
        (or two detectors') trials pair.
    """
    folder = Path(folder)
    loaded, records = [], {}
    for k in range(n_folds):
        sub = load_folder(folder / f"fold{k}" / "trials" / detector)
        if sub["kind"] != "trials":
            raise ValueError(f"{sub['folder']}: not a trials folder")
        loaded.append(sub)
        records.update({(k, i): r for i, r in sub["records"].items()})
    return loaded, records


def _load_objectwise(folder: Path, detector: str = "dlsr") -> dict:
    """An object-wise validation folder as one folder of paired trials (see
    :func:`load_folder`): ``detector``'s trials of every fold, keyed by (fold, trial index)."""
    path = folder / OBJECTWISE
    summary = read_json(path, "object-wise validation summary")
    folds = summary.get("folds") if isinstance(summary, dict) else None
    if not isinstance(folds, list) or not folds or not all(
            isinstance(f, dict) and isinstance(f.get("objects"), list) for f in folds):
        raise ValueError(f"{path}: no 'folds' with their objects")
    loaded, records = pooled_fold_trials(folder, len(folds), detector)
    config = {"fold_seed": summary.get("fold_seed"),
              "folds": [list(f["objects"]) for f in folds]}
    name = str((summary.get("config") or {}).get("name") or folder.name)
    return {"folder": folder, "kind": "objectwise", "config": config, "name": name,
            "file": path, "records": records, "folds": loaded}


def _scene_differences(a: dict, b: dict) -> list[str]:
    """What makes two loaded folders' scenes differ (empty: they pair)."""
    if a["kind"] != b["kind"]:
        return [f"a {a['kind']} folder against a {b['kind']} folder"]
    ca, cb = a["config"], b["config"]
    if a["kind"] == "objectwise":
        if ca["folds"] != cb["folds"]:
            return [f"object folds {json.dumps(ca['folds'])} vs {json.dumps(cb['folds'])} "
                    "(validate both with the same --folds and --fold-seed)"]
        return [f"fold {k}: {d}" for k, (fa, fb) in enumerate(zip(a["folds"], b["folds"],
                                                                 strict=True))
                for d in _scene_differences(fa, fb)]
    if a["kind"] == "scores":
        fa, fb = ca.get("dataset_fingerprint"), cb.get("dataset_fingerprint")
        return [] if fa == fb else [f"dataset_fingerprint {fa} vs {fb}"]
    out = []
    for key in ("seed", "objects"):
        if key not in ca or key not in cb:
            out.append(f"no '{key}' in config.json of "
                       f"{a['folder'] if key not in ca else b['folder']}")
        elif ca[key] != cb[key]:
            out.append(f"{key} {json.dumps(ca[key])} vs {json.dumps(cb[key])}")
    na = (ca.get("config") or {}).get("n_objects", 1)
    nb = (cb.get("config") or {}).get("n_objects", 1)
    if na != nb:
        out.append(f"n_objects {na} vs {nb}")
    sa = (ca.get("config") or {}).get("scene", "drop")
    sb = (cb.get("config") or {}).get("scene", "drop")
    if sa != sb:
        out.append(f"scene {sa} vs {sb}")
    if not out:
        for i in sorted(set(a["records"]) & set(b["records"])):
            oa, ob = a["records"][i].get("object"), b["records"][i].get("object")
            if oa != ob:
                out.append(f"trial {i} has objects {oa} vs {ob}")
                break
    return out


def _tail(text: str, k: int) -> str:
    """The last ``k`` parts of a path-like name (the whole name when it has fewer)."""
    parts = [p for p in str(text).replace("\\", "/").split("/") if p]
    return "/".join(parts[-k:]) if parts else str(text)


def _unique(labels: list[str], longer) -> list[str]:
    """``labels`` where every label that two folders share is replaced by ``longer(i, k)``
    with ``k`` = 2, 3, ... until the shared ones differ (or ``longer`` stops changing)."""
    labels = list(labels)
    for k in range(2, 64):
        dup = [i for i, lab in enumerate(labels) if labels.count(lab) > 1]
        if not dup:
            break
        new = {i: longer(i, k) for i in dup}
        if all(new[i] == labels[i] for i in dup):
            break
        labels = [new.get(i, lab) for i, lab in enumerate(labels)]
    return labels


def short_labels(names, folders) -> list[str]:
    """Short, distinct labels of compared folders, for tables and verdicts.

    Each detector name is shortened to its last path part (a model at ``runs/net/model/ggcnn``
    is ``ggcnn``; ``ggcnn-model+aware`` stays), more of the path is added where two labels
    would be the same, and folders of the same detector name are told apart by the shortest
    part of their folder paths that differs (``runs/a/trials/mask-pca`` and
    ``runs/b/trials/mask-pca``: ``mask-pca [a]`` and ``mask-pca [b]``).

    Parameters
    ----------
    names : sequence of str
        The detectors recorded in the folders.
    folders : sequence of str or Path
        The folders, in the same order.

    Returns
    -------
    list of str
    """
    names = [str(n) for n in names]
    parts = [Path(f).resolve().parts for f in folders]
    labels = _unique([_tail(n, 1) for n in names], lambda i, k: _tail(names[i], k))
    for lab in {lab for lab in labels if labels.count(lab) > 1}:
        group = [i for i, x in enumerate(labels) if x == lab]
        common = 0  # folder path parts the group's folders end with alike (trials/mask-pca)
        while all(len(parts[i]) > common + 1 for i in group) and len(
                {parts[i][-common - 1] for i in group}) == 1:
            common += 1
        cut = [parts[i][: len(parts[i]) - common] for i in group]
        for k in range(1, max(len(c) for c in cut) + 1):
            tails = ["/".join(c[-k:]) for c in cut]
            if len(set(tails)) == len(tails) or k == max(len(c) for c in cut):
                break
        if len(set(tails)) < len(tails):  # the same folder twice: its whole path
            tails = [Path(*parts[i]).as_posix() for i in group]
        for i, tail in zip(group, tails, strict=True):
            labels[i] = f"{lab} [{tail}]"
    return labels


def _compact_names(folders: list[dict]) -> list[str]:
    """Detector names with their options (``mod:Det(model=a.pt,top_k=5)``) cut to the options
    that differ among the compared folders of the same detector: none when it is compared
    once."""
    bases, options = [], []
    for f in folders:
        name, opts = str(f["name"]), (f.get("config") or {}).get("detector_options")
        if isinstance(opts, dict) and opts and "(" in name:
            suffix = name[name.rindex(")") + 1:]  # "+aware"
            bases.append(name[: name.index("(")] + suffix)
            options.append(opts)
        else:
            bases.append(name)
            options.append(None)
    out = []
    for base, opts in zip(bases, options, strict=True):
        group = [o or {} for b, o in zip(bases, options, strict=True) if b == base]
        if opts is None or len(group) < 2:
            out.append(base)
            continue
        keys = sorted({k for o in group for k in o})
        differ = {k: opts.get(k) for k in keys
                  if len({json.dumps(o.get(k), sort_keys=True) for o in group}) > 1}
        head, plus, tail = base.partition("+aware")
        out.append(detector_label(head, differ) + plus + tail)
    return out


def _labels(folders: list[dict]) -> list[str]:
    return short_labels(_compact_names(folders), [f["folder"] for f in folders])


def _pair(a: dict, b: dict, names, alpha: float) -> dict:
    diff = _scene_differences(a, b)
    if diff:
        raise ValueError(f"{a['folder']} and {b['folder']} did not run on the same scenes: "
                         + "; ".join(diff))
    ka, kb = set(a["records"]), set(b["records"])
    keys = sorted(ka & kb)
    unit = {"scores": "images", "rounds": "rounds (first grasps)"}.get(a["kind"], "trials")
    if not keys:
        raise ValueError(f"{a['folder']} and {b['folder']} share no {unit}")
    unpaired = {"a": len(ka - kb), "b": len(kb - ka)}
    if unpaired["a"] or unpaired["b"]:
        log.warning("%s vs %s: %d %s paired; %d only in %s and %d only in %s left out",
                    names[0], names[1], len(keys), unit, unpaired["a"], a["folder"],
                    unpaired["b"], b["folder"])
    sa = [bool(a["records"][k]["success"]) for k in keys]
    sb = [bool(b["records"][k]["success"]) for k in keys]
    res = compare_outcomes(sa, sb, names=names, alpha=alpha, unit=unit)
    side = {}
    for tag, f, k, name in (("a", a, res["success_a"], names[0]),
                            ("b", b, res["success_b"], names[1])):
        side[tag] = {"folder": str(f["folder"]), "name": name, "successes": k,
                     "success_rate": k / res["n"],
                     "success_ci95": list(wilson_interval(k, res["n"]))}
    extra = {}
    if a["kind"] == "rounds":
        extra["removed"] = removed_sign_test([a["records"][k]["removed"] for k in keys],
                                             [b["records"][k]["removed"] for k in keys])
    if a["kind"] != "scores":
        g = [k for k in keys if a["records"][k].get("graspable") is True]
        if 0 < len(g) < len(keys):
            r = compare_outcomes([bool(a["records"][k]["success"]) for k in g],
                                 [bool(b["records"][k]["success"]) for k in g],
                                 names=names, alpha=alpha, unit=unit)
            extra["graspable"] = {k: r[k] for k in ("n", "counts", "success_a", "success_b",
                                                    "difference", "difference_ci",
                                                    "mcnemar_p", "better")}
    if a["kind"] in ("trials", "rounds"):
        ea, eb = _execution_changes(a), _execution_changes(b)
        if ea != eb:
            extra["execution"] = {"a": ea, "b": eb}
            log.warning("%s vs %s: run with different execution parameters (%s; %s): the "
                        "difference mixes detector and harness", names[0], names[1],
                        describe_changes(ea), describe_changes(eb))
    return {"kind": a["kind"], "unit": unit, **side, "unpaired": unpaired, **res, **extra}


def _execution_changes(f: dict) -> dict:
    """The execution parameters a trial folder ran with that differ from the defaults."""
    return execution_changes(execution_params_from_dict(
        f["config"].get("execution", {}), str(Path(f["folder"]) / "config.json")))



def compare_pair(folder_a, folder_b, names=None, alpha: float = 0.05) -> dict:
    """Compare two trial folders (or two score folders, or two object-wise validations) scene by
    scene.

    Parameters
    ----------
    folder_a, folder_b : str or Path
    names : (str, str) or None
        Labels of the two detectors (default: the detectors their ``config.json`` records).
    alpha : float
        Test level and 1 - interval level (0.05: 5 % test, 95 % interval).

    Returns
    -------
    dict
        ``a`` and ``b`` (folder, name, successes, success rate and its Wilson interval on the
        paired scenes), ``kind``, ``unit``, ``unpaired`` (scenes left out of each folder) and
        the fields of :func:`compare_outcomes`.
    """
    fa, fb = load_folder(folder_a), load_folder(folder_b)
    return _pair(fa, fb, tuple(names) if names is not None else tuple(_labels([fa, fb])), alpha)


def compare_folders(folders, alpha: float = 0.05) -> list[dict]:
    """Every pair of the given folders compared (see :func:`compare_pair`).

    Parameters
    ----------
    folders : sequence of str or Path
        At least two trial folders, two score folders or two object-wise validation folders.
    alpha : float

    Returns
    -------
    list of dict
        One comparison per pair, in the order of :func:`itertools.combinations`.
    """
    folders = list(folders)
    if len(folders) < 2:
        raise ValueError(f"compare needs at least two folders, got {len(folders)}")
    loaded = [load_folder(f) for f in folders]
    labels = _labels(loaded)
    return [_pair(loaded[i], loaded[j], (labels[i], labels[j]), alpha)
            for i, j in itertools.combinations(range(len(loaded)), 2)]


def comparison_text(c: dict) -> str:
    """A comparison (from :func:`compare_pair`) as a few lines of plain text."""
    na, nb = c["a"]["name"], c["b"]["name"]
    n = c["n"]
    k = c["counts"]
    un = c["unpaired"]
    left = ("" if not (un["a"] or un["b"]) else
            f"; left out: {un['a']} only in {na}'s folder, {un['b']} only in {nb}'s")
    w = max(len(na), len(nb)) + 8
    lo, hi = c["difference_ci"]
    level = f"{100 * (1 - c['alpha']):g} %"
    return "\n".join([
        f"{na} vs {nb}: {n} paired {c['unit']}{left}",
        f"  {'':{w}} {nb + ' ok':>{len(nb) + 5}} {nb + ' failed':>{len(nb) + 9}}",
        f"  {na + ' ok':{w}} {k['both']:>{len(nb) + 5}} {k['only_a']:>{len(nb) + 9}}",
        f"  {na + ' failed':{w}} {k['only_b']:>{len(nb) + 5}} {k['neither']:>{len(nb) + 9}}",
        f"  success: {na} {c['success_a']}/{n} = {100 * c['success_a'] / n:.1f} %, "
        f"{nb} {c['success_b']}/{n} = {100 * c['success_b'] / n:.1f} %",
        f"  difference {na} - {nb}: {100 * c['difference']:+.1f} points, {level} interval "
        f"[{100 * lo:+.1f}, {100 * hi:+.1f}] (Newcombe 1998, method 10)",
        f"  exact McNemar p = {c['mcnemar_p']:.3g}",
        f"  {c['verdict']}",
        *_removed_lines(c, na, nb),
        *_graspable_lines(c, na, nb, level),
        *([f"  execution parameters differ ({na}: {describe_changes(c['execution']['a'])}; "
           f"{nb}: {describe_changes(c['execution']['b'])}): the difference mixes detector and "
           "harness"] if c.get("execution") else []),
    ])


def _removed_lines(c: dict, na: str, nb: str) -> list[str]:
    r = c.get("removed")
    if not r:
        return []
    return [f"  objects removed: {na} {r['a']}, {nb} {r['b']}; {na} removed more in "
            f"{r['more']} rounds, fewer in {r['fewer']} (sign test p = {r['sign_test_p']:.3g})"]


def _graspable_lines(c: dict, na: str, nb: str, level: str) -> list[str]:
    g = c.get("graspable")
    if not g:
        return []
    n, (lo, hi) = g["n"], g["difference_ci"]
    return [f"  on graspable objects ({n} paired {c['unit']}): {na} {g['success_a']}/{n} = "
            f"{100 * g['success_a'] / n:.1f} %, {nb} {g['success_b']}/{n} = "
            f"{100 * g['success_b'] / n:.1f} %; difference {100 * g['difference']:+.1f} "
            f"points, {level} interval [{100 * lo:+.1f}, {100 * hi:+.1f}], exact McNemar "
            f"p = {g['mcnemar_p']:.3g} ({g['counts']['only_a']} against "
            f"{g['counts']['only_b']} won alone)"]

"""The data-efficiency curve carried to the crossover: DLSR against the CNN peers trained to
their plateau, at growing training sizes, on the same labelled test scenes.

:func:`crossover_study` grows one physics-labelled dataset of the train objects and, for every
training size ``n`` (nested subsets, smallest first):

* trains DLSR's two rows (:func:`graspsim.eval.data_efficiency.train_dlsr_models`, timed);
* trains each CNN peer (GG-CNN, GR-ConvNet) to its plateau
  (:mod:`graspsim.detectors.ggcnn.plateau`):
  budgets doubled from ``start`` sample-steps until physical success on ``val_trials``
  validation scenes of the *train* objects stops improving for two budgets in a row, or the
  authors' recipe (:data:`RECIPES`) is reached; the budget with the most validation successes
  is used (ties to the smaller). GR-ConvNet is the published ``k = 32`` network unless its
  plateau is not reached within ``max_hours`` of training at that size; it is then trained as
  the authors' ``k = 16`` variant and named so (``grconvnet16``), and the ``k = 32`` budget
  curve stays in the record beside it (the two compared at that size); at the larger sizes,
  whose plateaus need no fewer steps, ``k = 16`` is trained directly. Once a plateau is found,
  the budgets' weights other than the chosen one's and the training checkpoint are deleted
  (:func:`graspsim.detectors.ggcnn.plateau.prune_snapshots`; their records stay);
* runs every detector on the same ``test_trials`` scenes of the test objects (one seed),
  labelled once (``test_candidates`` physics labels per scene, shared by every detector through
  :class:`graspsim.labels.store.SceneLabels`), so that each trial has both its physical outcome
  and the rectangle metric's verdict on the executed rectangle: the peers raw and gripper-aware,
  both also at DLSR's training wall time (:func:`graspsim.eval.data_efficiency.equal_time_model`),
  DLSR's two rows, mask-pca and the oracle (best labelled candidate);
* compares them scene by scene (exact McNemar): each peer against DLSR, and against mask-pca.

:func:`crossover` states, for the pair fixed beforehand (DLSR's default against each peer made
gripper-aware), the first size at which the peer is ahead with p < 0.05, or that there is none;
:func:`metric_physics` gives the rectangle metric against physics as a 2x2 table per detector.

Everything is written as it is finished (``crossover.json``, ``crossover.md``) and a rerun
resumes (datasets per scene, models per budget, trials per trial); ``max_size`` stops after a
size, so a long campaign lands in pieces.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

from dlsr.datasets import load_cornell
from dlsr.records import read_json, write_text_atomic

from ..data.datagen import make_dataset
from ..detectors.ggcnn.detector import GGCNNDetector, GRConvNetDetector
from ..detectors.ggcnn.model import model_paths, network_of
from ..detectors.ggcnn.plateau import prune_snapshots, train_to_plateau
from ..detectors.ggcnn.train import trainer
from ..detectors.gripper_aware import gripper_aware
from ..detectors.loading import load_detector
from ..runtime.executor import Executor, task_seeds
from .compare import compare_outcomes
from .data_efficiency import equal_time_model, train_dlsr_models
from .stats import wilson_interval
from .trials import TrialConfig, run_trials

log = logging.getLogger(__name__)

__all__ = ["RECIPES", "PEERS", "crossover_study", "crossover", "metric_physics",
           "crossover_markdown"]

#: The authors' training recipes in sample-steps (batch 8): GR-ConvNet 50 epochs of 1,000
#: batches (Kumra et al.'s ``train_network.py`` defaults, docs/guides/grconvnet.md); GG-CNN
#: 30 epochs of 1,000 batches, the upper end of the 160k-240k of Morrison et al.'s training
#: script (docs/guides/ggcnn.md).
RECIPES = {"ggcnn": 240_000, "grconvnet": 400_000}
#: The CNN peers, in table order.
PEERS = ("ggcnn", "grconvnet")


def metric_physics(records) -> dict:
    """The rectangle metric's verdict against the physical outcome of the same trials.

    Parameters
    ----------
    records : sequence of dict
        Trial records with ``success`` and ``metric`` (None when the scene had no label, or
        nothing was proposed and executed: left out).

    Returns
    -------
    dict
        ``right_lifted``, ``right_dropped``, ``wrong_lifted``, ``wrong_dropped`` (counts),
        ``n`` (trials with a verdict), ``metric_accuracy`` and ``success_rate`` on them, and
        ``lifted_given_right`` (how often a rectangle the metric accepts lifts the object;
        None when it accepts none).
    """
    t = {"right_lifted": 0, "right_dropped": 0, "wrong_lifted": 0, "wrong_dropped": 0}
    for r in records:
        if r.get("metric") is None:
            continue
        key = ("right" if r["metric"] else "wrong") + ("_lifted" if r["success"] else "_dropped")
        t[key] += 1
    n = sum(t.values())
    right = t["right_lifted"] + t["right_dropped"]
    return {**t, "n": n,
            "metric_accuracy": right / n if n else None,
            "success_rate": (t["right_lifted"] + t["wrong_lifted"]) / n if n else None,
            "lifted_given_right": t["right_lifted"] / right if right else None}


def crossover(result: dict, dlsr: str = "dlsr", alpha: float = 0.05) -> dict:
    """The first training size at which each peer (gripper-aware, as DLSR's default is) is
    ahead of DLSR with exact McNemar p < ``alpha``, on the scenes of :func:`crossover_study`.

    Returns
    -------
    dict
        Peer row name (``ggcnn+aware``, ``grconvnet+aware``, ...) to ``size`` (None: none up to
        the largest size measured), ``sizes`` (measured) and ``sentence``; the same at equal
        training wall time under ``"<peer>@dlsr-time"``.
    """
    out = {}
    peers = sorted({name for rows in result.get("rows", {}).values() for name in rows
                    if name.endswith("+aware") or name.endswith("+aware@dlsr-time")})
    for peer in peers:
        sizes = sorted(int(k) for k, rows in result["rows"].items()
                       if "n" in rows.get(peer, {}) and "n" in rows.get(dlsr, {}))
        first = None
        for n in sizes:
            c = result.get("comparisons", {}).get(str(n), {}).get(f"{peer} vs {dlsr}")
            if c and c["mcnemar_p"] < alpha and c["counts"]["only_a"] > c["counts"]["only_b"]:
                first = n
                break
        if not sizes:
            sentence = "no size measured yet"
        elif first is not None:
            sentence = (f"{peer} is ahead of {dlsr} from {first} training scenes (exact "
                        f"McNemar p < {alpha:g} on the same test scenes)")
        else:
            sentence = (f"{peer} is not ahead of {dlsr} with p < {alpha:g} at any size up to "
                        f"{sizes[-1]} training scenes")
        out[peer] = {"size": first, "sizes": sizes, "sentence": sentence}
    return out


def _k32_capped_at(result: dict, n: int) -> int | None:
    """The smallest training size below ``n`` at which GR-ConvNet ``k = 32`` passed the time
    cap (None: none)."""
    capped = [int(k) for k, p in result.get("plateau", {}).items()
              if int(k) < n and p.get("grconvnet", {}).get("stopped") == "capped"]
    return min(capped) if capped else None


def _peer_trainer(network: str, samples, seed: int, device: str, dlsr_seconds: float,
                  arch: dict, progress: bool):
    def train(out, steps, snapshots):
        return trainer(network)(samples, out, steps=steps, seed=seed, device=device,
                                snapshots=snapshots, snapshot_seconds=[dlsr_seconds],
                                progress=progress, **arch)

    return train


def crossover_study(out, sizes=(10, 30, 100, 300, 1000, 3000), peers=PEERS,
                    train_objects: str = "ycb:train", test_objects: str = "ycb:test",
                    test_trials: int = 200, val_trials: int = 100, candidates: int = 64,
                    test_candidates: int = 32, start: int = 2500, recipes=None,
                    max_hours: float = 4.0, seed: int = 0, device: str = "cpu",
                    n_atoms: int = 200, n_patches: int = 50_000, max_size: int | None = None,
                    executor=None, progress: bool = False) -> dict:
    """Run (or resume) the study (see the module docstring); write ``crossover.json`` and
    ``crossover.md`` into ``out`` after every size.

    Parameters
    ----------
    out : str or Path
    sizes : sequence of int
        Training scenes, nested subsets of one dataset of ``train_objects``.
    peers : sequence of str
        Networks of :data:`graspsim.detectors.ggcnn.model.NETWORKS`.
    train_objects, test_objects : str
        Object sets (:func:`graspsim.labels.graspability.resolve_objects`): training and validation
        scenes
        show the first, test scenes the second.
    test_trials, val_trials : int
        Trials per detector on the test scenes; per budget on the validation scenes.
    candidates, test_candidates : int
        Physics labels per training scene (dense sampler) and per test scene.
    start : int
        First budget of the plateau search (sample-steps).
    recipes : dict or None
        Network to its authors' recipe (sample-steps); default :data:`RECIPES`.
    max_hours : float
        GR-ConvNet's training time at ``k = 32`` beyond which ``k = 16`` is trained instead.
    seed : int
    device : str
    n_atoms, n_patches : int
        DLSR's dictionary size and patches (``graspsim run``'s defaults).
    max_size : int or None
        Stop after this size (a piece of a long campaign).
    executor : graspsim.runtime.executor.Executor or None
        Where trials and labelling run (default: this process).
    progress : bool

    Returns
    -------
    dict
        ``config``; ``rows``: size to detector to ``successes``, ``n``, ``ci95``,
        ``train_seconds``, ``planning_seconds`` (median), ``metric_physics``
        (:func:`metric_physics`) and, for peers, ``budget`` and ``network``; ``plateau``:
        size to network to its plateau record; ``comparisons``; ``crossover``
        (:func:`crossover`).
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    recipes = dict(RECIPES if recipes is None else recipes)
    sizes = sorted(int(s) for s in sizes)
    for p in peers:
        network_of(p)  # an unknown network is a one-line error before any work
        if p not in recipes:
            raise ValueError(f"no training recipe for {p!r}; give recipes={{{p!r}: steps}}")
    s_data, s_val, s_test, s_model = task_seeds(seed, 4)
    ex = executor or Executor("sequential", progress=progress)
    cfg = {"sizes": sizes, "peers": list(peers), "train_objects": train_objects,
           "test_objects": test_objects, "test_trials": test_trials, "val_trials": val_trials,
           "candidates": candidates, "test_candidates": test_candidates, "start": start,
           "recipes": recipes, "max_hours": max_hours, "seed": seed, "device": device,
           "n_atoms": n_atoms, "n_patches": n_patches}
    path = out / "crossover.json"
    result = read_json(path, "crossover study") if path.exists() else {}
    old = {k: v for k, v in result.get("config", {}).items() if k != "sizes"}
    if old and old != {k: v for k, v in cfg.items() if k != "sizes"}:
        raise ValueError(f"{path} was written with other settings; use another folder")
    result["config"] = cfg
    for key in ("rows", "plateau", "comparisons"):
        result.setdefault(key, {})
    labelled = TrialConfig(n_candidates=test_candidates)

    def save():
        result["crossover"] = crossover(result)
        write_text_atomic(path, json.dumps(result, indent=2, default=float))
        write_text_atomic(out / "crossover.md", crossover_markdown(result))

    def test(det, name, folder):
        return run_trials(det, objects=test_objects, n=test_trials, seed=s_test,
                          out=out / "trials" / folder, config=labelled, executor=ex,
                          progress=progress, detector_name=name, labels=out / "test-labels")

    for n in sizes:
        if max_size is not None and n > max_size:
            break
        make_dataset(n_scenes=n, objects=train_objects, out=out / "dataset", seed=s_data,
                     n_candidates=candidates, sampler="dense", executor=ex, progress=progress)
        samples = sorted(load_cornell(out / "dataset"), key=lambda s: s.image_id)[:n]
        key = str(n)
        rows = result["rows"].setdefault(key, {})
        models = {name: (det, secs, {}) for name, (det, secs) in
                  train_dlsr_models(samples, out / "models", n, s_model, n_atoms,
                                    n_patches).items()}
        dlsr_seconds = models["dlsr"][1]
        plateaus = result["plateau"].setdefault(key, {})
        for p in peers:
            variants = [(p, {})]
            if p == "grconvnet":
                variants = [("grconvnet", {"channels": 32}), ("grconvnet16", {"channels": 16})]
                capped_at = _k32_capped_at(result, n)
                if capped_at is not None:
                    # a larger training set needs no fewer steps: k = 32 would pass the cap
                    # again, so the k = 16 variant is trained directly
                    log.info("grconvnet at %d scenes: k = 32 passed %.1f h at %d scenes; "
                             "k = 16", n, max_hours, capped_at)
                    plateaus["grconvnet"] = {"skipped": f"k = 32 capped at {capped_at} "
                                                        "scenes"}
                    variants = variants[1:]
            for label, arch in variants:
                mpath = out / "models" / f"{label}_{n}"

                cls = GRConvNetDetector if p == "grconvnet" else GGCNNDetector

                def validate(model, budget, label=label, n=n, cls=cls):
                    d = cls(model, device=device)
                    t = run_trials(d, objects=train_objects, n=val_trials, seed=s_val,
                                   out=out / "validation" / f"{label}_{n}_{budget}",
                                   config=TrialConfig(n_candidates=0), executor=ex,
                                   progress=progress, detector_name=f"{label}_{n}_{budget}")
                    return t["successes"], t["n"]

                capped = label == "grconvnet"
                rec = train_to_plateau(
                    _peer_trainer(p, samples, s_model, device, dlsr_seconds, arch, progress),
                    validate, mpath, start=start, recipe=recipes[p], patience=2,
                    max_seconds=3600 * max_hours if capped else None)
                plateaus[label] = rec
                prune_snapshots(mpath)  # the chosen budget's weights stay, for the record
                if rec["stopped"] == "capped":
                    log.info("%s at %d scenes: no plateau in %.1f h at k = 32; k = 16", label,
                             n, max_hours)
                    continue
                chosen = Path(rec["model"])
                meta = read_json(model_paths(chosen)[1], "model")["training"]
                g = cls(chosen, device=device)
                info = {"network": label, "budget": meta["sample_steps"]}
                models[label] = (g, meta["seconds"], info)
                models[f"{label}+aware"] = (gripper_aware(g), meta["seconds"], info)
                epath = equal_time_model(mpath, dlsr_seconds, samples, seed=s_model,
                                         device=device, progress=progress, network=p, **arch)
                emeta = read_json(model_paths(epath)[1], "model")["training"]
                e = cls(epath, device=device)
                einfo = {"network": label, "budget": emeta["sample_steps"]}
                models[f"{label}@dlsr-time"] = (e, emeta["seconds"], einfo)
                models[f"{label}+aware@dlsr-time"] = (gripper_aware(e), emeta["seconds"], einfo)
                break  # k = 32 reached its plateau: no k = 16 at this size
            save()
        models["mask-pca"] = (load_detector("mask-pca"), 0.0, {})
        models["oracle"] = (load_detector("oracle"), 0.0, {})
        outcomes = {}
        for name, (det, train_s, info) in models.items():
            shared = name in ("mask-pca", "oracle")  # trains on nothing: its trials once
            t = test(det, name, name if shared else f"{name}_{n}")
            recs = sorted(t["records"], key=lambda r: r["index"])
            outcomes[name] = {r["index"]: bool(r["success"]) for r in recs}
            rows[name] = {"successes": t["successes"], "n": t["n"],
                          "ci95": list(wilson_interval(t["successes"], t["n"])),
                          "train_seconds": train_s,
                          "planning_seconds": (t.get("planning_seconds") or {}).get("median"),
                          "metric_physics": metric_physics(recs), **info}
            save()

        def paired(a, b, outcomes=outcomes):
            common = sorted(set(outcomes[a]) & set(outcomes[b]))
            return compare_outcomes([outcomes[a][i] for i in common],
                                    [outcomes[b][i] for i in common], names=(a, b))

        comps = {}
        peer_rows = [m for m in models if m not in ("dlsr", "dlsr-paper", "mask-pca", "oracle")]
        for m in peer_rows:
            comps[f"{m} vs dlsr"] = paired(m, "dlsr")
            comps[f"{m} vs dlsr-paper"] = paired(m, "dlsr-paper")
        for m in ("dlsr", "dlsr-paper", *peer_rows):
            comps[f"{m} vs mask-pca"] = paired(m, "mask-pca")
        result["comparisons"][key] = comps
        save()
    save()
    return result


def _pct(x) -> str:
    return "" if x is None else f"{100 * x:.1f} %"


def crossover_markdown(result: dict) -> str:
    """The study as Markdown: success and the rectangle metric per size and detector, the
    paired comparisons, the peers' budget curves and the crossover sentences."""
    lines = ["| training scenes | detector | success | 95 % (Wilson) | metric accuracy | "
             "metric right & lifted | right & dropped | wrong & lifted | wrong & dropped | "
             "training s | plan s (median) | budget |", "|---" * 12 + "|"]
    for key in sorted(result.get("rows", {}), key=int):
        for name, r in result["rows"][key].items():
            mp = r.get("metric_physics") or {}
            lo, hi = r["ci95"]
            plan = r.get("planning_seconds")
            lines.append(
                f"| {key} | {name} | {r['successes']}/{r['n']} | {100 * lo:.1f}-{100 * hi:.1f} % "
                f"| {_pct(mp.get('metric_accuracy'))} | {mp.get('right_lifted', '')} | "
                f"{mp.get('right_dropped', '')} | {mp.get('wrong_lifted', '')} | "
                f"{mp.get('wrong_dropped', '')} | {r['train_seconds']:.0f} | "
                f"{'' if plan is None else f'{plan:.2f}'} | {r.get('budget', '')} |")
    lines += ["", "| training scenes | comparison | only first | only second | exact McNemar p |",
              "|---|---|---|---|---|"]
    for key in sorted(result.get("comparisons", {}), key=int):
        for name, c in result["comparisons"][key].items():
            k = c["counts"]
            lines.append(f"| {key} | {name} | {k['only_a']} | {k['only_b']} | "
                         f"{c['mcnemar_p']:.3g} |")
    lines += ["", "Budget curves (validation successes on scenes of the train objects, "
              "training seconds, loss):", "",
              "| training scenes | network | budgets | stopped | chosen |", "|---|---|---|---|---|"]
    for key in sorted(result.get("plateau", {}), key=int):
        for net, rec in result["plateau"][key].items():
            curve = "; ".join(f"{b['budget']:,}: {b['successes']}/{b['n']}, {b['seconds']:.0f} s"
                              + (f", {b['loss']:.4g}" if b.get("loss") is not None else "")
                              for b in rec.get("budgets", []))
            stopped = rec.get("stopped", rec.get("skipped", ""))
            lines.append(f"| {key} | {net} | {curve} | {stopped} | "
                         f"{rec.get('chosen', '')} |")
    lines += [""] + [f"- {c['sentence']}." for c in result.get("crossover", {}).values()]
    return "\n".join(lines) + "\n"

"""Training a network to its plateau: the budget doubled until validation stops improving.

:func:`train_to_plateau` trains one of this package's networks (:func:`train_network`) in
budgets ``start, 2 start, 4 start, ...`` sample-steps, each resumed from the previous one's
checkpoint (the batches depend only on the seed and the batch number, so the run is the same
as one uninterrupted run), saves the model at every budget (``MODEL_stepN``) and scores it on
validation scenes with a caller's function (physical success on scenes of the *train*
objects). It stops when

* the last ``patience`` budgets (2 by default) did not improve on the best success before them
  ("stops improving for two budgets in a row"), or
* the authors' recipe (``recipe`` sample-steps; the last budget is cut to it) is reached, or
* the training wall time passes ``max_seconds`` (then the record says ``"capped"``: the
  network did not reach its plateau in the time allowed).

The chosen budget has the most validation successes; ties go to the smaller budget. The record
(``MODEL.plateau.json``) holds the budget curve: per budget, successes, trials, the training
wall time and the training loss there; a rerun resumes from it (a budget already validated is
not validated again; the caller's validation is expected to resume too).
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

from dlsr.records import read_json, write_text_atomic

from .model import model_paths, snapshot_path

log = logging.getLogger(__name__)

__all__ = ["budgets_to", "plateau_reached", "train_to_plateau", "plateau_model",
           "prune_snapshots"]


def budgets_to(start: int, recipe: int) -> list[int]:
    """The budgets ``start, 2 start, 4 start, ...`` up to ``recipe`` (the last one cut to it).

    Raises
    ------
    ValueError
        When ``start`` is not in ``1 .. recipe``.
    """
    start, recipe = int(start), int(recipe)
    if not 1 <= start <= recipe:
        raise ValueError(f"the first budget must be between 1 and the recipe's {recipe} "
                         f"sample-steps, got {start}")
    out = [start]
    while out[-1] < recipe:
        out.append(min(2 * out[-1], recipe))
    return out


def plateau_reached(successes, patience: int = 2) -> bool:
    """Whether the last ``patience`` budgets all failed to improve on the best success of the
    budgets before them.

    Parameters
    ----------
    successes : sequence of int
        Validation successes per budget, in budget order.
    patience : int
    """
    s = [int(x) for x in successes]
    if len(s) <= patience:
        return False
    return max(s[-patience:]) <= max(s[:-patience])


def _write_changed(path: Path, record: dict) -> None:
    """Write ``record`` unless the file already holds it (a resumed run leaves it as it is)."""
    text = json.dumps(record, indent=2)
    if not path.is_file() or path.read_text() != text:
        write_text_atomic(path, text)


def train_to_plateau(train_fn, validate_fn, out, start: int = 2500, recipe: int = 400_000,
                     patience: int = 2, max_seconds: float | None = None) -> dict:
    """Train to the plateau of validation success (see the module docstring); resumable.

    Parameters
    ----------
    train_fn : callable
        ``train_fn(out, steps, snapshots)`` trains (resuming from ``out``'s checkpoint) to
        ``steps`` sample-steps and saves ``out`` and, for each of ``snapshots``, ``out_stepN``
        (:func:`graspsim.detectors.ggcnn.train.train_network` with the data and options bound);
        returns
        the model's record (``training.seconds``, ``training.loss``).
    validate_fn : callable
        ``validate_fn(model_path, budget)`` returns ``(successes, trials)`` on validation
        scenes of the train objects.
    out : str or Path
        ``MODEL``; the budgets' models are ``MODEL_stepN``, the record ``MODEL.plateau.json``.
    start, recipe : int
        The first budget and the authors' recipe, in sample-steps.
    patience : int
        Budgets in a row without improvement that end the doubling.
    max_seconds : float or None
        Training wall time after which no further budget is trained.

    Returns
    -------
    dict
        ``budgets`` (each ``budget``, ``successes``, ``n``, ``seconds`` (training wall time
        to there), ``loss``), ``chosen`` (the budget), ``model`` (its path), ``stopped``
        (``"plateau"``, ``"recipe"`` or ``"capped"``) and the settings.
    """
    out = Path(out)
    rec_path = out.with_name(out.name + ".plateau.json")
    settings = {"start": int(start), "recipe": int(recipe), "patience": int(patience),
                "max_seconds": None if max_seconds is None else float(max_seconds)}
    record = read_json(rec_path, "plateau record") if rec_path.is_file() else {}
    if record and record.get("settings") != settings:
        log.info("%s: other settings than recorded; its budgets are validated again", rec_path)
        record = {}
    done = {int(b["budget"]): b for b in record.get("budgets", [])}
    curve: list[dict] = []
    stopped = "recipe"
    for budget in budgets_to(start, recipe):
        if budget in done:
            entry = done[budget]
        else:
            snap = snapshot_path(out, budget)
            if not model_paths(snap)[1].is_file():
                train_fn(out, budget, [budget])
            meta = read_json(model_paths(snap)[1], "model")["training"]
            k, n = validate_fn(snap, budget)
            entry = {"budget": budget, "successes": int(k), "n": int(n),
                     "seconds": float(meta["seconds"]), "loss": meta.get("loss")}
            log.info("%s: %d sample-steps, validation %d/%d, %.0f s of training", out.name,
                     budget, k, n, entry["seconds"])
        curve.append(entry)
        if budget not in done:  # a resumed run rewrites nothing until a new budget
            _write_changed(rec_path, {"settings": settings, "budgets": curve})
        if plateau_reached([b["successes"] for b in curve], patience):
            stopped = "plateau"
            break
        if max_seconds is not None and entry["seconds"] >= max_seconds:
            stopped = "capped" if budget < recipe else "recipe"
            break
    best = max(curve, key=lambda b: (b["successes"], -b["budget"]))
    result = {"settings": settings, "budgets": curve, "chosen": best["budget"],
              "model": str(snapshot_path(out, best["budget"])), "stopped": stopped}
    _write_changed(rec_path, result)
    return result


def plateau_model(out) -> Path:
    """The model :func:`train_to_plateau` chose for ``out`` (``MODEL_stepN``).

    Raises
    ------
    FileNotFoundError
        When ``out`` has no finished plateau record.
    """
    out = Path(out)
    rec_path = out.with_name(out.name + ".plateau.json")
    if not rec_path.is_file():
        raise FileNotFoundError(f"{rec_path}: not found (train to the plateau first)")
    record = read_json(rec_path, "plateau record")
    if "chosen" not in record:
        raise FileNotFoundError(f"{rec_path}: the training has not finished")
    return snapshot_path(out, int(record["chosen"]))


def prune_snapshots(out) -> list[Path]:
    """Delete what a finished plateau search no longer needs: the weights of the budgets not
    chosen (their ``.json`` records, with the loss and wall time, stay) and the training
    checkpoint (``MODEL.ckpt.pt`` and ``.ckpt.json``). ``MODEL`` (the last budget) and the
    chosen ``MODEL_stepN`` stay, so a rerun of :func:`train_to_plateau` finds everything done.

    Returns
    -------
    list of Path
        The files deleted.

    Raises
    ------
    FileNotFoundError
        When ``out`` has no finished plateau record (nothing is deleted).
    """
    out = Path(out)
    chosen = model_paths(plateau_model(out))[0]
    gone = [p for p in out.parent.glob(f"{out.name}_step*.pt") if p != chosen]
    gone += [p for p in (out.with_name(out.name + ".ckpt.pt"),
                         out.with_name(out.name + ".ckpt.json")) if p.is_file()]
    for p in gone:
        p.unlink()
    if gone:
        log.info("%s: removed %d files the plateau no longer needs", out.name, len(gone))
    return sorted(gone)

"""Standard against self-taught detection (the paper's Table 3): the detection benchmark
with and without extra unlabelled patches in each fold's dictionary learning.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

from dlsr.features import ENCODERS, LEARNERS
from dlsr.patches import load_patch_file
from dlsr.records import CorruptFileError, read_json, write_text_atomic

from ..stats import paired_detection_test
from .detection import detection_benchmark

__all__ = ["TABLE3_COMBINATIONS", "selftaught_benchmark", "table3_markdown"]

log = logging.getLogger(__name__)


#: The five combinations of the paper's Table 3 (learner, encoder).
TABLE3_COMBINATIONS = ("NKM-SC", "NKM-Natural", "GSVQ-ST", "OMP-Natural", "RP-Natural")


def selftaught_benchmark(data, format: str, extra_patches, out,
                         combinations=TABLE3_COMBINATIONS, progress: bool = True,
                         **detection_options) -> dict:
    """Standard against self-taught detection for learner-encoder combinations (Table 3).

    For each ``"LEARNER-ENCODER"`` of ``combinations``, :func:`detection_benchmark` runs twice
    with the same folds, seeds and options (``detection_options``): without extra patches
    (standard) and with ``extra_patches`` joined to each fold's dictionary learning
    (self-taught); the two are compared per image by an exact McNemar test
    (:func:`paired_detection_test`). Each run lives in ``out/<combination>_<standard|
    selftaught>`` and resumes there; ``out/table3.json`` and ``out/table3.md`` are rewritten
    after every combination, so an interrupted run keeps the finished rows. Rows of other
    combinations already in ``out/table3.json`` with the same configuration (data, patches,
    options) are kept, in their place, so a run of one combination adds its row to the table
    (a row of the same combination is replaced); a table of another configuration is replaced.

    Returns
    -------
    dict
        ``rows``: per combination, the two accuracies, images right, the test and the run
        folders (this run's combinations and the kept ones); ``config``: the shared options.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    for combo in combinations:
        parts = str(combo).split("-")
        if len(parts) != 2 or parts[0] not in LEARNERS or parts[1] not in ENCODERS:
            raise ValueError(f"combination must be LEARNER-ENCODER with a learner in {LEARNERS} "
                             f"and an encoder in {ENCODERS}, got {combo!r}")

    n_extra = len(load_patch_file(extra_patches)[0])  # a clear error before any work
    result = {"config": {"data": str(data), "format": format,
                         "extra_patches": str(extra_patches), "n_extra_patches": n_extra,
                         **{k: v for k, v in detection_options.items() if k != "executor"}},
              "rows": []}
    result["rows"] = _table3_rows_kept(out / "table3.json", result["config"])
    for combo in combinations:
        learner, encoder = combo.split("-")
        runs = {}
        for variant, extra in (("standard", None), ("selftaught", extra_patches)):
            folder = out / f"{combo}_{variant}"
            runs[variant] = detection_benchmark(data, format, folder, learner=learner,
                                                encoder=encoder, extra_patches=extra,
                                                progress=progress, **detection_options)
            runs[variant]["folder"] = str(folder)
        test = paired_detection_test(runs["selftaught"], runs["standard"])
        row = {
            "combination": combo,
            "standard": runs["standard"]["accuracy"],
            "selftaught": runs["selftaught"]["accuracy"],
            "n_images": test["n"], "selftaught_only": test["a_only"],
            "standard_only": test["b_only"], "p_value": test["p_value"],
            "baselines": runs["standard"]["baselines"],
            "encoder_param": runs["standard"]["config"]["encoder_param"],
            "folders": {v: runs[v]["folder"] for v in runs},
        }
        at = [i for i, r in enumerate(result["rows"]) if r["combination"] == combo]
        if at:
            result["rows"][at[0]] = row
        else:
            result["rows"].append(row)
        write_text_atomic(out / "table3.json", json.dumps(result, indent=2))
        write_text_atomic(out / "table3.md", table3_markdown(result))
    return result


def _table3_rows_kept(path, config: dict) -> list[dict]:
    """The rows of an earlier ``table3.json`` at ``path`` when its configuration is ``config``.

    A missing file, or a table of another configuration, gives no rows (the table is then
    rewritten); a corrupt file is an error naming it (:func:`dlsr.records.read_json`).
    """
    if not Path(path).is_file():
        return []
    earlier = read_json(path, "Table 3 results")
    if earlier.get("config") != json.loads(json.dumps(config)):
        return []
    rows = earlier.get("rows")
    if not isinstance(rows, list) or not all(isinstance(r, dict) and "combination" in r
                                             for r in rows):
        raise CorruptFileError(f"Table 3 results {path}: 'rows' must be a list of rows, "
                               f"each with its 'combination'")
    return rows


def table3_markdown(result: dict) -> str:
    """The rows of :func:`selftaught_benchmark` as the paper's Table 3 (plus the paired test)."""
    cfg = result["config"]
    lines = ["| combination | standard (%) | self-taught (%) | difference (points) | "
             "images won alone (self-taught vs standard) | McNemar p |",
             "|---|---|---|---|---|---|"]
    for r in result["rows"]:
        n = r["n_images"]
        lines.append(
            f"| {r['combination']} | {100 * r['standard']:.1f} ({round(r['standard'] * n)}/{n})"
            f" | {100 * r['selftaught']:.1f} ({round(r['selftaught'] * n)}/{n}) | "
            f"{100 * (r['selftaught'] - r['standard']):+.1f} | {r['selftaught_only']} vs "
            f"{r['standard_only']} | {r['p_value']:.3g} |")
    lines.append("")
    lines.append(
        f"Detection accuracy by the rectangle metric (top-1), {cfg.get('split', 'object')}-wise "
        f"cross-validation on {cfg['format']} `{Path(cfg['data']).name}`; self-taught adds "
        f"{cfg['n_extra_patches']:,} unlabelled patches (`{Path(cfg['extra_patches']).name}`) "
        f"to each fold's whitening and dictionary learning, the labelled training being the "
        f"same. Exact McNemar test on the images one variant gets right and the other not "
        f"(two-sided binomial test of the discordant pairs)."
    )
    return "\n".join(lines) + "\n"

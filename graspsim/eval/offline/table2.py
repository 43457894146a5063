"""The detection benchmark's table (``table2.md``): the paper's Table 2 beside a run's
accuracy and its baselines, or, for a saved model tested on another dataset, the cross-dataset
table."""

from __future__ import annotations

from pathlib import Path

from ...data.samples import DEFAULT_SCALE

__all__ = ["PAPER_TABLE2", "table2_markdown", "table2_rows_markdown"]

#: Table 2 of the paper (detection accuracy %, Cornell, rectangle metric): (image-wise,
#: object-wise); None where shared/reference/dlsr-reference-facts.md records no number.
PAPER_TABLE2 = (
    ("Jiang et al. (2011)", 60.5, 58.3, "prior work"),
    ("Lenz et al. (2015)", 73.9, 75.6, "prior work"),
    ("Redmon and Angelova (2015)", 88.0, 87.1, "prior work"),
    ("NKM-Natural", 89.40, None, "paper"),
    ("GSVQ-ST", None, 88.79, "paper"),
    ("NKM-SC", 88.67, 88.07, "paper"),
    ("OMP-Natural", 89.34, 88.56, "paper"),
    ("RP-Natural", 87.70, 86.61, "paper"),
)


def table2_markdown(summary: dict) -> str:
    """The paper's Table 2 layout (image-wise | object-wise) with our run and the baselines."""
    cfg = summary["config"]
    if cfg["split"] == "model":
        return _cross_markdown(summary)
    col = 1 if cfg["split"] == "image" else 2

    def cell(v):
        return "—" if v is None else f"{v:.2f}"

    lines = ["| method | image-wise (%) | object-wise (%) | source |", "|---|---|---|---|"]
    for name, img, obj, src in PAPER_TABLE2:
        lines.append(f"| {name} | {cell(img)} | {cell(obj)} | {src} (Cornell) |")
    where = f"{cfg['format']} `{Path(cfg['data']).name}`, {cfg['n_images']} images"
    ours = [(f"{cfg['learner']}-{cfg['encoder']} ({cfg['detector']} detector)",
             summary["accuracy"])]
    ours += [(f"baseline: {n}", v) for n, v in summary["baselines"].items()]
    for name, acc in ours:
        vals = [None, None]
        vals[col - 1] = 100 * acc
        lines.append(f"| {name} | {cell(vals[0])} | {cell(vals[1])} | this run ({where}) |")
    lines.append("")
    lines.append(
        f"Detection accuracy by the rectangle metric (top-1 rectangle within 30 degrees and "
        f"Jaccard > 0.25 of some positive), {cfg['n_folds']}-fold {cfg['split']}-wise cross-"
        f"validation. Paper and prior-work rows: Trottier et al. 2016, Table 2, on Cornell; "
        f"only the cells recorded in the reference facts are shown. Seconds per image: "
        f"{summary['seconds_per_image']:.2f}."
    )
    return "\n".join(lines) + "\n"


def _cross_markdown(summary: dict) -> str:
    """A saved model evaluated on another dataset, beside the baselines on the same images."""
    cfg = summary["config"]
    n = cfg["n_images"]
    scale = DEFAULT_SCALE[cfg["format"]] if cfg["scale"] is None else cfg["scale"]
    lines = ["| method | accuracy (%) | images won | won alone vs it | McNemar p |",
             "|---|---|---|---|---|"]
    k = sum(r["success"] for r in summary["per_image"])
    lines.append(f"| {cfg['learner']}-{cfg['encoder']} model `{Path(cfg['model']).name}` "
                 f"({cfg['detector']} detector) | {100 * summary['accuracy']:.2f} | {k}/{n} "
                 f"| — | — |")
    for name, t in summary["vs_baselines"].items():
        kb = sum(r["baselines"][name] for r in summary["per_image"])
        lines.append(f"| baseline: {name} | {100 * summary['baselines'][name]:.2f} | {kb}/{n} "
                     f"| {t['b_only']} vs {t['a_only']} | {t['p_value']:.3g} |")
    lines.append("")
    lines.append(
        f"Cross-dataset detection: the saved model, trained elsewhere, on every labelled image "
        f"of {cfg['format']} `{Path(cfg['data']).name}` (scale {scale:g}), top-1 rectangle "
        f"by the rectangle metric (within 30 degrees and Jaccard > 0.25 of some positive); "
        f"\"won alone\" counts the images the baseline gets right and the model not, against "
        f"the reverse (exact McNemar test). Seconds per image: "
        f"{summary['seconds_per_image']:.2f}."
    )
    return "\n".join(lines) + "\n"


def table2_rows_markdown(table: dict) -> str:
    """The paper's Table 2 beside every row of a one-pass run (``table2.json`` of
    :func:`graspsim.eval.offline.table2_pass.table2_benchmark`) and its baselines."""

    def cell(v):
        return "—" if v is None else f"{v:.2f}"

    splits = table["splits"]
    lines = ["| method | image-wise (%) | object-wise (%) | source |", "|---|---|---|---|"]
    for name, img, obj, src in PAPER_TABLE2:
        lines.append(f"| {name} | {cell(img)} | {cell(obj)} | {src} (Cornell) |")
    some = next(iter(splits.values()))
    cfg = some["config"]
    where = f"{cfg['format']} `{Path(cfg['data']).name}`, {some['n_images']} images"
    names = list(dict.fromkeys(n for s in splits.values() for n in s["rows"]))
    ours = [(f"{n} ({cfg['detector']} detector)",
             {sp: s["rows"][n]["accuracy"] for sp, s in splits.items() if n in s["rows"]})
            for n in names]
    bases = list(dict.fromkeys(b for s in splits.values() for b in s["baselines"]))
    ours += [(f"baseline: {b}", {sp: s["baselines"][b] for sp, s in splits.items()})
             for b in bases]
    for name, accs in ours:
        vals = [accs.get("image"), accs.get("object")]
        vals = [None if v is None else 100 * v for v in vals]
        lines.append(f"| {name} | {cell(vals[0])} | {cell(vals[1])} | this run ({where}) |")
    lines.append("")
    lines.append(
        f"Detection accuracy by the rectangle metric (top-1 rectangle within 30 degrees and "
        f"Jaccard > 0.25 of some positive), {cfg['n_folds']}-fold cross-validation per split, "
        f"every row in one pass (the training rectangles, the NKM dictionary and each test "
        f"image's candidates shared). Paper and prior-work rows: Trottier et al. 2016, Table 2, "
        f"on Cornell; only the cells recorded in the reference facts are shown. Each row's "
        f"folder holds its own `detection.json` (per-image outcomes, paired tests against the "
        f"baselines).")
    return "\n".join(lines) + "\n"

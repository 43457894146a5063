"""The run report: ``report.md`` and a self-contained ``report.html`` from the same blocks.

Pictures are files beside the report (linked from the Markdown) and embedded as base64 data URIs
in the HTML, so the HTML page can be mailed or archived alone.
"""

from __future__ import annotations

import base64
import html
import json
import logging
from dataclasses import asdict
from pathlib import Path

from dlsr.mosaic import plot_dictionary_mosaic
from dlsr.records import read_jsonl
from dlsr.rectangles import GraspRectangle

from ..eval.compare import compare_pair
from ..eval.trialviz import save_gif, trial_frames
from ..runtime.campaign import is_skipped
from ..sim.bullet import Simulation
from ..sim.object_sets import parse_object_set
from ..sim.observe import observe_scene
from .figures import (
    plot_paired_differences,
    plot_success_per_object,
    plot_success_rates,
    plot_verdicts,
)
from .plan import departs_from_paper, trial_names

log = logging.getLogger(__name__)

__all__ = [
    "write_report",
    "render_markdown",
    "render_html",
]

# The paper's headline numbers (Trottier et al. 2016; shared/reference/dlsr-reference-facts.md).
PAPER = {
    "recognition": ("NKM-SC", 96.86),
    "detection_image": ("NKM-Natural", 89.40),
    "detection_object": ("GSVQ-ST", 88.79),
}


def _pct(x, digits=1):
    return "n/a" if x is None else f"{100 * x:.{digits}f} %"


def _seconds(x) -> str:
    """Seconds with three decimals, ``n/a`` when not recorded."""
    return "n/a" if x is None else f"{x:.3f}"


def _ci(c):
    return "" if not c else f"[{100 * c[0]:.1f}, {100 * c[1]:.1f}]"


def render_markdown(blocks) -> str:
    out = []
    for kind, *rest in blocks:
        if kind == "h1":
            out.append(f"# {rest[0]}\n")
        elif kind == "h2":
            out.append(f"## {rest[0]}\n")
        elif kind == "p":
            out.append(f"{rest[0]}\n")
        elif kind == "table":
            header, rows = rest
            out.append("| " + " | ".join(header) + " |")
            out.append("|" + "---|" * len(header))
            out += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
            out.append("")
        elif kind == "img":
            path, alt = rest
            out.append(f"![{alt}]({path})\n")
        elif kind == "md":
            out.append(rest[0])
    return "\n".join(out)


def _md_table_to_html(md: str) -> str:
    rows = [ln.strip().strip("|").split("|") for ln in md.splitlines()
            if ln.strip().startswith("|")]
    rows = [r for r in rows if not all(set(c.strip()) <= set("-:") for c in r)]
    if not rows:
        return f"<pre>{html.escape(md)}</pre>"
    head = "".join(f"<th>{html.escape(c.strip())}</th>" for c in rows[0])
    body = "".join("<tr>" + "".join(f"<td>{html.escape(c.strip())}</td>" for c in r) + "</tr>"
                   for r in rows[1:])
    rest = "".join(f"<p>{html.escape(ln)}</p>" for ln in md.splitlines()
                   if ln.strip() and not ln.strip().startswith("|"))
    return f"<table><tr>{head}</tr>{body}</table>{rest}"


def render_html(blocks, base: Path, title: str) -> str:
    parts = []
    for kind, *rest in blocks:
        if kind == "h1":
            parts.append(f"<h1>{html.escape(rest[0])}</h1>")
        elif kind == "h2":
            parts.append(f"<h2>{html.escape(rest[0])}</h2>")
        elif kind == "p":
            parts.append(f"<p>{html.escape(rest[0])}</p>")
        elif kind == "table":
            header, rows = rest
            head = "".join(f"<th>{html.escape(str(c))}</th>" for c in header)
            body = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in r)
                           + "</tr>" for r in rows)
            parts.append(f"<table><tr>{head}</tr>{body}</table>")
        elif kind == "img":
            path, alt = rest
            f = base / path
            if not f.exists():
                parts.append(f"<p>(missing picture {html.escape(path)})</p>")
                continue
            mime = {"png": "image/png", "gif": "image/gif"}.get(f.suffix[1:].lower(), "image/png")
            data = base64.b64encode(f.read_bytes()).decode()
            parts.append(f'<figure><img alt="{html.escape(alt)}" src="data:{mime};base64,{data}">'
                         f"<figcaption>{html.escape(alt)}</figcaption></figure>")
        elif kind == "md":
            parts.append(_md_table_to_html(rest[0]))
    style = ("body{font-family:sans-serif;max-width:1100px;margin:2em auto;color:#222}"
             "table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #bbb;"
             "padding:4px 8px;text-align:left}th{background:#eee}img{max-width:100%}"
             "figcaption{color:#555;font-size:90%}")
    return (f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'><title>"
            f"{html.escape(title)}</title><style>{style}</style></head><body>"
            + "\n".join(parts) + "</body></html>\n")


def _trial_records(root: Path, name: str) -> list[dict]:
    return sorted((r for r in read_jsonl(root / "trials" / name / "trials.jsonl")
                   if not is_skipped(r)), key=lambda r: r["index"])


def _mosaic(root: Path, pics: Path) -> str | None:
    npz = sorted((root / "model").glob("*.npz"))
    if not npz:
        return None
    with __import__("numpy").load(npz[0]) as z:
        key = next((k for k in z.files if k.endswith("dictionary")), None)
        if key is None:
            return None
        D = z[key]
    out = pics / "dictionary.png"
    plot_dictionary_mosaic(D, title="learned dictionary (whitened patches)", path=out)
    return str(out.relative_to(root))


def _trial_gifs(root: Path, records: list[dict], config, pics: Path) -> list[tuple[str, str]]:
    """Replay the first successful and the first failed DLSR trial as GIFs."""
    chosen = []
    for want in (True, False):
        r = next((r for r in records if bool(r["success"]) == want and r.get("rectangle")), None)
        if r is not None:
            chosen.append((want, r))
    if not chosen:
        return []
    specs = config.object_set("trial_objects").specs()
    sim = Simulation()
    out = []
    try:
        for ok, r in chosen:
            scene, _, frame, _ = observe_scene(sim, specs, r["seed"], r["index"])
            frames, _ = trial_frames(sim, scene, frame, GraspRectangle(*r["rectangle"]))
            path = pics / f"trial_{'success' if ok else 'failure'}.gif"
            save_gif(frames, path)
            label = "successful" if ok else f"failed ({r['reason']})"
            out.append((str(path.relative_to(root)),
                        f"a {label} DLSR trial on {'+'.join(r['object'])}"))
    finally:
        sim.close()
    return out


def _scene_phrase(config) -> str:
    """How the report names a run's ``scene`` and ``gripper`` when they are not the defaults."""
    parts = []
    if config.scene != "drop":
        parts.append(f"{config.scene} scenes of {config.objects_per_scene} objects")
    if config.gripper != "builtin":
        parts.append(f"the {config.gripper} hand")
    return (", ".join(parts).capitalize() + ". ") if parts else ""


def _objects_phrase(objects: str) -> str:
    """How the report names a run's ``train_objects`` or ``trial_objects`` setting."""
    if objects in ("train", "test", "all"):
        return {"train": "the built-in train objects", "test": "the held-out test objects",
                "all": "all built-in objects"}[objects]

    oset = parse_object_set(objects)
    names = [s.name for s in oset.specs()]
    if oset.source != "builtin":
        return f"the object set `{objects}` ({len(names)} objects)"
    return f"{len(names)} built-in object{'s' if len(names) > 1 else ''} ({', '.join(names)})"


def _picture(blocks: list, fn, args, path: Path, root: Path, alt: str) -> None:
    """Draw one picture into the report; a failed picture is logged, never loses the report."""
    try:
        fn(*args, path)
    except Exception as exc:
        log.warning("%s failed: %s", path.name, exc)
        return
    blocks.append(("img", str(path.relative_to(root)), alt))


def _paired_section(root: Path, names: list[str], stages: dict, pics: Path) -> list[tuple]:
    """DLSR against each baseline on the same trial scenes (see :mod:`graspsim.eval.compare`)."""
    if not stages.get("trials/dlsr"):
        return []
    comparisons, errors = [], []
    for name in names[1:]:
        if not stages.get(f"trials/{name}"):
            continue
        try:
            comparisons.append(compare_pair(root / "trials" / "dlsr", root / "trials" / name,
                                            names=("dlsr", name)))
        except (ValueError, FileNotFoundError) as exc:
            errors.append(f"dlsr against {name}: not compared ({exc}).")
    if not comparisons and not errors:
        return []
    blocks: list[tuple] = [("h2", "DLSR against each baseline, scene by scene")]
    blocks.append(("p", "Trial i of every detector ran on the same scene, so the outcomes pair "
                        "up: the table counts the trials both detectors won, those only one "
                        "won, and those both lost. The difference in success rate has "
                        "Newcombe's 95 % interval for paired proportions (method 10, 1998); "
                        "p is the exact McNemar test (two-sided binomial test of the trials "
                        "only one detector won). The verdict is the test's at the 5 % level."))
    rows = []
    graspable = any("graspable" in c for c in comparisons)
    for c in comparisons:
        k = c["counts"]
        lo, hi = c["difference_ci"]
        verdict = {"a": "DLSR better", "b": f"{c['b']['name']} better"}.get(
            c["better"], "not separated")
        row = [c["b"]["name"], c["n"], k["both"], k["only_a"], k["only_b"], k["neither"],
               f"{100 * c['difference']:+.1f} [{100 * lo:+.1f}, {100 * hi:+.1f}]"]
        if graspable:
            g = c.get("graspable")
            row.append("" if g is None else
                       f"{g['n']}: {100 * g['difference']:+.1f} [{100 * g['difference_ci'][0]:+.1f}"
                       f", {100 * g['difference_ci'][1]:+.1f}], p = {g['mcnemar_p']:.2g}")
        rows.append([*row, f"{c['mcnemar_p']:.2g}", verdict])
    if rows:
        head = ["baseline", "paired trials", "both succeeded", "only DLSR", "only baseline",
                "neither", "DLSR - baseline, points [95 % CI]"]
        if graspable:
            head.append("on graspable objects: trials, points [95 % CI], p")
        blocks.append(("table", [*head, "exact McNemar p", "verdict (5 %)"], rows))
    blocks += [("p", c["verdict"]) for c in comparisons]
    blocks += [("p", e) for e in errors]
    if comparisons:
        (root / "comparisons.json").write_text(
            json.dumps({"alpha": comparisons[0]["alpha"], "comparisons": comparisons},
                       indent=2) + "\n")
        _picture(blocks, plot_paired_differences, (comparisons,), pics / "paired_differences.png",
                 root, "DLSR minus each baseline: paired difference in success with its 95 % "
                       "interval (green: DLSR better, red: baseline better, gray: not separated)")
    return blocks


def write_report(root, config, stages: dict, wall: float | None = None) -> Path:
    """Write ``report.md`` and ``report.html`` in ``root`` from the stage results on disk."""
    root = Path(root)
    pics = root / "pictures"
    pics.mkdir(exist_ok=True)
    cfg = asdict(config)
    run = json.loads((root / "run.json").read_text()) if (root / "run.json").exists() else {}
    combo = f"{config.learner}-{config.encoder}"
    blocks: list[tuple] = [("h1", f"graspsim run: {config.name}")]
    blocks.append(("p", f"DLSR {combo} (d = {config.n_atoms}) trained on {config.scenes} "
                        f"synthetic Cornell images of {_objects_phrase(config.train_objects)}; "
                        f"simulated grasp trials on {_objects_phrase(config.trial_objects)}. "
                        + _scene_phrase(config) + f"Seed {config.seed}."
                   + (f" Wall time {wall / 60:.1f} min." if wall else "")))
    training = ("the paper's training (labelled rectangles only)" if not config.grid_negatives
                else f"{config.grid_negatives:g} negative(s) per labelled rectangle from its "
                     f"own search grid")
    if config.physical:
        training += (", with the rectangles' physical features in the SVM (not in the paper: "
                     "opening in metres, heights of the centre and the finger footprints "
                     "above the table, place on the object's axes)")
    lattice = config.detector == "lattice"
    search = ("rectangles fitted to the object region (not in the paper: the region "
              "completed with the missing depth inside its convex hull, lattice points "
              "every 15 degrees, openings from the region's chords)" if lattice
              else "the paper's grid search")
    if config.gripper_aware:
        search += (", gripper-aware (not in the paper): openings the gripper reaches"
                   + ("" if lattice else " and jaws beside the object")
                   + ", and of its best 40 the first whose fingers land on no surface seen in "
                     "the depth image nor on the object's unseen surface")
    if departs_from_paper(config):
        search += ("; `dlsr-paper` is the paper's configuration on the same images (the "
                   "paper's training and grid search)")
    blocks.append(("p", f"DLSR: {training}; {search}. Labels: {config.label_sampler} "
                        f"candidates, {config.candidates} per image."))

    rec = stages.get("recognition")
    det = stages.get("detection") or {}
    blocks.append(("h2", "Offline benchmarks (object-wise cross-validation)"))
    rows = []
    if rec:
        rows.append(["recognition (per rectangle)", combo,
                     f"{100 * rec['accuracy']:.2f} ± {100 * rec['std']:.2f} %",
                     f"{PAPER['recognition'][1]:.2f} % ({PAPER['recognition'][0]}, Cornell)"])
    if det.get("accuracy") is not None:
        rows.append(["detection (rectangle metric)", combo, _pct(det["accuracy"], 2),
                     f"{PAPER['detection_object'][1]:.2f} % ({PAPER['detection_object'][0]}, "
                     f"Cornell object-wise)"])
    for name, acc in (det.get("baselines") or {}).items():
        rows.append(["detection (rectangle metric)", name, _pct(acc, 2), ""])
    if rows:
        blocks.append(("table", ["task", "method", "this run", "paper"], rows))
    elif not config.offline:
        blocks.append(("p", "Not run (`offline = false`): dataset, models and trials only."))
    for name in ("table1.md",):
        f = root / "recognition" / name
        if f.exists():
            blocks.append(("p", "Recognition table (layout of the paper's Table 1):"))
            blocks.append(("md", f.read_text()))
    for f in sorted((root / "detection").glob("table2*.md")):
        blocks.append(("p", "Detection table (layout of the paper's Table 2):"))
        blocks.append(("md", f.read_text()))

    blocks.append(("h2", "Physical grasp success on the "
                         + ("test objects" if config.trial_objects == "test" else "trial objects")))
    names = trial_names(config)
    rows, tables = [], []
    for name in names:
        s = stages.get(f"trials/{name}")
        if not s:
            continue
        plan = s.get("planning_seconds") or {}
        rows.append([name, f"{s['successes']}/{s['n']}", _pct(s["success_rate"]),
                     _ci(s["success_ci95"]), _pct(s.get("graspable_success_rate")),
                     _pct(s.get("metric_accuracy")), _pct(s.get("agreement")),
                     _seconds(plan.get("median")), _seconds(plan.get("p95"))])
        t = s["verdict_vs_outcome"]
        tables.append([name, t["metric_true"]["success"], t["metric_true"]["failure"],
                       t["metric_false"]["success"], t["metric_false"]["failure"]])
    blocks.append(("table", ["detector", "successes", "success rate", "95 % CI (Wilson)",
                             "on graspable objects", "rectangle metric says correct",
                             "metric agrees with physics", "plan time median (s)",
                             "plan time p95 (s)"], rows))
    summaries = {n: stages[f"trials/{n}"] for n in names if stages.get(f"trials/{n}")}
    if summaries:
        _picture(blocks, plot_success_rates, (summaries,), pics / "success_rates.png", root,
                 "physical success per detector with Wilson 95 % intervals, on all test "
                 "objects and on the graspable ones")
    blocks.append(("p", "Rectangle-metric verdict against physical outcome, per detector "
                        "(how often the benchmark metric is wrong about a real grasp): the "
                        "metric-correct grasps that failed and the metric-wrong grasps that "
                        "succeeded are its errors."))
    blocks.append(("table", ["detector", "metric correct & succeeded", "metric correct & failed",
                             "metric wrong & succeeded", "metric wrong & failed"], tables))
    if any(s.get("metric_n") for s in summaries.values()):
        _picture(blocks, plot_verdicts, (summaries,), pics / "verdict_vs_outcome.png", root,
                 "rectangle-metric verdict against physical outcome per detector (the "
                 "diagonal is where the metric is right)")
    blocks += _paired_section(root, names, stages, pics)

    per_obj: dict[str, dict[str, str]] = {}
    for name in names:
        s = stages.get(f"trials/{name}")
        for obj, v in (s or {}).get("per_object", {}).items():
            per_obj.setdefault(obj, {})[name] = f"{v['successes']}/{v['n']}"
    if per_obj:
        blocks.append(("h2", "Success per object"))
        blocks.append(("table", ["object", *names],
                       [[o, *[per_obj[o].get(n, "") for n in names]] for o in sorted(per_obj)]))
        _picture(blocks, plot_success_per_object, (summaries,), pics / "success_per_object.png",
                 root, "physical success per test object and detector")

    blocks.append(("h2", "Pictures"))
    try:
        m = _mosaic(root, pics)
        if m:
            blocks.append(("img", m, f"the {config.learner} dictionary: atoms as K, RGB, D and "
                                     "normal panels"))
    except Exception as exc:  # a picture must not lose the report
        log.warning("dictionary mosaic failed: %s", exc)
    for f in sorted((root / "detection").glob("**/*.png"))[:4]:
        blocks.append(("img", str(f.relative_to(root)), f"detection overlay {f.stem}"))
    try:
        for path, alt in _trial_gifs(root, _trial_records(root, "dlsr"), config, pics):
            blocks.append(("img", path, alt))
    except Exception as exc:
        log.warning("trial GIFs failed: %s", exc)

    blocks.append(("h2", "Configuration and versions"))
    blocks.append(("table", ["setting", "value"], [[k, json.dumps(v)] for k, v in cfg.items()]))
    blocks.append(("table", ["package", "version"],
                   [[k, v] for k, v in run.get("versions", {}).items()]))
    timing = [[k, f"{v.get('seconds', 0):.1f}"] for k, v in stages.items()
              if isinstance(v, dict) and "seconds" in v]
    blocks.append(("table", ["stage", "seconds"], timing))

    md = root / "report.md"
    md.write_text(render_markdown(blocks))
    (root / "report.html").write_text(render_html(blocks, root, f"graspsim run {config.name}"))
    return md

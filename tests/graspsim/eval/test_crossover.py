"""graspsim.eval.crossover: the curve carried to the crossover (peers trained to their plateau,
every detector on the same labelled test scenes, the metric against physics)."""

from __future__ import annotations

import json

import pytest

from graspsim.eval.crossover import crossover, crossover_markdown, metric_physics

pytestmark = pytest.mark.sim


def test_metric_physics_counts_the_four_cells():
    recs = [{"metric": True, "success": True}, {"metric": True, "success": False},
            {"metric": False, "success": True}, {"metric": False, "success": False},
            {"metric": False, "success": False}, {"metric": None, "success": True}]
    t = metric_physics(recs)
    assert (t["right_lifted"], t["right_dropped"], t["wrong_lifted"], t["wrong_dropped"]) == \
        (1, 1, 1, 2)
    assert t["n"] == 5 and t["metric_accuracy"] == 0.4 and t["success_rate"] == 0.4
    assert t["lifted_given_right"] == 0.5
    assert metric_physics([])["metric_accuracy"] is None


def _result(ps, only):
    def row(k):
        return {"successes": k, "n": 200}

    return {"rows": {str(n): {"dlsr": row(100), "ggcnn+aware": row(90)}
                     for n in (10, 30, 100)},
            "comparisons": {str(n): {"ggcnn+aware vs dlsr": {
                "mcnemar_p": p, "counts": {"only_a": a, "only_b": b}}}
                for n, p, (a, b) in zip((10, 30, 100), ps, only, strict=True)}}


def test_crossover_is_the_first_size_ahead_and_separated():
    c = crossover(_result((0.01, 0.03, 0.001), ((2, 20), (30, 10), (40, 5))))
    assert c["ggcnn+aware"]["size"] == 30 and "from 30 training scenes" in \
        c["ggcnn+aware"]["sentence"]
    c = crossover(_result((0.01, 0.2, 0.001), ((2, 20), (30, 20), (5, 40))))
    assert c["ggcnn+aware"]["size"] is None
    assert "not ahead" in c["ggcnn+aware"]["sentence"] and "100" in c["ggcnn+aware"]["sentence"]


def test_study_trains_to_plateaus_labels_test_scenes_once_and_resumes(tmp_path):
    pytest.importorskip("torch")
    from graspsim.eval.crossover import crossover_study

    out = tmp_path / "x"
    kw = dict(sizes=[2, 3], train_objects="train", test_objects="test", test_trials=1,
              val_trials=1, candidates=16, test_candidates=8, start=8,
              recipes={"ggcnn": 16, "grconvnet": 16}, max_hours=0.0, n_atoms=16,
              n_patches=10_000, max_size=2)
    res = crossover_study(out, **kw)
    assert list(res["rows"]) == ["2"]  # stopped after the first size
    rows = res["rows"]["2"]
    # GR-ConvNet k = 32 passed the time cap at its first budget: k = 16, named so
    assert res["plateau"]["2"]["grconvnet"]["stopped"] == "capped"
    assert res["plateau"]["2"]["grconvnet16"]["stopped"] in ("plateau", "recipe")
    expected = {"dlsr", "dlsr-paper", "mask-pca", "oracle"} | {
        f"{p}{s}" for p in ("ggcnn", "grconvnet16")
        for s in ("", "+aware", "@dlsr-time", "+aware@dlsr-time")}
    assert set(rows) == expected
    positives = None
    for name, r in rows.items():
        folder = out / "trials" / (name if name in ("mask-pca", "oracle") else f"{name}_2")
        recs = [json.loads(x) for x in (folder / "trials.jsonl").read_text().splitlines()]
        mp = r["metric_physics"]
        assert mp == metric_physics(recs) and r["successes"] == sum(x["success"] for x in recs)
        # every detector sees the same labelled scenes
        here = [x["n_positives"] for x in sorted(recs, key=lambda x: x["index"])]
        assert positives is None or here == positives
        positives = here
    assert rows["ggcnn"]["budget"] == res["plateau"]["2"]["ggcnn"]["chosen"]
    assert "ggcnn+aware vs dlsr" in res["comparisons"]["2"]
    assert (out / "crossover.md").read_text() == crossover_markdown(res)
    # a rerun trains and tries nothing again
    kept = {p: p.stat().st_mtime_ns for p in out.glob("trials/*/trials.jsonl")}
    kept |= {p: p.stat().st_mtime_ns for p in (out / "models").iterdir()}
    again = crossover_study(out, **kw)
    assert again["rows"] == res["rows"]
    assert not [p for p, t in kept.items() if p.stat().st_mtime_ns != t]
    # only the chosen budgets' weights are kept
    for label in ("ggcnn", "grconvnet", "grconvnet16"):
        chosen = res["plateau"]["2"][label]["chosen"]
        assert sorted(p.name for p in (out / "models").glob(f"{label}_2_step*.pt")) == [
            f"{label}_2_step{chosen}.pt"]
        assert not (out / "models" / f"{label}_2.ckpt.pt").exists()
    # k = 32 passed the cap at 2 scenes: at 3 scenes k = 16 is trained directly
    more = crossover_study(out, **{**kw, "max_size": 3})
    assert more["plateau"]["3"]["grconvnet"] == {"skipped": "k = 32 capped at 2 scenes"}
    assert "grconvnet16" in more["plateau"]["3"] and "grconvnet16+aware" in more["rows"]["3"]
    assert not list((out / "models").glob("grconvnet_3*"))
    assert "k = 32 capped at 2 scenes" in (out / "crossover.md").read_text()
    with pytest.raises(ValueError, match="other settings"):
        crossover_study(out, **{**kw, "val_trials": 3})

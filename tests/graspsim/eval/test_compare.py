"""Paired comparisons: exact McNemar, Newcombe's interval, folder pairing and refusals, CLI."""

from __future__ import annotations

import json
from math import comb, sqrt

import numpy as np
import pytest

from graspsim.cli import main
from graspsim.eval.compare import (
    compare_folders,
    compare_outcomes,
    compare_pair,
    comparison_text,
    load_folder,
)
from graspsim.eval.stats import (
    mcnemar_exact,
    paired_counts,
    paired_difference_ci,
    wilson_interval,
)


def _binomial_mcnemar(b, c):
    """Two-sided exact McNemar p from the binomial formula: twice the smaller tail."""
    m = b + c
    tail = sum(comb(m, k) for k in range(min(b, c) + 1)) / 2**m
    return min(1.0, 2 * tail)


@pytest.mark.parametrize("b,c", [(1, 7), (6, 16), (0, 5), (10, 2), (3, 3), (25, 40)])
def test_mcnemar_exact_is_the_binomial_test_of_discordant_pairs(b, c):
    expected = _binomial_mcnemar(b, c)
    assert mcnemar_exact(b, c) == pytest.approx(expected, rel=1e-9)
    assert mcnemar_exact(c, b) == pytest.approx(expected, rel=1e-9)


def test_mcnemar_textbook_values_and_edges():
    # 1 against 7 discordant pairs: 2 * (1 + 8) / 2**8
    assert mcnemar_exact(1, 7) == pytest.approx(18 / 256)
    assert mcnemar_exact(0, 0) == 1.0
    assert mcnemar_exact(4, 4) == 1.0
    with pytest.raises(ValueError, match="only_a"):
        mcnemar_exact(-1, 3)
    with pytest.raises(ValueError, match="only_b"):
        mcnemar_exact(1, 2.5)


def test_difference_interval_contains_the_estimate_and_shrinks_with_n():
    table = np.array([20, 10, 4, 66])
    widths = []
    for scale in (1, 4, 16):
        both, only_a, only_b, neither = (int(v) for v in table * scale)
        lo, hi = paired_difference_ci(both, only_a, only_b, neither)
        d = (only_a - only_b) / (both + only_a + only_b + neither)
        assert lo < d < hi
        assert -1 <= lo and hi <= 1
        widths.append(hi - lo)
        # A and B swapped: the interval of -d
        lo2, hi2 = paired_difference_ci(both, only_b, only_a, neither)
        assert (lo2, hi2) == pytest.approx((-hi, -lo))
    assert widths[0] > widths[1] > widths[2]
    # a 99 % interval is wider than the 95 % one
    lo99, hi99 = paired_difference_ci(20, 10, 4, 66, alpha=0.01)
    lo95, hi95 = paired_difference_ci(20, 10, 4, 66)
    assert lo99 < lo95 and hi99 > hi95


def test_difference_interval_without_correlation_is_square_and_add_of_wilson():
    # both * neither - only_a * only_b = 12 - 7 lies in [0, n / 2]: Newcombe sets phi to 0
    both, only_a, only_b, neither = 1, 1, 7, 12
    n = 21
    pa, pb = 2 / n, 8 / n
    la, ua = wilson_interval(2, n)
    lb, ub = wilson_interval(8, n)
    lo, hi = paired_difference_ci(both, only_a, only_b, neither)
    assert lo == pytest.approx(pa - pb - sqrt((pa - la) ** 2 + (ub - pb) ** 2))
    assert hi == pytest.approx(pa - pb + sqrt((pb - lb) ** 2 + (ua - pa) ** 2))


def test_positive_correlation_narrows_the_interval():
    # strongly concordant detectors: pairing makes the difference more precise than the
    # square-and-add of two independent Wilson intervals
    both, only_a, only_b, neither = 40, 5, 2, 53
    n = 100
    la, ua = wilson_interval(45, n)
    lb, ub = wilson_interval(42, n)
    unpaired = sqrt((0.45 - la) ** 2 + (ub - 0.42) ** 2) + sqrt((0.42 - lb) ** 2
                                                               + (ua - 0.45) ** 2)
    lo, hi = paired_difference_ci(both, only_a, only_b, neither)
    assert hi - lo < unpaired


def test_no_discordant_pair_still_has_an_interval():
    lo, hi = paired_difference_ci(3, 0, 0, 7)
    assert lo < 0 < hi
    assert np.isnan(paired_difference_ci(0, 0, 0, 0)).all()
    with pytest.raises(ValueError, match="alpha"):
        paired_difference_ci(1, 2, 3, 4, alpha=1.5)


def test_paired_counts_and_bad_outcomes():
    a = [True, True, False, False, True]
    b = [True, False, True, False, False]
    assert paired_counts(a, b) == {"both": 1, "only_a": 2, "only_b": 1, "neither": 1}
    assert paired_counts(np.array(a, int), np.array(b, int))["only_a"] == 2
    with pytest.raises(ValueError, match="same length"):
        paired_counts(a, b[:3])
    with pytest.raises(ValueError, match="0/1"):
        paired_counts([0, 2], [1, 1])


def test_verdict_names_the_better_detector_or_says_not_separated():
    a = [True] * 30 + [False] * 10 + [True] * 20
    b = [False] * 30 + [False] * 10 + [True] * 20
    c = compare_outcomes(a, b, names=("dlsr", "mask-pca"))
    assert c["better"] == "a" and c["mcnemar_p"] < 0.05
    assert c["verdict"].startswith("dlsr is better than mask-pca at the 5 % level")
    c = compare_outcomes(b, a, names=("mask-pca", "dlsr"))
    assert c["better"] == "b" and c["verdict"].startswith("dlsr is better than mask-pca")
    c = compare_outcomes([True, False, True, False], [False, True, True, False],
                         names=("x", "y"))
    assert c["better"] is None and "not separated" in c["verdict"]
    assert c["difference"] == 0.0 and c["n"] == 4


# --- folders ---------------------------------------------------------------------------------

OBJECTS = ["mug", "bowl", "box", "can"]


def _trials(path, detector, success, seed=0, objects="test", n_objects=1, names=None,
            indices=None, graspable=None, execution=None):
    path.mkdir(parents=True)
    cfg = {"detector": detector, "objects": objects, "seed": seed,
           "config": {"n_candidates": 8, "n_objects": n_objects, "label_with_clean_depth": False}}
    if execution is not None:
        cfg["execution"] = execution
    (path / "config.json").write_text(json.dumps(cfg))
    indices = range(len(success)) if indices is None else indices
    with open(path / "trials.jsonl", "w") as fh:
        for i, s in zip(indices, success, strict=True):
            obj = (names or {}).get(i, OBJECTS[i % len(OBJECTS)])
            rec = {"index": i, "seed": seed, "object": [obj], "success": bool(s),
                   "reason": None if s else "slipped", "rectangle": None}
            if graspable is not None:
                rec["graspable"] = bool(graspable[i])
            fh.write(json.dumps(rec) + "\n")
    return path


def _scores(path, success, fingerprint="abc123", name=None):
    path.mkdir(parents=True)
    cfg = {"dataset": "data/x", "dataset_fingerprint": fingerprint, "top_k": 1,
           "predictions": f"{path.name}.csv", "format": "csv"}
    if name:
        cfg["detector"] = name
    (path / "config.json").write_text(json.dumps(cfg))
    (path / "scores.jsonl").write_text("".join(
        json.dumps({"image": f"{i:04d}", "success": bool(s), "reason": None}) + "\n"
        for i, s in enumerate(success)))
    return path


def test_trial_folders_pair_by_index(tmp_path):
    a = _trials(tmp_path / "a", "dlsr", [1, 1, 0, 0, 1, 0])
    b = _trials(tmp_path / "b", "mask-pca", [1, 0, 1, 0, 0, 0])
    c = compare_pair(a, b)
    assert c["counts"] == {"both": 1, "only_a": 2, "only_b": 1, "neither": 2}
    assert (c["a"]["name"], c["b"]["name"], c["n"]) == ("dlsr", "mask-pca", 6)
    assert c["unpaired"] == {"a": 0, "b": 0} and c["unit"] == "trials"
    lo, hi = c["difference_ci"]
    assert c["difference"] == pytest.approx(1 / 6)
    assert lo < c["difference"] < hi
    json.dumps(c)  # plain JSON


def test_graspable_scenes_are_compared_on_their_own(tmp_path, capsys):
    flags = [1, 1, 1, 1, 0, 0, 1, 0]
    a = _trials(tmp_path / "a", "dlsr", [1, 1, 1, 0, 0, 0, 1, 0], graspable=flags)
    b = _trials(tmp_path / "b", "mask-pca", [1, 0, 0, 0, 0, 1, 0, 0], graspable=flags)
    c = compare_pair(a, b)
    g = c["graspable"]
    assert g["n"] == 5 and (g["success_a"], g["success_b"]) == (4, 1)
    assert g["counts"] == {"both": 1, "only_a": 3, "only_b": 0, "neither": 1}
    assert g["difference"] == pytest.approx(3 / 5) and c["difference"] == pytest.approx(2 / 8)
    assert g["mcnemar_p"] == pytest.approx(_binomial_mcnemar(3, 0))
    assert main(["compare", str(a), str(b)]) == 0
    assert "on graspable objects (5 paired trials): dlsr 4/5 = 80.0 %" in capsys.readouterr().out
    # Nothing to add when every scene, or none, is marked graspable.
    for name, marks in (("all", [1] * 8), ("none", None)):
        x = _trials(tmp_path / f"{name}a", "dlsr", [1] * 8, graspable=marks)
        y = _trials(tmp_path / f"{name}b", "mask-pca", [0] * 8, graspable=marks)
        assert "graspable" not in compare_pair(x, y)


def test_different_execution_parameters_pair_and_are_named(tmp_path, capsys, caplog):
    a = _trials(tmp_path / "settle", "dlsr", [1, 1, 0, 1], execution={"min_grip": 0.01})
    b = _trials(tmp_path / "plain", "dlsr", [1, 0, 0, 1])
    c = compare_pair(a, b)
    assert c["n"] == 4 and c["execution"] == {"a": {"min_grip": 0.01}, "b": {}}
    assert "mixes detector and harness" in caplog.text
    assert main(["compare", str(a), str(b)]) == 0
    assert "execution parameters differ" in capsys.readouterr().out
    same = _trials(tmp_path / "same", "mask-pca", [0, 0, 0, 0], execution={"min_grip": None})
    assert "execution" not in compare_pair(b, same)
    bad = _trials(tmp_path / "bad", "dlsr", [1, 1, 1, 1], execution={"min_grip": -1})
    with pytest.raises(ValueError, match="bad/config.json"):
        compare_pair(a, bad)


def test_incomplete_folders_pair_on_shared_trials(tmp_path):
    a = _trials(tmp_path / "a", "dlsr", [1, 1, 0, 0, 1, 0, 1, 1])
    b = _trials(tmp_path / "b", "oracle", [1, 0, 1, 0, 1], indices=[0, 1, 2, 3, 9])
    c = compare_pair(a, b)
    assert c["n"] == 4 and c["unpaired"] == {"a": 4, "b": 1}
    assert c["counts"] == {"both": 1, "only_a": 1, "only_b": 1, "neither": 1}


@pytest.mark.parametrize("change,what", [
    ({"seed": 1}, "seed 0 vs 1"),
    ({"objects": "train"}, 'objects "test" vs "train"'),
    ({"n_objects": 3}, "n_objects 1 vs 3"),
    ({"names": {2: "plate"}}, "trial 2 has objects ['box'] vs ['plate']"),
])
def test_different_scenes_are_refused(tmp_path, change, what):
    a = _trials(tmp_path / "a", "dlsr", [1, 0, 1, 0])
    b = _trials(tmp_path / "b", "random", [0, 0, 1, 1], **change)
    with pytest.raises(ValueError) as err:
        compare_pair(a, b)
    msg = str(err.value)
    assert "\n" not in msg and what in msg
    assert str(a) in msg and str(b) in msg and "same scenes" in msg


def test_score_folders_pair_by_image_and_fingerprint(tmp_path):
    a = _scores(tmp_path / "gg", [1, 1, 1, 0, 1], name="ggcnn")
    b = _scores(tmp_path / "dl", [0, 1, 0, 0, 1])
    c = compare_pair(a, b)
    assert (c["a"]["name"], c["b"]["name"]) == ("ggcnn", "dl")  # folder name without detector
    assert c["counts"] == {"both": 2, "only_a": 2, "only_b": 0, "neither": 1}
    assert c["unit"] == "images" and "images" in c["verdict"]
    other = _scores(tmp_path / "other", [1, 1, 1, 0, 1], fingerprint="fff")
    with pytest.raises(ValueError, match="dataset_fingerprint abc123 vs fff"):
        compare_pair(a, other)
    t = _trials(tmp_path / "t", "dlsr", [1, 0, 1, 0, 1])
    with pytest.raises(ValueError, match="a scores folder against a trials folder"):
        compare_pair(a, t)


def test_compare_folders_makes_every_pair(tmp_path):
    dirs = [_trials(tmp_path / n, n, s) for n, s in
            (("dlsr", [1, 0, 1, 1]), ("mask-pca", [1, 1, 0, 1]), ("random", [0, 0, 0, 0]))]
    out = compare_folders(dirs)
    assert [(c["a"]["name"], c["b"]["name"]) for c in out] == [
        ("dlsr", "mask-pca"), ("dlsr", "random"), ("mask-pca", "random")]
    # two folders of the same detector are told apart by the part of their paths that differs
    twin = _trials(tmp_path / "again" / "dlsr", "dlsr", [1, 0, 1, 1])
    c = compare_folders([dirs[0], twin])[0]
    assert (c["a"]["name"], c["b"]["name"]) == (f"dlsr [{tmp_path.name}]", "dlsr [again]")
    with pytest.raises(ValueError, match="at least two"):
        compare_folders(dirs[:1])
    disjoint = _trials(tmp_path / "later", "oracle", [1, 1], indices=[10, 11])
    with pytest.raises(ValueError, match="share no trials"):
        compare_pair(dirs[0], disjoint)


def test_bad_folders(tmp_path):
    with pytest.raises(FileNotFoundError, match="no such folder"):
        compare_pair(tmp_path / "absent", tmp_path / "absent2")
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(FileNotFoundError, match="config.json is missing"):
        compare_pair(empty, empty)
    a = _trials(tmp_path / "a", "dlsr", [1, 0])
    (a / "trials.jsonl").unlink()
    with pytest.raises(FileNotFoundError, match="trials.jsonl is missing"):
        compare_pair(a, a)
    (a / "trials.jsonl").write_text("")
    with pytest.raises(ValueError, match="no records"):
        compare_pair(a, a)
    (a / "trials.jsonl").write_text(json.dumps({"index": 0, "success": "yes"}) + "\n")
    with pytest.raises(ValueError, match="record 1 has success 'yes'"):
        compare_pair(a, a)
    (a / "trials.jsonl").write_text(json.dumps({"index": 0, "success": True}) + "\n"
                                    + json.dumps({"index": 0, "success": False}) + "\n")
    with pytest.raises(ValueError, match="appears twice"):
        compare_pair(a, a)


def test_cli_prints_and_writes_json(tmp_path, capsys):
    a = _trials(tmp_path / "dlsr", "dlsr", [1] * 12 + [0] * 4)
    b = _trials(tmp_path / "random", "random", [0] * 16)
    out = tmp_path / "cmp" / "pairs.json"
    assert main(["compare", str(a), str(b), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "dlsr vs random: 16 paired trials" in text
    assert "dlsr is better than random at the 5 % level" in text
    data = json.loads(out.read_text())
    assert data["alpha"] == 0.05 and len(data["comparisons"]) == 1
    c = data["comparisons"][0]
    assert c["counts"]["only_a"] == 12 and c["better"] == "a"
    assert c["mcnemar_p"] == pytest.approx(_binomial_mcnemar(12, 0))


@pytest.mark.parametrize("make,expect", [
    (lambda p: None, "no such folder"),
    (lambda p: (p.mkdir(), (p / "config.json").write_text("{}")), "trials.jsonl is missing"),
])
def test_cli_one_line_errors(tmp_path, capsys, make, expect):
    good = _trials(tmp_path / "good", "dlsr", [1, 0])
    bad = tmp_path / "bad"
    make(bad)
    assert main(["compare", str(good), str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("graspsim compare: error: ") and expect in err
    assert "\n" not in err and str(bad) in err


def test_cli_refuses_different_scenes_in_one_line(tmp_path, capsys):
    a = _trials(tmp_path / "a", "dlsr", [1, 0])
    b = _trials(tmp_path / "b", "random", [1, 0], seed=5)
    assert main(["compare", str(a), str(b)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("graspsim compare: error: ") and "seed 0 vs 5" in err
    assert "\n" not in err


def _objectwise(path, name, folds, per_fold, seeds=None):
    """An object-wise validation folder: ``objectwise.json`` and each fold run's DLSR trials
    (``per_fold``: the outcomes of each fold)."""
    for k, success in enumerate(per_fold):
        _trials(path / f"fold{k}" / "trials" / "dlsr", "dlsr", success,
                seed=(seeds or {}).get(k, 7), objects=",".join(folds[k]),
                names={i: folds[k][i % len(folds[k])] for i in range(len(success))})
    (path / "objectwise.json").write_text(json.dumps({
        "config": {"name": name}, "n_folds": len(folds), "fold_seed": 0,
        "folds": [{"objects": f, "run": str(path / f"fold{k}")} for k, f in enumerate(folds)]}))
    return path


def test_objectwise_validations_pool_their_folds_by_fold_and_trial(tmp_path):
    folds = [["mug", "can"], ["box", "dice"]]
    a = _objectwise(tmp_path / "a", "default", folds, [[1, 1, 0, 0], [1, 0, 1]])
    b = _objectwise(tmp_path / "b", "wider", folds, [[1, 0, 1, 0], [0, 0, 1]])
    c = compare_pair(a, b)
    # fold 0: both 1, only a 1, only b 1, neither 1; fold 1: only a 1, both 1, neither 1
    assert c["counts"] == {"both": 2, "only_a": 2, "only_b": 1, "neither": 2}
    assert (c["a"]["name"], c["b"]["name"], c["n"], c["unit"]) == ("default", "wider", 7,
                                                                    "trials")
    assert c["kind"] == "objectwise"
    # the same trial index in two folds is two scenes: pooling by index alone would pair 4
    assert len(load_folder(a)["records"]) == 7
    json.dumps(c)


@pytest.mark.parametrize("change,what", [
    ({"folds": [["mug", "box"], ["can", "dice"]]}, "object folds"),
    ({"seeds": {1: 8}}, "fold 1: seed 7 vs 8"),
])
def test_objectwise_validations_of_other_folds_or_scenes_are_refused(tmp_path, change, what):
    folds = [["mug", "can"], ["box", "dice"]]
    a = _objectwise(tmp_path / "a", "default", folds, [[1, 0], [1, 0]])
    b = _objectwise(tmp_path / "b", "other", change.get("folds", folds), [[1, 1], [0, 0]],
                    seeds=change.get("seeds"))
    with pytest.raises(ValueError, match="same scenes") as err:
        compare_pair(a, b)
    assert what in str(err.value)
    with pytest.raises(ValueError, match="objectwise folder against a trials folder"):
        compare_pair(a, a / "fold0" / "trials" / "dlsr")


def test_an_unfinished_objectwise_validation_is_named(tmp_path):
    a = _objectwise(tmp_path / "a", "default", [["mug"], ["box"]], [[1], [0]])
    (a / "objectwise.json").unlink()
    with pytest.raises(FileNotFoundError, match="unfinished object-wise validation"):
        load_folder(a)


def _rounds(path, detector, rounds, seed=0, scene="pile"):
    """A clutter-round folder: ``rounds`` is a list of (first grasp succeeded or None for
    nothing proposed, objects removed)."""
    path.mkdir(parents=True)
    cfg = {"detector": detector, "objects": "test", "seed": seed,
           "config": {"n_candidates": 0, "n_objects": 3, "scene": scene}}
    (path / "config.json").write_text(json.dumps(cfg))
    with open(path / "rounds.jsonl", "w") as fh:
        for i, (first, removed) in enumerate(rounds):
            attempts = [] if first is None else [{"attempt": 0, "success": bool(first)}]
            fh.write(json.dumps({"index": i, "seed": seed, "objects": OBJECTS[:3],
                                 "attempts": attempts, "removed": removed}) + "\n")
    return path


def test_clutter_rounds_pair_on_first_grasps_with_a_sign_test_on_removals(tmp_path, capsys):
    a = _rounds(tmp_path / "a", "dlsr", [(1, 3), (1, 2), (0, 0), (1, 1), (None, 0), (1, 2)])
    b = _rounds(tmp_path / "b", "mask-pca", [(0, 0), (1, 2), (0, 1), (0, 0), (1, 1), (0, 0)])
    c = compare_pair(a, b)
    assert c["kind"] == "rounds" and c["unit"] == "rounds (first grasps)"
    # first grasps: a 4 of 6 (nothing proposed is a failure), b 1 of 6
    assert c["counts"] == {"both": 1, "only_a": 3, "only_b": 1, "neither": 1}
    r = c["removed"]
    assert (r["a"], r["b"], r["more"], r["fewer"], r["same"]) == (8, 4, 3, 2, 1)
    assert r["sign_test_p"] == pytest.approx(_binomial_mcnemar(3, 2))
    assert main(["compare", str(a), str(b)]) == 0
    out = capsys.readouterr().out
    assert "6 paired rounds (first grasps)" in out
    assert "dlsr removed more in 3 rounds, fewer in 2" in out
    # rounds of another scene protocol, or a trial folder, do not pair
    other = _rounds(tmp_path / "c", "mask-pca", [(0, 0)] * 6, scene="packed")
    with pytest.raises(ValueError, match="scene pile vs packed"):
        compare_pair(a, other)
    with pytest.raises(ValueError, match="a rounds folder against a trials folder"):
        compare_pair(a, _trials(tmp_path / "t", "x", [1, 0]))
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "config.json").write_text(json.dumps({"seed": 0, "objects": "test"}))
    (tmp_path / "bad" / "rounds.jsonl").write_text(json.dumps({"index": 0}) + "\n")
    with pytest.raises(ValueError, match="round record 1 has no 'attempts'"):
        compare_pair(a, tmp_path / "bad")


def test_labels_are_short_and_distinct(tmp_path):
    from graspsim.eval.compare import short_labels

    long_model = str(tmp_path / "campaigns" / "2026" / "grconv" / "model" / "ggcnn")
    # a model's path becomes its last part; a plug-in label with options stays whole
    assert short_labels([long_model, "mask-pca", "m:Det(model=a.pt)"], ["x", "y", "z"]) == [
        "ggcnn", "mask-pca", "m:Det(model=a.pt)"]
    # two models of the same file name in different folders: as much path as tells them apart
    other = long_model.replace("grconv", "ggcnn")
    assert short_labels([long_model, other, "mask-pca"], ["x", "y", "z"]) == [
        "grconv/model/ggcnn", "ggcnn/model/ggcnn", "mask-pca"]
    # the same name in two runs: the run folders tell them apart
    a, b = tmp_path / "run-a" / "trials" / "m", tmp_path / "run-b" / "trials" / "m"
    assert short_labels(["m", "m"], [a, b]) == ["m [run-a]", "m [run-b]"]


def test_compare_table_width_stays_short_with_model_paths(tmp_path):
    deep = tmp_path / "home" / "user" / "experiments" / "2026-12-05" / "grconvnet3" / "model"
    a = _trials(tmp_path / "a", str(deep / "ggcnn"), [1, 0, 1, 1])
    b = _trials(tmp_path / "b", "mask-pca", [1, 1, 0, 1])
    text = comparison_text(compare_pair(a, b))
    assert str(deep) not in text
    assert max(len(line) for line in text.splitlines()[:4]) < 60


def test_plugin_labels_keep_only_the_options_that_differ(tmp_path):
    def plugin(folder, options, success, aware=""):
        from graspsim.detectors import detector_label

        path = _trials(tmp_path / folder, detector_label("net:Det", options) + aware, success)
        cfg = json.loads((path / "config.json").read_text())
        cfg["detector_options"] = options
        (path / "config.json").write_text(json.dumps(cfg))
        return path

    a = plugin("a", {"model": "/x/runs/a/model.pt", "top_k": 5}, [1, 0, 1, 1])
    b = plugin("b", {"model": "/x/runs/b/other.pt", "top_k": 5}, [1, 1, 0, 1])
    c = _trials(tmp_path / "c", "mask-pca", [0, 1, 0, 1])
    assert [(x["a"]["name"], x["b"]["name"]) for x in compare_folders([a, b, c])] == [
        ("net:Det(model=model.pt)", "net:Det(model=other.pt)"),
        ("net:Det(model=model.pt)", "mask-pca"), ("net:Det(model=other.pt)", "mask-pca")]
    # compared once, a plug-in is its spec; +aware stays
    assert compare_pair(a, c)["a"]["name"] == "net:Det"
    d = plugin("d", {"model": "m.pt"}, [1, 1, 1, 1], aware="+aware")
    assert compare_pair(d, c)["a"]["name"] == "net:Det+aware"

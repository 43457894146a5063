import json

import pytest

from dlsr.rectangles import GraspRectangle
from graspsim.eval import trials as trials_mod
from graspsim.eval.trials import TrialConfig, run_trials
from graspsim.labels.labelling import Labelled, rank_order, rank_positives
from graspsim.labels.store import SceneLabels, candidates_digest

CFG = TrialConfig(n_candidates=8)
TIMES = ("seconds", "planning_seconds")


def _outcomes(summary):
    return [{k: v for k, v in r.items() if k not in TIMES} for r in summary["records"]]


class _Result:
    def __init__(self, success):
        self.success = success


def test_rank_order_names_the_ranked_positives():
    rects = [GraspRectangle(100, 100, 0.0, 40, 10), GraspRectangle(300, 300, 1.0, 40, 10),
             GraspRectangle(104, 102, 0.05, 40, 10), GraspRectangle(101, 99, 0.1, 40, 10),
             GraspRectangle(50, 400, 0.0, 30, 10)]
    lab = Labelled(rects, [_Result(s) for s in (False, True, True, True, True)])
    order = rank_order(lab)
    # 2 and 3 have each other as neighbours (1 has none, 4 none): they come first, ties in
    # sampling order; the failure 0 is not a positive
    assert order == [2, 3, 1, 4]
    assert [rects[i] for i in order] == rank_positives(lab)
    assert rank_order(Labelled(rects[:1], [_Result(False)])) == []


def test_shared_labels_give_the_same_trials_and_label_each_scene_once(tmp_path, easy_objects,
                                                                     monkeypatch):
    fresh = run_trials("oracle", easy_objects, n=3, seed=7, config=CFG)
    store = tmp_path / "labels"
    first = run_trials("mask-pca", easy_objects, n=3, seed=7, out=tmp_path / "m", config=CFG,
                       labels=store)
    entries = SceneLabels(store).read()
    assert sorted(entries) == [0, 1, 2]
    assert all("_labels" not in r for r in first["records"])  # not in the trial records
    assert "_labels" not in (tmp_path / "m" / "trials.jsonl").read_text()

    def no_labelling(*a, **k):
        raise AssertionError("a scene of the store was labelled again")

    monkeypatch.setattr(trials_mod, "label_rectangles", no_labelling)
    shared = run_trials("oracle", easy_objects, n=3, seed=7, out=tmp_path / "o", config=CFG,
                        labels=store)
    assert _outcomes(shared) == _outcomes(fresh)  # the oracle proposes from the labels
    assert sum(r["n_positives"] for r in shared["records"]) > 0


def test_a_store_of_other_scenes_is_refused(tmp_path, easy_objects):
    store = tmp_path / "labels"
    run_trials("random", easy_objects, n=1, seed=7, config=CFG, labels=store)
    with pytest.raises(ValueError, match=r"labels of other scenes .*key\.json"):
        run_trials("random", easy_objects, n=1, seed=8, config=CFG, labels=store)
    with pytest.raises(ValueError, match="labels of other scenes"):
        run_trials("random", easy_objects, n=1, seed=7, config=TrialConfig(n_candidates=4),
                   labels=store)
    # without labelling there is nothing to share: the store is not even opened
    run_trials("random", easy_objects, n=1, seed=8, config=TrialConfig(n_candidates=0),
               labels=store)


def test_an_entry_of_other_candidates_is_labelled_again(tmp_path, easy_objects):
    fresh = run_trials("oracle", easy_objects, n=2, seed=7, config=CFG)
    store = tmp_path / "labels"
    run_trials("random", easy_objects, n=2, seed=7, config=CFG, labels=store)
    path = store / "labels.jsonl"
    lines = [json.loads(x) for x in path.read_text().splitlines()]
    good = {e["index"]: e for e in lines}
    # a stale entry: other candidates, and positives that would mislead the oracle
    stale = dict(good[0], candidates="0" * 16, positives=list(range(good[0]["n_labelled"])))
    path.write_text("".join(json.dumps(e) + "\n" for e in [stale, good[1]]))
    again = run_trials("oracle", easy_objects, n=2, seed=7, config=CFG, labels=store)
    assert _outcomes(again) == _outcomes(fresh)
    assert SceneLabels(store).read()[0] == good[0]  # the new entry replaces the stale one


def test_candidates_digest_sees_any_change():
    a = [GraspRectangle(10.0, 20.0, 0.5, 30.0, 8.0)]
    b = [GraspRectangle(10.0, 20.0, 0.5, 30.0 + 1e-9, 8.0)]
    assert candidates_digest(a) == candidates_digest(list(a))
    assert candidates_digest(a) != candidates_digest(b)
    assert len(candidates_digest([])) == 16


def _one_line_error(capsys, code):
    err = capsys.readouterr().err.strip()
    assert code != 0 and "Traceback" not in err and len(err.splitlines()) == 1, err
    return err


def test_graspsim_trials_labels_from_the_command_line(tmp_path, capsys):
    from graspsim.cli import main

    store = tmp_path / "labels"
    argv = ["trials", "--detector", "random", "--n", "2", "--candidates", "4", "--labels",
            str(store)]
    assert main([*argv, "--out", str(tmp_path / "a")]) == 0
    assert sorted(SceneLabels(store).read()) == [0, 1]
    capsys.readouterr()  # the progress bar
    # the other scenes' store, a corrupt store and clutter rounds: one line each
    code = main([*argv, "--seed", "1", "--out", str(tmp_path / "b")])
    assert "key.json" in _one_line_error(capsys, code)
    lines = (store / "labels.jsonl").read_text().splitlines()
    (store / "labels.jsonl").write_text(lines[0] + "\n{not json\n" + lines[1] + "\n")
    code = main([*argv, "--out", str(tmp_path / "c")])
    assert "labels.jsonl" in _one_line_error(capsys, code)
    code = main([*argv, "--declutter", "--out", str(tmp_path / "d")])
    assert "--declutter" in _one_line_error(capsys, code)

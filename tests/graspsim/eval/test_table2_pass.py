"""Table 2 in one pass (:func:`graspsim.eval.offline.table2_pass.table2_benchmark`): the same
cells and every detection as the separate detection benchmarks, for any number of workers,
resumable, and behind ``graspsim benchmark table2``."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from dlsr.datasets import write_cornell
from dlsr.detection import DLSRDetector
from graspsim.cli import main
from graspsim.detectors.dlsr_options import PRESETS
from graspsim.eval.offline.detection import detection_benchmark
from graspsim.eval.offline.table2_pass import row_folder, table2_benchmark
from graspsim.runtime.executor import Executor

ROWS = (("NKM", "Natural"), ("NKM", "SC"), ("RP", "Natural"))
SPLITS = ("image", "object")
OPTS = dict(scale=0.5, n_folds=2, n_atoms=8, n_patches=1500, grid_negatives=0.5,
            options=PRESETS["real"], n_overlays=1, progress=False, seed=3)


@pytest.fixture(scope="module")
def dataset(box_samples, tmp_path_factory):
    return write_cornell(box_samples(6), tmp_path_factory.mktemp("t2") / "cornell")


@pytest.fixture(scope="module")
def separate(dataset, tmp_path_factory):
    """Today's way: one detection benchmark per row and split."""
    out = tmp_path_factory.mktemp("separate")
    return out, {(row, split): detection_benchmark(
        dataset, "cornell", row_folder(out, *row, split), split=split, learner=row[0],
        encoder=row[1], **OPTS) for split in SPLITS for row in ROWS}


@pytest.fixture(scope="module")
def one_pass(dataset, tmp_path_factory):
    out = tmp_path_factory.mktemp("onepass")
    return out, table2_benchmark(dataset, "cornell", out, splits=SPLITS, rows=ROWS, **OPTS)


def _records(folder):
    """``results.jsonl`` by image, without the timing."""
    recs = [json.loads(line) for line in (folder / "results.jsonl").read_text().splitlines()]
    return {r["image_id"]: {k: v for k, v in r.items() if k != "seconds"} for r in recs}


def _same(key, x, y) -> bool:
    """A score computed in another process may differ in its last float32 bits (BLAS picks
    its kernels per process and thread count); every other field must be equal."""
    if key == "score" and isinstance(x, float) and isinstance(y, float):
        return math.isclose(x, y, rel_tol=1e-5, abs_tol=1e-6)
    return x == y


def _differences(a: dict, b: dict) -> list:
    """(image, field, a's value, b's value) where two folders' records differ."""
    out = [(i, "missing", i in a, i in b) for i in sorted(set(a) ^ set(b))]
    for i in sorted(set(a) & set(b)):
        out += [(i, k, a[i].get(k), b[i].get(k)) for k in sorted(set(a[i]) | set(b[i]))
                if not _same(k, a[i].get(k), b[i].get(k))]
    return out


def _cells(summary):
    drop = ("seconds_this_run", "seconds_per_image", "candidates_per_second", "machine")
    return {k: v for k, v in summary.items() if k not in drop}


def test_one_pass_equals_the_separate_benchmarks(separate, one_pass):
    out_a, summaries = separate
    out_b, table = one_pass
    for (row, split), alone in summaries.items():
        folder_a, folder_b = row_folder(out_a, *row, split), row_folder(out_b, *row, split)
        # every detection: the top rectangle, its score, the metric and the baselines
        assert _records(folder_b) == _records(folder_a), (row, split)
        assert any(r["rect"] is not None for r in _records(folder_a).values())
        together = json.loads((folder_b / "detection.json").read_text())
        assert _cells(together) == _cells(alone), (row, split)
        assert table["splits"][split]["rows"][f"{row[0]}-{row[1]}"]["accuracy"] == \
            alone["accuracy"]
        assert table["splits"][split]["baselines"] == alone["baselines"]
        # the same fold models, named by the same training key (either run resumes the other)
        names = sorted(p.name for p in (folder_a / "models").glob("*.npz"))
        assert names == sorted(p.name for p in (folder_b / "models").glob("*.npz"))
        for name in names:
            a = DLSRDetector.load(folder_a / "models" / name)
            b = DLSRDetector.load(folder_b / "models" / name)
            np.testing.assert_array_equal(a.coef, b.coef)
            np.testing.assert_array_equal(a.representation.dictionary,
                                          b.representation.dictionary)
    # NKM-Natural and NKM-SC read the same NKM dictionary
    for split in SPLITS:
        for name in sorted(p.name for p in (row_folder(out_b, "NKM", "SC", split)
                                            / "models").glob("*.npz")):
            sc = DLSRDetector.load(row_folder(out_b, "NKM", "SC", split) / "models" / name)
            nat = next((row_folder(out_b, "NKM", "Natural", split) / "models").glob(
                f"*{name.rsplit('_', 1)[1]}"))
            np.testing.assert_array_equal(sc.representation.dictionary,
                                          DLSRDetector.load(nat).representation.dictionary)
    md = (out_b / "table2.md").read_text()
    assert "NKM-SC (lattice detector)" in md and "baseline: mask-pca" in md


def test_one_pass_does_not_depend_on_the_workers(dataset, one_pass, tmp_path):
    out_b, _ = one_pass
    out = tmp_path / "two"
    table2_benchmark(dataset, "cornell", out, splits=SPLITS, rows=ROWS,
                     executor=Executor("loky", n_jobs=2, progress=False), **OPTS)
    for split in SPLITS:
        for row in ROWS:
            diff = _differences(_records(row_folder(out, *row, split)),
                                _records(row_folder(out_b, *row, split)))
            assert not diff, (row, split, diff[:5])


def test_one_pass_resumes_at_the_model_and_the_image(dataset, one_pass, tmp_path,
                                                     monkeypatch):
    """A run stopped after its first detection task keeps the models and that image's
    results; the rerun trains nothing and detects each (row, image) once more at most."""
    import graspsim.eval.offline.table2_pass as t2

    out_b, _ = one_pass
    out = tmp_path / "stopped"
    real_detect, real_train = t2.detect_image, t2.train_fold_rows
    calls, trained = [], []

    class Stop(Exception):
        pass

    def stop_second(dets, s, *a):
        if calls:
            raise Stop
        calls.append(len(dets))
        return real_detect(dets, s, *a)

    def spy_train(paths, *a):
        trained.append(len(paths))
        return real_train(paths, *a)

    monkeypatch.setattr(t2, "detect_image", stop_second)
    monkeypatch.setattr(t2, "train_fold_rows", spy_train)
    with pytest.raises(Stop):
        table2_benchmark(dataset, "cornell", out, splits=("image",), rows=ROWS, **OPTS)
    assert trained == [3, 3] and calls == [3]  # both folds' rows trained together

    def spy_detect(dets, s, *a):
        calls.append(len(dets))
        return real_detect(dets, s, *a)

    monkeypatch.setattr(t2, "detect_image", spy_detect)
    table2_benchmark(dataset, "cornell", out, splits=("image",), rows=ROWS, **OPTS)
    assert trained == [3, 3]  # nothing trained again
    assert len(calls) == 6  # the first image is not detected again
    for row in ROWS:
        assert _records(row_folder(out, *row, "image")) == \
            _records(row_folder(out_b, *row, "image"))


def test_one_pass_detects_each_image_once_for_both_splits(dataset, one_pass, tmp_path,
                                                          monkeypatch):
    """An image is tested once per split, by another fold's models: one task scores it with
    every split's and row's model, and the records are those of the pass on its own."""
    import graspsim.eval.offline.table2_pass as t2

    out_b, _ = one_pass
    real_detect = t2.detect_image
    calls = []

    def spy(dets, s, baselines, seed, bases):
        calls.append((s.image_id, sorted((b["config_key"], b["fold"]) for b in bases)))
        return real_detect(dets, s, baselines, seed, bases)

    monkeypatch.setattr(t2, "detect_image", spy)
    out = tmp_path / "spied"
    table = table2_benchmark(dataset, "cornell", out, splits=SPLITS, rows=ROWS, **OPTS)
    ids = [i for i, _ in calls]
    assert len(ids) == len(set(ids)) == 6  # one task per image
    for _, held in calls:  # every split's and row's configuration, each once
        assert len({key for key, _ in held}) == len(held) == len(ROWS) * len(SPLITS)
    for split in SPLITS:
        for row in ROWS:
            assert _records(row_folder(out, *row, split)) == \
                _records(row_folder(out_b, *row, split)), (row, split)
    phases = table["phase_seconds_this_run"]
    assert set(phases) == {"training", "detection"} and min(phases.values()) > 0


def test_one_pass_refuses_per_row_arguments(dataset, tmp_path):
    with pytest.raises(ValueError, match="learner"):
        table2_benchmark(dataset, "cornell", tmp_path, learner="NKM")
    with pytest.raises(ValueError, match="split"):
        table2_benchmark(dataset, "cornell", tmp_path, splits=("pixel",))


def test_table2_cli_calls_the_one_pass(dataset, tmp_path, monkeypatch, capsys):
    import graspsim.eval.offline.table2_pass as t2

    seen = {}

    def fake(data, format, out, **kw):
        seen.update(kw, data=data, out=out)
        return {"splits": {"image": {"rows": {"NKM-SC": {"accuracy": 0.5}},
                                     "baselines": {"mask-pca": 0.25}}},
                "seconds_this_run": 1.0}

    monkeypatch.setattr(t2, "table2_benchmark", fake)
    assert main(["benchmark", "table2", "--data", str(dataset), "--format", "cornell",
                 "--split", "image", "--rows", "NKM-SC,RP-Natural", "--folds", "3",
                 "--jobs", "2", "--out", str(tmp_path / "o")]) == 0
    assert seen["splits"] == ["image"] and seen["rows"] == [("NKM", "SC"), ("RP", "Natural")]
    assert seen["n_folds"] == 3 and seen["executor"].n_jobs == 2
    assert seen["options"] == PRESETS["real"]
    assert "NKM-SC" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        main(["benchmark", "table2", "--data", str(dataset), "--format", "cornell",
              "--rows", "NKM", "--out", str(tmp_path / "o")])

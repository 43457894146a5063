"""Scoring predictions on a dataset's rebuilt scenes: formats, round trip, resume, CLI, Ray."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from dlsr.datasets import load_cornell
from graspsim.data.datagen import make_dataset
from graspsim.eval.scoring import detect_format, read_predictions, score_predictions
from graspsim.sim.objects import builtin_objects

pytestmark = pytest.mark.sim


@pytest.fixture(scope="module")
def dataset(small_labelled_dataset):
    return small_labelled_dataset


def strip(records):
    return [{k: v for k, v in r.items() if k != "seconds"} for r in records]


def write_csv(path, ranked, score=False):
    lines = ["image,x,y,theta_deg,w,h" + (",score" if score else "")]
    for image, rects in ranked.items():
        for i, r in enumerate(rects):
            row = f"{image},{r.x!r},{r.y!r},{float(np.degrees(r.theta))!r},{r.w!r},{r.h!r}"
            lines.append(row + (f",{-i}" if score else ""))
    path.write_text("\n".join(lines) + "\n")
    return path


def write_cornell(folder, ranked):
    for image, rects in ranked.items():
        sub = folder / "any"
        sub.mkdir(parents=True, exist_ok=True)
        corners = np.concatenate([r.corners() for r in rects]) if rects else np.zeros((0, 2))
        (sub / f"pcd{image}_pred.txt").write_text("".join(f"{x:.10f} {y:.10f}\n"
                                                          for x, y in corners))
    return folder


def write_jacquard(folder, ranked):
    folder.mkdir(parents=True, exist_ok=True)
    for image, rects in ranked.items():
        # Jacquard's angle is clockwise as displayed: the opposite sign of ours.
        (folder / f"{image}_grasps.txt").write_text("".join(
            f"{r.x!r};{r.y!r};{-float(np.degrees(r.theta))!r};{r.w!r};{r.h!r}\n" for r in rects))
    return folder


WRITERS = {"csv": lambda d, ranked: write_csv(d / "p.csv", ranked),
           "cornell": lambda d, ranked: write_cornell(d / "cornell", ranked),
           "jacquard": lambda d, ranked: write_jacquard(d / "jacquard", ranked)}


@pytest.mark.parametrize("fmt", ["csv", "cornell", "jacquard"])
def test_labelled_rectangles_score_as_labelled(dataset, tmp_path, fmt):
    root, stats, samples = dataset
    ranked = {s.image_id: s.positives + s.negatives for s in samples}
    k = max(len(v) for v in ranked.values())
    path = WRITERS[fmt](tmp_path, ranked)
    assert detect_format(path) == fmt
    s = score_predictions(root, path, out=tmp_path / "out", top_k=k)
    assert s["format"] == fmt and s["dataset_fingerprint"] == stats["fingerprint"]
    assert [r["image"] for r in s["records"]] == [x.image_id for x in samples]
    for rec, sample in zip(s["records"], samples, strict=True):
        labels = [True] * len(sample.positives) + [False] * len(sample.negatives)
        assert [a["success"] for a in rec["attempts"]] == labels
        assert [a["rank"] for a in rec["attempts"]] == list(range(1, len(labels) + 1))
        # A labelled positive is right by the rectangle metric against the positives.
        assert all(a["metric"] for a in rec["attempts"][:len(sample.positives)])
        assert rec["success"] == labels[0] and rec["success_at_k"] == any(labels)
        np.testing.assert_allclose(rec["rectangle"], ranked[sample.image_id][0].as_array(),
                                   atol=1e-6)
    at = s["success_at"]
    assert [a["k"] for a in at] == list(range(1, k + 1))
    assert at[0]["successes"] == s["successes"]
    assert at[-1]["successes"] == sum(bool(x.positives) for x in samples)
    assert all(a["successes"] <= b["successes"] for a, b in zip(at, at[1:], strict=False))
    cfg = json.loads((tmp_path / "out" / "config.json").read_text())
    assert cfg["top_k"] == k and cfg["format"] == fmt
    assert cfg["dataset_fingerprint"] == stats["fingerprint"]
    lines = (tmp_path / "out" / "scores.jsonl").read_text().splitlines()
    assert len(lines) == len(samples)
    md = (tmp_path / "out" / "summary.md").read_text()
    assert stats["fingerprint"] in md and "success at k" in md


def test_top1_by_score_column_and_images_without_predictions(dataset, tmp_path):
    root, _, samples = dataset
    with_pos = [x for x in samples if x.positives and x.negatives][0]
    # The negative first in the file but ranked second by its score: top-1 is the positive.
    rows = ["image,x,y,theta_deg,w,h,score"]
    for r, score in ((with_pos.negatives[0], 0.1), (with_pos.positives[0], 0.9)):
        rows.append(f"{int(with_pos.image_id)},{r.x!r},{r.y!r},"
                    f"{float(np.degrees(r.theta))!r},{r.w!r},{r.h!r},{score}")
    path = tmp_path / "p.csv"
    path.write_text("\n".join(rows) + "\n")
    s = score_predictions(root, path)
    by_image = {r["image"]: r for r in s["records"]}
    top = by_image[with_pos.image_id]
    assert top["success"] is True and top["metric"] is True and top["n_predictions"] == 2
    assert "attempts" not in top
    others = [r for r in s["records"] if r["image"] != with_pos.image_id]
    assert all(r["success"] is False and r["reason"] == "no grasp proposed" for r in others)
    assert s["images_without_predictions"] == len(samples) - 1
    assert s["successes"] == 1 and s["n"] == len(samples)


def test_a_subset_of_the_images_is_scored_and_summarised_alone(dataset, tmp_path):
    root, _, samples = dataset
    path = write_csv(tmp_path / "p.csv", {x.image_id: x.positives[:1] for x in samples
                                          if x.positives})
    first, rest = samples[0].image_id, [x.image_id for x in samples[1:]]
    full = score_predictions(root, path, out=tmp_path / "out")
    part = score_predictions(root, path, out=tmp_path / "out", images=[first, first])
    assert part["n"] == 1 and [r["image"] for r in part["records"]] == [first]
    assert part["records"][0] == next(r for r in full["records"] if r["image"] == first)
    # the folder keeps every image's record; a fresh folder scores only those asked for
    assert len((tmp_path / "out" / "scores.jsonl").read_text().splitlines()) == len(samples)
    alone = score_predictions(root, path, out=tmp_path / "alone", images=rest)
    assert {r["image"] for r in alone["records"]} == set(rest)
    assert len((tmp_path / "alone" / "scores.jsonl").read_text().splitlines()) == len(rest)
    with pytest.raises(ValueError, match=r"no image '9999' in the dataset"):
        score_predictions(root, path, images=[first, "9999"])


def test_resume_after_a_kill_and_other_configurations(dataset, tmp_path):
    root, _, samples = dataset
    path = write_csv(tmp_path / "p.csv", {x.image_id: x.negatives[:1] + x.positives[:1]
                                          for x in samples})
    full = score_predictions(root, path, out=tmp_path / "a", top_k=2)
    out = tmp_path / "b"
    score_predictions(root, path, out=out, top_k=2)
    lines = (out / "scores.jsonl").read_text().splitlines()
    (out / "scores.jsonl").write_text(lines[0] + "\n" + lines[1][:30])
    resumed = score_predictions(root, path, out=out, top_k=2)
    assert strip(resumed["records"]) == strip(full["records"])
    assert len((out / "scores.jsonl").read_text().splitlines()) == len(samples)
    with pytest.raises(ValueError, match="another configuration.*top_k"):
        score_predictions(root, path, out=out, top_k=1)
    path.write_text(path.read_text().replace(",", ", "))
    with pytest.raises(ValueError, match="predictions_sha256"):
        score_predictions(root, path, out=out, top_k=2)
    # The same dataset moved elsewhere has the same fingerprint and still resumes.
    moved = tmp_path / "moved"
    shutil.copytree(root, moved)
    again = score_predictions(moved, tmp_path / "p.csv", out=tmp_path / "c", top_k=2)
    assert again["dataset_fingerprint"] == full["dataset_fingerprint"]


def test_bad_prediction_files_name_the_file_and_line(dataset, tmp_path):
    root, _, samples = dataset
    ids = [x.image_id for x in samples]
    head = "image,x,y,theta_deg,w,h\n"
    cases = {
        "nan.csv": (head + "0000,1,2,3,4,5\n0001,nan,2,3,4,5\n", r"nan\.csv:3: non-finite"),
        "cols.csv": (head + "0000,1,2,3,4\n", r"cols\.csv:2: expected 6 columns"),
        "mixed.csv": ("0000,1,2,3,4,5\n0000,1,2,3,4,5,0.5\n", r"mixed\.csv:2: expected 6"),
        "unknown.csv": (head + "0000,1,2,3,4,5\n0999,1,2,3,4,5\n",
                        r"unknown\.csv:3: image '0999' is not an image of the dataset"),
        "text.csv": (head + "0000,a,2,3,4,5\n", r"text\.csv:2: expected numbers"),
        "size.csv": (head + "0000,1,2,3,0,5\n", r"size\.csv:2: w and h must be positive"),
        "header.csv": ("image,x,y,angle,w,h\n", r"header\.csv:1: header must be"),
    }
    for name, (text, match) in cases.items():
        (tmp_path / name).write_text(text)
        with pytest.raises(ValueError, match=match):
            read_predictions(tmp_path / name, image_ids=ids)
    folder = tmp_path / "c"
    folder.mkdir()
    (folder / "pcd0042_pred.txt").write_text("1 2\n3 4\n5 6\n7 8\n")
    with pytest.raises(ValueError, match=r"pcd0042_pred\.txt: image '0042' is not an image"):
        read_predictions(folder, "cornell", image_ids=ids)
    (folder / "pcd0042_pred.txt").unlink()
    (folder / "pcd0000_pred.txt").write_text("1 2\n3 4\n5 6\n")
    with pytest.raises(ValueError, match=r"pcd0000_pred\.txt: 3 corner lines"):
        read_predictions(folder, "cornell", image_ids=ids)
    (folder / "pcd0000cpos.txt").write_text("")
    with pytest.raises(ValueError, match="two prediction files for image 0000"):
        read_predictions(folder, "cornell", image_ids=ids)
    jac = tmp_path / "j"
    jac.mkdir()
    (jac / "0001_grasps.txt").write_text("1;2;3;4;5\n1;2;3;4\n")
    with pytest.raises(ValueError, match=r"0001_grasps\.txt:2: expected"):
        read_predictions(jac, image_ids=ids)
    (folder / "0000_grasps.txt").write_text("")
    with pytest.raises(ValueError, match="give --format"):
        detect_format(folder)
    (tmp_path / "p.txt").write_text("")
    with pytest.raises(ValueError, match="give --format"):
        detect_format(tmp_path / "p.txt")
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(ValueError, match="no prediction files"):
        detect_format(empty)
    with pytest.raises(ValueError, match="csv format is one file"):
        read_predictions(jac, "csv")
    with pytest.raises(FileNotFoundError, match="scenes.json"):
        score_predictions(tmp_path, tmp_path / "cols.csv")
    with pytest.raises(ValueError, match="top_k"):
        score_predictions(root, tmp_path / "cols.csv", top_k=0)


def test_score_cli(dataset, tmp_path, capsys):
    from graspsim.cli import main

    root, _, samples = dataset
    path = write_csv(tmp_path / "p.csv", {x.image_id: x.positives[:1] for x in samples})
    out = tmp_path / "out"
    assert main(["score", "--data", str(root), "--predictions", str(path), "--out",
                 str(out)]) == 0
    printed = capsys.readouterr().out
    assert "top-1 success" in printed and "summary.md" in printed
    summary = json.loads((out / "summary.json").read_text())
    assert summary["successes"] == sum(bool(x.positives) for x in samples)
    (tmp_path / "bad.csv").write_text("0000,1,2,3,4\n")
    assert main(["score", "--data", str(root), "--predictions", str(tmp_path / "bad.csv"),
                 "--out", str(tmp_path / "o2")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("graspsim score: error:") and "bad.csv:1" in err
    assert main(["score", "--data", str(root), "--predictions", str(path), "--out",
                 str(tmp_path / "o3"), "--jobs", "0"]) == 2
    assert "--jobs" in capsys.readouterr().err
    assert main(["dataset", "--scenes", "1", "--out", str(tmp_path / "d"), "--address",
                 "127.0.0.1:1"]) == 2
    assert "--address needs --backend ray" in capsys.readouterr().err


@pytest.mark.slow
def test_ray_gives_the_records_of_loky(dataset, tmp_path):
    pytest.importorskip("ray", reason="Ray is an optional extra (pip install '.[ray]')")
    import ray

    from graspsim.runtime.executor import Executor

    root, _, samples = dataset
    specs = [s for s in builtin_objects("all") if s.name in {"can_tall", "toothbrush"}]
    path = write_csv(tmp_path / "p.csv", {x.image_id: x.negatives[:1] + x.positives[:1]
                                          for x in samples})
    loky = Executor("loky", n_jobs=2, progress=False)
    a = score_predictions(root, path, top_k=2, executor=loky)
    da = make_dataset(n_scenes=2, objects=specs, out=tmp_path / "da", seed=7, n_candidates=3,
                      executor=loky)
    # One local Ray instance for both runs (the executor leaves an initialised Ray running).
    ray.init(include_dashboard=False, log_to_driver=False, _node_ip_address="127.0.0.1",
             num_cpus=2)
    try:
        on_ray = Executor("ray", n_jobs=2, progress=False)
        b = score_predictions(root, path, top_k=2, executor=on_ray)
        db = make_dataset(n_scenes=2, objects=specs, out=tmp_path / "db", seed=7,
                          n_candidates=3, executor=on_ray)
    finally:
        ray.shutdown()
    assert strip(b["records"]) == strip(a["records"])
    # Executed in fresh worker processes, the labelled rectangles keep their labels.
    for rec, x in zip(a["records"], samples, strict=True):
        labels = [False] * len(x.negatives[:1]) + [True] * len(x.positives[:1])
        assert [t["success"] for t in rec["attempts"]] == labels
    assert db["fingerprint"] == da["fingerprint"]
    for x, y in zip(load_cornell(tmp_path / "da"), load_cornell(tmp_path / "db"), strict=True):
        np.testing.assert_array_equal(x.depth, y.depth)
        assert [r.as_array().tolist() for r in x.positives + x.negatives] == \
            [r.as_array().tolist() for r in y.positives + y.negatives]

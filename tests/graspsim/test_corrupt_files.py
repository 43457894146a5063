"""Every file the command line reads, truncated, empty, garbage or of the wrong shape, gives
``graspsim CMD: error: ...`` on one stderr line naming the file, and exit code 2; a torn last
line of a resumable results file is dropped (what a kill leaves), anything else is an error
naming the file and line."""

from __future__ import annotations

import hashlib
import json
import shutil

import numpy as np
import pytest
import tifffile
from PIL import Image

from dlsr.datasets import read_jacquard_grasps, read_mapping, read_pcd_depth
from graspsim.cli import main

GARBAGE = np.random.default_rng(0).bytes(3000)


def truncated(b: bytes) -> bytes:
    return b[: len(b) // 2]


def empty(b: bytes) -> bytes:
    return b""


def garbage(b: bytes) -> bytes:
    return GARBAGE


CORRUPTIONS = {"truncated": truncated, "empty": empty, "garbage": garbage}


def corrupt(path, how):
    """Rewrite ``path`` truncated/empty/garbage, or with ``how`` itself (bytes or str)."""
    if isinstance(how, str) and how in CORRUPTIONS:
        path.write_bytes(CORRUPTIONS[how](path.read_bytes()))
    else:
        path.write_bytes(how.encode() if isinstance(how, str) else how)


def one_line_error(capsys, code, command, path):
    out, err = capsys.readouterr()
    assert code == 2, err
    assert err.startswith(f"graspsim {command}: error: "), err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert str(path) in err, err
    return err


# --------------------------------------------------------------------------------------------
# graspsim detect: the model files and the images


@pytest.fixture
def detect_files(saved_model, obs_files, tmp_path):
    """A copy of the saved model and the image files, to be corrupted one at a time."""
    path, obs = saved_model
    for suffix in (".npz", ".json"):
        shutil.copy(str(path) + suffix, tmp_path / f"m{suffix}")
    files = dict(zip(("rgb", "depth", "mask"), obs_files, strict=True), model=tmp_path / "m")
    return files, obs


def _detect(files, depth=None):
    return main(["detect", "--model", str(files["model"]), "--rgb", str(files["rgb"]),
                 "--depth", str(depth or files["depth"]), "--mask", str(files["mask"])])


def _npz_with(path, **changes):
    """Rewrite the model's arrays with ``changes`` (None: removed), its JSON made to match."""
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    arrays.update(changes)
    np.savez(path, **{k: v for k, v in arrays.items() if v is not None})
    _json_with(path.with_suffix(".json"),
               arrays_sha256=hashlib.sha256(path.read_bytes()).hexdigest())


def _without_digest(damage):
    """``damage`` to a model saved before the JSON recorded its arrays' digest."""
    def apply(path):
        meta = json.loads(path.with_suffix(".json").read_text())
        meta.pop("arrays_sha256")
        path.with_suffix(".json").write_text(json.dumps(meta))
        damage(path)
    return apply


def _json_with(path, **changes):
    meta = json.loads(path.read_text())
    meta.update(changes)
    path.write_text(json.dumps(meta))


MODEL_CASES = {
    "npz-1000-bytes": ("m.npz", lambda p: corrupt(p, p.read_bytes()[:1000])),
    "npz-truncated": ("m.npz", lambda p: corrupt(p, "truncated")),
    "npz-empty": ("m.npz", lambda p: corrupt(p, "empty")),
    "npz-garbage": ("m.npz", lambda p: corrupt(p, "garbage")),
    "npz-of-another-save": ("m.npz", lambda p: np.savez(p, **{**dict(np.load(p)),
                                                             "intercept": np.ones(1)})),
    "old-npz-1000-bytes": ("m.npz", _without_digest(lambda p: corrupt(p, p.read_bytes()[:1000]))),
    "old-npz-empty": ("m.npz", _without_digest(lambda p: corrupt(p, "empty"))),
    "old-npz-garbage": ("m.npz", _without_digest(lambda p: corrupt(p, "garbage"))),
    "npz-missing-array": ("m.npz", lambda p: _npz_with(p, coef=None)),
    "npz-coef-length": ("m.npz", lambda p: _npz_with(p, coef=np.ones(7))),
    "npz-dictionary-shape": ("m.npz", lambda p: _npz_with(p, rep_dictionary=np.ones((4, 5)))),
    "npz-nan": ("m.npz", lambda p: _npz_with(p, coef=np.full(
        np.load(p)["coef"].shape, np.nan))),
    "npz-zero-scale": ("m.npz", lambda p: _npz_with(p, scaler_scale=np.zeros(
        np.load(p)["scaler_scale"].shape))),
    "json-truncated": ("m.json", lambda p: corrupt(p, "truncated")),
    "json-empty": ("m.json", lambda p: corrupt(p, "empty")),
    "json-garbage": ("m.json", lambda p: corrupt(p, "garbage")),
    "json-list": ("m.json", lambda p: corrupt(p, "[1, 2]")),
    "json-no-learner": ("m.json", lambda p: _json_with(p, learner=None)),
    "json-bad-encoder": ("m.json", lambda p: _json_with(p, encoder="Fourier")),
    "json-bad-preprocess": ("m.json", lambda p: _json_with(p, preprocess="fast")),
    "json-newer-version": ("m.json", lambda p: _json_with(p, version=99)),
    "json-param-string": ("m.json", lambda p: _json_with(p, encoder_param="0.5")),
    "json-bad-grid": ("m.json", lambda p: _json_with(p, config={"grid": {"step": "ten"}})),
    "json-bad-grid-key": ("m.json", lambda p: _json_with(p, config={"grid": {"stp": 1}})),
    "json-bad-detector": ("m.json", lambda p: _json_with(p, config={"detector": "fast"})),
}


@pytest.mark.parametrize("case", MODEL_CASES)
def test_detect_corrupt_model(detect_files, capsys, case):
    files, _ = detect_files
    name, damage = MODEL_CASES[case]
    damage(files["model"].with_name(name))
    one_line_error(capsys, _detect(files), "detect", files["model"].with_name(name))


def test_model_save_never_leaves_a_half_written_or_mismatched_model(saved_model, tmp_path,
                                                                    monkeypatch):
    from dlsr.detection import DLSRDetector, model

    target = tmp_path / "m"
    m = DLSRDetector.load(saved_model[0])
    m.save(target)
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    m.config["callback"] = object()  # not JSON: refused before any file is touched
    with pytest.raises(TypeError):
        m.save(target)
    del m.config["callback"]
    m.intercept += 1.0

    def killed(path, text):
        raise KeyboardInterrupt

    monkeypatch.setattr(model, "write_text_atomic", killed)  # killed between the two files
    with pytest.raises(KeyboardInterrupt):
        m.save(target)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(before)  # no temporary file
    assert (tmp_path / "m.json").read_bytes() == before["m.json"]
    with pytest.raises(ValueError, match=r"m\.npz: not the arrays m\.json was saved with"):
        DLSRDetector.load(target)
    monkeypatch.undo()
    m.save(target)
    assert DLSRDetector.load(target).intercept == pytest.approx(m.intercept)


def _rgb_other_size(p, obs):
    Image.fromarray(obs["rgb"][:-3]).save(p, format="PNG")


IMAGE_CASES = {
    "rgb-truncated": ("rgb", "truncated"),
    "rgb-empty": ("rgb", "empty"),
    "rgb-garbage": ("rgb", "garbage"),
    "rgb-other-size": ("rgb", _rgb_other_size),
    "depth-truncated": ("depth", "truncated"),
    "depth-100-bytes": ("depth", lambda p, obs: corrupt(p, p.read_bytes()[:100])),
    "rgb-100-bytes": ("rgb", lambda p, obs: corrupt(p, p.read_bytes()[:100])),
    "depth-empty": ("depth", "empty"),
    "depth-garbage": ("depth", "garbage"),
    "depth-three-channels": ("depth", lambda p, obs: tifffile.imwrite(p, obs["rgb"])),
    "mask-truncated": ("mask", "truncated"),
    "mask-garbage": ("mask", "garbage"),
}


@pytest.mark.parametrize("case", IMAGE_CASES)
def test_detect_corrupt_images(detect_files, capsys, case):
    files, obs = detect_files
    key, how = IMAGE_CASES[case]
    if callable(how):
        how(files[key], obs)
    else:
        corrupt(files[key], how)
    one_line_error(capsys, _detect(files), "detect", files[key])


@pytest.mark.parametrize("how", ["truncated", "empty", "garbage", "npz", "3d", "strings"])
def test_detect_corrupt_npy_depth(detect_files, capsys, how, tmp_path):
    files, obs = detect_files
    path = tmp_path / "depth.npy"
    if how == "npz":
        np.savez(path.with_suffix(".npz"), d=obs["depth"])
        path.with_suffix(".npz").rename(path)
    elif how == "3d":
        np.save(path, obs["depth"][..., None].repeat(2, -1))
    elif how == "strings":
        np.save(path, np.full(obs["depth"].shape, "x"))
    else:
        np.save(path, obs["depth"])
        corrupt(path, how)
    one_line_error(capsys, _detect(files, depth=path), "detect", path)


def test_trials_corrupt_model(detect_files, capsys, tmp_path):
    files, _ = detect_files
    corrupt(files["model"].with_suffix(".npz"), "truncated")
    code = main(["trials", "--detector", str(files["model"]), "--n", "1",
                 "--out", str(tmp_path / "t")])
    one_line_error(capsys, code, "trials", files["model"].with_suffix(".npz"))


# --------------------------------------------------------------------------------------------
# graspsim run: --config files and run.json / stages.json of --resume


CONFIG_CASES = {
    "toml-truncated": ("c.toml", '[run]\nscenes = 7\nname = "unfin'),
    "toml-empty": ("c.toml", ""),
    "toml-garbage": ("c.toml", GARBAGE),
    "toml-string-count": ("c.toml", '[run]\nscenes = "many"\n'),
    "toml-bool-count": ("c.toml", "[run]\ntrials = true\n"),
    "toml-run-not-a-table": ("c.toml", "run = 3\n"),
    "toml-list-of-numbers": ("c.toml", "[run]\nbaselines = [1, 2]\n"),
    "yaml-garbage": ("c.yaml", "scenes: [1, 2\nname: {"),
    "yaml-empty": ("c.yaml", ""),
    "yaml-list": ("c.yaml", "- 1\n- 2\n"),
    "yaml-wrong-type": ("c.yaml", "run:\n  C: fast\n"),
}


@pytest.mark.parametrize("case", CONFIG_CASES)
def test_run_corrupt_config(tmp_path, capsys, case):
    if case.startswith("yaml"):
        pytest.importorskip("yaml")
    name, content = CONFIG_CASES[case]
    path = tmp_path / name
    corrupt(path, content)
    code = main(["run", "--config", str(path), "--out", str(tmp_path / "r")])
    one_line_error(capsys, code, "run", path)
    assert not (tmp_path / "r").exists()


def _valid_run(folder):
    from dataclasses import asdict

    from graspsim.pipeline import load_config

    folder.mkdir()
    cfg = asdict(load_config(quick=True, jobs=1))
    (folder / "run.json").write_text(json.dumps({"config": cfg}))
    return cfg


RUN_CASES = {
    "truncated": ("run.json", "truncated"),
    "empty": ("run.json", "empty"),
    "garbage": ("run.json", "garbage"),
    "list": ("run.json", "[]"),
    "no-config": ("run.json", '{"versions": {}}'),
    "unknown-setting": ("run.json", '{"config": {"scenez": 3}}'),
    "wrong-type": ("run.json", '{"config": {"scenes": "3"}}'),
    "config-not-a-table": ("run.json", '{"config": [3]}'),
    "stages-truncated": ("stages.json", '{"dataset": {"images": 3'),
    "stages-garbage": ("stages.json", GARBAGE),
}


@pytest.mark.parametrize("case", RUN_CASES)
def test_run_resume_corrupt_records(tmp_path, capsys, case):
    folder = tmp_path / "r"
    _valid_run(folder)
    name, how = RUN_CASES[case]
    path = folder / name
    if not path.exists():
        path.write_text("{}")
    corrupt(path, how)
    one_line_error(capsys, main(["run", "--resume", str(folder)]), "run", path)


# --------------------------------------------------------------------------------------------
# Datasets: Cornell rectangle files (graspsim show), PCD, mapping and Jacquard grasp files


@pytest.mark.parametrize("how", ["cut-mid-line", "garbage", "three-numbers", "words"])
def test_show_corrupt_cornell_rectangles(cornell_root, tmp_path, capsys, how):
    path = next(cornell_root.rglob("pcd0101cpos.txt"))
    text = path.read_text()
    corrupt(path, {"cut-mid-line": text[: len(text) // 2 + 7], "garbage": GARBAGE,
                   "three-numbers": "1 2 3\n" * 4, "words": "x y\n" * 4}[how])
    code = main(["show", str(cornell_root), "--format", "cornell", "--out", str(tmp_path / "o")])
    one_line_error(capsys, code, "show", path)


def test_show_empty_rectangle_file_is_an_image_without_rectangles(cornell_root, tmp_path,
                                                                    capsys):
    corrupt(next(cornell_root.rglob("pcd0101cneg.txt")), "empty")
    assert main(["show", str(cornell_root), "--format", "cornell",
                 "--out", str(tmp_path / "o")]) == 0


@pytest.mark.parametrize("how", ["truncated", "empty", "garbage", "other-size"])
def test_show_corrupt_cornell_images(cornell_root, tmp_path, capsys, how):
    kind = "r.png" if how != "other-size" else "d.tiff"
    path = next(cornell_root.rglob(f"pcd0102{kind}"))
    if how == "other-size":
        tifffile.imwrite(path, np.ones((10, 10), np.float32))
    else:
        corrupt(path, how)
    code = main(["show", str(cornell_root), "--format", "cornell", "--out", str(tmp_path / "o")])
    one_line_error(capsys, code, "show", path)


PCD = ("# .PCD v0.7\nFIELDS x y z rgb index\nSIZE 4 4 4 4 4\nTYPE F F F F U\nCOUNT 1 1 1 1 1\n"
       "WIDTH 2\nHEIGHT 1\nPOINTS 2\nDATA ascii\n1 2 600 0 0\n1 2 610 0 7\n")


@pytest.mark.parametrize("content", [
    PCD[:-20],                                  # truncated: fewer points than POINTS
    PCD[:PCD.index("1 2 600")],                 # truncated after the header: no points
    "",                                         # empty
    GARBAGE,                                    # garbage
    PCD.replace("0 7\n", "7\n"),                # a row of 4 numbers for 5 fields
    PCD.replace("POINTS 2", "POINTS two"),      # a header that is not a count
    PCD.replace("DATA ascii", "DATA binary"),   # another encoding
    PCD.replace("1 2 610", "1 2 six"),          # a word in the data
])
def test_corrupt_point_cloud(tmp_path, content):
    path = tmp_path / "pcd0100.txt"
    corrupt(path, content)
    with pytest.raises(ValueError, match="pcd0100.txt") as info:
        read_pcd_depth(path, (3, 4))
    assert "\n" not in str(info.value)


def test_valid_point_cloud(tmp_path):
    (tmp_path / "p.txt").write_text(PCD)
    depth, valid = read_pcd_depth(tmp_path / "p.txt", (3, 4))
    assert valid.sum() == 2 and depth[1, 3] == pytest.approx(np.sqrt(5 + 610**2) / 1000)


@pytest.mark.parametrize("content", [GARBAGE, "0100\n", "0100 a\n0100 b\n"])
def test_corrupt_mapping(tmp_path, content):
    path = tmp_path / "objectClasses.txt"
    corrupt(path, content)
    with pytest.raises(ValueError, match="objectClasses.txt") as info:
        read_mapping(path)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("content", ["1;2;3;4;5\n6;7;8;9", GARBAGE, "1;2;3\n", "a;b;c;d;e\n",
                                     "1,2,3,4,5\n"])
def test_corrupt_jacquard_grasps(tmp_path, content):
    path = tmp_path / "0_abc_grasps.txt"
    corrupt(path, content)
    with pytest.raises(ValueError, match="0_abc_grasps.txt") as info:
        read_jacquard_grasps(path)
    assert "\n" not in str(info.value)


# --------------------------------------------------------------------------------------------
# Resumable results files and the benchmarks' inputs


BAD_MIDDLE = '{"index": 0, "x": 1}\n{"index": 1, "x"\n{"index": 2, "x": 3}\n'
RESULTS_CASES = {
    "torn-middle": (BAD_MIDDLE, r":2: not a JSON record"),
    "garbage": (GARBAGE, r":1: not a JSON record"),
    "not-records": ("[1]\n[2]\n", r":1: not a JSON record"),
}


@pytest.mark.parametrize("case", RESULTS_CASES)
def test_benchmark_detection_corrupt_results(cornell_root, tmp_path, capsys, case):
    content, where = RESULTS_CASES[case]
    out = tmp_path / "b"
    out.mkdir()
    corrupt(out / "results.jsonl", content.replace('"index"', '"image_id"')
            if isinstance(content, str) else content)
    code = main(["benchmark", "detection", "--data", str(cornell_root), "--format", "cornell",
                 "--split", "image", "--folds", "2", "--out", str(out)])
    assert where in one_line_error(capsys, code, "benchmark", out / "results.jsonl")


def test_benchmark_detection_record_without_its_key(cornell_root, tmp_path, capsys):
    out = tmp_path / "b"
    out.mkdir()
    (out / "results.jsonl").write_text('{"fold": 0}\n{"fold": 1}\n')
    code = main(["benchmark", "detection", "--data", str(cornell_root), "--format", "cornell",
                 "--split", "image", "--folds", "2", "--out", str(out)])
    assert "lacks ['image_id']" in one_line_error(capsys, code, "benchmark",
                                                  out / "results.jsonl")


@pytest.mark.parametrize("how", ["truncated", "empty", "garbage", "no-folds", "cell-list"])
def test_benchmark_detection_corrupt_recognition_json(cornell_root, tmp_path, capsys, how):
    path = tmp_path / "recognition.json"
    path.write_text(json.dumps({"cells": [{"learner": "NKM", "encoder": "Natural",
                                           "folds": [{"encoder_param": None, "C": 1.0}]}]}))
    corrupt(path, {"no-folds": '{"cells": [{"learner": "NKM", "encoder": "Natural"}]}',
                   "cell-list": '{"cells": [[1, 2]]}'}.get(how, how))
    code = main(["benchmark", "detection", "--data", str(cornell_root), "--format", "cornell",
                 "--split", "image", "--folds", "2", "--recognition", str(path),
                 "--out", str(tmp_path / "b")])
    one_line_error(capsys, code, "benchmark", path)


def _recognition(cornell_root, out, *extra):
    return main(["benchmark", "recognition", "--data", str(cornell_root), "--format",
                 "cornell", "--learners", "NKM", "--encoders", "Natural", "--atoms", "8",
                 "--patches", "500", "--folds", "2", "--inner-folds", "2", *extra,
                 "--out", str(out)])


@pytest.mark.parametrize("case", RESULTS_CASES)
def test_benchmark_recognition_corrupt_results(cornell_root, tmp_path, capsys, case):
    content, where = RESULTS_CASES[case]
    out = tmp_path / "b"
    out.mkdir()
    corrupt(out / "results.jsonl", content.replace('"index"', '"learner": "NKM", "encoder"')
            if isinstance(content, str) else content)
    assert where in one_line_error(capsys, _recognition(cornell_root, out), "benchmark",
                                   out / "results.jsonl")


def _patch_file(path, **changes):
    arrays = {"patches": np.zeros((5, 6, 6, 8), np.float32), "masks": np.ones((5, 6, 6, 8), bool)}
    arrays.update(changes)
    np.savez(path, **{k: v for k, v in arrays.items() if v is not None})


@pytest.mark.parametrize("how", ["truncated", "empty", "garbage", "shape", "masks-missing",
                                 "masks-float", "nan"])
def test_benchmark_recognition_corrupt_extra_patches(cornell_root, tmp_path, capsys, how):
    path = tmp_path / "patches.npz"
    _patch_file(path)
    if how in CORRUPTIONS:
        corrupt(path, how)
    else:
        _patch_file(path, **{
            "shape": {"patches": np.zeros((5, 6, 6, 3), np.float32)},
            "masks-missing": {"masks": None},
            "masks-float": {"masks": np.full((5, 6, 6, 8), 0.5)},
            "nan": {"patches": np.full((5, 6, 6, 8), np.nan, np.float32)},
        }[how])
    code = _recognition(cornell_root, tmp_path / "b", "--extra-patches", str(path))
    one_line_error(capsys, code, "benchmark", path)


@pytest.mark.sim
@pytest.mark.parametrize("case", RESULTS_CASES)
def test_trials_corrupt_results(tmp_path, capsys, case):
    content, where = RESULTS_CASES[case]
    out = tmp_path / "t"
    out.mkdir()
    corrupt(out / "trials.jsonl", content)
    code = main(["trials", "--detector", "random", "--n", "1", "--candidates", "0",
                 "--out", str(out)])
    assert where in one_line_error(capsys, code, "trials", out / "trials.jsonl")


@pytest.mark.sim
def test_trials_bad_index_and_config(tmp_path, capsys):
    out = tmp_path / "t"
    out.mkdir()
    (out / "trials.jsonl").write_text('{"index": "zero"}\n')
    code = main(["trials", "--detector", "random", "--n", "1", "--candidates", "0",
                 "--out", str(out)])
    assert "'zero'" in one_line_error(capsys, code, "trials", out / "trials.jsonl")
    (out / "trials.jsonl").unlink()
    (out / "config.json").write_text('{"detector": "rand')
    code = main(["trials", "--detector", "random", "--n", "1", "--candidates", "0",
                 "--out", str(out)])
    one_line_error(capsys, code, "trials", out / "config.json")


@pytest.mark.sim
def test_trials_torn_last_line_is_dropped_and_redone(tmp_path, capsys):
    out = tmp_path / "t"
    argv = ["trials", "--detector", "random", "--n", "2", "--candidates", "0", "--out", str(out)]
    assert main(argv) == 0
    lines = (out / "trials.jsonl").read_text().splitlines()
    (out / "trials.jsonl").write_text(lines[0] + "\n" + lines[1][:20])
    capsys.readouterr()
    assert main(argv) == 0
    again = (out / "trials.jsonl").read_text().splitlines()
    assert len(again) == 2 and again[0] == lines[0]
    assert {json.loads(x)["index"] for x in again} == {0, 1}
    assert not list(out.glob(".*tmp"))


@pytest.mark.sim
@pytest.mark.parametrize("name, content", [("scenes.jsonl", BAD_MIDDLE),
                                           ("scenes.jsonl", GARBAGE),
                                           ("dataset_config.json", '{"seed": 0, "obj'),
                                           ("dataset_config.json", "")])
def test_dataset_corrupt_records(tmp_path, capsys, name, content):
    out = tmp_path / "d"
    out.mkdir()
    corrupt(out / name, content)
    code = main(["dataset", "--scenes", "1", "--candidates", "2", "--out", str(out)])
    one_line_error(capsys, code, "dataset", out / name)
    assert not list(out.rglob("*.png"))  # refused before any scene was rendered


@pytest.fixture(scope="module")
def one_scene_dataset(tmp_path_factory):
    from graspsim.data.datagen import make_dataset

    root = tmp_path_factory.mktemp("data") / "ds"
    make_dataset(n_scenes=1, objects="test", out=root, seed=1, n_candidates=2)
    return root


@pytest.mark.sim
@pytest.mark.parametrize("how", ["garbage", "binary-csv", "columns", "manifest-truncated",
                                 "manifest-garbage", "config-truncated"])
def test_score_corrupt_inputs(one_scene_dataset, tmp_path, capsys, how):
    data = tmp_path / "ds"
    shutil.copytree(one_scene_dataset, data)
    pred, out = tmp_path / "p.csv", tmp_path / "s"
    pred.write_text("image,x,y,theta_deg,w,h\n0000,100,100,0,40,20\n")
    path = {"manifest-truncated": data / "scenes.json", "manifest-garbage": data / "scenes.json",
            "config-truncated": out / "config.json"}.get(how, pred)
    if how == "config-truncated":
        out.mkdir()
        path.write_text('{"data": "x", "dataset_finger')
    else:
        corrupt(path, {"columns": "0000,1,2\n", "binary-csv": b"\xff\xfe" + GARBAGE,
                       "manifest-truncated": "truncated",
                       "manifest-garbage": "garbage"}.get(how, how))
    code = main(["score", "--data", str(data), "--predictions", str(pred), "--out", str(out)])
    one_line_error(capsys, code, "score", path)


@pytest.mark.parametrize("name, content, where", [
    ("config.json", '{"detector": "rand', ""),
    ("config.json", GARBAGE, ""),
    ("trials.jsonl", BAD_MIDDLE, ":2: "),
    ("trials.jsonl", GARBAGE, ":1: "),
])
def test_compare_corrupt_folders(tmp_path, capsys, name, content, where):
    folders = []
    for d in ("a", "b"):
        f = tmp_path / d
        f.mkdir()
        (f / "config.json").write_text(json.dumps({"detector": d, "seed": 0, "objects": "test"}))
        (f / "trials.jsonl").write_text("".join(
            json.dumps({"index": i, "success": i % 2 == 0}) + "\n" for i in range(4)))
        folders.append(f)
    corrupt(folders[1] / name, content)
    code = main(["compare", *map(str, folders)])
    assert f"{name}{where}" in one_line_error(capsys, code, "compare", folders[1] / name)

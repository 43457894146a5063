"""Detector plug-ins: ``module:NAME`` from the current folder, entry points, the return-value
check, errors recorded per trial, planning time, the pipeline's baselines and worker processes."""

from __future__ import annotations

import json
import pickle
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from dlsr.rectangles import GraspRectangle
from graspsim.detectors import (
    GraspDetector,
    PluginDetector,
    check_detections,
    check_detector,
    detector_label,
    load_detector,
    parse_detector_options,
    plugin_names,
)

# A plug-in outside the project: mask-pca's rectangles as an (n, 5) array with scores.
PLUGIN = """
import numpy as np

from graspsim.detectors import MaskPCADetector


class Det:
    calls = 0

    def predict(self, obs):
        type(self).calls += 1
        rects = MaskPCADetector().predict(obs)
        arr = np.array([r.as_array() for r in rects]).reshape(-1, 5)
        return arr, np.full(len(arr), 0.5)


def make():
    return Det()


class Frames:
    # Checks the observation's keys, dtypes, intrinsics and camera pose, then proposes nothing.
    def predict(self, obs):
        assert obs["rgb"].dtype == np.uint8 and obs["rgb"].ndim == 3
        assert obs["depth"].dtype == np.float32 and obs["depth_valid"].dtype == np.uint8
        assert obs["K"].shape == (3, 3) and obs["T_world_cam"].shape == (4, 4)
        assert isinstance(obs["seed"], int)
        v, u = np.nonzero(obs["depth_valid"])
        z = obs["depth"][v, u].astype(float)
        rays = np.linalg.solve(obs["K"], np.stack([u, v, np.ones_like(u)]).astype(float))
        p_cam = rays * z
        p_world = obs["T_world_cam"][:3, :3] @ p_cam + obs["T_world_cam"][:3, 3:4]
        # Most valid pixels see the table top, the plane z = 0 of the world frame.
        assert abs(np.median(p_world[2])) < 0.005, np.median(p_world[2])
        return []


class Flaky:
    # Raises on its first call in a process, then behaves like Det.
    calls = 0

    def predict(self, obs):
        type(self).calls += 1
        if type(self).calls == 1:
            raise RuntimeError("boom\\non two lines")
        return Det().predict(obs)


class BadShape:
    def predict(self, obs):
        return np.zeros((1, 4))


class NoPredict:
    pass


def failing_factory():
    raise OSError("checkpoint missing")


instance = Det()


class WithOptions:
    # A network wrapper: its checkpoint and settings come as keyword arguments.
    def __init__(self, model, top_k=1, scale=1.0):
        self.model, self.top_k, self.scale = model, top_k, scale

    def predict(self, obs):
        return []


class NeedsVision:
    # Imports a package that is not installed when it is built.
    def __init__(self):
        import not_installed_vision_q  # noqa: F401

    def predict(self, obs):
        return []
"""


@pytest.fixture
def plugin_dir(tmp_path, monkeypatch):
    """``tmp_path`` holding the plug-in as a module of a unique name; returns (dir, name)."""
    names = []

    def write(name, source=PLUGIN):
        (tmp_path / f"{name}.py").write_text(textwrap.dedent(source))
        names.append(name)
        return name

    monkeypatch.setattr(sys, "path", list(sys.path))  # the loader may append the cwd
    monkeypatch.chdir(tmp_path)
    yield tmp_path, write
    for n in names:
        sys.modules.pop(n, None)


def strip(records, extra=()):
    drop = {"seconds", "planning_seconds", *extra}
    return [{k: v for k, v in r.items() if k not in drop} for r in records]


# --- the return-value check --------------------------------------------------------------------
def test_check_detections_accepts_the_documented_forms():
    r = GraspRectangle(10, 20, 0.3, 30, 10)
    rects, scores = check_detections([r, r])
    assert rects == [r, r] and scores is None
    rects, scores = check_detections(np.array([[10, 20, 0.3, 30, 10], [1, 2, 4.0, 3, 1]]))
    assert len(rects) == 2 and rects[0] == r
    assert -np.pi / 2 <= rects[1].theta < np.pi / 2  # normalised like every rectangle
    rects, scores = check_detections(([r], [0.7]))
    assert scores.tolist() == [0.7] and scores.dtype == np.float64
    assert check_detections([]) == ([], None)
    assert check_detections(np.zeros((0, 5)))[0] == []
    assert check_detections((np.zeros((0, 5)), np.zeros(0)))[1].shape == (0,)


@pytest.mark.parametrize("bad, match", [
    ({"x": 1}, "returned a dict"),
    (None, "returned a NoneType"),
    ([(1, 2, 0, 3, 4)], "item 0 is a tuple, not a GraspRectangle"),
    (np.zeros((2, 4)), r"shape \(2, 4\)"),
    (np.array([1.0, 2, 0, 3, 4]), r"shape \(5,\)"),
    (np.array([[1.0, np.nan, 0, 3, 4]]), "non-finite values in row 0"),
    (np.array([[1.0, 2, 0, 3, 4], [1.0, 2, np.inf, 3, 4]]), "non-finite values in row 1"),
    (np.array([[1.0, 2, 0, 0, 4]]), "non-positive opening"),
    (np.array([["a", "b", "c", "d", "e"]]), "dtype"),
    (np.ones((1, 5), dtype=bool), "dtype bool"),
    ((np.ones((2, 5)), np.ones(3)), r"scores of shape \(3,\) for 2 rectangles"),
    ((np.ones((1, 5)), np.array([np.nan])), "non-finite scores"),
    ((np.ones((1, 5)), np.ones(1), 3), "tuple of 3 items"),
])
def test_check_detections_rejects_with_one_line(bad, match):
    with pytest.raises(ValueError, match=match) as err:
        check_detections(bad, "mine")
    assert "'mine'" in str(err.value) and "\n" not in str(err.value)


# --- loading -----------------------------------------------------------------------------------
def test_module_in_the_current_folder_loads(plugin_dir):
    _, write = plugin_dir
    name = write("mydet_load")
    for attr in ("Det", "make", "instance"):
        check_detector(f"{name}:{attr}")
        det = load_detector(f"{name}:{attr}")
        assert isinstance(det, PluginDetector) and isinstance(det, GraspDetector)
        assert det.spec == f"{name}:{attr}" and not det.requires_labels


@pytest.mark.parametrize("spec, match", [
    ("no_such_module_q:Det", "no module named 'no_such_module_q'"),
    ("{mod}:Nope", "has no attribute 'Nope'"),
    ("{mod}:NoPredict", "NoPredict gave a NoPredict with no predict"),
    ("{mod}:failing_factory", "calling failing_factory.*OSError: checkpoint missing"),
    ("{broken}:Det", "importing mydet_broken failed: No module named .not_installed_dep_q."),
    ("{syntax}:Det", "importing .* failed: SyntaxError"),
])
def test_bad_plugins_give_one_line_errors(plugin_dir, spec, match):
    _, write = plugin_dir
    mod = write("mydet_errors")
    broken = write("mydet_broken", "import not_installed_dep_q\n")
    syntax = write("mydet_syntax", "def f(:\n")
    spec = spec.format(mod=mod, broken=broken, syntax=syntax)
    with pytest.raises(ValueError, match=match) as err:
        load_detector(spec)
    assert "\n" not in str(err.value) and spec in str(err.value)
    if "NoPredict" in spec:  # the check before a run calls no factory but looks at classes
        with pytest.raises(ValueError, match="class NoPredict has no predict"):
            check_detector(spec)
    elif "failing_factory" not in spec:
        with pytest.raises(ValueError, match=match):
            check_detector(spec)


def test_unknown_names_still_name_the_model_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="unknown detector 'nothing-here'.*plug-in"):
        load_detector("nothing-here")


def test_entry_point_group_registers_names(tmp_path, monkeypatch):
    site = tmp_path / "site"
    dist = site / "fake_graspsim_plugin-1.0.dist-info"
    dist.mkdir(parents=True)
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: fake-graspsim-plugin\n"
                                   "Version: 1.0\n")
    (dist / "entry_points.txt").write_text(
        "[graspsim.detectors]\nfake-net = fake_ep_module:make\nfake-broken = fake_ep_module:Nope\n")
    (site / "fake_ep_module.py").write_text(textwrap.dedent(PLUGIN))
    monkeypatch.setattr(sys, "path", list(sys.path))
    monkeypatch.syspath_prepend(str(site))
    try:
        assert plugin_names()["fake-net"] == "fake_ep_module:make"
        det = load_detector("fake-net")
        assert isinstance(det, PluginDetector) and det.spec == "fake-net"
        assert det.path == str(site)
        with pytest.raises(ValueError, match="fake-broken.*entry point"):
            load_detector("fake-broken")
        with pytest.raises(FileNotFoundError, match="fake-broken, fake-net"):
            load_detector("not-registered")
        check_detector("fake-net")
        with pytest.raises(FileNotFoundError, match="not-registered"):
            check_detector("not-registered")
    finally:
        sys.modules.pop("fake_ep_module", None)


def test_pickled_plugin_reloads_in_a_process_without_the_folder(plugin_dir, tmp_path_factory):
    folder, write = plugin_dir
    name = write("mydet_pickle")
    det = load_detector(f"{name}:Det")
    elsewhere = tmp_path_factory.mktemp("elsewhere")
    code = ("import pickle, sys\n"
            f"assert {str(folder)!r} not in sys.path\n"
            "det = pickle.loads(sys.stdin.buffer.read())\n"
            "print(type(det).__name__, det.spec, type(det.detector).__module__)\n")
    out = subprocess.run([sys.executable, "-c", code], input=pickle.dumps(det), cwd=elsewhere,
                         capture_output=True, check=True)
    assert out.stdout.decode().split() == ["PluginDetector", f"{name}:Det", name]


# --- through the trials ------------------------------------------------------------------------

@pytest.mark.sim
def test_cli_runs_a_plugin_from_the_current_folder_on_two_workers(plugin_dir, capsys):
    from graspsim.cli import main
    from graspsim.eval.trials import run_trials

    folder, write = plugin_dir
    name = write("mydet_cli")
    out = folder / "out"
    args = ["trials", "--detector", f"{name}:Det", "--objects", "test", "--n", "3",
            "--candidates", "0", "--out", str(out)]
    assert main([*args, "--jobs", "2"]) == 0
    assert f"{name}:Det: success" in capsys.readouterr().out
    recs = [json.loads(x) for x in (out / "trials.jsonl").read_text().splitlines()]
    assert sorted(r["index"] for r in recs) == [0, 1, 2]
    assert all(r["score"] == 0.5 and r["planning_seconds"] > 0 for r in recs)
    # The plug-in wraps mask-pca: the same grasps as the built-in detector.
    ref = run_trials("mask-pca", "test", n=3, seed=0, config=_cfg(0))
    assert strip(sorted(recs, key=lambda r: r["index"]), ["score"]) == strip(ref["records"])
    summary = json.loads((out / "summary.json").read_text())
    p = summary["planning_seconds"]
    assert p["n"] == 3 and 0 < p["median"] <= p["p95"]
    assert "95th percentile" in (out / "summary.md").read_text()
    assert json.loads((out / "config.json").read_text())["detector"] == f"{name}:Det"


def _cfg(n_candidates, n_objects=1):
    from graspsim.eval.trials import TrialConfig

    return TrialConfig(n_candidates=n_candidates, n_objects=n_objects)


@pytest.mark.sim
def test_observation_carries_intrinsics_and_camera_pose(plugin_dir, easy_objects):
    from graspsim.eval.trials import NO_PROPOSAL, run_trials

    _, write = plugin_dir
    name = write("mydet_frames")
    s = run_trials(f"{name}:Frames", easy_objects, n=2, seed=4, config=_cfg(0))
    # An assertion failing inside predict would show as "detector error: AssertionError".
    assert [r["reason"] for r in s["records"]] == [NO_PROPOSAL, NO_PROPOSAL]


@pytest.mark.sim
def test_a_raising_predict_fails_its_trial_and_the_campaign_goes_on(plugin_dir, easy_objects):
    from graspsim.eval.trials import run_trials

    folder, write = plugin_dir
    name = write("mydet_flaky")
    s = run_trials(f"{name}:Flaky", easy_objects, n=3, seed=1, out=folder / "f",
                   config=_cfg(0))
    first, *rest = s["records"]
    assert first["reason"] == "detector error: RuntimeError: boom on two lines"
    assert first["success"] is False and first["rectangle"] is None
    assert first["planning_seconds"] >= 0
    ref = run_trials("mask-pca", easy_objects, n=3, seed=1, config=_cfg(0))
    assert strip(rest, ["score"]) == strip(ref["records"][1:])
    assert len((folder / "f" / "trials.jsonl").read_text().splitlines()) == 3
    assert s["failure_reasons"]["detector error: RuntimeError: boom on two lines"] == 1


@pytest.mark.sim
def test_a_bad_return_value_stops_the_run_with_one_line(plugin_dir, easy_objects, capsys):
    from graspsim.cli import main

    folder, write = plugin_dir
    name = write("mydet_badshape")
    assert main(["trials", "--detector", f"{name}:BadShape", "--n", "1", "--candidates", "0",
                 "--out", str(folder / "b")]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]  # after the progress bar
    assert err.startswith("graspsim trials: error: trial 0 (seed 0): detector "
                          f"'{name}:BadShape' returned an array of shape (1, 4)")
    assert main(["trials", "--detector", "no_such_module_q:Det", "--n", "1",
                 "--out", str(folder / "c")]) == 2
    assert "no module named 'no_such_module_q'" in capsys.readouterr().err


@pytest.mark.sim
def test_pipeline_baselines_take_plugins(plugin_dir):
    from graspsim.pipeline import job as pipeline
    from graspsim.runtime.executor import Executor

    folder, write = plugin_dir
    name = write("mydet_run")
    toml = folder / "campaign.toml"
    toml.write_text(f'[run]\ntrials = 2\ntrial_candidates = 0\nbaselines = ["{name}:Det"]\n')
    config = pipeline.load_config(toml)
    assert config.baselines == [f"{name}:Det"]
    with pytest.raises(ValueError, match="baselines: detector 'no_such_module_q:Det'"):
        pipeline.load_config(baselines=["no_such_module_q:Det"])
    with pytest.raises(ValueError, match="listed twice"):
        pipeline.load_config(baselines=["random", "random"])
    with pytest.raises(ValueError, match="DLSR's own trial name"):
        pipeline.load_config(baselines=["dlsr-paper"])  # it runs with the gripper-aware search
    # The trial stage, with DLSR's trials (both searches) already finished.
    root = folder / "run"
    root.mkdir()
    stages = pipeline._Stages(root)
    assert pipeline.trial_names(config) == ["dlsr", "dlsr-paper", f"{name}:Det"]
    stages.finish("trials/dlsr", {"n": 0})
    stages.finish("trials/dlsr-paper", {"n": 0})
    pipeline.trial_stage(root, config, stages, root / "model" / "dlsr", seed=3,
                         executor=Executor("sequential", progress=False), progress=False)
    s = stages.get(f"trials/{name}:Det")
    assert s["n"] == 2 and s["detector"] == f"{name}:Det"
    lines = (root / "trials" / f"{name}:Det" / "trials.jsonl").read_text().splitlines()
    assert len(lines) == 2 and json.loads(lines[0])["score"] == 0.5


# --- options -----------------------------------------------------------------------------------
def test_detector_options_parse_json_values_else_text():
    opts = parse_detector_options(["model=runs/net/model.pt", "top_k=5", "scale=0.5",
                                   "aware=true", "sizes=[224, 300]", 'name="5"', "empty="])
    assert opts == {"model": "runs/net/model.pt", "top_k": 5, "scale": 0.5, "aware": True,
                    "sizes": [224, 300], "name": "5", "empty": ""}
    assert list(opts) == ["model", "top_k", "scale", "aware", "sizes", "name", "empty"]
    for bad, match in (("model", "KEY=VALUE"), ("2x=1", "identifier"), ("=1", "KEY=VALUE")):
        with pytest.raises(ValueError, match=match):
            parse_detector_options([bad])
    with pytest.raises(ValueError, match="given twice"):
        parse_detector_options(["a=1", "a=2"])


def test_detector_label_says_the_options_shortly():
    assert detector_label("m:Det") == detector_label("m:Det", {}) == "m:Det"
    long = "/home/someone/experiments/2026-12-05/grconvnet3/epoch_30_iou_0.97"
    label = detector_label("m:Det", {"top_k": 5, "model": long, "sizes": [224, 300]})
    assert label == "m:Det(model=epoch_30_iou_0.97,sizes=[224,300],top_k=5)"
    assert detector_label("m:Det", {"note": "x" * 60}) == "m:Det(note=" + "x" * 21 + "...)"
    # keys sorted: the same options in another order give the same name
    assert detector_label("m:D", {"b": 1, "a": 2}) == detector_label("m:D", {"a": 2, "b": 1})


def test_plugin_options_reach_the_constructor(plugin_dir, tmp_path_factory):
    folder, write = plugin_dir
    name = write("mydet_options")
    spec = f"{name}:WithOptions"
    opts = {"model": "runs/net/model.pt", "top_k": 3}
    check_detector(spec, opts)
    det = load_detector(spec, opts)
    assert (det.detector.model, det.detector.top_k, det.detector.scale) == (
        "runs/net/model.pt", 3, 1.0)
    assert det.label == f"{spec}(model=model.pt,top_k=3)"
    # a worker process builds it again with the same options
    code = ("import pickle, sys\n"
            "det = pickle.loads(sys.stdin.buffer.read())\n"
            "print(det.detector.model, det.detector.top_k, det.label)\n")
    out = subprocess.run([sys.executable, "-c", code], input=pickle.dumps(det),
                         cwd=tmp_path_factory.mktemp("worker"), capture_output=True, check=True)
    assert out.stdout.decode().split() == ["runs/net/model.pt", "3", det.label]
    # a class that needs an argument says how to give it; an unknown option is named
    for check in (check_detector, load_detector):
        with pytest.raises(ValueError, match="model.*--detector-option KEY=VALUE") as err:
            check(spec)
        assert "\n" not in str(err.value)
        with pytest.raises(ValueError, match="depth_scale"):
            check(spec, {"model": "m.pt", "depth_scale": 2})
    # an instance takes no options; a saved model neither
    with pytest.raises(ValueError, match="takes no options"):
        load_detector(f"{name}:instance", {"top_k": 2})
    with pytest.raises(ValueError, match="not a Python identifier"):
        load_detector(spec, {"no good": 1})
    # built-in detectors take their class's parameters
    assert load_detector("mask-pca", {"margin_px": 9.0}).margin_px == 9.0


def test_a_missing_package_is_named(plugin_dir):
    _, write = plugin_dir
    name = write("mydet_vision")
    broken = write("mydet_vision_import", "import numpy\nimport not_installed_vision_q\n")
    with pytest.raises(ValueError) as err:
        load_detector(f"{name}:NeedsVision")
    msg = str(err.value)
    assert msg.startswith(f"plug-in '{name}:NeedsVision': NeedsVision() failed importing "
                          "not_installed_vision_q: No module named 'not_installed_vision_q'")
    assert "factory taking no argument" not in msg and "\n" not in msg
    for call in (load_detector, check_detector):
        with pytest.raises(ValueError) as err:
            call(f"{broken}:Det")
        assert str(err.value).startswith(
            f"plug-in '{broken}:Det': importing {broken} failed: No module named "
            "'not_installed_vision_q'")


def test_options_are_recorded_and_checked_on_resume(plugin_dir, capsys):
    from graspsim.cli import main
    from graspsim.eval.trials import run_trials

    folder, write = plugin_dir
    name = write("mydet_record")
    spec = f"{name}:WithOptions"
    out = folder / "t"
    s = run_trials(spec, "test", n=0, out=out, config=_cfg(0),
                   detector_options={"model": "nets/a/model.pt", "top_k": 2})
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["detector_options"] == {"model": "nets/a/model.pt", "top_k": 2}
    assert cfg["detector"] == s["detector"] == f"{spec}(model=model.pt,top_k=2)"
    run_trials(spec, "test", n=0, out=out, config=_cfg(0),
               detector_options={"top_k": 2, "model": "nets/a/model.pt"})  # same: resumes
    with pytest.raises(ValueError, match="another configuration"):
        run_trials(spec, "test", n=0, out=out, config=_cfg(0),
                   detector_options={"model": "nets/b/model.pt", "top_k": 2})
    # without options nothing new is recorded: folders written before options still resume
    plain = folder / "plain"
    run_trials("mask-pca", "test", n=0, out=plain, config=_cfg(0))
    assert "detector_options" not in json.loads((plain / "config.json").read_text())
    # the command line
    assert main(["trials", "--detector", spec, "--detector-option", "model=nets/c/net.pt",
                 "--detector-option", "scale=0.5", "--n", "0", "--candidates", "0",
                 "--out", str(folder / "cli")]) == 0
    assert capsys.readouterr().out.startswith(f"{spec}(model=net.pt,scale=0.5): success")
    cfg = json.loads((folder / "cli" / "config.json").read_text())
    assert cfg["detector_options"] == {"model": "nets/c/net.pt", "scale": 0.5}
    assert main(["trials", "--detector", spec, "--n", "0", "--out", str(folder / "c2")]) == 2
    assert "--detector-option" in capsys.readouterr().err


def test_run_config_takes_a_detector_options_table(plugin_dir):
    from graspsim.pipeline import job as pipeline

    folder, write = plugin_dir
    name = write("mydet_table")
    toml = folder / "campaign.toml"
    toml.write_text(f'[run]\ntrials = 2\nbaselines = ["mask-pca", "{name}:WithOptions"]\n\n'
                    f'[run.detector_options."{name}:WithOptions"]\n'
                    'model = "runs/net/model.pt"\ntop_k = 4\n')
    config = pipeline.load_config(toml)
    assert config.detector_options == {f"{name}:WithOptions": {"model": "runs/net/model.pt",
                                                               "top_k": 4}}
    det = pipeline.trial_detector(f"{name}:WithOptions", folder / "model", config)
    assert (det.detector.model, det.detector.top_k) == ("runs/net/model.pt", 4)
    with pytest.raises(ValueError, match="baselines: plug-in .*model"):
        pipeline.load_config(baselines=[f"{name}:WithOptions"])  # its argument is missing
    with pytest.raises(ValueError, match="not among the baselines"):
        pipeline.load_config(baselines=["mask-pca"],
                             detector_options={f"{name}:WithOptions": {"model": "m"}})
    # a recorded run without the setting is the same configuration as one with no options
    recorded = {k: v for k, v in pipeline.asdict(pipeline.RunConfig()).items()
                if k != "detector_options"}
    assert pipeline._recorded_config(recorded) == json.loads(json.dumps(
        pipeline.asdict(pipeline.RunConfig())))


@pytest.mark.sim
def test_run_trial_stage_passes_and_records_the_options(plugin_dir):
    from graspsim.pipeline import job as pipeline
    from graspsim.runtime.executor import Executor

    folder, write = plugin_dir
    name = write("mydet_stage")
    spec = f"{name}:WithOptions"
    config = pipeline.load_config(trials=1, trial_candidates=0, baselines=[spec],
                                  detector_options={spec: {"model": "runs/net/m.pt"}})
    root = folder / "run"
    root.mkdir()
    stages = pipeline._Stages(root)
    stages.finish("trials/dlsr", {"n": 0})
    stages.finish("trials/dlsr-paper", {"n": 0})
    pipeline.trial_stage(root, config, stages, root / "model" / "dlsr", seed=3,
                         executor=Executor("sequential", progress=False), progress=False)
    cfg = json.loads((root / "trials" / spec / "config.json").read_text())
    assert cfg["detector_options"] == {"model": "runs/net/m.pt"}
    assert cfg["detector"] == stages.get(f"trials/{spec}")["detector"] == f"{spec}(model=m.pt)"

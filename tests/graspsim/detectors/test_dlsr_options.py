"""The detector options (:mod:`graspsim.detectors.dlsr_options`): one set of names for ``graspsim
benchmark detection``, ``graspsim detect`` and ``graspsim run``."""

from __future__ import annotations

import argparse
import dataclasses

import pytest

from graspsim.cli import build_parser
from graspsim.detectors.dlsr_options import (
    OPTION_NAMES,
    PRESETS,
    REAL_DEFAULT,
    DetectorOptions,
    candidate_options,
    options_from_args,
)
from graspsim.pipeline import RunConfig


def _subparser(parser: argparse.ArgumentParser, *path: str) -> argparse.ArgumentParser:
    for name in path:
        action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        parser = action.choices[name]
    return parser


def _option_flags(parser: argparse.ArgumentParser) -> dict[str, set[str]]:
    """dest -> option strings of the detector options in ``parser``."""
    return {a.dest: set(a.option_strings) for a in parser._actions if a.dest in OPTION_NAMES}


def test_the_three_commands_share_the_detector_option_names():
    root = build_parser()
    flags = {path: _option_flags(_subparser(root, *path))
             for path in (("benchmark", "detection"), ("detect",), ("run",))}
    expected = {name: {"--" + name.replace("_", "-")} | (
        set() if name == "detector" else {"--no-" + name.replace("_", "-")})
        for name in OPTION_NAMES}
    for path, got in flags.items():
        assert got == expected, path
    # and graspsim run's configuration files take the same names as settings
    assert set(OPTION_NAMES) <= {f.name for f in dataclasses.fields(RunConfig)}


def test_presets_and_overrides():
    root = build_parser()
    args = root.parse_args(["detect", "--model", "m", "--rgb", "r", "--depth", "d"])
    assert options_from_args(args) == PRESETS[REAL_DEFAULT]
    args = root.parse_args(["detect", "--model", "m", "--rgb", "r", "--depth", "d",
                            "--preset", "paper", "--clear-jaws"])
    assert options_from_args(args) == dataclasses.replace(PRESETS["paper"], clear_jaws=True)
    args = root.parse_args(["benchmark", "detection", "--data", "x", "--format", "jacquard",
                            "--out", "o", "--preset", "all", "--no-physical", "--detector",
                            "dense"])
    o = options_from_args(args)
    assert (o.detector, o.physical, o.gripper_aware) == ("dense", False, True)
    # the real-data default is the choice of the nested cross-validation: the lattice alone
    assert PRESETS[REAL_DEFAULT] == candidate_options()["paper+lattice"]
    assert PRESETS["all"] == DetectorOptions()


def test_run_flags_override_the_config():
    from graspsim.pipeline import load_config

    args = build_parser().parse_args(["run", "--quick", "--no-gripper-aware",
                                      "--detector", "dense"])
    config = load_config(None, quick=True, **{k: getattr(args, k) for k in OPTION_NAMES})
    assert (config.detector, config.gripper_aware, config.physical) == ("dense", False, True)


def test_candidates_are_the_paper_each_departure_alone_and_all():
    c = candidate_options()
    assert list(c)[0] == "paper" and list(c)[-1] == "all"
    assert c["paper"].departures() == [] and c["all"] == DetectorOptions()
    singles = [o for n, o in c.items() if n not in ("paper", "all")]
    assert sorted(len(o.departures()) for o in singles) == [1] * 4
    assert {o.departures()[0] for o in singles} == set(OPTION_NAMES) - {"clear_jaws"}
    assert c["paper+lattice"].detector == "lattice"
    assert len(set(c.values())) == len(c)


def test_unknown_preset_is_refused_by_the_parser(capsys):
    with pytest.raises(SystemExit):
        build_parser().parse_args(["detect", "--model", "m", "--rgb", "r", "--depth", "d",
                                   "--preset", "nope"])
    assert "invalid choice" in capsys.readouterr().err


def test_benchmark_keeps_the_given_images_and_fewer_training_positives(tmp_path, box_samples,
                                                                      monkeypatch):
    """What :func:`graspsim.eval.offline.nested.nested_detector_choice` relies on: ``images``
    keeps
    only those images, ``train_positives`` trains on at most that many positives each."""
    from dlsr.datasets import write_cornell
    from graspsim.eval.offline.detection import detection_benchmark

    root = write_cornell(box_samples(6), tmp_path / "cornell")
    seen = []

    class Stop(Exception):
        pass

    def fake_train(samples, **kw):
        seen.append(samples)
        raise Stop

    monkeypatch.setattr("graspsim.eval.offline.detection.train_detector", fake_train)
    with pytest.raises(Stop):
        detection_benchmark(root, "cornell", tmp_path / "o", split="image", n_folds=2,
                            images=["0100", "0101", "0102", "0103"], train_positives=1,
                            options=PRESETS["paper"], progress=False)
    (train,) = seen
    assert len(train) == 2 and {s.image_id for s in train} <= {"0100", "0101", "0102", "0103"}
    assert all(len(s.positives) == 1 for s in train)
    with pytest.raises(ValueError, match="not among the labelled images"):
        detection_benchmark(root, "cornell", tmp_path / "o", split="image", n_folds=2,
                            images=["9999"], progress=False)


def test_search_grid_keeps_complete_region_through_its_dict():
    from dlsr.detection import PAPER_GRID, SearchGrid

    assert "complete_region" not in PAPER_GRID.to_dict()  # earlier models' grids unchanged
    grid = dataclasses.replace(PAPER_GRID, complete_region=True)
    assert SearchGrid.from_dict(grid.to_dict()) == grid

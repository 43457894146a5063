"""stdout carries only what a command means to print: pybullet's C banners (``pybullet build
time: ...`` at import, ``argv[0]=`` at connect) are silenced in graspsim.sim.bullet."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

BANNERS = ("pybullet build time", "argv[0]")


def _cli(*argv, cwd):
    return subprocess.run([sys.executable, "-m", "graspsim.cli", *map(str, argv)], cwd=cwd,
                          capture_output=True, text=True, timeout=600)


@pytest.mark.sim
def test_trials_stdout_is_only_the_summary_line(tmp_path):
    res = _cli("trials", "--detector", "random", "--n", "2", "--candidates", "0",
               "--out", tmp_path / "t", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert res.stdout.startswith("random: success ") and res.stdout.count("\n") == 1
    assert not any(b in res.stdout + res.stderr for b in BANNERS)


@pytest.mark.sim
def test_connect_restores_stdout_and_keeps_its_order(tmp_path):
    code = ("import graspsim.sim.bullet as s\nprint('before', flush=True)\nc = s.connect()\n"
            "print('after')\nc.disconnect()\nimport os\nos.write(1, b'raw\\n')\n")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120, cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert res.stdout == "before\nafter\nraw\n"
    assert not any(b in res.stderr for b in BANNERS)


def test_detect_stdout_is_json(saved_model, obs_files, tmp_path):
    path, _ = saved_model
    rgb, depth, mask = obs_files
    res = _cli("detect", "--model", path, "--rgb", rgb, "--depth", depth, "--mask", mask,
               "--top-k", "2", "--out", tmp_path / "o.png",
               "--preset", "paper",  # these files have no camera matrix
               cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    result = json.loads(res.stdout)
    assert len(result["rectangles"]) == 2 and (tmp_path / "o.png").is_file()
    assert not any(b in res.stdout for b in BANNERS)

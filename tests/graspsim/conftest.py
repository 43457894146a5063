"""Fixtures of the graspsim tests: a small saved DLSR model and its scene's image files, and
what the tests of stopping parallel workers share."""

from __future__ import annotations

import os
import time

import numpy as np
import pytest
import tifffile
from PIL import Image

from dlsr import patches, whitening
from dlsr.detection import DLSRDetector, SearchGrid
from dlsr.features import Representation, rectangle_features
from dlsr.preprocess import rectangle_images
from dlsr.svm import FeatureStandardizer, SquaredHingeSVC

H, W = 100, 130


def _scene():
    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:H, 0:W]
    rgb = 100 + 60 * np.sin(xx / 7.0)[..., None] + 40 * rng.random((H, W, 3))
    depth = (0.8 + 0.0003 * xx).astype(np.float32)
    mask = np.zeros((H, W), bool)
    mask[40:60, 30:100] = True
    depth[mask] -= 0.03
    rgb[mask] = [200, 40, 40]
    return {"rgb": np.clip(rgb, 0, 255).astype(np.uint8), "depth": depth,
            "depth_valid": np.ones((H, W), bool), "mask": mask}


def _small_model(obs):
    """NKM-Natural on random whitened patches, an SVM on random labels: enough for the CLI."""
    rng = np.random.default_rng(0)
    R = np.column_stack([rng.uniform(35, 95, 40), rng.uniform(40, 60, 40),
                         rng.uniform(-1.5, 1.5, 40), np.full(40, 30.0), np.full(40, 20.0)])
    im, mk = rectangle_images(obs["rgb"], obs["depth"], obs["depth_valid"], R)
    X, M = patches.extract_patches(im, mk, 6)
    X, M = X.reshape(-1, 288), M.reshape(-1, 288)
    Xs = whitening.standardize_patches(X, M)
    mean, P = whitening.fit_zca(Xs, M)
    Xw = whitening.apply_zca(Xs, M, mean, P)
    cents = Xw[rng.choice(np.flatnonzero(M.all(1)), 16, replace=False)].astype(np.float32)
    rep = Representation("NKM", cents / np.linalg.norm(cents, axis=1, keepdims=True), cents,
                         mean, P, None)
    F = rectangle_features(im, mk, rep, "Natural", None, polarity=False)
    scaler = FeatureStandardizer().fit(F)
    svm = SquaredHingeSVC().fit(scaler.transform(F), np.arange(40) % 2)
    return DLSRDetector(rep, "Natural", None, False, scaler.mean_, scaler.scale_,
                        np.asarray(svm.coef_[0]), float(svm.intercept_[0]))


@pytest.fixture(scope="session")
def saved_model(tmp_path_factory):
    """``(path, obs)``: a small model saved at ``path`` (+ .npz/.json) and its scene."""
    obs = _scene()
    model = _small_model(obs)
    grid = SearchGrid(angles_deg=(0, 90), openings=(20, 30), jaws=(10, 20), step=10.0,
                      dilate=5)
    model.config.update(grid=grid.to_dict(), rescore=10)
    path = tmp_path_factory.mktemp("model") / "m"
    model.save(path)
    return path, obs


@pytest.fixture
def obs_files(saved_model, tmp_path):
    """The saved model's scene written as ``rgb.png``, ``depth.tiff``, ``mask.png``."""
    _, obs = saved_model
    rgb, depth, mask = tmp_path / "rgb.png", tmp_path / "depth.tiff", tmp_path / "mask.png"
    Image.fromarray(obs["rgb"]).save(rgb)
    tifffile.imwrite(depth, obs["depth"])
    Image.fromarray(obs["mask"].astype(np.uint8) * 255).save(mask)
    return rgb, depth, mask


@pytest.fixture(scope="session")
def easy_objects():
    """A few graspable test-split objects (kept short for CI)."""
    from graspsim.sim.objects import builtin_objects

    names = {"can_tall", "box_matches", "toothbrush", "bottle_shampoo"}
    specs = [s for s in builtin_objects("all") if s.name in names]
    assert len(specs) >= 2, "built-in objects missing: run scripts/make_objects.py"
    return specs


@pytest.fixture
def pid_after():
    """A task for a worker: sleeps ``seconds``, then returns the worker's process id (from
    ``worker_tasks``, a module a worker can import by a name no other test module has)."""
    from worker_tasks import pid_after

    return pid_after


@pytest.fixture
def depth_source():
    """A task for a worker: the class of a sample's depth array as the worker received it, the
    file it maps and the sha256 of its values (from ``worker_tasks``)."""
    from worker_tasks import depth_source

    return depth_source


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)  # signal 0: only asks whether the process exists
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


@pytest.fixture
def still_running():
    """``still_running(pids, within=15.0)``: those of ``pids`` still running after waiting up to
    ``within`` seconds for them to end (loky reaps the workers it stops)."""
    def check(pids, within: float = 15.0) -> set:
        deadline = time.monotonic() + within
        while True:
            alive = {p for p in pids if _alive(p)}
            if not alive or time.monotonic() > deadline:
                return alive
            time.sleep(0.1)
    return check


@pytest.fixture(scope="session")
def observed_test_scenes():
    """``observed_test_scenes(seed, n)``: the observations of trials ``0 .. n-1`` of ``seed``
    on the built-in test objects (a detector's input), each with detector seed 0."""
    return _observed_test_scenes


def _observed_test_scenes(seed: int, n: int) -> list[dict]:
    from graspsim.labels.graspability import resolve_objects
    from graspsim.sim.bullet import Simulation
    from graspsim.sim.observe import observation, observe_scene

    sim = Simulation()
    try:
        specs = resolve_objects("test")
        return [observation(observe_scene(sim, specs, seed, i)[2], 0) for i in range(n)]
    finally:
        sim.close()

"""A trial's seeded scene and what the camera sees of it.

Every trial ``i`` of a run with seed ``s`` gets its own generator streams from
``SeedSequence(s, spawn_key=(i,))`` (scene, camera, labelling candidates, detector seed), so the
scene and observation of a trial depend only on ``(s, i)``: the same in any process, for any
number of trials, and on resume. The trials, the datasets, the environment and the scripts that
replay a trial all build its scene here.
"""

from __future__ import annotations

import logging

import numpy as np

from ..sim.profiles import get_profile
from .bullet import renew_worker_sim
from .layouts import make_scene_of
from .scene import build_scene, capture

__all__ = ["SceneError", "made_again_if_unmade", "trial_streams", "observe_scene",
           "profile_capture", "observation"]

log = logging.getLogger(__name__)


class SceneError(ValueError):
    """A seeded scene that cannot be made (objects that never come to rest, a pile that never
    settles). It is the same scene for every detector, so a campaign records it as a skip
    (:func:`graspsim.runtime.campaign.skipped_record`) and pairs detectors on the scenes that
    were made."""


def made_again_if_unmade(make):
    """``make()``, made once more in a new simulation if its scene could not be made.

    ``make`` builds its scene in this process's simulator (:func:`graspsim.sim.bullet.worker_sim`,
    which it calls). A :class:`SceneError` there is followed by a new connection
    (:func:`graspsim.sim.bullet.renew_worker_sim`) and a second ``make()``, whose error, if any,
    is raised: a scene that cannot be made fails twice, the same for every detector, while a
    failure of the reused connection does not cost a scene. On 2026-12-06 one scene of the
    Cornell stand-in (random_053) failed with an infinite moment of inertia from pybullet in a
    worker that had run hundreds of scenes, and was made in a new process with the labels of a
    run in which it had not failed.

    Parameters
    ----------
    make : callable
        Takes no argument.

    Returns
    -------
    What ``make`` returns.
    """
    try:
        return make()
    except SceneError as exc:
        log.info("%s; made again in a new simulation", exc)
    renew_worker_sim()
    return make()


def trial_streams(seed: int, index: int) -> dict:
    """Independent generators (scene, camera, labels) and a detector seed for one trial."""
    ss = np.random.SeedSequence(seed, spawn_key=(index,))
    scene_ss, camera_ss, label_ss, det_ss = ss.spawn(4)
    return {
        "scene": np.random.default_rng(scene_ss),
        "camera": np.random.default_rng(camera_ss),
        "label": np.random.default_rng(label_ss),
        "detector_seed": int(det_ss.generate_state(1)[0]),
    }


def observe_scene(sim, specs, seed: int, index: int, n_objects: int = 1, profile=None,
                  scene: str = "drop"):
    """Build trial ``index``'s seeded scene in ``sim`` and take its observation.

    ``scene`` is the protocol (:func:`graspsim.sim.layouts.make_scene_of`). ``profile`` (a
    :class:`graspsim.sim.profiles.SimProfile` or a name in :data:`graspsim.sim.profiles.PROFILES`;
    None for the default) sets the camera height and
    intrinsics, table colour, lighting ranges and depth noise; the objects and their poses are
    the same under every profile.

    Returns
    -------
    scene : Scene
    bodies : the loaded bodies (see :func:`graspsim.sim.scene.build_scene`)
    frame : RGBDFrame
    streams : dict
        The trial's generators (:func:`trial_streams`); ``"label"`` and ``"detector_seed"``
        are still unused.

    Raises
    ------
    SceneError
        When the scene cannot be made (:func:`graspsim.sim.scene.make_scene`); the message names
        the scene's index and seed.
    """
    prof = get_profile(profile)
    st = trial_streams(seed, index)
    try:
        placed = make_scene_of(scene, sim, specs, st["scene"], n_objects=n_objects,
                               table=prof.table)
    except ValueError as exc:
        raise SceneError(f"scene {index} of seed {seed}: {exc}") from None
    bodies = build_scene(sim, placed)
    frame = profile_capture(sim, placed, bodies, st["camera"], prof)
    return placed, bodies, frame, st


def profile_capture(sim, scene, bodies, rng, profile=None, noise=None):
    """:func:`graspsim.sim.scene.capture` with a profile's camera height, intrinsics, lighting
    ranges and depth noise (``profile``: a :class:`graspsim.sim.profiles.SimProfile`, a name, or
    None for the default; ``noise``, when given, replaces the profile's depth noise)."""
    prof = get_profile(profile)
    return capture(sim, scene, bodies, rng, noise=prof.depth_noise if noise is None else noise,
                   intrinsics=prof.intrinsics, height=prof.camera_height,
                   lighting=prof.lighting)


def observation(frame, detector_seed: int) -> dict:
    """What a detector's ``predict`` gets (see :class:`graspsim.detectors.GraspDetector`).

    Parameters
    ----------
    frame : graspsim.sim.camera.RGBDFrame
    detector_seed : int

    Returns
    -------
    dict
        ``rgb`` (H, W, 3) uint8, ``depth`` (H, W) float32 metres (0 where missing),
        ``depth_valid`` (H, W) uint8, ``K`` (3, 3) float64 pixels, ``T_world_cam`` (4, 4)
        float64 (OpenCV camera frame to world, metres) and ``seed``; copies, so a detector
        cannot change what the gripper then executes.
    """
    return {
        "rgb": np.array(frame.rgb, dtype=np.uint8),
        "depth": np.array(frame.depth, dtype=np.float32),
        "depth_valid": np.asarray(frame.depth_valid).astype(np.uint8),
        "K": np.array(frame.intrinsics.K, dtype=np.float64),
        "T_world_cam": np.array(frame.T_world_cam, dtype=np.float64),
        "seed": int(detector_seed),
    }

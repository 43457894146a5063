"""``graspsim/Grasp-v0``: one planar grasp per step, scored by physics.

Observation (``Dict``):

* ``rgb``: ``Box(0, 255, (480, 640, 3), uint8)``
* ``depth``: ``Box(0, 10, (480, 640), float32)``, metres, 0 where missing (Kinect-like noise)
* ``depth_valid``: ``Box(0, 1, (480, 640), uint8)``

Action: ``Box(5)`` = ``(x, y, theta, w, h)`` in pixels and radians (the
:class:`~dlsr.rectangles.GraspRectangle` convention); values are clipped to the action space.

Reward 1.0 when the grasp lifts an object (>= 10 cm, held by both fingers), else 0.0.
``reset``'s ``info`` has the camera's intrinsics ``K`` (3, 3, pixels) and pose ``T_world_cam``
(4, 4; OpenCV camera frame to world, metres), as the trial harness gives detectors.
``step``'s ``info``: ``success``, ``failure_reason`` (None on success), ``lift_height`` (m),
``gripper_pose`` (the executed 4x4 ``T_world_tcp``, or None when nothing was executed),
``object`` (the name of the object between the jaws, or None), and ``rectangle_metric`` (bool)
when the episode was reset with ``options={"label": True}``: the action against the scene's
physics-labelled positives (also given as ``info["positives"]`` by ``reset``).

``scene`` chooses the protocol (:mod:`graspsim.sim.layouts`: ``"drop"``, the default,
``"isolated"``, ``"packed"``, ``"pile"``; packed and pile scenes have 5 objects unless
``n_objects`` says otherwise). Default episode: one object, one grasp (``terminated`` after
the step). ``declutter=True``:
``n_objects`` objects; a grasped object is removed (and so are objects pushed off the table,
listed in ``info["fell_off"]``), the others settle and a new observation is rendered (the scene
update of :func:`graspsim.eval.declutter.scene_after_grasp`); the episode terminates when the table
is empty and is truncated by the ``max_episode_steps`` of the registration. Every random value
comes from ``self.np_random`` (seeded by ``reset(seed=...)``), so the same seed gives the same
observations and outcomes. ``execution`` (a :class:`graspsim.sim.execution.ExecutionParams`) sets
how grasps are executed and labelled, as for trials (e.g. ``ExecutionParams(min_grip=0.01)``).
"""

from __future__ import annotations

from dataclasses import replace

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from dlsr.metrics import rectangle_metric
from dlsr.rectangles import GraspRectangle

from .labels.graspability import resolve_objects
from .labels.labelling import label_rectangles, rank_positives, sample_candidates
from .sim.bullet import Simulation
from .sim.execution import ExecutionParams, execute_grasp, harness_grasps, run_grasp
from .sim.gripper import hand_params
from .sim.layouts import check_scene, default_objects_per_scene, make_scene_of
from .sim.observe import profile_capture
from .sim.profiles import get_profile
from .sim.scene import build_scene, scene_after_grasp

__all__ = ["GraspEnv"]

H, W = 480, 640


class GraspEnv(gym.Env):
    """Planar grasping with simulation in the loop (see the module docstring).

    Parameters
    ----------
    render_mode : {"rgb_array"} or None
    objects : str, ObjectSet or list of ObjectSpec
        An object set (:func:`graspsim.labels.graspability.resolve_objects`: a built-in split or
        names,
        ``random_urdfs[:split]``, ``folder:PATH[:split]``).
    n_objects : int
        Objects per scene (default 1; 5 in declutter mode when not given).
    declutter : bool
    n_candidates : int
        Candidates executed to label a scene when ``reset(options={"label": True})``.
    noise : graspsim.sim.camera.DepthNoise or None
        None: the profile's depth noise (the default profile's: Kinect-like).
    profile : str, graspsim.sim.profiles.SimProfile or None
        How scenes are seen: camera height and intrinsics, table colour, lighting ranges and
        depth noise (:mod:`graspsim.sim.profiles`, e.g. ``"jacquard"``); None: the default. The
        observation space follows its image size.
    execution : graspsim.sim.execution.ExecutionParams or None
        How grasps are executed (and labelled); None: the harness's defaults.
    scene : {"drop", "isolated", "packed", "pile"}
        How the objects are put on the table (:mod:`graspsim.sim.layouts`); ``"drop"``, the
        default, is the scene of earlier versions.
    gripper : {"builtin", "franka", "wsg50", "robotiq-2f85"} or None
        The hand (:mod:`graspsim.sim.hands`; :func:`graspsim.sim.gripper.hand_params`), replacing
        ``execution``'s gripper parameters; None: those of ``execution`` (the built-in hand by
        default).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 2}

    def __init__(self, render_mode=None, objects="test", n_objects=None, declutter=False,
                 n_candidates=32, noise=None, profile=None, execution=None, scene="drop",
                 gripper=None):
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        if execution is not None and not isinstance(execution, ExecutionParams):
            raise TypeError(f"execution must be an ExecutionParams or None, got "
                            f"{type(execution).__name__}")
        self.render_mode = render_mode
        self.execution = execution
        self._params = ExecutionParams() if execution is None else execution
        self.gripper = gripper
        if gripper is not None:
            self._params = replace(self._params, gripper=hand_params(gripper))
        self.specs = resolve_objects(objects, self._params)
        self.declutter = bool(declutter)
        self.n_objects = (default_objects_per_scene(scene, declutter) if n_objects is None
                          else int(n_objects))
        self.scene = check_scene(scene, self.n_objects)
        self.n_candidates = int(n_candidates)
        self.noise = noise
        self.profile = profile
        self._profile = get_profile(profile)
        H, W = self._profile.intrinsics.height, self._profile.intrinsics.width
        self.observation_space = spaces.Dict({
            "rgb": spaces.Box(0, 255, (H, W, 3), np.uint8),
            "depth": spaces.Box(0.0, 10.0, (H, W), np.float32),
            "depth_valid": spaces.Box(0, 1, (H, W), np.uint8),
        })
        self.action_space = spaces.Box(
            low=np.array([0.0, 0.0, -np.pi / 2, 1.0, 1.0], dtype=np.float32),
            high=np.array([W - 1.0, H - 1.0, np.pi / 2, 200.0, 100.0], dtype=np.float32),
            dtype=np.float32,
        )
        self.sim = Simulation()
        self._scene = None
        self._frame = None
        self._positives = None

    # --- helpers --------------------------------------------------------------------------
    def _observe(self):
        bodies = build_scene(self.sim, self._scene)
        self._frame = profile_capture(self.sim, self._scene, bodies, self.np_random,
                                      self._profile, noise=self.noise)
        self._bodies = bodies
        f = self._frame
        return {
            "rgb": f.rgb.copy(),
            "depth": np.asarray(f.depth, dtype=np.float32).copy(),
            "depth_valid": np.asarray(f.depth_valid, dtype=np.uint8).copy(),
        }

    def _camera_info(self):
        """``K`` (3, 3) and ``T_world_cam`` (4, 4) of the current observation, as the trial
        harness gives them to detectors (:class:`graspsim.detectors.GraspDetector`)."""
        f = self._frame
        return {"K": np.array(f.intrinsics.K, dtype=np.float64),
                "T_world_cam": np.array(f.T_world_cam, dtype=np.float64)}

    def _label(self):
        f = self._frame
        cands = sample_candidates(f.segmentation, self._bodies.objects, self.np_random,
                                  self.n_candidates, depth=f.depth_clean,
                                  max_opening=self._params.gripper.geometry.max_opening)
        # Labelled at the action space's float32 precision, so that stepping with a positive
        # executes exactly the labelled grasp (light objects in marginal grasps are chaotic).
        cands = [GraspRectangle(*r.as_array().astype(np.float32).astype(np.float64))
                 for r in cands]
        labelled = label_rectangles(self.sim, self._scene, f, cands, self._params)
        self._positives = rank_positives(labelled)

    # --- gymnasium API ---------------------------------------------------------------------
    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        options = options or {}
        self._scene = make_scene_of(self.scene, self.sim, self.specs, self.np_random,
                                    n_objects=self.n_objects, table=self._profile.table,
                                    spread=0.05 if self.n_objects == 1 else 0.1)
        self._label_scenes = bool(options.get("label", False))
        self._positives = None
        obs = self._observe()
        info = {"objects": [o.spec.name for o in self._scene.objects],
                "redraws": list(self._scene.redraws), **self._camera_info()}
        if self._label_scenes:
            self._label()
            info["positives"] = np.array([r.as_array() for r in self._positives],
                                         dtype=np.float32).reshape(-1, 5)
        return obs, info

    def step(self, action):
        if self._scene is None:
            raise RuntimeError("call reset() before step()")
        a = np.clip(np.asarray(action, dtype=np.float64).reshape(5),
                    self.action_space.low, self.action_space.high)
        rect = GraspRectangle(*a)
        f = self._frame
        grasp = harness_grasps([rect], f, self._scene.table_z, self._params)[0]
        if grasp.failure is None:
            bodies = build_scene(self.sim, self._scene)
            res = execute_grasp(self.sim, self._scene, bodies, grasp, self._params)
        else:  # nothing moves
            bodies, res = None, run_grasp(self.sim, self._scene, grasp, self._params)
        info = {
            "success": bool(res.success),
            "failure_reason": res.reason,
            "lift_height": float(res.lift_height),
            "gripper_pose": None if res.T_world_tcp is None else np.array(res.T_world_tcp),
            "object": None if res.object_index is None
            else self._scene.objects[res.object_index].spec.name,
        }
        if self._positives is not None:
            info["rectangle_metric"] = bool(rectangle_metric(rect, self._positives))
        reward = 1.0 if res.success else 0.0
        if not self.declutter:
            terminated = True
            obs = {
                "rgb": f.rgb.copy(),
                "depth": np.asarray(f.depth, dtype=np.float32).copy(),
                "depth_valid": np.asarray(f.depth_valid, dtype=np.uint8).copy(),
            }
            return obs, reward, terminated, False, info
        # Declutter: the grasped object leaves, objects pushed off the table too; the rest
        # settle where the grasp left them (the same update as graspsim.eval.declutter's rounds).
        names = [o.spec.name for o in self._scene.objects]
        self._scene, fell = scene_after_grasp(self.sim, self._scene, bodies, res)
        info["fell_off"] = [names[i] for i in fell]
        terminated = len(self._scene.objects) == 0
        obs = self._observe()
        info.update(self._camera_info())  # of the new observation
        if self._label_scenes and not terminated:
            self._label()
        return obs, reward, terminated, False, info

    def render(self):
        if self.render_mode == "rgb_array":
            return None if self._frame is None else self._frame.rgb.copy()
        return None

    def close(self):
        if getattr(self, "sim", None) is not None:
            self.sim.close()
            self.sim = None

"""Scenes: a table and one (Cornell-like) or several (clutter) objects dropped and settled.

A :class:`Scene` is a *description* -- which objects, at which settled poses, on which table --
not a live simulation. :func:`build_scene` turns it into bodies in a
:class:`~graspsim.sim.bullet.Simulation` from scratch (``resetSimulation`` then the same loads in
the
same order), so every grasp of a labelling run, every trial and every environment step starts
from exactly the same state.

Objects are dropped from just above the table at a random pose and stepped until at rest. An
object that rolls off the table or does not come to rest within ``settle_time`` is re-drawn
(another object and pose from the same generator) and the re-draw is logged and recorded in
``Scene.redraws``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from . import camera
from .objects import ObjectSpec, load_object

__all__ = [
    "PlacedObject",
    "Scene",
    "SceneBodies",
    "build_scene",
    "make_scene",
    "random_quaternion",
    "drop_orientation",
    "TABLE_HALF_SIZE",
    "TABLE_COLOURS",
    "table_colour",
    "capture",
    "settle",
    "scene_after_grasp",
    "off_table",
    "OFF_TABLE",
    "link_pose",
]

log = logging.getLogger(__name__)

TABLE_HALF_SIZE = 0.5  #: m, half the side of the square table top.
TABLE_THICKNESS = 0.04  #: m


@dataclass(frozen=True)
class PlacedObject:
    """An object at a settled pose (world frame; metres; quaternion x, y, z, w)."""

    spec: ObjectSpec
    position: tuple[float, float, float]
    orientation: tuple[float, float, float, float]


@dataclass
class Scene:
    """A table top (at ``table_z``) with settled objects.

    Attributes
    ----------
    objects : list of PlacedObject
    table_z : float
        Height of the table top, metres.
    table_rgba : tuple of 4 floats
    redraws : list of str
        One message per object that was re-drawn while making the scene.
    """

    objects: list[PlacedObject]
    table_z: float = 0.0
    table_rgba: tuple[float, float, float, float] = (0.55, 0.45, 0.35, 1.0)
    redraws: list[str] = field(default_factory=list)

    def without(self, index: int) -> Scene:
        """The same scene with object ``index`` removed."""
        objs = [o for i, o in enumerate(self.objects) if i != index]
        return Scene(objs, self.table_z, self.table_rgba, list(self.redraws))

    def to_dict(self) -> dict:
        return {
            "table_z": self.table_z,
            "objects": [
                {"name": o.spec.name, "position": [round(v, 6) for v in o.position],
                 "orientation": [round(v, 6) for v in o.orientation]}
                for o in self.objects
            ],
            "redraws": list(self.redraws),
        }


@dataclass
class SceneBodies:
    """Body ids of a built scene: the table, then one per object in ``Scene.objects`` order."""

    table: int
    objects: list[int]

    def materials(self, scene: Scene) -> dict[int, str]:
        """``{body_id: material}`` for the camera's depth-dropout model."""
        return {b: o.spec.material for b, o in zip(self.objects, scene.objects, strict=True)}


def random_quaternion(rng: np.random.Generator) -> tuple[float, float, float, float]:
    """A uniformly random rotation, quaternion (x, y, z, w)."""
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    return tuple(float(v) for v in q)


def drop_orientation(rng: np.random.Generator, upright: float = 0.5):
    """Upright with a random yaw (probability ``upright``), else a uniform random rotation."""
    if rng.random() < upright:
        yaw = rng.uniform(-np.pi, np.pi)
        return (0.0, 0.0, float(np.sin(yaw / 2)), float(np.cos(yaw / 2)))
    return random_quaternion(rng)


TABLE_COLOURS = ("random", "grey")


def table_colour(draws, table: str = "random") -> tuple[float, float, float, float]:
    """RGBA of the table top from three uniform draws in 0.25-0.75 (see :func:`make_scene`).

    Parameters
    ----------
    draws : (3,) array of float
    table : {"random", "grey"}

    Returns
    -------
    tuple of 4 floats
    """
    if table not in TABLE_COLOURS:
        raise ValueError(f"unknown table colour {table!r}; use one of {TABLE_COLOURS}")
    d = [float(v) for v in draws]
    if table == "grey":
        level = 0.6 + 0.2 * (sum(d) / 3.0 - 0.25) / 0.5
        return (level, level, level, 1.0)
    return (d[0], d[1], d[2], 1.0)


def _add_table(sim, table_z: float, rgba) -> int:
    c = sim.client
    half = [TABLE_HALF_SIZE, TABLE_HALF_SIZE, TABLE_THICKNESS / 2]
    col = c.createCollisionShape(c.GEOM_BOX, halfExtents=half)
    vis = c.createVisualShape(c.GEOM_BOX, halfExtents=half, rgbaColor=list(rgba))
    body = c.createMultiBody(0.0, col, vis, [0.0, 0.0, table_z - TABLE_THICKNESS / 2])
    c.changeDynamics(body, -1, lateralFriction=0.8, spinningFriction=0.001,
                     rollingFriction=0.0001)
    return body


def build_scene(sim, scene: Scene) -> SceneBodies:
    """Rebuild ``scene`` in ``sim`` from scratch (``resetSimulation`` first); deterministic."""
    sim.reset()
    table = _add_table(sim, scene.table_z, scene.table_rgba)
    bodies = [load_object(sim.client, o.spec, o.position, o.orientation) for o in scene.objects]
    return SceneBodies(table, bodies)


def _at_rest(client, body, lin_tol=0.005, ang_tol=0.05) -> bool:
    lin, ang = client.getBaseVelocity(body)
    return float(np.linalg.norm(lin)) < lin_tol and float(np.linalg.norm(ang)) < ang_tol


def settle(sim, bodies, max_time: float = 3.0, check_every: int = 12, quiet_checks: int = 3):
    """Step until every body is at rest for ``quiet_checks`` checks in a row.

    Returns
    -------
    bool
        True when the bodies came to rest within ``max_time`` seconds.
    """
    n_max = int(round(max_time / sim.time_step))
    quiet = 0
    for _ in range(0, n_max, check_every):
        sim.step(check_every)
        if all(_at_rest(sim.client, b) for b in bodies):
            quiet += 1
            if quiet >= quiet_checks:
                return True
        else:
            quiet = 0
    return False


def link_pose(client, body):
    """Pose of the base *link* frame (what ``loadURDF`` takes), not of its centre of mass.

    ``getBasePositionAndOrientation`` reports the inertial frame; reloading a body at that pose
    would shift it by the URDF's inertial origin.
    """
    pos, orn = client.getBasePositionAndOrientation(body)
    info = client.getDynamicsInfo(body, -1)
    inv_pos, inv_orn = client.invertTransform(info[3], info[4])
    pos, orn = client.multiplyTransforms(pos, orn, inv_pos, inv_orn)
    return tuple(float(v) for v in pos), tuple(float(v) for v in orn)


def _drop_height(spec: ObjectSpec) -> float:
    return 0.5 * float(np.linalg.norm(spec.size)) * spec.scale + 0.005


def make_scene(
    sim,
    specs: list[ObjectSpec],
    rng: np.random.Generator,
    n_objects: int = 1,
    spread: float = 0.05,
    table_z: float = 0.0,
    settle_time: float = 3.0,
    max_redraws: int = 20,
    upright: float = 0.5,
    table: str = "random",
    restarts: int = 3,
) -> Scene:
    """Drop objects one by one at random poses and let them settle.

    Parameters
    ----------
    sim : graspsim.sim.bullet.Simulation
    specs : list of ObjectSpec
        Objects to draw from (uniformly, with replacement).
    rng : numpy.random.Generator
        Every random value is drawn from it.
    n_objects : int
        1 for a Cornell-like scene, more for clutter.
    spread : float
        Half side of the square (centred under the camera) the objects are dropped in, metres.
    table_z : float
    settle_time : float
        Seconds of simulation after which an object that still moves is re-drawn.
    max_redraws : int
        Re-draws of an object that does not rest before the pile is started again.
    upright : float
        Probability of dropping an object in its modelled (upright) orientation with a random
        yaw, as people place objects for a Cornell-like picture; otherwise the orientation is
        uniformly random.
    table : {"random", "grey"}
        The table top's colour: ``"random"``, each channel uniform in 0.25-0.75 (muted
        colours); ``"grey"``, a light grey of level 0.6-0.8 (like Jacquard's renders) made from
        the same three draws (their mean, rescaled), so the objects and poses do not change.
    restarts : int
        Times the pile is started again from an empty table (with the next draws of ``rng``)
        when an object still does not rest after ``max_redraws`` re-draws: in a pile, an object
        already placed can keep every new one from settling. A scene that needs no restart
        is the same whatever ``restarts`` is.

    Returns
    -------
    Scene
        Its ``redraws`` list every re-draw and restart.

    Raises
    ------
    ValueError
        When the pile could not be made in ``restarts + 1`` attempts (the message says which
        object moved last).
    """
    if not specs:
        raise ValueError("make_scene needs at least one object spec")
    if n_objects < 1:
        raise ValueError(f"n_objects must be >= 1, got {n_objects}")
    hue = rng.uniform(0.25, 0.75, size=3)
    scene = Scene([], table_z, table_colour(hue, table))
    redraws, restarted = 0, 0
    while len(scene.objects) < n_objects:
        spec = specs[int(rng.integers(len(specs)))]
        xy = rng.uniform(-spread, spread, size=2)
        orn = drop_orientation(rng, upright)
        pos = (float(xy[0]), float(xy[1]), table_z + _drop_height(spec))
        trial = Scene(scene.objects + [PlacedObject(spec, pos, orn)], table_z, scene.table_rgba)
        bodies = build_scene(sim, trial)
        rested = settle(sim, bodies.objects, max_time=settle_time)
        poses = [link_pose(sim.client, b) for b in bodies.objects]
        off = [
            i for i, (p, _) in enumerate(poses)
            if max(abs(p[0]), abs(p[1])) > TABLE_HALF_SIZE - 0.02 or p[2] < table_z
        ]
        if rested and not off:
            scene.objects = [
                PlacedObject(o.spec, p, q) for o, (p, q) in zip(trial.objects, poses, strict=True)
            ]
            continue
        why = "rolled off the table" if off else f"did not settle within {settle_time} s"
        msg = f"object {spec.name!r} {why}; re-drawn"
        log.info(msg)
        scene.redraws.append(msg)
        redraws += 1
        if redraws > max_redraws:
            if restarted >= restarts:
                raise ValueError(f"could not make a scene: {redraws} re-draws in each of "
                                 f"{restarted + 1} attempts (last: {msg})")
            restarted += 1
            msg = (f"{redraws} re-draws without a rest ({spec.name!r} last); the pile is "
                   f"started again ({restarted} of {restarts})")
            log.info(msg)
            scene.redraws.append(msg)
            scene.objects, redraws = [], 0
    return scene


def capture(sim, scene: Scene, bodies: SceneBodies, rng: np.random.Generator, noise=None,
            intrinsics=None, height=(0.6, 0.8), table_texture: bool = False, lighting=None):
    """Render the built scene from a random look-down camera pose.

    Parameters
    ----------
    sim : graspsim.sim.bullet.Simulation
    scene : Scene
    bodies : SceneBodies
    rng : numpy.random.Generator
        Draws the camera pose, then the camera's lights and noise.
    noise : graspsim.sim.camera.DepthNoise or None
        None: the camera's default (Kinect-like) noise.
    intrinsics : graspsim.sim.camera.CameraIntrinsics or None
    height : (float, float)
        Camera height range above the table, metres.
    table_texture : bool
        Put a random texture (wood, checker, speckle, plain) on the table first. Off by default:
        pybullet 3.2.7's TinyRenderer keeps showing the first texture a client loaded after
        ``resetSimulation`` (texture ids restart, its cache does not), so textures would make a
        frame depend on what the same simulator rendered before. The table colour (drawn by
        :func:`make_scene`) and the lights still vary.
    lighting : graspsim.sim.camera.LightRanges or None
        The ranges the lights are drawn from (None: the camera's default).

    Returns
    -------
    RGBDFrame
    """
    intr = camera.CameraIntrinsics() if intrinsics is None else intrinsics
    T = camera.look_down_pose(rng, height=height, table_z=scene.table_z)
    if table_texture:
        camera.random_table_texture(sim.client, rng, body=bodies.table)
    kwargs = {"materials": bodies.materials(scene), "lighting": lighting}
    if noise is not None:
        kwargs["noise"] = noise
    return camera.Camera(sim.client, intr).render(T, rng, **kwargs)


#: An object whose base link ends farther than this from the table centre (x or y, metres), or
#: below the table top, has left the table.
OFF_TABLE = TABLE_HALF_SIZE - 0.05


def off_table(position, table_z: float) -> bool:
    """Whether a body at ``position`` ((3,) metres, world frame) has left a table whose top is
    at ``table_z``: beyond :data:`OFF_TABLE` in x or y, or below the top.

    Parameters
    ----------
    position : array-like of shape (3,)
    table_z : float

    Returns
    -------
    bool
    """
    return max(abs(position[0]), abs(position[1])) > OFF_TABLE or position[2] < table_z - 0.01


def scene_after_grasp(sim, scene: Scene, bodies, result, settle_time: float = 2.0):
    """The scene an executed grasp leaves: the lifted object gone, fallen objects gone, the
    others settled where the grasp left them.

    Parameters
    ----------
    sim : graspsim.sim.bullet.Simulation
        Still holding the bodies of the grasp, as :func:`graspsim.sim.execution.execute_grasp`
        left them.
    scene : Scene
        The scene the grasp was executed in.
    bodies : SceneBodies or None
        Its bodies; None when the gripper never moved (the scene is returned unchanged).
    result : GraspResult
    settle_time : float
        Seconds of simulation for the remaining objects to come to rest.

    Returns
    -------
    scene : Scene
        The remaining objects at rest (the simulator then holds them, built anew).
    fell : list of int
        Indices into ``scene.objects`` of the objects that left the table (never the grasped
        one on a success).
    """
    if bodies is None:
        return scene, []
    c = sim.client
    kept, fell = [], []
    for i, (o, b) in enumerate(zip(scene.objects, bodies.objects, strict=True)):
        if result is not None and result.success and i == result.object_index:
            continue
        pos, orn = link_pose(c, b)
        if off_table(pos, scene.table_z):
            fell.append(i)
            continue
        kept.append((i, PlacedObject(o.spec, pos, orn)))
    left = []
    if kept:
        rest = Scene([o for _, o in kept], scene.table_z, scene.table_rgba)
        new_bodies = build_scene(sim, rest)
        settle(sim, new_bodies.objects, max_time=settle_time)
        for (i, o), b in zip(kept, new_bodies.objects, strict=True):
            pos, orn = link_pose(c, b)
            if off_table(pos, scene.table_z):
                fell.append(i)
            else:
                left.append(PlacedObject(o.spec, pos, orn))
    return Scene(left, scene.table_z, scene.table_rgba, list(scene.redraws)), sorted(fell)

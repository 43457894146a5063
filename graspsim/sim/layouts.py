"""Scene protocols: how the objects of a trial, a clutter round or an episode are put on the table.

* ``"drop"`` (the default, what every campaign before this option ran): objects dropped one by
  one from just above the table at random poses (upright with a random yaw half of the time)
  and each settled (:func:`graspsim.sim.scene.make_scene`); with one object, the isolated scene.
* ``"isolated"``: the same as ``"drop"`` with exactly one object (more is refused), so the
  scenes of a seed are those of ``"drop"``.
* ``"packed"``: VGN's and GIGA's packed scene (Breyer et al., CoRL 2020; Jiang et al., RSS
  2021): objects stood upright (their modelled orientation, a random yaw) side by side on the
  table, each at a random place in a square of ``PACKED_HALF_SIDE`` half side where it does not
  overlap the ones already there, then settled; a draw that overlaps, tips over or pushes another
  object over is re-drawn (:func:`make_packed_scene`).
* ``"pile"``: VGN's and GIGA's pile: objects dropped one by one at random orientations into an
  open box standing on the table, each settled, then the box is removed and the heap settles on
  the table (:func:`make_pile_scene`).

Every random value comes from the generator passed in, so a scene depends only on it. The result
is a :class:`graspsim.sim.scene.Scene` (objects at settled poses, no box), rebuilt by
:func:`graspsim.sim.scene.build_scene` like any other.
"""

from __future__ import annotations

import logging

import numpy as np

from .objects import ObjectSpec
from .scene import (
    TABLE_HALF_SIZE,
    PlacedObject,
    Scene,
    build_scene,
    link_pose,
    make_scene,
    random_quaternion,
    settle,
    table_colour,
)

__all__ = [
    "SCENES",
    "DEFAULT_SCENE",
    "PACKED_HALF_SIDE",
    "PILE_BOX_HALF_SIDE",
    "PILE_BOX_HEIGHT",
    "check_scene",
    "make_packed_scene",
    "make_pile_scene",
    "make_scene_of",
    "tilt",
    "default_objects_per_scene",
]

log = logging.getLogger(__name__)

SCENES = ("drop", "isolated", "packed", "pile")
DEFAULT_SCENE = "drop"
#: m, half side of the square the packed objects' centres are drawn in (a 24 cm square; VGN's
#: packed objects are placed in the middle 14 cm of its 30 cm workspace, with smaller objects).
PACKED_HALF_SIDE = 0.12
#: m, inner half side of the pile's box (VGN drops into a box scaled to about 16 cm).
PILE_BOX_HALF_SIDE = 0.08
#: m, height of the pile box's walls above the table.
PILE_BOX_HEIGHT = 0.12
#: m, thickness of the pile box's walls.
PILE_WALL = 0.01
#: degrees: a packed object whose vertical axis leans more than this has tipped over.
MAX_TILT = 15.0


def default_objects_per_scene(kind: str, clutter: bool = False) -> int:
    """Objects per scene when none is asked for: 5 in packed and pile scenes and in clutter
    (declutter) rounds, as VGN and GIGA use, else 1 (Cornell-like)."""
    return 5 if clutter or kind in ("packed", "pile") else 1


def check_scene(kind: str, n_objects: int = 1) -> str:
    """Validate a scene protocol for ``n_objects`` objects; returns ``kind``.

    Raises
    ------
    ValueError
        One line: an unknown protocol (the message lists them), or ``"isolated"`` with more
        than one object.
    """
    if kind not in SCENES:
        raise ValueError(f"unknown scene {kind!r}; use one of {', '.join(SCENES)}")
    if kind == "isolated" and n_objects != 1:
        raise ValueError(f"the isolated scene has one object, got {n_objects} objects per scene "
                         "(use --scene drop, packed or pile for clutter)")
    return kind


def tilt(orientation) -> float:
    """Angle (degrees) between a body's vertical axis and the world's, for an (x, y, z, w)
    quaternion."""
    x, y, _, _ = (float(v) for v in orientation)
    zz = 1.0 - 2.0 * (x * x + y * y)  # the (2, 2) entry of the rotation matrix
    return float(np.degrees(np.arccos(np.clip(zz, -1.0, 1.0))))


def _yaw_quaternion(rng: np.random.Generator) -> tuple[float, float, float, float]:
    yaw = rng.uniform(-np.pi, np.pi)
    return (0.0, 0.0, float(np.sin(yaw / 2)), float(np.cos(yaw / 2)))


def _bottom_offset(sim, spec: ObjectSpec) -> float:
    """Height of the link frame above the lowest point of the object, upright (metres)."""
    sim.reset()
    body = sim.client.loadURDF(str(spec.urdf), [0, 0, 1.0], [0, 0, 0, 1],
                               globalScaling=spec.scale)
    low = sim.client.getAABB(body)[0][2]
    return 1.0 - float(low)


def _on_table(position, table_z: float) -> bool:
    return max(abs(position[0]), abs(position[1])) <= TABLE_HALF_SIZE - 0.02 and (
        position[2] >= table_z - 0.01)


def make_packed_scene(sim, specs: list[ObjectSpec], rng: np.random.Generator,
                      n_objects: int = 5, table_z: float = 0.0, table: str = "random",
                      half_side: float = PACKED_HALF_SIDE, max_attempts: int = 100,
                      settle_time: float = 3.0, gap: float = 0.002,
                      max_tilt: float = MAX_TILT) -> Scene:
    """VGN's packed scene: upright objects side by side on the table, without overlap.

    Objects are drawn uniformly with replacement from ``specs``. Each is stood upright (its
    modelled orientation with a uniform yaw) with its lowest point ``gap`` above the table, its
    link frame at a uniform place in ``[-half_side, half_side]^2``; a place where it comes within
    ``gap`` of an object already there is re-drawn without stepping. The table is then stepped
    until every object is at rest; a draw after which an object leans more than ``max_tilt``
    degrees, has not come to rest within ``settle_time`` seconds or left the table is
    re-drawn too (another object and place).

    Parameters
    ----------
    sim : graspsim.sim.bullet.Simulation
    specs : list of ObjectSpec
    rng : numpy.random.Generator
        Every random value is drawn from it (the table colour first, as
        :func:`graspsim.sim.scene.make_scene`).
    n_objects : int
    table_z : float
    table : {"random", "grey"}
    half_side : float
        Metres.
    max_attempts : int
        Draws for one object before the scene is given up.
    settle_time, gap, max_tilt : float
        Seconds, metres, degrees.

    Returns
    -------
    Scene
        ``redraws`` lists every re-draw.

    Raises
    ------
    ValueError
        When an object cannot be placed in ``max_attempts`` draws (more objects than fit in the
        square), naming it and the square.
    """
    _check_common(specs, n_objects)
    c = sim.client
    scene = Scene([], table_z, table_colour(rng.uniform(0.25, 0.75, size=3), table))
    offsets: dict[str, float] = {}
    while len(scene.objects) < n_objects:
        for _ in range(max_attempts):
            spec = specs[int(rng.integers(len(specs)))]
            xy = rng.uniform(-half_side, half_side, size=2)
            orn = _yaw_quaternion(rng)
            if spec.name not in offsets:
                offsets[spec.name] = _bottom_offset(sim, spec)
            pos = (float(xy[0]), float(xy[1]), table_z + offsets[spec.name] + gap)
            trial = Scene(scene.objects + [PlacedObject(spec, pos, orn)], table_z,
                          scene.table_rgba)
            bodies = build_scene(sim, trial)
            new = bodies.objects[-1]
            if any(c.getClosestPoints(new, b, gap) for b in bodies.objects[:-1]):
                why = "overlaps an object already placed"
            else:
                rested = settle(sim, bodies.objects, max_time=settle_time)
                poses = [link_pose(c, b) for b in bodies.objects]
                if not rested:
                    why = f"did not settle within {settle_time} s"
                elif any(tilt(q) > max_tilt for _, q in poses):
                    why = f"tipped over (more than {max_tilt:g} degrees)"
                elif not all(_on_table(p, table_z) for p, _ in poses):
                    why = "left the table"
                else:
                    scene.objects = [PlacedObject(o.spec, p, q)
                                     for o, (p, q) in zip(trial.objects, poses, strict=True)]
                    break
            msg = f"packed: object {spec.name!r} {why}; re-drawn"
            log.debug(msg)
            scene.redraws.append(msg)
        else:
            raise ValueError(
                f"packed scene: object {len(scene.objects) + 1} of {n_objects} could not be "
                f"placed upright without overlap in {max_attempts} draws in the "
                f"{200 * half_side:.0f} cm square (last: {spec.name!r} {why}); use fewer "
                "objects per scene")
    return scene


def _add_box(sim, table_z: float, half_side: float, height: float) -> list[int]:
    """Four static walls of an open box standing on the table, centred on the origin."""
    c = sim.client
    walls = []
    t = PILE_WALL / 2
    for axis in (0, 1):
        for sign in (-1.0, 1.0):
            half = [half_side + PILE_WALL, t, height / 2] if axis else [t, half_side + PILE_WALL,
                                                                         height / 2]
            pos = [0.0, 0.0, table_z + height / 2]
            pos[axis] = sign * (half_side + t)
            col = c.createCollisionShape(c.GEOM_BOX, halfExtents=half)
            walls.append(c.createMultiBody(0.0, col, -1, pos))
    return walls


def make_pile_scene(sim, specs: list[ObjectSpec], rng: np.random.Generator,
                    n_objects: int = 5, table_z: float = 0.0, table: str = "random",
                    box_half_side: float = PILE_BOX_HALF_SIDE, box_height: float = PILE_BOX_HEIGHT,
                    settle_time: float = 3.0, max_redraws: int = 20,
                    restarts: int = 3) -> Scene:
    """VGN's pile: objects dropped into a box on the table, then the box removed.

    An open box (inner side ``2 box_half_side``, walls ``box_height`` high) stands on the table
    centre. Objects, drawn uniformly with replacement from ``specs``, are dropped one by one at
    a uniformly random orientation from above the walls, their centre at a uniform place in the
    middle half of the box, and the box's content is stepped until at rest (an object that
    does not rest within ``settle_time`` is re-drawn). The box is then removed and the heap
    stepped until at rest on the table; when an object leaves the table then, or does not rest,
    the pile is started again with the next draws.

    Parameters
    ----------
    sim : graspsim.sim.bullet.Simulation
    specs : list of ObjectSpec
    rng : numpy.random.Generator
        Every random value is drawn from it (the table colour first).
    n_objects : int
    table_z : float
    table : {"random", "grey"}
    box_half_side, box_height : float
        Metres.
    settle_time : float
        Seconds.
    max_redraws, restarts : int
        As :func:`graspsim.sim.scene.make_scene`.

    Returns
    -------
    Scene
        The heap at rest without the box; ``redraws`` lists every re-draw and restart.

    Raises
    ------
    ValueError
        When no pile could be made in ``restarts + 1`` attempts.
    """
    _check_common(specs, n_objects)
    c = sim.client
    scene = Scene([], table_z, table_colour(rng.uniform(0.25, 0.75, size=3), table))
    redraws: list[str] = []
    for start in range(restarts + 1):
        placed: list[PlacedObject] = []
        failed = None
        while len(placed) < n_objects and failed is None:
            for _ in range(max_redraws + 1):
                spec = specs[int(rng.integers(len(specs)))]
                xy = rng.uniform(-box_half_side / 2, box_half_side / 2, size=2)
                orn = random_quaternion(rng)
                radius = 0.5 * float(np.linalg.norm(spec.size)) * spec.scale
                pos = (float(xy[0]), float(xy[1]), table_z + box_height + radius + 0.01)
                trial = Scene(placed + [PlacedObject(spec, pos, orn)], table_z, scene.table_rgba)
                bodies = build_scene(sim, trial)
                _add_box(sim, table_z, box_half_side, box_height)
                if settle(sim, bodies.objects, max_time=settle_time):
                    placed = [PlacedObject(o.spec, *link_pose(c, b))
                              for o, b in zip(trial.objects, bodies.objects, strict=True)]
                    break
                msg = f"pile: object {spec.name!r} did not settle in the box; re-drawn"
                log.debug(msg)
                redraws.append(msg)
            else:
                failed = f"{max_redraws} re-draws of one object without a rest"
        if failed is None:
            heap = Scene(placed, table_z, scene.table_rgba)
            bodies = build_scene(sim, heap)  # the box is gone
            rested = settle(sim, bodies.objects, max_time=settle_time)
            poses = [link_pose(c, b) for b in bodies.objects]
            if rested and all(_on_table(p, table_z) for p, _ in poses):
                return Scene([PlacedObject(o.spec, p, q)
                              for o, (p, q) in zip(placed, poses, strict=True)],
                             table_z, scene.table_rgba, redraws)
            failed = ("an object left the table" if rested
                      else f"the heap did not settle within {settle_time} s")
            failed += " when the box was removed"
        msg = f"pile: {failed}; the pile is started again ({start + 1} of {restarts})"
        log.info(msg)
        redraws.append(msg)
    raise ValueError(f"could not make a pile of {n_objects} objects in {restarts + 1} attempts "
                     f"(last: {failed})")


def _check_common(specs, n_objects: int) -> None:
    if not specs:
        raise ValueError("a scene needs at least one object spec")
    if isinstance(n_objects, bool) or not isinstance(n_objects, (int, np.integer)) or (
            n_objects < 1):
        raise ValueError(f"n_objects must be an integer >= 1, got {n_objects!r}")


def make_scene_of(kind: str, sim, specs: list[ObjectSpec], rng: np.random.Generator,
                  n_objects: int = 1, table: str = "random", **drop) -> Scene:
    """A scene of the protocol ``kind`` (see the module docstring).

    Parameters
    ----------
    kind : {"drop", "isolated", "packed", "pile"}
    sim : graspsim.sim.bullet.Simulation
    specs : list of ObjectSpec
    rng : numpy.random.Generator
    n_objects : int
    table : {"random", "grey"}
    **drop
        Keyword arguments of :func:`graspsim.sim.scene.make_scene` (``spread``, ...) for
        ``"drop"`` and ``"isolated"``; ignored by the others.

    Returns
    -------
    Scene
    """
    check_scene(kind, n_objects)
    if kind in ("drop", "isolated"):
        return make_scene(sim, specs, rng, n_objects=n_objects, table=table, **drop)
    if kind == "packed":
        return make_packed_scene(sim, specs, rng, n_objects=n_objects, table=table)
    return make_pile_scene(sim, specs, rng, n_objects=n_objects, table=table)

"""Executing a grasp with the floating gripper and scoring it by physics.

Sequence (VGN-like, 1/240 s steps):

1. the scene is rebuilt from its description (:func:`graspsim.sim.scene.build_scene`);
2. the gripper appears at the pre-grasp pose, 10 cm back along the approach, open to the grasp's
   opening (a teleport in free space; if it already overlaps something that is a collision);
3. approach: the base constraint's target moves to the grasp pose at ``approach_speed``; any
   contact aborts with ``"collision on approach"``;
4. close: the fingers are commanded shut and squeeze with their force limit until they stop;
   an object must touch both fingers, else ``"nothing between the jaws"``;
5. lift 15 cm straight up at ``lift_speed``, then hold 1 s;
6. success = that object is at least 10 cm above its start **and** touches both fingers;
   otherwise ``"slipped during lift"``.

The pre-grasp teleport and the brisk motions (a constraint with a bounded ``maxForce`` moving its
target several millimetres per step) replace a slow arm trajectory; contacts stay physical.

The grasp is moved back along its approach until the fingertips are at least ``tip_clearance``
(1 mm) above the table (a robot knows its table plane); the approach direction is unchanged. With
3 mm the pads ended above the lower edge of anything thinner than about 8 mm lying on the table
(pybullet also keeps resting bodies about 1 mm above it) and their tip edge pressed the object's
lower flank, squeezing a 6.4 mm stick down and out from under the fingertips.

Where the fingers would meet a surface above the table on the way down -- the plate or the bowl
a small object rests on in a pile, the floor of a bowl under the inner finger of a rim grasp --
the harness's poses (:func:`harness_grasps`, with ``ExecutionParams.min_grip`` set) stop them
2 mm short of it, if the fingertips still reach ``min_grip`` beyond the surface under the
rectangle's centre (:func:`graspsim.sim.grasp.settle_fingers`; the gripper-aware detectors judge
their rectangles the same way). Otherwise the grasp comes down as far as before and meets it.

Labelling many candidates in one scene has a faster path (:func:`precheck_grasps`, used by
:func:`graspsim.labels.labelling.label_rectangles`): with the scene built once and the open gripper
moved kinematically (no physics step), a grasp whose jaws would pass through something on the
way in is a ``"collision on approach"`` and one whose way in is clear while the space between
the open pads holds no object is ``"nothing between the jaws"`` -- both decided with geometric
margins so that the full execution could not disagree. Every other grasp is executed as above.
With ``ExecutionParams(hold_until_still=True)`` the 1 s hold ends early once the object has
stopped moving in the hand.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields

import numpy as np

from .grasp import Grasp, rectangle_to_grasp, settle_fingers, table_plane_depth
from .gripper import Gripper, GripperParams, hand_params, pose_from_matrix
from .hands import BUILTIN
from .scene import Scene, SceneBodies, build_scene

__all__ = [
    "ExecutionParams",
    "GraspResult",
    "describe_changes",
    "execution_changes",
    "execution_params_from_dict",
    "execute_grasp",
    "harness_grasps",
    "precheck_grasps",
    "run_grasp",
    "COLLISION",
    "NOTHING",
    "SLIPPED",
]

COLLISION = "collision on approach"
NOTHING = "nothing between the jaws"
SLIPPED = "slipped during lift"


@dataclass(frozen=True)
class ExecutionParams:
    """Motion parameters (metres, seconds, m/s).

    ``hold_until_still`` (off by default) ends the hold early, as a success, once the lifted
    object is at least ``success_height`` up, touches both fingers and has moved less than
    ``still_tolerance`` metres relative to the TCP between ``still_checks`` consecutive checks
    (one every 0.1 s); otherwise the hold lasts ``hold_time``.

    ``min_grip`` (metres; None, the default, turns it off): fingers that would meet a surface
    above the table on the way down stop 2 mm short of it when they still reach this far beyond
    the surface under the rectangle's centre (:func:`harness_grasps`). Not adopted as the
    default: on validation scenes of the train objects it changed nothing on single objects
    and removed no more objects in clutter (README, "Clutter removal").
    """

    pregrasp_distance: float = 0.10
    approach_speed: float = 0.5
    lift_height: float = 0.15
    lift_speed: float = 0.5
    hold_time: float = 1.0
    close_time: float = 0.6
    success_height: float = 0.10
    tip_clearance: float = 0.001
    arrive_steps: int = 48
    gripper: GripperParams = field(default_factory=GripperParams)
    hold_until_still: bool = False
    still_tolerance: float = 2e-4
    still_checks: int = 2
    min_grip: float | None = None

    @classmethod
    def with_hand(cls, hand: str = "builtin", **fields) -> ExecutionParams:
        """The parameters with ``hand``'s gripper (:func:`graspsim.sim.gripper.hand_params`: a name
        of :data:`graspsim.sim.hands.HAND_NAMES`; an unknown name is a ValueError) and ``fields``
        set."""
        return cls(gripper=hand_params(hand), **fields)

    def __post_init__(self):
        if self.min_grip is not None and not float(self.min_grip) >= 0:
            raise ValueError(f"ExecutionParams.min_grip must be None or >= 0 metres, "
                             f"got {self.min_grip!r}")


def execution_params_from_dict(d, where: str) -> ExecutionParams:
    """The :class:`ExecutionParams` that ``dataclasses.asdict`` (as saved in JSON) describes.

    Fields ``d`` lacks take their defaults (a file written before the field existed ran with
    it); a field this version does not know, or a value it refuses, is a ValueError naming
    ``where`` (the file).

    Parameters
    ----------
    d : dict
    where : str

    Returns
    -------
    ExecutionParams
    """
    if not isinstance(d, dict) or not isinstance(d.get("gripper", {}), dict):
        raise ValueError(f"{where}: the execution parameters are not a JSON object of "
                         f"ExecutionParams fields (got {d!r:.80})")
    d = dict(d)
    try:
        if "gripper" in d:
            d["gripper"] = GripperParams(**d["gripper"])
        return ExecutionParams(**d)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{where}: the execution parameters do not match this graspsim's "
                         f"ExecutionParams ({exc})") from None


def execution_changes(params: ExecutionParams | None) -> dict:
    """The fields of ``params`` that differ from the defaults, ``{name: value}``.

    A gripper field is named ``gripper.<field>``; None (the defaults) gives ``{}``.
    """
    if params is None:
        return {}
    default, out = ExecutionParams(), {}
    for f in fields(ExecutionParams):
        a, b = getattr(params, f.name), getattr(default, f.name)
        if f.name == "gripper":
            ga, gb = asdict(a), asdict(b)
            out.update({f"gripper.{k}": v for k, v in ga.items() if v != gb[k]})
        elif a != b:
            out[f.name] = a
    return out


def describe_changes(changes: dict) -> str:
    """:func:`execution_changes` as text: ``"min_grip = 0.01, ..."``, or ``"the defaults"``."""
    return ", ".join(f"{k} = {v}" for k, v in changes.items()) or "the defaults"


@dataclass
class GraspResult:
    """Outcome of one executed grasp.

    Attributes
    ----------
    success : bool
    reason : str or None
        Failure reason; None on success.
    lift_height : float
        Metres the grasped object rose above its start (0 when nothing was grasped).
    object_index : int or None
        Index into ``Scene.objects`` of the object between the jaws.
    T_world_tcp : ndarray of shape (4, 4) or None
        The executed grasp pose (after the table clamp).
    frames : list of ndarray
        Snapshots (only when ``record`` was given).
    steps : int
        Physics steps taken.
    """

    success: bool
    reason: str | None
    lift_height: float = 0.0
    object_index: int | None = None
    T_world_tcp: np.ndarray | None = None
    frames: list = field(default_factory=list)
    steps: int = 0

    def to_dict(self) -> dict:
        return {
            "success": bool(self.success),
            "reason": self.reason,
            "lift_height": round(float(self.lift_height), 6),
            "object_index": self.object_index,
            "T_world_tcp": None if self.T_world_tcp is None
            else np.round(self.T_world_tcp, 6).tolist(),
        }


def clamp_to_table(T_world_grasp, table_z: float, clearance: float = 0.001,
                   opening: float = 0.08, geometry=None) -> np.ndarray:
    """Move the grasp back along its approach until the fingertips clear the table.

    The fingertips lie ``tip_offset`` beyond the TCP; the pads are ``pad_width`` wide (grasp y)
    and their outer faces ``opening / 2 + finger_thickness`` from the centre (grasp x), so the
    lowest pad corner is bounded with the tilt of the approach (``geometry``, a
    :class:`graspsim.sim.hands.HandGeometry`; None: the built-in hand's 1 cm, 2 cm and 8 mm).
    """
    hand = BUILTIN if geometry is None else geometry
    T = np.array(T_world_grasp, dtype=float)
    a = T[:3, 2]
    half_x = opening / 2 + hand.finger_thickness
    lowest = (T[2, 3] + hand.tip_offset * a[2] - hand.pad_width / 2 * abs(T[2, 1])
              - half_x * abs(T[2, 0]))
    gap = lowest - (table_z + clearance)
    if gap < 0 and a[2] < -1e-6:
        T[:3, 3] += (gap / -a[2]) * a  # gap < 0, -a[2] > 0: move back against the approach
    return T


def harness_grasps(rects, frame, table_z: float, params: ExecutionParams | None = None,
                   depth=None, depth_valid=None, **pose) -> list[Grasp]:
    """The poses the harness executes for image rectangles seen in ``frame``.

    Each rectangle becomes a pose by :func:`graspsim.sim.grasp.rectangle_to_grasp` for the hand of
    ``params.gripper`` (its geometry and largest opening); when
    ``params.min_grip`` is set, fingers that would meet a surface above the table on the way
    down stop short of it if they still grip that much of the object
    (:func:`graspsim.sim.grasp.settle_fingers`, with the table plane at ``table_z``).

    Parameters
    ----------
    rects : sequence of GraspRectangle
    frame : graspsim.sim.camera.Frame
        Its ``depth``, ``depth_valid``, ``intrinsics`` and ``T_world_cam``.
    table_z : float
        The table top's height in the world, metres (``Scene.table_z``).
    params : ExecutionParams or None
    depth, depth_valid : ndarray of shape (H, W) or None
        Depth to compute the poses from instead of the frame's (e.g. ``frame.depth_clean``).
    **pose
        Keyword arguments of :func:`graspsim.sim.grasp.rectangle_to_grasp` (``depth_offset``,
        ``margin``, ...).

    Returns
    -------
    list of Grasp
    """
    p = ExecutionParams() if params is None else params
    depth = frame.depth if depth is None else depth
    valid = frame.depth_valid if depth_valid is None else depth_valid
    hand = p.gripper.geometry
    pose = {"max_opening": hand.max_opening, **pose}
    grasps = [rectangle_to_grasp(r, depth, valid, frame.intrinsics, frame.T_world_cam,
                                 geometry=hand, **pose)
              for r in rects]
    if p.min_grip is None or not grasps:
        return grasps
    table = table_plane_depth(frame.intrinsics, frame.T_world_cam, table_z, np.shape(depth))
    return [settle_fingers(g, depth, valid, frame.intrinsics, frame.T_world_cam, table,
                           min_grip=p.min_grip, tip_clearance=p.tip_clearance, geometry=hand)
            for g in grasps]


def _move(sim, gripper: Gripper, start, goal, speed: float, check=None):
    """Move the base target linearly from ``start`` to ``goal``; ``check()`` after every step."""
    start, goal = np.asarray(start, float), np.asarray(goal, float)
    n = max(int(np.ceil(np.linalg.norm(goal - start) / (speed * sim.time_step))), 1)
    for i in range(1, n + 1):
        gripper.set_target(start + (goal - start) * (i / n))
        sim.step()
        if check is not None and check():
            return True
    return False


def execute_grasp(sim, scene: Scene, bodies: SceneBodies, grasp: Grasp,
                  params: ExecutionParams | None = None, record=None) -> GraspResult:
    """Execute ``grasp`` in the already built scene (``bodies``); see the module docstring.

    Parameters
    ----------
    sim : graspsim.sim.bullet.Simulation
    scene : Scene
    bodies : SceneBodies
        As returned by :func:`graspsim.sim.scene.build_scene` for ``scene``.
    grasp : Grasp
    params : ExecutionParams or None
    record : callable or None
        ``record(phase)`` is called at the end of each phase ("pregrasp", "approach", "close",
        "lift", "hold"); its return values are collected in ``GraspResult.frames``.
    """
    p = ExecutionParams() if params is None else params
    if grasp.failure is not None:
        return GraspResult(False, grasp.failure, T_world_tcp=grasp.T_world_grasp)
    c = sim.client
    frames = []
    steps0 = sim.steps
    T = clamp_to_table(grasp.T_world_grasp, scene.table_z, p.tip_clearance, grasp.opening,
                       p.gripper.geometry)
    a = T[:3, 2]
    T_pre = T.copy()
    T_pre[:3, 3] -= p.pregrasp_distance * a
    gripper = Gripper(sim, T_pre, opening=grasp.opening, params=p.gripper)
    starts = [np.array(c.getBasePositionAndOrientation(b)[0]) for b in bodies.objects]

    def done(reason, idx=None, lift=0.0, success=False):
        return GraspResult(success, reason, lift, idx, T, frames, sim.steps - steps0)

    if record is not None:
        frames.append(record("pregrasp"))
    if gripper.overlaps():
        return done(COLLISION)
    hit = _move(sim, gripper, T_pre[:3, 3], T[:3, 3], p.approach_speed, gripper.in_contact)
    for _ in range(p.arrive_steps if not hit else 0):
        # Let the base catch up with the target (it lags at speed), still checking contacts,
        # so the final pose -- and the outcome -- depends as little as possible on the speed.
        sim.step()
        if gripper.in_contact():
            hit = True
            break
        if np.linalg.norm(gripper.pose()[:3, 3] - T[:3, 3]) < 1e-4:
            break
    if hit:
        if record is not None:
            frames.append(record("approach"))
        return done(COLLISION)
    if record is not None:
        frames.append(record("approach"))
    # Close until the fingers stop (or the close time runs out).
    gripper.close()
    n_close = int(round(p.close_time / sim.time_step))
    for i in range(0, n_close, 6):
        sim.step(6)
        if i >= 24 and gripper.finger_speed() < 1e-3:
            break
    if record is not None:
        frames.append(record("close"))
    held = [i for i, b in enumerate(bodies.objects) if gripper.touching_both(b)]
    if not held:
        return done(NOTHING)
    idx = held[0]
    body = bodies.objects[idx]
    # Lift straight up, then hold.
    goal = T[:3, 3] + np.array([0.0, 0.0, p.lift_height])
    _move(sim, gripper, T[:3, 3], goal, p.lift_speed)
    if record is not None:
        frames.append(record("lift"))
    n_hold = int(round(p.hold_time / sim.time_step))
    rel_prev, still = None, 0
    for _ in range(0, n_hold, 24):
        sim.step(24)
        pos = np.array(c.getBasePositionAndOrientation(body)[0])
        z = pos[2]
        if z - starts[idx][2] < 0.5 * p.success_height and not gripper.touching_both(body):
            break  # it fell: no need to hold any longer
        if p.hold_until_still:
            rel = pos - np.array(c.getBasePositionAndOrientation(gripper.body)[0])
            moved = np.inf if rel_prev is None else float(np.linalg.norm(rel - rel_prev))
            rel_prev = rel
            still = still + 1 if moved < p.still_tolerance else 0
            if (still >= p.still_checks and z - starts[idx][2] >= p.success_height
                    and gripper.touching_both(body)):
                break  # at rest in the hand, high enough: the rest of the hold changes nothing
    if record is not None:
        frames.append(record("hold"))
    lift = float(c.getBasePositionAndOrientation(body)[0][2] - starts[idx][2])
    ok = lift >= p.success_height and gripper.touching_both(body)
    return done(None if ok else SLIPPED, idx, lift, ok)


def run_grasp(sim, scene: Scene, grasp: Grasp, params: ExecutionParams | None = None,
              record=None) -> GraspResult:
    """Rebuild ``scene`` from scratch and execute ``grasp`` in it (deterministic)."""
    if grasp.failure is not None:
        return GraspResult(False, grasp.failure, T_world_tcp=grasp.T_world_grasp)
    bodies = build_scene(sim, scene)
    return execute_grasp(sim, scene, bodies, grasp, params, record)


def _min_distance(client, body, others, query: float) -> float:
    """Smallest signed distance (m) from ``body`` to any of ``others``; ``query`` if farther."""
    d = query
    for b in others:
        for cp in client.getClosestPoints(body, b, query):
            d = min(d, cp[8])
    return d


def precheck_grasps(sim, scene: Scene, grasps, params: ExecutionParams | None = None,
                    clearance: float = 0.001, penetration: float = 0.0005,
                    region_margin: float = 0.002, min_advance: float = 0.0005) -> list:
    """Decide the obvious outcomes of many grasps in one scene geometrically, without stepping.

    The scene is built once and the open gripper (at each grasp's opening) is swept
    kinematically along the approach, from the pre-grasp pose to the (table-clamped) grasp
    pose, by conservative advancement (each move no longer than the current distance to the
    nearest body minus ``clearance``, at least ``min_advance``).

    * The gripper overlaps something at the pre-grasp pose (the same test as
      :func:`execute_grasp`), or penetrates any body by more than ``penetration`` anywhere on
      the way in: ``"collision on approach"``. The executed approach follows the same straight
      line and stops at the first contact closer than 0.5 mm, so it cannot pass there.
    * The way in stays at least ``clearance`` from everything (which covers the base's small
      overshoot at arrival) **and** no object comes within ``region_margin`` of the space
      between the open pads (``opening`` x pad width x pad length, 2 cm x 5 cm for the
      built-in hand): ``"nothing between the jaws"``; the
      closing pads sweep only that space and nothing can enter it.
    * Anything else (near contacts, an object between the jaws) is left undecided: None.

    Parameters
    ----------
    sim : graspsim.sim.bullet.Simulation
        Its world is replaced (the scene is built in it).
    scene : Scene
    grasps : list of Grasp
    params : ExecutionParams or None
    clearance, penetration, region_margin, min_advance : float
        Metres.

    Returns
    -------
    list of (GraspResult or None)
        Decided results carry ``steps=0``; grasps with a failure reason (no depth, too wide)
        get it as their result, as :func:`run_grasp` gives.
    """
    p = ExecutionParams() if params is None else params
    out: list = [None] * len(grasps)
    todo = []
    for i, g in enumerate(grasps):
        if g.failure is not None:
            out[i] = GraspResult(False, g.failure, T_world_tcp=g.T_world_grasp)
        else:
            todo.append(i)
    if not todo:
        return out
    c = sim.client
    bodies = build_scene(sim, scene)
    others = [bodies.table, *bodies.objects]
    gripper = None
    query = p.pregrasp_distance + 0.05
    hand = p.gripper.geometry
    for i in todo:
        g = grasps[i]
        T = clamp_to_table(g.T_world_grasp, scene.table_z, p.tip_clearance, g.opening,
                           hand)
        a = T[:3, 2]
        T_pre = T.copy()
        T_pre[:3, 3] -= p.pregrasp_distance * a
        if gripper is None:
            gripper = Gripper(sim, T_pre, opening=g.opening, params=p.gripper)
        else:
            gripper.teleport(T_pre)
            gripper.set_opening(g.opening, reset=True)
        if gripper.overlaps():
            out[i] = GraspResult(False, COLLISION, T_world_tcp=T)
            continue
        orn = pose_from_matrix(T)[1]
        s, clear, hit = 0.0, True, False
        while True:
            pos = T_pre[:3, 3] + s * a
            c.resetBasePositionAndOrientation(gripper.body, pos.tolist(), orn)
            d = _min_distance(c, gripper.body, others, query)
            if d < -penetration:
                hit = True
                break
            if d < clearance:
                clear = False
            if s >= p.pregrasp_distance:
                break
            s = min(s + max(d - clearance, min_advance), p.pregrasp_distance)
        if hit:
            out[i] = GraspResult(False, COLLISION, T_world_tcp=T)
            continue
        if not clear:
            continue
        half = [g.opening / 2, hand.pad_width / 2, hand.pad_length / 2]
        shape = c.createCollisionShape(c.GEOM_BOX, halfExtents=half)
        centre = (T @ np.array([0.0, 0.0, hand.tip_offset - half[2], 1.0]))[:3]
        empty = all(
            not c.getClosestPoints(bodyA=-1, bodyB=b, distance=region_margin,
                                   collisionShapeA=shape,
                                   collisionShapePositionA=centre.tolist(),
                                   collisionShapeOrientationA=orn)
            for b in bodies.objects
        )
        if empty:
            out[i] = GraspResult(False, NOTHING, T_world_tcp=T)
    return out

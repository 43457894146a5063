"""A floating parallel-jaw gripper: base moved by a constraint, gear-coupled position-controlled
fingers.

The gripper is purpose-built (``objects/gripper/parallel_jaw.urdf``, installed with the assets): its
base frame is the tool centre point (TCP) midway between the pads, ``z`` the approach direction,
``x`` the closing direction. Opening up to 8 cm; 2 cm wide pads reaching 1 cm beyond the TCP.
Forces follow a Franka hand (about 70 N continuous per finger, here 40 N) and rubber-like pad
friction (mu = 1.0, combined by pybullet as the product with the object's friction).

The base is held by a fixed constraint to the world whose target pose is moved (VGN's scheme);
the constraint's ``maxForce`` bounds the arm force, so contacts are physical.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .hands import BUILTIN, check_hand, hand_force, hand_geometry, hand_urdf

__all__ = ["Gripper", "GripperParams", "gripper_urdf", "hand_params", "pose_from_matrix",
           "matrix_from_pose"]

# The built-in hand's dimensions (graspsim.sim.hands.BUILTIN), metres.
MAX_OPENING = BUILTIN.max_opening  #: largest opening between the pads.
TIP_OFFSET = BUILTIN.tip_offset  #: fingertips lie this far beyond the TCP along the approach.
PALM_OFFSET = BUILTIN.palm_offset  #: the palm's face lies this far behind the TCP.
FINGER_THICKNESS = BUILTIN.finger_thickness  #: each finger's thickness (closing direction).
PAD_WIDTH = BUILTIN.pad_width  #: the pads' width across the closing direction.
PALM_LENGTH = BUILTIN.palm_length  #: the palm's length along the closing direction.
PALM_WIDTH = BUILTIN.palm_width  #: the palm's width across the closing direction.


def gripper_urdf(hand: str = "builtin"):
    """Path of a hand's URDF: the built-in one resolved from the installed assets (never the
    cwd), the others written on first use (:func:`graspsim.sim.hands.hand_urdf`)."""
    return hand_urdf(hand)


@dataclass(frozen=True)
class GripperParams:
    """Physical parameters of the gripper.

    Attributes
    ----------
    finger_force : float
        N, force limit of each finger's position controller.
    finger_speed : float
        m/s, largest finger speed.
    finger_friction : float
        Lateral friction coefficient of the pads.
    arm_force : float
        N, ``maxForce`` of the base constraint (what the "arm" can push or lift).
    hand : {"builtin", "franka", "wsg50", "robotiq-2f85"}
        Which hand (:mod:`graspsim.sim.hands`): its URDF and geometry. Each but the built-in one
        is meant with its own ``finger_force`` (:func:`graspsim.sim.hands.hand_force`;
        :func:`hand_params`).
    """

    finger_force: float = 40.0
    finger_speed: float = 0.2
    finger_friction: float = 1.0
    arm_force: float = 300.0
    hand: str = "builtin"

    def __post_init__(self):
        check_hand(self.hand)

    @property
    def geometry(self):
        """The hand's :class:`graspsim.sim.hands.HandGeometry`."""
        return hand_geometry(self.hand)


def hand_params(hand: str = "builtin") -> GripperParams:
    """The gripper parameters of a hand: the defaults, with the hand's documented grasp force
    (:func:`graspsim.sim.hands.hand_force`: the Franka hand's 70 N, the WSG 50's 80 N, the
    Robotiq 2F-85's 235 N) for any but the built-in hand.

    Raises
    ------
    ValueError
        One line, for an unknown hand.
    """
    force = hand_force(hand)
    if force is None:
        return GripperParams()
    return GripperParams(hand=hand, finger_force=force)


def matrix_from_pose(client, position, quaternion) -> np.ndarray:
    """4x4 homogeneous transform from a position and an (x, y, z, w) quaternion."""
    T = np.eye(4)
    T[:3, :3] = np.asarray(client.getMatrixFromQuaternion(quaternion)).reshape(3, 3)
    T[:3, 3] = position
    return T


def pose_from_matrix(T) -> tuple[list[float], list[float]]:
    """Position and (x, y, z, w) quaternion of a 4x4 transform (pure numpy)."""
    T = np.asarray(T, dtype=float)
    R = T[:3, :3]
    # Shepperd's method, numerically stable for every rotation.
    tr = np.trace(R)
    if tr > 0:
        s = np.sqrt(tr + 1.0) * 2
        w, x = 0.25 * s, (R[2, 1] - R[1, 2]) / s
        y, z = (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2]) * 2
        w, x = (R[2, 1] - R[1, 2]) / s, 0.25 * s
        y, z = (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s
    elif R[1, 1] > R[2, 2]:
        s = np.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2]) * 2
        w, x = (R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s
        y, z = 0.25 * s, (R[1, 2] + R[2, 1]) / s
    else:
        s = np.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1]) * 2
        w, x = (R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s
        y, z = (R[1, 2] + R[2, 1]) / s, 0.25 * s
    q = np.array([x, y, z, w])
    q /= np.linalg.norm(q)
    return [float(v) for v in T[:3, 3]], [float(v) for v in q]


class Gripper:
    """The gripper loaded into a simulation at a given TCP pose.

    Parameters
    ----------
    sim : graspsim.sim.bullet.Simulation
    T_world_tcp : ndarray of shape (4, 4)
        Initial TCP pose (the gripper is teleported there, fingers at ``opening``).
    opening : float
        Initial opening between the pads, metres (clipped to [0, the hand's largest]).
    params : GripperParams or None
        Its ``hand`` chooses the URDF (:mod:`graspsim.sim.hands`).
    """

    def __init__(self, sim, T_world_tcp, opening: float = MAX_OPENING,
                 params: GripperParams | None = None):
        self.sim = sim
        self.params = GripperParams() if params is None else params
        c = sim.client
        pos, orn = pose_from_matrix(T_world_tcp)
        self.body = c.loadURDF(str(gripper_urdf(self.params.hand)), pos, orn)
        self.fingers = (0, 1)  # joint (= link) indices of the left and right finger
        for j in self.fingers:
            c.changeDynamics(self.body, j, lateralFriction=self.params.finger_friction,
                             spinningFriction=0.002, rollingFriction=0.0)
        c.changeDynamics(self.body, -1, lateralFriction=0.6)
        self.cid = c.createConstraint(
            self.body, -1, -1, -1, c.JOINT_FIXED, jointAxis=[0, 0, 0],
            parentFramePosition=[0, 0, 0], childFramePosition=pos,
            parentFrameOrientation=[0, 0, 0, 1], childFrameOrientation=orn,
        )
        c.changeConstraint(self.cid, pos, orn, maxForce=self.params.arm_force)
        gear = c.createConstraint(self.body, 0, self.body, 1, c.JOINT_GEAR, [1, 0, 0],
                                  [0, 0, 0], [0, 0, 0])
        c.changeConstraint(gear, gearRatio=-1, erp=0.1, maxForce=50)
        self.set_opening(opening, reset=True)
        self._target = (pos, orn)

    # --- base -----------------------------------------------------------------------------
    def teleport(self, T_world_tcp) -> None:
        """Put the base at a pose instantly (free space only) and hold it there."""
        c = self.sim.client
        pos, orn = pose_from_matrix(T_world_tcp)
        c.resetBasePositionAndOrientation(self.body, pos, orn)
        c.resetBaseVelocity(self.body, [0, 0, 0], [0, 0, 0])
        c.changeConstraint(self.cid, pos, orn, maxForce=self.params.arm_force)
        self._target = (pos, orn)

    def set_target(self, position, orientation=None) -> None:
        """Move the constraint's target (the base follows under ``arm_force``)."""
        orn = self._target[1] if orientation is None else list(orientation)
        pos = [float(v) for v in position]
        self.sim.client.changeConstraint(self.cid, pos, orn, maxForce=self.params.arm_force)
        self._target = (pos, orn)

    @property
    def target(self):
        return self._target

    def pose(self) -> np.ndarray:
        """Current TCP pose, 4x4."""
        c = self.sim.client
        pos, orn = c.getBasePositionAndOrientation(self.body)
        return matrix_from_pose(c, pos, orn)

    # --- fingers --------------------------------------------------------------------------
    def set_opening(self, opening: float, reset: bool = False) -> None:
        """Command the opening (metres); ``reset=True`` also puts the fingers there instantly."""
        c = self.sim.client
        q = float(np.clip(opening, 0.0, self.params.geometry.max_opening)) / 2
        if reset:
            for j in self.fingers:
                c.resetJointState(self.body, j, q, 0.0)
        # Per-joint maxVelocity (not changeDynamics' maxJointVelocity, which in a multibody
        # also caps the floating base's speed).
        for j in self.fingers:
            c.setJointMotorControl2(
                self.body, j, c.POSITION_CONTROL, targetPosition=q,
                force=self.params.finger_force, maxVelocity=self.params.finger_speed,
            )

    def close(self) -> None:
        """Command the fingers shut (they stop on the object, squeezing with ``finger_force``)."""
        self.set_opening(0.0)

    def opening(self) -> float:
        """Current opening between the pads, metres."""
        c = self.sim.client
        return float(sum(c.getJointState(self.body, j)[0] for j in self.fingers))

    def finger_speed(self) -> float:
        c = self.sim.client
        return float(max(abs(c.getJointState(self.body, j)[1]) for j in self.fingers))

    # --- contacts -------------------------------------------------------------------------
    def in_contact(self, gap: float = 0.0005, force: float = 0.05) -> bool:
        """Whether any part of the gripper touches anything.

        A contact point counts when the bodies are closer than ``gap`` metres (pybullet also
        reports points a little apart, within its contact margin) or push with more than
        ``force`` newtons.
        """
        return any(cp[8] < gap or cp[9] > force
                   for cp in self.sim.client.getContactPoints(bodyA=self.body))

    def touching_both(self, body: int) -> bool:
        """Whether ``body`` touches both fingers."""
        c = self.sim.client
        return all(
            len(c.getContactPoints(bodyA=self.body, bodyB=body, linkIndexA=j)) > 0
            for j in self.fingers
        )

    def overlaps(self, margin: float = 0.0) -> bool:
        """Whether the gripper is within ``margin`` of any other body (without stepping)."""
        c = self.sim.client
        for b in range(c.getNumBodies()):
            body = c.getBodyUniqueId(b)
            if body == self.body:
                continue
            if c.getClosestPoints(self.body, body, margin):
                return True
        return False

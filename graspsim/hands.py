"""The hands the floating gripper can have: graspsim's built-in parallel jaw and the Franka hand.

A hand is its URDF (base frame = the tool centre point, TCP, midway between the pads: ``z`` the
approach, ``x`` the closing direction; two prismatic finger joints, indices 0 and 1, each at
half the opening) and its :class:`HandGeometry`, the dimensions the pose computation, the
depth-image checks of the gripper-aware detectors, the table clamp and the labeller's
geometric precheck use.

* ``"builtin"``: ``objects/gripper/parallel_jaw.urdf``, 8 cm stroke, 8 mm x 2 cm x 5 cm pads.
* ``"franka"``: the Franka Emika hand of ``pybullet_data``'s ``franka_panda`` model (its
  ``hand.obj`` and ``finger.obj`` collision and visual meshes), floating as in VGN (Breyer et
  al., CoRL 2020) and GIGA (Jiang et al., RSS 2021). Stroke 8 cm (two fingers of 4 cm travel,
  the ``panda_finger_joint`` limits; the datasheet's 80 mm). The URDF is written at run time
  next to nothing of the project's (a temporary folder), referring to the meshes where
  ``pybullet_data`` installed them. Its grasp force is :data:`FRANKA_FORCE`.

The Franka hand's frame sits where its fingertips reach 1 cm beyond the TCP, as the built-in
hand's, so a grasp pose means the same depth of grip for both.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

from .objects import assets_dir

__all__ = ["HAND_NAMES", "HandGeometry", "hand_geometry", "hand_urdf", "check_hand",
           "FRANKA_FORCE"]

HAND_NAMES = ("builtin", "franka")

#: N, the Franka hand's continuous grasp force (Franka Emika, *Panda* datasheet: "continuous
#: force 70 N, maximum force 140 N", stroke 80 mm); the force limit of each finger's motor, so
#: the object is squeezed with it.
FRANKA_FORCE = 70.0


@dataclass(frozen=True)
class HandGeometry:
    """Dimensions of a hand in its TCP frame (metres).

    Attributes
    ----------
    max_opening : float
        Largest opening between the pads.
    tip_offset : float
        The fingertips lie this far beyond the TCP along the approach (+z).
    palm_offset : float
        The palm's face lies this far behind the TCP.
    finger_thickness : float
        Each finger's thickness along the closing direction, at its lower end.
    pad_width : float
        The pads' width across the closing direction.
    pad_length : float
        The fingers' length below the palm's face (``tip_offset + palm_offset``).
    palm_length, palm_width : float
        The palm's extent along and across the closing direction.
    """

    max_opening: float
    tip_offset: float
    palm_offset: float
    finger_thickness: float
    pad_width: float
    pad_length: float
    palm_length: float
    palm_width: float


BUILTIN = HandGeometry(max_opening=0.08, tip_offset=0.01, palm_offset=0.04,
                       finger_thickness=0.008, pad_width=0.02, pad_length=0.05,
                       palm_length=0.11, palm_width=0.03)

# From pybullet_data's franka_panda: finger joints 58.4 mm below the hand frame, finger.obj
# 53.8 mm long, 21 mm wide, 14 mm thick over its lowest centimetre (26 mm at its root); the
# hand.obj's lowest face 66 mm below the hand frame, 204 mm x 63 mm across.
_FINGER_JOINT_Z = 0.0584
_FINGER_LENGTH = 0.0538
_HAND_FACE_Z = 0.066
# pybullet pads a convex mesh by about 1 mm (measured: the fingertips' collision surface lies
# 1.05 mm beyond finger.obj's last vertex, the palm's 0.8 mm), so the collision tips and palm
# are where the geometry below says.
_MESH_MARGIN = 0.001
_TCP_Z = _FINGER_JOINT_Z + _FINGER_LENGTH + _MESH_MARGIN - 0.01  # tips 1 cm beyond the TCP

FRANKA = HandGeometry(max_opening=0.08, tip_offset=0.01,
                      palm_offset=round(_TCP_Z - _HAND_FACE_Z - _MESH_MARGIN, 4),
                      finger_thickness=0.014 + _MESH_MARGIN, pad_width=0.021 + 2 * _MESH_MARGIN,
                      pad_length=round(_FINGER_JOINT_Z + _FINGER_LENGTH - _HAND_FACE_Z
                                       + 2 * _MESH_MARGIN, 4),
                      palm_length=0.204 + 2 * _MESH_MARGIN, palm_width=0.063 + 2 * _MESH_MARGIN)

_GEOMETRY = {"builtin": BUILTIN, "franka": FRANKA}


def check_hand(hand: str) -> str:
    """``hand`` when it names a hand, else a one-line ValueError listing them."""
    if hand not in _GEOMETRY:
        raise ValueError(f"unknown gripper {hand!r}; use one of {', '.join(HAND_NAMES)}")
    return hand


def hand_geometry(hand: str = "builtin") -> HandGeometry:
    """The :class:`HandGeometry` of a hand named in :data:`HAND_NAMES`."""
    return _GEOMETRY[check_hand(hand)]


def hand_urdf(hand: str = "builtin") -> Path:
    """Path of the hand's URDF (the Franka hand's is written on first use).

    Raises
    ------
    FileNotFoundError
        When the built-in URDF or ``pybullet_data``'s Franka meshes are missing.
    """
    if check_hand(hand) == "builtin":
        path = assets_dir() / "gripper" / "parallel_jaw.urdf"
        if not path.exists():
            raise FileNotFoundError(f"gripper URDF not found: {path}")
        return path
    return _franka_urdf()


def _franka_meshes() -> Path:
    import pybullet_data

    root = Path(pybullet_data.getDataPath()) / "franka_panda" / "meshes"
    for part in ("collision/hand.obj", "collision/finger.obj", "visual/hand.obj",
                 "visual/finger.obj"):
        if not (root / part).is_file():
            raise FileNotFoundError(f"the Franka hand needs pybullet_data's {root / part}, "
                                    "which is missing")
    return root


def _franka_text(meshes: Path) -> str:
    z_hand, z_finger = -_TCP_Z, _FINGER_JOINT_Z - _TCP_Z

    def mesh(kind, name):
        return f'<geometry><mesh filename="{meshes / kind / name}"/></geometry>'

    def finger(name, rpy, inertial_x):
        return f"""  <link name="{name}">
    <inertial><origin xyz="{inertial_x} 0 0.03"/><mass value="0.03"/>
      <inertia ixx="0.00001" ixy="0" ixz="0" iyy="0.00001" iyz="0" izz="0.00001"/></inertial>
    <visual><origin xyz="0 0 0" rpy="{rpy}"/>{mesh("visual", "finger.obj")}</visual>
    <collision><origin xyz="0 0 0" rpy="{rpy}"/>{mesh("collision", "finger.obj")}</collision>
  </link>
"""

    def joint(name, child, axis):
        return f"""  <joint name="{name}" type="prismatic">
    <parent link="hand"/><child link="{child}"/>
    <origin xyz="0 0 {z_finger:.4f}" rpy="0 0 0"/><axis xyz="{axis} 0 0"/>
    <limit lower="0.0" upper="0.04" effort="{FRANKA_FORCE}" velocity="0.2"/>
    <dynamics damping="1.0" friction="0.0"/>
  </joint>
"""

    # The hand's inertial frame is the TCP: pybullet holds and reports a base by its inertial
    # frame (the gripper's constraint, resetBasePositionAndOrientation). The meshes close along
    # their y axis; turned a quarter about z so that they close along
    # the TCP frame's x. The left finger (joint 0) sits at -x, the right (joint 1) at +x.
    return f"""<?xml version="1.0"?>
<!-- The Franka Emika hand (pybullet_data franka_panda meshes), floating, written by
graspsim.hands. Base frame = the TCP: z approach, x closing; fingertips 1 cm beyond it. -->
<robot name="graspsim_franka_hand">
  <link name="hand">
    <inertial><origin xyz="0 0 0"/><mass value="0.73"/>
      <inertia ixx="0.0025" ixy="0" ixz="0" iyy="0.0025" iyz="0" izz="0.0017"/></inertial>
    <visual><origin xyz="0 0 {z_hand:.4f}" rpy="0 0 1.5707963"/>{mesh("visual", "hand.obj")}
    </visual>
    <collision><origin xyz="0 0 {z_hand:.4f}" rpy="0 0 1.5707963"/>
      {mesh("collision", "hand.obj")}</collision>
  </link>
{finger("finger_left", "0 0 1.5707963", -0.01)}{finger("finger_right", "0 0 -1.5707963", 0.01)}
{joint("joint_left", "finger_left", -1)}{joint("joint_right", "finger_right", 1)}</robot>
"""


def _franka_urdf() -> Path:
    text = _franka_text(_franka_meshes())
    digest = hashlib.sha256(text.encode()).hexdigest()[:12]
    folder = Path(tempfile.gettempdir()) / "graspsim-hands"
    path = folder / f"franka_hand-{digest}.urdf"
    if not path.is_file():
        folder.mkdir(parents=True, exist_ok=True)
        tmp = folder / f".{path.name}.{os.getpid()}"
        tmp.write_text(text)
        os.replace(tmp, path)  # atomic: parallel workers may write it at once
    return path

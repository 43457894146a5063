"""The hands the floating gripper can have: graspsim's built-in parallel jaw, the Franka hand,
the Schunk WSG 50 and the Robotiq 2F-85.

A hand is its URDF (base frame = the tool centre point, TCP, midway between the pads: ``z`` the
approach, ``x`` the closing direction; two prismatic finger joints, indices 0 and 1, each at
half the opening) and its :class:`HandGeometry`, the dimensions the pose computation, the
depth-image checks of the gripper-aware detectors, the table clamp and the labeller's
geometric precheck use. Every hand's frame sits where its fingertips reach 1 cm beyond the TCP,
so a grasp pose means the same depth of grip for all of them. The finger speed and the pad
friction are the harness's (:class:`graspsim.sim.gripper.GripperParams`) for every hand; the
grasp force is each hand's own (:func:`graspsim.sim.gripper.hand_params`).

* ``"builtin"``: ``objects/gripper/parallel_jaw.urdf``, 8 cm stroke, 8 mm x 2 cm x 5 cm pads.
* ``"franka"``: the Franka Emika hand of ``pybullet_data``'s ``franka_panda`` model (its
  ``hand.obj`` and ``finger.obj`` collision and visual meshes), floating as in VGN (Breyer et
  al., CoRL 2020) and GIGA (Jiang et al., RSS 2021). Stroke 8 cm (two fingers of 4 cm travel,
  the ``panda_finger_joint`` limits; the datasheet's 80 mm). Its grasp force is
  :data:`FRANKA_FORCE`.
* ``"wsg50"``: the Schunk (Weiss Robotics) WSG 50-110 with the WSG-FMF fingers of
  ``pybullet_data``'s ``gripper/`` model (the ``WSG50_110.stl`` housing, ``GUIDE_WSG50_110.stl``
  base jaws and ``WSG-FMF.stl`` fingers as visual meshes). Its numbers:

  - stroke 110 mm (55 mm per jaw), grip force 5-80 N (80 N nominal, 120 N in overdrive),
    housing 146 x 50 x 72.5 mm, 1.2 kg: the WSG 50 *Assembly and operating manual* (Weiss
    Robotics / Schunk, 05.00, sections 3.1-3.2) and Schunk's WSG 050-110-B product data. The
    housing mesh measures 146 x 50 x 72.5 mm, as the manual says;
  - the base jaws (18 mm along the closing direction, 30 mm across, up to 96.5 mm above the
    mounting face) and the fingers (a 20 mm wide, 11 mm thick finger with a 3 mm pad over its
    last 16.5 mm, reaching 153.5 mm above the mounting face): measured on ``pybullet_data``'s
    meshes placed as its ``wsg50_one_motor_gripper_new_free_base.sdf`` places them. The
    fingers are set 3 mm further out than that model so that their pads, not the jaws, open
    the datasheet's 110 mm (pybullet_data's fingers stand 3 mm proud of the jaws: 104 mm);
  - collision shapes are boxes fitted to those meshes (as the SDF's own finger collisions are
    boxes: the convex hull pybullet would take of the L-shaped finger mesh fills its notch).

  Its grasp force is :data:`WSG50_FORCE`; the masses (1.0 kg housing, 0.1 kg per finger)
  add up to the manual's 1.2 kg.
* ``"robotiq-2f85"``: the Robotiq 2F-85, modelled from its published dimensions as a
  **parallel approximation** of its linkage (boxes written as a URDF, no mesh): two pads that
  slide straight along the closing direction. Its numbers:

  - stroke 85 mm and grip force 20-235 N: Robotiq's 2F-85 specifications (the *2F-85 &
    2F-140 Instruction Manual*, section 6.1, and its product sheet; about 0.9 kg);
  - the pads, 22 mm wide, 37.5 mm long and 8 mm thick, and the fingertips 88.5 mm beyond
    the spring links' pivots with the fingers open (the pivots 71.7 mm from the coupling's
    face, so the fingertips 160.2 mm): MuJoCo Menagerie's ``robotiq_2f85`` model (Zakka et
    al., 2022), which its authors derived from Robotiq's published CAD files;
  - estimates (no published figure found): the finger behind each pad (the follower link)
    as a 10 mm thick box over the finger's length below the pivots, and the housing as an
    85 x 60 mm box (enclosing the drivers' pivots, 61.2 mm apart in the Menagerie model)
    reaching the 71.7 mm from the pivots back to the coupling.

  What the approximation leaves out: the adaptive (underactuated) linkage that closes the
  fingers into an *encompassing* grip around an object their inner phalanges touch first,
  and the arc the fingertips describe while closing (their height changes with the opening,
  Robotiq's note on the 2F-85's vertical motion; here it stays the same). A parallel pinch
  between the pads, the grasp a planar detector asks for, is what it models; the linkage's
  lateral reach when open is that of the finger boxes. Its grasp force is
  :data:`ROBOTIQ_2F85_FORCE`.

The hands of ``pybullet_data`` are written at run time next to nothing of the project's (a
temporary folder), referring to the meshes where ``pybullet_data`` installed them.
"""

from __future__ import annotations

import hashlib
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

from .bullet import pybullet_data
from .objects import assets_dir

__all__ = ["HAND_NAMES", "HandGeometry", "hand_geometry", "hand_urdf", "hand_force",
           "check_hand", "FRANKA_FORCE", "WSG50_FORCE", "ROBOTIQ_2F85_FORCE"]

HAND_NAMES = ("builtin", "franka", "wsg50", "robotiq-2f85")

#: N, the Franka hand's continuous grasp force (Franka Emika, *Panda* datasheet: "continuous
#: force 70 N, maximum force 140 N", stroke 80 mm); the force limit of each finger's motor, so
#: the object is squeezed with it.
FRANKA_FORCE = 70.0
#: N, the WSG 50's nominal grip force (WSG 50 manual, section 3.2: 5-80 N adjustable, 120 N
#: only in its overdrive mode).
WSG50_FORCE = 80.0
#: N, the Robotiq 2F-85's largest grip force (its specifications: 20-235 N adjustable).
ROBOTIQ_2F85_FORCE = 235.0


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

# The WSG 50 in its mounting frame (z from the mounting face towards the fingertips, metres),
# measured on pybullet_data's meshes as its wsg50_one_motor_gripper_new_free_base.sdf places
# them: housing 0 to 72.5 mm; base jaws (GUIDE_WSG50_110.stl) 18 mm thick, 30 mm wide, their
# full section from 76 mm to 96.5 mm; fingers (WSG-FMF.stl, placed 23 mm higher than the mesh
# file's frame) from 80.5 mm to their tips at 153.5 mm: a 20 mm x 30 mm root to 103 mm, then
# 11 mm thick and 20 mm wide with a 3 mm pad over the last 16.5 mm.
# The palm's face is taken at the jaws' ends (the lowest part above the fingers), its footprint
# the housing's.
_WSG_TIP_Z = 0.1535
_WSG_TCP_Z = _WSG_TIP_Z - 0.01  # tips 1 cm beyond the TCP
_WSG_JAW_END_Z = 0.0965
_WSG_HOUSING = (0.146, 0.050, 0.0725)

WSG50 = HandGeometry(max_opening=0.110, tip_offset=0.01,
                     palm_offset=round(_WSG_TCP_Z - _WSG_JAW_END_Z, 4),
                     finger_thickness=0.014, pad_width=0.020,
                     pad_length=round(_WSG_TIP_Z - _WSG_JAW_END_Z, 4),
                     palm_length=_WSG_HOUSING[0], palm_width=_WSG_HOUSING[1])

# The Robotiq 2F-85 (parallel approximation) in its TCP frame: pads 8 mm x 22 mm x 37.5 mm at
# the fingertips, the follower behind each pad 10 mm thick, the fingers 88.5 mm long below
# the palm (the spring links' pivots), the housing 85 mm x 60 mm x 71.7 mm behind it.
_ROBOTIQ_PAD = (0.008, 0.022, 0.0375)
_ROBOTIQ_FOLLOWER = 0.010
_ROBOTIQ_FINGER_LENGTH = 0.0885
_ROBOTIQ_HOUSING = (0.085, 0.060, 0.0717)

ROBOTIQ_2F85 = HandGeometry(max_opening=0.085, tip_offset=0.01,
                            palm_offset=round(_ROBOTIQ_FINGER_LENGTH - 0.01, 4),
                            finger_thickness=_ROBOTIQ_PAD[0] + _ROBOTIQ_FOLLOWER,
                            pad_width=_ROBOTIQ_PAD[1], pad_length=_ROBOTIQ_FINGER_LENGTH,
                            palm_length=_ROBOTIQ_HOUSING[0], palm_width=_ROBOTIQ_HOUSING[1])

_GEOMETRY = {"builtin": BUILTIN, "franka": FRANKA, "wsg50": WSG50,
             "robotiq-2f85": ROBOTIQ_2F85}
_FORCE = {"franka": FRANKA_FORCE, "wsg50": WSG50_FORCE, "robotiq-2f85": ROBOTIQ_2F85_FORCE}


def check_hand(hand: str) -> str:
    """``hand`` when it names a hand, else a one-line ValueError listing them."""
    if hand not in _GEOMETRY:
        raise ValueError(f"unknown gripper {hand!r}; use one of {', '.join(HAND_NAMES)}")
    return hand


def hand_geometry(hand: str = "builtin") -> HandGeometry:
    """The :class:`HandGeometry` of a hand named in :data:`HAND_NAMES`."""
    return _GEOMETRY[check_hand(hand)]


def hand_force(hand: str = "builtin") -> float | None:
    """N, the grasp force each finger of ``hand`` presses with: :data:`FRANKA_FORCE`,
    :data:`WSG50_FORCE` or :data:`ROBOTIQ_2F85_FORCE`; None for the built-in hand (the
    harness's default, :class:`graspsim.sim.gripper.GripperParams`)."""
    return _FORCE.get(check_hand(hand))


def hand_urdf(hand: str = "builtin") -> Path:
    """Path of the hand's URDF (all but the built-in hand's are written on first use).

    Raises
    ------
    FileNotFoundError
        When the built-in URDF or the ``pybullet_data`` meshes a hand needs are missing.
    """
    if check_hand(hand) == "builtin":
        path = assets_dir() / "gripper" / "parallel_jaw.urdf"
        if not path.exists():
            raise FileNotFoundError(f"gripper URDF not found: {path}")
        return path
    if hand == "franka":
        return _write_urdf("franka_hand", _franka_text(_franka_meshes()))
    if hand == "wsg50":
        return _write_urdf("wsg50_hand", _wsg50_text(_wsg50_meshes()))
    return _write_urdf("robotiq_2f85_hand", _robotiq_text())


def _franka_meshes() -> Path:
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
graspsim.sim.hands. Base frame = the TCP: z approach, x closing; fingertips 1 cm beyond it. -->
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


def _box(xyz, size, rpy="0 0 0") -> str:
    """A URDF ``<origin>`` and box ``<geometry>`` (metres)."""
    return (f'<origin xyz="{xyz[0]:.5f} {xyz[1]:.5f} {xyz[2]:.5f}" rpy="{rpy}"/>'
            f'<geometry><box size="{size[0]:.5f} {size[1]:.5f} {size[2]:.5f}"/></geometry>')


def _span_box(x, y, z) -> tuple:
    """Centre and size of the box spanning the intervals ``x``, ``y``, ``z``."""
    return (tuple((a + b) / 2 for a, b in (x, y, z)), tuple(abs(b - a) for a, b in (x, y, z)))


def _prismatic(name, child, axis, upper, effort) -> str:
    """A finger joint at the TCP: ``q`` the pad's distance from the plane x = 0."""
    return f"""  <joint name="{name}" type="prismatic">
    <parent link="hand"/><child link="{child}"/>
    <origin xyz="0 0 0" rpy="0 0 0"/><axis xyz="{axis} 0 0"/>
    <limit lower="0.0" upper="{upper}" effort="{effort}" velocity="0.2"/>
    <dynamics damping="1.0" friction="0.0"/>
  </joint>
"""


def _wsg50_meshes() -> Path:
    root = Path(pybullet_data.getDataPath()) / "gripper" / "meshes"
    for part in ("WSG50_110.stl", "GUIDE_WSG50_110.stl", "WSG-FMF.stl"):
        if not (root / part).is_file():
            raise FileNotFoundError(f"the WSG 50 needs pybullet_data's {root / part}, "
                                    "which is missing")
    return root


def _wsg50_text(meshes: Path) -> str:
    # Mounting frame z = TCP frame z + _WSG_TCP_Z. The left finger link's frame has its pad face
    # at x = 0, the finger at -x; the right finger is the same turned half a turn about z.
    def z(v):
        return v - _WSG_TCP_Z

    def mesh(name, scale, xyz, rpy):
        return (f'<origin xyz="{xyz[0]:.5f} 0 {xyz[2]:.5f}" rpy="{rpy}"/><geometry><mesh '
                f'filename="{meshes / name}" scale="{scale} {scale} {scale}"/></geometry>')

    parts = [  # the finger's collision boxes, left finger (x <= 0), mounting-frame z
        _span_box((-0.003, 0.0), (-0.010, 0.010), (z(0.1370), z(_WSG_TIP_Z))),  # pad
        _span_box((-0.014, -0.003), (-0.010, 0.010), (z(0.1030), z(_WSG_TIP_Z))),  # finger
        _span_box((-0.023, -0.003), (-0.015, 0.015), (z(0.0805), z(0.1030))),  # its root
        _span_box((-0.018, 0.0), (-0.015, 0.015), (z(0.0760), z(_WSG_JAW_END_Z))),  # jaw
    ]

    def finger(name, rpy, sign):
        boxes = "".join(f"\n    <collision>{_box((sign * c[0], c[1], c[2]), size)}</collision>"
                        for c, size in parts)
        # meshes: the jaw as the SDF places it; the finger 23 mm higher and 3 mm further out
        return f"""  <link name="{name}">
    <inertial><origin xyz="{sign * -0.012} 0 {z(0.100):.4f}"/><mass value="0.1"/>
      <inertia ixx="0.00005" ixy="0" ixz="0" iyy="0.00005" iyz="0" izz="0.00002"/></inertial>
    <visual>{mesh("GUIDE_WSG50_110.stl", 0.001, (0, 0, z(0.0)), rpy)}
      <material name="jaw"><color rgba="0.55 0.57 0.6 1"/></material></visual>
    <visual>{mesh("WSG-FMF.stl", 0.001, (sign * -0.003, 0, z(0.023)), rpy)}
      <material name="finger"><color rgba="0.75 0.75 0.78 1"/></material></visual>{boxes}
  </link>
"""

    hx, hy, hz = _WSG_HOUSING
    housing = _box((0.0, 0.0, z(hz / 2)), _WSG_HOUSING)
    return f"""<?xml version="1.0"?>
<!-- The Schunk WSG 50-110 with WSG-FMF fingers (pybullet_data gripper meshes), floating,
written by graspsim.sim.hands. Base frame = the TCP: z approach, x closing; fingertips 1 cm beyond
it. Joint q = each pad's distance from the TCP, 0 to 55 mm (the 110 mm stroke). -->
<robot name="graspsim_wsg50_hand">
  <link name="hand">
    <inertial><origin xyz="0 0 0"/><mass value="1.0"/>
      <inertia ixx="0.0030" ixy="0" ixz="0" iyy="0.0025" iyz="0" izz="0.0020"/></inertial>
    <visual>{mesh("WSG50_110.stl", 1, (0, 0, z(0.0)), "0 0 0")}
      <material name="housing"><color rgba="0.3 0.32 0.36 1"/></material></visual>
    <collision>{housing}</collision>
  </link>
{finger("finger_left", "0 0 0", 1)}{finger("finger_right", "0 0 3.14159265", -1)}
{_prismatic("joint_left", "finger_left", -1, 0.055, WSG50_FORCE)}\
{_prismatic("joint_right", "finger_right", 1, 0.055, WSG50_FORCE)}</robot>
"""


def _robotiq_text() -> str:
    px, py, pz = _ROBOTIQ_PAD
    tip = 0.01
    palm = tip - _ROBOTIQ_FINGER_LENGTH
    pad = _span_box((-px, 0.0), (-py / 2, py / 2), (tip - pz, tip))
    follower = _span_box((-px - _ROBOTIQ_FOLLOWER, -px), (-py / 2, py / 2), (palm, tip))

    def finger(name, sign):
        body = ""
        for k, ((c, size), colour) in enumerate(((pad, "0.15 0.15 0.15 1"),
                                             (follower, "0.25 0.25 0.27 1"))):
            xyz = (sign * c[0], c[1], c[2])
            body += (f"\n    <visual>{_box(xyz, size)}<material name=\"{name}{k}\">"
                     f"<color rgba=\"{colour}\"/></material></visual>"
                     f"\n    <collision>{_box(xyz, size)}</collision>")
        return f"""  <link name="{name}">
    <inertial><origin xyz="{sign * -0.01} 0 {(palm + tip) / 2:.4f}"/><mass value="0.06"/>
      <inertia ixx="0.00004" ixy="0" ixz="0" iyy="0.00004" iyz="0" izz="0.00001"/></inertial>\
{body}
  </link>
"""

    hx, hy, hz = _ROBOTIQ_HOUSING
    housing = _box((0.0, 0.0, palm - hz / 2), _ROBOTIQ_HOUSING)
    return f"""<?xml version="1.0"?>
<!-- The Robotiq 2F-85 as a parallel approximation of its linkage (two pads sliding straight),
from its published dimensions, floating, written by graspsim.sim.hands. Base frame = the TCP:
z approach, x closing; fingertips 1 cm beyond it. Joint q = each pad's distance from the TCP,
0 to 42.5 mm (the 85 mm stroke). -->
<robot name="graspsim_robotiq_2f85_hand">
  <link name="hand">
    <inertial><origin xyz="0 0 0"/><mass value="0.8"/>
      <inertia ixx="0.0012" ixy="0" ixz="0" iyy="0.0012" iyz="0" izz="0.0008"/></inertial>
    <visual>{housing}<material name="housing"><color rgba="0.12 0.12 0.13 1"/></material>
    </visual>
    <collision>{housing}</collision>
  </link>
{finger("finger_left", 1)}{finger("finger_right", -1)}
{_prismatic("joint_left", "finger_left", -1, 0.0425, ROBOTIQ_2F85_FORCE)}\
{_prismatic("joint_right", "finger_right", 1, 0.0425, ROBOTIQ_2F85_FORCE)}</robot>
"""


def _write_urdf(stem: str, text: str) -> Path:
    """Write ``text`` once under the temporary folder, named by its digest (atomic)."""
    digest = hashlib.sha256(text.encode()).hexdigest()[:12]
    folder = Path(tempfile.gettempdir()) / "graspsim-hands"
    path = folder / f"{stem}-{digest}.urdf"
    if not path.is_file():
        folder.mkdir(parents=True, exist_ok=True)
        tmp = folder / f".{path.name}.{os.getpid()}"
        tmp.write_text(text)
        os.replace(tmp, path)  # atomic: parallel workers may write it at once
    return path

"""Generate the built-in object set in ``objects/`` (reproducible, seeded).

Every object is built from simple solids (trimesh primitives and revolved (r, z) profiles):

* the **visual mesh** (``<name>/<name>.obj``) is the watertight union of the solids, computed with
  manifold3d (``trimesh.boolean.union(engine="manifold")``);
* the **collision shape** (``<name>/<name>_collision.obj``) is a *constructive* convex
  decomposition: one ``o`` group per convex piece, which pybullet loads as a compound of convex
  hulls (the format of pybullet's own V-HACD output). Convex solids are one piece; hollow vessels
  (mugs, cups, bowls) are cut into a base disk plus wall wedges (profile segment x angular sector),
  handles into short cylinders, tori into arcs. Because the pieces follow the modelled geometry
  exactly, no V-HACD/CoACD run is needed and the result is bit-for-bit reproducible;
* the **URDF** carries the mass, the inertia of the visual solid (principal axes, used by
  ``load_object`` with ``URDF_USE_INERTIA_FROM_FILE``), friction and an rgba colour consistent with
  the material class (dark near-black, specular light and shiny, transparent alpha < 1);
* ``objects/manifest.json`` lists name, urdf, split, mass, friction, size, material, graspable,
  tags.

Objects are modelled in their stable resting pose (z up), centred on their bounding box.
``graspable`` is ``min_width < GRIPPER_OPENING`` where ``min_width`` (also in the manifest) is the
narrowest horizontal width of any convex piece: a handle, a rim wall, a neck or the whole body. The
too-wide objects (tag ``"too_wide"``) are solid and flat, so they rest in the modelled pose.

Run: ``.venv/bin/python scripts/make_objects.py`` (rewrites ``objects/`` except ``__init__.py``).
"""

from __future__ import annotations

import argparse
import json
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

SEED = 20161  # any fixed value; changing it changes colours, jitter and the train/test split
GRIPPER_OPENING = 0.08  # m, the gripper of graspsim opens up to 8 cm
SECTIONS = 24  # angular resolution of revolved solids (low-poly on purpose)
ROOT = Path(__file__).resolve().parents[1] / "objects"


# --------------------------------------------------------------------------- geometry helpers


def _fix(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    if mesh.volume < 0:
        mesh.invert()
    return mesh


def place(mesh: trimesh.Trimesh, xyz=(0.0, 0.0, 0.0), rpy=(0.0, 0.0, 0.0)) -> trimesh.Trimesh:
    """Copy of ``mesh`` rotated by roll-pitch-yaw (radians, extrinsic xyz) then translated."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", rpy).as_matrix()
    T[:3, 3] = xyz
    out = mesh.copy()
    out.apply_transform(T)
    return out


def box(ex, ey, ez, xyz=(0, 0, 0), rpy=(0, 0, 0)):
    return place(trimesh.creation.box((ex, ey, ez)), xyz, rpy)


def cyl(r, h, xyz=(0, 0, 0), rpy=(0, 0, 0), sections=SECTIONS):
    return place(trimesh.creation.cylinder(radius=r, height=h, sections=sections), xyz, rpy)


def sphere(r, xyz=(0, 0, 0), subdiv=2):
    return place(trimesh.creation.icosphere(subdivisions=subdiv, radius=r), xyz)


def ellipsoid(rx, ry, rz, xyz=(0, 0, 0), subdiv=2):
    m = trimesh.creation.icosphere(subdivisions=subdiv, radius=1.0)
    m.apply_scale((rx, ry, rz))
    return place(m, xyz)


def segment(p, q, r, sections=12):
    """Cylinder of radius ``r`` from point ``p`` to point ``q``."""
    p, q = np.asarray(p, float), np.asarray(q, float)
    return trimesh.creation.cylinder(radius=r, segment=np.stack([p, q]), sections=sections)


def revolve(profile, sections=SECTIONS) -> trimesh.Trimesh:
    """Watertight solid of revolution about z of a closed (r, z) polygon (first point repeated)."""
    pts = np.asarray(profile, float)
    if not np.allclose(pts[0], pts[-1]):
        pts = np.vstack([pts, pts[:1]])
    return _fix(trimesh.creation.revolve(pts, sections=sections))


def solid_profile(rz):
    """Closed profile of a solid of revolution from its outer (r, z) points, bottom to top."""
    rz = [tuple(p) for p in rz]
    return [(0.0, rz[0][1])] + rz + [(0.0, rz[-1][1])]


def frustum_hulls(rz, sections=16):
    """Convex pieces of a solid of revolution: one frustum per profile segment."""
    hulls = []
    a = np.linspace(0, 2 * np.pi, sections, endpoint=False)
    for (r0, z0), (r1, z1) in zip(rz[:-1], rz[1:], strict=True):
        if abs(z1 - z0) < 1e-6:
            continue
        pts = [(r * np.cos(a), r * np.sin(a), np.full_like(a, z)) for r, z in ((r0, z0), (r1, z1))]
        pts = np.concatenate([np.stack(p, 1) for p in pts])
        hulls.append(trimesh.convex.convex_hull(pts))
    return hulls


def offset_inward(rz, t):
    """Inner wall of a vessel: the outer (r, z) wall polyline moved by ``t`` along its normal."""
    rz = np.asarray(rz, float)
    d = np.gradient(rz, axis=0)
    n = np.stack([d[:, 1], -d[:, 0]], 1)  # outward normal (towards +r for a rising wall)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    return rz - t * n


def vessel(outer, t, tb, sections=SECTIONS, wedges=12):
    """Open-topped hollow vessel (mug, cup, bowl).

    Parameters
    ----------
    outer : (n, 2) outer wall (r, z) from the base edge (z = 0) up to the rim.
    t : wall thickness, tb : base thickness (m).

    Returns the visual solid and its convex pieces (base disk + wall wedges).
    """
    outer = np.asarray(outer, float)
    inner = offset_inward(outer, t)
    inner[0] = (outer[0, 0] - t, tb)  # the cavity floor
    inner[-1, 1] = outer[-1, 1]  # flat rim
    inner[:, 0] = np.maximum(inner[:, 0], 0.002)
    prof = [(0.0, 0.0)] + [tuple(p) for p in outer] + [tuple(p) for p in inner[::-1]]
    prof += [(0.0, tb)]
    visual = revolve(prof, sections)
    hulls = [cyl(outer[0, 0], tb, (0, 0, tb / 2), sections=sections)]
    edges = np.linspace(0, 2 * np.pi, wedges + 1)
    for i in range(len(outer) - 1):
        quad = [outer[i], outer[i + 1], inner[i + 1], inner[i]]
        for a0, a1 in zip(edges[:-1], edges[1:], strict=True):
            pts = [
                (r * np.cos(a), r * np.sin(a), z)
                for a in (a0, 0.5 * (a0 + a1), a1)
                for r, z in quad
            ]
            hulls.append(trimesh.convex.convex_hull(np.array(pts)))
    return [visual], hulls


def arc_handle(x0, z0, z1, reach, r, n=6):
    """C-shaped handle in the xz plane from (x0, z0) to (x0, z1), bulging by ``reach`` along +x."""
    s = np.linspace(0, np.pi, n + 1)
    zc, hz = 0.5 * (z0 + z1), 0.5 * (z1 - z0)
    pts = np.stack([x0 + reach * np.sin(s), np.zeros_like(s), zc - hz * np.cos(s)], 1)
    segs = [segment(p, q, r) for p, q in zip(pts[:-1], pts[1:], strict=True)]
    joints = [sphere(r, p, subdiv=1) for p in pts[1:-1]]
    return segs + joints, segs


def torus_pieces(R, r, n=10, sections=10):
    """A torus (ring) about z, as arc segments: visual solid pieces and convex pieces."""
    a = np.linspace(0, 2 * np.pi, n + 1)
    pts = np.stack([R * np.cos(a), R * np.sin(a), np.zeros_like(a)], 1)
    segs = [segment(p, q, r, sections) for p, q in zip(pts[:-1], pts[1:], strict=True)]
    joints = [sphere(r, p, subdiv=1) for p in pts[:-1]]
    return segs + joints, segs


def union(solids) -> trimesh.Trimesh:
    solids = [_fix(s) for s in solids]
    if len(solids) == 1:
        return solids[0]
    return trimesh.boolean.union(solids, engine="manifold")


# --------------------------------------------------------------------------- the catalogue


@dataclass
class Obj:
    name: str
    category: str
    material: str
    mass: float
    solids: list  # visual solids (unioned)
    hulls: list  # convex collision pieces
    friction: float = 0.8
    tags: list = field(default_factory=list)
    rgba: tuple | None = None


def colour(rng, material):
    """rgba consistent with the material class (see module docstring)."""
    if material == "dark":
        g = rng.uniform(0.03, 0.08)
        return (g, g, g * rng.uniform(0.9, 1.2), 1.0)
    if material == "specular":
        g = rng.uniform(0.75, 0.9)
        return (g, g, g * rng.uniform(0.95, 1.05), 1.0)
    if material == "transparent":
        return (rng.uniform(0.75, 0.9), rng.uniform(0.85, 0.95), 1.0, rng.uniform(0.25, 0.4))
    h = rng.uniform(0, 1)
    c = _hsv(h, rng.uniform(0.45, 0.85), rng.uniform(0.55, 0.95))
    return (*c, 1.0)


def _hsv(h, s, v):
    i = int(h * 6) % 6
    f = h * 6 - int(h * 6)
    p, q, t = v * (1 - s), v * (1 - f * s), v * (1 - (1 - f) * s)
    return [(v, t, p), (q, v, p), (p, v, t), (p, q, v), (t, p, v), (v, p, q)][i]


def catalogue(rng) -> list[Obj]:
    j = lambda lo, hi: float(rng.uniform(lo, hi))  # noqa: E731 - small size jitter
    out: list[Obj] = []

    def add(name, category, material, mass, solids_hulls, **kw):
        solids, hulls = solids_hulls
        out.append(Obj(name, category, material, mass, solids, hulls, **kw))

    # ---- mugs and cups (hollow: decomposed)
    def mug(R, h, t=0.004, handle=True, taper=0.0):
        outer = [(R - taper, 0.0), (R - taper * 0.5, h * 0.5), (R, h)]
        solids, hulls = vessel(outer, t, 0.006)
        if handle:
            hs, hh = arc_handle(R - 0.003, 0.25 * h, 0.8 * h, 0.028, 0.005)
            solids += hs
            hulls += hh
        return solids, hulls

    add("mug_classic", "mug", "matte", 0.30, mug(0.035, 0.095), tags=["handle", "concave"])
    add("mug_black", "mug", "dark", 0.28, mug(0.033, 0.085), tags=["handle", "concave"])
    add("mug_enamel", "mug", "specular", 0.25, mug(0.034, 0.105), tags=["handle", "concave"])
    add("mug_espresso", "mug", "matte", 0.12, mug(0.028, 0.06), tags=["handle", "concave"])
    add("mug_tapered", "mug", "matte", 0.22, mug(0.034, 0.09, taper=0.006),
        tags=["handle", "concave"])
    add("cup_paper", "mug", "matte", 0.02,
        mug(0.036, 0.095, t=0.002, handle=False, taper=0.011), friction=0.6, tags=["concave"])
    add("cup_glass", "mug", "transparent", 0.20,
        mug(0.032, 0.10, t=0.003, handle=False, taper=0.005), friction=0.5, tags=["concave"])

    # ---- bottles (solid of revolution: frustum pieces)
    def bottle(R, h, neck_r, shoulder=0.65, neck=0.85):
        rz = [(R * 0.92, 0.0), (R, 0.01), (R, h * shoulder), (R * 0.8, h * (shoulder + 0.06)),
              (neck_r * 1.2, h * neck), (neck_r, h * (neck + 0.03)), (neck_r, h)]
        return [revolve(solid_profile(rz))], frustum_hulls(rz)

    add("bottle_water", "bottle", "transparent", 0.35, bottle(j(0.031, 0.033), 0.22, 0.013),
        friction=0.6)
    add("bottle_wine", "bottle", "dark", 0.9, bottle(0.036, 0.29, 0.0125, 0.6, 0.82))
    add("bottle_small", "bottle", "matte", 0.15, bottle(0.022, 0.14, 0.01))
    add("bottle_ketchup", "bottle", "matte", 0.4, bottle(0.028, 0.18, 0.012, 0.75, 0.9))
    add("bottle_pill", "bottle", "matte", 0.05, bottle(0.018, 0.075, 0.015, 0.8, 0.9))
    add("bottle_shampoo", "bottle", "specular", 0.3, bottle(0.026, 0.19, 0.011, 0.78, 0.88))

    # ---- cans
    def can(R, h):
        rz = [(R * 0.9, 0.0), (R, 0.006), (R, h - 0.006), (R * 0.9, h)]
        return [revolve(solid_profile(rz))], frustum_hulls(rz)

    add("can_soda", "can", "specular", 0.35, can(0.033, 0.122))
    add("can_tall", "can", "specular", 0.45, can(0.029, 0.16))
    add("can_food", "can", "matte", 0.42, can(0.037, 0.11))
    add("can_paint", "can", "dark", 0.5, can(0.032, 0.075))
    add("can_tuna", "can", "specular", 0.18, can(0.0475, 0.04), tags=["too_wide"])

    # ---- boxes (modelled lying on their largest face)
    def bx(ex, ey, ez):
        b = box(ex, ey, ez)
        return [b], [b]

    add("box_small", "box", "matte", 0.08, bx(0.05, 0.04, 0.03))
    add("box_tea", "box", "matte", 0.1, bx(0.12, 0.065, 0.06))
    add("box_matches", "box", "matte", 0.03, bx(0.055, 0.035, 0.016))
    add("box_juice", "box", "matte", 0.25, bx(0.095, 0.06, 0.04))
    add("box_phone", "box", "dark", 0.17, bx(0.145, 0.07, 0.009))
    add("box_soap", "box", "matte", 0.12, bx(0.09, 0.06, 0.035))
    add("box_cereal", "box", "matte", 0.4, bx(0.28, 0.19, 0.07), tags=["too_wide"])
    add("box_tissue", "box", "matte", 0.15, bx(0.24, 0.12, 0.09), tags=["too_wide"])

    # ---- bowls (hollow: decomposed; graspable by the rim)
    def bowl(R, h, rb, t=0.004):
        z = np.linspace(0, 1, 5)
        outer = [(rb + (R - rb) * np.sin(0.5 * np.pi * s) ** 0.8, h * s) for s in z]
        return vessel(outer, t, 0.005, wedges=12)

    add("bowl_small", "bowl", "matte", 0.25, bowl(0.06, 0.055, 0.035), tags=["rim", "concave"])
    add("bowl_large", "bowl", "dark", 0.4, bowl(0.08, 0.07, 0.045), tags=["rim", "concave"])
    add("bowl_metal", "bowl", "specular", 0.2, bowl(0.065, 0.05, 0.04, 0.002),
        tags=["rim", "concave"])
    add("bowl_ramekin", "bowl", "matte", 0.15, bowl(0.034, 0.045, 0.03, 0.005),
        tags=["concave"])

    # ---- tools (unions of convex parts)
    def screwdriver(L=0.2):
        hl = 0.4 * L
        s = [cyl(0.014, hl, (-L / 2 + hl / 2, 0, 0), (0, np.pi / 2, 0), sections=8),
             cyl(0.004, L - hl, (L / 2 - (L - hl) / 2, 0, 0), (0, np.pi / 2, 0), sections=8)]
        return s, s

    def hammer():
        s = [box(0.28, 0.026, 0.02, (0, 0, 0)), box(0.03, 0.10, 0.03, (0.14, 0, 0.005))]
        return s, s

    def spatula():
        s = [box(0.18, 0.022, 0.012, (-0.06, 0, 0.0)),
             box(0.09, 0.075, 0.004, (0.075, 0, -0.004), (0, 0.12, 0))]
        return s, s

    def wrench():
        s = [box(0.16, 0.018, 0.007), cyl(0.018, 0.008, (0.085, 0, 0), sections=12),
             cyl(0.015, 0.008, (-0.085, 0, 0), sections=12)]
        return s, s

    def brush():
        s = [box(0.16, 0.03, 0.018, (-0.02, 0, -0.005)), box(0.07, 0.045, 0.028, (0.03, 0, 0.0))]
        return s, s

    def knife():
        s = [box(0.11, 0.022, 0.016, (-0.07, 0, 0.0)), box(0.15, 0.03, 0.003, (0.06, 0, -0.006))]
        return s, s

    def wooden_spoon():
        head = ellipsoid(0.035, 0.025, 0.007, (0.1, 0, 0), subdiv=2)
        s = [cyl(0.007, 0.22, (-0.02, 0, 0), (0, np.pi / 2, 0), sections=8), head]
        return s, s

    add("screwdriver", "tool", "matte", 0.08, screwdriver(), tags=["long"])
    add("screwdriver_small", "tool", "dark", 0.05, screwdriver(0.15), tags=["long"])
    add("hammer", "tool", "matte", 0.45, hammer(), tags=["long"])
    add("spatula", "tool", "dark", 0.07, spatula(), tags=["long", "thin"])
    add("wrench", "tool", "specular", 0.15, wrench(), tags=["long", "thin"])
    add("brush", "tool", "matte", 0.08, brush())
    add("knife", "tool", "specular", 0.09, knife(), tags=["long", "thin"])
    add("wooden_spoon", "tool", "matte", 0.04, wooden_spoon(), tags=["long"])

    # ---- toys
    def duck():
        s = [ellipsoid(0.04, 0.03, 0.025, (0, 0, 0.0)), sphere(0.018, (0.028, 0, 0.03)),
             ellipsoid(0.012, 0.008, 0.004, (0.05, 0, 0.028), subdiv=1)]
        # flat bottom so it rests stably
        s = [s[0].slice_plane((0, 0, -0.018), (0, 0, 1), cap=True)] + s[1:]
        return s, s

    def car():
        s = [box(0.10, 0.045, 0.025, (0, 0, 0.02)), box(0.05, 0.04, 0.02, (-0.01, 0, 0.04))]
        for x in (-0.032, 0.032):
            for y in (-0.024, 0.024):
                s.append(cyl(0.012, 0.008, (x, y, 0.012), (np.pi / 2, 0, 0), sections=12))
        return s, s

    def block_l():
        s = [box(0.09, 0.03, 0.03, (0, 0, 0)), box(0.03, 0.06, 0.03, (-0.03, 0.045, 0))]
        return s, s

    def block_t():
        s = [box(0.09, 0.025, 0.025, (0, 0, 0)), box(0.025, 0.06, 0.025, (0, -0.0425, 0))]
        return s, s

    def cross():
        s = [box(0.075, 0.02, 0.02), box(0.02, 0.075, 0.02)]
        return s, s

    def teddy():
        s = [ellipsoid(0.03, 0.025, 0.035, (0, 0, 0.035)), sphere(0.022, (0, 0, 0.085)),
             sphere(0.008, (0.012, 0, 0.105), 1), sphere(0.008, (-0.012, 0, 0.105), 1),
             ellipsoid(0.012, 0.02, 0.012, (0.018, 0.02, 0.018), 1),
             ellipsoid(0.012, 0.02, 0.012, (-0.018, 0.02, 0.018), 1)]
        s[0] = s[0].slice_plane((0, 0, 0.006), (0, 0, 1), cap=True)
        return s, s

    add("toy_duck", "toy", "matte", 0.05, duck())
    add("toy_car", "toy", "matte", 0.12, car())
    add("block_l", "toy", "matte", 0.06, block_l(), tags=["concave"])
    add("block_t", "toy", "matte", 0.05, block_t(), tags=["concave"])
    add("block_cross", "toy", "dark", 0.05, cross(), tags=["concave"])
    add("dice", "toy", "matte", 0.03, bx(0.032, 0.032, 0.032))
    add("toy_ring", "toy", "matte", 0.04, torus_pieces(0.033, 0.009), tags=["concave", "rim"])
    add("teddy", "toy", "matte", 0.1, teddy())

    # ---- thin and long
    def prism(r, L, n=6):
        # n-gon prism lying along x with a flat face down (does not roll)
        m = cyl(r, L, (0, 0, 0), (0, np.pi / 2, 0), sections=n)
        m = place(m, rpy=(np.pi / n, 0, 0))
        return [m], [m]

    add("pen", "thin", "dark", 0.012, prism(0.005, 0.14), tags=["long", "thin"])
    add("pencil", "thin", "matte", 0.006, prism(0.004, 0.175), tags=["long", "thin"])
    add("marker", "thin", "matte", 0.015, prism(0.009, 0.13, 8), tags=["long", "thin"])
    add("stick", "thin", "matte", 0.03, bx(0.25, 0.015, 0.01), tags=["long", "thin"])
    add("ruler", "thin", "transparent", 0.02, bx(0.30, 0.03, 0.003), tags=["long", "thin"])
    add("chopstick", "thin", "matte", 0.008, prism(0.0045, 0.23, 4), tags=["long", "thin"])

    def toothbrush():
        s = [box(0.15, 0.012, 0.008, (-0.02, 0, -0.004)), box(0.03, 0.012, 0.012, (0.06, 0, 0.006))]
        return s, s

    add("toothbrush", "thin", "matte", 0.015, toothbrush(), tags=["long", "thin"])

    # ---- too wide to grasp (solid, flat: they rest in the modelled pose)
    def disk(R, h):
        rz = [(R - 0.01, 0.0), (R, h)]
        return [revolve(solid_profile(rz))], frustum_hulls(rz)

    add("book", "wide", "matte", 0.5, bx(0.22, 0.15, 0.03), tags=["too_wide"])
    add("cutting_board", "wide", "matte", 0.6, bx(0.30, 0.20, 0.015), tags=["too_wide"])
    add("plate", "wide", "matte", 0.45, disk(0.11, 0.018), tags=["too_wide"])
    add("cake_tin", "wide", "specular", 0.5, disk(0.1, 0.06), tags=["too_wide"])
    return out


# --------------------------------------------------------------------------- writers


def _fmt(x):
    s = f"{x:.5f}".rstrip("0").rstrip(".")
    return "0" if s in ("", "-0") else s


def write_obj(path: Path, meshes: list, names: list | None = None):
    """Wavefront OBJ, one ``o`` group per mesh (no normals, no material: colour is in the URDF)."""
    lines = ["# generated by scripts/make_objects.py"]
    base = 1
    for k, m in enumerate(meshes):
        lines.append(f"o {names[k] if names else f'part{k}'}")
        lines += ["v " + " ".join(_fmt(c) for c in v) for v in np.asarray(m.vertices)]
        lines += ["f " + " ".join(str(base + i) for i in f) for f in np.asarray(m.faces)]
        base += len(m.vertices)
    path.write_text("\n".join(lines) + "\n")


URDF = """<?xml version="1.0"?>
<!-- generated by scripts/make_objects.py -->
<robot name="{name}">
  <link name="{name}">
    <contact>
      <lateral_friction value="{friction}"/>
      <rolling_friction value="0.0005"/>
      <spinning_friction value="0.002"/>
    </contact>
    <inertial>
      <origin xyz="{com}" rpy="{rpy}"/>
      <mass value="{mass}"/>
      <inertia ixx="{ixx}" ixy="0" ixz="0" iyy="{iyy}" iyz="0" izz="{izz}"/>
    </inertial>
    <visual>
      <origin xyz="0 0 0" rpy="0 0 0"/>
      <geometry><mesh filename="{name}.obj"/></geometry>
      <material name="{material}_{name}">
        <color rgba="{rgba}"/>
        <specular rgb="{spec}"/>
      </material>
    </visual>
    <collision>
      <origin xyz="0 0 0" rpy="0 0 0"/>
      <geometry><mesh filename="{name}_collision.obj"/></geometry>
    </collision>
  </link>
</robot>
"""


def principal_frame(inertia):
    """Principal moments and a rotation whose columns are the principal axes, chosen as close to
    the identity as possible (so the URDF's rpy stays small and free of gimbal lock)."""
    w, V = np.linalg.eigh(inertia)
    order, used = [], set()
    for axis in range(3):  # greedily match each world axis to its closest principal axis
        k = max((k for k in range(3) if k not in used), key=lambda k: abs(V[axis, k]))
        used.add(k)
        order.append(k)
    R = V[:, order] * np.sign(V[[0, 1, 2], order])
    if np.linalg.det(R) < 0:
        R[:, 2] *= -1
    return w[order], R


def min_width(hulls) -> float:
    """Narrowest horizontal width over the convex pieces (m): the smallest opening a top-down
    parallel jaw needs to close across some part of the object (a handle, a rim wall, a neck).
    Width of a piece = min over horizontal directions of the extent of its vertices."""
    a = np.deg2rad(np.arange(0, 180, 2.0))
    dirs = np.stack([np.cos(a), np.sin(a)], 1)
    best = np.inf
    for h in hulls:
        proj = np.asarray(h.vertices)[:, :2] @ dirs.T
        best = min(best, float((proj.max(0) - proj.min(0)).min()))
    return best


def is_graspable(width: float) -> bool:
    """The manifest rule (also asserted by the tests): some part is narrower than the opening."""
    return width < GRIPPER_OPENING


def build(root: Path = ROOT, seed: int = SEED, test_fraction: float = 0.25) -> list[dict]:
    rng = np.random.default_rng(seed)
    objs = catalogue(rng)
    names = [o.name for o in objs]
    if len(set(names)) != len(names):
        raise ValueError("duplicate object names")
    for o in objs:
        o.rgba = colour(rng, o.material)
    # split: per category, a seeded ~test_fraction of the objects go to test (at least one)
    split = {}
    for cat in sorted({o.category for o in objs}):
        members = sorted(o.name for o in objs if o.category == cat)
        n_test = max(1, int(round(test_fraction * len(members))))
        for k, name in enumerate(rng.permutation(members)):
            split[name] = "test" if k < n_test else "train"

    # remove only this generator's own folders (objects/ also holds other assets, e.g. gripper/)
    old = root / "manifest.json"
    previous = set(names)
    if old.exists():
        try:
            previous |= {e["name"] for e in json.loads(old.read_text()).get("objects", [])}
        except (ValueError, KeyError):
            pass
    for name in sorted(previous):
        if (root / name / f"{name}.urdf").exists():
            shutil.rmtree(root / name)
    root.mkdir(parents=True, exist_ok=True)
    entries = []
    for o in objs:
        visual = union(o.solids)
        hulls = [trimesh.convex.convex_hull(h.vertices) for h in o.hulls]
        centre = visual.bounds.mean(axis=0)
        visual.apply_translation(-centre)
        for h in hulls:
            h.apply_translation(-centre)
        if not visual.is_volume:
            raise RuntimeError(f"{o.name}: visual mesh is not a closed volume")
        size = [float(round(e, 4)) for e in visual.extents]
        # inertia of the visual solid at its centre of mass, in principal axes
        visual.density = o.mass / visual.volume
        com = visual.center_mass
        comps, R = principal_frame(visual.moment_inertia)
        rpy = Rotation.from_matrix(R).as_euler("xyz")
        d = root / o.name
        d.mkdir()
        write_obj(d / f"{o.name}.obj", [visual], [o.name])
        write_obj(d / f"{o.name}_collision.obj", hulls)
        spec = "0.9 0.9 0.9" if o.material in ("specular", "transparent") else "0.1 0.1 0.1"
        (d / f"{o.name}.urdf").write_text(URDF.format(
            name=o.name, friction=o.friction, mass=o.mass, material=o.material,
            com=" ".join(_fmt(c) for c in com), rpy=" ".join(_fmt(a) for a in rpy),
            ixx=f"{comps[0]:.4g}", iyy=f"{comps[1]:.4g}", izz=f"{comps[2]:.4g}",
            rgba=" ".join(f"{c:.3f}" for c in o.rgba), spec=spec,
        ))
        tags = [o.category, *o.tags]
        width = min_width(hulls)
        if GRIPPER_OPENING - 0.005 < width < GRIPPER_OPENING + 0.01:
            raise RuntimeError(f"{o.name}: narrowest part {width:.3f} m too close to the opening")
        if (width >= GRIPPER_OPENING) != ("too_wide" in tags):
            raise RuntimeError(f"{o.name}: 'too_wide' tag disagrees with the width {width:.3f} m")
        entries.append({
            "name": o.name, "urdf": f"{o.name}/{o.name}.urdf", "split": split[o.name],
            "mass": o.mass, "friction": o.friction, "size": size, "material": o.material,
            "graspable": is_graspable(width), "tags": tags,
            "min_width": round(width, 4),
            "rgba": [round(c, 3) for c in o.rgba], "collision_pieces": len(hulls),
        })
    manifest = {
        "generator": "scripts/make_objects.py", "seed": seed,
        "gripper_opening": GRIPPER_OPENING, "objects": entries,
    }
    (root / "manifest.json").write_text(json.dumps(manifest, indent=1) + "\n")
    return entries


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT)
    ap.add_argument("--seed", type=int, default=SEED)
    args = ap.parse_args(argv)
    entries = build(args.out, args.seed)
    n_test = sum(e["split"] == "test" for e in entries)
    n_wide = sum(not e["graspable"] for e in entries)
    print(f"wrote {len(entries)} objects to {args.out} ({n_test} test, {n_wide} too wide)")


if __name__ == "__main__":
    main()

"""The built-in object set, the random_urdfs loader and user folders."""

from __future__ import annotations

import importlib.util
import json
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

pybullet = pytest.importorskip("pybullet")
import pybullet_data  # noqa: E402
from pybullet_utils.bullet_client import BulletClient  # noqa: E402

from graspsim.sim.objects import (  # noqa: E402
    GRIPPER_OPENING,
    MIN_INERTIA_RATIO,
    ObjectSpec,
    _obj_bounds,
    assets_dir,
    builtin_objects,
    condition_inertia,
    folder_objects,
    load_object,
    random_urdf_objects,
)

pytestmark = pytest.mark.sim

REPO = Path(__file__).resolve().parents[3]
MATERIALS = {"matte", "dark", "specular", "transparent"}


@pytest.fixture(scope="module")
def manifest() -> dict:
    return json.loads((assets_dir() / "manifest.json").read_text())


@pytest.fixture
def client():
    c = BulletClient(connection_mode=pybullet.DIRECT)
    yield c
    c.disconnect()


def settle_on_plane(c, spec: ObjectSpec, seconds=1.0):
    """Load ``spec`` just above a plane in its modelled pose; return start and end poses."""
    c.resetSimulation()
    c.setGravity(0, 0, -9.81)
    c.loadURDF(str(Path(pybullet_data.getDataPath()) / "plane.urdf"))
    body = load_object(c, spec, (0.0, 0.0, spec.size[2] / 2 + 0.002))
    p0, o0 = c.getBasePositionAndOrientation(body)
    for _ in range(int(240 * seconds)):
        c.stepSimulation()
    p1, o1 = c.getBasePositionAndOrientation(body)
    return body, (np.array(p0), o0), (np.array(p1), o1)


# --------------------------------------------------------------------------- manifest


def test_manifest_entries_are_valid(manifest):
    entries = manifest["objects"]
    names = [e["name"] for e in entries]
    assert len(names) == len(set(names))
    for e in entries:
        assert {"name", "urdf", "split", "mass", "friction", "size", "material", "graspable",
                "tags"} <= set(e), e["name"]
        assert (assets_dir() / e["urdf"]).is_file(), e["name"]
        assert e["split"] in ("train", "test")
        assert e["material"] in MATERIALS
        assert 0.001 < e["mass"] < 2.0 and 0.1 < e["friction"] < 2.0
        assert len(e["size"]) == 3 and all(0.002 < s < 0.35 for s in e["size"]), e["name"]
        assert isinstance(e["graspable"], bool) and isinstance(e["tags"], list)


def test_at_least_40_objects_and_mixed_splits():
    objs = builtin_objects()
    train, test = builtin_objects("train"), builtin_objects("test")
    assert len(objs) >= 40
    assert len(train) + len(test) == len(objs)
    assert 0.15 <= len(test) / len(objs) <= 0.35
    categories = lambda specs: {s.tags[0] for s in specs}  # noqa: E731
    assert len(categories(test)) >= 5 and categories(test) <= categories(train)
    with pytest.raises(ValueError, match="split"):
        builtin_objects("validation")


def test_categories_present():
    cats = {s.tags[0] for s in builtin_objects()}
    assert {"mug", "bottle", "can", "box", "bowl", "tool", "toy", "thin", "wide"} <= cats
    assert any("handle" in s.tags for s in builtin_objects())


def test_graspable_flag_consistent_with_size(manifest):
    assert manifest["gripper_opening"] == GRIPPER_OPENING == 0.08
    wide = 0
    for e in manifest["objects"]:
        w = e["min_width"]
        # the narrowest part is no wider than the footprint, and clear of the opening
        assert w <= min(e["size"][:2]) + 1e-3, e["name"]
        assert not (GRIPPER_OPENING - 0.005 < w < GRIPPER_OPENING + 0.01), e["name"]
        assert e["graspable"] == (w < GRIPPER_OPENING), e["name"]
        if min(e["size"][:2]) < GRIPPER_OPENING:
            assert e["graspable"], e["name"]
        if not e["graspable"]:
            wide += 1
            assert "too_wide" in e["tags"]
            assert e["size"][2] == min(e["size"]), e["name"]  # flat: rests in this pose
    assert 3 <= wide <= 0.25 * len(manifest["objects"])


def test_colours_follow_material():
    for s in builtin_objects():
        root = ET.parse(s.urdf).getroot()
        rgba = [float(x) for x in root.find("./link/visual/material/color").get("rgba").split()]
        if s.material == "dark":
            assert max(rgba[:3]) < 0.15, s.name
        if s.material == "transparent":
            assert rgba[3] < 1.0, s.name
        else:
            assert rgba[3] == 1.0, s.name


def test_meshes_match_sizes_and_concave_ones_are_decomposed():
    for s in builtin_objects():
        folder = s.urdf.parent
        b = _obj_bounds(folder / f"{s.name}.obj")
        np.testing.assert_allclose(b[1] - b[0], s.size, atol=6e-4, err_msg=s.name)
        np.testing.assert_allclose(b.mean(axis=0), 0.0, atol=1e-4, err_msg=s.name)
        groups = (folder / f"{s.name}_collision.obj").read_text().count("\no ")
        if "concave" in s.tags:
            assert groups >= 2, s.name
    size = sum(p.stat().st_size for p in assets_dir().rglob("*") if p.is_file())
    assert size < 5e6


def test_every_object_loads_and_rests_stably(client):
    for s in builtin_objects():
        body, (p0, o0), (p1, o1) = settle_on_plane(client, s)
        contacts = client.getContactPoints(bodyA=body)
        assert contacts, f"{s.name} is not touching the plane"
        assert min(c[5][2] for c in contacts) > -0.003, f"{s.name} sank into the plane"
        assert np.linalg.norm(p1[:2] - p0[:2]) < 0.01, f"{s.name} drifted"
        assert abs(p1[2] - p0[2]) < 0.01, f"{s.name} moved vertically"
        q = client.getDifferenceQuaternion(o0, o1)
        angle = 2 * np.degrees(np.arccos(min(1.0, abs(q[3]))))
        assert angle < 5, f"{s.name} tipped by {angle:.1f} deg"
        assert np.linalg.norm(client.getBaseVelocity(body)[0]) < 0.02, f"{s.name} still moving"


def test_load_object_sets_mass_friction_and_file_inertia(client):
    s = next(s for s in builtin_objects() if s.name == "hammer")
    body = load_object(client, s, (0, 0, 0.1))
    info = client.getDynamicsInfo(body, -1)
    assert info[0] == pytest.approx(s.mass)
    assert info[1] == pytest.approx(s.friction)
    # the hammer's inertia from the URDF: long along x, so Ixx is the smallest moment
    inertia = np.array(info[2])
    assert inertia.min() < 0.2 * inertia.max()
    with pytest.raises(FileNotFoundError):
        load_object(client, ObjectSpec("ghost", Path("/nonexistent/ghost.urdf")), (0, 0, 0))


def test_condition_inertia_floors_a_thin_rod_and_leaves_a_box():
    # a solid square rod 4 mm x 4 mm x 20 cm, 10 g: roll moment m t^2 / 6, tumble m L^2 / 12
    m, t, length = 0.01, 0.004, 0.2
    rod = np.array([m * t**2 / 6, m * (length**2 + t**2) / 12, m * (length**2 + t**2) / 12])
    before = rod.copy()
    out = condition_inertia(rod)
    assert np.array_equal(rod, before)  # input untouched
    assert out[0] == pytest.approx(MIN_INERTIA_RATIO * rod.max())
    assert out[1:] == pytest.approx(rod[1:])
    box = np.array([2e-5, 3e-5, 4e-5])
    assert np.array_equal(condition_inertia(box), box)
    assert np.array_equal(condition_inertia(rod, min_ratio=0.0), rod)
    for bad in ([1e-6, 1e-6], [1e-6, -1e-6, 1e-6], [np.nan, 1e-6, 1e-6]):
        with pytest.raises(ValueError, match="inertia"):
            condition_inertia(bad)
    with pytest.raises(ValueError, match="min_ratio"):
        condition_inertia(box, min_ratio=1.5)


def test_load_object_floors_the_chopsticks_roll_inertia_only(client):
    specs = {s.name: s for s in builtin_objects()}
    for name, floored in (("chopstick", True), ("box_small", False)):
        s = specs[name]
        raw = client.loadURDF(str(s.urdf), flags=client.URDF_USE_INERTIA_FROM_FILE)
        info = client.getDynamicsInfo(raw, -1)
        file_inertia = np.array(info[2]) * (s.mass / info[0])
        inertia = np.array(client.getDynamicsInfo(load_object(client, s, (0, 0, 0.1)), -1)[2])
        assert (file_inertia.min() < MIN_INERTIA_RATIO * file_inertia.max()) == floored
        assert inertia.min() >= MIN_INERTIA_RATIO * inertia.max() * (1 - 1e-6)
        assert inertia.max() == pytest.approx(file_inertia.max(), rel=1e-6)
        if not floored:
            assert inertia == pytest.approx(file_inertia, rel=1e-6)


def test_mug_is_hollow(client):
    s = next(s for s in builtin_objects() if s.name == "mug_classic")
    load_object(client, s, (0, 0, 0))
    hit = client.rayTest((0, 0, 0.3), (0, 0, -0.3))[0]
    # the ray down the mug's axis passes the opening and hits the inner floor
    floor = -s.size[2] / 2 + 0.006
    assert hit[3][2] == pytest.approx(floor, abs=0.003)


def _obj_parts(path: Path) -> list[tuple[np.ndarray, np.ndarray]]:
    """(vertices, faces) of each ``o`` group of a generated OBJ file, faces 0-based per part."""
    parts, verts, base = [], [], 0
    for line in path.read_text().splitlines():
        if line.startswith("o "):
            parts.append([])
        elif line.startswith("v "):
            verts.append([float(x) for x in line.split()[1:]])
        elif line.startswith("f "):
            parts[-1].append([int(i) - 1 for i in line.split()[1:]])
    out = []
    for faces in parts:
        f = np.array(faces)
        lo, hi = f.min(), f.max()
        assert lo == base, f"{path}: parts do not list their vertices in order"
        out.append((np.array(verts[lo:hi + 1]), f - lo))
        base = hi + 1
    return out


def _inertia_tensor(inertial) -> np.ndarray:
    """The URDF inertia about the centre of mass, in the link frame (principal moments rotated by
    the origin's rpy)."""
    from scipy.spatial.transform import Rotation

    rpy = [float(x) for x in inertial.find("origin").get("rpy").split()]
    I = inertial.find("inertia")
    R = Rotation.from_euler("xyz", rpy).as_matrix()
    return R @ np.diag([float(I.get(k)) for k in ("ixx", "iyy", "izz")]) @ R.T


def test_generator_reproduces_every_committed_object(tmp_path, manifest, monkeypatch):
    # What the files mean, not their bytes: on another CPU or BLAS kernel set the same
    # geometry can come out with a coplanar facet split along the other diagonal, and an
    # object with two equal principal moments (a pen) with another, equivalent principal frame.
    import trimesh

    spec = importlib.util.spec_from_file_location("make_objects", REPO / "scripts/make_objects.py")
    mod = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, "make_objects", mod)  # dataclasses look the module up
    spec.loader.exec_module(mod)
    mod.build(tmp_path)
    assert json.loads((tmp_path / "manifest.json").read_text()) == manifest
    atol = 1.5e-5  # m: the files print 5 decimals; a value on a rounding boundary may flip
    for entry in manifest["objects"]:
        name = entry["name"]
        for suffix in (".obj", "_collision.obj"):
            new, old = (_obj_parts(root / name / f"{name}{suffix}")
                        for root in (tmp_path, assets_dir()))
            assert len(new) == len(old), f"{name}{suffix}: number of parts"
            for (v1, f1), (v0, f0) in zip(new, old, strict=True):
                assert v1.shape == v0.shape and f1.shape == f0.shape, f"{name}{suffix}"
                np.testing.assert_allclose(v1, v0, rtol=0, atol=atol, err_msg=f"{name}{suffix}")
                m1, m0 = trimesh.Trimesh(v1, f1, process=False), trimesh.Trimesh(v0, f0,
                                                                                 process=False)
                assert m1.volume == pytest.approx(m0.volume, rel=1e-3), f"{name}{suffix}"
                assert m1.area == pytest.approx(m0.area, rel=1e-3), f"{name}{suffix}"
        new, old = (ET.parse(root / name / f"{name}.urdf").getroot()
                    for root in (tmp_path, assets_dir()))
        i1, i0 = new.find("link/inertial"), old.find("link/inertial")
        np.testing.assert_allclose(  # the moments are printed with 4 significant digits
            _inertia_tensor(i1), _inertia_tensor(i0), rtol=0,
            atol=1e-3 * np.abs(_inertia_tensor(i0)).max(), err_msg=f"{name}.urdf inertia")
        xyz = [np.array(i.find("origin").get("xyz").split(), float) for i in (i1, i0)]
        np.testing.assert_allclose(*xyz, rtol=0, atol=atol, err_msg=f"{name}.urdf centre of mass")
        for i in (i1, i0):  # the rest of the file, word for word
            i.remove(i.find("origin"))
            i.remove(i.find("inertia"))
        assert ET.tostring(new) == ET.tostring(old), f"{name}.urdf"


# --------------------------------------------------------------------------- other object sets


def test_random_urdfs_follow_the_kuka_diverse_rule():
    root = Path(pybullet_data.getDataPath()) / "random_urdfs"
    if not root.is_dir():
        pytest.skip(f"pybullet_data has no random_urdfs at {root}")
    all_, train, test = (random_urdf_objects(s) for s in ("all", "train", "test"))
    assert len(all_) == 1000 and len(test) == 100 and len(train) == 900
    assert all(s.urdf.parent.name.endswith("0") for s in test)
    assert not any(s.urdf.parent.name.endswith("0") for s in train)
    s = all_[0]
    assert s.name == "random_000" and s.split == "test"
    assert all(0.001 < x < 0.3 for x in s.size)
    assert not s.inertia_from_file
    with pytest.raises(FileNotFoundError):
        random_urdf_objects(root=root / "nope")


def test_random_urdf_loads(client):
    s = random_urdf_objects("test")[3]
    body = load_object(client, s, (0, 0, 0.1))
    lo, hi = client.getAABB(body)
    assert np.all(np.subtract(hi, lo) > 0.005)


def test_folder_objects_from_obj_and_urdf(tmp_path, client):
    trimesh = pytest.importorskip("trimesh")
    (tmp_path / "ycb_like" / "001_block").mkdir(parents=True)
    box = trimesh.creation.box((0.04, 0.03, 0.02))
    box.export(tmp_path / "ycb_like" / "001_block" / "textured.obj")
    cyl = trimesh.creation.cylinder(radius=0.05, height=0.02)
    cyl.export(tmp_path / "disk.obj")
    (tmp_path / "cube").mkdir()
    (tmp_path / "cube" / "cube.urdf").write_text(
        '<robot name="cube"><link name="cube"><inertial><mass value="0.1"/>'
        '<inertia ixx="1e-5" ixy="0" ixz="0" iyy="1e-5" iyz="0" izz="1e-5"/></inertial>'
        '<visual><geometry><box size="0.05 0.05 0.05"/></geometry></visual>'
        '<collision><geometry><box size="0.05 0.05 0.05"/></geometry></collision>'
        "</link></robot>"
    )
    specs = {s.name: s for s in folder_objects(tmp_path, mass=0.2)}
    assert set(specs) == {"cube__cube", "disk", "ycb_like__001_block__textured"}
    block = specs["ycb_like__001_block__textured"]
    np.testing.assert_allclose(sorted(block.size), [0.02, 0.03, 0.04], atol=1e-4)
    assert block.graspable and not specs["disk"].graspable
    assert block.urdf.parent == tmp_path / ".graspsim_urdf"
    np.testing.assert_allclose(specs["cube__cube"].size, [0.05] * 3, atol=2e-3)
    assert {s.split for s in specs.values()} == {"train", "test"}
    for s in specs.values():
        body = load_object(client, s, (0, 0, 0.2))
        assert client.getDynamicsInfo(body, -1)[0] == pytest.approx(0.2)
    # re-scanning skips the generated cache and gives the same objects
    assert {s.name for s in folder_objects(tmp_path)} == set(specs)
    with pytest.raises(FileNotFoundError):
        folder_objects(tmp_path / "missing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(FileNotFoundError, match="no .urdf or .obj"):
        folder_objects(tmp_path / "empty")

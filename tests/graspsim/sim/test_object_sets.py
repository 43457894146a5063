"""One object-set syntax on every command: parsing, folders, bad input, fingerprints, the
record in config.json and the refused resume, the commands, run configs and the environment."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import pytest

from graspsim.cli import main
from graspsim.eval.trials import TrialConfig, run_trials
from graspsim.labels.graspability import resolve_objects
from graspsim.sim.bullet import pybullet_data
from graspsim.sim.object_sets import ObjectSet, check_units, parse_object_set

trimesh = pytest.importorskip("trimesh")


def _mesh_folder(root: Path, boxes=((0.04, 0.03, 0.02), (0.05, 0.02, 0.03))) -> Path:
    root.mkdir(parents=True, exist_ok=True)
    for i, extents in enumerate(boxes):
        trimesh.creation.box(extents).export(root / f"box{i}.obj")
    return root


def test_parse_every_form():
    assert parse_object_set("test") == ObjectSet(text="test", source="builtin", split="test")
    s = parse_object_set(" can_soda, bottle_water ")
    assert (s.source, s.names) == ("builtin", ("can_soda", "bottle_water"))
    assert parse_object_set("random_urdfs").split == "all"
    assert parse_object_set("random_urdfs:test").split == "test"
    f = parse_object_set("folder:/data/ycb:train", scale=0.001, mass=0.2, decompose=True)
    assert (f.source, f.path, f.split, f.scale, f.mass, f.decompose) == (
        "folder", "/data/ycb", "train", 0.001, 0.2, True)
    assert parse_object_set("folder:C:/meshes").path == "C:/meshes"  # only a split is cut off


@pytest.mark.parametrize("text, match", [
    ("", "non-empty"), ("random_urdfs:val", "split must be"), ("folder:", "needs a path"),
    ("shapenet:test", "choose train, test"),
])
def test_parse_refuses_bad_text(text, match):
    with pytest.raises(ValueError, match=match):
        parse_object_set(text)


@pytest.mark.parametrize("kw", [{"scale": 0}, {"scale": -1.0}, {"mass": 0.0}, {"mass": True}])
def test_parse_refuses_bad_scale_or_mass(kw):
    with pytest.raises(ValueError, match="must be a number > 0"):
        parse_object_set("test", **kw)


def test_builtin_names_keep_the_set_order_and_unknown_names_are_listed():
    names = [s.name for s in resolve_objects("can_soda,bottle_water")]
    assert names == [s.name for s in resolve_objects("bottle_water,can_soda")]
    with pytest.raises(ValueError, match="no built-in object named nope.*random_urdfs"):
        resolve_objects("can_soda,nope")


def test_scale_and_mass_apply_to_builtin_objects():
    plain = parse_object_set("can_soda").specs()[0]
    s = parse_object_set("can_soda", scale=2.0, mass=0.3).specs()[0]
    assert s.scale == 2 * plain.scale and s.mass == 0.3
    assert s.size == pytest.approx(tuple(2 * x for x in plain.size))


def test_random_urdfs_test_split():
    if not (Path(pybullet_data.getDataPath()) / "random_urdfs").is_dir():
        pytest.skip("pybullet_data has no random_urdfs")
    specs = resolve_objects("random_urdfs:test")
    assert len(specs) == 100 and all(s.urdf.parent.name.endswith("0") for s in specs)


def test_folder_set_objects_and_split(tmp_path):
    folder = _mesh_folder(tmp_path / "meshes", [(0.04, 0.03, 0.02)] * 8)
    every = resolve_objects(f"folder:{folder}")
    test = resolve_objects(f"folder:{folder}:test")
    assert len(every) == 8 and [s.name for s in test] == ["box0", "box4"]
    assert every[0].size == pytest.approx((0.04, 0.03, 0.02))


def test_missing_and_empty_folders_are_one_line_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="object folder not found"):
        resolve_objects(f"folder:{tmp_path / 'nope'}")
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "readme.txt").write_text("no meshes here")
    with pytest.raises(FileNotFoundError, match="no .urdf or .obj files"):
        resolve_objects(f"folder:{tmp_path / 'empty'}")


def test_a_mesh_in_millimetres_suggests_the_scale(tmp_path):
    folder = _mesh_folder(tmp_path / "mm", [(40.0, 30.0, 20.0)])
    with pytest.raises(ValueError, match=r"box0.*40 m across.*--object-scale 0\.001") as e:
        resolve_objects(f"folder:{folder}")
    assert "\n" not in str(e.value)
    specs = parse_object_set(f"folder:{folder}", scale=0.001).specs()
    assert specs[0].size == pytest.approx((0.04, 0.03, 0.02))
    tiny = _mesh_folder(tmp_path / "km", [(0.00004, 0.00003, 0.00002)])
    with pytest.raises(ValueError, match="under 5 mm"):
        resolve_objects(f"folder:{tiny}")


def test_check_units_passes_the_builtin_set():
    check_units(resolve_objects("all"))


def test_a_urdf_pybullet_cannot_load_is_a_one_line_error(tmp_path):
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "thing.urdf").write_text(
        '<robot name="thing"><link name="thing"><visual><geometry>'
        '<mesh filename="missing.obj"/></geometry></visual></link></robot>')
    with pytest.raises(ValueError, match=r"thing\.urdf") as e:
        resolve_objects(f"folder:{tmp_path / 'bad'}")
    assert "\n" not in str(e.value)


def test_fingerprint_follows_the_files_bytes(tmp_path):
    folder = _mesh_folder(tmp_path / "m")
    oset = parse_object_set(f"folder:{folder}")
    fp = oset.fingerprint()
    assert fp == parse_object_set(f"folder:{folder}", mass=0.5).fingerprint()
    rec = oset.record()
    assert rec["fingerprint"] == fp and rec["source"] == "folder" and rec["n_objects"] == 2
    trimesh.creation.box((0.041, 0.03, 0.02)).export(folder / "box0.obj")
    assert parse_object_set(f"folder:{folder}").fingerprint() != fp
    assert parse_object_set("test").fingerprint() != parse_object_set("train").fingerprint()


def test_trials_record_the_set_and_refuse_another_on_resume(tmp_path):
    folder = _mesh_folder(tmp_path / "m")
    out = tmp_path / "t"
    cfg = TrialConfig(n_candidates=0)
    run_trials("random", objects=f"folder:{folder}", n=0, out=out, config=cfg)
    rec = json.loads((out / "config.json").read_text())
    assert rec["objects"] == f"folder:{folder}"
    assert rec["object_set"]["fingerprint"] == parse_object_set(f"folder:{folder}").fingerprint()
    run_trials("random", objects=f"folder:{folder}", n=0, out=out, config=cfg)  # same set: ok
    with pytest.raises(ValueError,
                       match=r"object set 'folder:.*' \(fingerprint .*\), not 'test'") as e:
        run_trials("random", objects="test", n=0, out=out, config=cfg)
    assert "\n" not in str(e.value)
    with pytest.raises(ValueError, match="scale 1.0.*scale 2.0"):
        run_trials("random", objects=parse_object_set(f"folder:{folder}", scale=2.0), n=0,
                   out=out, config=cfg)


def test_a_changed_file_refuses_the_resume(tmp_path):
    folder = _mesh_folder(tmp_path / "m")
    out = tmp_path / "t"
    cfg = TrialConfig(n_candidates=0)
    run_trials("random", objects=f"folder:{folder}", n=0, out=out, config=cfg)
    trimesh.creation.box((0.045, 0.03, 0.02)).export(folder / "box1.obj")
    with pytest.raises(ValueError, match="holds results on object set"):
        run_trials("random", objects=f"folder:{folder}", n=0, out=out, config=cfg)


def test_an_old_folder_without_the_record_resumes(tmp_path):
    out = tmp_path / "t"
    cfg = TrialConfig(n_candidates=0)
    run_trials("random", objects="can_soda", n=0, out=out, config=cfg)
    path = out / "config.json"
    old = json.loads(path.read_text())
    del old["object_set"]
    path.write_text(json.dumps(old))
    run_trials("random", objects="can_soda", n=0, out=out, config=cfg)


@pytest.mark.sim
def test_cli_trials_on_a_folder(tmp_path, capsys):
    folder = _mesh_folder(tmp_path / "m")
    out = tmp_path / "t"
    assert main(["trials", "--detector", "mask-pca", "--objects", f"folder:{folder}", "--n", "1",
                 "--candidates", "0", "--object-mass", "0.05", "--out", str(out)]) == 0
    assert capsys.readouterr().out.startswith("mask-pca: success ")
    rec = json.loads((out / "config.json").read_text())["object_set"]
    assert rec["mass"] == 0.05 and rec["text"] == f"folder:{folder}"
    assert len((out / "trials.jsonl").read_text().splitlines()) == 1


def test_cli_refuses_a_bad_set_in_one_line(tmp_path, capsys):
    code = main(["trials", "--detector", "random", "--objects", f"folder:{tmp_path / 'x'}",
                 "--n", "1", "--out", str(tmp_path / "t")])
    err = capsys.readouterr().err
    assert code != 0 and "object folder not found" in err and "Traceback" not in err


@pytest.mark.sim
def test_dataset_from_a_folder_of_obj_files(tmp_path):
    folder = _mesh_folder(tmp_path / "m")
    out = tmp_path / "d"
    assert main(["dataset", "--scenes", "1", "--candidates", "4", "--objects",
                 f"folder:{folder}", "--out", str(out)]) == 0
    cfg = json.loads((out / "dataset_config.json").read_text())
    assert cfg["object_set"]["source"] == "folder"
    manifest = json.loads((out / "scenes.json").read_text())
    assert manifest["generator"]["object_set"] == cfg["object_set"]
    with pytest.raises(ValueError, match="holds results on object set"):
        from graspsim.data.datagen import make_dataset

        make_dataset(n_scenes=1, objects="train", out=out, n_candidates=4)


def test_score_objects_must_have_the_datasets_fingerprint(tmp_path):
    from graspsim.data.manifest import relocated_specs as _relocated_specs

    folder = _mesh_folder(tmp_path / "m")
    rec = parse_object_set(f"folder:{folder}").record()
    manifest = {"generator": {"object_set": rec}, "object_specs": {"box0": {"urdf": {}}}}
    records, recorded = _relocated_specs(manifest, f"folder:{folder}", tmp_path)
    assert recorded == rec and Path(records["box0"]["urdf"]["path"]).is_file()
    with pytest.raises(ValueError, match="are not the objects of dataset"):
        _relocated_specs(manifest, "test", tmp_path)


def test_run_config_takes_object_sets(tmp_path):
    from graspsim.pipeline import RunConfig

    folder = _mesh_folder(tmp_path / "m")
    cfg = RunConfig(trial_objects=f"folder:{folder}", object_mass=0.2).validated()
    assert cfg.object_set("trial_objects").mass == 0.2
    assert [s.name for s in cfg.object_set("trial_objects").specs()] == ["box0", "box1"]
    with pytest.raises(ValueError, match="trial_objects: object folder not found"):
        RunConfig(trial_objects=f"folder:{tmp_path / 'x'}").validated()
    with pytest.raises(ValueError, match="train_objects: object scale"):
        RunConfig(object_scale=-1.0).validated()


def test_env_takes_an_object_set(tmp_path):
    from graspsim.env import GraspEnv

    folder = _mesh_folder(tmp_path / "m")
    env = GraspEnv(objects=f"folder:{folder}")
    assert [s.name for s in env.specs] == ["box0", "box1"]
    env = GraspEnv(objects=parse_object_set(f"folder:{folder}", mass=0.3))
    assert {s.mass for s in env.specs} == {0.3}


def test_vhacd_log_goes_to_debug_not_stdout(tmp_path, capfd, caplog):
    folder = tmp_path / "concave"
    folder.mkdir()
    a = trimesh.creation.box((0.06, 0.02, 0.02))
    b = trimesh.creation.box((0.02, 0.06, 0.02))
    b.apply_translation((0.02, 0.02, 0.0))
    trimesh.util.concatenate([a, b]).export(folder / "ell.obj")
    capfd.readouterr()
    with caplog.at_level(logging.DEBUG, logger="graspsim.sim.objects"):
        specs = resolve_objects(parse_object_set(f"folder:{folder}", decompose=True))
    out, err = capfd.readouterr()
    assert out == "" and "V-HACD" not in err
    assert len(specs) == 1 and (folder / ".graspsim_urdf" / "ell_vhacd.obj").is_file()
    assert any(r.levelno == logging.DEBUG for r in caplog.records
               if r.name == "graspsim.sim.objects")

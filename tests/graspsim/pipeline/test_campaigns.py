"""Campaigns of the default job's detectors (graspsim.pipeline.campaigns), on written trial
folders."""

from __future__ import annotations

import json

import pytest

from graspsim.pipeline.campaigns import campaign_folder, table_markdown, table_only, trial_table
from graspsim.sim.object_sets import parse_object_set


def _trials(folder, outcomes, objects=("can_tall",)):
    folder.mkdir(parents=True)
    with (folder / "trials.jsonl").open("w") as fh:
        for i, ok in enumerate(outcomes):
            fh.write(json.dumps({"index": i, "success": ok, "object": list(objects)}) + "\n")


def test_the_table_pairs_the_trials_every_detector_finished(tmp_path):
    folder = campaign_folder(tmp_path, "can_tall,box_matches")
    assert folder == tmp_path / "can_tall,box_matches"
    _trials(folder / "dlsr", [True, True, False, True, True])
    _trials(folder / "mask-pca", [False, True, False, True])  # one trial fewer
    oset = parse_object_set("can_tall,box_matches")
    t = trial_table(folder, ["dlsr", "mask-pca"], oset, compute=False)
    assert t["indices"] == 4 and t["objects"] == "can_tall,box_matches"
    dlsr, pca = t["rows"]
    assert (dlsr["successes"], dlsr["n"], pca["successes"]) == (3, 4, 2)
    assert dlsr["vs_mask_pca"]["counts"] == {"both": 2, "only_a": 1, "only_b": 0, "neither": 1}
    assert "vs_mask_pca" not in pca
    assert dlsr["ci95"][0] < 0.75 < dlsr["ci95"][1]
    text = table_markdown(t)
    assert "| dlsr | 3/4 = 75.0 % |" in text and "| mask-pca | 2/4 = 50.0 % |" in text


def test_table_only_writes_beside_the_trials(tmp_path):
    folder = campaign_folder(tmp_path, "can_tall")
    _trials(folder / "mask-pca", [True, False])
    t = table_only(tmp_path, "can_tall", ["mask-pca"])
    assert json.loads((folder / "table.json").read_text()) == json.loads(json.dumps(t))
    assert (folder / "table.md").read_text() == table_markdown(t)


def test_a_missing_detector_folder_is_named(tmp_path):
    with pytest.raises(FileNotFoundError, match="trials.jsonl"):
        table_only(tmp_path, "can_tall", ["dlsr"])

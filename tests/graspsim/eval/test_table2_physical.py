"""Table 2's detections executed in the stand-in's rebuilt scenes: rows of both benchmark
layouts, the pair with mask-pca, sizes kept across runs, and records that do not match."""

from __future__ import annotations

import json

import pytest

from graspsim.data.standin import usable_scenes
from graspsim.eval.offline.table2_physical import benchmark_folders, execute_table2

pytestmark = pytest.mark.sim


@pytest.fixture(scope="module")
def labelled(small_labelled_dataset):
    root, _, samples = small_labelled_dataset
    usable = usable_scenes(samples)
    assert len(usable) >= 2, "the tests need two scenes with a positive and a negative"
    return root, usable


def _rect(r):
    return [r.x, r.y, r.theta, r.w, r.h]


def _write(folder, records):
    folder.mkdir(parents=True)
    (folder / "results.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))


def _record(k, sample, rect, success, pca):
    return {"image_id": f"{k:04d}", "object_id": sample.object_id, "rect": rect,
            "success": success, "baselines": {"random": False, "mask-pca": pca}}


def test_rows_executed_beside_mask_pca_and_sizes_kept(labelled, tmp_path):
    root, usable = labelled
    bench = tmp_path / "bench"
    # one-pass layout: a labelled positive, then an image without a detection
    _write(bench / "table2_2" / "NKM-Natural_image",
           [_record(0, usable[0], _rect(usable[0].positives[0]), True, False),
            _record(1, usable[1], None, False, True)])
    # one folder per command: labelled negatives
    _write(bench / "table2_2_RP-Natural_object",
           [_record(k, usable[k], _rect(usable[k].negatives[0]), False, False)
            for k in range(2)])
    assert sorted((r, s) for _, r, s in benchmark_folders([bench], 2)) == [
        ("NKM-Natural", "image"), ("RP-Natural", "object")]

    out = tmp_path / "out"
    report = execute_table2(root, [bench], [2], out)
    rows = report["sizes"]["2"]
    assert set(rows) == {"NKM-Natural image", "RP-Natural object", "mask-pca"}
    ids = [s.image_id for s in usable[:2]]
    for name, slug in (("NKM-Natural image", "NKM-Natural_image"),
                       ("RP-Natural object", "RP-Natural_object"), ("mask-pca", "mask-pca")):
        scores = {json.loads(line)["image"]: json.loads(line)
                  for line in (out / "2" / slug / "scores.jsonl").read_text().splitlines()}
        lifted = sum(bool(scores[i]["success"]) for i in ids)
        assert rows[name]["physical"]["k"] == lifted
        assert sum(rows[name]["reasons"].values()) == 2
        assert rows[name]["reasons"].get("lifted", 0) == lifted
    # the image without a detection is not lifted; a labelled positive keeps its label
    nkm = rows["NKM-Natural image"]
    assert nkm["physical"]["k"] == 1
    assert nkm["metric_table2"]["k"] == 1 and nkm["mask_pca_metric_table2"]["k"] == 1
    assert nkm["metric_vs_physics"] == {"right_lifted": 1, "right_dropped": 0,
                                        "wrong_lifted": 0, "wrong_dropped": 1}
    pair = nkm["vs_mask_pca"]
    assert pair["both"] + pair["only_a"] + pair["only_b"] + pair["neither"] == 2
    assert pair["both"] + pair["only_a"] == nkm["physical"]["k"]
    assert pair["both"] + pair["only_b"] == rows["mask-pca"]["physical"]["k"]
    assert rows["RP-Natural object"]["physical"]["k"] == 0
    assert rows["RP-Natural object"]["metric_table2"]["k"] == 0

    # another size later: the first one stays in the report and the Markdown
    _write(bench / "table2_1" / "NKM-SC_image",
           [_record(0, usable[0], _rect(usable[0].positives[0]), True, False)])
    again = execute_table2(root, [bench], [1], out)
    assert set(again["sizes"]) == {"1", "2"}
    assert again["sizes"]["2"] == json.loads(json.dumps(rows))
    md = (out / "table2_physical.md").read_text()
    assert md.index("## 1 images") < md.index("## 2 images")
    assert "| NKM-SC image | 1/1 = 100 %" in md


def test_records_of_another_standin_name_the_folder(labelled, tmp_path):
    root, usable = labelled
    bench = tmp_path / "bench"
    wrong = usable[1].object_id if usable[1].object_id != usable[0].object_id else "other"
    rec = _record(0, usable[0], None, False, False)
    _write(bench / "table2_1" / "NKM-Natural_image", [{**rec, "object_id": wrong}])
    with pytest.raises(ValueError, match=r"NKM-Natural_image: image 0000 shows"):
        execute_table2(root, [bench], [1], tmp_path / "out")
    _write(bench / "table2_1" / "OMP-Natural_image", [_record(5, usable[0], None, False, False)])
    (bench / "table2_1" / "NKM-Natural_image" / "results.jsonl").unlink()
    with pytest.raises(ValueError, match=r"OMP-Natural_image: image 0005 is past"):
        execute_table2(root, [bench], [1], tmp_path / "out")
    with pytest.raises(ValueError, match=r"usable labelled scenes, 100 needed"):
        execute_table2(root, [bench], [100], tmp_path / "out")
    with pytest.raises(ValueError, match=r"no Table 2 benchmark of 2 images"):
        execute_table2(root, [tmp_path / "empty"], [2], tmp_path / "out")

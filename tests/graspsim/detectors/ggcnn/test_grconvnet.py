"""GR-ConvNet with torch: the published architecture's size, its RGB-D input, training (loss,
determinism, resume), the model files (weights-only, checksummed, one-line errors for a
truncated file or another network's), the detector protocol, trials, run configs, the CLI and
the offline benchmark. Tiny images and k keep the file fast."""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest

from dlsr.datasets import write_cornell

torch = pytest.importorskip("torch")

from test_ggcnn import TINY as GG_TINY  # noqa: E402
from test_ggcnn import tiny_samples  # noqa: E402

from graspsim.cli import main  # noqa: E402
from graspsim.detectors import (  # noqa: E402
    GripperAwareDetector,
    check_detector,
    load_detector,
)
from graspsim.detectors.ggcnn.detector import GGCNNDetector, GRConvNetDetector, crop_input  # noqa: E402
from graspsim.detectors.ggcnn.grconvnet import build_grconvnet, grconvnet_parameter_count  # noqa: E402
from graspsim.detectors.ggcnn.maps import grasp_maps, prepare_rgb  # noqa: E402
from graspsim.detectors.ggcnn.model import load_model, model_paths, n_parameters  # noqa: E402
from graspsim.detectors.ggcnn.train import augment, train_ggcnn, train_grconvnet  # noqa: E402

TINY = {"input_size": 48, "crop": 72, "channels": 4, "crop_method": "centre", "threads": 1,
        "progress": False}


def layer_count(k, c_in=4):
    """Parameters of the layer table of Kumra et al. (2020), Fig. 2, written out layer by
    layer: (in, out, kernel) of every convolution, channels of every batch norm."""
    convs = [(c_in, k, 9), (k, 2 * k, 4), (2 * k, 4 * k, 4)]
    convs += [(4 * k, 4 * k, 3)] * 10                       # five residual blocks, two each
    convs += [(4 * k, 2 * k, 4), (2 * k, k, 4), (k, k, 9)]  # transposed convolutions
    convs += [(k, 1, 2)] * 4                                # quality, cos, sin, width
    norms = [k, 2 * k, 4 * k] + [4 * k] * 10 + [2 * k, k]
    return sum(i * o * n * n + o for i, o, n in convs) + sum(2 * c for c in norms)


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    path = tmp_path_factory.mktemp("grconvnet") / "model"
    meta = train_grconvnet(tiny_samples(), path, steps=240, seed=3, checkpoint_every=48,
                           lr=3e-3, **TINY)
    return path, meta


@pytest.mark.parametrize("k", [32, 16])
def test_parameter_count_is_the_published_architectures(k):
    net = build_grconvnet(k)
    assert n_parameters(net) == layer_count(k) == grconvnet_parameter_count(k)
    if k == 32:  # about 1.9 million (the paper; the authors list 1,900,900)
        assert abs(n_parameters(net) - 1.9e6) < 0.01 * 1.9e6
    net.eval()
    with torch.no_grad():
        assert net(torch.zeros(1, 4, 224, 224)).shape == (1, 4, 224, 224)
        assert net(torch.zeros(2, 4, 48, 48)).shape == (2, 4, 48, 48)


def test_rgbd_input_is_depth_then_normalised_colour():
    s = tiny_samples(1)[0]
    x, (row0, col0, scale) = crop_input(s.depth, s.depth_valid, 72, 48, "centre", s.rgb)
    assert x.shape == (4, 48, 48) and x.dtype == np.float32
    depth_only, _ = crop_input(s.depth, s.depth_valid, 72, 48, "centre")
    np.testing.assert_array_equal(x[0], depth_only)
    c = prepare_rgb(s.rgb)
    assert c.shape == (3, 72, 72) and abs(c.mean()) < 1e-6
    np.testing.assert_allclose(c.max() - c.min(), 1.0)  # the bar is white on black: /255
    with pytest.raises(ValueError, match=r"\(H, W, 3\)"):
        prepare_rgb(s.rgb[..., 0])
    with pytest.raises(ValueError, match="rgb has shape"):
        crop_input(s.depth, s.depth_valid, 72, 48, "centre", s.rgb[:70])
    # an image without colour, or with colour of another size, is skipped with a logged line
    from graspsim.detectors.ggcnn.train import prepare_samples

    bad = tiny_samples(3)
    bad[0].rgb = None
    bad[1].rgb = bad[1].rgb[:70]
    X, R, ids = prepare_samples(bad, 72, 48, "centre", "rgbd", "GR-ConvNet")
    assert X.shape == (1, 4, 48, 48) and ids == [bad[2].image_id]
    with pytest.raises(ValueError, match="no image to train GR-ConvNet on"):
        prepare_samples(bad[:2], 72, 48, "centre", "rgbd", "GR-ConvNet")


def test_quarter_turn_augmentation_moves_every_channel_and_the_rectangles(rng):
    r = np.array([[30.0, 20.0, 0.3, 18.0, 6.0]])
    label = grasp_maps(r, (48, 48))[0]
    x = np.stack([label, 2 * label, -label, label])
    for _ in range(4):
        x2, r2 = augment(x, r, rng, rotate="quarter", zoom=None, keep=(0.5, 1.0))
        assert x2.shape == x.shape
        np.testing.assert_allclose(x2[1], 2 * x2[0], atol=1e-6)
        assert np.isclose(np.cos(4 * (r2[0, 2] - r[0, 2])), 1.0, atol=1e-9)  # 90 deg turns
        assert r[0, 3] <= r2[0, 3] <= 2 * r[0, 3] + 1e-9  # kept half to all: x1 to x2
        drawn = grasp_maps(r2, (48, 48))[0] > 0
        warped = x2[0] > 0.5
        assert (drawn & warped).sum() >= 0.7 * max(drawn.sum(), warped.sum())


def test_training_lowers_the_loss_and_saves_a_grconvnet_record(trained):
    path, meta = trained
    t = meta["training"]
    assert t["sample_steps"] == 240 and t["network"] == "grconvnet"
    curve = t["loss_curve"]
    assert len(curve) == 5 and curve[-1][1] < 0.9 * curve[0][1]
    pt, js = model_paths(path)
    record = json.loads(js.read_text())
    assert record["format"] == "grconvnet" and record["channels"] == 4
    assert record["width_scale"] == 24.0  # half the input side
    assert record["sha256"] == hashlib.sha256(pt.read_bytes()).hexdigest()
    state = torch.load(pt, weights_only=True)  # a plain state dict, no pickled objects
    assert all(isinstance(v, torch.Tensor) for v in state.values())
    assert any("running_mean" in k for k in state)  # batch norm's statistics are kept


def test_same_seed_same_weights_resumed_or_not(tmp_path, trained):
    path, _ = trained
    ref = torch.load(model_paths(path)[0], weights_only=True)
    out = tmp_path / "m"
    train_grconvnet(tiny_samples(), out, steps=96, seed=3, checkpoint_every=48, lr=3e-3, **TINY)
    train_grconvnet(tiny_samples(), out, steps=240, seed=3, checkpoint_every=48, lr=3e-3,
                    **TINY)
    got = torch.load(model_paths(out)[0], weights_only=True)
    assert all(torch.equal(ref[k], got[k]) for k in ref)
    other = tmp_path / "other"
    train_grconvnet(tiny_samples(), other, steps=48, seed=4, checkpoint_every=48, lr=3e-3,
                    **TINY)
    diff = torch.load(model_paths(other)[0], weights_only=True)
    assert not all(torch.equal(ref[k], diff[k]) for k in ref)


def test_detector_protocol_ranked_rectangles_in_image_pixels(trained):
    path, _ = trained
    s = tiny_samples(1)[0]
    obs = {"rgb": s.rgb, "depth": s.depth, "depth_valid": s.depth_valid}
    det = GRConvNetDetector(path, top_k=3)
    rects, scores = det.predict(obs)
    assert rects.ndim == 2 and rects.shape[1] == 5 and 1 <= len(rects) <= 3
    assert np.all(np.diff(scores) <= 0)
    assert np.all((rects[:, :2] >= 0) & (rects[:, :2] < 72))
    assert np.allclose(rects[:, 4], rects[:, 3] / 2)
    again, _ = GRConvNetDetector(path, top_k=3).predict(obs)  # eval mode: no dropout
    np.testing.assert_array_equal(rects, again)
    loaded = load_detector(str(path))
    assert isinstance(loaded, GGCNNDetector)
    np.testing.assert_array_equal(loaded.predict(obs)[0][:1], rects[:1])
    aware = load_detector(str(path) + "+aware")  # as run configs and --gripper-aware
    assert isinstance(aware, GripperAwareDetector) and aware.detector.top_k == 40
    check_detector(str(path) + "+aware")
    with pytest.raises(ValueError, match="GR-ConvNet needs the colour image"):
        det.predict({"depth": s.depth, "depth_valid": s.depth_valid})


def test_truncated_file_gives_one_line_naming_it(tmp_path, trained):
    path, _ = trained
    pt, js = model_paths(path)
    bad = tmp_path / "bad"
    bpt, bjs = model_paths(bad)
    bjs.write_text(js.read_text())
    bpt.write_bytes(pt.read_bytes()[: len(pt.read_bytes()) // 2])
    with pytest.raises(ValueError, match="do not match the sha256") as e:
        load_model(bad)
    assert str(bpt) in str(e.value) and "\n" not in str(e.value)
    record = json.loads(js.read_text())  # truncated, and its record rewritten to match
    record["sha256"] = hashlib.sha256(bpt.read_bytes()).hexdigest()
    bjs.write_text(json.dumps(record))
    with pytest.raises(ValueError, match="not a readable weights file") as e:
        load_model(bad)
    assert str(bpt) in str(e.value) and "\n" not in str(e.value)
    assert main(["trials", "--detector", str(bad), "--n", "1", "--out",
                 str(tmp_path / "t")]) == 2


def test_weights_of_another_network_or_size_give_one_line(tmp_path, trained):
    path, _ = trained
    record = json.loads(model_paths(path)[1].read_text())
    # GG-CNN's weights under a GR-ConvNet record
    gg = tmp_path / "gg"
    train_ggcnn(tiny_samples(), gg, steps=8, seed=0, **GG_TINY)
    fake = tmp_path / "fake"
    fpt, fjs = model_paths(fake)
    fpt.write_bytes(model_paths(gg)[0].read_bytes())
    fjs.write_text(json.dumps({**record, "sha256": hashlib.sha256(fpt.read_bytes())
                               .hexdigest()}))
    with pytest.raises(ValueError, match="do not fit GR-ConvNet with channels 4") as e:
        load_model(fake)
    assert str(fpt) in str(e.value) and "\n" not in str(e.value)
    # k = 4 weights under a record saying k = 16
    fjs.write_text(json.dumps({**record, "channels": 16}))
    fpt.write_bytes(model_paths(path)[0].read_bytes())
    with pytest.raises(ValueError, match="do not fit GR-ConvNet with channels 16"):
        load_model(fake)
    # a GG-CNN model asked for as GR-ConvNet
    with pytest.raises(ValueError, match="a GG-CNN model, not GR-ConvNet"):
        GRConvNetDetector(gg).predict({})
    with pytest.raises(ValueError, match="multiple of 4"):
        train_grconvnet(tiny_samples(), tmp_path / "x", steps=8, **{**TINY, "input_size": 50})


def test_cli_train_then_trials(tmp_path, easy_objects, capsys):
    from graspsim.eval.trials import TrialConfig, run_trials

    data = write_cornell(tiny_samples(), tmp_path / "data")
    model = tmp_path / "grconvnet"
    assert main(["train", "grconvnet", "--data", str(data), "--out", str(model), "--steps",
                 "16", "--channels", "16", "--input-size", "48", "--crop", "72",
                 "--threads", "1"]) == 0
    assert "GR-ConvNet k = 16, 16 sample-steps on 4 images" in capsys.readouterr().out
    assert json.loads(model_paths(model)[1].read_text())["dropout"] == 0.1
    for name in (str(model), str(model) + "+aware"):
        s = run_trials(name, easy_objects, n=2, seed=0, config=TrialConfig(n_candidates=0))
        assert s["n"] == 2
        assert not any(str(r["reason"]).startswith("detector error") for r in s["records"])


def test_offline_benchmark_on_dlsrs_folds(tmp_path, capsys):
    from dlsr.datasets import object_wise_folds
    from graspsim.data.samples import load_samples

    data = write_cornell(tiny_samples(), tmp_path / "data")
    out = tmp_path / "bench"
    args = ["benchmark", "detection", "--data", str(data), "--format", "cornell",
            "--detector", "grconvnet", "--folds", "2", "--ggcnn-steps", "8",
            "--ggcnn-input-size", "48", "--grconvnet-channels", "16", "--out", str(out)]
    assert main(args) == 0
    assert "GR-ConvNet accuracy" in capsys.readouterr().out
    s = json.loads((out / "grconvnet.json").read_text())
    assert s["n"] == 4 and s["config"]["network"] == "grconvnet"
    assert s["config"]["train"] == {"channels": 16, "input_size": 48}
    assert len(list((out / "models").glob("grconvnet_*_fold?.json"))) == 2
    samples = load_samples(data, "cornell")
    by_fold = {r["image_id"]: r["fold"] for r in s["per_image"]}
    for k, (_, test) in enumerate(object_wise_folds(samples, 2, 0)):
        assert {by_fold[samples[i].image_id] for i in test} == {k}
    assert "| GR-ConvNet |" in (out / "grconvnet.md").read_text()


def test_run_configs_accept_grconvnet_raw_and_aware(trained, monkeypatch):
    from graspsim.pipeline import RunConfig
    from graspsim.pipeline.plan import trial_names

    path, _ = trained
    monkeypatch.chdir(path.parent)
    cfg = RunConfig(baselines=["mask-pca", "model", "model+aware"]).validated()
    assert trial_names(cfg)[-2:] == ["model", "model+aware"]


def test_clutter_rounds_run_it_gripper_aware(trained, easy_objects):
    from graspsim.eval.declutter import run_rounds
    from graspsim.eval.trials import TrialConfig

    path, _ = trained
    s = run_rounds(str(path) + "+aware", easy_objects, n=1, seed=0,
                   config=TrialConfig(n_candidates=0, n_objects=2))
    (r,) = s["records"]
    assert r["attempts"]
    assert not str(r["end"]).startswith("detector error")

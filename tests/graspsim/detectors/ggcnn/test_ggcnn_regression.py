"""GG-CNN's behaviour is kept across the refactor that made its data, training and files shared
with GR-ConvNet: committed GG-CNN models (``results/ggcnn-curve/models``) load and give the
maps and rectangles they gave before it, a committed checkpoint still loads, and a short
training run gives the weights it gave before (to float32 rounding: training has run in the
channels-last layout since).

``data/ggcnn_reference.npz`` was written by :func:`reference_outputs` with the code as it was
before the refactor (``python tests/graspsim/detectors/ggcnn/test_ggcnn_regression.py``); the
comparison is
exact up to float32 rounding of the network on this CPU (BLAS kernels may differ elsewhere,
hence the small tolerance on the maps).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")

REPO = Path(__file__).resolve().parents[4]
MODELS = REPO / "results" / "ggcnn-curve" / "models"
REFERENCE = Path(__file__).with_name("data") / "ggcnn_reference.npz"
COMMITTED = ("ggcnn_10", "ggcnn_300_step2000")


def observation():
    """A 480 x 640 view of two boxes on a tilted table with missing pixels (seeded)."""
    rng = np.random.default_rng(7)
    rows, cols = np.mgrid[0:480, 0:640]
    depth = (0.72 + 0.00005 * cols + 0.00003 * rows).astype(np.float32)
    depth[200:260, 250:420] -= 0.04
    depth[300:330, 300:340] -= 0.06
    depth += rng.normal(0, 0.0005, depth.shape).astype(np.float32)
    valid = rng.random(depth.shape) > 0.02
    valid[200:205, 250:300] = False
    depth[~valid] = 0
    rgb = rng.integers(0, 255, (480, 640, 3), dtype=np.uint8)
    return {"rgb": rgb, "depth": depth, "depth_valid": valid}


def _tiny_training(tmp: Path) -> dict:
    from graspsim.detectors.ggcnn.model import model_paths
    from graspsim.detectors.ggcnn.train import train_ggcnn

    sys.path.insert(0, str(Path(__file__).parent))
    from test_ggcnn import TINY, tiny_samples

    out = tmp / "tiny"
    train_ggcnn(tiny_samples(), out, steps=64, seed=5, checkpoint_every=32, lr=5e-3, **TINY)
    state = torch.load(model_paths(out)[0], weights_only=True)
    return {f"train/{k}": v.numpy() for k, v in state.items()}


def reference_outputs(tmp: Path) -> dict:
    """Maps and rectangles of the committed models on :func:`observation`, the tensors of a
    committed checkpoint, and the weights of a 64-sample-step tiny training run."""
    from graspsim.detectors.ggcnn.detector import GGCNNDetector

    out = {}
    obs = observation()
    for name in COMMITTED:
        det = GGCNNDetector(MODELS / name, top_k=10)
        maps, box = det.maps(obs)
        rects, scores = det.predict(obs)
        out[f"{name}/maps"] = maps[:, ::5, ::5]  # a 60 x 60 grid keeps the file small
        out[f"{name}/box"] = np.asarray(box, dtype=np.float64)
        out[f"{name}/rects"] = rects
        out[f"{name}/scores"] = scores
    ck = torch.load(MODELS / "ggcnn_10.ckpt.pt", weights_only=True)
    for k, v in ck["model"].items():
        out[f"ckpt/{k}"] = v.numpy()
    out.update(_tiny_training(tmp))
    return out


@pytest.fixture(scope="module")
def reference():
    if not (MODELS / f"{COMMITTED[0]}.json").is_file():
        pytest.skip(f"committed GG-CNN models absent: {MODELS}")
    with np.load(REFERENCE) as z:
        return dict(z)


def test_committed_ggcnn_models_predict_as_before(reference, tmp_path):
    got = reference_outputs(tmp_path)
    assert set(got) == set(reference)
    for name in COMMITTED:
        np.testing.assert_allclose(got[f"{name}/maps"], reference[f"{name}/maps"], atol=1e-5)
        np.testing.assert_array_equal(got[f"{name}/box"], reference[f"{name}/box"])
        np.testing.assert_allclose(got[f"{name}/rects"], reference[f"{name}/rects"],
                                   atol=1e-6)
        np.testing.assert_allclose(got[f"{name}/scores"], reference[f"{name}/scores"],
                                   atol=1e-5)
    for k in reference:
        if k.startswith("ckpt/"):
            np.testing.assert_array_equal(got[k], reference[k], err_msg=k)
        elif k.startswith("train/"):
            # training runs channels-last since the reference was written: the convolutions
            # sum in another order (largest change measured 2.7e-8, on weights up to 0.29)
            np.testing.assert_allclose(got[k], reference[k], rtol=0, atol=1e-6, err_msg=k)


if __name__ == "__main__":  # writes the reference (only with the code before the refactor)
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        np.savez_compressed(REFERENCE, **reference_outputs(Path(d)))
    print(f"wrote {REFERENCE}")

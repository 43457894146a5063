"""The detector kinds a model builds come from dlsr.detection.registry, not from the model."""

from __future__ import annotations

import pytest

from dlsr import detection
from dlsr.detection import registry


def test_the_builtin_kinds_are_registered_by_their_modules():
    assert set(registry.registered_kinds()) == set(registry.DETECTOR_KINDS)
    assert registry._REGISTRY["dense"].cls is detection.DenseDetector
    assert registry._REGISTRY["exact"].cls is detection.ExactGridDetector
    assert registry._REGISTRY["lattice"].cls is detection.LatticeDetector
    assert not registry._REGISTRY["lattice"].grid_search


class _Model:
    def __init__(self, config):
        self.config = config


class _Recorder:
    def __init__(self, model, **options):
        self.model, self.options = model, options


@pytest.fixture
def recorder_kind():
    registry.register_detector("recorder", _Recorder, grid_search=False)
    yield "recorder"
    registry._REGISTRY.pop("recorder")


def test_build_detector_passes_the_saved_options(recorder_kind):
    model = _Model({"detector": recorder_kind, "top_k": 3, "rescore": 7,
                    "grid": detection.PAPER_GRID.to_dict()})
    det = registry.build_detector(model, coarse_to_fine=True, region="mask")
    assert isinstance(det, _Recorder) and det.model is model
    # saved top_k kept, the call's region wins, the grid search's options dropped
    assert det.options == {"top_k": 3, "region": "mask"}


def test_a_kind_is_not_registered_twice_to_another_class(recorder_kind):
    registry.register_detector(recorder_kind, _Recorder)  # the same class again: fine
    with pytest.raises(ValueError, match="already registered"):
        registry.register_detector(recorder_kind, dict)


def test_an_unknown_kind_is_named():
    with pytest.raises(ValueError, match="unknown detector 'nope'"):
        registry.build_detector(_Model({}), "nope")

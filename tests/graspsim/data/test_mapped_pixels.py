"""Samples whose pixels are memory-mapped from one file
(:func:`graspsim.data.samples.mapped_pixels`): the same values, read-only, sent to loky's workers
as a reference to the file, and the file removed at the end."""

from __future__ import annotations

import dataclasses
import hashlib
import os

import numpy as np
import pytest

from graspsim.data.samples import PIXEL_FIELDS, mapped_pixels
from graspsim.runtime.executor import Executor


@pytest.fixture
def samples(box_samples):
    out = box_samples(3)
    # one sample with an object mask, one whose depth is not C-ordered
    out[1] = dataclasses.replace(out[1], mask=out[1].depth > 0)
    out[2] = dataclasses.replace(out[2], depth=np.asfortranarray(out[2].depth))
    return out


def test_mapped_pixels_keep_every_value_and_field(samples, tmp_path):
    with mapped_pixels(samples, tmp_path) as mapped:
        assert len(mapped) == len(samples)
        for s, m in zip(samples, mapped, strict=True):
            for name in PIXEL_FIELDS:
                a, b = getattr(s, name), getattr(m, name)
                if a is None:
                    assert b is None
                    continue
                assert isinstance(b, np.memmap)
                assert b.dtype == a.dtype and b.shape == a.shape
                np.testing.assert_array_equal(b, a)
                assert not b.flags.writeable
            assert m.image_id == s.image_id and m.positives == s.positives
            assert m.negatives == s.negatives and m.source == s.source
            assert (m.K is None) == (s.K is None)
        folder = os.path.dirname(mapped[0].depth.filename)
        assert os.path.isfile(mapped[0].depth.filename)
        assert os.path.commonpath([folder, str(tmp_path)]) == str(tmp_path)
    assert not os.path.exists(folder)
    for s in samples:  # the inputs are untouched
        assert not isinstance(s.depth, np.memmap)


def test_a_mapped_sample_reaches_a_worker_as_a_reference(samples, depth_source, tmp_path):
    with mapped_pixels(samples, tmp_path) as mapped:
        out = Executor("loky", n_jobs=2, progress=False).map(
            depth_source, [(m,) for m in mapped], star=True)
        for (kind, filename, digest), m, s in zip(out, mapped, samples, strict=True):
            assert kind == "memmap"
            assert os.path.samefile(filename, m.depth.filename)
            assert digest == hashlib.sha256(np.ascontiguousarray(s.depth).tobytes()).hexdigest()

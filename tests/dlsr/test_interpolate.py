"""The hole-filling interpolation equals SciPy's LinearNDInterpolator."""

from __future__ import annotations

import numpy as np
from scipy.interpolate import LinearNDInterpolator

from dlsr.preprocess import _linear_interpolate


def test_matches_linear_nd_interpolator_on_random_points(rng):
    pts = rng.random((200, 2)) * 20
    vals = np.sin(pts[:, 0]) + pts[:, 1] ** 2
    q = rng.random((300, 2)) * 24 - 2  # some outside the hull
    ref = LinearNDInterpolator(pts, vals)(q)
    np.testing.assert_allclose(_linear_interpolate(pts, vals, q), ref, equal_nan=True,
                               rtol=1e-10, atol=1e-10)


def test_matches_on_a_degenerate_pixel_grid(rng):
    valid = rng.random((13, 10)) > 0.35
    z = rng.normal(size=(13, 10))
    pts = np.argwhere(valid).astype(float)
    q = np.argwhere(~valid).astype(float)
    ref = LinearNDInterpolator(pts, z[valid])(q)
    got = _linear_interpolate(pts, z[valid], q)
    # Grid points are co-circular: a query on a shared edge may be located in either
    # triangle, but a linear interpolant agrees there.
    np.testing.assert_allclose(got, ref, equal_nan=True, atol=1e-9)
    # And it is exact for a plane.
    plane = 2 * pts[:, 0] - 3 * pts[:, 1] + 1
    got = _linear_interpolate(pts, plane, q)
    ok = np.isfinite(got)
    np.testing.assert_allclose(got[ok], 2 * q[ok, 0] - 3 * q[ok, 1] + 1, atol=1e-9)

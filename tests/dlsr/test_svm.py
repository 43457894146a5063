"""The squared-hinge SVM and the feature standardiser."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.datasets import make_classification
from sklearn.svm import LinearSVC

from dlsr.svm import FeatureStandardizer, SquaredHingeSVC, squared_hinge_objective


def _objective(model, X, y, C):
    y_pm = np.where(y == model.classes_[1], 1.0, -1.0)
    params = np.r_[model.coef_[0], model.intercept_]
    return squared_hinge_objective(params, X, y_pm, C)[0]


@pytest.mark.parametrize("C", [0.1, 1.0, 10.0])
def test_matches_liblinear_with_C_over_n(C):
    X, y = make_classification(300, 20, random_state=1)
    ours = SquaredHingeSVC(C=C).fit(X, y)
    # LIBLINEAR regularises the intercept; a large intercept_scaling makes that negligible.
    ref = LinearSVC(C=C / len(X), loss="squared_hinge", intercept_scaling=1e3, tol=1e-10,
                    max_iter=200_000).fit(X, y)
    assert _objective(ours, X, y, C) <= _objective(ref, X, y, C) + 1e-6
    np.testing.assert_allclose(ours.coef_, ref.coef_, atol=1e-3)
    assert np.mean(ours.predict(X) == ref.predict(X)) > 0.99


def test_gradient_matches_finite_differences(rng):
    X = rng.normal(size=(40, 5))
    y = np.where(rng.random(40) > 0.5, 1.0, -1.0)
    p = rng.normal(size=6)
    _, g = squared_hinge_objective(p, X, y, 3.0)
    eps = 1e-6
    num = [(squared_hinge_objective(p + eps * e, X, y, 3.0)[0]
            - squared_hinge_objective(p - eps * e, X, y, 3.0)[0]) / (2 * eps) for e in np.eye(6)]
    np.testing.assert_allclose(g, num, rtol=1e-5, atol=1e-6)


def test_bias_is_not_regularised():
    # All points on one side far from the origin: a regularised bias would be pulled to 0.
    X = np.r_[np.full((20, 1), 100.0), np.full((20, 1), 101.0)]
    y = np.r_[np.zeros(20), np.ones(20)]
    model = SquaredHingeSVC(C=100.0).fit(X, y)
    assert np.mean(model.predict(X) == y) == 1.0


def test_separable_string_labels():
    X = np.r_[np.random.default_rng(0).normal(-3, 1, (30, 2)),
              np.random.default_rng(1).normal(3, 1, (30, 2))]
    y = np.array(["bad"] * 30 + ["good"] * 30)
    model = SquaredHingeSVC().fit(X, y)
    assert set(model.predict(X)) == {"bad", "good"}
    assert np.mean(model.predict(X) == y) == 1.0


def test_single_class_is_a_clear_error():
    with pytest.raises(ValueError, match="both\\s+positive and negative"):
        SquaredHingeSVC().fit(np.ones((4, 2)), np.ones(4))


def test_standardizer_uses_var_plus_eps(rng):
    X = rng.normal(2.0, 3.0, size=(100, 3))
    X[:, 2] = 7.0  # constant feature stays finite
    Z = FeatureStandardizer(eps=1e-5).fit(X).transform(X)
    np.testing.assert_allclose(Z.mean(0), 0, atol=1e-12)
    np.testing.assert_allclose(Z[:, :2].var(0), X[:, :2].var(0) / (X[:, :2].var(0) + 1e-5))
    assert np.all(np.isfinite(Z))

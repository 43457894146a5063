"""The paper's classifier: an L2-regularised squared-hinge linear SVM on standardised features.

Following the authors' implementation (see ``shared/reference/dlsr-reference-facts.md``):

* features are standardised per dimension with the training mean and ``sqrt(var + 1e-5)``
  (:class:`FeatureStandardizer`);
* the SVM minimises ``0.5 ||w||^2 + C * mean_i max(0, 1 - y_i (w.x_i + b))^2`` with an
  unregularised bias, by L-BFGS (:class:`SquaredHingeSVC`). This is LIBLINEAR's / scikit-learn's
  ``LinearSVC(loss="squared_hinge")`` with ``C / n_train`` except that LIBLINEAR regularises the
  intercept.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize
from sklearn.base import BaseEstimator, ClassifierMixin, TransformerMixin
from sklearn.utils.multiclass import check_classification_targets
from sklearn.utils.validation import check_is_fitted, validate_data

__all__ = ["FeatureStandardizer", "SquaredHingeSVC", "squared_hinge_objective"]


class FeatureStandardizer(TransformerMixin, BaseEstimator):
    """Standardise each feature with the training mean and ``sqrt(var + eps)``.

    Parameters
    ----------
    eps : float, default=1e-5
        Added to the variance; keeps constant features finite.

    Attributes
    ----------
    mean_ : ndarray of shape (n_features,)
    scale_ : ndarray of shape (n_features,)
    """

    def __init__(self, eps: float = 1e-5):
        self.eps = eps

    def fit(self, X, y=None):
        X = validate_data(self, X, dtype=[np.float64, np.float32])
        if self.eps <= 0:
            raise ValueError(f"eps must be positive, got {self.eps}")
        self.mean_ = X.mean(axis=0)
        self.scale_ = np.sqrt(X.var(axis=0) + self.eps)
        return self

    def transform(self, X):
        check_is_fitted(self)
        X = validate_data(self, X, dtype=[np.float64, np.float32], reset=False)
        return ((X - self.mean_) / self.scale_).astype(X.dtype, copy=False)


def squared_hinge_objective(params, X, y_pm, C):
    """Objective and gradient of the squared-hinge SVM.

    Parameters
    ----------
    params : ndarray of shape (n_features + 1,)
        Weights followed by the bias.
    X : ndarray of shape (n_samples, n_features)
    y_pm : ndarray of shape (n_samples,)
        Labels in {-1, +1}.
    C : float

    Returns
    -------
    value : float
    grad : ndarray of shape (n_features + 1,)
    """
    w, b = params[:-1], params[-1]
    margin = 1.0 - y_pm * (X @ w + b)
    active = margin > 0
    m = np.where(active, margin, 0.0)
    n = X.shape[0]
    value = 0.5 * w @ w + C * (m @ m) / n
    coef = -2.0 * C / n * (y_pm * m)
    grad_w = w + X.T @ coef
    grad_b = coef.sum()
    return value, np.concatenate([grad_w, [grad_b]])


class SquaredHingeSVC(ClassifierMixin, BaseEstimator):
    """Binary linear SVM with the squared hinge loss, solved by L-BFGS.

    Minimises ``0.5 ||w||^2 + C * mean(max(0, 1 - y (X w + b))^2)``; the bias is not regularised.

    Parameters
    ----------
    C : float, default=1.0
        Weight of the mean squared hinge loss.
    tol : float, default=1e-6
        L-BFGS gradient tolerance.
    max_iter : int, default=1000

    Attributes
    ----------
    classes_ : ndarray of shape (2,)
    coef_ : ndarray of shape (1, n_features)
    intercept_ : ndarray of shape (1,)
    n_iter_ : int
    """

    def __init__(self, C: float = 1.0, tol: float = 1e-6, max_iter: int = 1000):
        self.C = C
        self.tol = tol
        self.max_iter = max_iter

    def fit(self, X, y):
        X, y = validate_data(self, X, y, dtype=[np.float64, np.float32])
        check_classification_targets(y)
        if not self.C > 0:
            raise ValueError(f"C must be positive, got {self.C}")
        self.classes_ = np.unique(y)
        if len(self.classes_) != 2:
            raise ValueError(
                f"SquaredHingeSVC is a binary classifier: the training labels have "
                f"{len(self.classes_)} class(es) {self.classes_.tolist()}; a fold needs both "
                f"positive and negative rectangles"
            )
        y_pm = np.where(y == self.classes_[1], 1.0, -1.0)
        X64 = np.asarray(X, dtype=np.float64)
        res = minimize(
            squared_hinge_objective,
            np.zeros(X.shape[1] + 1),
            args=(X64, y_pm, float(self.C)),
            jac=True,
            method="L-BFGS-B",
            options={"gtol": self.tol, "maxiter": self.max_iter, "maxcor": 20},
        )
        self.coef_ = res.x[None, :-1]
        self.intercept_ = res.x[-1:]
        self.n_iter_ = int(res.nit)
        return self

    def decision_function(self, X):
        check_is_fitted(self)
        X = validate_data(self, X, dtype=[np.float64, np.float32], reset=False)
        return X @ self.coef_[0] + self.intercept_[0]

    def predict(self, X):
        return self.classes_[(self.decision_function(X) > 0).astype(int)]


# Instances collected by tests/dlsr/test_estimator_checks.py (parametrize_with_checks).
ESTIMATORS = [FeatureStandardizer(), SquaredHingeSVC()]

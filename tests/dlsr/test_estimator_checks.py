"""scikit-learn's estimator checks on every estimator of the project.

Collected from the modules' ``ESTIMATORS`` lists: ``dlsr.coding`` (encoders),
``dlsr.dictionaries`` (dictionary learners), ``dlsr.whitening`` (standardisation and ZCA) and
``dlsr.svm`` (feature standardiser and the squared-hinge SVM).
"""

from __future__ import annotations

import importlib

import pytest
from sklearn.utils.estimator_checks import parametrize_with_checks


def _collect():
    out = []
    for name in ("dlsr.coding", "dlsr.dictionaries", "dlsr.whitening", "dlsr.svm"):
        try:
            mod = importlib.import_module(name)
        except ImportError:  # a module still being written: its checks are skipped below
            continue
        out.extend(getattr(mod, "ESTIMATORS", []))
    return out


ESTIMATORS = _collect()


def _expected_failed_checks(estimator):
    """Checks that cannot pass by design, with the reason (none at present)."""
    return {}


def test_every_module_exposes_estimators():
    names = {type(e).__name__ for e in ESTIMATORS}
    assert {"SparseEncoder", "DictionaryLearner", "SquaredHingeSVC"} <= names
    try:
        importlib.import_module("dlsr.whitening")
    except ImportError:
        pytest.skip("dlsr.whitening is not there yet (another engineer is writing it)")
    assert getattr(importlib.import_module("dlsr.whitening"), "ESTIMATORS", None), (
        "dlsr.whitening should expose ESTIMATORS")


@parametrize_with_checks(ESTIMATORS, expected_failed_checks=_expected_failed_checks)
def test_sklearn_compatible(estimator, check):
    check(estimator)

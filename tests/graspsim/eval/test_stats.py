"""One home for the statistics: the one exact McNemar test behind every paired comparison."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import binomtest

from graspsim.eval import stats


def test_paired_accuracy_test_is_mcnemar_on_the_paired_counts():
    rng = np.random.default_rng(3)
    a, b = rng.random(40) < 0.6, rng.random(40) < 0.4
    t = stats.paired_accuracy_test(a, b)
    c = stats.paired_counts(a, b)
    assert (t["a_only"], t["b_only"], t["n"]) == (c["only_a"], c["only_b"], 40)
    assert t["p_value"] == stats.mcnemar_exact(c["only_a"], c["only_b"])
    assert t["a"] == pytest.approx(a.mean()) and t["b"] == pytest.approx(b.mean())


def test_removed_sign_test_is_mcnemar_on_rounds_won_and_lost():
    t = stats.removed_sign_test([3, 2, 5, 1, 4], [1, 2, 2, 0, 5])
    assert (t["more"], t["fewer"], t["same"], t["a"], t["b"]) == (3, 1, 1, 15, 10)
    assert t["sign_test_p"] == pytest.approx(binomtest(1, 4, 0.5).pvalue)
    with pytest.raises(ValueError, match="do not pair"):
        stats.removed_sign_test([1, 2], [1])


def test_the_module_holds_every_statistic_once():
    from graspsim.eval import compare, declutter, summary

    for name in ("mcnemar_exact", "paired_counts", "paired_difference_ci",
                 "removed_sign_test", "wilson_interval", "bootstrap_ratio_interval"):
        assert getattr(stats, name).__module__ == "graspsim.eval.stats"
        for module in (compare, declutter, summary):
            f = getattr(module, name, None)
            assert f is None or f is getattr(stats, name)

"""Statistics of the evaluations, in one place: binomial intervals, paired tests of two
methods on the same items, and the bootstrap of a ratio over units.

* :func:`wilson_interval`: the Wilson score interval of a success rate (Wilson, JASA 1927).
* :func:`paired_counts`, :func:`mcnemar_exact`: two methods on the same scenes or images,
  tested by the exact McNemar test (a two-sided binomial test of the discordant pairs at
  p = 1/2); :func:`paired_accuracy_test` does both for per-item outcomes and
  :func:`paired_detection_test` for two detection benchmarks' images,
  :func:`removed_sign_test` applies the same test as a sign test to clutter rounds.
* :func:`paired_difference_ci`: the interval of the difference of two paired proportions,
  Newcombe's (Statistics in Medicine, 1998) method 10.
* :func:`bootstrap_ratio_interval`: a percentile bootstrap of ``sum(num) / sum(den)`` over
  units (the grasp and declutter rates of clutter rounds).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.stats import binomtest, norm

__all__ = [
    "wilson_interval",
    "paired_counts",
    "mcnemar_exact",
    "paired_accuracy_test",
    "paired_detection_test",
    "paired_difference_ci",
    "removed_sign_test",
    "bootstrap_ratio_interval",
    "CI_METHOD",
    "TEST_METHOD",
]


def wilson_interval(k: int, n: int, z: float = 1.959964) -> tuple[float, float]:
    """Wilson score interval for a binomial proportion (95 % by default).

    Parameters
    ----------
    k : int
        Successes.
    n : int
        Trials.
    z : float
        The normal quantile of the level (1.96: 95 %).

    Returns
    -------
    (low, high) : tuple of float
        ``(nan, nan)`` for ``n == 0``.
    """
    if n == 0:
        return (float("nan"), float("nan"))
    p = k / n
    denom = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    return (float(max(0.0, centre - half)), float(min(1.0, centre + half)))


CI_METHOD = "Newcombe (1998) method 10: Wilson score intervals combined for paired data"


TEST_METHOD = "exact McNemar: two-sided binomial test of the discordant pairs, p = 1/2"


def paired_counts(a, b) -> dict:
    """The 2x2 table of two paired sequences of outcomes.

    Parameters
    ----------
    a, b : array-like of bool, shape (n,)
        Success of detector A and of detector B on the same ``n`` scenes, in the same order.

    Returns
    -------
    dict
        ``both``, ``only_a``, ``only_b``, ``neither`` (ints summing to ``n``).
    """
    a = np.asarray(a)
    b = np.asarray(b)
    if a.ndim != 1 or a.shape != b.shape:
        raise ValueError(f"paired outcomes must be two 1-D sequences of the same length, "
                         f"got shapes {a.shape} and {b.shape}")
    for name, x in (("a", a), ("b", b)):
        if x.dtype != bool and not np.isin(x, (0, 1)).all():
            raise ValueError(f"outcomes {name} must be booleans or 0/1")
    a = a.astype(bool)
    b = b.astype(bool)
    return {"both": int(np.sum(a & b)), "only_a": int(np.sum(a & ~b)),
            "only_b": int(np.sum(~a & b)), "neither": int(np.sum(~a & ~b))}


def _check_count(name, v) -> int:
    if isinstance(v, bool) or not float(v).is_integer() or v < 0:
        raise ValueError(f"{name} must be a count (an integer >= 0), got {v!r}")
    return int(v)


def mcnemar_exact(only_a: int, only_b: int) -> float:
    """Exact two-sided McNemar p-value from the discordant counts.

    Parameters
    ----------
    only_a, only_b : int
        Scenes where only A succeeded, and where only B succeeded.

    Returns
    -------
    float
        ``min(1, 2 P(X <= min(only_a, only_b)))`` for ``X ~ Binomial(only_a + only_b, 1/2)``;
        1.0 when there is no discordant pair.
    """
    only_a = _check_count("only_a", only_a)
    only_b = _check_count("only_b", only_b)
    m = only_a + only_b
    if m == 0:
        return 1.0
    # For p = 1/2 the distribution is symmetric, so scipy's two-sided p (the probability of
    # every outcome no likelier than the one observed) is the doubled smaller tail.
    return float(min(1.0, binomtest(min(only_a, only_b), m, 0.5).pvalue))


def paired_difference_ci(both: int, only_a: int, only_b: int, neither: int,
                         alpha: float = 0.05) -> tuple[float, float]:
    """Newcombe's interval for the difference of two paired success rates (method 10).

    Parameters
    ----------
    both, only_a, only_b, neither : int
        The paired 2x2 table (see :func:`paired_counts`).
    alpha : float
        1 - confidence level (0.05: a 95 % interval).

    Returns
    -------
    (lower, upper) : tuple of float
        Bounds for ``p_A - p_B`` (fractions in [-1, 1]); ``(nan, nan)`` when the table is empty.

    Notes
    -----
    With ``p_A = (both + only_a) / n``, ``p_B = (both + only_b) / n`` and their Wilson intervals
    ``[l_A, u_A]``, ``[l_B, u_B]``, the bounds are
    ``p_A - p_B - sqrt(dA^2 - 2 phi dA eB + eB^2)`` and ``p_A - p_B + sqrt(dB^2 - 2 phi dB eA
    + eA^2)``, where ``dX = p_X - l_X`` and ``eX = u_X - p_X``. ``phi`` is the phi coefficient
    of the table with Newcombe's continuity correction of its numerator
    ``both * neither - only_a * only_b`` (reduced by n/2 when larger than n/2, set to 0 between
    0 and n/2), and 0 when a margin is empty.
    """
    both, only_a, only_b, neither = (_check_count(k, v) for k, v in (
        ("both", both), ("only_a", only_a), ("only_b", only_b), ("neither", neither)))
    if not 0 < alpha < 1:
        raise ValueError(f"alpha must be in (0, 1), got {alpha}")
    n = both + only_a + only_b + neither
    if n == 0:
        return (float("nan"), float("nan"))
    z = float(norm.ppf(1 - alpha / 2))
    ka, kb = both + only_a, both + only_b
    pa, pb = ka / n, kb / n
    la, ua = wilson_interval(ka, n, z)
    lb, ub = wilson_interval(kb, n, z)
    margins = (ka, n - ka, kb, n - kb)
    phi = 0.0
    if min(margins) > 0:
        num = both * neither - only_a * only_b
        if num > n / 2:
            num -= n / 2
        elif num >= 0:
            num = 0
        phi = num / math.sqrt(math.prod(float(m) for m in margins))
    d = pa - pb
    lower = d - math.sqrt(max(0.0, (pa - la) ** 2 - 2 * phi * (pa - la) * (ub - pb)
                                   + (ub - pb) ** 2))
    upper = d + math.sqrt(max(0.0, (pb - lb) ** 2 - 2 * phi * (pb - lb) * (ua - pa)
                                   + (ua - pa) ** 2))
    return (max(-1.0, lower), min(1.0, upper))


def removed_sign_test(removed_a, removed_b) -> dict:
    """Sign test on the objects two detectors removed in the same clutter rounds.

    Parameters
    ----------
    removed_a, removed_b : sequence of int, shape (n_rounds,)
        Objects each round removed, round by round.

    Returns
    -------
    dict
        ``a``, ``b`` (totals), ``more`` / ``fewer`` / ``same`` (rounds where A removed more,
        fewer, as many) and ``sign_test_p`` (the exact two-sided binomial test of ``more``
        against ``fewer``, ties dropped: :func:`mcnemar_exact`).
    """
    ra, rb = [int(x) for x in removed_a], [int(x) for x in removed_b]
    if len(ra) != len(rb):
        raise ValueError(f"removed counts of {len(ra)} and {len(rb)} rounds do not pair")
    more = sum(x > y for x, y in zip(ra, rb, strict=True))
    fewer = sum(x < y for x, y in zip(ra, rb, strict=True))
    return {"a": sum(ra), "b": sum(rb), "more": more, "fewer": fewer,
            "same": len(ra) - more - fewer, "sign_test_p": mcnemar_exact(more, fewer)}


def paired_accuracy_test(a, b) -> dict:
    """Exact McNemar test of two paired per-image outcomes (two-sided binomial on discordants).

    Parameters
    ----------
    a, b : array-like of bool, shape (n,)
        Per-image success of two methods on the same images, in the same order.

    Returns
    -------
    dict
        ``n`` images, ``a_only`` and ``b_only`` (images one method wins alone), the accuracies
        ``a`` and ``b``, and ``p_value`` (:func:`graspsim.eval.mcnemar_exact`); 1.0 when
        there is no discordant pair.
    """
    counts = paired_counts(a, b)
    n = sum(counts.values())
    return {"n": n,
            "a": (counts["both"] + counts["only_a"]) / n if n else None,
            "b": (counts["both"] + counts["only_b"]) / n if n else None,
            "a_only": counts["only_a"], "b_only": counts["only_b"],
            "p_value": mcnemar_exact(counts["only_a"], counts["only_b"])}


def bootstrap_ratio_interval(num, den, n_boot: int = 2000, level: float = 0.95,
                             random_state=None) -> list[float | None]:
    """Percentile bootstrap interval of ``sum(num) / sum(den)``, resampling the units.

    Parameters
    ----------
    num, den : array-like of shape (n,)
        Per unit (here: per round) numerator and denominator counts.
    n_boot : int
    level : float
    random_state : int, SeedSequence, Generator or None

    Returns
    -------
    [low, high], or [None, None] when there is no unit or the denominator is 0.
    """
    num, den = np.asarray(num, dtype=float), np.asarray(den, dtype=float)
    if num.size == 0 or den.sum() <= 0:
        return [None, None]
    rng = np.random.default_rng(random_state)
    idx = rng.integers(0, num.size, size=(n_boot, num.size))
    d = den[idx].sum(axis=1)
    ratios = num[idx].sum(axis=1)[d > 0] / d[d > 0]
    a = (1 - level) / 2
    return [float(np.quantile(ratios, a)), float(np.quantile(ratios, 1 - a))]


def paired_detection_test(a: dict, b: dict) -> dict:
    """Exact McNemar test of two detection runs on the same images (per-image top-1 success).

    Parameters
    ----------
    a, b : dict
        Summaries of :func:`detection_benchmark` (``per_image`` outcomes) on the same images.

    Returns
    -------
    dict
        :func:`graspsim.eval.stats.paired_accuracy_test` of ``a`` against ``b``.
    """
    sa = {r["image_id"]: bool(r["success"]) for r in a["per_image"]}
    sb = {r["image_id"]: bool(r["success"]) for r in b["per_image"]}
    if set(sa) != set(sb):
        raise ValueError(f"the two runs were tested on different images ({len(sa)} and "
                         f"{len(sb)}, {len(set(sa) ^ set(sb))} not in both)")
    ids = sorted(sa)
    return paired_accuracy_test([sa[i] for i in ids], [sb[i] for i in ids])

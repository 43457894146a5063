"""The squared-hinge SVM (Newton solver against the L-BFGS reference) and the standardiser."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import minimize, minimize_scalar
from sklearn.datasets import make_classification
from sklearn.exceptions import ConvergenceWarning
from sklearn.svm import LinearSVC

from dlsr.svm import (
    FeatureStandardizer,
    SquaredHingeSVC,
    _exact_step,
    squared_hinge_fit,
    squared_hinge_objective,
)


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


# --- the Newton solver (squared_hinge_fit, solver="newton") ---------------------------------

C_VALUES = [0.01, 1.0, 10.0, 1000.0]
# (n, d): kernel form without the subset start, primal form, kernel form with the subset start
SHAPES = [(60, 150), (300, 40), (450, 300)]


def _planted(n, d, seed, noise=0.1):
    """Standardised-looking features, labels from a planted linear rule with label noise."""
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(n, d))
    score = X @ rng.normal(size=d) / np.sqrt(d) + 0.3
    y = np.where(score > 0, 1.0, -1.0)
    flip = rng.random(n) < noise
    y[flip] = -y[flip]
    return X, y


def _value(w, b, X, y, C):
    return squared_hinge_objective(np.r_[w, b], X, y, C)[0]


def _grad(w, b, X, y, C):
    return squared_hinge_objective(np.r_[w, b], X, y, C)[1]


def _lbfgs(X, y, C):
    """Reference: L-BFGS on the same objective, run to its limits."""
    res = minimize(squared_hinge_objective, np.zeros(X.shape[1] + 1), args=(X, y, C), jac=True,
                   method="L-BFGS-B",
                   options={"gtol": 1e-12, "ftol": 1e-16, "maxiter": 100_000, "maxcor": 30})
    return res.x[:-1], res.x[-1]


@pytest.mark.parametrize(("n", "d"), SHAPES)
@pytest.mark.parametrize("C", C_VALUES)
def test_newton_reaches_the_lbfgs_minimum(n, d, C):
    X, y = _planted(n, d, seed=n + d)
    ((w, b, n_iter),) = squared_hinge_fit(X, y, [C])
    w_ref, b_ref = _lbfgs(X, y, C)
    ours, ref = _value(w, b, X, y, C), _value(w_ref, b_ref, X, y, C)
    assert abs(ours - ref) <= 1e-6 * ref
    assert ours <= ref * (1 + 1e-12)  # exact: never above what L-BFGS reaches
    assert 1 <= n_iter <= 50  # a few steps; C = 1000 with n close to d takes the most
    X_new, _ = _planted(500, d, seed=7)
    f, f_ref = X_new @ w + b, X_new @ w_ref + b_ref
    clear = np.abs(f) > 1e-3 * np.abs(f).max()  # not on the boundary itself
    assert clear.mean() > 0.95
    np.testing.assert_array_equal(f[clear] > 0, f_ref[clear] > 0)
    # training rows too, off the boundary (both solutions agree to about 1e-6 relative, so a
    # row closer to it than that may land on either side, depending on rounding)
    f, f_ref = X @ w + b, X @ w_ref + b_ref
    clear = np.abs(f) > 1e-3 * np.abs(f).max()
    assert clear.mean() > 0.9
    np.testing.assert_array_equal(f[clear] > 0, f_ref[clear] > 0)


@pytest.mark.parametrize(("n", "d"), SHAPES)
def test_estimator_solvers_agree(n, d):
    X, y01 = _planted(n, d, seed=3)
    y = (y01 > 0).astype(int)
    newton = SquaredHingeSVC(C=10.0).fit(X, y)
    lbfgs = SquaredHingeSVC(C=10.0, solver="lbfgs").fit(X, y)
    assert newton.solver == "newton" and newton.n_iter_ < lbfgs.n_iter_
    value_newton, value_lbfgs = _objective(newton, X, y, 10.0), _objective(lbfgs, X, y, 10.0)
    assert value_newton <= value_lbfgs
    assert value_lbfgs - value_newton <= 1e-5 * value_newton  # L-BFGS stops at gtol=1e-6
    assert np.mean(newton.predict(X) == lbfgs.predict(X)) >= 0.99


@pytest.mark.parametrize(("n", "d"), SHAPES)
def test_kernel_and_primal_forms_agree(n, d):
    X, y = _planted(n, d, seed=11)
    kernel = squared_hinge_fit(X, y, C_VALUES, form="kernel")
    primal = squared_hinge_fit(X, y, C_VALUES, form="primal")
    for (wk, bk, _), (wp, bp, _) in zip(kernel, primal, strict=True):
        np.testing.assert_allclose(wk, wp, rtol=0, atol=1e-8 * np.abs(wp).max())
        assert abs(bk - bp) <= 1e-8 * max(1.0, abs(bp))


@pytest.mark.parametrize(("n", "d"), SHAPES)
def test_warm_started_and_cold_solutions_agree(n, d):
    X, y = _planted(n, d, seed=5)
    Cs = [1.0, 10.0, 1000.0, 0.01, 10.0, 10.0]  # increasing, jumps down and up, a repeat
    warm = squared_hinge_fit(X, y, Cs)
    cold = squared_hinge_fit(X, y, Cs, warm_start=False)
    for C, (ww, bw, _), (wc, bc, _) in zip(Cs, warm, cold, strict=True):
        np.testing.assert_allclose(ww, wc, rtol=0, atol=1e-8 * np.abs(wc).max())
        assert abs(bw - bc) <= 1e-8 * max(1.0, abs(bc))
        ((w1, b1, _),) = squared_hinge_fit(X, y, [C])  # alone
        np.testing.assert_allclose(ww, w1, rtol=0, atol=1e-8 * np.abs(w1).max())
    # the repeated C starts at its own solution: one step, which changes nothing
    assert warm[-1][2] == 1 and cold[-1][2] > 1
    np.testing.assert_allclose(warm[-1][0], warm[-2][0], rtol=0, atol=1e-12)


@pytest.mark.parametrize(("n", "d"), SHAPES)
@pytest.mark.parametrize("form", ["kernel", "primal"])
def test_a_start_from_a_neighbouring_problem_reaches_the_same_minimum(n, d, form):
    """``start`` (a neighbouring problem's solution, as the next inner fold gets) changes the
    path only: the same minimiser as the cold start, up to rounding, for every C after it."""
    X, y = _planted(n, d, seed=17)
    keep = np.arange(n) % 5 != 0  # the neighbour: another four fifths of the rows
    neighbour = squared_hinge_fit(X[keep], y[keep], [1.0], form=form)[0]
    Cs = [1.0, 100.0]
    cold = squared_hinge_fit(X, y, Cs, form=form)
    warm = squared_hinge_fit(X, y, Cs, form=form, start=neighbour[:2])
    for (wc, bc, _), (ww, bw, _), C in zip(cold, warm, Cs, strict=True):
        np.testing.assert_allclose(ww, wc, rtol=0, atol=1e-8 * np.abs(wc).max())
        assert abs(bw - bc) <= 1e-8 * max(1.0, abs(bc))
        assert _value(ww, bw, X, y, C) <= _value(wc, bc, X, y, C) * (1 + 1e-12)
    # started at its own solution, one step that changes nothing
    again = squared_hinge_fit(X, y, [1.0], form=form, start=cold[0][:2])[0]
    assert again[2] == 1
    np.testing.assert_allclose(again[0], cold[0][0], rtol=0,
                               atol=1e-10 * np.abs(cold[0][0]).max())
    # without warm starts between the C values, only the first C starts there
    sep = squared_hinge_fit(X, y, Cs, form=form, start=cold[0][:2], warm_start=False)
    alone = squared_hinge_fit(X, y, [100.0], form=form)[0]
    assert sep[0][2] == 1 and sep[1][2] == alone[2]


def test_a_bad_start_is_a_clear_error():
    X, y = _planted(60, 5, seed=0)
    with pytest.raises(ValueError, match="start must be a finite"):
        squared_hinge_fit(X, y, [1.0], start=(np.zeros(4), 0.0))
    with pytest.raises(ValueError, match="start must be a finite"):
        squared_hinge_fit(X, y, [1.0], start=(np.zeros(5), np.nan))


def test_primal_gram_is_updated_in_place_as_the_violators_change():
    """The primal form's ``[X_S 1]^T [X_S 1]`` (lower triangle), after rows enter and leave in
    several blocks, equals the sum over the current rows; the same scratch and work arrays
    serve every update and solve."""
    from dlsr import svm

    rng = np.random.default_rng(3)
    X = rng.normal(size=(300, 7))
    y = np.where(rng.random(300) < 0.5, 1.0, -1.0)
    system = svm._PrimalSystem(X, y)
    old_block = svm._BLOCK_ROWS
    svm._BLOCK_ROWS = 16  # several blocks per update
    try:
        buf = A = None
        for frac in (1.0, 0.6, 0.65, 0.3, 0.31, 0.9):
            idx = np.flatnonzero(rng.random(300) < frac)
            w, b = system.solve(idx, lam=2.0)
            Z = np.c_[X[idx], np.ones(idx.size)]
            np.testing.assert_allclose(np.tril(system._H), np.tril(Z.T @ Z), rtol=1e-12,
                                       atol=1e-10)
            # the solve is that of the full symmetric system
            lhs = Z.T @ Z + np.diag(np.r_[np.full(7, 2.0), 0.0])
            x = np.linalg.solve(lhs, Z.T @ y[idx])
            np.testing.assert_allclose(np.r_[w, b], x, rtol=1e-9, atol=1e-12)
            if buf is not None:
                assert system._buf is buf and system._A is A
            buf, A = system._buf, system._A
    finally:
        svm._BLOCK_ROWS = old_block


@pytest.mark.parametrize(("n", "d"), SHAPES)
@pytest.mark.parametrize("form", ["kernel", "primal"])
def test_optimality_conditions_hold(n, d, form):
    X, y = _planted(n, d, seed=13)
    for C, (w, b, _) in zip(C_VALUES, squared_hinge_fit(X, y, C_VALUES, form=form),
                            strict=True):
        g = _grad(w, b, X, y, C)
        g0 = _grad(np.zeros(d), 0.0, X, y, C)
        assert np.linalg.norm(g) <= 1e-9 * np.linalg.norm(g0)
        # stationarity in w and b, written out: w = 2C/n sum_SV y_i m_i x_i, sum_SV y_i m_i = 0
        m = np.maximum(0.0, 1.0 - y * (X @ w + b))
        alpha = 2.0 * C / n * y * m
        np.testing.assert_allclose(w, X.T @ alpha, rtol=0, atol=1e-9 * np.abs(w).max())
        assert abs(alpha.sum()) <= 1e-9 * np.abs(alpha).sum()
        assert np.any((m > 0) & (y > 0)) and np.any((m > 0) & (y < 0))


def test_separable_data():
    X, y = _planted(80, 200, seed=1, noise=0.0)  # n < d: linearly separable
    for C, (w, b, _) in zip(C_VALUES, squared_hinge_fit(X, y, C_VALUES), strict=True):
        w_ref, b_ref = _lbfgs(X, y, C)
        ours, ref = _value(w, b, X, y, C), _value(w_ref, b_ref, X, y, C)
        assert abs(ours - ref) <= 1e-6 * ref
        if C >= 10:
            assert np.all(y * (X @ w + b) > 0)


def test_duplicate_rows():
    X, y = _planted(120, 30, seed=2)
    # every row twice: the mean loss, hence the minimiser, is the same
    ((w, b, _),) = squared_hinge_fit(X, y, [10.0])
    ((w2, b2, _),) = squared_hinge_fit(np.r_[X, X], np.r_[y, y], [10.0])
    np.testing.assert_allclose(w2, w, rtol=0, atol=1e-9 * np.abs(w).max())
    assert abs(b2 - b) <= 1e-9
    # every row once with each label: the origin is the minimiser (the gradient there is 0)
    for form in ("kernel", "primal"):
        ((w0, b0, n_iter),) = squared_hinge_fit(np.r_[X, X], np.r_[y, -y], [10.0], form=form)
        assert np.abs(w0).max() < 1e-9 and abs(b0) < 1e-9 and n_iter == 1


@pytest.mark.parametrize("form", ["kernel", "primal"])
def test_constant_and_zero_feature_columns(form):
    X, y = _planted(200, 20, seed=4)
    X[:, 3] = 7.0  # collinear with the bias: its weight is 0, the bias takes it
    X[:, 5] = 0.0
    for C, (w, b, _) in zip(C_VALUES, squared_hinge_fit(X, y, C_VALUES, form=form),
                            strict=True):
        assert abs(w[3]) < 1e-9 and w[5] == 0
        w_ref, b_ref = _lbfgs(np.delete(X, [3, 5], axis=1), y, C)
        np.testing.assert_allclose(np.delete(w, [3, 5]), w_ref, rtol=0, atol=1e-4)
        assert abs(b - b_ref) < 1e-4


def test_exact_line_search_minimises_the_piecewise_quadratic(rng):
    c = 0.05
    n_breaks = 0
    for scale in np.geomspace(0.01, 10, 40):
        m = rng.normal(size=30)
        s = scale * rng.normal(size=30)
        pp = rng.random() + 0.1
        # a Newton direction: the quadratic model of the current violators has its minimum at 1
        act = m > 0
        wp = -pp - np.sum(2 * c * s[act] * (s[act] - m[act]))

        def phi(t, m=m, s=s, wp=wp, pp=pp):
            return wp * t + 0.5 * pp * t * t + c * np.sum(np.maximum(0.0, m - t * s) ** 2)

        t = _exact_step(m, s, wp, pp, c)
        ref = minimize_scalar(phi, bounds=(0, 1e3), method="bounded",
                              options={"xatol": 1e-12}).x
        assert t >= 0
        assert phi(t) <= phi(ref) + 1e-12
        assert abs(t - ref) < 1e-5
        breaks = m / s
        n_breaks += np.any((breaks > 0) & (breaks < t))
        if not np.any((breaks > 0) & (breaks < 1)):
            assert t == 1.0  # the full Newton step, exactly
    assert n_breaks >= 10  # most searches crossed breakpoints


def _tiny(seed):
    """A tiny random problem (the generator that found those where plain Newton cycles)."""
    rng = np.random.default_rng(seed)
    n, d = rng.integers(4, 12), rng.integers(1, 4)
    X = rng.normal(size=(n, d)) * rng.choice([0.1, 1, 10])
    y = np.where(rng.random(n) < 0.5, 1.0, -1.0)
    return X, y, float(rng.choice([0.1, 1, 100, 1e4]))


@pytest.mark.parametrize("seed", [40, 258, 941])
def test_line_search_stops_the_cycles_of_plain_newton(seed, monkeypatch):
    X, y, C = _tiny(seed)
    for form in ("kernel", "primal"):
        ((w, b, n_iter),) = squared_hinge_fit(X, y, [C], form=form)
        w_ref, b_ref = _lbfgs(X, y, C)
        assert _value(w, b, X, y, C) <= _value(w_ref, b_ref, X, y, C) * (1 + 1e-10)
        assert n_iter <= 10
    # full Newton steps (no line search) go round in circles on these problems
    monkeypatch.setattr("dlsr.svm._exact_step", lambda *args: 1.0)
    with pytest.warns(ConvergenceWarning, match="did not converge"):
        squared_hinge_fit(X, y, [C], max_iter=200)


def test_too_few_iterations_warn():
    X, y = _planted(300, 40, seed=6)
    with pytest.warns(ConvergenceWarning, match="did not converge for C=10"):
        ((_, _, n_iter),) = squared_hinge_fit(X, y, [10.0], max_iter=1)
    assert n_iter == 1


def test_bad_input_is_a_clear_error():
    X, y = _planted(30, 5, seed=0)
    with pytest.raises(ValueError, match="both classes"):
        squared_hinge_fit(X, np.ones(30), [1.0])
    X_nan = X.copy()
    X_nan[3, 2] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        squared_hinge_fit(X_nan, y, [1.0])
    for C in (0.0, -1.0, np.nan, [1.0, 0.0]):
        with pytest.raises(ValueError, match="C must be positive"):
            squared_hinge_fit(X, y, C)
    with pytest.raises(ValueError, match="only -1 and \\+1"):
        squared_hinge_fit(X, (y > 0).astype(float), [1.0])
    with pytest.raises(ValueError, match="same length"):
        squared_hinge_fit(X, y[:-1], [1.0])
    with pytest.raises(ValueError, match="form must be"):
        squared_hinge_fit(X, y, [1.0], form="dual")
    # the estimator, as before
    with pytest.raises(ValueError, match="C must be positive"):
        SquaredHingeSVC(C=0.0).fit(X, y)
    with pytest.raises(ValueError, match="NaN"):
        SquaredHingeSVC().fit(X_nan, y)
    with pytest.raises(ValueError, match="solver must be"):
        SquaredHingeSVC(solver="sgd").fit(X, y)
    with pytest.raises(ValueError, match="both\\s+positive and negative"):
        SquaredHingeSVC(solver="lbfgs").fit(X, np.ones(30))


def test_the_solution_does_not_depend_on_the_blas_threads():
    # with two threads the Gram and kernel products summed in another order: a detector
    # trained in a worker (one thread) and in the main process differed in the last bits
    from dlsr import _threads
    from dlsr.svm import squared_hinge_fit

    rng = np.random.default_rng(1)
    for n, d in ((600, 2400), (3000, 400)):  # the kernel form, then the primal form
        X = rng.normal(size=(n, d))
        y = np.where(X[:, :5].sum(axis=1) + rng.normal(size=n) > 0, 1.0, -1.0)
        fits = []
        for threads in (1, 2):
            with _threads.limit(threads, user_api="blas"):
                fits.append(squared_hinge_fit(X, y, [1.0, 10.0]))
        for a, b in zip(*fits, strict=True):
            assert np.asarray(a[0]).tobytes() == np.asarray(b[0]).tobytes()
            assert float(a[1]) == float(b[1])


def _factorised_solution(system, idx, lam):
    """The solution of the system on rows ``idx`` by a factorisation of its own ``H``."""
    A = system._full(lam)
    y_S = np.zeros(len(system.y))
    y_S[idx] = system.y[idx]
    return np.linalg.solve(A, np.r_[system.X.T @ y_S, y_S.sum()])


@pytest.mark.parametrize("lam", [0.05, 5.0, 500.0])
def test_primal_solves_near_the_factorised_violators_use_its_factor(lam, monkeypatch):
    """A system whose violators differ from the last factorised one's by a few rows is solved
    with that factor (Woodbury, refined) to the rounding of a factorisation of its own; a
    larger change, or a new penalty, factorises again."""
    from dlsr import svm

    monkeypatch.setattr(svm, "_LOW_RANK_MIN_FEATURES", 0)  # small test problems

    rng = np.random.default_rng(5)
    n, d = 400, 47  # (d + 1) / 8 = 6 rows may differ
    X = rng.normal(size=(n, d)) + 0.3
    y = np.where(rng.random(n) < 0.4, 1.0, -1.0)
    system = svm._PrimalSystem(X, y)
    S = rng.random(n) < 0.7
    system.solve(np.flatnonzero(S), lam)
    assert (system.n_factorisations, system.n_low_rank) == (1, 0)
    base = S.copy()
    expect_low = 0
    for n_enter, n_leave in ((2, 0), (0, 3), (3, 3), (1, 2), (5, 1)):
        S = base.copy()
        S[rng.choice(np.flatnonzero(~base), n_enter, replace=False)] = True
        S[rng.choice(np.flatnonzero(base), n_leave, replace=False)] = False
        idx = np.flatnonzero(S)
        w, b = system.solve(idx, lam)
        expect_low += 1
        assert (system.n_factorisations, system.n_low_rank) == (1, expect_low)
        x = _factorised_solution(system, idx, lam)
        np.testing.assert_allclose(np.r_[w, b], x, rtol=0, atol=1e-12 * np.abs(x).max())
    # more rows than (d + 1) / 8 differ from the factorised set: a new factorisation
    S = base.copy()
    S[np.flatnonzero(base)[:10]] = False
    system.solve(np.flatnonzero(S), lam)
    assert (system.n_factorisations, system.n_low_rank) == (2, expect_low)
    # the same violators under another penalty: factorised too
    system.solve(np.flatnonzero(S), 2.0 * lam)
    assert system.n_factorisations == 3


def test_a_low_rank_solve_that_does_not_converge_factorises(monkeypatch):
    from dlsr import svm

    monkeypatch.setattr(svm, "_LOW_RANK_MIN_FEATURES", 0)  # small test problems

    rng = np.random.default_rng(6)
    X = rng.normal(size=(300, 31))
    y = np.where(rng.random(300) < 0.5, 1.0, -1.0)
    monkeypatch.setattr(svm, "_REFINE_TOL", 0.0)  # no correction is ever small enough
    system = svm._PrimalSystem(X, y)
    S = np.arange(300) % 3 > 0
    system.solve(np.flatnonzero(S), 2.0)
    S[:4] = ~S[:4]
    w, b = system.solve(np.flatnonzero(S), 2.0)
    assert (system.n_factorisations, system.n_low_rank) == (2, 0)
    x = _factorised_solution(system, np.flatnonzero(S), 2.0)
    np.testing.assert_allclose(np.r_[w, b], x, rtol=0, atol=1e-12 * np.abs(x).max())


def _served(monkeypatch, method: str) -> list:
    """Wrap ``_PrimalSystem.<method>`` so that each call appends whether it served (returned
    something other than None) to the list returned."""
    from dlsr import svm

    used = []
    original = getattr(svm._PrimalSystem, method)

    def counted(self, *args):
        out = original(self, *args)
        used.append(out is not None)
        return out

    monkeypatch.setattr(svm._PrimalSystem, method, counted)
    return used


def _assert_same_minimiser(X, a, b) -> None:
    """``a = (w, b)`` equals ``b`` to 1e-10 of its largest entry, with the same sign of every
    decision value on ``X``."""
    (w1, b1), (w0, b0) = a, b
    scale = max(np.abs(w0).max(), abs(b0))
    np.testing.assert_allclose(w1, w0, rtol=0, atol=1e-10 * scale)
    assert abs(b1 - b0) <= 1e-10 * scale
    np.testing.assert_array_equal(X @ w1 + b1 > 0, X @ w0 + b0 > 0)


def test_newton_with_low_rank_solves_reaches_the_factorised_minimiser(monkeypatch):
    """The whole solver, with and without the low-rank solves, reaches the same minimiser
    (primal form, several C, each warm-started) in the same number of Newton steps."""
    from dlsr import svm

    monkeypatch.setattr(svm, "_LOW_RANK_MIN_FEATURES", 0)  # small test problems

    X, y = _planted(900, 120, seed=17)
    used = _served(monkeypatch, "_low_rank_solve")
    with_low = squared_hinge_fit(X, y, C_VALUES, form="primal")
    assert sum(used) >= 3  # the low-rank solves did serve
    monkeypatch.setattr(svm._PrimalSystem, "_low_rank_solve", lambda *args: None)  # factorise
    without = squared_hinge_fit(X, y, C_VALUES, form="primal")
    for (w1, b1, n1), (w0, b0, n0) in zip(with_low, without, strict=True):
        assert n1 == n0
        _assert_same_minimiser(X, (w1, b1), (w0, b0))


def test_an_approximate_first_step_per_c_reaches_the_same_minimiser(monkeypatch):
    """Each warm-started C's first step may aim at a conjugate-gradient approximation
    preconditioned by the previous penalty's factor (primal form): the solver reaches the
    same minimiser as with exact steps only, with the same signs of every decision value."""
    from dlsr import svm

    monkeypatch.setattr(svm, "_LOW_RANK_MIN_FEATURES", 0)  # small test problems

    X, y = _planted(900, 120, seed=19)
    used = _served(monkeypatch, "approximate")
    with_approx = squared_hinge_fit(X, y, C_VALUES, form="primal")
    assert sum(used) >= 2  # the approximations did serve (not for the first C)
    monkeypatch.setattr(svm._PrimalSystem, "approximate", lambda *args: None)
    exact = squared_hinge_fit(X, y, C_VALUES, form="primal")
    for (w1, b1, _), (w0, b0, _), C in zip(with_approx, exact, C_VALUES, strict=True):
        _assert_same_minimiser(X, (w1, b1), (w0, b0))
        g = _grad(w1, b1, X, y, C)
        assert np.linalg.norm(g) <= 1e-6 * np.linalg.norm(_grad(np.zeros(120), 0.0, X, y, C))


def test_the_approximation_needs_a_factor_of_nearby_violators(monkeypatch):
    """No factor yet, the same penalty as the factor's, or violators too far from the
    factorised ones: no approximation (the step is solved exactly)."""
    from dlsr import svm

    monkeypatch.setattr(svm, "_LOW_RANK_MIN_FEATURES", 0)  # small test problems

    rng = np.random.default_rng(8)
    X = rng.normal(size=(300, 39))
    y = np.where(rng.random(300) < 0.5, 1.0, -1.0)
    system = svm._PrimalSystem(X, y)
    idx = np.flatnonzero(np.arange(300) % 4 > 0)
    w, b = np.zeros(39), 0.0
    assert system.approximate(idx, 2.0, w, b) is None  # no factor
    system.solve(idx, 2.0)
    assert system.approximate(idx, 2.0, w, b) is None  # the factor's own penalty
    assert system.approximate(idx[20:], 0.2, w, b) is None  # 20 rows > 40 / 8
    w1, b1 = system.approximate(idx[2:], 0.2, w, b)  # 2 rows left: approximated
    assert system.n_approximate == 1 and system.n_factorisations == 1
    x = _factorised_solution(system, idx[2:], 0.2)
    assert np.linalg.norm(np.r_[w1, b1] - x) < 0.5 * np.linalg.norm(x)  # towards it


def test_small_problems_always_factorise(monkeypatch):
    """Below ``_LOW_RANK_MIN_FEATURES`` features every system is factorised (cheaper there)."""
    from dlsr import svm

    X, y = _planted(600, 60, seed=23)
    systems = []
    init = svm._PrimalSystem.__init__

    def recorded(self, *args):
        init(self, *args)
        systems.append(self)

    monkeypatch.setattr(svm._PrimalSystem, "__init__", recorded)
    squared_hinge_fit(X, y, C_VALUES, form="primal")
    (system,) = systems
    assert system.n_factorisations > len(C_VALUES)
    assert system.n_low_rank == system.n_approximate == 0

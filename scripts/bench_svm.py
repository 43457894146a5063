"""Speed and exactness of the squared-hinge SVM solvers (one JSON object on stdout).

The recognition benchmark fits ``SquaredHingeSVC`` on standardised float32 features of about
1,280-1,600 rows and 1,200 or 2,400 columns, for C in {1, 10}. Problems here:

* ``synthetic_<n>x<d>``: float32 features with correlated columns (a power-law spectrum like
  that of the real features), standardised with :class:`dlsr.svm.FeatureStandardizer`, labels
  from a planted linear rule with noise and 5% of them flipped; shapes (1280, 2400) and
  (1280, 1200);
* ``features_<i>`` (with ``--features``): the first ``ntr`` rows of ``F[i]`` of a .npz with keys
  ``F`` (k, n, d), ``y`` (n,) and ``ntr`` (a training fold), standardised the same way.

Per problem and C: seconds (best of ``--repeat``), objective value (``0.5 ||w||^2 + C mean
squared hinge``, bias unregularised, evaluated in float64) and iterations of

* ``newton_cold``: :func:`dlsr.svm.squared_hinge_fit` for this C alone;
* ``newton_warm``: the call the benchmark makes, both C in one call (C = 10 warm-started from
  C = 1, one kernel): for C = 1 the same as cold; for C = 10 the joint call's time minus the
  C = 1 call's time (the increment of adding C = 10);
* ``lbfgs``: ``SquaredHingeSVC(solver="lbfgs")``, the former solver and the reference;
* ``liblinear``: scikit-learn's ``LinearSVC(loss="squared_hinge", C=C / n)``, which minimises
  the same loss but **regularises the intercept** (``intercept_scaling=1``), so its minimiser is
  not ours: its objective here is ours evaluated at its (w, b), above the minimum.

Ratios are seconds of the peer over seconds of ``newton`` (> 1: Newton is faster);
``joint`` compares the whole per-fold cost (both C) of the benchmark's call with L-BFGS fitting
each C. ``objective_gap`` is (peer objective - Newton objective) / Newton objective.

With ``--features`` and ``--inner`` (default), also the recognition benchmark's inner CV of one
outer fold (:func:`dlsr.recognition.inner_choice` then :func:`~dlsr.recognition.outer_test`:
every ``F[i]`` an encoder parameter, 5 inner group folds over the .npz's ``g`` (or rows) and
C in {1, 10}, then the final fit) against the former per-(fold, C) L-BFGS loop, with their
outputs compared.

Timing is single-threaded BLAS by default (``--threads``).

Usage: python scripts/bench_svm.py [--features /tmp/prof/st_feats.npz] [--repeat 3]
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
import warnings
from pathlib import Path

import numpy as np
from sklearn.svm import LinearSVC
from threadpoolctl import threadpool_limits

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from dlsr.svm import (  # noqa: E402
    FeatureStandardizer,
    SquaredHingeSVC,
    squared_hinge_fit,
    squared_hinge_objective,
)

C_GRID = (1.0, 10.0)


def _best(f, repeat):
    """Output of the last call and the best of ``repeat`` timed calls."""
    best = np.inf
    out = None
    for _ in range(repeat):
        t = time.perf_counter()
        out = f()
        best = min(best, time.perf_counter() - t)
    return out, best


def _r(x, nd=4):
    return None if x is None else float(round(float(x), nd))


def _synthetic(n, d, seed):
    """Standardised float32 features with a power-law spectrum and a noisy planted rule.

    The column covariance has eigenvalues proportional to ``k^-1.76`` (the decay measured on
    real ST features of the benchmark: 48% of the variance in 10 directions); labels are the
    sign of a random linear score plus noise (0.3 of its standard deviation), split at the
    median, then 5% of them flipped.
    """
    rng = np.random.default_rng(seed)
    r = min(n, d)
    spectrum = np.arange(1, r + 1) ** -1.76
    X = (rng.normal(size=(n, r)) * np.sqrt(spectrum)) @ rng.normal(size=(r, d))
    score = X @ rng.normal(size=d)
    score = score / score.std() + 0.3 * rng.normal(size=n)
    y = np.where(score > np.median(score), 1, 0)
    flip = rng.random(n) < 0.05
    y[flip] = 1 - y[flip]
    X = X.astype(np.float32)
    return FeatureStandardizer().fit(X).transform(X), y


def _value(w, b, X64, y_pm, C):
    return float(squared_hinge_objective(np.r_[w, b], X64, y_pm, C)[0])


def _problem(X, y, repeat):
    """Timings and objectives of every solver on one problem."""
    y_pm = np.where(y == np.unique(y)[1], 1.0, -1.0)
    X64 = X.astype(np.float64)
    n = len(y)
    out = {"shape": list(X.shape), "dtype": str(X.dtype), "positive_fraction": _r(np.mean(y > 0))}
    joint, t_joint = _best(lambda: squared_hinge_fit(X, y_pm, C_GRID), repeat)
    t_first = None
    per_c = {}
    for k, C in enumerate(C_GRID):
        row = {}
        ((w, b, it),), t = _best(lambda C=C: squared_hinge_fit(X, y_pm, [C]), repeat)
        newton_value = _value(w, b, X64, y_pm, C)
        row["newton_cold"] = {"seconds": _r(t), "objective": newton_value, "iterations": it}
        if k == 0:
            t_first = t
        w, b, it = joint[k]
        t_warm = t if k == 0 else t_joint - t_first
        row["newton_warm"] = {"seconds": _r(t_warm), "objective": _value(w, b, X64, y_pm, C),
                              "iterations": it}
        svm, t = _best(lambda C=C: SquaredHingeSVC(C=C, solver="lbfgs").fit(X, y), repeat)
        value = _value(svm.coef_[0], svm.intercept_[0], X64, y_pm, C)
        row["lbfgs"] = {"seconds": _r(t), "objective": value, "iterations": svm.n_iter_,
                        "objective_gap": value / newton_value - 1}
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            lin, t = _best(lambda C=C: LinearSVC(loss="squared_hinge", C=C / n).fit(X, y),
                           repeat)
        value = _value(lin.coef_[0], lin.intercept_[0], X64, y_pm, C)
        row["liblinear"] = {
            "seconds": _r(t), "objective": value, "iterations": int(np.max(lin.n_iter_)),
            "objective_gap": value / newton_value - 1,
            "converged": not any("converge" in str(w.message) for w in caught),
            "note": "regularises the intercept: a different minimiser",
        }
        row["speedup_vs_lbfgs"] = {
            "cold": _r(row["lbfgs"]["seconds"] / row["newton_cold"]["seconds"], 2),
            "warm": _r(row["lbfgs"]["seconds"] / max(row["newton_warm"]["seconds"], 1e-9), 2),
        }
        row["speedup_vs_liblinear_cold"] = _r(
            row["liblinear"]["seconds"] / row["newton_cold"]["seconds"], 2)
        per_c[str(C)] = row
    out["C"] = per_c
    lbfgs_total = sum(per_c[str(C)]["lbfgs"]["seconds"] for C in C_GRID)
    out["joint"] = {
        "newton_seconds": _r(t_joint), "lbfgs_seconds": _r(lbfgs_total),
        "speedup": _r(lbfgs_total / t_joint, 2),
    }
    return out


def _old_choose_and_test(feats, y_tr, y_te, inner, C_grid):
    """The inner CV as it was: one standardiser and one L-BFGS fit per (parameter, C, fold)."""
    def fit(F, y, C):
        scaler = FeatureStandardizer().fit(F)
        return scaler, SquaredHingeSVC(C=C, solver="lbfgs").fit(scaler.transform(F), y)

    best = None
    for param, (Ftr, _) in feats.items():
        for C in C_grid:
            accs = []
            for itr, iva in inner:
                if len(np.unique(y_tr[itr])) < 2:
                    continue
                scaler, svm = fit(Ftr[itr], y_tr[itr], C)
                accs.append(np.mean(svm.predict(scaler.transform(Ftr[iva])) == y_tr[iva]))
            score = float(np.mean(accs)) if accs else -np.inf
            if best is None or score > best[0] + 1e-12:
                best = (score, param, C)
    score, param, C = best
    Ftr, Fte = feats[param]
    scaler, svm = fit(Ftr, y_tr, C)
    pred = svm.predict(scaler.transform(Fte))
    return {"accuracy": float(np.mean(pred == y_te)), "encoder_param": param, "C": C,
            "inner_accuracy": score, "predictions": pred.tolist()}


def _inner_cv(z):
    """Inner CV of one outer fold, new and former; ``z`` maps the .npz's keys to arrays."""
    from dlsr.recognition import inner_choice, outer_folds, outer_test

    F, y, ntr = z["F"], z["y"], int(z["ntr"])
    groups = z["g"] if "g" in z else np.arange(ntr)
    inner = outer_folds(groups, 5)
    group_note = "g of the .npz" if "g" in z else "each row its own group (no readable g)"
    feats = {i: (F[i][:ntr], F[i][ntr:]) for i in range(len(F))}
    y_tr, y_te = y[:ntr], y[ntr:]
    t, c = time.perf_counter(), time.process_time()
    choice = inner_choice({i: tr for i, (tr, _) in feats.items()}, y_tr, inner, C_GRID)
    new = outer_test(*feats[choice[1]], y_tr, y_te, choice)
    t_new, c_new = time.perf_counter() - t, time.process_time() - c
    t, c = time.perf_counter(), time.process_time()
    old = _old_choose_and_test(feats, y_tr, y_te, inner, C_GRID)
    t_old, c_old = time.perf_counter() - t, time.process_time() - c
    same = np.mean(np.asarray(new["predictions"]) == np.asarray(old["predictions"]))
    return {
        "n_parameters": len(F), "inner_folds": len(inner), "groups": group_note,
        "n_train": ntr,
        "n_test": len(y) - ntr, "n_features": int(F.shape[2]),
        "newton": {"seconds": _r(t_new, 3), "cpu_seconds": _r(c_new, 3),
                   "accuracy": new["accuracy"], "inner_accuracy": new["inner_accuracy"],
                   "encoder_param": new["encoder_param"], "C": new["C"]},
        "lbfgs_per_fold_and_C": {"seconds": _r(t_old, 3), "cpu_seconds": _r(c_old, 3),
                                 "accuracy": old["accuracy"],
                                 "inner_accuracy": old["inner_accuracy"],
                                 "encoder_param": old["encoder_param"], "C": old["C"]},
        "same_choice": bool(new["encoder_param"] == old["encoder_param"]
                            and new["C"] == old["C"]),
        "test_predictions_agree": float(same),
        "speedup_cpu": _r(c_old / c_new, 2),
    }


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--features", type=Path, default=None,
                    help=".npz with F (k, n, d), y (n,), ntr (and optionally g)")
    ap.add_argument("--max-feature-sets", type=int, default=2,
                    help="time the solvers on the first few F[i] (default 2)")
    ap.add_argument("--no-inner", dest="inner", action="store_false",
                    help="skip the inner-CV comparison on --features")
    ap.add_argument("--allow-pickle", action="store_true",
                    help="read an object array g (groups) from --features (a trusted file)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--quick", action="store_true", help="one synthetic shape, one repeat")
    args = ap.parse_args(argv)
    shapes = [(1280, 2400)] if args.quick else [(1280, 2400), (1280, 1200)]
    repeat = 1 if args.quick else args.repeat
    result = {
        "machine": {"platform": platform.platform(), "processor": platform.processor(),
                    "python": platform.python_version(), "blas_threads": args.threads},
        "objective": "0.5 ||w||^2 + C * mean_i max(0, 1 - y_i (w.x_i + b))^2, b unregularised",
        "repeat": repeat,
        "problems": {},
    }
    with threadpool_limits(args.threads):
        for n, d in shapes:
            X, y = _synthetic(n, d, seed=n + d)
            result["problems"][f"synthetic_{n}x{d}"] = _problem(X, y, repeat)
        if args.features is not None:
            with np.load(args.features, allow_pickle=args.allow_pickle) as npz:
                z = {k: npz[k] for k in ("F", "y", "ntr")}
                try:
                    z["g"] = npz["g"]
                except (KeyError, ValueError):  # absent, or an object array: fold by rows
                    pass
            ntr = int(z["ntr"])
            for i in range(min(args.max_feature_sets, len(z["F"]))):
                Ftr = z["F"][i][:ntr]
                X = FeatureStandardizer().fit(Ftr).transform(Ftr)
                result["problems"][f"features_{i}"] = _problem(X, z["y"][:ntr], repeat)
            if args.inner:
                result["inner_cv_one_outer_fold"] = _inner_cv(z)
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()

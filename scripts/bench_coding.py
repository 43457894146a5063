"""Speed and quality of dlsr.coding and dlsr.dictionaries against their peers (JSON on stdout).

Data: 100,000 whitened real 6x6x8 patches (288 dimensions) from the positive rectangles of the
real Jacquard samples (every ``--rect-step``-th rectangle is cropped; patches are drawn with
replacement among the accepted positions of those crops, so some repeat), 300 atoms.

Peers in the same process:
* scikit-learn: ``sparse_encode`` (lasso_lars, omp, threshold), ``MiniBatchDictionaryLearning``
  (lars) and ``KMeans`` (lloyd, random init, 100 iterations, tol=0); for the masked encoders a
  per-sample loop of scikit-learn solvers over the masked sub-problems;
* SPAMS (``spams-bin``, GPL, benchmark-only, imported only if installed): lasso, lassoMask, omp,
  ompMask, trainDL.

Slow peers are timed on a subset and extrapolated linearly (per-patch solvers; the JSON says
which and on how many rows); the online dictionary learners (ours and the peers) are timed on
``--dl-batches`` of the 1,000 mini-batches and extrapolated to 1,000. Ratios are peer seconds /
our seconds (> 1: we are faster). Objectives: mean lasso objective of ours vs the peer on the
same rows, and the max relative gap.

Usage: python scripts/bench_coding.py [--quick] [--n-jobs 2]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "scripts"))

from figure_mosaics import real_patches  # noqa: E402

from dlsr.coding import (  # noqa: E402
    kmeans_triangle,
    lasso,
    lasso_objective,
    lasso_rowwise,
    omp,
    omp_rowwise,
    soft_threshold,
)
from dlsr.dictionaries import learn_dictionary  # noqa: E402


def _timed(f, *a, **k):
    t = time.perf_counter()
    out = f(*a, **k)
    return out, time.perf_counter() - t


def _best(f, *a, repeat=3, **k):
    """Output, best and first of ``repeat`` timed calls."""
    ts = []
    for _ in range(repeat):
        out, t = _timed(f, *a, **k)
        ts.append(t)
    return out, min(ts), ts[0]


def _r(x, nd=3):
    return None if x is None else float(round(x, nd))


def _spams():
    try:
        import spams  # noqa: F401  (GPL: benchmark-only peer)

        return spams
    except Exception:  # noqa: BLE001 - any import problem means "not available"
        return None


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="small smoke run")
    ap.add_argument("--n-jobs", type=int, default=2)
    ap.add_argument("--rect-step", type=int, default=4)
    ap.add_argument("--lam", type=float, default=1.0)
    ap.add_argument("--L", type=int, default=10)
    ap.add_argument("--dl-batches", type=int, default=50)
    args = ap.parse_args(argv)
    q = args.quick
    n = 5000 if q else 100_000
    n_atoms = 300
    nj = args.n_jobs
    lam, L = args.lam, args.L
    sub_lars = 300 if q else 4000
    sub_omp = 1000 if q else 20000
    sub_loop_lasso = 50 if q else 300
    sub_loop_omp = 200 if q else 2000
    sub_spams = n if q else 25000
    dl_batches = 5 if q else args.dl_batches
    t_start = time.perf_counter()
    res = {"load_average_before": os.getloadavg(), "n_patches": n, "n_atoms": n_atoms,
           "n_jobs": nj, "lam": lam, "L": L, "quick": q}

    (Xs, X, M, info), t = _timed(real_patches, n, args.rect_step if not q else 16, 0)
    info["seconds"] = _r(t, 1)
    res["patches"] = info
    X = np.ascontiguousarray(X, dtype=np.float32)
    X64 = X.astype(np.float64)
    spams = _spams()
    res["spams"] = "available" if spams is not None else "not installed"

    # ---------------------------------------------------------------- dictionaries
    dl = {}
    dicts = {}
    for method in ("R", "RP", "GSVQ", "NKM"):
        kw = {"n_iter": 10} if q and method in ("GSVQ", "NKM") else {}
        D, t = _timed(learn_dictionary, X, method, n_atoms, 0, return_centroids=method == "NKM",
                      **kw)
        if method == "NKM":
            D, dicts["NKM_centroids"] = D
        dicts[method] = D
        dl[method] = {"seconds": _r(t)}
    for method in ("SC", "OMP"):
        D, t = _timed(learn_dictionary, X, method, n_atoms, 0, lam=lam, n_nonzero=L,
                      n_iter=dl_batches, n_jobs=nj)
        dicts[method] = D
        dl[method] = {"seconds_measured": _r(t), "batches_measured": dl_batches,
                      "seconds": _r(t * 1000 / dl_batches), "extrapolated_to_batches": 1000}
    # peers
    from sklearn.cluster import KMeans
    from sklearn.decomposition import MiniBatchDictionaryLearning

    it = 10 if q else 100
    km, t = _timed(KMeans(n_atoms, init="random", n_init=1, max_iter=it, tol=0,
                          algorithm="lloyd", random_state=0).fit, X)
    from dlsr.dictionaries import kmeans as our_kmeans

    _, _, our_inertia = our_kmeans(X, n_atoms, it, 0)
    dl["NKM"].update(sklearn_kmeans_seconds=_r(t), ratio_sklearn=_r(t / dl["NKM"]["seconds"]),
                     inertia_ours=_r(our_inertia, 1), inertia_sklearn=_r(km.inertia_, 1),
                     note="sklearn relocates empty clusters to far points; ours resets them "
                          "to random patches (reference)")
    n_mb = 10_000 if not q else 5 * 1000  # scikit-learn's LARS learner: 10 mini-batches
    mb = MiniBatchDictionaryLearning(n_atoms, alpha=lam, max_iter=1, batch_size=1000,
                                     fit_algorithm="lars", tol=0, max_no_improvement=None,
                                     random_state=0, n_jobs=nj)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _, t = _timed(mb.fit, X[: min(n_mb, n)])
    nb = min(n_mb, n) // 1000
    dl["SC"].update(sklearn_minibatch_seconds=_r(t * 1000 / nb), sklearn_batches_measured=nb,
                    ratio_sklearn=_r(t * 1000 / nb / dl["SC"]["seconds"]))
    if spams is not None:
        Xf = np.asfortranarray(X64.T)
        for method, kw in (("SC", dict(mode=2, lambda1=lam)), ("OMP", dict(mode=3, lambda1=L))):
            D0 = np.asfortranarray(dicts["RP"].T)
            _, t = _timed(spams.trainDL, Xf, D=D0, iter=dl_batches, batchsize=1000,
                          numThreads=nj, verbose=False, **kw)
            dl[method].update(spams_trainDL_seconds=_r(t * 1000 / dl_batches),
                              ratio_spams=_r(t * 1000 / dl_batches / dl[method]["seconds"]))
    res["dictionaries"] = dl
    res["dictionaries_seconds_total"] = _r(time.perf_counter() - t_start, 1)

    # ---------------------------------------------------------------- encoders
    from sklearn.decomposition import sparse_encode

    D = dicts["SC"]
    enc = {}
    A, t = _timed(lasso, X, D, lam, n_jobs=nj)
    sl = slice(0, sub_lars)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        R, ts = _timed(sparse_encode, X64[sl], D, algorithm="lasso_lars", alpha=lam, n_jobs=nj)
    o_ours = lasso_objective(X64[sl], D, A[sl], lam)
    o_ref = lasso_objective(X64[sl], D, R, lam)
    ts_full = ts * n / sub_lars
    enc["lasso"] = {"seconds": _r(t), "nnz_mean": _r((A != 0).sum(1).mean(), 1),
                    "sklearn_lasso_lars_seconds": _r(ts_full), "sklearn_rows_measured": sub_lars,
                    "ratio_sklearn": _r(ts_full / t, 1),
                    "objective_mean_ours": _r(o_ours.mean(), 6),
                    "objective_mean_sklearn": _r(o_ref.mean(), 6),
                    "objective_max_rel_gap": float((o_ours - o_ref).max() / o_ref.mean())}
    Am, t = _timed(lasso, X, D, lam, mask=M, n_jobs=nj)
    ls = slice(0, sub_loop_lasso)
    Rl, tl = _timed(lasso_rowwise, X64[ls], D, lam, M[ls])
    o1 = lasso_objective(X64[ls], D, Am[ls], lam, M[ls])
    o2 = lasso_objective(X64[ls], D, Rl, lam, M[ls])
    enc["masked_lasso"] = {"seconds": _r(t), "per_sample_loop_seconds": _r(tl * n / sub_loop_lasso),
                           "loop_rows_measured": sub_loop_lasso,
                           "ratio_loop": _r(tl * n / sub_loop_lasso / t, 1),
                           "objective_max_rel_gap_vs_loop": float((o1 - o2).max() / o2.mean())}
    Ao, t = _timed(omp, X, D, L, n_jobs=nj)
    so = slice(0, sub_omp)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        Ro, ts = _timed(sparse_encode, X64[so], D, algorithm="omp", n_nonzero_coefs=L,
                        n_jobs=nj)
    big = np.abs(Ro) > 1e-4 * np.abs(Ro).max(axis=1, keepdims=True)
    same = np.all((np.abs(Ao[so]) > 1e-4 * np.abs(Ao[so]).max(axis=1, keepdims=True)) == big, 1)
    enc["omp"] = {"seconds": _r(t), "sklearn_omp_seconds": _r(ts * n / sub_omp),
                  "sklearn_rows_measured": sub_omp, "ratio_sklearn": _r(ts * n / sub_omp / t, 1),
                  "same_support_fraction": _r(same.mean(), 4),
                  "max_abs_coef_diff_same_support": _r(np.abs(Ao[so][same] - Ro[same]).max(), 6)}
    for LL in sorted({1, L}):
        Amo, t = _timed(omp, X, D, LL, mask=M, n_jobs=nj)
        lo = slice(0, sub_loop_omp)
        Rlo, tl = _timed(omp_rowwise, X64[lo], D, LL, M[lo])
        enc[f"masked_omp_L{LL}"] = {
            "seconds": _r(t), "per_sample_loop_seconds": _r(tl * n / sub_loop_omp),
            "loop_rows_measured": sub_loop_omp, "ratio_loop": _r(tl * n / sub_loop_omp / t, 1),
            "max_abs_coef_diff_vs_loop": _r(np.abs(Amo[lo] - Rlo).max(), 6)}
    # dense encoders (wall time, float32): best of 3 warm calls (as timeit), first call beside
    Dt32 = np.ascontiguousarray(D.T, dtype=np.float32)
    P = np.empty((n, D.shape[0]), np.float32)
    _, tmm, _ = _best(np.matmul, X, Dt32, out=P)  # the floor: the product alone
    T, t, t1 = _best(soft_threshold, X, D, lam)
    Rt, ts, _ = _best(sparse_encode, X64, D, algorithm="threshold", alpha=lam)
    enc["soft_threshold"] = {"seconds": _r(t, 4), "first_call_seconds": _r(t1, 4),
                             "patches_per_second": _r(n / t, 0),
                             "matmul_only_seconds": _r(tmm, 4),
                             "sklearn_seconds": _r(ts, 4), "ratio_sklearn": _r(ts / t, 1),
                             "max_abs_diff": _r(np.abs(T - Rt).max(), 6)}
    C = dicts["NKM_centroids"]
    T, t, t1 = _best(kmeans_triangle, X, C)
    enc["triangle"] = {"seconds": _r(t, 4), "first_call_seconds": _r(t1, 4),
                       "patches_per_second": _r(n / t, 0)}
    if spams is not None:
        ss = slice(0, sub_spams)
        Xf = np.asfortranarray(X64[ss].T)
        Df = np.asfortranarray(D.T)
        Mf = np.asfortranarray(M[ss].T)
        f = n / sub_spams
        _, t = _timed(spams.lasso, Xf, D=Df, lambda1=lam, mode=2, numThreads=nj)
        enc["lasso"].update(spams_seconds=_r(t * f),
                            ratio_spams=_r(t * f / enc["lasso"]["seconds"]))
        _, t = _timed(spams.lassoMask, Xf, D=Df, B=Mf, lambda1=lam, mode=2, numThreads=nj)
        enc["masked_lasso"].update(spams_seconds=_r(t * f),
                                   ratio_spams=_r(t * f / enc["masked_lasso"]["seconds"]))
        _, t = _timed(spams.omp, Xf, D=Df, L=L, numThreads=nj)
        enc["omp"].update(spams_seconds=_r(t * f), ratio_spams=_r(t * f / enc["omp"]["seconds"]))
        for LL in sorted({1, L}):
            _, t = _timed(spams.ompMask, Xf, D=Df, B=Mf, L=LL, numThreads=nj)
            e = enc[f"masked_omp_L{LL}"]
            e.update(spams_seconds=_r(t * f), ratio_spams=_r(t * f / e["seconds"]))
        res["spams_rows_measured"] = sub_spams
    res["encoders"] = enc
    res["total_seconds"] = _r(time.perf_counter() - t_start, 1)
    res["load_average_after"] = os.getloadavg()
    print(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()

"""The figures of the run report: success rates with their intervals, success per object, the
rectangle metric's verdicts against the physical outcomes, and the paired differences between
detectors (PNG files, matplotlib).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["plot_success_rates", "plot_success_per_object", "plot_verdicts",
           "plot_paired_differences"]


def _pyplot():
    # deferred, heavy and rarely used: matplotlib, for figures only
    import matplotlib

    matplotlib.use("Agg", force=False)
    # deferred, heavy and rarely used: matplotlib, for figures only
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    _pyplot().close(fig)
    return path


def _finite_ci(ci) -> bool:
    return ci is not None and all(v is not None and v == v for v in ci)


def plot_success_rates(summaries: dict, path) -> Path:
    """Physical success rate per detector with its Wilson 95 % interval, on all objects and on
    the objects graspable by physics (:mod:`graspsim.labels.graspability`).

    Parameters
    ----------
    summaries : dict
        Detector name -> trial summary (:func:`graspsim.eval.summary.summarize`: ``successes``,
        ``n``, ``success_rate``, ``success_ci95``, ``graspable_*``).
    path : str or Path
        The PNG written.

    Returns
    -------
    Path
    """
    plt = _pyplot()
    names = list(summaries)
    if not names:
        raise ValueError("no trial summaries to plot")
    fig, ax = plt.subplots(figsize=(8, 1.2 + 0.7 * len(names)))
    series = (("all objects", "", "o", "tab:blue", -0.15),
              ("graspable objects only", "graspable_", "s", "tab:orange", 0.15))
    for label, pre, marker, color, dy in series:
        ys, xs, lo, hi, texts = [], [], [], [], []
        for i, name in enumerate(names):
            s = summaries[name]
            rate, ci = s.get(f"{pre}success_rate"), s.get(f"{pre}success_ci95")
            if rate is None or not _finite_ci(ci):
                continue
            ys.append(i + dy)
            xs.append(100 * rate)
            lo.append(100 * (rate - ci[0]))
            hi.append(100 * (ci[1] - rate))
            k = s["successes"] if not pre else round(rate * s["graspable_n"])
            n = s["n"] if not pre else s["graspable_n"]
            texts.append((100 * ci[1], i + dy, f"{k}/{n}"))
        ax.errorbar(xs, ys, xerr=[lo, hi], fmt=marker, color=color, capsize=3, label=label)
        for x, y, t in texts:
            ax.text(x + 1.5, y, t, va="center", fontsize=8, color=color)
    ax.set_yticks(range(len(names)), names)
    ax.set_ylim(len(names) - 0.5, -0.5)
    ax.set_xlim(-3, 112)
    ax.set_xticks(range(0, 101, 20))
    ax.set_xlabel("physical grasp success (%), Wilson 95 % interval")
    ax.grid(axis="x", alpha=0.3)
    ax.legend(loc="lower center", bbox_to_anchor=(0.5, 1.0), ncol=2, frameon=False)
    return _save(fig, path)


def plot_success_per_object(summaries: dict, path) -> Path:
    """Heat map of the success rate per test object (rows) and detector (columns).

    Parameters
    ----------
    summaries : dict
        Detector name -> trial summary with ``per_object`` (object -> ``successes``, ``n``).
    path : str or Path

    Returns
    -------
    Path
    """
    plt = _pyplot()
    names = list(summaries)
    objects = sorted({o for s in summaries.values() for o in s.get("per_object", {})})
    if not names or not objects:
        raise ValueError("no per-object results to plot")
    rate = np.full((len(objects), len(names)), np.nan)
    text = [["" for _ in names] for _ in objects]
    for j, name in enumerate(names):
        for i, obj in enumerate(objects):
            v = summaries[name].get("per_object", {}).get(obj)
            if v and v["n"]:
                rate[i, j] = v["successes"] / v["n"]
                text[i][j] = f"{v['successes']}/{v['n']}"
    longest = max(len(o) for o in objects)
    fig, ax = plt.subplots(figsize=(1.5 + 0.08 * longest + 1.1 * len(names),
                                    1.4 + 0.32 * len(objects)))
    cmap = plt.get_cmap("viridis").with_extremes(bad="#dddddd")  # gray: no trial
    im = ax.imshow(np.ma.masked_invalid(rate), cmap=cmap, vmin=0, vmax=1, aspect="auto")
    for i in range(len(objects)):
        for j in range(len(names)):
            if text[i][j]:
                ax.text(j, i, text[i][j], ha="center", va="center", fontsize=8,
                        color="black" if rate[i, j] > 0.6 else "white")
    ax.set_xticks(range(len(names)), names, rotation=30, ha="right")
    ax.set_yticks(range(len(objects)), objects)
    ax.tick_params(length=0)
    ax.set_title("physical success per object (successes/trials)", fontsize=10)
    fig.colorbar(im, ax=ax, fraction=0.05, pad=0.03, label="success rate")
    return _save(fig, path)


def plot_verdicts(summaries: dict, path) -> Path:
    """The rectangle metric's verdict against the physical outcome, one 2x2 panel per detector.

    Parameters
    ----------
    summaries : dict
        Detector name -> trial summary with ``verdict_vs_outcome`` and ``metric_n``; detectors
        without verdicts (unlabelled scenes) are left out.
    path : str or Path

    Returns
    -------
    Path
    """
    plt = _pyplot()
    names = [n for n, s in summaries.items() if s.get("metric_n")]
    if not names:
        raise ValueError("no rectangle-metric verdicts to plot")
    fig, axes = plt.subplots(1, len(names), figsize=(0.6 + 2.6 * len(names), 3.0),
                             squeeze=False)
    for ax, name in zip(axes[0], names, strict=True):
        s = summaries[name]
        t = s["verdict_vs_outcome"]
        m = np.array([[t["metric_true"]["success"], t["metric_true"]["failure"]],
                      [t["metric_false"]["success"], t["metric_false"]["failure"]]])
        frac = m / max(1, m.sum())
        ax.imshow(frac, cmap="Blues", vmin=0, vmax=1)
        for i in range(2):
            for j in range(2):
                ax.text(j, i, f"{m[i, j]}\n{100 * frac[i, j]:.0f} %", ha="center",
                        va="center", fontsize=9,
                        color="white" if frac[i, j] > 0.55 else "black")
        ax.set_xticks([0, 1], ["succeeded", "failed"])
        ax.set_yticks([0, 1], ["correct", "wrong"])
        ax.set_xlabel("physical outcome")
        ax.tick_params(length=0)
        agree = s.get("agreement")
        ax.set_title(f"{name}\nagreement {100 * agree:.0f} %" if agree is not None else name,
                     fontsize=10)
    axes[0][0].set_ylabel("rectangle metric says")
    fig.tight_layout()
    return _save(fig, path)


def plot_paired_differences(comparisons: list[dict], path) -> Path:
    """Forest plot of paired differences in success rate (A - B) with their intervals.

    Parameters
    ----------
    comparisons : list of dict
        From :func:`graspsim.eval.compare.compare_pair`.
    path : str or Path

    Returns
    -------
    Path
    """
    plt = _pyplot()
    if not comparisons:
        raise ValueError("no comparisons to plot")
    fig, ax = plt.subplots(figsize=(8, 1.2 + 0.6 * len(comparisons)))
    labels = []
    for i, c in enumerate(comparisons):
        d = 100 * c["difference"]
        lo, hi = (100 * v for v in c["difference_ci"])
        color = {"a": "tab:green", "b": "tab:red"}.get(c["better"], "tab:gray")
        ax.errorbar([d], [i], xerr=[[d - lo], [hi - d]], fmt="o", color=color, capsize=3)
        labels.append(f"{c['a']['name']} - {c['b']['name']}")
    ax.axvline(0, color="black", lw=0.8)
    ax.set_yticks(range(len(comparisons)), labels)
    ax.set_ylim(len(comparisons) - 0.5, -0.5)
    ax.set_xlim(-100, 100)
    ax.set_xticks(range(-100, 101, 25))
    right = ax.twinx()  # the p-values as labels of a right-hand axis
    right.set_ylim(ax.get_ylim())
    right.set_yticks(range(len(comparisons)),
                     [f"p = {c['mcnemar_p']:.2g}" for c in comparisons])
    right.tick_params(length=0)
    level = f"{100 * (1 - comparisons[0]['alpha']):g} %"
    ax.set_xlabel(f"paired difference in success (percentage points), {level} interval "
                  "(Newcombe); p: exact McNemar")
    ax.grid(axis="x", alpha=0.3)
    return _save(fig, path)

"""The statistics of a paired study: a metric's mean and confidence interval over trials, and the paired
tests of two conditions (Wilcoxon signed-rank, paired t, Cohen's d_z), with scipy.stats. Used by the
report and by the drivers' comparison (``rl-compare``)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import pandas as pd
from scipy import stats

from dt_highway.metrics.trial_log import FINISHED_STATUSES

MIN_PAIRS = 10
"""Below this many pairs a comparison carries a small-sample warning"""


def describe(x: np.ndarray, lo: float = -math.inf, hi: float = math.inf) -> dict[str, Any]:
    """n, mean, SD (N-1) and the 95 % confidence interval of the mean of the finite values of ``x``.

    The interval is Student t's, ``mean +/- t(0.975, n-1) SD / sqrt(n)``, clipped to ``[lo, hi]``,
    the range the metric can take (:data:`dt_highway.report.METRIC_INFO`): a variance's interval does not go
    below 0, a share's not above 1.

    :param x: one value per trial
    :param lo: the smallest value the metric can take
    :param hi: the largest value the metric can take
    :return: ``n``, ``mean``, ``sd``, ``ci95`` ``[low, high]`` (``None`` with fewer than 2 values)
        and ``ci95_clipped`` (a bound was clipped)
    """
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    n = len(x)
    if not n:
        return {"n": 0, "mean": None, "sd": None, "ci95": [None, None], "ci95_clipped": False}
    mean = float(x.mean())
    sd = float(x.std(ddof=1)) if n > 1 else None
    ci: list[float | None] = [None, None]
    clipped = False
    if n > 1 and sd is not None:
        half = float(stats.t.ppf(0.975, n - 1) * sd / math.sqrt(n))
        low, high = mean - half, mean + half
        clipped = low < lo or high > hi
        ci = [max(low, lo), min(high, hi)]
    return {"n": n, "mean": mean, "sd": sd, "ci95": ci, "ci95_clipped": clipped}


def completed_pairs(metrics: pd.DataFrame) -> pd.DataFrame:
    """The completed trials not excluded, with their pair ``key``: participant and seed (the pair number
    without a seed).

    :param metrics: one row per trial (:func:`dt_highway.report.collect`)
    :return: a copy of those trials' rows, with a ``key`` column
    """
    ok = metrics["status"].isin(FINISHED_STATUSES)
    if "excluded" in metrics:
        ok &= metrics["excluded"].fillna("").astype(str) == ""
    done = metrics[ok].copy()
    seed = done["seed"] if "seed" in done else pd.Series(np.nan, index=done.index)
    pair = done["pair"] if "pair" in done else pd.Series(np.nan, index=done.index)
    seed_key = ("seed " + seed.astype(str)).where(seed.notna(), "pair " + pair.astype(str))
    participant = done["participant"].fillna("").astype(str) if "participant" in done else ""
    done["key"] = participant + "/" + seed_key
    return done


def check_conditions(metrics: pd.DataFrame, *names: str) -> None:
    """Refuse a condition no trial of ``metrics`` ran in (its trials may all be excluded: that is no mistake).

    :param metrics: one row per trial (:func:`dt_highway.report.collect`)
    :param names: the conditions that must be there
    :raises ValueError: one line, naming the missing condition and the ones held
    """
    held = sorted({str(c) for c in metrics["condition"].dropna()}) if "condition" in metrics else []
    for name in names:
        if name not in held:
            raise ValueError(f"no trial of condition {name!r} in these metrics (conditions: {', '.join(held) or 'none'})")


def paired_tests(metrics: pd.DataFrame, a: str, b: str, names: Sequence[str]) -> dict[str, Any]:
    """Wilcoxon signed-rank and paired t-test of ``b - a`` per metric, with Cohen's ``d_z``.

    Pairs: same seed (and participant, for keyboard trials).

    :param metrics: one row per trial (:func:`dt_highway.report.collect`)
    :param a: the reference condition
    :param b: the condition tested against it
    :param names: the columns tested (a column without pairs is left out)
    :return: per metric: ``n_pairs``, ``mean_diff``, ``wilcoxon_p``, ``ttest_p``, ``effect_size_dz``
    :raises ValueError: one line, when ``metrics`` holds no trial of ``a`` or ``b`` (a mistyped name)
    """
    check_conditions(metrics, a, b)
    done = completed_pairs(metrics)
    out: dict[str, Any] = {}
    for m in names:
        if m not in done:
            continue
        wide = done.pivot_table(index="key", columns="condition", values=m, aggfunc="first")
        if a not in wide or b not in wide:
            continue
        pair = wide[[a, b]].replace([np.inf, -np.inf], np.nan).dropna()
        diff = (pair[b] - pair[a]).to_numpy(float)
        res: dict[str, Any] = {"n_pairs": len(diff), "mean_diff": float(diff.mean()) if len(diff) else None,
                               "wilcoxon_p": None, "ttest_p": None, "effect_size_dz": None}
        if len(diff) >= 2 and np.any(diff != 0):
            res["wilcoxon_p"] = float(stats.wilcoxon(diff).pvalue)
            sd = diff.std(ddof=1)
            if sd > 0:
                res["ttest_p"] = float(stats.ttest_rel(pair[b], pair[a]).pvalue)
                res["effect_size_dz"] = float(diff.mean() / sd)
        out[m] = res
    return out

"""The safety-metrics report of a study directory (paper Fig. 7): tables, paired tests, plots.

``write_report(study_dir)`` reads every trial log under ``<study>/trials`` and writes
``metrics.csv`` (one row per trial), ``summary.json`` (per condition: n, mean, SD and 95 %
CI of each metric, conflicts per hour, collision kinds, trials cut short by a collision, the
overlay's metrics; paired tests between conditions) and a self-contained ``report.html``
(plots embedded as PNG). Practice trials are left out.

Every trial is checked as it is read (:func:`~dt_highway.metrics.trial_log.check_trial`:
completed, every row its duration makes, the columns there and numbers, a readable
``meta.json``); a trial that fails is *excluded*: one warning line names it and the reason,
and the report and ``summary.json`` (``excluded``) list it. An attempt stopped before its end
(status ``aborted``: Esc, the window closed, a signal, an error, a process that died) is kept
apart: ``aborted_trials`` lists it with its reason and the attempt driven instead (a keyboard
session keeps every attempt: ``P01-adas``, ``P01-adas-retry1``...). Only input that leaves no study to
report (no study directory, no trials, none usable) is an error. Both files open with the
study's provenance (:func:`provenance`: scenario, trial length, seeds, drivers, package
version and git commit, dates, hosts). Metrics are labelled with their units from one table
(:data:`METRIC_INFO`); 95 % confidence intervals are Student-t intervals of the mean clipped
to the metric's range (:func:`describe`).

Comparisons (:func:`comparisons`), for any number of conditions: every condition against
``baseline``, and each ``adas*`` condition against its sham (``sham-<mode>`` for
``adas-<mode>`` when the study has it, else ``sham``). Pairs are trials with the same seed (and
participant, for keyboard trials; the pair number when a trial has no seed). A trial cut short
by a collision stays in its pair (its metrics cover the time it ran); the report lists such
trials and counts, per comparison, the pairs that hold one.

Questionnaires (only when some trial directory holds a ``questionnaires.json``): each score is a
column ``q_<name>`` of ``metrics.csv`` (:func:`questionnaire_scores`); ``summary.json``'s
``questionnaires`` and the html's section hold, per condition, n, mean, SD and 95 % CI of each
score and the same paired tests between conditions (:func:`questionnaire_summary`).
"""

from __future__ import annotations

import base64
import io
import json
import math
import socket
import sys
import time
import warnings
from collections import Counter
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import jinja2
import matplotlib
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from dt_highway._version import __version__
from dt_highway.conditions import CONDITIONS
from dt_highway.config import ConfigError
from dt_highway.jsonio import dump_json, finite_number
from dt_highway.metrics.overlay_metrics import WARNING_HORIZON_S, WARNING_LEAD_S, marked_before, marked_ids, warned_cut_ins
from dt_highway.metrics.questionnaires import read_results
from dt_highway.metrics.safety import (
    CONFLICT_TTC_S,
    CUT_IN_WINDOW_S,
    MS_TO_KMH,
    TTC_CAP_S,
    TTC_STAR_S,
    collision_label,
)
from dt_highway.metrics.stats import MIN_PAIRS, check_conditions, completed_pairs, describe
from dt_highway.metrics.stats import paired_tests as stats_paired_tests
from dt_highway.metrics.trial_log import (
    FINISHED_STATUSES,
    META,
    Trial,
    TrialLogError,
    check_trial,
    git_commit,
    load_trial,
)

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

SUMMARY_METRICS = ("speed_variance_kmh2", "ttc_mean_s", "ttc_min_s", "tet_s", "tit_s2", "ttc2d_min_s", "tet2d_s",
                   "tit2d_s2", "conflicts_2d_per_h", "speed_mean_kmh", "headway_mean_s", "drac_max_mps2", "hard_brakes",
                   "cut_in_ttc_min_s", "pet_min_s", "pet_median_s", "reaction_mean_s")
"""Metrics summarised per condition and tested between conditions"""
OVERLAY_METRICS = ("overlay_on_share", "marks_per_min", "false_warnings_per_min", "cut_ins_warned_share")
"""The overlay's metrics, summarised per condition (not tested: nothing is shown in ``baseline``)"""
PAPER = {"speed_variance_kmh2": (16.6, 14.2), "ttc_mean_s": (1.2, 3.2)}
"""The paper's values, baseline -> ADAS (units not stated there)"""
DEFINITIONS = {
    "speed_variance_kmh2": (
        "sample variance (N-1) of the ego's speed in km/h over the trial's simulation steps [(km/h)^2]"
    ),
    "ttc_mean_s": f"mean TTC over closing samples with TTC below {TTC_CAP_S:g} s [s]",
    "ttc_min_s": f"minimum TTC over the trial, capped at {TTC_CAP_S:g} s (never closer: {TTC_CAP_S:g}) [s]",
    "tet_s": f"time exposed TTC: time with 0 <= TTC <= {TTC_STAR_S:g} s [s] (Minderhoud & Bovy 2001)",
    "tit_s2": f"time integrated TTC: integral of ({TTC_STAR_S:g} s - TTC) over that time [s^2]",
    "ttc2d_min_s": f"minimum 2-D TTC (oriented rectangles, constant velocity; Jiao 2023), capped at {TTC_CAP_S:g} s [s]",
    "tet2d_s": f"time with 0 <= 2-D TTC <= {TTC_STAR_S:g} s [s]",
    "tit2d_s2": f"integral of ({TTC_STAR_S:g} s - 2-D TTC) over that time [s^2]",
    "conflicts_2d_per_h": f"onsets of 2-D TTC below {CONFLICT_TTC_S:g} s per hour of trial [1/h]",
    "speed_mean_kmh": "mean ego speed [km/h]",
    "headway_mean_s": "mean time headway gap / ego speed, with a leader [s]",
    "drac_max_mps2": "maximum deceleration rate to avoid the crash dv^2 / (2 gap), capped at 10 m/s^2 (about 1 g) [m/s^2]",
    "hard_brakes": "onsets of ego deceleration >= 3 m/s^2 [-]",
    "cut_in_ttc_min_s": f"smallest of the cut-ins' minimum TTC to the cutting vehicle, capped at {TTC_CAP_S:g} s [s]",
    "pet_min_s": (
        "smallest of the cut-ins' post-encroachment time along the ego's path: from the cutting car's rear "
        f"leaving a spot to the ego's front reaching it, capped at {TTC_CAP_S:g} s [s]"
    ),
    "pet_median_s": "median of the cut-ins' PET, each capped the same [s]",
    "reaction_mean_s": "mean time from a cut-in to the ego's first deceleration >= 1 m/s^2 [s]",
    "ttc": (
        "gap / closing speed, bumper to bumper to the nearest vehicle ahead whose (heading-aware) footprint "
        "overlaps the ego's body laterally; infinite when not closing; a contact (gap <= 0) is a collision "
        "state, not a TTC sample"
    ),
    "collisions": "onsets of the ego's crash [-]",
    "collision kinds": (
        "cut_in: the partner cut in front of the ego within 5 s; rear_end: front/rear faces met (ego struck a "
        "vehicle ahead, or was struck from behind); side_swipe: sides met, with whose lane change"
    ),
    "cut short": "the trial ended before its configured duration with a collision",
    "overlay_on_share": "share of the trial's samples with at least one mark shown [-]",
    "marks_per_min": "mark onsets per minute [1/min]",
    "false_warnings_per_min": (
        f"mark onsets on a car that did not cut in in front of the ego within {WARNING_HORIZON_S + 1:g} s, "
        "per minute [1/min]"
    ),
    "cut_ins_warned_share": (
        f"share of cut-ins whose car was marked {WARNING_LEAD_S:g} to {WARNING_HORIZON_S + 1:g} s before its "
        "first overlap with the ego's path [-]"
    ),
}

_INF = math.inf
METRIC_INFO: dict[str, tuple[str, str, float, float]] = {
    "speed_variance_kmh2": ("Speed variance", "(km/h)^2", 0.0, _INF),
    "ttc_mean_s": ("Mean TTC while closing", "s", 0.0, TTC_CAP_S),
    "ttc_min_s": ("Minimum TTC", "s", 0.0, TTC_CAP_S),
    "tet_s": ("Time exposed TTC (TET)", "s", 0.0, _INF),
    "tit_s2": ("Time integrated TTC (TIT)", "s^2", 0.0, _INF),
    "ttc2d_min_s": ("Minimum 2-D TTC", "s", 0.0, TTC_CAP_S),
    "tet2d_s": ("2-D TET", "s", 0.0, _INF),
    "tit2d_s2": ("2-D TIT", "s^2", 0.0, _INF),
    "conflicts_2d_per_h": (f"Conflicts (2-D TTC < {CONFLICT_TTC_S:g} s)", "1/h", 0.0, _INF),
    "speed_mean_kmh": ("Mean speed", "km/h", 0.0, _INF),
    "headway_mean_s": ("Mean time headway", "s", 0.0, _INF),
    "drac_max_mps2": ("Maximum DRAC", "m/s^2", 0.0, 10.0),
    "hard_brakes": ("Hard brakes", "count", 0.0, _INF),
    "cut_in_ttc_min_s": ("Minimum TTC to a cutting-in car", "s", 0.0, TTC_CAP_S),
    "pet_min_s": ("Minimum PET of the cut-ins", "s", 0.0, TTC_CAP_S),
    "pet_median_s": ("Median PET of the cut-ins", "s", 0.0, TTC_CAP_S),
    "reaction_mean_s": ("Mean reaction time to a cut-in", "s", 0.0, _INF),
    "overlay_on_share": ("Time with a mark shown", "share", 0.0, 1.0),
    "marks_per_min": ("Marks shown", "1/min", 0.0, _INF),
    "false_warnings_per_min": ("False warnings", "1/min", 0.0, _INF),
    "cut_ins_warned_share": ("Cut-ins warned in time", "share", 0.0, 1.0),
}
"""Each reported metric: its label, its unit and the range its values can take (the
confidence intervals are clipped to it), used by the tables and the plots"""
NOTES = {
    "ci95": ("95 % confidence interval of the mean: Student t (mean +/- t(0.975, n-1) SD / sqrt n), clipped to "
             "the range the metric can take (>= 0; TTC, 2-D TTC and PET <= the "
             f"{TTC_CAP_S:g} s cap; shares <= 1); a bound that was clipped is marked *"),
    "d_z": "Cohen's d_z for paired samples: the mean of the paired differences (b - a) divided by their SD (N-1)",
    "p": ("two-sided p-values of the Wilcoxon signed-rank test and the paired t-test, given to 3 decimals "
          "(below 0.001: < 0.001), not corrected for the number of metrics and comparisons"),
    "TTC*": f"TTC* = {TTC_STAR_S:g} s, the TET/TIT threshold (SUMO's SSM device default), dashed in the TTC plot",
    "small sample": (f"a comparison with fewer than {MIN_PAIRS} pairs is flagged: its p-values and intervals "
                     "say little"),
}
"""How the report's statistics are made (in ``summary.json`` and the html)"""


def metric_label(name: str, tex: bool = False) -> str:
    """A metric's label with its unit, ``"Speed variance [(km/h)^2]"`` (:data:`METRIC_INFO`).

    :param name: the metric's column name (``speed_variance_kmh2``); an unknown one is returned as it is
    :param tex: matplotlib mathtext for the powers (``(km/h)$^2$``), for plots
    :return: the label
    """
    if name not in METRIC_INFO:
        return name
    label, unit = METRIC_INFO[name][:2]
    if tex:
        unit = unit.replace("^2", "$^2$")
    return f"{label} [{unit}]"


def condition_order(conditions: Sequence[Any]) -> list[str]:
    """Conditions in the report's order: as in :data:`~dt_highway.conditions.CONDITIONS`
    (``baseline``, ``adas``, ``adas-*``, ``sham*``), then any other by name.

    :param conditions: the conditions found (each taken as its string, duplicates once)
    :return: their names, in that order
    """
    names = {str(c) for c in conditions}
    return [c for c in CONDITIONS if c in names] + sorted(names - set(CONDITIONS))


def comparisons(conditions: Sequence[Any]) -> list[tuple[str, str]]:
    """The paired comparisons ``(a, b)`` (tested as ``b - a``) of a study's conditions: every
    condition against ``baseline``; each ``adas*`` against its sham (``sham-<mode>`` for
    ``adas-<mode>`` when present, else ``sham``).

    :param conditions: the study's conditions
    :return: the pairs, ``baseline`` ones first
    """
    conds = condition_order(conditions)
    out = [("baseline", c) for c in conds if c != "baseline"] if "baseline" in conds else []
    for c in conds:
        if c.startswith("adas"):
            sham = "sham" + c[len("adas"):]
            sham = sham if sham in conds else "sham"
            if sham in conds:
                out.append((sham, c))
    return out


Warn = Callable[[str], None]
"""Takes one warning line (an excluded trial, an unreadable ``study.json``)"""


def _stderr_warning(message: str) -> None:
    print(f"warning: {message}", file=sys.stderr)


def _trial_dirs(root: Path) -> list[Path]:
    """The trial directories of a study (every directory under ``trials/``).

    :raises ConfigError: one line naming the file, when there is no study to report
    """
    if not root.exists():
        raise ConfigError(f"study directory {root} does not exist")
    if not root.is_dir():
        raise ConfigError(f"{root} is not a study directory (it is a file)")
    trials = root / "trials"
    try:
        dirs = sorted(p for p in trials.iterdir() if p.is_dir() and not p.name.startswith("."))
    except FileNotFoundError:
        dirs = []
    except NotADirectoryError:
        raise ConfigError(f"{trials} is not a directory") from None
    except OSError as exc:
        raise ConfigError(f"cannot read {trials}: {exc.strerror or exc}") from None
    if not dirs:
        raise ConfigError(f"no trials under {trials} (run dt-highway study first)")
    return dirs


def _planned_not_run(root: Path, dirs: Sequence[Path], warn: Warn) -> list[dict[str, str]]:
    """The trials the study's ``study.json`` plans that have no directory (an interrupted study)."""
    record = root / "study.json"
    if not record.exists():
        return []
    try:
        planned = {Path(t["directory"]).name for t in json.loads(record.read_text(encoding="utf-8"))["trials"]}
    except (OSError, ValueError, KeyError, TypeError) as exc:
        warn(f"{record} cannot be read ({type(exc).__name__}): trials planned but not run are not listed")
        return []
    have = {d.name for d in dirs}
    return [{"trial": name, "reason": "not run (planned in study.json, no trial directory)"}
            for name in sorted(planned - have)]


def read_checked(directory: str | Path) -> tuple[Trial | None, str | None]:
    """Read a trial directory and check it (:func:`~dt_highway.metrics.trial_log.check_trial`).

    :param directory: the trial's directory
    :return: the trial (``None`` when it cannot be read) and why it cannot enter the statistics
        (``None`` when it can)
    """
    d = Path(directory)
    if not (d / META).exists():
        return None, f"{META} missing"
    try:
        trial = load_trial(d)
    except TrialLogError as exc:
        return None, exc.reason
    except OSError as exc:
        return None, f"cannot be read ({exc.strerror or exc})"
    return trial, check_trial(trial)


def _row(d: Path, trial: Trial | None) -> dict[str, Any]:
    meta = trial.meta if trial is not None else {}
    return {"trial": d.name, "condition": meta.get("condition"), "pair": meta.get("pair"),
            "participant": meta.get("participant"), "driver": meta.get("driver"), "seed": meta.get("seed"),
            "status": meta.get("status"), "end_reason": meta.get("end_reason"),
            "planned_duration_s": trial.planned_duration_s if trial is not None else None}


def _plot_data(trial: Trial, extra: dict[str, Any]) -> None:
    """Add a usable trial's TTC samples, speed traces around its cut-ins and their marks to ``extra``."""
    s, cond = trial.steps, trial.meta.get("condition")
    ttc = s["ttc_s"].to_numpy(float)
    extra["ttc"].setdefault(cond, []).append(ttc[(s["closing_mps"].to_numpy(float) > 0) & (ttc < TTC_CAP_S)])
    t = s["t_s"].to_numpy(float)
    v = s["speed_mps"].to_numpy(float) * MS_TO_KMH
    marks = marked_ids(s)
    warned = warned_cut_ins(t, marks, trial.cut_ins)
    in_time = marked_before(t, marks, trial.cut_ins)
    for c, warned_in_time, marked_in_time in zip(trial.cut_ins, warned, in_time, strict=True):
        t0 = float(c["t_s"])
        grid = np.arange(-2.0, CUT_IN_WINDOW_S + 1e-9, 0.5)
        trace = np.interp(t0 + grid, t, v, left=np.nan, right=np.nan)
        extra["traces"].append({"condition": cond, "grid": grid, "speed_kmh": trace - np.interp(t0, t, v)})
        extra["cut_ins"].append({"condition": cond, "driver_type": c.get("driver_type"), "marked_in_time": marked_in_time,
                                 "near_miss": c.get("maneuver") == "dangerous", "warned": warned_in_time})


def collect(study_dir: str | Path, warn: Warn | None = None) -> tuple[pd.DataFrame, dict[str, Any]]:
    """Every trial's metrics (one row each; ``excluded`` holds why a trial is left out) and the
    data the plots and the provenance need.

    Each trial is read and checked (:func:`read_checked`); one that fails is excluded, with one
    warning line naming it and the reason; an attempt stopped before its end (status ``aborted``)
    is listed apart, with one warning line too. Practice trials are left out without a word.

    :param study_dir: the study directory
    :param warn: takes each warning line (default: printed to stderr)
    :return: the rows, and ``traces``, ``ttc``, ``cut_ins`` (plots), ``excluded`` (trial, reason),
        ``aborted`` (the aborted attempts' names) and ``metas`` (the usable trials' metadata)
    :raises ConfigError: one line naming the file, when the study directory or its ``trials/``
        cannot be read, holds no trials, or none usable
    """
    root = Path(study_dir)
    warn = warn or _stderr_warning
    dirs = _trial_dirs(root)
    rows: list[dict[str, Any]] = []
    extra: dict[str, Any] = {"traces": [], "ttc": {}, "cut_ins": [], "excluded": [], "metas": [], "aborted": []}
    for d in dirs:
        trial, reason = read_checked(d)
        if trial is not None and trial.meta.get("practice"):
            continue  # practice trials are not data
        row = _row(d, trial)
        if trial is not None and trial.meta.get("status") == "aborted":  # an attempt stopped early: kept, listed
            row["excluded"] = reason
            rows.append(row)
            extra["aborted"].append(d.name)
            warn(f"trial {d.name}: aborted attempt ({trial.meta.get('end_reason') or 'no reason logged'}), "
                 "not in the statistics")
            continue
        if trial is not None and reason is None:
            try:
                row.update(trial.metrics())
            except Exception as exc:  # noqa: BLE001 - one odd trial must not sink the report: exclude it, say why
                reason = f"its metrics cannot be computed ({type(exc).__name__}: {exc})"
        row["excluded"] = reason or ""
        rows.append(row)
        if trial is None or reason is not None:
            extra["excluded"].append({"trial": d.name, "reason": reason})
            continue
        extra["metas"].append(trial.meta)
        _plot_data(trial, extra)
    extra["excluded"] += _planned_not_run(root, dirs, warn)
    for e in extra["excluded"]:
        warn(f"trial {e['trial']} excluded: {e['reason']}")
    if not extra["metas"]:
        n_out = len(extra["excluded"]) + len(extra["aborted"])
        what = "excluded or aborted" if extra["aborted"] else "excluded"
        why = f"all {n_out} {what} (see the warnings)" if n_out else "only practice trials"
        raise ConfigError(f"no usable trial under {root / 'trials'}: {why}")
    return pd.DataFrame(rows), extra


def _ranges(values: Iterable[int]) -> str:
    """``[0, 1, 2, 5]`` as ``"0-2, 5"``."""
    out: list[str] = []
    vals = sorted(set(values))
    i = 0
    while i < len(vals):
        j = i
        while j + 1 < len(vals) and vals[j + 1] == vals[j] + 1:
            j += 1
        out.append(str(vals[i]) if i == j else f"{vals[i]}-{vals[j]}")
        i = j + 1
    return ", ".join(out)


def _distinct(metas: Sequence[dict[str, Any]], get: Callable[[dict[str, Any]], Any]) -> list[Any]:
    """The distinct non-empty values of ``get(meta)``, sorted by their text."""
    seen: dict[str, Any] = {}
    for m in metas:
        v = get(m)
        if v not in (None, "", []):
            seen.setdefault(json.dumps(v, sort_keys=True, default=str), v)
    return [seen[k] for k in sorted(seen)]


def provenance(study_dir: str | Path, metas: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Where a report came from: the trials' scenario, length, seeds and drivers, the package
    version and git commit that ran them and that wrote the report, dates and hosts.

    :param study_dir: the study directory
    :param metas: the usable trials' metadata (``meta.json``)
    :return: ``study``, ``scenario`` (file names), ``overrides`` (each distinct ``--set`` list),
        ``trial_length_s``, ``simulation_frequency_hz``, ``seeds``, ``seeds_text``, ``drivers``,
        ``participants``, ``trials``, ``package_version`` and ``git_commit`` (``trials``:
        distinct values in the logs, ``report``: this process's; ``None`` outside a git
        checkout), ``trials_started``, ``trials_ended``, ``report_date``, ``hosts``
    """
    def highway(m: dict[str, Any]) -> dict[str, Any]:
        return (m.get("config") or {}).get("highway") or {}

    seeds = [int(m["seed"]) for m in metas if isinstance(m.get("seed"), int)]
    starts = [str(m["start_time"]) for m in metas if m.get("start_time")]
    ends = [str(m["end_time"]) for m in metas if m.get("end_time")]
    return {
        "study": str(Path(study_dir).resolve()),
        "scenario": _distinct(metas, lambda m: Path(m["scenario"]).name if m.get("scenario") else "defaults"),
        "overrides": _distinct(metas, lambda m: m.get("overrides")),
        "trial_length_s": _distinct(metas, lambda m: highway(m).get("duration")),
        "simulation_frequency_hz": _distinct(metas, lambda m: m.get("simulation_frequency_hz")),
        "seeds": sorted(set(seeds)),
        "seeds_text": _ranges(seeds),
        "drivers": _distinct(metas, lambda m: m.get("driver")),
        "participants": _distinct(metas, lambda m: m.get("participant")),
        "trials": len(metas),
        "package_version": {"trials": _distinct(metas, lambda m: m.get("package_version")), "report": __version__},
        "git_commit": {"trials": _distinct(metas, lambda m: m.get("git_commit")), "report": git_commit()},
        "trials_started": min(starts) if starts else None,
        "trials_ended": max(ends) if ends else None,
        "report_date": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "hosts": {"trials": _distinct(metas, lambda m: m.get("host")), "report": socket.gethostname()},
    }


def _cut_short(done: pd.DataFrame) -> pd.Series:
    return done["cut_short"].eq(True) if "cut_short" in done else pd.Series(False, index=done.index)


def _plain(x: Any) -> Any:
    """A numpy scalar as the Python one (for JSON); NaN as ``None``."""
    x = x.item() if isinstance(x, np.generic) else x
    return None if isinstance(x, float) and math.isnan(x) else x


def paired_tests(metrics: pd.DataFrame, a: str = "baseline", b: str = "adas",
                 names: Sequence[str] = SUMMARY_METRICS) -> dict[str, Any]:
    """Paired tests of the report's metrics, condition ``b`` against ``a``.

    :func:`dt_highway.metrics.stats.paired_tests` of the report's metrics (``names``: :data:`SUMMARY_METRICS`).

    :param metrics: one row per trial (:func:`collect`)
    :param a: the reference condition
    :param b: the condition tested against it
    :param names: the columns tested
    :return: per metric: ``n_pairs``, ``mean_diff``, ``wilcoxon_p``, ``ttest_p``, ``effect_size_dz``
    :raises ValueError: one line, when ``metrics`` holds no trial of ``a`` or ``b`` (a mistyped name)
    """
    return stats_paired_tests(metrics, a, b, names)


def compare(metrics: pd.DataFrame, a: str, b: str) -> dict[str, Any]:
    """One paired comparison ``b - a``: the tests (:func:`paired_tests`), how many pairs there
    are and which of them hold a trial cut short by a collision.

    :param metrics: one row per trial (:func:`collect`)
    :param a: the reference condition
    :param b: the condition tested against it
    :return: ``a``, ``b``, ``n_pairs``, ``small_sample`` (fewer than :data:`MIN_PAIRS` pairs),
        ``cut_short_pairs`` (pair keys), ``tests``
    :raises ValueError: one line, when ``metrics`` holds no trial of ``a`` or ``b`` (a mistyped name)
    """
    check_conditions(metrics, a, b)
    done = completed_pairs(metrics)
    sub = done[done["condition"].isin([a, b])]
    counts = sub.groupby("key")["condition"].nunique()
    keys = set(counts[counts == 2].index)
    short = sub[_cut_short(sub) & sub["key"].isin(keys)]
    return {"a": a, "b": b, "n_pairs": len(keys), "small_sample": len(keys) < MIN_PAIRS,
            "cut_short_pairs": sorted(set(short["key"])),
            "tests": paired_tests(metrics, a, b)}


def _condition_entry(g: pd.DataFrame, cuts: list[dict[str, Any]]) -> dict[str, Any]:
    """One condition's summary (completed trials ``g``, its cut-ins)."""
    entry: dict[str, Any] = {"n": int(len(g))}
    for m in SUMMARY_METRICS + OVERLAY_METRICS:
        if m in g:
            lo, hi = METRIC_INFO[m][2:] if m in METRIC_INFO else (-math.inf, math.inf)
            entry[m] = describe(g[m].to_numpy(float), lo, hi)
    entry["collisions"] = int(g["collisions"].sum()) if "collisions" in g else 0
    hours = float(g["duration_s"].sum()) / 3600.0 if "duration_s" in g else 0.0
    conflicts = int(g["conflicts_2d"].fillna(0).sum()) if "conflicts_2d" in g else None
    entry["conflicts_2d"] = conflicts
    entry["conflicts_2d_per_h_pooled"] = conflicts / hours if conflicts is not None and hours else None
    kinds: Counter[str] = Counter()
    if "collision_kind" in g:
        for _, r in g[g["collision_kind"].fillna("").astype(str) != ""].iterrows():
            kinds[collision_label(r["collision_kind"], r.get("collision_striker"), r.get("collision_lane_changer"))] += 1
    entry["collision_kinds"] = dict(sorted(kinds.items()))
    entry["cut_short_trials"] = sorted(g.loc[_cut_short(g), "trial"].astype(str))
    entry["cut_ins"] = len(cuts)
    entry["cut_ins_marked_in_time"] = sum(c["marked_in_time"] for c in cuts)
    rough = [c for c in cuts if c["driver_type"] == "aggressive"]
    entry["cut_ins_by_aggressive"] = len(rough)
    entry["cut_ins_by_aggressive_marked_in_time"] = sum(c["marked_in_time"] for c in rough)
    near = [c for c in cuts if c.get("near_miss")]
    entry["cut_ins_near_miss"] = len(near)
    entry["cut_ins_near_miss_warned"] = sum(bool(c.get("warned")) for c in near)
    if "cut_ins_warned" in g and "cut_ins" in g:
        total = int(g["cut_ins"].fillna(0).sum())
        entry["cut_ins_warned"] = int(g["cut_ins_warned"].fillna(0).sum())
        entry["cut_ins_warned_share_pooled"] = entry["cut_ins_warned"] / total if total else None
    return entry


def aborted_trials(metrics: pd.DataFrame) -> list[dict[str, Any]]:
    """The attempts stopped before their end (status ``aborted``: Esc, the window closed, a signal,
    an error, a process that died), each with its reason and the attempt that was driven instead.

    :param metrics: one row per trial (:func:`collect`)
    :return: per aborted attempt: ``trial``, ``participant``, ``condition``, ``end_reason`` and
        ``retried_in`` (the completed trial of the same participant, condition and seed, or ``None``)
    """
    if "status" not in metrics:
        return []
    done = metrics[metrics["status"].isin(FINISHED_STATUSES)]
    out = []
    for _, r in metrics[metrics["status"] == "aborted"].iterrows():
        same = done[(done["participant"].astype(str) == str(r["participant"]))
                    & (done["condition"].astype(str) == str(r["condition"])) & (done["seed"] == r["seed"])]
        out.append({"trial": r["trial"], "participant": _plain(r["participant"]), "condition": _plain(r["condition"]),
                    "end_reason": _plain(r["end_reason"]), "retried_in": same["trial"].iloc[0] if len(same) else None})
    return out


def summarise(metrics: pd.DataFrame, extra: dict[str, Any]) -> dict[str, Any]:
    """``summary.json``'s contents (but the provenance): per condition, the comparisons
    (``paired_tests``: the ``adas - baseline`` one's tests, when the study has both), the trials
    excluded (``excluded``: trial and reason), aborted and cut short, the metrics' labels and
    units (``labels``), definitions and notes on the statistics.

    :param metrics: :func:`collect`'s metrics (one row per trial)
    :param extra: :func:`collect`'s plot data
    :return: the summary: ``conditions``, ``comparisons``, ``paired_tests``, ``excluded``, ``aborted_trials``,
        ``cut_short_trials``, ``paper``, ``labels``, ``definitions``, ``notes``
    :raises ValueError: on other tables (a one-line note that says so)
    """
    if not isinstance(metrics, pd.DataFrame) or not {"condition", "status"} <= set(metrics.columns) \
            or not isinstance(extra, dict) or "cut_ins" not in extra:
        raise ValueError("summarise takes the metrics and data collect(study_dir) gives")
    done = completed_pairs(metrics)
    conditions = {}
    for cond in condition_order(done["condition"].dropna().unique()):
        g = done[done["condition"].astype(str) == cond]
        conditions[cond] = _condition_entry(g, [c for c in extra["cut_ins"] if str(c["condition"]) == cond])
    comps = [compare(metrics, a, b) for a, b in comparisons(list(conditions))]
    legacy: dict[str, Any] = next((c["tests"] for c in comps if (c["a"], c["b"]) == ("baseline", "adas")), {})
    short = done[_cut_short(done)]
    return {"conditions": conditions, "comparisons": comps, "paired_tests": legacy,
            "excluded": list(extra.get("excluded", [])),
            "aborted_trials": aborted_trials(metrics),
            "cut_short_trials": [
                {"trial": r["trial"], "condition": r["condition"], "pair": _plain(r["pair"]),
                 "duration_s": _plain(r.get("duration_s")), "planned_duration_s": _plain(r.get("planned_duration_s")),
                 "collision": collision_label(r.get("collision_kind"), r.get("collision_striker"),
                                              r.get("collision_lane_changer"))}
                for _, r in short.iterrows()
            ],
            "paper": {k: {"baseline": v[0], "adas": v[1]} for k, v in PAPER.items()},
            "labels": {k: {"label": v[0], "unit": v[1], "range": [v[2], v[3]]} for k, v in METRIC_INFO.items()},
            "definitions": DEFINITIONS, "notes": NOTES}


def _png(fig: Figure) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _legend(ax: Axes) -> None:
    if ax.get_legend_handles_labels()[1]:
        ax.legend(fontsize=8)
    else:
        ax.text(0.5, 0.5, "no data", transform=ax.transAxes, ha="center", va="center", color="0.5")


def _colours(conds: Sequence[str]) -> dict[str, Any]:
    fixed = {"baseline": "tab:grey", "adas": "tab:red", "sham": "tab:blue"}
    spare = iter(c for c in plt.rcParams["axes.prop_cycle"].by_key()["color"] if c not in fixed.values())
    return {c: fixed.get(c) or next(spare, "k") for c in conds}


def _plots(metrics: pd.DataFrame, extra: dict[str, Any], conds: list[str]) -> dict[str, str]:
    matplotlib.use("Agg")
    colours = _colours(conds)
    out = {}
    fig, ax = plt.subplots(figsize=(6, 3.2))
    for cond in conds:
        chunks = extra["ttc"].get(cond, [])
        x = np.concatenate(chunks) if chunks else np.zeros(0)
        if len(x):
            ax.hist(x, bins=np.linspace(0, TTC_CAP_S, 41).tolist(), alpha=0.55, density=True,
                    label=f"{cond} ({len(x)} samples)", color=colours[cond])
    ax.axvline(TTC_STAR_S, color="k", lw=0.8, ls="--", label=f"TTC* = {TTC_STAR_S:g} s (TET/TIT threshold)")
    ax.text(TTC_STAR_S, 0.98, " TTC*", transform=ax.get_xaxis_transform(), ha="left", va="top", fontsize=8)
    if not any(len(c) for chunks in extra["ttc"].values() for c in chunks):
        ax.text(0.5, 0.5, "no closing samples", transform=ax.transAxes, ha="center", va="center", color="0.5")
    ax.set_xlabel("TTC while closing [s]")
    ax.set_ylabel("density")
    _legend(ax)
    out["ttc"] = _png(fig)

    fig, ax = plt.subplots(figsize=(1.5 + 1.5 * max(len(conds), 2), 3.4))
    done = completed_pairs(metrics)
    wide = done.pivot_table(index="key", columns="condition", values="speed_variance_kmh2", aggfunc="first")
    shown = [c for c in conds if c in wide.columns]
    if len(shown) >= 2:
        for _, r in wide[shown].iterrows():
            ax.plot(range(len(shown)), r.to_numpy(float), color="0.6", marker="o", ms=3, lw=0.8)
        ax.plot(range(len(shown)), wide[shown].mean().to_numpy(float), color="tab:red", marker="o", lw=2.5,
                label="mean")
    _legend(ax)
    ax.set_xticks(range(len(shown)), shown)
    ax.set_ylabel(metric_label("speed_variance_kmh2", tex=True))
    out["variance"] = _png(fig)

    fig, ax = plt.subplots(figsize=(6, 3.2))
    for cond in conds:
        tr = [t for t in extra["traces"] if t["condition"] == cond]
        if tr:
            arr = np.array([t["speed_kmh"] for t in tr])
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # instants no trace reaches
                ax.plot(tr[0]["grid"], np.nanmean(arr, axis=0), color=colours[cond], lw=2,
                        label=f"{cond} ({len(tr)} cut-ins)")
    ax.axvline(0, color="k", lw=0.8, ls="--")
    ax.set_xlabel("time from the cut-in [s]")
    ax.set_ylabel("ego speed change [km/h]")
    _legend(ax)
    out["cut_in_speed"] = _png(fig)
    return out


_TEMPLATE = """<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>dt-highway safety report: {{ name }}</title>
<style>body{font-family:system-ui,sans-serif;max-width:64em;margin:2em auto;padding:0 1em;color:#222}
table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #ccc;padding:.3em .6em;text-align:right}
th{background:#f3f3f3}td:first-child,th:first-child{text-align:left}td+td{white-space:nowrap}img{max-width:100%}
table.prov td{text-align:left;border:none;padding:.1em .8em .1em 0}table.prov td:first-child{color:#555;white-space:nowrap}
.small{color:#666;font-size:.9em}.flag{color:#b00}.warn{background:#fff4d6;border:1px solid #e0b000;padding:.5em .8em}
.excluded{background:#fde8e8;border:1px solid #d88;padding:.5em .8em}</style></head><body>
<h1>Safety metrics: {{ name }}</h1>
<table class="prov">{% for k, v in prov_rows %}<tr><td>{{ k }}</td><td>{{ v }}</td></tr>{% endfor %}</table>
{% if small %}<p class="warn"><b>Small sample:</b> {% for comp in small %}{{ comp.b }} &minus; {{ comp.a }} has {{ comp.n_pairs }} pair{{ "" if comp.n_pairs == 1 else "s" }}{% if not loop.last %}, {% endif %}{% endfor %}; below {{ min_pairs }} pairs the p-values and confidence intervals say little.</p>{% endif %}
{% if summary.excluded %}<div class="excluded"><b>{{ summary.excluded|length }} trial{{ "" if summary.excluded|length == 1 else "s" }} excluded</b> (not in any table, test or plot):
<ul>{% for e in summary.excluded %}<li>{{ e.trial }}: {{ e.reason }}</li>{% endfor %}</ul></div>{% endif %}
{% if summary.aborted_trials %}<div class="small"><b>{{ summary.aborted_trials|length }} aborted attempt{{ "" if summary.aborted_trials|length == 1 else "s" }}</b> (kept in trials/, not in any table, test or plot):
<ul>{% for a in summary.aborted_trials %}<li>{{ a.trial }}: {{ a.end_reason }}{% if a.retried_in %}; driven again in {{ a.retried_in }}{% endif %}</li>{% endfor %}</ul></div>{% endif %}
{% if summary.cut_short_trials %}<p class="flag">{{ summary.cut_short_trials|length }} of the {{ n_used }} trials cut short by a collision (listed below the table).</p>{% endif %}
<h2>Per condition</h2>
<table><tr><th>metric [unit]</th>{% for c in conds %}<th>{{ c }}: mean &plusmn; SD [95% CI] (n)</th>{% endfor %}<th>paper (baseline &rarr; ADAS)</th></tr>
{% for m in metrics %}<tr><td title="{{ m }}: {{ definitions[m] }}">{{ label(m) }}</td>
{% for c in conds %}{% set d = summary.conditions[c][m] %}<td>{{ fmt(d.mean) }} &plusmn; {{ fmt(d.sd) }} [{{ fmt(d.ci95[0]) }}, {{ fmt(d.ci95[1]) }}]{% if d.ci95_clipped %}*{% endif %} ({{ d.n }})</td>{% endfor %}
<td>{% if m in paper %}{{ paper[m].baseline }} &rarr; {{ paper[m].adas }}{% endif %}</td></tr>{% endfor %}
<tr><td title="{{ definitions['conflicts_2d_per_h'] }}">Conflicts (2-D TTC &lt; {{ conflict }} s), pooled [1/h] (count)</td>{% for c in conds %}<td>{{ fmt(summary.conditions[c].conflicts_2d_per_h_pooled) }} ({{ summary.conditions[c].conflicts_2d }})</td>{% endfor %}<td></td></tr>
<tr><td title="{{ definitions['collisions'] }}">Collisions [count]</td>{% for c in conds %}<td>{{ summary.conditions[c].collisions }}</td>{% endfor %}<td></td></tr>
{% for k in kinds %}<tr><td title="{{ definitions['collision kinds'] }}">&nbsp;&nbsp;{{ k }}</td>{% for c in conds %}<td>{{ summary.conditions[c].collision_kinds.get(k, 0) }}</td>{% endfor %}<td></td></tr>{% endfor %}
<tr><td title="{{ definitions['cut short'] }}">Trials cut short by a collision [count]</td>{% for c in conds %}<td{% if summary.conditions[c].cut_short_trials %} class="flag"{% endif %}>{{ summary.conditions[c].cut_short_trials|length }}</td>{% endfor %}<td></td></tr>
</table>
<p class="small">* a bound of the interval clipped to the range the metric can take (see Notes). Hover a metric for its definition.</p>
{% if summary.cut_short_trials %}<p class="flag">Cut short by a collision (their metrics cover the time they ran; they stay in their pairs):
{% for t in summary.cut_short_trials %}{{ t.trial }} ({{ fmt(t.duration_s) }} of {{ fmt(t.planned_duration_s) }} s, {{ t.collision }}){% if not loop.last %}, {% endif %}{% endfor %}.</p>{% endif %}
<h2>Paired tests</h2>
<p class="small">Pairs: trials with the same seed (and participant). d<sub>z</sub> = mean of the paired differences / their SD. p-values two-sided, to 3 decimals, not corrected for multiple comparisons.</p>
{% for comp in summary.comparisons %}<h3>{{ comp.b }} &minus; {{ comp.a }}</h3>
<p>{{ comp.n_pairs }} pairs (same seed){% if comp.cut_short_pairs %}; <span class="flag">{{ comp.cut_short_pairs|length }} hold a trial cut short by a collision</span>{% endif %}.</p>
{% if comp.small_sample %}<p class="warn">Small sample: {{ comp.n_pairs }} pair{{ "" if comp.n_pairs == 1 else "s" }} (fewer than {{ min_pairs }}).</p>{% endif %}
<table><tr><th>metric [unit]</th><th>pairs</th><th>mean difference ({{ comp.b }} &minus; {{ comp.a }})</th><th>Wilcoxon p</th><th>paired t p</th><th title="{{ notes['d_z'] }}">d<sub>z</sub></th></tr>
{% for m, t in comp.tests.items() %}<tr><td title="{{ m }}: {{ definitions[m] }}">{{ label(m) }}</td><td>{{ t.n_pairs }}</td><td>{{ fmt(t.mean_diff) }}</td><td>{{ pfmt(t.wilcoxon_p) }}</td><td>{{ pfmt(t.ttest_p) }}</td><td>{{ fmt(t.effect_size_dz) }}</td></tr>{% endfor %}
</table>{% else %}<p>No two conditions to compare.</p>{% endfor %}
{% if questionnaires %}<h2>Questionnaires</h2>
<p class="small">Answered by the participant after each trial (questionnaires.json in the trial's directory); practice and excluded trials left out. Pairs and tests as above; * a bound clipped to the score's range.</p>
<table><tr><th>questionnaire: score</th>{% for c in questionnaires.condition_order %}<th>{{ c }}: mean &plusmn; SD [95% CI] (n)</th>{% endfor %}</tr>
{% for q, info in questionnaires.questionnaires.items() %}<tr><td title="{{ q }}: {{ info.citation }}">{{ info.title }}: {{ info.label }}</td>
{% for c in questionnaires.condition_order %}{% set d = questionnaires.conditions[c][q] %}<td>{% if d.n %}{{ fmt(d.mean) }} &plusmn; {{ fmt(d.sd) }} [{{ fmt(d.ci95[0]) }}, {{ fmt(d.ci95[1]) }}]{% if d.ci95_clipped %}*{% endif %} ({{ d.n }}){% else %}not asked{% endif %}</td>{% endfor %}</tr>{% endfor %}
</table>
{% for comp in questionnaires.comparisons %}<h3>Questionnaires: {{ comp.b }} &minus; {{ comp.a }}</h3>
<table><tr><th>score</th><th>pairs</th><th>mean difference ({{ comp.b }} &minus; {{ comp.a }})</th><th>Wilcoxon p</th><th>paired t p</th><th title="{{ notes['d_z'] }}">d<sub>z</sub></th></tr>
{% for q, t in comp.tests.items() %}<tr><td>{{ questionnaires.questionnaires[q].label }}</td><td>{{ t.n_pairs }}</td><td>{{ fmt(t.mean_diff) }}</td><td>{{ pfmt(t.wilcoxon_p) }}</td><td>{{ pfmt(t.ttest_p) }}</td><td>{{ fmt(t.effect_size_dz) }}</td></tr>{% endfor %}
</table>{% endfor %}{% endif %}
<h2>Plots</h2>
<h3>TTC distribution</h3><img alt="TTC distribution per condition, with the TTC* threshold" src="data:image/png;base64,{{ plots.ttc }}">
<h3>Speed variance, paired by trial</h3><img alt="paired speed variance" src="data:image/png;base64,{{ plots.variance }}">
<h3>Speed around cut-ins</h3><img alt="speed traces around cut-ins" src="data:image/png;base64,{{ plots.cut_in_speed }}">
<h2>How the overlay performed</h2>
<p>A cut-in's vehicle counts as marked in time when the overlay showed it at some moment of the {{ window }} s before it cut in; warned in time, when it was shown {{ warned_window }} s before (the overlay's metric below).</p>
<table><tr><th>condition</th><th>cut-ins</th><th>marked in time</th><th>cut-ins by aggressive drivers (true type)</th><th>of those, marked in time</th><th title="the traffic's near-miss cut-ins (maneuver = dangerous): from just ahead in the next lane, braking">near-miss cut-ins</th><th title="{{ definitions['cut_ins_warned_share'] }}">of those, warned in time</th></tr>
{% for c in conds %}{% set e = summary.conditions[c] %}<tr><td>{{ c }}</td><td>{{ e.cut_ins }}</td><td>{{ e.cut_ins_marked_in_time }}{{ pct(e.cut_ins_marked_in_time, e.cut_ins) }}</td>
<td>{{ e.cut_ins_by_aggressive }}</td><td>{{ e.cut_ins_by_aggressive_marked_in_time }}{{ pct(e.cut_ins_by_aggressive_marked_in_time, e.cut_ins_by_aggressive) }}</td>
<td>{{ e.get("cut_ins_near_miss", "–") }}</td><td>{{ e.get("cut_ins_near_miss_warned", "–") }}{{ pct(e.get("cut_ins_near_miss_warned", 0), e.get("cut_ins_near_miss", 0)) }}</td></tr>{% endfor %}
</table>
{% if overlay_metrics %}<table><tr><th>metric per trial [unit]</th>{% for c in conds %}<th>{{ c }}: mean &plusmn; SD (n)</th>{% endfor %}</tr>
{% for m in overlay_metrics %}<tr><td title="{{ m }}: {{ definitions[m] }}">{{ label(m) }}</td>{% for c in conds %}{% set d = summary.conditions[c][m] %}<td>{{ fmt(d.mean) }} &plusmn; {{ fmt(d.sd) }} ({{ d.n }})</td>{% endfor %}</tr>{% endfor %}
<tr><td title="{{ definitions['cut_ins_warned_share'] }}">Cut-ins warned in time, pooled [count]</td>{% for c in conds %}{% set e = summary.conditions[c] %}<td>{{ e.get("cut_ins_warned", "–") }}{{ pct(e.get("cut_ins_warned", 0), e.cut_ins) }}</td>{% endfor %}</tr>
</table>{% endif %}
<h2>Notes</h2><ul>{% for k, v in notes.items() %}<li><b>{{ k }}</b>: {{ v }}</li>{% endfor %}</ul>
<h2>Definitions</h2><ul>{% for k, v in definitions.items() %}<li><b>{{ label(k) }}</b>{% if k in info %} <span class="small">({{ k }})</span>{% endif %}: {{ v }}</li>{% endfor %}</ul>
<p class="small">The paper does not state its units or how it aggregates TTC; the values above follow the definitions listed here.</p>
</body></html>
"""  # noqa: E501 - the HTML template's lines are as long as its rows


QUESTIONNAIRE_PREFIX = "q_"
"""A questionnaire's score is the column ``q_<name>`` of ``metrics.csv``"""


def questionnaire_scores(study_dir: str | Path, metrics: pd.DataFrame) -> tuple[pd.DataFrame, dict[str, dict[str, Any]]]:
    """The trials' questionnaire scores (``questionnaires.json`` in a trial's directory, written
    by :func:`~dt_highway.hmi.questionnaire.run_questionnaires`) as columns ``q_<name>`` of the
    metrics (empty where a trial has none or did not finish that questionnaire).

    :param study_dir: the study directory
    :param metrics: one row per trial (:func:`collect`)
    :return: the metrics with those columns, and per column the questionnaire's ``name``,
        ``title``, ``citation``, ``label`` and score ``range`` (empty when no trial has answers)
    """
    scores: dict[str, list[float]] = {}
    info: dict[str, dict[str, Any]] = {}
    trials = metrics["trial"].astype(str).tolist() if "trial" in metrics else []
    for row, trial in enumerate(trials):
        data = read_results(Path(study_dir) / "trials" / trial)
        quest = data.get("questionnaires") if data else None
        for name, entry in (quest.items() if isinstance(quest, dict) else []):
            result = entry.get("score") if isinstance(entry, dict) else None
            if not isinstance(result, dict) or not isinstance(entry, dict):
                continue  # not finished
            value = finite_number(result.get("score"))
            if value is None:
                continue  # not finished (or not a score)
            col = QUESTIONNAIRE_PREFIX + str(name)
            scores.setdefault(col, [math.nan] * len(trials))[row] = value
            info.setdefault(col, {"name": str(name), "title": str(entry.get("title", name)),
                                  "citation": str(entry.get("citation", "")), "label": str(result.get("label", name)),
                                  "range": _score_range(result.get("range"))})
    out = metrics.copy()
    for col in sorted(scores):
        out[col] = scores[col]
    return out, {c: info[c] for c in sorted(info)}


def _score_range(value: Any) -> list[float]:
    """A questionnaire score's ``[low, high]`` as written, or unbounded when it is not two numbers in order."""
    ok = (isinstance(value, list) and len(value) == 2
          and all(isinstance(v, int | float) and not isinstance(v, bool) for v in value) and value[0] < value[1])
    return [float(value[0]), float(value[1])] if ok else [-math.inf, math.inf]


def questionnaire_summary(metrics: pd.DataFrame, questionnaires: dict[str, dict[str, Any]]) -> dict[str, Any] | None:
    """Per condition, n, mean, SD and 95 % CI of each questionnaire score (:func:`describe`), and
    the paired tests between conditions (:func:`comparisons`, :func:`paired_tests`).

    :param metrics: one row per trial, with the score columns (:func:`questionnaire_scores`)
    :param questionnaires: the score columns' descriptions (:func:`questionnaire_scores`)
    :return: ``questionnaires`` (column -> description), ``condition_order``, ``conditions``
        (condition -> column -> :func:`describe`) and ``comparisons`` (``a``, ``b``, ``tests`` per
        column with pairs); ``None`` when no usable trial has a score
    """
    done = completed_pairs(metrics)
    cols = [c for c in questionnaires if c in done and done[c].notna().any()]
    if not cols:
        return None
    conds = condition_order(done.loc[done[cols].notna().any(axis=1), "condition"].dropna().unique())
    conditions = {}
    for cond in conds:
        g = done[done["condition"].astype(str) == cond]
        conditions[cond] = {c: describe(g[c].to_numpy(float), *questionnaires[c]["range"]) for c in cols}
    comps = []
    for a, b in comparisons(conds):
        tests = paired_tests(metrics, a, b, names=cols)
        if tests:
            comps.append({"a": a, "b": b, "tests": tests})
    return {"questionnaires": {c: questionnaires[c] for c in cols}, "condition_order": conds,
            "conditions": conditions, "comparisons": comps}


def _pfmt(p: float | None) -> str:
    """A p-value in the report's one format: 3 decimals, ``< 0.001`` below that, ``–`` when there is none."""
    if p is None or not math.isfinite(p):
        return "–"
    return "< 0.001" if p < 0.001 else f"{p:.3f}"


def _listed(values: Sequence[Any], unit: str = "") -> str:
    return ", ".join(f"{v:g}{unit}" if isinstance(v, float) else f"{v}{unit}" for v in values) or "–"


def _provenance_rows(prov: dict[str, Any], n_excluded: int) -> list[tuple[str, str]]:
    """The provenance header's lines (label, text)."""
    sets = ["; ".join(f"--set {o}" for o in overrides) for overrides in prov["overrides"]]
    commits = prov["git_commit"]
    trials_commit = _listed(commits["trials"]) if commits["trials"] else "not recorded"
    rows = [
        ("Study", prov["study"]),
        ("Scenario", _listed(prov["scenario"]) + (f" ({' | '.join(sets)})" if sets else "")),
        ("Trial length", f"{_listed(prov['trial_length_s'], ' s')} at {_listed(prov['simulation_frequency_hz'], ' Hz')}"),
        ("Seeds", prov["seeds_text"] or "–"),
        ("Drivers", _listed(prov["drivers"])),
    ]
    if prov["participants"]:
        rows.append(("Participants", _listed(prov["participants"])))
    rows += [
        ("Trials", f"{prov['trials']} used" + (f", {n_excluded} excluded" if n_excluded else "")),
        ("Package", (f"dt-highway {_listed(prov['package_version']['trials'])} (trials), "
                     f"{prov['package_version']['report']} (report)")),
        ("Git commit", f"{trials_commit} (trials), {commits['report'] or 'none: not a git checkout'} (report)"),
        ("Trials run", (f"{prov['trials_started'] or '?'} to {prov['trials_ended'] or '?'} "
                        f"on {_listed(prov['hosts']['trials'])}")),
        ("Report written", f"{prov['report_date']} on {prov['hosts']['report']}"),
    ]
    return rows


def _fmt(x: Any) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "–"
    if isinstance(x, float):
        return f"{x:.3g}" if abs(x) < 0.01 else f"{x:.2f}"
    return str(x)


def write_report(study_dir: str | Path, warn: Warn | None = None) -> dict[str, Path]:
    """Write ``metrics.csv``, ``summary.json`` and ``report.html`` into the study directory.

    :param study_dir: the study directory
    :param warn: takes each warning line, one per excluded trial (default: printed to stderr)
    :return: the files written
    :raises ConfigError: one line naming the file, when there is no study to report (no
        directory, no trials, none usable)
    """
    root = Path(study_dir)
    metrics, extra = collect(root, warn)
    metrics, questionnaires = questionnaire_scores(root, metrics)
    summary = {"provenance": provenance(root, extra["metas"]), **summarise(metrics, extra)}
    quest = questionnaire_summary(metrics, questionnaires) if questionnaires else None
    if quest is not None:
        summary["questionnaires"] = quest
    files = {"metrics": root / "metrics.csv", "summary": root / "summary.json", "html": root / "report.html"}
    metrics.to_csv(files["metrics"], index=False)
    files["summary"].write_text(dump_json(summary) + "\n")
    env = jinja2.Environment(autoescape=True, undefined=jinja2.StrictUndefined)
    conds = list(summary["conditions"])
    kinds = sorted({k for c in conds for k in summary["conditions"][c]["collision_kinds"]})
    html = env.from_string(_TEMPLATE).render(
        name=root.name, prov_rows=_provenance_rows(summary["provenance"], len(summary["excluded"])),
        n_used=len(extra["metas"]), conds=conds,
        metrics=[m for m in SUMMARY_METRICS if all(m in summary["conditions"][c] for c in conds)], summary=summary,
        overlay_metrics=[m for m in OVERLAY_METRICS if conds and all(m in summary["conditions"][c] for c in conds)],
        kinds=kinds, paper=summary["paper"], definitions=DEFINITIONS, notes=NOTES, info=METRIC_INFO,
        small=[c for c in summary["comparisons"] if c["small_sample"]], min_pairs=MIN_PAIRS,
        plots=_plots(metrics, extra, conds), fmt=_fmt, pfmt=_pfmt, label=metric_label, questionnaires=quest,
        window=f"{CUT_IN_WINDOW_S:g}", conflict=f"{CONFLICT_TTC_S:g}",
        warned_window=f"{WARNING_LEAD_S:g} to {WARNING_HORIZON_S + 1:g}",
        pct=lambda k, n: f" ({100 * k / n:.0f} %)" if n else "")
    files["html"].write_text(html, encoding="utf-8")
    return files

"""How the overlay behaved in a trial, from its log: what was marked (``steps.csv``'s
``overlay_ids``, ``;``-separated vehicle ids per sample) against the cut-ins that happened
(the ``cut_in`` events, evaluation ground truth from the simulator).

Definitions (``H`` = ``horizon_s``, 3 s by default, the horizon a warning is meant to cover):

* **mark share** ``overlay_on_share`` [-]: share of the samples with at least one mark shown.
* **marks** and **marks per minute** ``marks_per_min`` [1/min]: mark onsets, a vehicle's id
  appearing in ``overlay_ids`` where it was not in the sample before (a mark shown at the first
  sample counts), per minute of trial (``n dt``).
* **false warnings** and ``false_warnings_per_min`` [1/min]: mark onsets at ``t`` on a vehicle
  that did not cut in in front of the ego (a ``cut_in`` event of that vehicle, at its first
  overlap with the ego's path) within ``[t, t + H + 1 s]``. Onsets later than ``H + 1 s``
  before the last sample cannot be judged and are left out, as is that end of the trial from
  the minutes (NaN when nothing can be judged).
* **warned cut-ins** ``cut_ins_warned`` and their share ``cut_ins_warned_share`` [-]: cut-ins
  whose vehicle was marked at some sample within ``[t_c - H - 1 s, t_c - lead_s]``, ``t_c``
  the cut-in's first overlap with the ego's path (the event's ``t_path_s`` when it has one,
  else its ``t_s``, which is that moment in :mod:`dt_highway.metrics.safety`), ``lead_s``
  1.5 s: warned at least 1.5 s before (NaN share without cut-ins). A mark whose onset was more
  than ``H + 1 s`` before a cut-in of its vehicle is a false warning and may still warn it.
* **marked in time** (the report's first overlay table, :func:`marked_before`): cut-ins whose
  vehicle was marked at some sample within ``[t_0 - W, t_0]``, ``t_0`` the cut-in event's ``t_s``
  (its start) and ``W`` the window after a cut-in the report studies (10 s): any mark of that
  car in the time before it, however late.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import pandas as pd

from dt_highway.metrics.safety import CUT_IN_WINDOW_S

WARNING_HORIZON_S = 3.0
"""H: a mark warns of a cut-in within ``H + 1 s`` [s]"""
WARNING_LEAD_S = 1.5
"""A cut-in is warned when its vehicle was marked at least this long before it [s]"""


def marked_ids(steps: pd.DataFrame) -> list[frozenset[int]]:
    """The vehicles marked at each sample.

    :param steps: the trial's samples with ``overlay_ids`` (``;``-separated ids, empty or NaN: none)
    :return: one set of ids per sample
    """
    out = []
    for cell in steps["overlay_ids"].tolist():
        text = "" if cell is None or (isinstance(cell, float) and math.isnan(cell)) else str(cell)
        out.append(frozenset(int(float(v)) for v in text.split(";") if v.strip()))
    return out


def mark_onsets(t_s: np.ndarray, marks: Sequence[frozenset[int]]) -> list[tuple[float, int]]:
    """Every mark onset: ``(time [s], vehicle id)``, in time order.

    :param t_s: sample times [s]
    :param marks: the marked ids per sample (:func:`marked_ids`)
    :return: the onsets
    """
    onsets: list[tuple[float, int]] = []
    before: frozenset[int] = frozenset()
    for t, now in zip(t_s, marks, strict=True):
        onsets += [(float(t), vid) for vid in sorted(now - before)]
        before = now
    return onsets


def _cut_in_time_s(ev: dict[str, Any]) -> float:
    return float(ev.get("t_path_s", ev["t_s"]))


def warned_cut_ins(t_s: np.ndarray, marks: Sequence[frozenset[int]], cut_ins: Sequence[dict[str, Any]],
                   horizon_s: float = WARNING_HORIZON_S, lead_s: float = WARNING_LEAD_S) -> list[bool]:
    """Whether each cut-in was warned: its vehicle marked at some sample within ``[t_c - H - 1 s, t_c - lead_s]``
    (module docstring).

    :param t_s: sample times [s]
    :param marks: the marked ids per sample (:func:`marked_ids`)
    :param cut_ins: the cut-in events (``t_s`` or ``t_path_s``, ``vehicle_id``)
    :param horizon_s: H [s]
    :param lead_s: how early the mark must have been shown [s]
    :return: one flag per cut-in
    """
    out = []
    for ev in cut_ins:
        tc, vid = _cut_in_time_s(ev), int(ev["vehicle_id"])
        before = np.flatnonzero((t_s >= tc - horizon_s - 1.0 - 1e-9) & (t_s <= tc - lead_s + 1e-9))
        out.append(any(vid in marks[int(k)] for k in before))
    return out


def marked_before(t_s: np.ndarray, marks: Sequence[frozenset[int]], cut_ins: Sequence[dict[str, Any]],
                  window_s: float = CUT_IN_WINDOW_S) -> list[bool]:
    """Whether each cut-in's vehicle was marked at some sample within ``[t_0 - window_s, t_0]`` (module docstring).

    :param t_s: sample times [s]
    :param marks: the marked ids per sample (:func:`marked_ids`)
    :param cut_ins: the cut-in events (``t_s``, ``vehicle_id``)
    :param window_s: how long before the cut-in's start a mark counts [s]
    :return: one flag per cut-in
    """
    out = []
    for ev in cut_ins:
        t0, vid = float(ev["t_s"]), int(ev["vehicle_id"])
        out.append(any(vid in marks[int(k)] for k in np.flatnonzero((t_s >= t0 - window_s) & (t_s <= t0))))
    return out


def overlay_metrics(steps: pd.DataFrame, dt_s: float, cut_ins: Sequence[dict[str, Any]],
                    horizon_s: float = WARNING_HORIZON_S, lead_s: float = WARNING_LEAD_S) -> dict[str, Any]:
    """The overlay's metrics of one trial (definitions: module docstring).

    :param steps: the samples, with ``t_s`` and ``overlay_ids``
    :param dt_s: sample period [s]
    :param cut_ins: the trial's cut-in events (``t_s`` or ``t_path_s``, ``vehicle_id``)
    :param horizon_s: H [s]
    :param lead_s: how early a cut-in must have been marked to count as warned [s]
    :return: ``overlay_on_share``, ``marks``, ``marks_per_min``, ``false_warnings``,
        ``false_warnings_per_min``, ``cut_ins_warned``, ``cut_ins_warned_share``
    """
    t = steps["t_s"].to_numpy(float)
    marks = marked_ids(steps)
    n = len(t)
    minutes = n * dt_s / 60.0
    onsets = mark_onsets(t, marks)
    cut_times: dict[int, list[float]] = {}
    for ev in cut_ins:
        cut_times.setdefault(int(ev["vehicle_id"]), []).append(_cut_in_time_s(ev))
    reach = horizon_s + 1.0
    last = float(t[-1]) if n else -math.inf
    judged = [(t_on, vid) for t_on, vid in onsets if t_on + reach <= last + 1e-9]
    false = sum(not any(t_on - 1e-9 <= tc <= t_on + reach + 1e-9 for tc in cut_times.get(vid, ())) for t_on, vid in judged)
    judged_min = int(np.count_nonzero(t + reach <= last + 1e-9)) * dt_s / 60.0
    warned = sum(warned_cut_ins(t, marks, cut_ins, horizon_s, lead_s))
    return {
        "overlay_on_share": float(np.mean([bool(m) for m in marks])) if n else math.nan,
        "marks": len(onsets),
        "marks_per_min": len(onsets) / minutes if minutes > 0 else math.nan,
        "false_warnings": int(false),
        "false_warnings_per_min": false / judged_min if judged_min > 0 else math.nan,
        "cut_ins_warned": int(warned),
        "cut_ins_warned_share": warned / len(cut_ins) if cut_ins else math.nan,
    }

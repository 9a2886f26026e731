"""The overlay's per-trial metrics on a hand-made steps table."""

import math

import numpy as np
import pandas as pd
import pytest

from dt_highway.metrics.overlay_metrics import mark_onsets, marked_ids, overlay_metrics, warned_cut_ins

DT = 0.5
T = np.arange(1, 61) * DT  # 0.5 .. 30 s: 60 samples, one minute is 120


def table(marks: dict[int, list[tuple[float, float]]]) -> pd.DataFrame:
    """Steps whose ``overlay_ids`` mark each vehicle over the given closed intervals [s]."""
    ids = []
    for t in T:
        on = sorted(v for v, spans in marks.items() if any(a - 1e-9 <= t <= b + 1e-9 for a, b in spans))
        ids.append(";".join(str(v) for v in on) if on else np.nan)  # an empty cell reads back as NaN
    return pd.DataFrame({"t_s": T, "overlay_ids": ids})


MARKS = {
    5: [(3.0, 6.0)],  # cuts in at 5.0 (its first overlap with the path; the event's t_s says 4.0): warned, true
    7: [(10.0, 12.0)],  # never cuts in: false
    8: [(14.0, 14.0), (15.0, 16.0)],  # two onsets; it cuts in at 21.0, more than H + 1 = 4 s after either: false
    3: [(27.0, 30.0)],  # onset 3 s before the end: not judged
}
CUT_INS = [{"t_s": 4.0, "t_path_s": 5.0, "vehicle_id": 5}, {"t_s": 21.0, "vehicle_id": 8}, {"t_s": 25.0, "vehicle_id": 9}]


def test_onsets_by_hand():
    steps = table(MARKS)
    assert mark_onsets(T, marked_ids(steps)) == [(3.0, 5), (10.0, 7), (14.0, 8), (15.0, 8), (27.0, 3)]


def test_overlay_metrics_by_hand():
    m = overlay_metrics(table(MARKS), DT, CUT_INS)
    assert m["overlay_on_share"] == pytest.approx((7 + 5 + 1 + 3 + 7) / 60)
    assert m["marks"] == 5 and m["marks_per_min"] == pytest.approx(5 / 0.5)
    # judged: onsets at t <= 30 - 4 = 26 s, over the 52 samples up to 26 s (26 s of trial)
    assert m["false_warnings"] == 3 and m["false_warnings_per_min"] == pytest.approx(3 / (26.0 / 60))
    assert m["cut_ins_warned"] == 1 and m["cut_ins_warned_share"] == pytest.approx(1 / 3)


def test_the_warning_must_come_early_enough():
    late = {5: [(4.0, 6.0)]}  # first marked 1.0 s before the cut-in at 5.0: less than 1.5 s
    m = overlay_metrics(table(late), DT, [{"t_s": 5.0, "vehicle_id": 5}])
    assert m["cut_ins_warned"] == 0 and m["false_warnings"] == 0  # yet a true warning: the cut-in followed
    early = {5: [(0.5, 0.5)]}  # 4.5 s before: outside [t - H - 1, t - 1.5]
    m = overlay_metrics(table(early), DT, [{"t_s": 5.0, "vehicle_id": 5}])
    assert m["cut_ins_warned"] == 0 and m["false_warnings"] == 1
    m = overlay_metrics(table(early), DT, [{"t_s": 5.0, "vehicle_id": 5}], horizon_s=4.0)  # H = 4 s reaches it
    assert m["cut_ins_warned"] == 1 and m["false_warnings"] == 0


def test_nothing_shown():
    m = overlay_metrics(table({}), DT, [])
    assert m["overlay_on_share"] == 0.0 and m["marks"] == 0 and m["false_warnings_per_min"] == 0.0
    assert math.isnan(m["cut_ins_warned_share"])


def test_each_cut_in_is_flagged_and_the_report_counts_the_near_misses():
    from dt_highway.report import _plot_data

    steps = table(MARKS)
    assert warned_cut_ins(T, marked_ids(steps), CUT_INS) == [True, False, False]

    class Trial:  # what the report reads of a trial
        meta = {"condition": "adas-threat"}
        cut_ins = [{**CUT_INS[0], "maneuver": "dangerous", "driver_type": "aggressive"},
                   {**CUT_INS[1], "maneuver": "dangerous", "driver_type": "aggressive"},
                   {**CUT_INS[2], "maneuver": "", "driver_type": "normal"}]

    Trial.steps = steps.assign(ttc_s=10.0, closing_mps=0.0, speed_mps=25.0)
    extra: dict = {"ttc": {}, "traces": [], "cut_ins": []}
    _plot_data(Trial(), extra)
    assert [(c["near_miss"], c["warned"]) for c in extra["cut_ins"]] == [(True, True), (True, False), (False, False)]

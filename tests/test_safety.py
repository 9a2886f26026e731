"""Safety metrics with hand-computed values, the per-step monitor, and crash-safe trial logs."""

import math
import os
import signal
import subprocess
import sys
import time
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from dt_highway.metrics.safety import SafetyMonitor, cut_in_outcomes, drac, time_exposed, time_to_collision, trial_metrics
from dt_highway.metrics.trial_log import TrialWriter, load_trial


def test_ttc_and_drac_by_hand():
    assert time_to_collision(25.0, 10.0) == pytest.approx(2.5)
    assert drac(25.0, 10.0) == pytest.approx(2.0)
    assert time_to_collision(25.0, -3.0) == math.inf  # opening gap
    assert time_to_collision(25.0, 0.0) == math.inf
    assert drac(25.0, -3.0) == 0.0
    assert math.isnan(time_to_collision(-1.0, 5.0))  # already overlapping: a contact, not a TTC of 0
    assert math.isnan(time_to_collision(0.0, -5.0)) and math.isnan(drac(-0.5, 5.0))  # opening or closing alike


def test_tet_and_tit_on_a_small_series():
    ttc = [math.inf, 4.0, 3.0, 2.0, 1.0, 0.5, math.inf]
    tet, tit = time_exposed(ttc, 0.1, ttc_star_s=3.0)
    assert tet == pytest.approx(0.4)  # 3, 2, 1, 0.5 s are within [0, 3]
    assert tit == pytest.approx((0.0 + 1.0 + 2.0 + 2.5) * 0.1)
    tet, tit = time_exposed([2.0, math.nan, math.nan, 1.0], 0.1)  # contact samples are not exposed
    assert tet == pytest.approx(0.2) and tit == pytest.approx((1.0 + 2.0) * 0.1)


def _steps(speeds, ttc=None, accel=None, lanes=None, leader=None, closing=None, drac_v=None):
    n = len(speeds)
    return pd.DataFrame({
        "t_s": np.arange(n) * 0.5, "speed_mps": speeds, "lane": lanes if lanes is not None else [1] * n,
        "accel_mps2": accel if accel is not None else [0.0] * n,
        "ttc_s": ttc if ttc is not None else [math.inf] * n,
        "closing_mps": closing if closing is not None else [0.0] * n,
        "drac_mps2": drac_v if drac_v is not None else [0.0] * n, "headway_s": [2.0] * n, "crashed": [False] * n,
        "leader_id": leader if leader is not None else [-1] * n,
    })


def test_trial_metrics_by_hand():
    m = trial_metrics(_steps([10.0, 20.0, 30.0], ttc=[5.0, 12.0, 2.0], closing=[1.0, 1.0, 1.0],
                             accel=[0.0, -4.0, -4.5], lanes=[0, 1, 1]), dt_s=0.5)
    assert m["speed_mean_kmh"] == pytest.approx(72.0)
    assert m["speed_variance_kmh2"] == pytest.approx(1296.0)  # (36^2 + 0 + 36^2) / (3 - 1)
    assert m["speed_sd_kmh"] == pytest.approx(36.0)
    assert m["ttc_mean_s"] == pytest.approx(3.5)  # 12 s is above the 10 s cap
    assert m["ttc_min_s"] == pytest.approx(2.0)
    assert m["tet_s"] == pytest.approx(0.5) and m["tit_s2"] == pytest.approx(0.5)
    assert m["hard_brakes"] == 1 and m["lane_changes"] == 1 and m["collisions"] == 0
    calm = trial_metrics(_steps([25.0] * 4, ttc=[math.inf, 400.0, 30.0, math.inf], closing=[0.0, 0.1, 1.0, -1.0]), 0.5)
    assert calm["ttc_min_s"] == 10.0 and math.isnan(calm["ttc_mean_s"])  # never below the cap: the cap
    # a contact (NaN) is neither the minimum, nor in the mean, nor exposed; DRAC's maximum skips it
    hit = trial_metrics(_steps([25.0] * 4, ttc=[4.0, 2.0, math.nan, math.nan], closing=[1.0] * 4,
                               drac_v=[0.5, 1.5, math.nan, math.nan]), 0.5)
    assert hit["ttc_min_s"] == 2.0 and hit["ttc_mean_s"] == pytest.approx(3.0) and hit["drac_max_mps2"] == 1.5
    near = trial_metrics(_steps([25.0] * 2, ttc=[1e-12, math.nan], closing=[5.0] * 2, drac_v=[1.25e13, math.nan]), 0.5)
    assert near["drac_max_mps2"] == 10.0  # the last sample before a contact: capped at about 1 g
    assert hit["tet_s"] == pytest.approx(0.5) and hit["tit_s2"] == pytest.approx(0.5) and hit["ttc_contact_s"] == 1.0
    assert hit["duration_s"] == 2.0 and hit["n_samples"] == 4


def test_cut_in_minimum_ttc_and_reaction_time():
    steps = _steps([25.0] * 8, ttc=[math.inf, math.inf, 4.0, 3.0, 2.5, 3.5, 1.0, 1.0],
                   accel=[0, 0, 0, 0, -1.5, -2, 0, 0], leader=[5, 5, 9, 9, 9, 9, 5, 5])
    (out,) = cut_in_outcomes(steps, [{"t_s": 1.0, "vehicle_id": 9}])
    assert out["min_ttc_s"] == pytest.approx(2.5)  # only while vehicle 9 leads
    assert out["reaction_s"] == pytest.approx(1.0)  # braking at t = 2.0 s
    assert math.isnan(out["pet_s"]) and not out["contact"]  # no positions in this log: no PET
    m = trial_metrics(steps, 0.5, [{"t_s": 1.0, "vehicle_id": 9}, {"t_s": 3.0, "vehicle_id": 5}])
    assert m["cut_ins"] == 2 and m["cut_in_ttc_min_s"] == pytest.approx(1.0)
    assert m["cut_in_ttc_mean_s"] == pytest.approx((2.5 + 1.0) / 2)


def _car(x, y, vx, vid=None):
    lane = ("0", "1", int(round(y / 4)))
    return SimpleNamespace(position=np.array([x, y]), velocity=np.array([vx, 0.0]), speed=vx, heading=0.0, LENGTH=5.0,
                           WIDTH=2.0, lane_index=lane, target_lane_index=lane, crashed=False)


def test_monitor_finds_the_leader_and_a_cut_in_from_the_first_overlap_with_the_path():
    mon = SafetyMonitor(lane_width_m=4.0)
    ego = _car(0.0, 4.0, 25.0)
    lead, side = _car(40.0, 4.0, 20.0), _car(20.0, 7.5, 24.0)  # side car: its body reaches 6.5 m, lane ends at 6 m
    s, cuts = mon.sample(0.0, 0.1, ego, 4.0, [lead, side], [1, 2])
    assert s.leader_id == 1 and s.gap_m == pytest.approx(35.0) and s.closing_mps == pytest.approx(5.0)
    assert s.ttc_s == pytest.approx(7.0) and not cuts
    side.position = np.array([20.0, 6.9])  # now 5.9..7.9: in the ego's lane (2..6 m), not yet in its path (3..5 m)
    s, cuts = mon.sample(0.1, 0.1, ego, 4.0, [lead, side], [1, 2])
    assert s.leader_id == 1 and not cuts
    side.position = np.array([20.0, 5.9])  # 4.9..6.9: overlaps the ego's body (3..5 m), leads now
    s, cuts = mon.sample(0.2, 0.1, ego, 4.0, [lead, side], [1, 2])
    assert s.leader_id == 2 and s.gap_m == pytest.approx(15.0)
    assert [(c.vehicle_id, c.t_s, c.t_lane_s, c.gap_m) for c in cuts] == [(2, 0.2, 0.1, pytest.approx(15.0))]
    s, cuts = mon.sample(0.3, 0.1, ego, 4.0, [lead, side], [1, 2])
    assert s.leader_id == 2 and not cuts  # one cut-in per entry


def test_no_cut_in_while_the_ego_changes_lanes_or_from_a_car_already_in_the_lane():
    mon = SafetyMonitor(lane_width_m=4.0)
    ego = _car(0.0, 4.0, 25.0)
    ego.target_lane_index = ("0", "1", 2)  # the ego is changing to the right lane
    side = _car(20.0, 7.5, 24.0)
    mon.sample(0.0, 0.1, ego, 4.0, [side], [2])
    for k, y in enumerate((6.9, 5.9, 5.0), start=1):  # the same entry as above
        side.position = np.array([20.0, y])
        s, cuts = mon.sample(0.1 * k, 0.1, ego, 4.0, [side], [2])
        assert not cuts
    assert s.leader_id == 2
    mon.reset()
    ego.target_lane_index = ego.lane_index
    near = _car(20.0, 6.9, 24.0)  # in the lane band from the first sample on: it did not enter it
    mon.sample(0.0, 0.1, ego, 4.0, [near], [3])
    near.position = np.array([20.0, 5.9])
    s, cuts = mon.sample(0.1, 0.1, ego, 4.0, [near], [3])
    assert s.leader_id == 3 and not cuts


def test_a_torn_last_line_is_dropped(tmp_path):
    with TrialWriter(tmp_path / "t", {"driver": "x"}) as log:
        for k in range(5):
            log.step({"t_s": k * 0.1, "speed_mps": 20.0, "keys": "UP", "overlay_ids": "", "overlay_labels": ""})
        log.event("cut_in", 0.2, vehicle_id=3)
    with open(tmp_path / "t" / "steps.csv", "a") as f:
        f.write("0.5,12")  # a row cut short by a kill
    with open(tmp_path / "t" / "events.jsonl", "a") as f:
        f.write('{"kind": "col')
    trial = load_trial(tmp_path / "t")
    assert len(trial.steps) == 5 and trial.steps["keys"].tolist() == ["UP"] * 5
    assert trial.events == [{"kind": "cut_in", "t_s": 0.2, "vehicle_id": 3}]
    assert trial.meta["status"] == "completed"


_WRITER = """
import sys, time
from dt_highway.metrics.trial_log import TrialWriter
log = TrialWriter(sys.argv[1], {"driver": "test"})
t = 0.0
while True:
    log.step({"t_s": t, "speed_mps": 20.0})
    print(f"{t:.4f}", flush=True)
    t += 1 / 15
    time.sleep(0.002)
"""


def test_a_sigkilled_trial_loses_at_most_a_second_and_reads_as_aborted(tmp_path):
    proc = subprocess.Popen([sys.executable, "-c", _WRITER, str(tmp_path / "k")], stdout=subprocess.PIPE, text=True)
    last = 0.0
    deadline = time.time() + 60
    while last < 5.0 and time.time() < deadline:  # 5 s of simulated time
        last = float(proc.stdout.readline())
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    trial = load_trial(tmp_path / "k")
    assert trial.meta["status"] == "aborted"
    assert last >= 5.0 and trial.steps["t_s"].max() >= last - 1.0

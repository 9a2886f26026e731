"""2-D TTC, the body-overlap leader, collision kinds and PET through the safety monitor and the
trial metrics, on built scenes with hand-computed values."""

import math
from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from dt_highway.metrics.safety import SafetyMonitor, cut_in_outcomes, pet_along_path, trial_metrics
from dt_highway.metrics.ttc2d import Footprint, post_encroachment_time

DT = 1 / 15


def car(x, y, vx, vy=0.0, heading=0.0, lane=None, target=None, crashed=False):
    """A 5 x 2 m vehicle; lane from y (4 m lanes, lane k centred at 4 k), target = lane unless given."""
    lane = ("0", "1", int(round(y / 4))) if lane is None else ("0", "1", lane)
    return SimpleNamespace(position=np.array([x, y], float), velocity=np.array([vx, vy], float), speed=math.hypot(vx, vy),
                           heading=heading, LENGTH=5.0, WIDTH=2.0, lane_index=lane,
                           target_lane_index=lane if target is None else ("0", "1", target), crashed=crashed)


def one(ego, others, lane_y=4.0):
    mon = SafetyMonitor()
    s, _ = mon.sample(0.0, DT, ego, lane_y, others, list(range(1, len(others) + 1)))
    return s


# ---------------------------------------------------------------------------------- 2-D TTC
def test_a_lane_change_into_a_slower_car_has_a_2d_ttc_the_1d_leader_misses():
    # ego x -2.5..2.5, y 3..5, sliding left at 1 m/s; the slower car x 15..20, y -1..1.
    # along x: |17.5 - 5 t| <= 5 for t in [2.5, 4.5]; across: |-4 + t| <= 2 for t in [2, 6] -> 2.5 s
    ego = car(0.0, 4.0, 25.0, vy=-1.0, target=0)
    s = one(ego, [car(17.5, 0.0, 20.0)])
    assert s.ttc2d_s == pytest.approx(2.5) and s.ttc2d_id == 1 and not s.ttc2d_contact
    assert s.leader_id == -1 and s.ttc_s == math.inf  # not in the ego's path yet


def test_parallel_cars_never_touch():
    ego = car(0.0, 4.0, 25.0)
    s = one(ego, [car(3.0, 0.0, 20.0), car(-10.0, 8.0, 30.0), car(30.0, 4.0, 30.0)])  # beside, beside, ahead and faster
    assert s.ttc2d_s == math.inf and s.ttc2d_id == -1 and not s.ttc2d_contact
    assert s.leader_id == 3 and s.ttc_s == math.inf


def test_far_vehicles_are_left_out_of_the_2d_ttc():
    ego = car(0.0, 4.0, 25.0)
    s = one(ego, [car(150.0, 4.0, 0.0)])  # standing still 150 m ahead: 1-D TTC 145 / 25 = 5.8 s
    assert s.ttc_s == pytest.approx(5.8) and s.ttc2d_s == math.inf


def test_an_overlap_is_a_collision_state_in_both_measures():
    ego = car(0.0, 4.0, 25.0)
    s = one(ego, [car(3.0, 4.5, 20.0), car(30.0, 4.0, 20.0)])
    assert s.ttc2d_contact and math.isnan(s.ttc2d_s) and s.ttc2d_id == 1
    assert s.ttc_contact and s.leader_id == 1 and s.gap_m == pytest.approx(-2.0)
    assert math.isnan(s.ttc_s) and math.isnan(s.drac_mps2)
    clear = one(ego, [car(30.0, 4.0, 20.0)])  # the same road without it: 25 m at 5 m/s
    assert clear.ttc2d_s == pytest.approx(5.0) and clear.ttc_s == pytest.approx(5.0)
    assert not clear.ttc_contact and not clear.ttc2d_contact


def test_the_leader_is_the_car_across_the_egos_body_not_the_one_in_its_lane():
    # The ego changes left: lane index still 1 (centre 4 m), body at 1.4..3.4 m. Car A, in lane 0 and
    # turned 0.1 rad, reaches 0.4 + 2.5 sin 0.1 + cos 0.1 = 1.645 m: across the ego's body, 5 m ahead;
    # car B in the ego's lane, 47 m ahead. The lane-band rule picked B.
    h = 0.1
    ext_long = 2.5 * math.cos(h) + 1.0 * math.sin(h)
    ego = car(0.0, 2.4, 25.0, vy=-0.8, lane=1, target=0)
    a = car(5.0 + ext_long + 2.5, 0.4, 24.0, heading=h, lane=0)
    b = car(47.0 + 5.0, 4.0, 22.0, lane=1)
    s = one(ego, [a, b])
    assert s.leader_id == 1 and s.gap_m == pytest.approx(5.0) and s.closing_mps == pytest.approx(1.0)
    assert s.ttc_s == pytest.approx(5.0)
    a.heading = 0.0  # not turned: 0.4 + 1 = 1.4 m, just short of the ego's body
    s = one(ego, [a, b])
    assert s.leader_id == 2 and s.gap_m == pytest.approx(47.0)


def test_2d_ttc_metrics_and_conflicts_by_hand():
    n = 8
    steps = pd.DataFrame({
        "t_s": np.arange(1, n + 1) * 0.5, "speed_mps": [20.0] * n, "lane": [1] * n, "accel_mps2": [0.0] * n,
        "ttc_s": [math.inf] * n, "closing_mps": [0.0] * n, "drac_mps2": [0.0] * n, "headway_s": [math.inf] * n,
        "crashed": [False] * n, "leader_id": [-1] * n,
        "ttc2d_s": [math.inf, 2.0, 1.0, 1.2, 4.0, 1.4, math.nan, 0.5],
    })
    m = trial_metrics(steps, 0.5)
    assert m["ttc2d_min_s"] == 0.5 and m["ttc2d_contact_s"] == 0.5
    assert m["tet2d_s"] == pytest.approx(5 * 0.5)  # 2.0, 1.0, 1.2, 1.4, 0.5
    assert m["tit2d_s2"] == pytest.approx((1.0 + 2.0 + 1.8 + 1.6 + 2.5) * 0.5)
    assert m["conflicts_2d"] == 2  # 1.0-1.2, then 1.4-contact-0.5: onsets of "below 1.5 s or in contact"
    assert m["conflicts_2d_per_h"] == pytest.approx(2 / (4.0 / 3600))
    assert m["duration_s"] == 4.0


# ------------------------------------------------------------------------------- collisions
def crash(ego, partner, cut_in_first=None):
    """The collision the monitor reports when the ego crashes into ``partner`` (id 7)."""
    mon = SafetyMonitor()
    if cut_in_first is not None:
        for k, (vehicle, ego_y) in enumerate(cut_in_first):
            s, _ = mon.sample(k * DT, DT, car(0.0, ego_y, 25.0), 4.0, [vehicle], [7])
    ego.crashed = True
    s, _ = mon.sample(1.0, DT, ego, 4.0, [partner], [7])
    assert s.crashed and s.collision is not None and s.collision.partner_id == 7
    again, _ = mon.sample(1.0 + DT, DT, ego, 4.0, [partner], [7])
    assert again.collision is None  # only at the onset
    return s.collision


def test_rear_end_by_the_ego_and_from_behind():
    c = crash(car(0.0, 4.0, 25.0), car(4.8, 4.0, 20.0))  # 0.2 m into the slower car ahead
    assert (c.kind, c.striker, c.lane_changer) == ("rear_end", "ego", "none")
    c = crash(car(0.0, 4.0, 20.0), car(-4.8, 4.0, 28.0))  # the faster car behind ran into the ego
    assert (c.kind, c.striker, c.lane_changer) == ("rear_end", "partner", "none")


def test_side_swipes_and_whose_lane_change():
    # side by side, 0.05 m across: the partner moving over at 1 m/s, its target the ego's lane
    c = crash(car(0.0, 4.0, 25.0), car(1.0, 2.05, 25.0, vy=1.0, lane=0, target=1))
    assert (c.kind, c.striker, c.lane_changer) == ("side_swipe", None, "partner")
    c = crash(car(0.0, 4.0, 25.0, vy=-1.0, target=0), car(1.0, 2.05, 25.0, lane=0))  # the ego moved over
    assert (c.kind, c.lane_changer) == ("side_swipe", "ego")
    c = crash(car(0.0, 4.0, 25.0, vy=-0.5), car(1.0, 2.05, 25.0, vy=0.5, lane=0))  # both, by lateral speed alone
    assert (c.kind, c.lane_changer) == ("side_swipe", "both")


def test_a_crash_into_a_car_that_just_cut_in_is_a_cut_in():
    # the car enters the ego's lane (6.5 m: body 5.5..7.5, lane band 2..6), then its path (5.9), then is hit
    steps = [(car(20.0, 7.5, 20.0), 4.0), (car(20.0, 6.5, 20.0, vy=-1.0), 4.0), (car(20.0, 5.9, 20.0, vy=-1.0), 4.0)]
    c = crash(car(0.0, 4.0, 25.0), car(4.8, 4.0, 20.0), cut_in_first=steps)
    assert (c.kind, c.striker) == ("cut_in", "ego")
    c = crash(car(0.0, 4.0, 25.0), car(4.8, 4.0, 20.0))  # the same crash without the cut-in
    assert c.kind == "rear_end"


def test_collision_metrics_and_cut_short():
    n = 6
    steps = pd.DataFrame({
        "t_s": np.arange(1, n + 1) * 0.5, "speed_mps": [20.0] * n, "lane": [1] * n, "accel_mps2": [0.0] * n,
        "ttc_s": [math.inf] * n, "closing_mps": [0.0] * n, "drac_mps2": [0.0] * n, "headway_s": [math.inf] * n,
        "crashed": [False] * 5 + [True], "leader_id": [-1] * n,
    })
    event = {"kind": "collision", "collision_kind": "side_swipe", "partner_id": 12, "partner_type": "aggressive",
             "lane_changer": "partner", "striker": None}
    m = trial_metrics(steps, 0.5, collisions=[event], planned_duration_s=120.0)
    assert m["collisions"] == 1 and m["cut_short"] and m["collision_kind"] == "side_swipe"
    assert (m["collision_partner_id"], m["collision_partner_type"], m["collision_lane_changer"]) == (
        12, "aggressive", "partner")
    assert not trial_metrics(steps, 0.5, collisions=[event], planned_duration_s=3.0)["cut_short"]  # ran its length
    old_log = trial_metrics(steps, 0.5, collisions=[{"kind": "collision", "leader_id": 3}])  # before the kinds
    assert old_log["collision_kind"] == "unknown" and old_log["collision_partner_id"] == -1 and old_log["cut_short"]
    env_samples = steps.assign(collision=[None] * 5 + [{"kind": "rear_end", "partner_id": 4, "striker": "ego"}])
    assert trial_metrics(env_samples, 0.5)["collision_kind"] == "rear_end"  # straight from the env: no events
    calm = trial_metrics(steps.assign(crashed=False), 0.5, collisions=[], planned_duration_s=120.0)
    assert not calm["cut_short"] and calm["collision_kind"] == "" and calm["collision_partner_id"] == -1


# -------------------------------------------------------------------------------------- PET
# The cutting car's rear at 14 + 20 t; the ego's front at 25 t until t = 2 s, then slower (15 m/s):
# PET(x) = x / 25 - (x - 14) / 20 = 0.7 - 0.01 x for x <= 50 (ego front at 50 m at t = 2 s), then
# rising: the smallest is 0.2 s, at x = 50 m.
T = np.arange(5.0)
REAR = 14.0 + 20.0 * T
FRONT = np.array([0.0, 25.0, 50.0, 65.0, 80.0])


def test_pet_along_the_path_by_hand():
    assert pet_along_path(T, REAR, T, FRONT) == pytest.approx(0.2)
    assert pet_along_path(T, REAR, T, FRONT * 0.1) == math.inf  # the ego never reaches the car's first spot
    assert pet_along_path(T, REAR, T, FRONT + 20.0) == 0.0  # the ego's front passes the car's rear: overlap


def test_pet_along_the_path_agrees_with_the_2d_helper():
    t = np.linspace(0.0, 4.0, 41)
    front = np.interp(t, T, FRONT)
    rear = 14.0 + 20.0 * t
    ego = [Footprint(f - 2.5, 0.0, 5.0, 2.0, 0.0) for f in front]
    other = [Footprint(r + 2.5, 0.0, 5.0, 2.0, 0.0) for r in rear]
    pet_2d = post_encroachment_time(t, ego, other, cell_m=0.25)
    assert pet_along_path(t, rear, t, front) == pytest.approx(0.2)
    assert pet_2d == pytest.approx(0.2, abs=0.25 * (1 / 15 + 1 / 20) + 1e-9)


def test_cut_in_pet_from_the_trial_log():
    # the log holds the ego's centre (front - 2.5 m: the same shift on both tracks) and the gap
    steps = pd.DataFrame({
        "t_s": T, "x_m": FRONT - 2.5, "gap_m": REAR - FRONT, "leader_id": [9] * 5, "ttc_s": [2.8, 1.8, 0.8, 1.8, 2.8],
        "accel_mps2": [0.0, 0.0, -10.0, 0.0, 0.0], "speed_mps": [25.0, 25.0, 15.0, 15.0, 15.0], "lane": [1] * 5,
        "closing_mps": [5.0] * 5, "drac_mps2": [0.0] * 5, "headway_s": [1.0] * 5, "crashed": [False] * 5,
    })
    (out,) = cut_in_outcomes(steps, [{"t_s": 0.0, "vehicle_id": 9}])
    assert out["pet_s"] == pytest.approx(0.2) and out["min_ttc_s"] == 0.8 and out["reaction_s"] == 2.0
    touched = steps.assign(gap_m=[14.0, 9.0, 0.0, 9.0, 14.0], ttc_s=[2.8, 1.8, math.nan, 1.8, 2.8])
    (out,) = cut_in_outcomes(touched, [{"t_s": 0.0, "vehicle_id": 9}])
    assert out["pet_s"] == 0.0 and out["contact"] and out["min_ttc_s"] == 1.8
    m = trial_metrics(steps, 1.0, [{"t_s": 0.0, "vehicle_id": 9}, {"t_s": 3.0, "vehicle_id": 4}])
    # vehicle 4 never leads: PET inf, capped at 10 s
    assert m["pet_min_s"] == pytest.approx(0.2) and m["pet_median_s"] == pytest.approx((0.2 + 10.0) / 2)


def test_penetration_depth_and_contact_faces_by_hand():
    from dt_highway.metrics.ttc2d import contact_axis, footprint_array, penetration_depth_m

    ego = footprint_array([Footprint(0.0, 0.0, 5.0, 2.0, 0.0, 25.0, 0.0)])
    behind_bumper = footprint_array([Footprint(4.8, 0.0, 5.0, 2.0, 0.0, 20.0, 0.0)])  # 0.2 m into it, closing along x
    beside = footprint_array([Footprint(1.0, -1.95, 5.0, 2.0, 0.0, 25.0, 1.0)])  # 0.05 m across, closing sideways
    apart = footprint_array([Footprint(10.0, 0.0, 5.0, 2.0, 0.0, 20.0, 0.0)])
    assert penetration_depth_m(ego, behind_bumper)[0] == pytest.approx(0.2)
    assert penetration_depth_m(ego, beside)[0] == pytest.approx(0.05)
    assert penetration_depth_m(ego, apart)[0] == pytest.approx(-5.0)
    assert contact_axis(ego, behind_bumper)[0] in (0, 2) and contact_axis(ego, beside)[0] in (1, 3)

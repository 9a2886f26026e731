"""The scripted drivers: IDM by hand, and the human-like driver reacting only to what the overlay shows."""

import copy
import math

import gymnasium as gym
import numpy as np
import pytest

import dt_highway  # noqa: F401  (registers the env)
from dt_highway.drivers import HumanDriver, HumanParams, IDMParams
from dt_highway.drivers.idm import idm_accel
from dt_highway.env.senses import look_around, marked_vehicles


def test_idm_acceleration_by_hand():
    p = IDMParams(desired_speed_mps=30.0, time_headway_s=1.5, min_gap_m=2.0, max_accel_mps2=1.0,
                  comfort_decel_mps2=1.0, delta=4.0)
    assert idm_accel(0.0, math.inf, 0.0, p) == pytest.approx(1.0)  # standing, free road: a
    assert idm_accel(30.0, math.inf, 0.0, p) == pytest.approx(0.0)  # at v0: no acceleration
    # v = 20, gap 40, closing 2: s* = 2 + 30 + 20 * 2 / (2 * 1) = 52; a = 1 - (2/3)^4 - (52/40)^2
    assert idm_accel(20.0, 40.0, 2.0, p) == pytest.approx(1.0 - (2 / 3) ** 4 - 1.3 ** 2)


@pytest.fixture(scope="module")
def scene():
    """An env stepped a little, with a vehicle near the ego and visible in its camera."""
    from conftest import SMALL

    cfg = copy.deepcopy(SMALL)
    cfg.update({"camera": {"enabled": True, "width_px": 320, "height_px": 180}, "fusion": {"enabled": True}})
    cfg["highway"]["action"] = {"type": "Driver"}
    env = gym.make("dt-highway-v0", config=cfg)
    u = env.unwrapped
    for seed in range(20):
        env.reset(seed=seed)
        s = look_around(u)
        frame = u.camera_frame()
        near = [vid for vid, (dx, off) in s.x_of.items()
                if (off == 0 and 0 < dx <= 60) and vid in frame.vehicles and frame.vehicles[vid].visible_box is not None]
        others = [vid for vid, t in frame.vehicles.items() if t.visible_box is not None and vid not in near]
        if near and others:
            yield u, frame, near[0], others[0]
            env.close()
            return
    pytest.fail("no seed in 0..19 puts a visible vehicle ahead of the ego within 60 m")


def _overlay_on(box, claimed_id=0):
    return {"adas": {"overlay": [{"vehicle_id": claimed_id, "box": [float(b) for b in box], "label": "AGGRESSIVE DRIVER",
                                  "confidence": 0.9, "distance_m": 20.0, "rule": "sudden_lane_change"}]}}


def test_the_driver_sees_the_marker_on_the_car_it_covers_not_the_id_the_fusion_claims(scene):
    env, frame, near, other = scene
    on_near = _overlay_on(frame.vehicles[near].visible_box, claimed_id=other)
    assert marked_vehicles(env, on_near) == {near}  # the fusion's id is not what a person sees
    assert marked_vehicles(env, _overlay_on(frame.vehicles[other].visible_box, claimed_id=near)) == {other}
    assert marked_vehicles(env, _overlay_on([0.0, 0.0, 2.0, 2.0])) == set()  # a marker on no car
    assert marked_vehicles(env, {"adas": {"overlay": []}}) == set() and marked_vehicles(env, {}) == set()


def test_the_human_driver_eases_off_only_when_the_overlay_marks_a_car_near_it(scene):
    env, frame, near, _ = scene

    def first_action(info):
        driver = HumanDriver("h", HumanParams())
        driver.reset(env, seed=5)
        return driver.act(env, None, info)

    plain = first_action({})
    assert np.array_equal(first_action({"adas": {"overlay": []}}), plain)  # nothing shown: as in baseline
    warned = first_action(_overlay_on(frame.vehicles[near].visible_box))
    assert warned[0] < plain[0]  # a marked car ahead: longer gap, lower desired speed
    far = first_action(_overlay_on([0.0, 0.0, 2.0, 2.0]))
    assert np.array_equal(far, plain)  # a marker on no car warns of nothing

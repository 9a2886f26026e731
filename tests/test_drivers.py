"""The scripted drivers: IDM by hand, and the human-like driver reacting only to what the overlay shows."""

import copy
import math

import gymnasium as gym
import numpy as np
import pytest

import dt_highway  # noqa: F401  (registers the env)
from dt_highway.drivers import HumanDriver, HumanParams, IDMParams
from dt_highway.drivers.idm import idm_accel
from dt_highway.env.seat import DriverSeat
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
        frame = u.camera_truth()
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
        driver.reset(seed=5)
        overlay = (info.get("adas") or {}).get("overlay") or []
        return driver.act(DriverSeat(env, driver.senses).perceive(overlay))

    plain = first_action({})
    assert np.array_equal(first_action({"adas": {"overlay": []}}), plain)  # nothing shown: as in baseline
    warned = first_action(_overlay_on(frame.vehicles[near].visible_box))
    assert warned[0] < plain[0]  # a marked car ahead: longer gap, lower desired speed
    far = first_action(_overlay_on([0.0, 0.0, 2.0, 2.0]))
    assert np.array_equal(far, plain)  # a marker on no car warns of nothing


# ----------------------------------------------------------------------------- driver files
HUMAN_PARAMS = {  # a trial's meta.json driver_params of agents/human.toml, key order included
    "idm": {"desired_speed_mps": 27.0, "time_headway_s": 1.6, "min_gap_m": 2.0, "max_accel_mps2": 0.73,
            "comfort_decel_mps2": 1.67, "delta": 4.0},
    "reaction_time_s": 1.0, "distance_error": 0.1, "inverse_ttc_error_per_s": 0.01, "error_correlation_s": 20.0,
    "politeness": 0.2, "lane_change_threshold_mps2": 0.2, "safe_decel_mps2": 4.0,
    "min_lane_change_interval_s": 10.0, "alert_headway_factor": 1.4, "alert_speed_factor": 0.95,
    "alert_reaction_factor": 0.7, "alert_ahead_m": 60.0, "alert_behind_m": 10.0, "alert_hold_s": 3.0,
    "anticipate_cut_in": True, "alert_ease_off_mps2": 0.5,
}


def test_driver_params_are_the_files_models_with_the_recorded_dict_unchanged():
    import json

    from dt_highway.agent_config import HumanParams as ConfigHumanParams
    from dt_highway.drivers import load_driver

    assert HumanParams is ConfigHumanParams and IDMParams().desired_speed_mps == 30.0
    human = load_driver("agents/human.toml")
    assert json.dumps(human.params()) == json.dumps(HUMAN_PARAMS)  # values, types and key order
    assert json.dumps(load_driver("agents/idm.toml").params()) == json.dumps({"idm": HUMAN_PARAMS["idm"]})
    assert list(load_driver("agents/random.toml").params().items()) == [
        ("accel_min_mps2", -2.0), ("accel_max_mps2", 2.0), ("lane_change_prob", 0.02)]
    from dt_highway.drivers import make_driver

    ints = make_driver({"kind": "human", "reaction_time_s": 1, "idm": {"delta": 4}}).params()
    assert ints["reaction_time_s"] == 1.0 and type(ints["reaction_time_s"]) is float
    partial_idm = make_driver({"kind": "human", "idm": {"time_headway_s": 1.2}}).params()["idm"]
    assert partial_idm["desired_speed_mps"] == 30.0  # a table given takes the IDM defaults, as before
    with pytest.raises(ValueError, match="frozen"):
        human.p.reaction_time_s = 2.0


@pytest.mark.parametrize("tree, must_contain", [
    ({"kind": "human", "reaction_time": 1.0}, "unknown key 'reaction_time' (allowed here: idm, reaction_time_s"),
    ({"kind": "human", "idm": {"v0": 1}}, "unknown key 'idm.v0' (allowed here: desired_speed_mps"),
    ({"kind": "human", "idm": 3}, "idm must be a table of keys (got 3)"),
    ({"kind": "human", "politeness": -0.1}, "politeness = -0.1: must be a finite number >= 0"),
    ({"kind": "human", "politeness": True}, "politeness = True: must be a finite number >= 0"),
    ({"kind": "human", "politeness": float("inf")}, "politeness = inf: must be a finite number >= 0"),
    ({"kind": "human", "anticipate_cut_in": 1}, "anticipate_cut_in = 1: must be true or false"),
    ({"kind": "human", "idm": {"desired_speed_mps": 0}}, "idm.desired_speed_mps = 0.0 is out of range: must be > 0"),
    ({"kind": "idm", "idm": {"desired_speed_mps": 0}}, "idm.desired_speed_mps = 0.0 is out of range: must be > 0"),
    ({"kind": "idm", "reaction_time_s": 1.0}, "unknown key 'reaction_time_s' (allowed here: kind, idm)"),
    ({"kind": "random", "accel_min_mps2": 1, "accel_max_mps2": 0}, "needs accel_min_mps2 < accel_max_mps2"),
    ({"kind": "random", "lane_change_prob": 1.5}, "lane_change_prob = 1.5 is out of range: must be <= 1"),
    ({"kind": "random", "accel_min_mps2": "slow"}, "accel_min_mps2 = 'slow': must be a finite number"),
    ({"kind": "robot"}, "a driver file needs kind = one of 'human', 'idm', 'random' (got 'robot')"),
    ({"reaction_time_s": 1.0}, "a driver file needs kind = one of 'human', 'idm', 'random' (got None)"),
    ({"kind": "rl"}, "this is an RL training config: train it"),
])
def test_driver_file_mistakes_are_one_line_naming_the_key(tree, must_contain):
    from dt_highway.config import ConfigError
    from dt_highway.drivers import make_driver

    with pytest.raises(ConfigError) as info:
        make_driver(tree)
    assert "\n" not in str(info.value) and must_contain in str(info.value), str(info.value)


def test_a_random_driver_takes_its_parameters_model():
    from dt_highway.agent_config import RandomParams
    from dt_highway.drivers import RandomDriver

    d = RandomDriver("r", RandomParams(accel_min_mps2=-1.0, accel_max_mps2=1.0, lane_change_prob=0.0))
    assert (d.accel_min_mps2, d.accel_max_mps2, d.lane_change_prob) == (-1.0, 1.0, 0.0)
    assert RandomDriver("r").params() == RandomParams().model_dump()

"""The safety-aware training reward (dt_highway.rl.rewards): each term by hand, on hand-built
scenes (the safety monitor's samples of set positions and speeds, and a scene set up in the env),
the default being highway-env's reward exactly, and the [reward] table's errors."""

import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from highway_env.vehicle.kinematics import Vehicle

from dt_highway.agent_config import RewardConfig
from dt_highway.config import ConfigError, load_config
from dt_highway.env import DTHighwayEnv
from dt_highway.metrics.safety import SafetyMonitor
from dt_highway.rl.config import parse_train_config
from dt_highway.rl.rewards import (
    TERMS,
    RewardTerms,
    SafetyReward,
    hard_braking_excess,
    jerk_variation,
    speed_progress,
    ttc_exposure,
)

ROOT = Path(__file__).resolve().parents[1]
SHORT = ["highway.duration=8", "twin.preroll_s=5", "highway.vehicles_count=12"]
DT = 1 / 15


# ----------------------------------------------------------------------------- the quantities
def test_ttc_exposure_tet_and_tit_by_hand():
    ttc = np.array([math.inf, 2.0, 3.0, 1.0, math.nan, 4.0])
    contact = np.array([False, False, False, False, True, False])  # the NaN is a contact: TTC 0
    # exposed: 2.0, 3.0 (at the threshold), 1.0, the contact; not inf, not 4.0
    assert ttc_exposure(ttc, contact, DT, 3.0, "tet") == pytest.approx(4 * DT)
    assert ttc_exposure(ttc, contact, DT, 3.0, "tit") == pytest.approx(DT * ((3 - 2) + 0 + (3 - 1) + 3))
    assert ttc_exposure(ttc, contact, DT, 0.5, "tet") == pytest.approx(DT)  # only the contact


def test_braking_jerk_and_speed_quantities_by_hand():
    assert hard_braking_excess(np.array([-2.0, -4.0, -5.5, 1.0]), DT, 3.0) == pytest.approx(DT * (1.0 + 2.5))
    assert jerk_variation(np.array([0.5, -1.0, 2.0]), 0.0) == pytest.approx(0.5 + 1.5 + 3.0)
    assert jerk_variation(np.array([0.5, -1.0, 2.0])) == pytest.approx(1.5 + 3.0)  # no sample before: not counted
    assert speed_progress(np.array([27.0, 24.3, 40.0, 60.0]), DT, 27.0) == pytest.approx(DT * (1 + 0.9 + 14 / 27 + 0))


# ----------------------------------------------------------------------------- scenes of the safety monitor
def car(x, y, v, vy=0.0, crashed=False):
    """A 5 x 2 m vehicle heading along the road; lane from y (4 m lanes, lane k centred at 4 k)."""
    lane = ("0", "1", int(round(y / 4)))
    return SimpleNamespace(position=np.array([x, y], float), velocity=np.array([v, vy], float), speed=math.hypot(v, vy),
                           heading=0.0, LENGTH=5.0, WIDTH=2.0, lane_index=lane, target_lane_index=lane, crashed=crashed)


def samples_of(scenes, lane_y=4.0):
    """The safety monitor's samples of a sequence of (ego, others) scenes, one simulation step apart."""
    mon, out = SafetyMonitor(), []
    for k, (ego, others) in enumerate(scenes):
        s, _ = mon.sample(k * DT, DT, ego, lane_y, others, list(range(1, len(others) + 1)))
        out.append(s.to_dict())
    return out[1:]  # the first primes the monitor, as at reset


def test_the_2d_ttc_term_on_a_car_ahead():
    # ego at 30 m/s, a car 20 m ahead (centre to centre; bumper gap 15 m) at 20 m/s in its lane: TTC 15 / 10 = 1.5 s
    samples = samples_of([(car(0.0, 4.0, 30.0), [car(40.0, 4.0, 20.0)]), (car(0.0, 4.0, 30.0), [car(20.0, 4.0, 20.0)])])
    assert samples[0]["ttc2d_s"] == pytest.approx(1.5)
    for mode, exposure in (("tet", DT), ("tit", DT * (3.0 - 1.5))):
        terms = RewardTerms(RewardConfig.model_validate({"ttc2d": {"weight": 2.0, "mode": mode}}), DT)
        terms.reset(0.0)
        assert terms.step(0.5, samples)["ttc2d"] == pytest.approx(-2.0 * exposure)
    # below the threshold only: with TTC* = 1 s nothing is exposed
    terms = RewardTerms(RewardConfig.model_validate({"ttc2d": {"weight": 2.0, "threshold_s": 1.0}}), DT)
    assert terms.step(0.5, samples)["ttc2d"] == 0.0


COSTS = {"collision": {"cut_in": 11.0, "rear_end": 7.0, "side_swipe": 5.0, "unknown": 3.0}}


def test_collisions_cost_by_their_kind():
    cost = RewardTerms(RewardConfig.model_validate(COSTS), DT)
    ego, crashed = car(0.0, 4.0, 25.0), car(0.0, 4.0, 25.0, crashed=True)
    # rear-end: the ego runs into the car ahead (front and rear faces met)
    rear = samples_of([(ego, [car(6.0, 4.0, 20.0)]), (crashed, [car(4.5, 4.0, 20.0)])])
    assert rear[0]["collision"]["kind"] == "rear_end"
    assert cost.step(0.0, rear)["collision"] == -7.0
    # side-swipe: a car alongside drifts into the ego's side
    side = samples_of([(ego, [car(0.0, 7.0, 25.0, vy=-2.0)]), (crashed, [car(0.0, 5.5, 25.0, vy=-2.0)])])
    assert side[0]["collision"]["kind"] == "side_swipe"
    assert cost.step(0.0, side)["collision"] == -5.0
    # cut-in: a car from the next lane enters the ego's path 12.5 m ahead, then the ego hits it
    cut = samples_of([(ego, [car(17.5, 0.0, 20.0)]), (ego, [car(17.5, 2.5, 20.0)]), (crashed, [car(4.5, 4.0, 20.0)])])
    assert cut[-1]["collision"]["kind"] == "cut_in"
    assert cost.step(0.0, cut)["collision"] == -11.0
    # no crash, no cost; the onset only (a crashed ego's later samples are not new collisions)
    assert cost.step(0.0, samples_of([(ego, [car(40.0, 4.0, 20.0)])] * 3))["collision"] == 0.0


def test_terms_sum_to_the_reward_and_the_default_is_highway_env_s():
    terms = RewardTerms(RewardConfig(), DT)
    terms.reset(0.0)
    samples = samples_of([(car(0.0, 4.0, 30.0), [car(40.0, 4.0, 20.0)]), (car(2.0, 4.0, 30.0), [car(20.0, 4.0, 20.0)])])
    out = terms.step(0.7317, samples)
    assert set(out) == set(TERMS) and out["highway"] == 0.7317 and sum(out.values()) == 0.7317
    assert RewardConfig().is_highway_only() and not RewardConfig(highway=0.5).is_highway_only()


# ----------------------------------------------------------------------------- a scene set up in the env
WEIGHTS = {"highway": 0.5, "ttc2d": {"weight": 1.0, "mode": "tit"}, "progress": {"weight": 0.1},
           "hard_braking": {"weight": 2.0, "threshold_mps2": 3.0}, "jerk": {"weight": 0.25}}


def _scene_env(reward: dict) -> tuple[SafetyReward, float]:
    """The trial highway with one car 20 m (bumper to bumper) ahead of the ego in its lane, 10 m/s
    slower, driving straight at a constant speed; every other car taken off the road."""
    cfg = load_config(str(ROOT / "envs/highway-trial.toml"), SHORT, {"highway": {"action": {"type": "Driver"}}})
    env = SafetyReward(DTHighwayEnv(config=cfg.to_dict()), RewardConfig.model_validate(reward))
    env.reset(seed=3)
    u = env.unwrapped
    ego = u.vehicle
    lane = u.road.network.get_lane(ego.lane_index)
    ego.position[1], ego.heading = float(lane.position(float(ego.position[0]), 0.0)[1]), 0.0
    ahead = Vehicle(u.road, [float(ego.position[0]) + 25.0, float(ego.position[1])], 0.0, float(ego.speed) - 10.0)
    ahead.dt_id = 999
    u.road.vehicles[:] = [ego, ahead]
    env.terms.reset(float(ego.position[0]))
    return env, float(ego.speed)


def test_each_term_by_hand_on_a_scene_in_the_env():
    env, v = _scene_env(WEIGHTS)
    x0 = float(env.unwrapped.vehicle.position[0])
    # step 1: pedals at 0 for 3 simulation steps; TTC after simulation step k: (20 - 10 k dt) / 10 = 2 - k / 15 s
    _, reward, _, _, info = env.step(np.array([0.0, 0.0]))
    t = info["reward_terms"]
    highway_reward = DTHighwayEnv._reward(env.unwrapped, np.array([0.0, 0.0]))
    assert t["highway"] == pytest.approx(0.5 * highway_reward)
    assert t["ttc2d"] == pytest.approx(-DT * sum(3.0 - (2.0 - k / 15) for k in (1, 2, 3)))  # TIT below 3 s
    assert t["progress"] == pytest.approx(0.1 * v * 3 * DT)  # 3 simulation steps at v [m]
    assert float(env.unwrapped.vehicle.position[0]) - x0 == pytest.approx(v * 3 * DT)
    assert t["hard_braking"] == 0.0 and t["jerk"] == 0.0 and t["collision"] == 0.0
    assert reward == pytest.approx(sum(t.values()))
    # step 2: braking at 5 m/s^2, 2 beyond the threshold, for 3 simulation steps; the pedal jumps once, 0 -> -5
    _, reward, _, _, info = env.step(np.array([-5.0, 0.0]))
    t = info["reward_terms"]
    assert t["hard_braking"] == pytest.approx(-2.0 * 3 * DT * 2.0)
    assert t["jerk"] == pytest.approx(-0.25 * 5.0)
    assert t["progress"] == pytest.approx(0.1 * sum(v - 5.0 * k * DT for k in range(3)) * DT)
    assert reward == pytest.approx(sum(t.values()))
    env.close()


def test_the_default_reward_wrapper_changes_nothing():
    cfg = load_config(str(ROOT / "envs/highway-trial.toml"), SHORT, {"highway": {"action": {"type": "Driver"}}})
    plain, wrapped = DTHighwayEnv(config=cfg.to_dict()), SafetyReward(DTHighwayEnv(config=cfg.to_dict()), RewardConfig())
    o1, _ = plain.reset(seed=5)
    o2, _ = wrapped.reset(seed=5)
    rng = np.random.default_rng(0)
    for _ in range(10):
        action = np.array([rng.uniform(-3, 2), 0.0])
        o1, r1, d1, _, _ = plain.step(action)
        o2, r2, d2, _, info = wrapped.step(action)
        assert r1 == r2 and np.array_equal(o1, o2) and d1 == d2  # exactly
        assert info["reward_terms"]["highway"] == r1
    plain.close()
    wrapped.close()


def test_the_reward_table_is_validated_in_one_line():
    ok = parse_train_config({"kind": "rl", "reward": {"collision": {"cut_in": 20}, "ttc2d": {"weight": 1}}})
    assert ok.reward.collision.cut_in == 20.0 and ok.reward.ttc2d.threshold_s == 3.0 and ok.reward.highway == 1.0
    assert parse_train_config({"kind": "rl"}).reward.is_highway_only()
    for bad, key in (({"ttc2d": {"weight": -1}}, "reward.ttc2d.weight"), ({"collision": {"head_on": 1}}, "head_on"),
                     ({"ttc2d": {"mode": "pet"}}, "reward.ttc2d.mode"), ({"speed": 1}, "speed")):
        with pytest.raises(ConfigError) as err:
            parse_train_config({"kind": "rl", "reward": bad})
        assert key in str(err.value) and "\n" not in str(err.value)


def test_training_with_the_safety_reward_logs_its_terms_and_the_policy_drives_with_the_delayed_menu(tmp_path):
    from dt_highway.drivers.policy import load_policy
    from dt_highway.rl.train import train

    cfg = parse_train_config({"kind": "rl", "observation": "kinematics", "action": "assisted-delayed", "set": SHORT,
                              "scenario": str(ROOT / "envs/highway-trial.toml"), "timesteps": 128, "n_envs": 1,
                              "eval_every_steps": 128, "eval_episodes": 1, "checkpoint_every_steps": 128,
                              "hyperparameters": {"n_steps": 64, "batch_size": 32, "n_epochs": 1},
                              "reward": {"collision": {"cut_in": 50.0}, "ttc2d": {"weight": 1.0}, "jerk": {"weight": 0.1}}})
    out = tmp_path / "safe.zip"
    meta = train(cfg, out, progress=False)
    assert meta["train_config"]["reward"]["ttc2d"]["weight"] == 1.0
    header = (out.with_suffix(".d") / "progress.csv").read_text().splitlines()[0].split(",")
    assert {"reward/highway", "reward/ttc2d", "reward/jerk", "reward/collision"} <= set(header)
    driver = load_policy(out)
    driver.reset(0)
    assert driver.menu is not None and driver.menu.assisted is not None
    assert driver.menu.assisted.reaction_time_s == 1.2 and driver.menu.assisted.brake_limit_mps2 == 6.0

"""The dt-highway-v0 env: registration, API checks, determinism, ids, info, memory."""

import copy
import gc
import json
import os
import shutil
import sqlite3
import subprocess
import sys
import time
from contextlib import closing
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import dt_highway  # noqa: F401
from dt_highway.config import ConfigError, load_config
from dt_highway.drivers.policy import load_policy
from dt_highway.env import ENV_ID, DTHighwayEnv
from dt_highway.env.seat import DriverSeat
from dt_highway.world.traffic import AGGRESSIVE, NORMAL

ROOT = Path(__file__).resolve().parent.parent


def _make(cfg, **kw):
    return gym.make("dt-highway-v0", config=cfg, **kw)


def test_registered_and_subclass_of_highway_env(small_config):
    from highway_env.envs.highway_env import HighwayEnv

    env = _make(small_config)
    assert isinstance(env.unwrapped, DTHighwayEnv)
    assert isinstance(env.unwrapped, HighwayEnv)
    env.close()


def test_gymnasium_check_env(small_config):
    from gymnasium.utils.env_checker import check_env

    env = _make(small_config)
    check_env(env.unwrapped, skip_render_check=True)
    env.close()


def test_sb3_check_env(small_config):
    from stable_baselines3.common.env_checker import check_env

    env = _make(small_config)
    check_env(env, warn=True)
    env.close()


def _trace(cfg, seed, steps=6):
    env = _make(cfg)
    obs, info = env.reset(seed=seed)
    out = {"obs": [obs], "pos": [], "twin": [], "tags": []}
    for _ in range(steps):
        obs, r, term, trunc, info = env.step(1)
        u = env.unwrapped
        out["obs"].append(obs)
        out["pos"].append(sorted((v.dt_id, tuple(np.round(v.position, 9))) for v in u.road.vehicles))
        out["twin"].append(info["twin"])
        records = u.twin.tagger.records.items()
        out["tags"].append(sorted((vid, r.tag, r.n_sudden, round(r.confidence, 12)) for vid, r in records))
        if term or trunc:
            break
    env.close()
    return out


def test_same_seed_same_everything(small_config):
    a, b = _trace(small_config, 7), _trace(small_config, 7)
    assert a["pos"] == b["pos"]
    assert a["twin"] == b["twin"]
    assert a["tags"] == b["tags"]
    assert all(np.array_equal(x, y) for x, y in zip(a["obs"], b["obs"], strict=True))
    c = _trace(small_config, 8)
    assert a["pos"] != c["pos"]


def test_ids_are_stable_and_unique(small_config):
    env = _make(small_config)
    env.reset(seed=0)
    u = env.unwrapped
    ids_by_object = {id(v): v.dt_id for v in u.road.vehicles}
    for _ in range(5):
        env.step(1)
        ids = [v.dt_id for v in u.road.vehicles]
        assert len(ids) == len(set(ids))
        for v in u.road.vehicles:
            if id(v) in ids_by_object:
                assert ids_by_object[id(v)] == v.dt_id
    assert u.vehicle.dt_id == 0
    env.close()


def test_info_keeps_ground_truth_apart(small_config):
    env = _make(small_config)
    _, info = env.reset(seed=1)
    _, _, _, _, info = env.step(1)
    assert set(info) >= {"speed", "crashed", "time_s", "ego", "twin", "ground_truth"}
    assert info["twin"], "the twin view should reach the ego after the pre-roll"
    for entry in info["twin"]:
        assert "driver_type" not in entry
        assert entry["tag"] in (AGGRESSIVE, NORMAL)
        assert 0.0 <= entry["confidence"] <= 1.0
        assert entry["age_s"] >= 0.0
    truth = info["ground_truth"]["vehicles"]
    assert {t["driver_type"] for t in truth.values()} <= {AGGRESSIVE, NORMAL}
    env.close()


def test_twin_tag_observation(small_config):
    small_config["twin"]["in_observation"] = True
    env = _make(small_config)
    obs, _ = env.reset(seed=2)
    assert obs.shape == (5, 7)
    assert env.observation_space.contains(obs)
    obs, *_ = env.step(1)
    known, p = obs[1:, 5], obs[1:, 6]
    assert set(np.unique(known)) <= {0.0, 1.0}
    assert known.sum() >= 1  # at least one neighbour associated with the twin's view
    assert np.all((p >= 0) & (p <= 1))
    env.close()


def test_twin_tag_observation_with_the_intention(small_config):
    small_config["twin"]["in_observation"] = True
    small_config["twin"]["in_observation_intent"] = True
    env = _make(small_config)
    env.reset(seed=2)
    u = env.unwrapped
    h = u.dt_config.twin.intention.operating_horizon_s
    seen = 0
    for _ in range(10):
        obs, _, terminated, truncated, _ = env.step(1)
        assert obs.shape == (5, 9) and env.observation_space.contains(obs)
        delivered = np.array([i.p_change for v in u.twin_view.vehicles if (i := v.intent(h)) is not None])
        known, p, dlane = obs[1:, 5], obs[1:, 7], obs[1:, 8]
        assert np.all(p[known == 0] == 0) and set(np.unique(dlane)) <= {-1.0, 0.0, 1.0}
        for q in p[known == 1]:  # each associated car carries one of the delivered probabilities
            assert np.abs(delivered - q).min() < 1e-6
            seen += 1
        if terminated or truncated:
            break
    assert seen >= 5
    assert "in_observation_intent" not in load_config().to_dict()["twin"]  # off: dumps as before
    env.close()


def test_subproc_vec_env_with_module_id(small_config):
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import SubprocVecEnv

    venv = make_vec_env("dt_highway:dt-highway-v0", n_envs=2, seed=0, vec_env_cls=SubprocVecEnv,
                        env_kwargs={"config": small_config})
    obs = venv.reset()
    assert obs.shape == (2, 5, 5)
    obs, rewards, dones, infos = venv.step(np.array([1, 1]))
    assert len(infos) == 2 and "twin" in infos[0]
    venv.close()


def test_population_persists_across_seedless_resets(small_config):
    env = _make(small_config)
    env.reset(seed=3)
    u = env.unwrapped
    pop = u.population
    for _ in range(3):
        env.step(1)
    first = dict(u.twin.tagger.records)
    assert first
    env.reset()  # no seed: the world goes on
    assert u.population is pop
    assert all(u.twin.tagger.records.get(vid) is rec for vid, rec in first.items())
    env.reset(seed=3)  # a seed starts the world over
    assert u.population is not pop
    assert not any(u.twin.tagger.records.get(vid) is rec for vid, rec in first.items())
    env.close()


def test_records_dropped_between_episodes_when_not_persisting(small_config):
    small_config["twin"]["store"] = {"persist_across_episodes": False}
    env = _make(small_config)
    env.reset(seed=3)
    u = env.unwrapped
    for _ in range(3):
        env.step(1)
    first = dict(u.twin.tagger.records)
    env.reset()
    assert not any(u.twin.tagger.records.get(vid) is rec for vid, rec in first.items())
    env.close()


def test_reseeding_the_same_env_repeats_the_episode(small_config):
    env = _make(small_config)
    runs = []
    for _ in range(2):
        env.reset(seed=11)
        trace = []
        for _ in range(4):
            _, _, _, _, info = env.step(1)
            trace.append((sorted(info["ground_truth"]["vehicles"].items()), info["twin"]))
        runs.append(trace)
    assert runs[0] == runs[1]
    env.close()


def test_a_seed_that_is_no_int_is_refused_in_one_line_and_changes_nothing(small_config):
    env = _make(small_config)
    env.reset(seed=11)
    _, _, _, _, info = env.step(1)
    for bad in ("a", 1.5, -1, np.int64(3)):  # 1.5 was seed 1; "a" a ValueError from int()
        with pytest.raises(gym.error.Error) as err:
            env.reset(seed=bad)
        assert "reset(seed=...) must be a Python int >= 0" in str(err.value) and "\n" not in str(err.value)
    for bad in (5, {"bogus": 1}, {"config": {}, "seed": 3}):  # 5 was highway-env's TypeError, then a broken env
        with pytest.raises(gym.error.Error, match=r"^reset\(options=...\) takes None or \{'config': \{...\}\}"):
            env.reset(seed=2, options=bad)
    assert env.unwrapped._world_seed == 11  # the refused resets changed nothing
    env.reset(options={"config": {}})
    env.step(1)
    env.close()


def test_the_constructors_episode_has_no_preroll_and_the_first_reset_does(small_config, monkeypatch):
    # highway-env's constructor resets once; that episode is never driven (gymnasium asks for a reset first),
    # so its pre-roll (seconds with the default world) is skipped; the first reset runs its own in full
    steps = []
    real = DTHighwayEnv._sim_step
    monkeypatch.setattr(DTHighwayEnv, "_sim_step", lambda self: (steps.append(self.sim_time_s), real(self))[1])
    env = _make(small_config)
    assert steps == [] and env.unwrapped.sim_time_s == 0.0
    env.reset(seed=5)
    cfg = env.unwrapped.dt_config
    assert len(steps) == round(cfg.twin.preroll_s * cfg.highway.simulation_frequency) > 0
    assert steps[0] == -cfg.twin.preroll_s and env.unwrapped.sim_time_s == 0.0
    env.close()


def test_a_seeded_episode_with_a_twin_store_is_the_same_on_every_fresh_store(small_config, tmp_path):
    # the constructor's unseeded world once pre-rolled, and its twin's records of those (random) drivers were
    # written to the store at the seeded reset and read back: every run of the same seed differed
    runs, learnt = [], []
    for k in range(2):
        small_config["twin"]["store"] = {"path": str(tmp_path / f"twin{k}.sqlite")}
        env = _make(small_config)
        learnt.append(len(env.unwrapped.twin.tagger.records))
        env.reset(seed=1)
        runs.append([env.step(1)[4]["twin"] for _ in range(10)])
        env.close()
    assert runs[0] == runs[1]
    assert learnt == [0, 0]  # the constructor's episode learnt nothing


def test_a_make_and_close_leaves_a_twin_store_as_it_found_it(small_config, tmp_path):
    # (the study CLI makes and closes an env per condition to check a trained policy: it drove nothing)
    path = tmp_path / "twin.sqlite"
    small_config["twin"]["store"] = {"path": str(path)}
    env = _make(small_config)
    env.reset(seed=1)
    for _ in range(5):
        env.step(1)
    env.close()

    def content():
        with closing(sqlite3.connect(path)) as con:
            tables = [t for (t,) in con.execute("SELECT name FROM sqlite_master WHERE type = 'table'")]
            return {t: sorted(con.execute(f"SELECT * FROM {t}").fetchall()) for t in tables}

    before = content()
    assert before["meta"]
    _make(small_config).close()
    assert content() == before


def test_twin_view_is_measured_not_true(small_config):
    env = _make(small_config)
    env.reset(seed=5)
    _, _, _, _, info = env.step(1)
    truth = info["ground_truth"]["vehicles"]
    u = env.unwrapped
    true_heading = {v.dt_id: float(v.heading) for v in u.road.vehicles}
    diffs = [abs(e["heading_rad"] - true_heading[e["vehicle_id"]]) for e in info["twin"] if e["vehicle_id"] in truth]
    pos = [abs(e["x_m"] - truth[e["vehicle_id"]]["x_m"]) for e in info["twin"] if e["vehicle_id"] in truth]
    assert diffs and min(diffs) > 0.0 and np.median(diffs) < 0.1  # noisy, not exact
    assert np.median(pos) > 0.1  # delayed and noisy positions
    env.close()


def test_partial_observation_config_is_merged(small_config):
    small_config["highway"]["observation"] = {"vehicles_count": 8}
    env = _make(small_config)
    obs, _ = env.reset(seed=0)
    assert obs.shape == (8, 5)
    env.close()


def test_long_run_memory_stays_flat():
    """20 minutes of simulated time: the twin's store, its records, the traffic and the
    number of live Python objects stay bounded (``dt-highway bench memory`` runs hours)."""
    cfg = {
        "highway": {"vehicles_count": 12, "lanes_count": 3, "duration": 4000.0, "simulation_frequency": 5},
        "ego": {"autopilot": True},
        "traffic": {"population_size": 40},
        "twin": {"preroll_s": 0.0, "uplink": {"rate_hz": 5.0}},
    }
    env = DTHighwayEnv(config=cfg)
    env.reset(seed=0)
    objects = {}
    for minute in range(20):
        for _ in range(60):
            env.step(0)
        if minute in (4, 19):
            gc.collect()
            objects[minute] = len(gc.get_objects())
        assert env.twin.store.n_fixes() <= (12 + 1 + 5) * 5.0 * 30.0 * 1.1
        assert len(env.twin.tagger.records) <= 41
        assert len(env.road.vehicles) == 13
        assert env.twin.n_pending() < 13 * 5
    growth = objects[19] - objects[4]
    assert growth < 0.02 * objects[4], f"{growth} more live objects after 15 more minutes"
    env.close()


@pytest.mark.parametrize("bad", ["fast", 3])
def test_bad_render_mode(bad):
    with pytest.raises(ValueError, match="render_mode"):
        DTHighwayEnv(render_mode=bad)



@pytest.mark.parametrize("table, words", [
    ({"type": "OccupancyGrid", "grid_step": [0, 0]},
     "highway-env cannot make type 'OccupancyGrid' with {'grid_step': [0, 0]} (ValueError"),
    ({"type": "OccupancyGrid", "vehicles_count": 15},  # in highway-env's own examples; OccupancyGrid ignores it
     "highway-env's OccupancyGridObservation does not read 'vehicles_count' (its options: absolute"),
    ({"type": "GrayscaleObservation", "observation_shape": [64, 32], "stack_size": 2, "weights": [1.0]},
     "cannot observe with type 'GrayscaleObservation'"),  # made, fails at the first observation
    ({"type": "AttributesObservation", "attributes": ["bogus"]}, "(AttributeError: 'DTHighwayEnv' object has no"),
    ({"type": "MultiAgentObservation", "observation_config": {"type": "Kinematics", "bogus": 1}},
     "highway.observation.observation_config: highway-env's KinematicObservation does not read 'bogus'"),
    ({"type": "TupleObservation", "observation_configs": [{"type": "Kinematics"}, {"type": "ExitObservation"}]},
     "highway.observation.observation_configs[1].type = 'ExitObservation': it needs an exit lane"),
    ({"type": "TimeToCollision", "horizon": "x"}, "type 'TimeToCollision' with {'horizon': 'x'}"),
    ({"type": "LidarObservation", "cells": 0}, "(ZeroDivisionError"),
    ({"type": "GrayscaleObservation"}, "missing 3 required positional arguments"),
    ({"type": "KinematicsGoal"}, "it needs a goal, as on highway-env's parking env"),
    ({"type": "ExitObservation"}, "it needs an exit lane"),
])
def test_highway_env_observation_options_it_cannot_take_are_one_line(table, words):
    # highway-env takes its types' options unchecked: a traceback from inside it, or dropped
    with pytest.raises(ConfigError) as err:
        gym.make("dt_highway:dt-highway-v0", config={"highway": {"observation": table}})
    assert words in str(err.value) and "\n" not in str(err.value), err.value


def test_highway_env_types_with_good_options_are_made():
    for table, shape in (({"type": "GrayscaleObservation", "observation_shape": [64, 32], "stack_size": 2,
                           "weights": [0.3, 0.6, 0.1]}, (2, 64, 32)),  # a TOML list where highway-env wants a tuple
                         ({"type": "OccupancyGrid", "grid_step": [11, 11]}, (4, 5, 5)),
                         ({"type": "LidarObservation", "cells": 8}, (8, 2))):
        env = gym.make("dt_highway:dt-highway-v0", config={"highway": {"observation": table}})
        assert env.observation_space.shape == shape
        env.close()
    for action, words in (({"type": "ContinuousAction", "bogus": 2}, "highway-env's ContinuousAction does not read 'bogus'"),
                          ({"type": "DiscreteAction", "speed_range": [0, 10]},  # DiscreteAction does not hand it on
                           "highway-env's DiscreteAction does not read 'speed_range'"),
                          ({"type": "DiscreteMetaAction", "target_speeds": []},  # an IndexError as the ego was made
                           r"highway.action.target_speeds = \[\]: must be 2 or more speeds >= 0 m/s in increasing"),
                          ({"type": "DiscreteMetaAction", "target_speeds": [25]}, "must be 2 or more speeds"),
                          ({"type": "DiscreteMetaAction", "target_speeds": [30, 20]}, "in increasing order")):
        with pytest.raises(ConfigError, match=words):
            gym.make("dt_highway:dt-highway-v0", config={"highway": {"action": action}})
    grayscale = {"type": "GrayscaleObservation", "observation_shape": [64, 32], "stack_size": 2, "weights": [0.3, 0.6, 0.1]}
    env = gym.make("dt_highway:dt-highway-v0", config={"highway": {"observation": {
        "type": "TupleObservation", "observation_configs": [{"type": "Kinematics"}, grayscale]}, "duration": 1},
        "twin": {"preroll_s": 1}})
    obs, _ = env.reset(seed=0)  # nested lists made tuples too
    assert obs[1].shape == (2, 64, 32)
    env.close()
    for speeds in ((20, 25, 30), np.array([20.0, 30.0]), [np.int64(20), 30], None):  # as highway-env takes them
        env = gym.make("dt_highway:dt-highway-v0", config={"highway": {"action": {
            "type": "DiscreteMetaAction", "target_speeds": speeds}}})
        env.close()
    discrete = {"type": "DiscreteAction", "actions_per_axis": 3}
    env = gym.make("dt_highway:dt-highway-v0", config={"highway": {"action": discrete}})
    assert env.action_space.n == 9
    env.close()


@pytest.mark.parametrize(("observation", "fast_road", "says"), [
    ({"type": "Kinematics", "features": ["presence", "nope"]}, True, "'nope' is not a feature of type 'Kinematics'"),
    ({"type": "OverlayKinematics", "features": ["x", "nope"]}, True, "features: 'nope' is not a feature"),
    ({"type": "Kinematics", "features_range": {"vxx": [0, 1]}}, True, "features_range: 'vxx' is not a feature"),
    ({"type": "Kinematics", "features_range": {"vxx": [0, 1]}}, False, "features_range: 'vxx' is not a feature"),
    ({"type": "Kinematics", "features": ["nope"]}, False, "features: 'nope' is not a feature of type 'Kinematics'"),
    ({"type": "OccupancyGrid", "features": ["presence", "nope"]}, True, "'nope' is not a feature of type 'OccupancyGrid'"),
    ({"type": "OccupancyGrid", "features_range": {"nope": [0, 1]}}, True, "features_range: 'nope'"),
    ({"type": "Kinematics", "features": ["nope", "x", "nah"]}, True, "'nope', 'nah' are not features of type"),
    ({"type": "OverlayKinematics", "features": ["x", "marked"]}, True,
     "features: 'marked' is a column the observation adds itself \\(type 'OverlayKinematics'\\): leave it out"),
])
def test_feature_names_no_vehicle_row_has_are_one_line(observation, fast_road, says):
    # before: a KeyError traceback (our Kinematics), or a name left silently unused (an empty grid layer)
    with pytest.raises(ConfigError, match=says):
        env = gym.make("dt_highway:dt-highway-v0", config={"highway": {"observation": observation, "duration": 1},
                                                           "twin": {"preroll_s": 1}, "traffic": {"fast_road": fast_road}})
        env.reset(seed=0)
    for good in ({"type": "OccupancyGrid", "features": ["presence", "on_road", "vx"]},
                 {"type": "Kinematics", "features": ["presence", "x", "cos_d"], "features_range": {"vx": [-5, 5]}},
                 {"type": "OverlayKinematics", "threat": True, "features_range": {"marked": [0, 1]}}):  # taken, unused
        if good["type"] == "OverlayKinematics" and not fast_road:
            continue
        env = gym.make("dt_highway:dt-highway-v0", config={"highway": {"observation": good, "duration": 1},
                                                           "twin": {"preroll_s": 1}, "traffic": {"fast_road": fast_road}})
        env.reset(seed=0)
        env.close()


@pytest.mark.parametrize("observation, says", [
    ({"type": "TupleObservation", "observation_configs": [
        {"type": "Kinematics"}, {"type": "OccupancyGrid", "features": ["presence", "nope"]}]},
     r"highway.observation.observation_configs\[1\].features: 'nope' is not a feature of type 'OccupancyGrid'"),
    ({"type": "MultiAgentObservation", "observation_config": {"type": "Kinematics", "features_range": {"vxx": [0, 1]}}},
     "highway.observation.observation_config.features_range: 'vxx' is not a feature of type 'Kinematics'"),
    ({"type": "MultiAgentObservation", "observation_config": {"type": "TupleObservation", "observation_configs": [
        {"type": "Kinematics"}, {"type": "OccupancyGrid", "features": ["nope"]}]}},
     r"highway.observation.observation_config.observation_configs\[1\].features: 'nope' is not a feature"),
    ({"type": "TupleObservation", "observation_configs": [{"type": "Kinematics", "features": ["presence", "nope"]}]},
     r"highway.observation.observation_configs\[0\].features: 'nope' is not a feature"),  # was highway-env's KeyError
])
def test_feature_names_in_nested_highway_env_tables_are_checked(observation, says):
    # before: the grid layer and the range were left silently unused (made, the env observes once)
    with pytest.raises(ConfigError, match=says):
        gym.make("dt_highway:dt-highway-v0", config={"highway": {"observation": observation, "duration": 1},
                                                     "twin": {"preroll_s": 1}}).reset(seed=0)


@pytest.mark.parametrize("good", [
    {"type": "TupleObservation", "observation_configs": [
        {"type": "Kinematics", "features_range": {"vx": [-5, 5]}}, {"type": "OccupancyGrid", "features": ["on_road"]}]},
    {"type": "MultiAgentObservation", "observation_config": {"type": "Kinematics", "features": ["presence", "x"]}},
])
def test_valid_feature_names_in_nested_highway_env_tables_still_observe(good):
    env = gym.make("dt_highway:dt-highway-v0", config={"highway": {"observation": good, "duration": 1},
                                                       "twin": {"preroll_s": 1}})
    obs, _ = env.reset(seed=0)
    assert len(obs) >= 1 and all(np.size(part) > 0 for part in obs)
    env.close()


def test_the_twin_columns_are_not_feature_names_and_a_policys_unused_range_still_drives(tmp_path):
    with pytest.raises(ConfigError, match="'twin_known' is a column the observation adds itself"):
        env = gym.make("dt_highway:dt-highway-v0", config={
            "highway": {"observation": {"features": ["presence", "twin_known"]}, "duration": 1},
            "twin": {"preroll_s": 1, "in_observation": True}})
        env.reset(seed=0)
    src = ROOT / "agents" / "ppo-adas.zip"  # trained on OverlayKinematics
    policy = tmp_path / "ranged.zip"
    shutil.copy(src, policy)
    meta = json.loads(src.with_suffix(".json").read_text())
    meta["env_config"]["highway"]["observation"]["features_range"] = {"vxx": [0, 1]}  # unused, as highway-env drops it
    policy.with_suffix(".json").write_text(json.dumps(meta))
    env = DTHighwayEnv(config=load_config(str(ROOT / "envs/highway-trial.toml"), ["highway.duration=1",
                                                                                   "twin.preroll_s=1"]).to_dict())
    env.reset(seed=0)
    assert DriverSeat(env, load_policy(policy).senses).perceive().observation is not None
    meta["env_config"]["highway"]["observation"]["features"] = ["presence", "x", "y", "vx", "nope"]
    policy.with_suffix(".json").write_text(json.dumps(meta))
    with pytest.raises(ConfigError, match="policy ranged: its metadata's observation.features: 'nope' is not a"):
        DriverSeat(env, load_policy(policy).senses).perceive()
    env.close()


def test_a_fault_of_ours_that_highway_env_calls_is_not_called_a_config_error(monkeypatch):
    from highway_env.vehicle.objects import RoadObject

    from dt_highway.world.vehicle import FastIDMVehicle

    def buggy(self, *args, **kwargs):
        raise IndexError("a bug in our vehicle code")

    env = gym.make("dt_highway:dt-highway-v0", config={"highway": {"observation": {"type": "OccupancyGrid"},
                                                                   "duration": 2}, "twin": {"preroll_s": 1}})
    env.reset(seed=0)
    monkeypatch.setattr(FastIDMVehicle, "to_dict", buggy)  # highway-env's observation calls it
    with pytest.raises(IndexError, match="a bug in our vehicle code"):
        env.reset(seed=1)
    env.close()
    monkeypatch.undo()
    monkeypatch.setattr(RoadObject, "lane_distance_to", lambda self, *a, **k: {}["a bug of ours"])
    with pytest.raises(KeyError):  # TimeToCollision observes while its space is made
        gym.make("dt_highway:dt-highway-v0", config={"highway": {"observation": {"type": "TimeToCollision"}},
                                                    "traffic": {"fast_road": False}})


def test_a_new_observation_type_does_not_inherit_the_old_ones_options():
    from dt_highway.config import deep_merge

    grid = {"type": "OccupancyGrid", "grid_step": [11, 11]}
    env = gym.make("dt_highway:dt-highway-v0", config={"highway": {"observation": grid, "duration": 1},
                                                       "twin": {"preroll_s": 1}})
    grayscale = {"type": "GrayscaleObservation", "observation_shape": [64, 32], "stack_size": 2,
                 "weights": [0.3, 0.6, 0.1]}
    obs, _ = env.reset(seed=0, options={"config": {"highway": {"observation": grayscale}}})
    assert obs.shape == (2, 64, 32)  # grid_step is not carried into the grayscale table
    env.close()
    kinematics = {"type": "Kinematics", "vehicles_count": 4, "features": ["presence", "x"]}
    assert deep_merge({"o": kinematics}, {"o": {"type": "OverlayKinematics"}})["o"] == {
        **kinematics, "type": "OverlayKinematics"}  # the same options: kept
    assert deep_merge({"o": kinematics}, {"o": {"type": "Camera"}})["o"] == {"type": "Camera"}
    assert deep_merge({"o": kinematics}, {"o": {"vehicles_count": 6}})["o"]["features"] == ["presence", "x"]
    continuous = {"type": "ContinuousAction", "longitudinal": False}
    assert deep_merge({"a": continuous}, {"a": {"type": "DiscreteAction"}})["a"] == {
        "type": "DiscreteAction", "longitudinal": False}  # DiscreteAction reads ContinuousAction's options


def test_a_type_named_after_its_options_on_the_command_line_keeps_them(tmp_path):
    scenario = tmp_path / "kinematics.toml"
    scenario.write_text('[highway.observation]\ntype = "Kinematics"\nvehicles_count = 5\n')
    cfg = load_config(scenario, ["camera.enabled=true", "highway.observation.depth=true",
                                 "highway.observation.type=Camera"])
    assert cfg.highway.observation == {"type": "Camera", "depth": True}  # the scenario's Kinematics options go

# ----------------------------------------------------------------------------- env.unwrapped.config, highway-env's way
def test_editing_env_config_before_reset_is_validated_and_applied(small_config):
    env = _make(small_config)
    u = env.unwrapped
    config = u.config
    config["lanes_count"] = 2  # highway-env's documented idiom
    config["duration"] = 3
    assert u.dt_config.highway.lanes_count == 2 and u.dt_config.highway.duration == 3.0
    assert config["lanes_count"] == 2 and u.config is config  # the same dict, showing the tree
    env.reset(seed=0)
    assert len(u.road.network.graph["0"]["1"]) == 2  # the road really has two lanes
    assert {v.lane_index[2] for v in u.road.vehicles} <= {0, 1}
    config["observation"]["vehicles_count"] = 4  # inside a table: applied at the next reset
    obs, _ = env.reset(seed=0)
    assert obs.shape == (4, 5) and u.dt_config.highway.observation["vehicles_count"] == 4
    config.update({"lanes_count": 3, "vehicles_count": 6})
    assert (u.dt_config.highway.lanes_count, u.dt_config.highway.vehicles_count) == (3, 6)
    env.close()


@pytest.mark.parametrize("key, value, must_contain", [
    ("banana", 1, "unknown key 'highway.banana' (allowed here: lanes_count"),
    ("lanes_count", 0, "highway.lanes_count = 0 is out of range: must be >= 1"),
    ("duration", "long", "highway.duration = 'long'"),
    ("other_vehicles_type", "x.Y", "is set by dt-highway-v0 itself"),  # not configurable here
    ("twin", {"enabled": False}, "set 'twin' with env.unwrapped.configure("),
    ("observation", {"type": "Nope"}, "highway.observation.type = 'Nope'"),
])
def test_bad_edits_of_env_config_are_one_line_errors_naming_the_key(small_config, key, value, must_contain):
    from dt_highway.config import ConfigError

    env = _make(small_config)
    u = env.unwrapped
    before = u.dt_config
    with pytest.raises(ConfigError) as info:
        u.config[key] = value
    assert "\n" not in str(info.value) and must_contain in str(info.value), str(info.value)
    assert u.dt_config == before and u.config.get(key) != value  # nothing applied
    with pytest.raises(ConfigError, match="cannot be removed"):
        del u.config["duration"]
    env.close()


def test_an_edit_inside_a_table_is_checked_at_reset(small_config):
    from dt_highway.config import ConfigError

    env = _make(small_config)
    env.unwrapped.config["action"]["type"] = "Nope"
    with pytest.raises(ConfigError, match=r"highway\.action\.type = 'Nope'.*DiscreteDriver"):
        env.reset(seed=0)
    assert env.unwrapped.config["action"]["type"] == "DiscreteMetaAction"  # the refused edit is gone
    env.close()


def test_highway_envs_own_writes_and_copies_of_env_config_work(small_config):
    import copy
    import pickle

    env = gym.make("dt-highway-v0", render_mode="rgb_array", config=small_config)
    u = env.unwrapped
    assert u.config["offscreen_rendering"] is True  # derived from render_mode, as highway-env does
    assert u.dt_config.highway.offscreen_rendering is None  # ... without changing the tree
    u.configure(None)  # highway-env's configure path, with its derived-value write
    u.config["controlled_vehicles"] = 1  # writing a value it already has is fine, even a key not in the tree
    u.config["offscreen_rendering"] = True
    env.reset(seed=0)
    assert env.render().shape == (u.config["screen_height"], u.config["screen_width"], 3)
    plain = copy.deepcopy(u.config)
    assert type(plain) is dict and plain == u.config
    assert type(pickle.loads(pickle.dumps(u.config))) is dict
    plain["lanes_count"] = 1  # a copy is the user's own dict
    assert u.config["lanes_count"] == 3
    clone = copy.deepcopy(u)  # highway-env's planners copy the env: the copy's dict stays live, on the copy
    clone.config["lanes_count"] = 2
    assert clone.dt_config.highway.lanes_count == 2 and u.dt_config.highway.lanes_count == 3
    explicit = gym.make("dt-highway-v0", render_mode="rgb_array", config={**small_config, "offscreen_rendering": False})
    assert explicit.unwrapped.config["offscreen_rendering"] is False
    explicit.close()
    env.close()


def test_the_offscreen_rendering_variable_gives_highway_envs_deprecation_warning(monkeypatch):
    """highway-env 1.12.1's tests/graphics TestDeprecation::test_offscreen_env_var_emits_warning, on our id."""
    import warnings

    monkeypatch.setenv("OFFSCREEN_RENDERING", "1")
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        env = gym.make("dt-highway-v0", render_mode="rgb_array", config={"twin": {"preroll_s": 0.0}})
        env.close()
    messages = [str(x.message) for x in w if issubclass(x.category, DeprecationWarning)]
    assert any("OFFSCREEN_RENDERING" in m and 'render_mode="rgb_array"' in m for m in messages), messages
    monkeypatch.setenv("OFFSCREEN_RENDERING", "0")
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        DTHighwayEnv(config={"twin": {"preroll_s": 0.0}}).close()
    assert any('render_mode="human"' in str(x.message) for x in w)
    monkeypatch.delenv("OFFSCREEN_RENDERING")
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        DTHighwayEnv(config={"twin": {"preroll_s": 0.0}}).close()
    assert not any("OFFSCREEN_RENDERING" in str(x.message) for x in w)


@pytest.mark.parametrize(("action_type", "bad", "takes"), [
    ({"type": "DiscreteMetaAction"}, 7, "one integer 0..4"),
    ({"type": "DiscreteMetaAction"}, -1, "one integer 0..4"),
    ({"type": "DiscreteMetaAction"}, 1.5, "one integer 0..4"),
    ({"type": "DiscreteMetaAction"}, "LEFT", "one integer 0..4"),
    ({"type": "DiscreteMetaAction"}, np.array([1, 2]), "one integer 0..4"),
    ({"type": "ContinuousAction"}, np.array([np.nan, np.nan]), "2 finite numbers in shape \\(2,\\)"),
    ({"type": "ContinuousAction"}, np.array([0.1]), "2 finite numbers in shape \\(2,\\)"),
    ({"type": "ContinuousAction"}, "ab", "2 finite numbers in shape \\(2,\\)"),
    ({"type": "Driver"}, [np.inf, 0.0], "2 finite numbers in shape \\(2,\\)"),
    # each went past the check and failed deep in highway-env (or, "1", was taken as 1)
    ({"type": "DiscreteMetaAction"}, np.array([3]), "one integer 0..4"),
    ({"type": "DiscreteMetaAction"}, [1], "one integer 0..4"),
    ({"type": "DiscreteMetaAction"}, "1", "one integer 0..4"),
    ({"type": "DiscreteAction"}, "1", "one integer 0..\\d+"),
    ({"type": "DiscreteAction"}, np.array([2]), "one integer 0..\\d+"),
    ({"type": "ContinuousAction"}, np.array([[0.1, 0.2]]), "2 finite numbers in shape \\(2,\\)"),
    ({"type": "ContinuousAction"}, [["0.5", "0"]], "2 finite numbers in shape \\(2,\\)"),
])
def test_an_action_the_space_cannot_hold_is_one_line_and_leaves_the_env_as_it_was(small_config, action_type, bad, takes):
    env = gym.make("dt-highway-v0", config={**small_config, "highway": {**small_config.get("highway", {}),
                                                                        "action": action_type}})
    env.reset(seed=0)
    before, clock = np.array(env.unwrapped.vehicle.position), env.unwrapped.time
    with pytest.raises(ValueError, match=f"is not in the {action_type['type']}\\w* action space .*: {takes}$"):
        env.step(bad)
    assert np.array_equal(env.unwrapped.vehicle.position, before) and env.unwrapped.time == clock  # nothing changed
    good = 1 if action_type["type"] in ("DiscreteMetaAction", "DiscreteAction") else np.zeros(2)
    obs, reward, *_ = env.step(good)
    assert np.isfinite(reward) and np.isfinite(np.asarray(obs, dtype=float)).all()
    env.close()


def test_a_refused_first_reset_leaves_the_made_env_usable():
    """gymnasium 1.4's passive checker, on a gym.make env whose first reset fails, made every later step
    raise TypeError while the simulation went on: the env is registered without it."""
    env = gym.make(ENV_ID, config={"highway": {"duration": 2, "vehicles_count": 5}, "twin": {"preroll_s": 0.0}})
    with pytest.raises(gym.error.Error, match="seed"):
        env.reset(seed=-1)
    env.reset(seed=0)
    for k in (1, 2):
        obs, reward, terminated, truncated, info = env.step(0)
        assert obs.shape == env.observation_space.shape and env.unwrapped.time == pytest.approx(k)
    env.close()


def test_a_script_that_never_closes_its_env_keeps_what_the_twin_learnt(tmp_path):
    """twin.store.path is written at close, at a seeded reset, and when the env is collected or Python exits
    without a close (a script or a notebook rarely closes); a close then a reset opens the file again."""
    path = tmp_path / "twin.sqlite"
    cfg = {"highway": {"duration": 3, "vehicles_count": 8}, "twin": {"preroll_s": 0.0, "store": {"path": str(path)}},
           "traffic": {"population_seed": 1}}
    code = (f"import gymnasium as gym, dt_highway\nenv = gym.make('dt-highway-v0', config={cfg!r})\n"
            "env.reset(seed=0)\nfor _ in range(3):\n    env.step(0)\nprint(len(env.unwrapped.twin.tagger.records))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         env={**os.environ, "SDL_VIDEODRIVER": "offscreen"})
    learnt = int(out.stdout.split()[-1])
    assert learnt > 0
    with sqlite3.connect(path) as con:
        assert con.execute("SELECT count(*) FROM drivers").fetchone() == (learnt,)
    env = DTHighwayEnv(config=cfg)
    assert len(env.twin.tagger.records) == learnt  # read back
    env.close()
    env.reset(seed=0)  # after a close: the twin is made again from the file
    assert len(env.twin.tagger.records) == learnt
    env.close()
    with pytest.raises(ConfigError, match="must name a SQLite file in an existing folder"):
        DTHighwayEnv(config={"twin": {"store": {"path": str(tmp_path / "no-such-folder" / "twin.sqlite")}}})


def _store_config(path):
    return {"highway": {"duration": 3, "vehicles_count": 8}, "twin": {"preroll_s": 0.0, "store": {"path": str(path)}},
            "traffic": {"population_seed": 1}}


def test_a_store_file_goes_with_an_env_that_is_dropped_copied_closed_or_forked(tmp_path):
    """An env dropped without close() held its file until the cycle collector ran (a notebook cell run twice
    failed); a copy of the env could not be made; a forked child kept the file from the next env; after a close
    the next reset takes the file again and keeps the same drivers and twin."""
    cfg = _store_config(tmp_path / "twin.sqlite")

    def episode():
        env = gym.make(ENV_ID, config=cfg)
        env.reset()
        env.step(0)

    episode()
    episode()  # the first one's env is garbage, not yet collected
    env = gym.make(ENV_ID, config=cfg)
    env.reset(seed=0)
    twin, population = env.unwrapped.twin, env.unwrapped.population
    copied = copy.deepcopy(env.unwrapped)  # holds no file: writes nothing, releases nothing
    assert copied.twin._lock is None and twin._lock is not None
    copied.close()
    assert twin._lock is not None
    pid = os.fork()
    if pid == 0:  # the child only sleeps a little: the parent's env must get the file back at once
        time.sleep(2.0)
        os._exit(0)
    try:
        env.close()
        env.reset()  # unseeded: the same world, the file taken again
        assert env.unwrapped.twin is twin and env.unwrapped.population is population and twin._lock is not None
        env.close()
        other = DTHighwayEnv(config=cfg)  # while the child lives
        other.close()
    finally:
        os.waitpid(pid, 0)

"""Pre-roll ahead: a helper process resets the next seed while the episode runs; the episodes are
the ones Reseed gives, byte for byte, and the helper goes away with the env."""

import pickle
from pathlib import Path

import numpy as np
import pytest

from dt_highway.config import load_config
from dt_highway.env import DTHighwayEnv
from dt_highway.rl.preroll import PrerollAhead, ahead_ok
from dt_highway.rl.train import Reseed, lean_env_config

ROOT = Path(__file__).resolve().parents[1]
SHORT = ["highway.duration=4", "twin.preroll_s=3", "highway.vehicles_count=12",
         "highway.observation.type=Kinematics", "highway.action.type=DiscreteMetaAction"]


def _config(extra=()):
    cfg, _ = lean_env_config(load_config(str(ROOT / "envs/highway-trial.toml"), [*SHORT, *extra]))
    return cfg


def _play(env, episodes, actions):
    out = []
    for _ in range(episodes):
        obs, _ = env.reset()
        out.append(("reset", obs.copy()))
        for a in actions:
            obs, reward, terminated, truncated, _ = env.step(int(a))
            out.append((obs.copy(), reward, terminated, truncated))
            if terminated or truncated:
                break
    return out


def _same(a, b):
    assert len(a) == len(b)
    for x, y in zip(a, b, strict=True):
        assert len(x) == len(y)
        for u, v in zip(x, y, strict=True):
            assert np.array_equal(np.asarray(u), np.asarray(v))


def test_the_episodes_are_reseeds_byte_for_byte_and_the_helper_served_them():
    cfg = _config()
    assert ahead_ok(cfg)
    actions = np.random.default_rng(3).integers(0, 5, 25)
    plain = Reseed(DTHighwayEnv(config=cfg.to_dict()), first=7, stride=4)
    ahead = PrerollAhead(cfg.to_dict(), first=7, stride=4)
    try:
        _same(_play(plain, 3, actions), _play(ahead, 3, actions))
        assert (ahead.served, ahead.missed) == (2, 1)  # the first start is made here, the next two came ready
        assert plain.next_seed == ahead.next_seed == 19
    finally:
        helper = ahead._helper
        ahead.close()
        plain.close()
    assert helper is not None and helper.poll() is not None  # the helper is gone with the env


def test_a_seed_out_of_turn_or_a_dead_helper_falls_back_to_a_reset_here():
    cfg = _config()
    ahead = PrerollAhead(cfg.to_dict(), first=7)
    plain = DTHighwayEnv(config=cfg.to_dict())
    try:
        ahead.reset()  # seed 7 here; seed 8 asked for
        obs, _ = ahead.reset(seed=11)  # out of turn: the helper's seed-8 env is dropped
        assert np.array_equal(obs, plain.reset(seed=11)[0]) and ahead.missed == 2
        ahead._helper.kill()
        ahead._helper.wait()
        obs, _ = ahead.reset()  # seed 8, but the helper is dead
        assert np.array_equal(obs, plain.reset(seed=8)[0]) and ahead.missed == 3 and ahead._helper is None
    finally:
        ahead.close()
        plain.close()


@pytest.mark.parametrize("extra", [["camera.enabled=true"], ["twin.enabled=true"], ["twin.preroll_s=0"]])
def test_only_configurations_that_pickle_and_have_a_pre_roll_go_ahead(extra):
    cfg = load_config(str(ROOT / "envs/highway-trial.toml"), [*SHORT, "twin.enabled=false", *extra])
    assert not ahead_ok(cfg)


def test_a_lean_kinematic_env_pickles_to_the_same_episode():
    cfg = _config()
    env = DTHighwayEnv(config=cfg.to_dict())
    env.reset(seed=5)
    copy = pickle.loads(pickle.dumps(env))
    actions = np.random.default_rng(0).integers(0, 5, 20)
    for a in actions:
        x, y = env.step(int(a)), copy.step(int(a))
        assert np.array_equal(x[0], y[0]) and x[1:4] == y[1:4]

"""The fast training path (:func:`~dt_highway.rl.train.lean_env_config`) and ``dt-highway bench train``."""

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from dt_highway.cli import main
from dt_highway.config import DTConfig, merge
from dt_highway.rl.config import TrainConfig, parse_train_config
from dt_highway.rl.train import _make_env, lean_env_config

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = str(ROOT / "envs/highway-trial.toml")
# the safety-aware reward's terms (read from the safety samples) must come out the same too
REWARD = {"ttc2d": {"weight": 1.0}, "hard_braking": {"weight": 0.1}, "progress": {"weight": 0.01}, "jerk": {"weight": 0.01}}


def _cfg(observation: str, **extra: Any) -> TrainConfig:
    return parse_train_config({"kind": "rl", "observation": observation, "scenario": SCENARIO, "action": "assisted",
                               **extra})


def _episode(cfg: TrainConfig, env_config: DTConfig, steps: int, seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """``steps`` steps of seeded random actions, as a training env (reward wrapper, reseeding) runs them."""
    env = _make_env(env_config.to_dict(), seed, 1, cfg.reward)()
    rng = np.random.default_rng(seed)
    obs, _ = env.reset()
    seen, rewards = [obs], []
    for _ in range(steps):
        obs, reward, terminated, truncated, _ = env.step(int(rng.integers(env.action_space.n)))
        seen.append(obs)
        rewards.append(reward)
        if terminated or truncated:
            seen.append(env.reset()[0])
    env.close()
    return np.stack(seen), np.asarray(rewards)


def test_lean_switches_off_only_what_the_observation_does_not_read():
    lean, off = lean_env_config(_cfg("kinematics").env_config())
    assert off == ["twin.enabled"] and not lean.twin.enabled and not lean.camera.enabled
    lean, off = lean_env_config(_cfg("adas").env_config())
    assert off == ["twin.intention.enabled"]
    assert lean.twin.enabled and lean.camera.enabled and lean.fusion.enabled and not lean.twin.intention.enabled
    # the threat marks and the threat cue read the intention; pixels need everything
    assert lean_env_config(_cfg("adas", set=["overlay.mode=both"]).env_config())[1] == []
    assert lean_env_config(_cfg("adas-threat").env_config())[1] == []
    assert lean_env_config(_cfg("vision").env_config())[1] == []
    # the twin's tags in the observation: the twin stays, its intention goes
    assert lean_env_config(_cfg("kinematics", set=["twin.in_observation=true"]).env_config())[1] == \
        ["twin.intention.enabled"]


@pytest.mark.parametrize("observation", ["kinematics", "adas"])
def test_the_fast_path_gives_the_same_observations_marks_and_rewards(observation):
    cfg = _cfg(observation, reward=REWARD, set=["highway.duration=30"])
    full = cfg.env_config()
    lean, off = lean_env_config(full)
    assert off
    obs_full, rew_full = _episode(cfg, full, 160)
    obs_lean, rew_lean = _episode(cfg, lean, 160)
    np.testing.assert_array_equal(obs_lean, obs_full)
    np.testing.assert_array_equal(rew_lean, rew_full)
    assert len(np.unique(rew_full)) > 10  # the safety terms move the reward: not a constant compared with itself
    if observation == "adas":
        marked = obs_full[..., -1]
        assert marked.sum() >= 5  # marks were on screen: not an empty comparison
        # the comparison sees a change of the marks: another overlay setting gives other observations (a mark
        # shows after 5 frames instead of 2; in this episode at most one car is marked at a time, so max_marks
        # would not do)
        other, _ = _episode(cfg, merge(full, {"overlay": {"onset_frames": 5}}), 160)
        assert other[..., -1].sum() < marked.sum()
        np.testing.assert_array_equal(other[..., :-1], obs_full[..., :-1])  # same world, fewer marks


def test_bench_train_runs_tiny_and_prints_its_fields(tmp_path, capsys, monkeypatch):
    config = tmp_path / "tiny.toml"
    config.write_text(
        'kind = "rl"\nobservation = "adas"\naction = "assisted"\n'
        f'scenario = "{SCENARIO}"\nset = ["twin.preroll_s=5", "highway.duration=10"]\nn_envs = 1\n'
        "[hyperparameters]\nn_steps = 32\nbatch_size = 32\nn_epochs = 1\n", encoding="utf-8")
    args = ["bench", "train", "--config", str(config), "--timesteps", "64", "--env-steps", "30", "--n-envs", "2",
            "--quiet"]
    assert main([*args, "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert r["switched_off"] == ["twin.intention.enabled"] and r["config"]["observation"] == "adas"
    assert r["env_only"]["same_observations"] and r["env_only"]["same_rewards"] and r["env_only"]["steps"] == 30
    today, fast = r["ppo"]["today"], r["ppo"]["fast"]
    assert (today["vec_env"], today["n_envs"], today["steps"]) == ("DummyVecEnv", 1, 64)  # 2 rollouts of 32
    assert (fast["vec_env"], fast["n_envs"], fast["steps"]) == ("SubprocVecEnv", 2, 64)  # 1 rollout of 2 x 32
    for run in (today, fast, r["env_only"]["today"], r["env_only"]["fast"]):
        assert run["steps_per_s"] > 0
    for run in (today, fast):
        assert run["steps_per_s"] == pytest.approx(run["steps"] / run["wall_s"], rel=0.02)
        assert run["collect_s"] + run["update_s"] == pytest.approx(run["wall_s"], abs=0.02)
        assert "load_1min_before" in run and "load_1min_after" in run
        assert run["cpu_s"] > 0 and run["steps_per_cpu_s"] == pytest.approx(run["steps"] / run["cpu_s"], rel=0.02)
    assert r["speedup"] == pytest.approx(fast["steps_per_s"] / today["steps_per_s"], abs=0.01)
    assert r["target_steps_per_s"] == 300 and r["target_met"] == (fast["steps_per_s"] >= 300)
    # the text form names each number
    monkeypatch.setattr("dt_highway.bench.bench_train", lambda *a, **k: r)
    assert main(args) == 0
    text = capsys.readouterr().out
    assert f"PPO today: {today['steps_per_s']} steps/s (1 env, DummyVecEnv; 64 steps" in text
    assert f"PPO fast: {fast['steps_per_s']} steps/s (2 envs, SubprocVecEnv; 64 steps" in text
    assert f"today {r['env_only']['today']['steps_per_s']} steps/s" in text and "same observations: yes" in text
    assert "switches off: twin.intention.enabled" in text and f"speedup x{r['speedup']}" in text
    assert "target 300 steps/s: " in text


def test_bench_train_refuses_a_missing_config(capsys):
    assert main(["bench", "train", "--config", "agents/nope.toml", "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nope.toml" in err[0]

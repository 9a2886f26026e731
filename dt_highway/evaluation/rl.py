"""Evaluate any driver on the same seeds (``dt-highway evaluate``): policies and scripted drivers.

Each episode is one trial of the scenario in one condition, the driver acting through the
``Driver`` action as in a study. Return is the env's reward summed over the decisions
(highway-env's reward: speed in ``reward_speed_range``, right lane, collision); the safety
metrics are :func:`~dt_highway.metrics.safety.trial_metrics` of the episode's per-step samples.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np
import pandas as pd

from dt_highway.conditions import condition_config
from dt_highway.config import ConfigError, deep_merge, load_config
from dt_highway.drivers import Driver, load_driver
from dt_highway.env.seat import DriverSeat
from dt_highway.metrics.safety import trial_metrics


def run_episode(driver: Driver, env: gym.Env, seed: int) -> dict[str, Any]:
    """One episode of ``driver`` in ``env`` from ``reset(seed)``; the driver acts on what its
    seat perceives (:class:`~dt_highway.env.seat.DriverSeat`), ``info`` is for the metrics.

    :param env: a ``dt-highway-v0`` env, wrapped (``gym.make``) or not
    :return: ``return``, ``steps``, ``collision`` and the trial metrics (units in the names)
    :raises TypeError: if ``env`` is not a ``dt-highway-v0`` env
    """
    _, info = env.reset(seed=seed)
    seat = DriverSeat(env, driver.senses)
    u = seat.env
    driver.reset(seed)
    samples, cut_ins = list(info["safety"]["samples"]), list(info["safety"]["cut_ins"])
    total, steps = 0.0, 0
    while True:
        action = np.asarray(driver.act(seat.perceive()), dtype=float)
        _, reward, terminated, truncated, info = env.step(action)
        total += float(reward)
        steps += 1
        samples += info["safety"]["samples"]
        cut_ins += info["safety"]["cut_ins"]
        if terminated or truncated:
            break
    metrics = trial_metrics(pd.DataFrame(samples), 1.0 / u.config["simulation_frequency"], cut_ins)
    return {"seed": seed, "return": total, "steps": steps, "collision": bool(u.vehicle.crashed), **metrics}


def _mean(values: list[float]) -> float:
    finite = [v for v in values if isinstance(v, (int, float)) and math.isfinite(v)]
    return float(np.mean(finite)) if finite else math.nan


def evaluate(driver_path: str, episodes: int, seed: int, scenario: str | None = "envs/highway-trial.toml",
             condition: str = "adas", overrides: tuple[str, ...] = (),
             progress: Callable[[int], None] | None = None, driver: Driver | None = None) -> dict[str, Any]:
    """Run ``episodes`` episodes (seeds ``seed .. seed + episodes - 1``) of a driver.

    :param driver_path: ``agents/<name>.zip`` or ``agents/<driver>.toml``
    :param driver: the driver already loaded from ``driver_path`` (else it is loaded here)
    :param episodes: number of episodes
    :param seed: first seed
    :param scenario: scenario file
    :param condition: ``baseline`` (no overlay) or ``adas``
    :param overrides: ``dotted.key=value`` overrides
    :param progress: called with 0 when the checks are done and the episodes start, then with 1 after each
    :return: the means over episodes and the episodes themselves
    :raises ConfigError: on a bad driver, scenario, condition or count
    """
    if episodes < 1:
        raise ConfigError(f"--episodes must be >= 1 (got {episodes})")
    driver = driver if driver is not None else load_driver(driver_path)
    cfg = load_config(scenario, list(overrides), deep_merge(condition_config(condition), driver.config_overrides()))
    env = gym.make("dt-highway-v0", config=cfg.to_dict())
    rows = []
    try:
        if hasattr(driver, "model"):  # a policy that cannot drive this env says so before any episode
            DriverSeat(env.unwrapped, driver.senses)
            driver.reset(seed)
        if progress is not None:
            progress(0)  # checks done: the episodes start
        for k in range(episodes):
            rows.append(run_episode(driver, env, seed + k))
            if progress is not None:
                progress(1)
    finally:
        env.close()
    cut_in_ttc = [r["cut_in_ttc_min_s"] for r in rows]
    return {
        "driver": driver_path,
        "condition": condition,
        "scenario": scenario,
        "overrides": list(overrides),
        "episodes": episodes,
        "seeds": [seed, seed + episodes - 1],
        "mean_return": _mean([r["return"] for r in rows]),
        "collision_rate": float(np.mean([r["collision"] for r in rows])),
        "mean_speed_kmh": _mean([r["speed_mean_kmh"] for r in rows]),
        "mean_ttc_s": _mean([r["ttc_mean_s"] for r in rows]),
        "cut_in_ttc_min_s": _mean(cut_in_ttc),
        "cut_ins": int(sum(r["cut_ins"] for r in rows)),
        "episodes_with_cut_ins": int(sum(1 for v in cut_in_ttc if math.isfinite(v))),
        "mean_steps": _mean([r["steps"] for r in rows]),
        "definitions": {
            "mean_return": "env reward summed over an episode's decisions, mean over episodes",
            "collision_rate": "share of episodes that end with the ego crashed",
            "mean_speed_kmh": "ego speed, mean over each episode's simulation steps, mean over episodes",
            "mean_ttc_s": "per episode: mean TTC over closing samples below the cap (safety.TTC_CAP_S); "
                          "mean over episodes that have any",
            "cut_in_ttc_min_s": "per episode: smallest TTC to a vehicle that cut in ahead (capped); "
                                "mean over episodes with a cut-in",
        },
        "per_episode": rows,
    }

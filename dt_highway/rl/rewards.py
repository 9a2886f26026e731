"""Safety-aware training rewards: the ``[reward]`` table of a training file
(:class:`~dt_highway.agent_config.RewardConfig`), computed for training only.

Per policy step the reward is::

    reward = highway * r_highway + progress - collision - ttc2d - hard_braking - jerk

each term summed over the simulation steps of the policy step, from the env's safety samples
(``info["safety"]["samples"]``: :class:`~dt_highway.metrics.safety.SafetyMonitor`, the same
samples, 2-D TTC and collision kinds as the trial logs). The terms, their units and sources:

* ``highway``: highway-env's own reward (speed in ``reward_speed_range``, right lane, collision;
  its weights are the scenario's ``highway.*_reward`` keys) times ``highway`` [-] per policy step.
* ``collision``: ``collision.<kind>`` per collision onset, by the kind the trial logs give it
  (``cut_in``, ``rear_end``, ``side_swipe``, ``unknown``; :mod:`dt_highway.metrics.safety`).
* ``ttc2d``: exposure to a small 2-D time to collision (the smallest over the vehicles within
  100 m; Jiao 2023's 2-D TTC of oriented rectangles at constant velocity, TTC itself after
  Hayward 1972), after Minderhoud & Bovy's (2001) time exposed / time integrated TTC with threshold
  ``TTC*`` (``threshold_s``): ``tet``, ``sum dt [TTC <= TTC*]`` [s]; ``tit``,
  ``sum dt (TTC* - TTC) [TTC <= TTC*]`` [s^2]. Unlike the trial metrics (where a contact sample
  is not an exposed sample), a contact counts here as ``TTC = 0``, the most exposed: a reward
  must not pay for touching.
* ``hard_braking``: ``sum dt max(0, -a - threshold)``, the speed shed beyond the threshold
  deceleration [m/s] (default 3 m/s^2, about 0.3 g: the trial metrics' hard braking).
* ``progress``: ``distance``, the metres travelled along the road [m]; or ``speed``,
  ``sum dt max(0, 1 - |v - v*| / v*)``, the time near the target speed [s].
* ``jerk``: ``sum dt |j|`` with ``j = (a_k - a_(k-1)) / dt``, i.e. ``sum |a_k - a_(k-1)|``, the
  total variation of the longitudinal acceleration [m/s^2]: ride comfort, the jerk that
  comfort-oriented trajectory planners minimise (e.g. Werling et al. 2010 integrate squared jerk;
  the absolute value here keeps one decision's step change of the pedal from dominating).

Samples of a crashed ego (after the collision onset) count in neither braking nor jerk: the
crash's stop is the collision term's business. The default table is highway-env's reward alone,
exactly; training then uses no wrapper at all.

The reward reads the simulator (collisions, 2-D TTC): it is a training signal, never part of what
the policy observes. :class:`SafetyReward` puts each term's contribution in ``info["reward_terms"]``
and :class:`RewardTermsLogger` writes their means to the training log.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

from dt_highway.agent_config import RewardConfig

TERMS = ("highway", "progress", "collision", "ttc2d", "hard_braking", "jerk")
"""The reward's terms, in ``info["reward_terms"]`` (signed contributions: costs negative)"""


# ----------------------------------------------------------------------------- the quantities, one per term
def collision_cost(samples: Sequence[Mapping[str, Any]], config: RewardConfig) -> float:
    """Cost of the collision onsets among the samples, by kind [-].

    :param samples: safety samples (a ``collision`` dict with its ``kind`` at a crash onset, else ``None``)
    :param config: the reward table
    :return: the summed cost (>= 0)
    """
    costs = config.collision.model_dump()
    total = 0.0
    for s in samples:
        col = s.get("collision")
        if col:
            total += float(costs.get(str(col.get("kind", "unknown")), costs["unknown"]))
    return total


def ttc_exposure(ttc_s: np.ndarray, contact: np.ndarray, dt_s: float, threshold_s: float, mode: str = "tet") -> float:
    """Exposure to a 2-D TTC at or below ``TTC*``: TET [s] or TIT [s^2] (Minderhoud & Bovy 2001).

    :param ttc_s: 2-D TTC per sample [s] (inf: no collision course; NaN: contact)
    :param contact: per sample, the ego's rectangle touches another (counted as ``TTC = 0``)
    :param dt_s: simulation step [s]
    :param threshold_s: ``TTC*`` [s]
    :param mode: ``tet`` or ``tit``
    :return: the exposure (>= 0)
    """
    ttc = np.where(np.asarray(contact, dtype=bool), 0.0, np.asarray(ttc_s, dtype=float))
    exposed = np.isfinite(ttc) & (ttc >= 0.0) & (ttc <= threshold_s)
    if mode == "tit":
        return float(dt_s * np.sum(threshold_s - ttc[exposed]))
    return float(dt_s * np.count_nonzero(exposed))


def hard_braking_excess(accel_mps2: np.ndarray, dt_s: float, threshold_mps2: float) -> float:
    """Speed shed beyond a threshold deceleration, ``sum dt max(0, -a - threshold)`` [m/s].

    :param accel_mps2: the ego's acceleration per sample [m/s^2]
    :param dt_s: simulation step [s]
    :param threshold_mps2: deceleration from which braking costs [m/s^2]
    :return: the excess (>= 0) [m/s]
    """
    a = np.asarray(accel_mps2, dtype=float)
    return float(dt_s * np.sum(np.maximum(0.0, -a - threshold_mps2)))


def speed_progress(speed_mps: np.ndarray, dt_s: float, target_mps: float) -> float:
    """Time near a target speed, ``sum dt max(0, 1 - |v - v*| / v*)`` [s].

    :param speed_mps: the ego's speed per sample [m/s]
    :param dt_s: simulation step [s]
    :param target_mps: ``v*`` [m/s]
    :return: the time (>= 0) [s]
    """
    v = np.asarray(speed_mps, dtype=float)
    return float(dt_s * np.sum(np.maximum(0.0, 1.0 - np.abs(v - target_mps) / target_mps)))


def jerk_variation(accel_mps2: np.ndarray, previous_mps2: float | None = None) -> float:
    """Total variation of the acceleration, ``sum |a_k - a_(k-1)|`` = ``sum dt |jerk|`` [m/s^2].

    :param accel_mps2: the ego's acceleration per sample [m/s^2]
    :param previous_mps2: the acceleration of the sample before the first (``None``: unknown, not counted)
    :return: the total variation (>= 0) [m/s^2]
    """
    a = np.asarray(accel_mps2, dtype=float)
    if previous_mps2 is not None and len(a):
        a = np.concatenate(([previous_mps2], a))
    return float(np.sum(np.abs(np.diff(a)))) if len(a) > 1 else 0.0


# ----------------------------------------------------------------------------- per policy step
class RewardTerms:
    """The reward's terms of one policy step after another, in one episode.

    :param config: the reward table
    :param dt_s: simulation step [s]
    """

    def __init__(self, config: RewardConfig, dt_s: float) -> None:
        if not (math.isfinite(dt_s) and dt_s > 0):
            raise ValueError(f"the simulation step must be > 0 s (got {dt_s})")
        self.config, self.dt_s = config, float(dt_s)
        self.x_m: float = 0.0
        self.accel_mps2: float | None = None

    def reset(self, x_m: float) -> None:
        """Start an episode with the ego at ``x_m`` [m] (its acceleration before the first sample unknown).

        :param x_m: the ego's position along the road [m]
        """
        self.x_m, self.accel_mps2 = float(x_m), None

    def step(self, highway_reward: float, samples: Sequence[Mapping[str, Any]]) -> dict[str, float]:
        """The terms of one policy step: each one's signed contribution to the reward (costs negative).

        :param highway_reward: highway-env's reward of the step [-]
        :param samples: the step's safety samples, one per simulation step, in order
        :return: ``{term: contribution}`` over :data:`TERMS`; their sum is the reward
        """
        c, dt = self.config, self.dt_s
        terms = dict.fromkeys(TERMS, 0.0)
        terms["highway"] = c.highway * float(highway_reward)
        if not samples:
            return terms
        free = [s for s in samples if not s.get("crashed")]
        accel = np.array([s["accel_mps2"] for s in free], dtype=float)
        if c.progress.weight:
            if c.progress.mode == "distance":
                amount = float(samples[-1]["x_m"]) - self.x_m
            else:
                amount = speed_progress(np.array([s["speed_mps"] for s in samples]), dt, c.progress.target_mps)
            terms["progress"] = c.progress.weight * amount
        if any(c.collision.model_dump().values()):
            terms["collision"] = 0.0 - collision_cost(samples, c)
        if c.ttc2d.weight:
            ttc = np.array([s["ttc2d_s"] for s in samples], dtype=float)
            contact = np.array([bool(s.get("ttc2d_contact", False)) for s in samples])
            terms["ttc2d"] = 0.0 - c.ttc2d.weight * ttc_exposure(ttc, contact, dt, c.ttc2d.threshold_s, c.ttc2d.mode)
        if c.hard_braking.weight:
            terms["hard_braking"] = 0.0 - c.hard_braking.weight * hard_braking_excess(accel, dt, c.hard_braking.threshold_mps2)
        if c.jerk.weight:
            terms["jerk"] = 0.0 - c.jerk.weight * jerk_variation(accel, self.accel_mps2)
        self.x_m = float(samples[-1]["x_m"])
        self.accel_mps2 = float(accel[-1]) if len(free) == len(samples) and len(accel) else None
        return terms


class SafetyReward(gym.Wrapper):
    """A ``dt-highway-v0`` env whose reward is the training file's (:mod:`dt_highway.rl.rewards`).

    The observation is the env's, unchanged; ``info["reward_terms"]`` holds each term's
    contribution (they sum to the reward).

    :param env: a ``dt-highway-v0`` env (``gym.make``'d or not)
    :param config: the reward table
    """

    def __init__(self, env: gym.Env, config: RewardConfig) -> None:
        super().__init__(env)
        self.config = config
        self.terms = RewardTerms(config, _sim_step_s(env))

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[Any, dict]:
        """Reset the env and the reward's terms.

        :param seed: the episode's seed, passed to the env
        :param options: passed to the env's reset
        :return: the env's ``(observation, info)``
        """
        obs, info = self.env.reset(seed=seed, options=options)
        self.terms.dt_s = _sim_step_s(self.env)  # a reset may reconfigure
        self.terms.reset(_ego_x(info))
        return obs, info

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict]:
        """Step the env; the reward is highway-env's plus the safety terms (their parts in ``info["reward_terms"]``).

        :param action: the policy's action, passed to the env
        :return: the env's ``(observation, reward, terminated, truncated, info)`` with this reward
        :raises ValueError: on an env without ``info["safety"]``
        """
        obs, reward, terminated, truncated, info = self.env.step(action)
        safety = info.get("safety")
        if safety is None:
            raise ValueError("the safety-aware reward reads info['safety'] of a dt-highway-v0 env")
        terms = self.terms.step(float(reward), safety["samples"])
        info["reward_terms"] = terms
        total = 0.0
        for name in TERMS:
            total += terms[name]
        return obs, total, terminated, truncated, info


def _sim_step_s(env: gym.Env) -> float:
    """The env's simulation step [s]."""
    config = getattr(env.unwrapped, "config", None)
    if not isinstance(config, Mapping) or "simulation_frequency" not in config:
        raise ValueError("the safety-aware reward wraps a dt-highway-v0 env (it has no simulation_frequency)")
    return 1.0 / float(config["simulation_frequency"])


def _ego_x(info: Mapping[str, Any]) -> float:
    ego = info.get("ego")
    if not ego:
        raise ValueError("the safety-aware reward reads info['ego'] of a dt-highway-v0 env")
    return float(ego["x_m"])


class RewardTermsLogger(BaseCallback):
    """Writes each reward term's mean per env step over the rollout to the training log
    (``reward/<term>`` in ``progress.csv`` and TensorBoard), from ``info["reward_terms"]``."""

    def __init__(self) -> None:
        super().__init__()
        self._sums = dict.fromkeys(TERMS, 0.0)
        self._n = 0

    def _on_step(self) -> bool:
        for info in self.locals.get("infos", ()):
            terms = info.get("reward_terms")
            if terms:
                for name in TERMS:
                    self._sums[name] += float(terms.get(name, 0.0))
                self._n += 1
        return True

    def _on_rollout_end(self) -> None:
        if self._n:
            for name in TERMS:
                self.logger.record(f"reward/{name}", self._sums[name] / self._n)
        self._sums, self._n = dict.fromkeys(TERMS, 0.0), 0

"""How well the twin's tags match the simulator's driver types (``dt-highway twin-eval``).

At the end of each episode, every connected NPC that the twin has observed for at least
``min_observed_s`` and that was on the road during the episode is one judgement: its tag
(``aggressive`` or ``normal``) against its true driver type. Judgements of all episodes are
pooled (a driver met in several episodes is judged in each, as the twin may have changed
its mind). Precision and recall are for the class ``aggressive``.

``median_time_to_tag_s`` is, over the truly aggressive drivers that the twin tagged, the
median time from the twin's first analysis of the driver (its first fixes, to within one
tagger update) to its first ``aggressive`` tag, read from the twin's records after the
last episode (with ``persist_across_episodes`` off, those of the last episode only).
The ego runs on its IDM autopilot: the twin does not depend on how the ego drives.
"""

from __future__ import annotations

import statistics
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from dt_highway.config import ConfigError, DTConfig, merge
from dt_highway.env import DTHighwayEnv
from dt_highway.labels import AGGRESSIVE
from dt_highway.twin.tagger import DriverRecord
from dt_highway.world.traffic import EGO_ID, Driver, DriverPopulation


def episode_steps(config: DTConfig) -> int:
    """Policy steps one evaluation episode takes, the pre-roll counted (for progress bars)."""
    hw = config.highway
    return int(round((config.twin.preroll_s + hw.duration) * hw.policy_frequency))


def evaluate_twin(
    config: DTConfig,
    episodes: int,
    seed: int,
    min_observed_s: float = 30.0,
    progress: Callable[[int], None] | None = None,
) -> dict[str, Any]:
    """Run ``episodes`` episodes of one env and score the twin's tags against ground truth.

    :param config: resolved configuration (``ego.autopilot`` is switched on)
    :param episodes: number of episodes (>= 1)
    :param seed: seed of the first reset; later episodes continue the same random streams
    :param min_observed_s: drivers observed for less than this are not judged [s]
    :param progress: called with the number of policy steps simulated (the pre-roll's after
        each reset, then 1 after each step): see :func:`episode_steps`
    :return: the scores (see the module docstring) and the settings used
    """
    if episodes < 1:
        raise ValueError(f"episodes must be >= 1 (got {episodes})")
    if not config.twin.enabled:
        raise ConfigError("twin-eval needs twin.enabled = true")
    if not config.traffic.driver_types:
        raise ConfigError("twin-eval needs traffic.driver_types = true (stock traffic has no driver types to score)")
    cfg = merge(config, {"ego": {"autopilot": True}})
    env = DTHighwayEnv(config=cfg.to_dict())
    score = _Score(min_observed_s)
    try:
        for ep in range(episodes):
            seen = _run_episode(env, seed if ep == 0 else None, cfg, progress)
            records, population = _truth_and_tags(env)
            for vid in sorted(seen):
                if vid == EGO_ID or vid not in population.drivers:
                    continue
                score.judge(population[vid], records.get(vid))
        records, population = _truth_and_tags(env)
        times_to_tag, untagged_aggressive = _times_to_tag(records, population, min_observed_s)
    finally:
        env.close()
    return _result(score, times_to_tag, untagged_aggressive, cfg, episodes, seed)


def _run_episode(env: DTHighwayEnv, seed: int | None, cfg: DTConfig,
                 progress: Callable[[int], None] | None) -> set[int]:
    """One episode with random actions (the ego is on its autopilot).

    :return: the ids of the NPCs that were on the road at some step
    """
    env.reset(seed=seed)
    if progress is not None:
        progress(int(round(cfg.twin.preroll_s * cfg.highway.policy_frequency)))
    seen = {vid for vid in (getattr(v, "dt_id", -1) for v in env.road.vehicles) if vid > 0}
    done = False
    while not done:
        _, _, terminated, truncated, info = env.step(env.action_space.sample())
        seen.update(int(k) for k in info["ground_truth"]["vehicles"])
        done = terminated or truncated
        if progress is not None:
            progress(1)
    return seen


def _truth_and_tags(env: DTHighwayEnv) -> tuple[dict[int, DriverRecord], DriverPopulation]:
    """The twin's records (its tags) and the driver population (the truth) of the env as it is now."""
    if env.twin is None or env.population is None:  # the caller checked twin.enabled and driver_types
        raise RuntimeError("twin-eval needs the env's twin and driver population")
    return env.twin.tagger.records, env.population


@dataclass
class _Score:
    """The confusion counts of the judgements (class ``aggressive``), and the counts beside them.

    :param min_observed_s: drivers observed for less than this are not judged [s]
    """

    min_observed_s: float
    tp: int = 0
    fp: int = 0
    fn: int = 0
    tn: int = 0
    unjudged: int = 0
    all_aggr: int = 0
    all_aggr_tagged: int = 0

    def judge(self, driver: Driver, rec: DriverRecord | None) -> None:
        """Count one driver met in an episode: its tag (if the twin has a record) against its type."""
        if not driver.connected or rec is None:
            return
        truly = driver.driver_type == AGGRESSIVE
        tagged = rec.tag == AGGRESSIVE
        if truly:
            self.all_aggr += 1
            self.all_aggr_tagged += tagged
        if rec.observed_s < self.min_observed_s:
            self.unjudged += 1
            return
        self.tp += truly and tagged
        self.fp += tagged and not truly
        self.fn += truly and not tagged
        self.tn += not truly and not tagged


def _times_to_tag(records: dict[int, DriverRecord], population: DriverPopulation,
                  min_observed_s: float) -> tuple[list[float], int]:
    """:return: the truly aggressive drivers' times from first analysis to first aggressive tag [s], and how
        many of those observed at least ``min_observed_s`` were never tagged"""
    times_to_tag: list[float] = []
    untagged_aggressive = 0
    for vid, rec in records.items():
        if vid in population.drivers and population[vid].driver_type == AGGRESSIVE:
            if rec.first_aggressive_s is not None:
                times_to_tag.append(rec.first_aggressive_s - rec.first_seen_s)
            elif rec.observed_s >= min_observed_s:
                untagged_aggressive += 1
    return times_to_tag, untagged_aggressive


def _result(score: _Score, times_to_tag: list[float], untagged_aggressive: int, cfg: DTConfig, episodes: int,
            seed: int) -> dict[str, Any]:
    nan = float("nan")
    tp, fp, fn, tn = score.tp, score.fp, score.fn, score.tn
    return {
        "precision": tp / (tp + fp) if tp + fp else nan,
        "recall": tp / (tp + fn) if tp + fn else nan,
        "recall_all_observed": score.all_aggr_tagged / score.all_aggr if score.all_aggr else nan,
        "median_time_to_tag_s": statistics.median(times_to_tag) if times_to_tag else nan,
        "n_aggressive": tp + fn,
        "n_normal": fp + tn,
        "tp": tp, "fp": fp, "fn": fn, "tn": tn,
        "n_unjudged_short_observation": score.unjudged,
        "n_aggressive_never_tagged": untagged_aggressive,
        "episodes": episodes,
        "seed": seed,
        "min_observed_s": score.min_observed_s,
        "settings": {
            "noise_sigma_m": cfg.twin.uplink.noise_sigma_m,
            "uplink_rate_hz": cfg.twin.uplink.rate_hz,
            "latency_mean_s": cfg.twin.uplink.latency_mean_s,
            "loss_prob": cfg.twin.uplink.loss_prob,
            "preroll_s": cfg.twin.preroll_s,
            "duration_s": cfg.highway.duration,
            "vehicles_count": cfg.highway.vehicles_count,
            "aggressive_fraction": cfg.traffic.aggressive_fraction,
        },
    }

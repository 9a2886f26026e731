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
from typing import Any

from dt_highway.config import ConfigError, DTConfig, merge
from dt_highway.world.traffic import AGGRESSIVE, EGO_ID


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
    from dt_highway.env import DTHighwayEnv

    if episodes < 1:
        raise ValueError(f"episodes must be >= 1 (got {episodes})")
    if not config.twin.enabled:
        raise ConfigError("twin-eval needs twin.enabled = true")
    if not config.traffic.driver_types:
        raise ConfigError("twin-eval needs traffic.driver_types = true (stock traffic has no driver types to score)")
    cfg = merge(config, {"ego": {"autopilot": True}})
    env = DTHighwayEnv(config=cfg.to_dict())
    tp = fp = fn = tn = 0
    unjudged = 0
    all_aggr = all_aggr_tagged = 0
    times_to_tag: list[float] = []
    untagged_aggressive = 0
    try:
        for ep in range(episodes):
            env.reset(seed=seed if ep == 0 else None)
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
            records = env.twin.tagger.records
            for vid in sorted(seen):
                if vid == EGO_ID or vid not in env.population.drivers:
                    continue
                driver = env.population[vid]
                rec = records.get(vid)
                if not driver.connected or rec is None:
                    continue
                truly = driver.driver_type == AGGRESSIVE
                tagged = rec.tag == AGGRESSIVE
                if truly:
                    all_aggr += 1
                    all_aggr_tagged += tagged
                if rec.observed_s < min_observed_s:
                    unjudged += 1
                    continue
                tp += truly and tagged
                fp += tagged and not truly
                fn += truly and not tagged
                tn += not truly and not tagged
        for vid, rec in env.twin.tagger.records.items():
            if vid in env.population.drivers and env.population[vid].driver_type == AGGRESSIVE:
                if rec.first_aggressive_s is not None:
                    times_to_tag.append(rec.first_aggressive_s - rec.first_seen_s)
                elif rec.observed_s >= min_observed_s:
                    untagged_aggressive += 1
    finally:
        env.close()
    nan = float("nan")
    return {
        "precision": tp / (tp + fp) if tp + fp else nan,
        "recall": tp / (tp + fn) if tp + fn else nan,
        "recall_all_observed": all_aggr_tagged / all_aggr if all_aggr else nan,
        "median_time_to_tag_s": statistics.median(times_to_tag) if times_to_tag else nan,
        "n_aggressive": tp + fn,
        "n_normal": fp + tn,
        "tp": tp, "fp": fp, "fn": fn, "tn": tn,
        "n_unjudged_short_observation": unjudged,
        "n_aggressive_never_tagged": untagged_aggressive,
        "episodes": episodes,
        "seed": seed,
        "min_observed_s": min_observed_s,
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


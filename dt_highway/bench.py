"""Benchmarks that print numbers (``dt-highway bench ...``), never timed tests."""

from __future__ import annotations

import gc
import os
import time
from collections.abc import Callable
from typing import Any

from dt_highway.config import DTConfig, merge


def _rss_mb() -> float:
    """Resident set size of this process [MB] (Linux ``/proc``; NaN elsewhere)."""
    try:
        with open("/proc/self/statm") as fh:
            pages = int(fh.read().split()[1])
        return pages * os.sysconf("SC_PAGE_SIZE") / 1e6
    except (OSError, ValueError, IndexError):
        return float("nan")


def bench_memory(
    config: DTConfig, hours: float, sample_every_min: float = 10.0, progress: Callable[[int], None] | None = None
) -> dict[str, Any]:
    """Run one env for ``hours`` of simulated time (ego on autopilot) and sample memory.

    The episode lasts the whole run unless the ego crashes; the env is then reset without a
    seed (same drivers, the twin keeps its records), so memory is watched across episodes
    too.

    :param config: resolved configuration (duration is set to cover ``hours``)
    :param hours: simulated time [h]
    :param sample_every_min: sampling period [min of simulated time]
    :param progress: called with the number of policy steps done after each step
    :return: samples of RSS [MB], live Python objects, fixes held, driver records, episodes, and the
        growth between the first sample after warm-up and the last one
    """
    from dt_highway.env import DTHighwayEnv

    freq = config.highway.policy_frequency
    steps_per_sample = max(1, int(round(sample_every_min * 60 * freq)))
    n_samples = max(2, int(round(hours * 3600.0 * freq / steps_per_sample)))
    seconds = n_samples * steps_per_sample / freq  # what is actually simulated
    cfg = merge(config, {"ego": {"autopilot": True}, "highway": {"duration": seconds + 10.0}})
    env = DTHighwayEnv(config=cfg.to_dict())
    env.reset(seed=0)
    samples = []
    episodes = 1
    t0 = time.perf_counter()
    for k in range(n_samples):
        for _ in range(steps_per_sample):
            _, _, terminated, truncated, _ = env.step(0)
            if terminated or truncated:  # e.g. the ego was hit by a cut-in: the world goes on
                env.reset()
                episodes += 1
            if progress is not None:
                progress(1)
        gc.collect()
        samples.append({
            "sim_time_min": round((k + 1) * steps_per_sample / freq / 60.0, 2),
            "episodes": episodes,
            "rss_mb": round(_rss_mb(), 2),
            "live_objects": len(gc.get_objects()),
            "twin_fixes_held": env.twin.store.n_fixes() if env.twin else 0,
            "twin_records": len(env.twin.tagger.records) if env.twin else 0,
            "vehicles": len(env.road.vehicles),
        })
    wall = time.perf_counter() - t0
    env.close()
    first, last = samples[min(1, len(samples) - 1)], samples[-1]
    return {
        "hours_simulated": round(seconds / 3600.0, 4),
        "wall_time_s": round(wall, 1),
        "sim_seconds_per_wall_second": round(seconds / wall, 1),
        "rss_growth_mb_after_warmup": round(last["rss_mb"] - first["rss_mb"], 2),
        "live_object_growth_after_warmup": last["live_objects"] - first["live_objects"],
        "samples": samples,
    }

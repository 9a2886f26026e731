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

With the continuum population (``traffic.population = "continuum"``) the result also ranks the
judgements (the same pooled ones as precision and recall) by the twin's probability that the
driver is aggressive (its confidence in the tag it gave, or one minus it), against the truth:

* ``auc_label``: ROC AUC against the label (top ``aggressive_fraction`` by latent score);
* ``auc_latent_above_median``: ROC AUC against "latent score above the population's median";
* ``spearman_latent``: Spearman's rank correlation with the latent score itself;
* ``precision_at_recall_0_80``: the best precision over thresholds on that probability whose recall
  is at least 0.80 (with the threshold, ``threshold_at_recall_0_80``, and the recall there);
* ``ceiling``: the same two scores for a ranking no twin can beat with a linear read of the drivers'
  behaviour: :func:`population_ceiling`, the best linear combination of every driver's **true**
  parameters (all eleven, as if the twin knew them exactly).

An AUC is the Mann-Whitney ``U / (n1 n2)`` (``scipy.stats.mannwhitneyu``; ties count one half,
as the trapezoidal ROC area; scikit-learn is not a dependency). With the two-class default the
result has none of these keys (it stays as it was, byte for byte).
"""

from __future__ import annotations

import statistics
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from dt_highway.config import ConfigError, DTConfig, NormalTrait, deep_merge, dotted_tree, merge
from dt_highway.env import DTHighwayEnv
from dt_highway.labels import AGGRESSIVE
from dt_highway.twin.tagger import DriverRecord
from dt_highway.world.continuum import draw_traits, top_share
from dt_highway.world.traffic import EGO_ID, Driver, DriverPopulation

UPLINK_STRESS = {"twin.uplink.latency_mean_s": 0.3, "twin.uplink.rate_hz": 1.0}
"""The degraded uplink of the targets: 300 ms at 1 Hz"""


def uplink_settings(cfg: DTConfig) -> dict[str, Any]:
    """The uplink, population and episode settings an evaluation's JSON records.

    :param cfg: resolved configuration
    :return: the settings by name
    """
    return {
        "noise_sigma_m": cfg.twin.uplink.noise_sigma_m,
        "uplink_rate_hz": cfg.twin.uplink.rate_hz,
        "latency_mean_s": cfg.twin.uplink.latency_mean_s,
        "loss_prob": cfg.twin.uplink.loss_prob,
        "preroll_s": cfg.twin.preroll_s,
        "duration_s": cfg.highway.duration,
        "vehicles_count": cfg.highway.vehicles_count,
        "aggressive_fraction": cfg.traffic.aggressive_fraction,
    }


def uplink_sweep_runs(sweep: tuple[tuple[str, str, tuple[float, ...]], ...]) -> list[tuple[str, Any, dict[str, Any]]]:
    """The runs of an uplink sweep: each ``(name, dotted key, values)`` one value at a time, then
    :data:`UPLINK_STRESS` (both settings together) as ``latency_0.3s_at_1hz``.

    :param sweep: the settings swept
    :return: ``(parameter name, value, configuration update)`` per run
    """
    runs: list[tuple[str, Any, dict[str, Any]]] = []
    for name, key, values in sweep:
        runs += [(name, v, dotted_tree(key, v)) for v in values]
    stress: dict[str, Any] = {}
    for key, v in UPLINK_STRESS.items():
        stress = deep_merge(stress, dotted_tree(key, v))
    runs.append(("latency_0.3s_at_1hz", "0.3 s, 1 Hz", stress))
    return runs


def episode_steps(config: DTConfig) -> int:
    """Policy steps one evaluation episode takes, the pre-roll counted (for progress bars).

    :param config: resolved configuration
    :return: the policy steps
    """
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
        raise ConfigError("scoring the twin needs twin.enabled = true")
    if not config.traffic.driver_types:
        raise ConfigError("scoring the twin needs traffic.driver_types = true (stock traffic has no driver types to score)")
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
        latent_median = _latent_median(population)
    finally:
        env.close()
    result = _result(score, times_to_tag, untagged_aggressive, cfg, episodes, seed)
    if latent_median is None:
        return result
    ranks = _ranking_scores(score.ranked, latent_median)
    ranks["ceiling"] = population_ceiling(cfg, seed=seed)
    at = list(result).index("episodes")  # beside the other scores
    items = list(result.items())
    return dict(items[:at] + list(ranks.items()) + items[at:])


CEILING_DRIVERS = 40_000
"""Drivers drawn for :func:`population_ceiling` (half to fit the combination, half to score it)"""


def population_ceiling(config: DTConfig, drivers: int = CEILING_DRIVERS, seed: int = 0) -> dict[str, float]:
    """What a tagger that knew every driver's true parameters could score on the continuum.

    Draws ``drivers`` drivers of ``config.traffic.continuum`` (:func:`~dt_highway.world.continuum.draw_traits`),
    labels the top ``traffic.aggressive_fraction`` by latent score, fits the least-squares linear
    combination of the parameters (the logarithm of the log-normal ones: the copula values up to
    clipping, for which the posterior mean of the latent score is linear) to the latent score on one
    half, and ranks the other half by it. A ceiling for the twin, which sees about two minutes of
    noisy fixes instead of the parameters.

    :param config: the configuration (its ``traffic`` section)
    :param drivers: drivers drawn, >= 100
    :param seed: random seed
    :return: ``auc_label`` and ``precision_at_recall_0_80`` of that ranking on the held-out half, ``drivers``
    """
    if drivers < 100:
        raise ValueError(f"drivers must be >= 100 (got {drivers})")
    rng = np.random.default_rng(seed)
    z = rng.standard_normal(drivers)
    values = draw_traits(config.traffic.continuum, z, rng)
    traits = config.traffic.continuum.traits()
    cols = [v if isinstance(traits[k], NormalTrait) else np.log(v) for k, v in values.items()]
    design = np.column_stack([*cols, np.ones(drivers)])
    label = top_share(z, config.traffic.aggressive_fraction)
    half = drivers // 2
    weights, *_ = np.linalg.lstsq(design[:half], z[:half], rcond=None)
    score = design[half:] @ weights
    return {
        "auc_label": auc(score, label[half:]),
        "precision_at_recall_0_80": precision_at_recall(score, label[half:], 0.80)[0],
        "drivers": float(drivers),
    }


def _latent_median(population: DriverPopulation) -> float | None:
    """The median latent aggressiveness of a driver population.

    :return: the median latent score of the population, ``None`` when it has none (two-class)
    """
    z = [d.aggressiveness for d in population.drivers.values() if d.aggressiveness is not None]
    return float(np.median(z)) if z else None


def auc(scores: np.ndarray, positive: np.ndarray) -> float:
    """ROC AUC of ``scores`` for the boolean labels ``positive``: the Mann-Whitney ``U / (n1 n2)``
    (the probability that a positive outscores a negative, ties counted one half).

    :param scores: one score per sample
    :param positive: the samples' labels (bool)
    :return: the AUC, NaN when either class is empty
    """
    from scipy.stats import mannwhitneyu  # lazy: heavy (scipy.stats, ~0.35 s), twin-eval on the continuum only

    pos, neg = scores[positive], scores[~positive]
    if len(pos) == 0 or len(neg) == 0:
        return float("nan")
    return float(mannwhitneyu(pos, neg).statistic) / (len(pos) * len(neg))


def precision_at_recall(scores: np.ndarray, positive: np.ndarray, min_recall: float) -> tuple[float, float, float]:
    """The best precision of the rule ``score >= threshold`` over the thresholds (the distinct scores)
    whose recall is at least ``min_recall``.

    :param scores: one score per sample
    :param positive: the samples' labels (bool)
    :param min_recall: the least recall [-]
    :return: precision, threshold and recall there (NaNs when there are no positives)
    """
    n_pos = int(positive.sum())
    if n_pos == 0:
        return float("nan"), float("nan"), float("nan")
    order = np.argsort(-scores, kind="stable")
    s, y = scores[order], positive[order]
    tp, fp = np.cumsum(y), np.cumsum(~y)
    last = np.r_[s[1:] != s[:-1], True]  # the last of each group of equal scores: a threshold
    tp, fp, thresholds = tp[last], fp[last], s[last]
    recall, precision = tp / n_pos, tp / (tp + fp)
    ok = np.flatnonzero(recall >= min_recall)  # never empty: the lowest threshold has recall 1
    best = int(ok[np.argmax(precision[ok])])  # the first (highest threshold) of the best
    return float(precision[best]), float(thresholds[best]), float(recall[best])


def _ranking_scores(ranked: list[tuple[float, bool, float]], latent_median: float) -> dict[str, Any]:
    """The continuum's ranking scores (see the module docstring)."""
    from scipy.stats import spearmanr  # lazy: heavy (scipy.stats, ~0.35 s), twin-eval on the continuum only

    p = np.array([r[0] for r in ranked], dtype=float)
    label = np.array([r[1] for r in ranked], dtype=bool)
    z = np.array([r[2] for r in ranked], dtype=float)
    precision, threshold, recall = precision_at_recall(p, label, 0.80)
    rho = float(spearmanr(p, z).statistic) if len(p) >= 2 and np.ptp(p) > 0 else float("nan")
    return {
        "population": "continuum",
        "auc_label": auc(p, label),
        "auc_latent_above_median": auc(p, z > latent_median),
        "spearman_latent": rho,
        "precision_at_recall_0_80": precision,
        "threshold_at_recall_0_80": threshold,
        "recall_at_threshold": recall,
        "latent_median": latent_median,
        "n_ranked": len(p),
    }


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
    ranked: list[tuple[float, bool, float]] = field(default_factory=list)
    """Continuum judgements: (the twin's probability of aggressive, the label, the latent score)"""

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
        if driver.aggressiveness is not None:
            p_aggressive = rec.confidence if tagged else 1.0 - rec.confidence
            self.ranked.append((p_aggressive, truly, driver.aggressiveness))


def _times_to_tag(records: dict[int, DriverRecord], population: DriverPopulation,
                  min_observed_s: float) -> tuple[list[float], int]:
    """How long the twin took to tag the truly aggressive drivers.

    :return: the truly aggressive drivers' times from first analysis to first aggressive tag [s], and how
        many of those observed at least ``min_observed_s`` were never tagged
    """
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
        "settings": uplink_settings(cfg),
    }

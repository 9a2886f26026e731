"""Fitting the twin's evidence tagger (``dt-highway train-tagger``; ``twin.tagger.model = "evidence"``).

Data: episodes of the configured world (the continuum of drivers by default), ``episodes`` per
training seed, the ego on its autopilot, as in ``twin-eval``: at each episode's end every connected
driver the twin has observed for at least ``min_observed_s`` is one sample, its
:func:`~dt_highway.twin.tagger.evidence_features` against its true label (ground truth: the top
``traffic.aggressive_fraction`` by latent score). The features are tallies of what the twin received;
the tag the twin gave during collection plays no part (collection runs a neutral model).

Model: :class:`~dt_highway.twin.tagger.EvidenceModel`, a logistic regression on the standardised
features with an L2 penalty ``l2`` on the weights (not the intercept), fitted by L-BFGS
(``scipy.optimize.minimize``; scikit-learn is not a dependency). Deterministic: the same seeds write
the same weights. Held-out scoring is ``dt-highway twin-eval`` on other seeds (100 in the docs).
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import minimize

from dt_highway.config import ConfigError, DTConfig, merge
from dt_highway.env import DTHighwayEnv
from dt_highway.evaluation.twin import _run_episode, auc, episode_steps
from dt_highway.labels import AGGRESSIVE
from dt_highway.twin.tagger import EVIDENCE_FEATURES, EvidenceModel, evidence_features
from dt_highway.world.traffic import EGO_ID


def collect(config: DTConfig, seeds: Sequence[int], episodes: int, min_observed_s: float = 30.0,
            progress: Callable[[int], None] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The evidence features and labels of the drivers of ``episodes`` episodes per seed.

    :param config: resolved configuration (``ego.autopilot`` and the evidence model are switched on)
    :param seeds: training seeds (the first reset of each; its later episodes continue its random streams)
    :param episodes: episodes per seed, >= 1
    :param min_observed_s: drivers observed for less than this are left out [s]
    :param progress: called with policy steps simulated (see :func:`~dt_highway.evaluation.twin.episode_steps`)
    :return: features ``(N, len(EVIDENCE_FEATURES))`` and labels ``(N,)`` (True: aggressive)
    """
    if episodes < 1 or not seeds:
        raise ValueError(f"need >= 1 episode and >= 1 seed (got {episodes} episodes, {len(seeds)} seeds)")
    if not config.twin.enabled or not config.traffic.driver_types:
        raise ConfigError("train-tagger needs twin.enabled = true and traffic.driver_types = true")
    xs: list[np.ndarray] = []
    ys: list[bool] = []
    with tempfile.TemporaryDirectory() as tmp:
        neutral = Path(tmp) / "neutral.json"
        n = len(EVIDENCE_FEATURES)
        EvidenceModel(np.zeros(n), np.ones(n), np.zeros(n), 0.0).save(neutral)
        cfg = merge(config, {"ego": {"autopilot": True},
                             "twin": {"tagger": {"model": "evidence", "evidence_weights": str(neutral)}}})
        for seed in seeds:
            env = DTHighwayEnv(config=cfg.to_dict())
            try:
                for ep in range(episodes):
                    seen = _run_episode(env, seed if ep == 0 else None, cfg, progress)
                    if env.twin is None or env.population is None:
                        raise RuntimeError("train-tagger needs the env's twin and driver population")
                    records, population = env.twin.tagger.records, env.population
                    for vid in sorted(seen):
                        rec = records.get(vid)
                        if vid == EGO_ID or vid not in population.drivers or rec is None:
                            continue
                        if not population[vid].connected or rec.observed_s < min_observed_s:
                            continue
                        xs.append(evidence_features(rec))
                        ys.append(population[vid].driver_type == AGGRESSIVE)
            finally:
                env.close()
    return np.array(xs).reshape(-1, len(EVIDENCE_FEATURES)), np.array(ys, dtype=bool)


def fit(features: np.ndarray, labels: np.ndarray, l2: float = 1.0) -> EvidenceModel:
    """The L2-penalised logistic regression of ``labels`` on the standardised ``features``.

    :param features: ``(N, F)``
    :param labels: ``(N,)`` booleans, both classes present
    :param l2: penalty on the squared weights (the intercept is free), >= 0
    :return: the fitted model
    :raises ValueError: one line, when a class is missing
    """
    y = labels.astype(float)
    if not 0 < y.sum() < len(y):
        raise ValueError(f"train-tagger needs drivers of both classes (got {int(y.sum())} aggressive of {len(y)})")
    mean, scale = features.mean(axis=0), features.std(axis=0)
    scale = np.where(scale > 1e-9, scale, 1.0)
    a = (features - mean) / scale

    def loss(w: np.ndarray) -> tuple[float, np.ndarray]:
        s = a @ w[:-1] + w[-1]
        p = 1.0 / (1.0 + np.exp(-s))
        value = float(np.sum(np.logaddexp(0.0, s) - y * s) + 0.5 * l2 * np.sum(w[:-1] ** 2))
        grad = np.append(a.T @ (p - y) + l2 * w[:-1], np.sum(p - y))
        return value, grad

    w = minimize(loss, np.zeros(a.shape[1] + 1), jac=True, method="L-BFGS-B").x
    return EvidenceModel(mean, scale, w[:-1], float(w[-1]))


def train_tagger(config: DTConfig, seeds: Sequence[int], episodes: int, out: str | Path, l2: float = 1.0,
                 progress: Callable[[int], None] | None = None) -> dict[str, Any]:
    """Collect, fit, write the weights to ``out``.

    :param config: resolved configuration (as :func:`collect` takes it)
    :param seeds: training seeds (:func:`collect`)
    :param episodes: episodes per seed, >= 1
    :param out: the weights file to write
    :param l2: penalty on the squared weights (:func:`fit`), >= 0
    :param progress: called with policy steps simulated
    :return: the training summary (samples, aggressive ones, training AUC, seeds), also stored in the file
    """
    features, labels = collect(config, seeds, episodes, progress=progress)
    model = fit(features, labels, l2)
    scores = np.array([model.probability(f) for f in features])
    summary = {"samples": len(labels), "aggressive": int(labels.sum()), "train_auc": auc(scores, labels),
               "seeds": list(seeds), "episodes_per_seed": episodes, "l2": l2,
               "population": config.traffic.population}
    model.save(out, training=summary)
    return summary


def training_steps(config: DTConfig, seeds: Sequence[int], episodes: int) -> int:
    """Policy steps :func:`collect` simulates (for a progress bar).

    :param config: resolved configuration
    :param seeds: training seeds
    :param episodes: episodes per seed
    :return: the policy steps
    """
    return len(seeds) * episodes * episode_steps(config)

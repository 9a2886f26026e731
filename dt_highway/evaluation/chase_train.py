"""Training and scoring of the twin's chase detector (``dt-highway train-chase``).

Data: episodes of the configured world (the trial scenario by default), one per seed (``seed0``,
``seed0 + 1``, ...; each a fresh world, the ego on its autopilot in a lane drawn per episode),
recorded by :func:`~dt_highway.evaluation.intent.record_episodes` with ``chase=True``: at every
intention estimate of the cloud, the detector's inputs for every connected vehicle
(:func:`~dt_highway.twin.chase.chase_inputs`, the cloud's data only) and, as the label, whether the
simulator had that driver chasing the ego (an open cut-in attempt that has set its speed to reach
the window just ahead of the ego). Model: :class:`~dt_highway.twin.chase.ChaseDetector`, fitted
with Adam on the logistic loss, on one CPU thread with fixed seeds (the same command writes the same
weights). Scored on other seeds (5000 on by default, away from every other command's seeds): ROC AUC,
precision and recall at :data:`SCORE_THRESHOLDS`, for every vehicle and for those near the ego (in
its lane or a neighbouring one, within :data:`NEAR_M`).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from dt_highway.choices import SCORE_THRESHOLDS, TEST_SEED
from dt_highway.choices import TRAIN_SEED as TRAIN_SEED  # re-exported: its home before dt_highway.choices
from dt_highway.config import DTConfig
from dt_highway.evaluation.intent import Episode, record_episodes
from dt_highway.evaluation.intent_train import numpy_layers, train_epochs
from dt_highway.evaluation.twin import auc
from dt_highway.twin.chase import CHASE_FEATURES, HIDDEN, ChaseDetector, ChaseInputs, save_chase_weights

NEAR_M = 200.0
"""'Near the ego': in its lane or a neighbouring one, within this distance along the road (the trial world's cut-in
search range) [m]"""


def chase_dataset(episodes: list[Episode]) -> tuple[np.ndarray, np.ndarray]:
    """The chase data set of recorded episodes.

    :param episodes: episodes recorded with ``chase=True``
    :return: the inputs ``(M, F)`` and labels ``(M,)`` (bool) of every recorded chase sample
    """
    xs = [inputs.x for ep in episodes for inputs, _ in (ep.chase or []) if len(inputs)]
    ys = [y for ep in episodes for inputs, y in (ep.chase or []) if len(inputs)]
    if not xs:
        return np.zeros((0, len(CHASE_FEATURES))), np.zeros(0, dtype=bool)
    return np.concatenate(xs), np.concatenate(ys)


def fit_chase(x: np.ndarray, y: np.ndarray, epochs: int = 12, batch: int = 512, lr: float = 2e-3, seed: int = 0,
              hidden: int = HIDDEN, progress: Callable[[int], None] | None = None,
              ) -> tuple[np.ndarray, np.ndarray, list[tuple[np.ndarray, np.ndarray]], list[float]]:
    """Fit the detector's perceptron on the logistic loss.

    :param x: the inputs ``(M, F)``
    :param y: the labels ``(M,)`` (bool: chasing)
    :param epochs: passes over the data
    :param batch: samples per optimiser step
    :param lr: Adam's learning rate
    :param seed: seeds torch's initial weights and the batches' order
    :param hidden: units in each of the two hidden layers
    :param progress: called with 1 after each epoch
    :return: input mean, input scale, layers ``(W, b)`` (``W`` as ``(in, out)``) and the loss of each epoch
    """
    import torch  # lazy: training only (the twin runs the detector in numpy)

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        torch.manual_seed(seed)
        mean = x.mean(axis=0)
        scale = x.std(axis=0)
        scale = np.where(scale > 1e-6, scale, 1.0)
        xt = torch.from_numpy(((x - mean) / scale).astype(np.float32))
        yt = torch.from_numpy(y.astype(np.float32))
        net = torch.nn.Sequential(torch.nn.Linear(x.shape[1], hidden), torch.nn.Tanh(),
                                  torch.nn.Linear(hidden, hidden), torch.nn.Tanh(), torch.nn.Linear(hidden, 1))
        opt = torch.optim.Adam(net.parameters(), lr=lr)
        gen = torch.Generator().manual_seed(seed)
        losses = train_epochs(opt, len(xt), epochs, batch, gen, lambda idx: (
            torch.nn.functional.binary_cross_entropy_with_logits(net(xt[idx])[:, 0], yt[idx]), len(idx)),
            progress=progress)
        layers = numpy_layers(net)
    finally:
        torch.set_num_threads(threads)
    return mean, scale, layers, losses


def near_ego(x: np.ndarray) -> np.ndarray:
    """The mask of the chase samples near the ego.

    :param x: chase inputs ``(M, F)``, columns of :data:`~dt_highway.twin.chase.CHASE_FEATURES`
    :return: which rows of chase inputs are near the ego (:data:`NEAR_M`, its lane or a neighbouring one)
    """
    dx = x[:, CHASE_FEATURES.index("dx_0s")] * 50.0
    far = x[:, CHASE_FEATURES.index("ego_far_lane")] > 0
    return ~far & (np.abs(dx) < NEAR_M)


def _scores(p: np.ndarray, y: np.ndarray) -> dict[str, Any]:
    out: dict[str, Any] = {"samples": int(len(y)), "chasing": int(y.sum()),
                           "auc": auc(p, y)}
    for th in SCORE_THRESHOLDS:
        hit = p >= th
        out[f"precision_at_{th:g}"] = float(y[hit].mean()) if hit.any() else float("nan")
        out[f"recall_at_{th:g}"] = float(hit[y].mean()) if y.any() else float("nan")
    return out


def score_chase(detector: ChaseDetector, x: np.ndarray, y: np.ndarray) -> dict[str, Any]:
    """Score a chase detector on labelled inputs.

    :param detector: the detector scored
    :param x: chase inputs ``(M, F)``
    :param y: their labels ``(M,)`` (bool: chasing)
    :return: AUC, precision and recall of ``detector`` on labelled inputs, for all and for those near the ego
    """
    p = detector.predict(ChaseInputs(np.arange(len(x)), 0.0, x))
    near = near_ego(x)
    return {"all": _scores(p, y), "near_ego": _scores(p[near], y[near])}


def train_chase(config: DTConfig, episodes: int, seed0: int, out: str | Path, epochs: int = 12,
                test_episodes: int = 0, test_seed: int = TEST_SEED,
                progress: Callable[[str, int], None] | None = None) -> dict[str, Any]:
    """Record training episodes, fit the detector, write the weights and score them on held-out episodes.

    :param config: resolved configuration (the world the data comes from)
    :param episodes: training episodes, one per seed ``seed0 + i``
    :param seed0: the first training seed
    :param out: the ``.npz`` file to write
    :param epochs: passes over the data
    :param test_episodes: held-out episodes to score on (0: none)
    :param test_seed: their first seed (keep it out of the training seeds)
    :param progress: called with ``("record", policy steps)`` and ``("fit", 1)`` per epoch
    :return: a summary (samples, chasing share, losses, held-out scores)
    """
    if episodes < 1:
        raise ValueError(f"episodes must be >= 1 (got {episodes})")
    if test_episodes < 0:
        raise ValueError(f"test episodes must be >= 0 (got {test_episodes})")
    seeds = [seed0 + i for i in range(episodes)]
    tests = [test_seed + i for i in range(test_episodes)]
    if set(seeds) & set(tests):
        raise ValueError(f"the held-out seeds {tests[0]}-{tests[-1]} overlap the training seeds {seeds[0]}-{seeds[-1]}: "
                         "move the held-out seeds or the training seeds")
    step = (lambda n: progress("record", n)) if progress else None
    x, y = chase_dataset(record_episodes(config, seeds, progress=step, chase=True))
    if not y.any():
        raise ValueError("no driver chased the ego in the training episodes: nothing to learn from (is traffic.cut_in_"
                         "rate_per_min 0, or the aggressive share?)")
    mean, scale, layers, losses = fit_chase(x, y, epochs=epochs, progress=(lambda n: progress("fit", n)) if progress else None)
    save_chase_weights(out, mean, scale, layers,
                       {"seeds": f"{seeds[0]}-{seeds[-1]}", "epochs": str(epochs), "samples": str(len(y))})
    summary: dict[str, Any] = {"out": str(out), "seeds": [seeds[0], seeds[-1]], "samples": int(len(y)),
                               "chasing_share": float(y.mean()), "losses": [round(v, 5) for v in losses]}
    if tests:
        xt, yt = chase_dataset(record_episodes(config, tests, progress=step, chase=True))
        summary["held_out"] = {"seeds": [tests[0], tests[-1]], **score_chase(ChaseDetector.load(out), xt, yt)}
    return summary

"""Training of the twin's learned lane-change intention model (``dt-highway train-intent``).

Data: episodes of the configured world (the trial scenario by default), one per training seed
(``seed0``, ``seed0 + 1``, ...; each a fresh world), pre-roll included, recorded by
:func:`~dt_highway.evaluation.intent.record_episodes`: the inputs of every second intention
estimate the cloud made (what the model sees in service), labelled from the simulator's truth
(the vehicle's lane ``H`` seconds on, for each trained horizon). A sample whose lane change ends
in a lane that is not a neighbour of the lane the twin placed it in (the twin's lane and the
truth disagree near a boundary), or whose track ends before ``H``, is left out at that horizon.

Model: :class:`~dt_highway.twin.intention.LearnedIntention` (the choice model of the module
docstring there), trained with Adam on the negative log-likelihood of the three alternatives at
every trained horizon, on one CPU thread with fixed seeds, so that the same command writes the
same weights. Evaluation seeds (``twin-eval --intent``, seed 0 and its world by default) are not
among the training seeds (1000 on by default).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from dt_highway.config import DTConfig, merge
from dt_highway.drivers import Driver
from dt_highway.evaluation.intent import Episode, Truth, record_episodes
from dt_highway.twin.intention import HIDDEN, OWN_FEATURES, SIDE_FEATURES, save_weights

if TYPE_CHECKING:
    import torch

TRAINED_HORIZONS_S = (0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0)
"""The horizons the network answers for (others are interpolated) [s]"""
TABLE_STRIDE = 2
"""Every this-many-th intention estimate is a training sample (consecutive ones are nearly the same)"""
N_FEATURES = len(OWN_FEATURES) + len(SIDE_FEATURES)
EGO_WEIGHT = 10.0
"""Loss weight of the samples near the ego (see :func:`sample_weights`)"""
EGO_RANGE_M = 80.0
"""Vehicles this close to the ego along the road, in its lane or a neighbouring one, are near it [m]"""


def dataset(episodes: list[Episode], horizons_s: tuple[float, ...] = TRAINED_HORIZONS_S) -> dict[str, np.ndarray]:
    """Inputs and labels of the recorded estimates.

    :param episodes: episodes recorded with their pre-roll (:func:`~dt_highway.evaluation.intent.record_episodes`)
    :param horizons_s: the horizons labelled [s]
    :return: ``x`` ``(M, 2, F)`` float32 (own inputs repeated beside each side's), ``side_ok`` ``(M, 2)``,
        ``y`` ``(M, H)`` int8: 0 stay, 1 left, 2 right, -1 left out
    """
    xs, oks, ys = [], [], []
    for ep in episodes:
        truth = Truth(ep.truth, ep.dt_s)
        for t, inputs in ep.tables[::TABLE_STRIDE]:
            n = len(inputs)
            if n == 0:
                continue
            tt = np.full(n, t)
            rows = truth.rows_at(inputs.vehicle_ids, tt)
            y = np.full((n, len(horizons_s)), -1, dtype=np.int8)
            for k, h in enumerate(horizons_s):
                known, changed, new_lane = truth.labels(rows, tt, h)
                y[known & ~changed, k] = 0
                y[changed & (new_lane == inputs.lane - 1), k] = 1
                y[changed & (new_lane == inputs.lane + 1), k] = 2
            keep = (y >= 0).any(axis=1)
            x = np.concatenate([np.repeat(inputs.own[:, None, :], 2, axis=1), inputs.side], axis=2)
            xs.append(x[keep].astype(np.float32))
            oks.append(inputs.side_ok[keep])
            ys.append(y[keep])
    if not xs:
        return {"x": np.zeros((0, 2, N_FEATURES), np.float32), "side_ok": np.zeros((0, 2), bool),
                "y": np.zeros((0, len(horizons_s)), np.int8)}
    return {"x": np.concatenate(xs), "side_ok": np.concatenate(oks), "y": np.concatenate(ys)}


Layers = list[tuple[np.ndarray, np.ndarray]]
"""``(W, b)`` of each layer, ``W`` as ``(in, out)``"""


def fit(data: dict[str, np.ndarray], epochs: int = 25, batch: int = 1024, lr: float = 3e-3, seed: int = 0,
        hidden: int = HIDDEN, progress: Callable[[int], None] | None = None,
        ) -> tuple[np.ndarray, np.ndarray, Layers, list[float]]:
    """Train the network on a :func:`dataset`.

    :param data: the arrays :func:`dataset` returns
    :param epochs: passes over the data
    :param batch: samples per optimiser step
    :param lr: Adam's initial learning rate (cosine-annealed to 0 over the epochs)
    :param seed: seeds torch's initial weights and the batches' order
    :param hidden: units in each of the two hidden layers
    :param progress: called with 1 after each epoch
    :return: input mean, input scale, layers ``(W, b)`` (numpy, ``W`` as ``(in, out)``) and the loss of each epoch
    """
    import torch  # lazy: training only (the twin runs the network in numpy)

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        torch.manual_seed(seed)
        x = data["x"].reshape(-1, N_FEATURES).astype(np.float64)
        mean = x.mean(axis=0)
        scale = x.std(axis=0)
        scale = np.where(scale > 1e-6, scale, 1.0)
        xt = torch.from_numpy(((data["x"] - mean) / scale).astype(np.float32))
        ok = torch.from_numpy(data["side_ok"])
        y = torch.from_numpy(data["y"].astype(np.int64))
        weight = torch.from_numpy(sample_weights(data["x"]).astype(np.float32))
        n_h = y.shape[1]
        net = torch.nn.Sequential(
            torch.nn.Linear(N_FEATURES, hidden), torch.nn.Tanh(),
            torch.nn.Linear(hidden, hidden), torch.nn.Tanh(),
            torch.nn.Linear(hidden, n_h),
        )
        opt = torch.optim.Adam(net.parameters(), lr=lr)
        sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=max(epochs, 1))
        gen = torch.Generator().manual_seed(seed)
        losses = train_epochs(opt, len(xt), epochs, batch, gen,
                              lambda idx: _nll(net, xt[idx], ok[idx], y[idx], weight[idx]), sched, progress)
        layers = numpy_layers(net)
    finally:
        torch.set_num_threads(threads)
    return mean, scale, layers, losses


def train_epochs(opt: torch.optim.Optimizer, n_samples: int, epochs: int, batch: int, gen: torch.Generator,
                 batch_loss: Callable[[torch.Tensor], tuple[torch.Tensor, int]],
                 sched: torch.optim.lr_scheduler.LRScheduler | None = None,
                 progress: Callable[[int], None] | None = None) -> list[float]:
    """Adam-style minibatch training: each epoch a fresh permutation from ``gen``, one optimiser step per batch.

    :param opt: the optimiser of the network's parameters
    :param n_samples: how many samples the data hold (the permutation's length)
    :param epochs: passes over the data
    :param batch: samples per optimiser step
    :param gen: the seeded generator of the permutations
    :param batch_loss: the loss of a batch of sample indices and the number of terms it averages
    :param sched: a learning-rate scheduler stepped after each epoch (``None``: none)
    :param progress: called with 1 after each epoch
    :return: the mean loss of each epoch (weighted by the batches' terms)
    """
    import torch  # lazy: training only, as in fit

    losses = []
    for _ in range(epochs):
        order = torch.randperm(n_samples, generator=gen)
        total, count = 0.0, 0
        for start in range(0, len(order), batch):
            loss, n = batch_loss(order[start:start + batch])
            opt.zero_grad()
            loss.backward()
            opt.step()
            total += float(loss.detach()) * n
            count += n
        if sched is not None:
            sched.step()
        losses.append(total / max(count, 1))
        if progress is not None:
            progress(1)
    return losses


def numpy_layers(net: torch.nn.Sequential) -> Layers:
    """The weights of a torch network as numpy arrays.

    :param net: the network
    :return: the ``(W, b)`` of each linear layer of a torch ``Sequential``, as float64 numpy (``W`` as ``(in, out)``)
    """
    import torch  # lazy: training only, as in fit

    return [(m.weight.detach().numpy().T.astype(np.float64).copy(), m.bias.detach().numpy().astype(np.float64).copy())
            for m in net if isinstance(m, torch.nn.Linear)]


def sample_weights(x: np.ndarray) -> np.ndarray:
    """Weight of each sample in the loss: ``EGO_WEIGHT`` for a vehicle within ``EGO_RANGE_M`` of the ego in its
    lane or a neighbouring one (the cut-ins a driver is warned of are among these few), else 1.

    :param x: ``(M, 2, F)`` inputs of :func:`dataset`
    :return: one weight per sample ``(M,)``
    """
    near_same = (x[:, 0, OWN_FEATURES.index("ego_same_lane")] > 0) & (np.abs(x[:, 0, OWN_FEATURES.index("ego_dx_same")]) * 50
                                                                      < EGO_RANGE_M)
    side = len(OWN_FEATURES)
    in_side = x[:, :, side + SIDE_FEATURES.index("ego_in_side")] > 0
    dx_side = np.abs(x[:, :, side + SIDE_FEATURES.index("ego_dx_side")]) * 50
    near_side = (in_side & (dx_side < EGO_RANGE_M)).any(axis=1)
    return np.where(near_same | near_side, EGO_WEIGHT, 1.0)


def _nll(net: Any, x: Any, ok: Any, y: Any, weight: Any) -> tuple[Any, int]:
    """Weighted mean negative log-likelihood of the labelled (horizon, sample) pairs of a batch, and their number."""
    import torch  # lazy: training only, as in fit

    b = x.shape[0]
    raw = net(x.reshape(2 * b, -1)).reshape(b, 2, -1)
    z = torch.cumsum(torch.cat([raw[:, :, :1], torch.nn.functional.softplus(raw[:, :, 1:])], dim=2), dim=2)
    z = torch.where(ok[:, :, None], z, torch.full_like(z, -1e9))
    logits = torch.cat([torch.zeros_like(z[:, :1]), z], dim=1)  # (B, 3, H)
    logp = torch.log_softmax(logits, dim=1)
    mask = (y >= 0) * weight[:, None]
    picked = torch.gather(logp, 1, y.clamp(min=0)[:, None, :])[:, 0]  # (B, H)
    n = int((y >= 0).sum())
    return -(picked * mask).sum() / mask.sum().clamp(min=1e-9), n


def train_intention(
    config: DTConfig,
    episodes: int,
    seed0: int,
    out: str | Path,
    epochs: int = 25,
    alternate: dict[str, Any] | None = None,
    progress: Callable[[str, int], None] | None = None,
    driver: Driver | None = None,
) -> dict[str, Any]:
    """Record training episodes, fit the network, write the weights.

    :param config: resolved configuration (the world the data comes from)
    :param episodes: training episodes, one per seed ``seed0 + i`` (each a fresh world)
    :param seed0: the first training seed (keep evaluation seeds out of ``seed0 .. seed0 + episodes - 1``)
    :param out: the ``.npz`` file to write
    :param epochs: passes over the data
    :param alternate: a partial configuration the odd seeds also take (a mix of two worlds, e.g. with the
        dangerous cut-in), ``None`` for one world
    :param progress: called with ``("record", policy steps)`` and ``("fit", 1)`` per epoch
    :param driver: the ego's driver in the recordings (``config`` merged with its condition and overrides);
        ``None``: the autopilot
    :return: a summary (samples, label counts, losses, seeds)
    :raises ValueError: on ``episodes`` < 1, or when the recordings hold no lane change to learn from
    """
    if episodes < 1:
        raise ValueError(f"episodes must be >= 1 (got {episodes})")
    seeds = [seed0 + i for i in range(episodes)]
    step = (lambda n: progress("record", n)) if progress else None
    if alternate:
        recorded = record_episodes(config, seeds[::2], with_preroll=True, progress=step, driver=driver)
        recorded += record_episodes(merge(config, alternate), seeds[1::2], with_preroll=True, progress=step,
                                    driver=driver)
    else:
        recorded = record_episodes(config, seeds, with_preroll=True, progress=step, driver=driver)
    data = dataset(recorded)
    if len(data["y"]) == 0 or not ((data["y"] == 1) | (data["y"] == 2)).any():
        raise ValueError(f"no lane change in {len(data['y'])} estimates of seeds {seeds[0]}-{seeds[-1]}: nothing to "
                         "learn from (are there connected vehicles: highway.vehicles_count, twin.enabled?)")
    mean, scale, layers, losses = fit(data, epochs=epochs, hidden=HIDDEN,
                                      progress=(lambda n: progress("fit", n)) if progress else None)
    meta = {"seeds": f"{seeds[0]}-{seeds[-1]}", "epochs": str(epochs), "samples": str(len(data["y"])),
            "alternate": json.dumps(alternate or {}, sort_keys=True)}
    if driver is not None:
        meta["driver"] = driver.name
    save_weights(out, TRAINED_HORIZONS_S, mean, scale, layers, meta)
    y = data["y"]
    return {
        "out": str(out),
        "seeds": [seeds[0], seeds[-1]],
        "samples": int(len(y)),
        "positives_per_horizon": {f"{h:g}s": int(((y[:, k] == 1) | (y[:, k] == 2)).sum())
                                  for k, h in enumerate(TRAINED_HORIZONS_S)},
        "losses": [round(v, 5) for v in losses],
        "final_loss": losses[-1] if losses else math.nan,
    }

"""Who is chasing the ego: the twin's estimate that a driver has a cut-in attempt open on the ego.

In the trial world an aggressive driver's cut-in attempt opens with nothing to see before it, and
while it is open a driver near the ego sets its speed to reach the window just ahead of it (the
*chase*): faster than the ego from behind, about its speed beside it, slower when too far ahead. The
chase is what makes a cut-in foreseeable seconds ahead (an oracle that knows who is chasing the ego
foresees the cut-ins about 2.5 s ahead, one that does not 1.3 s: ``docs/reproduction/twin-intention.md``),
and it shows in the fixes only as a history of speeds and gaps relative to the ego. This module
estimates, for every connected vehicle, the probability that its driver is chasing the ego, from
what the cloud has received only (the :class:`~dt_highway.twin.store.FixStore`, the tagger's records,
the map); like :mod:`~dt_highway.twin.intention` it reads neither the world, the env nor the evaluation.

**Inputs** (:func:`chase_inputs`, named in :data:`CHASE_FEATURES`): the tagger's posterior that the
driver is aggressive; where its lane is relative to the ego's (the same, next to it, further); its and
the ego's speed; and, at each lag of :data:`CHASE_LAGS_S` (now, 1, 2, 3, 4, 6 s ago), its position
along the road and speed relative to the ego's at that time (each the mean of the fixes of the 0.5 s
before, positions moved to that time at their speed); its own speed change over the last 2 s and over
the 2 s before. The chase law itself is not written in: the network learns from the gaps and speed
differences what chasing looks like (a hand-written law as an extra input was tried: AUC 0.971 against
0.966 near the ego, not worth tying the twin to the simulator's constants).

**Model**: a two-layer tanh perceptron (:data:`HIDDEN` units) with a logistic output, trained by
:func:`dt_highway.evaluation.chase_train.train_chase` (``dt-highway train-chase``) on simulated fixes from
training seeds with the simulator's chase state as the label; weights shipped (``chase_weights.npz``, read
with ``allow_pickle=False``), inference in numpy.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from dt_highway.twin.intention import p_aggressive
from dt_highway.twin.weights import Layers, read_weights, write_weights

if TYPE_CHECKING:
    from dt_highway.twin.store import FixStore
    from dt_highway.twin.tagger import DriverRecord, HighwayMap

CHASE_LAGS_S = (0.0, 1.0, 2.0, 3.0, 4.0, 6.0)
"""The times before now at which the positions and speeds relative to the ego are taken [s]"""
LAG_WINDOW_S = 0.5
"""Each lag's position and speed: the mean over the fixes of this long before it [s]"""
MAX_AGE_S = 2.0
"""A vehicle whose last fix is older than this is not judged [s]"""
HIDDEN = 32
"""Hidden units per layer"""
WEIGHTS_FILE = "chase_weights.npz"
"""The shipped weights, in this package"""

CHASE_FEATURES = (
    "p_aggressive",  # the tagger's posterior that the driver is aggressive [-]
    "ego_same_lane",  # 1 when the ego is in its lane
    "ego_next_lane",  # 1 when the ego is in a neighbouring lane
    "ego_far_lane",  # 1 when the ego is two or more lanes away
    "speed",  # own speed / 30 [m/s]
    "ego_speed",  # the ego's speed / 30 [m/s]
    *(f"{name}_{lag:g}s" for lag in CHASE_LAGS_S for name in ("dx", "dv", "seen")),
    # dx: (own x - ego x) / 50, clipped to [-4, 4] [m]; dv: (own speed - ego speed) / 5, clipped to [-3, 3] [m/s];
    # seen: 1 when both had fixes then (else dx = dv = 0)
    "speed_change_2s",  # own speed now minus 2 s ago / 2, clipped to [-3, 3] [m/s]
    "speed_change_2_4s",  # own speed 2 s ago minus 4 s ago / 2, clipped to [-3, 3] [m/s]
)
"""The detector's inputs, in order (each with its scale)"""


@dataclass(frozen=True)
class ChaseInputs:
    """The detector's inputs for every judged vehicle (the ego left out).

    :param vehicle_ids: the vehicles, ``(N,)``
    :param t_s: twin time [s]
    :param x: ``(N, len(CHASE_FEATURES))`` inputs
    """

    vehicle_ids: np.ndarray
    t_s: float
    x: np.ndarray

    def __len__(self) -> int:
        return len(self.vehicle_ids)


def _at_lags(history: np.ndarray, now_s: float) -> np.ndarray:
    """``(len(CHASE_LAGS_S), 3)``: position along the road (moved to the lag's time) [m], speed [m/s] and lateral
    position [m] at each lag, each the mean of the fixes of the ``LAG_WINDOW_S`` before it (NaN: no fix then)."""
    t, x, y, v, heading = (history[:, k] for k in range(5))
    out = np.full((len(CHASE_LAGS_S), 3), np.nan)
    for k, lag in enumerate(CHASE_LAGS_S):
        t_lag = now_s - lag
        m = (t <= t_lag + 1e-9) & (t > t_lag - LAG_WINDOW_S)
        if m.any():
            out[k] = ((x[m] + v[m] * np.cos(heading[m]) * (t_lag - t[m])).mean(), v[m].mean(), y[m].mean())
    return out


def _one(me: np.ndarray, ego: np.ndarray, rel_lane: int, p_aggr: float) -> list[float]:
    """One vehicle's inputs from its and the ego's :func:`_at_lags`."""
    f = [p_aggr, float(rel_lane == 0), float(abs(rel_lane) == 1), float(abs(rel_lane) >= 2),
         me[0, 1] / 30.0, ego[0, 1] / 30.0]
    for k in range(len(CHASE_LAGS_S)):
        seen = not (np.isnan(me[k, 0]) or np.isnan(ego[k, 0]))
        f += [float(np.clip((me[k, 0] - ego[k, 0]) / 50.0, -4, 4)) if seen else 0.0,
              float(np.clip((me[k, 1] - ego[k, 1]) / 5.0, -3, 3)) if seen else 0.0, float(seen)]
    lag2, lag4 = CHASE_LAGS_S.index(2.0), CHASE_LAGS_S.index(4.0)
    f += [float(np.clip((me[0, 1] - me[lag2, 1]) / 2.0, -3, 3)) if not np.isnan(me[lag2, 1]) else 0.0,
          float(np.clip((me[lag2, 1] - me[lag4, 1]) / 2.0, -3, 3)) if not np.isnan(me[lag4, 1]) else 0.0]
    return f


def chase_inputs(store: FixStore, records: dict[int, DriverRecord], road: HighwayMap, now_s: float, ego_id: int = 0,
                 prior_aggressive: float = 0.2) -> ChaseInputs:
    """The detector's inputs for every vehicle with a fix in the last ``LAG_WINDOW_S`` and within ``MAX_AGE_S``.

    :param store: the cloud's fix histories
    :param records: the tagger's driver records (read only)
    :param road: the twin's map
    :param now_s: twin time [s]
    :param ego_id: the ego's id
    :param prior_aggressive: posterior used for a driver without a record [-]
    :return: the inputs (none when the ego has no recent fix: the chase is judged relative to it)
    """
    empty = ChaseInputs(np.zeros(0, dtype=np.int64), now_s, np.zeros((0, len(CHASE_FEATURES))))
    if ego_id not in store:
        return empty
    ego = _at_lags(store.history(ego_id), now_s)
    if np.isnan(ego[0, 0]):
        return empty
    ego_lane = road.lane_of_one(ego[0, 2])
    ids, rows = [], []
    for vid in store.vehicle_ids():
        if vid == ego_id:
            continue
        h = store.history(vid)
        if len(h) == 0 or now_s - h[-1, 0] > MAX_AGE_S:
            continue
        me = _at_lags(h, now_s)
        if np.isnan(me[0, 0]):
            continue
        ids.append(vid)
        rows.append(_one(me, ego, road.lane_of_one(me[0, 2]) - ego_lane,
                         p_aggressive(records.get(vid), prior_aggressive)))
    if not ids:
        return empty
    return ChaseInputs(np.asarray(ids, dtype=np.int64), now_s, np.asarray(rows, dtype=float))


@dataclass(frozen=True)
class ChaseDetector:
    """P(the driver is chasing the ego) from :class:`ChaseInputs` (see the module docstring).

    :param mean: input normalisation, ``(F,)``
    :param scale: input normalisation, ``(F,)``
    :param layers: ``(W, b)`` of each layer, ``W`` as ``(in, out)``, the last with one output (the logit)
    :param meta: how the weights were made (seeds, epochs, samples)
    """

    mean: np.ndarray
    scale: np.ndarray
    layers: Layers
    meta: dict[str, str] = field(default_factory=dict)

    @staticmethod
    def load(path: str | Path | None = None) -> ChaseDetector:
        """Read weights written by :func:`save_chase_weights` (``None``: the shipped ones).

        :param path: the ``.npz`` file (``None``: the shipped weights)
        :return: the detector
        :raises ValueError: when the file cannot be read or was made for other inputs
        """
        if path is None:
            with resources.as_file(resources.files("dt_highway.twin").joinpath(WEIGHTS_FILE)) as p:
                return ChaseDetector._from_npz(p)
        return ChaseDetector._from_npz(Path(path))

    @staticmethod
    def _from_npz(path: Path) -> ChaseDetector:
        arrays, layers, meta = read_weights(path, "chase")
        if tuple(str(s) for s in arrays.get("features", ())) != CHASE_FEATURES:
            raise ValueError(f"chase weights {path} were trained for other inputs (retrain: dt-highway train-chase)")
        return ChaseDetector(arrays["mean"], arrays["scale"], layers, meta)

    def predict(self, inputs: ChaseInputs) -> np.ndarray:
        """The probability that each vehicle is chasing the ego.

        :param inputs: the detector's inputs
        :return: ``(N,)`` P(chasing the ego) of ``inputs.vehicle_ids`` [-]
        """
        if len(inputs) == 0:
            return np.zeros(0)
        a = (inputs.x - self.mean) / self.scale
        for w, b in self.layers[:-1]:
            a = np.tanh(a @ w + b)
        w, b = self.layers[-1]
        logit = (a @ w + b)[:, 0]
        return 1.0 / (1.0 + np.exp(-np.clip(logit, -40.0, 40.0)))


def save_chase_weights(path: str | Path, mean: np.ndarray, scale: np.ndarray, layers: list[tuple[np.ndarray, np.ndarray]],
                       meta: dict[str, str] | None = None) -> None:
    """Write the detector's weights as a ``.npz`` of plain arrays (no pickles).

    :param path: the ``.npz`` file to write (its folder is created)
    :param mean: input normalisation, ``(F,)``
    :param scale: input normalisation, ``(F,)``
    :param layers: ``(W, b)`` of each layer, ``W`` as ``(in, out)``, the last with one output (the logit)
    :param meta: how the weights were made (seeds, epochs, samples)
    """
    write_weights(path, {"mean": np.asarray(mean, dtype=np.float64), "scale": np.asarray(scale, dtype=np.float64),
                         "features": np.asarray(CHASE_FEATURES)}, layers, meta)

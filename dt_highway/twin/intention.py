"""Lane-change intention in the cloud twin: P(a vehicle changes lane within H s, and into which lane).

The twin estimates, for every connected vehicle, from what the cloud has received only (GNSS
fix histories in the :class:`~dt_highway.twin.store.FixStore`, its picture of the neighbours
built from their fixes, the tagger's driver-type posterior), the probability that the vehicle
changes lane within each horizon ``H`` and the lane it moves to. The downlink carries the
estimates beside the tag (:attr:`~dt_highway.twin.cloud.TwinVehicleView.intents`); the threat
overlay reads them. Nothing here reads the simulator: the inputs are the store, the tagger's
records and the map (``tests/test_intention.py`` checks that this module imports neither the
world, the env nor the evaluation).

**What the model sees** (:func:`intention_inputs`, named in :data:`OWN_FEATURES` and
:data:`SIDE_FEATURES`). From each vehicle's fixes of the last ``WINDOW_S`` seconds: its lateral
offset from its lane's centre averaged over 0.5, 1 and 2 s (the trend), its lateral speed from
the GNSS course (``speed sin(heading)``, averaged over 0.3, 0.6 and 1.2 s: with 0.02 rad of
course noise at 25 m/s this is ~0.5 m/s per fix, where differentiating 1 m position noise at
10 Hz gives ~14 m/s) and from a least-squares slope of its positions over 1 s; its speed, its
acceleration, and from its last ``LONG_WINDOW_S`` of speeds how long it has kept roughly its
present speed (a car that slowed down to hang beside the ego some seconds ago); the twin's
posterior that the driver is aggressive and how long ago the tagger last saw it change lane.
From the other vehicles' own fixes, moved to the present at their speed: the bumper gap and
speed difference to the nearest vehicle ahead and behind in its own lane and in each
neighbouring lane, MOBIL's two ingredients with a generic IDM car (:data:`IDM`: the braking the
side lane's leader would impose minus its own leader's, and what the side lane's follower would
have to brake), and where the ego is (a connected vehicle, id 0 by default): in which lane, how
far ahead or behind, how much faster, whether it is the side lane's follower.

**The model** (``twin.intention.model``) is a discrete choice between three alternatives,
*stay*, *left* (lane ``k - 1``) and *right* (lane ``k + 1``), for each horizon: the utility of
staying is 0 and that of moving toward a side is ``u(own features, that side's features)``, the
same function for both sides (the side's features are mirrored so that "toward the side" is
positive); the probabilities are the softmax of ``(0, u_left, u_right)``, a side with no lane
dropped. Utilities grow with the horizon (increments are softplus-positive), so that
``P(change within H)`` never falls as ``H`` grows.

* ``learned`` (the default): ``u`` is a small multilayer perceptron (two hidden layers of
  :data:`HIDDEN` tanh units, one output per trained horizon, 0.5-4 s) trained by
  :func:`dt_highway.evaluation.intent_train.train_intention` (``dt-highway train-intent``) on
  simulated fixes from training seeds, with the simulator's future lane changes as labels;
  evaluated on other seeds (``dt-highway twin-eval --intent``). The weights ship with the package
  (``intention_weights.npz``, read with ``allow_pickle=False``); inference is plain numpy.
* ``physics``: lateral motion and gap acceptance, no training: the probability that the
  vehicle's centre crosses the boundary toward a side within ``H`` at its present lateral speed
  (Gaussian uncertainty on speed and offset), times a gap-acceptance factor that is small when
  the side lane's follower or leader is too close (a shorter gap for a driver the twin thinks
  aggressive; none for a move already under way).

*Why learned.* A lane change's lateral motion starts only 0.3-0.7 s before an aggressive car
first overlaps the next lane (1.5-2 s for the whole move), so a model of lateral motion alone
cannot warn 2 s ahead (the physics model is there to show it, see the README's table). What
gives more lead is the context: an aggressive-tagged car beside or just ahead of the ego in the
neighbouring lane, matching its speed, with room in the ego's lane or a slow car ahead of it.
How these combine (gap windows, speed differences, the driver's type) is not a formula we know
well enough to write down, but it is a small function of a few named, physical inputs, which a
small network learns from simulated data and which stays explainable through its inputs (the
feature table) and its calibration (measured by the evaluation). scikit-learn and LightGBM are
not dependencies; torch (one already) is used for training only.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from functools import cached_property
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

import numpy as np

from dt_highway.labels import AGGRESSIVE
from dt_highway.twin.weights import read_weights, write_weights

if TYPE_CHECKING:
    from dt_highway.config import IntentionConfig
    from dt_highway.twin.store import FixStore
    from dt_highway.twin.tagger import DriverRecord, HighwayMap

NO_LANE = -1
"""``target_lane`` when the vehicle has no neighbouring lane to move to"""

WINDOW_S = 2.0
"""Fix history each estimate looks at [s]"""
MIN_FIXES = 3
"""Fewest fixes for an estimate (a vehicle with fewer gets no intents; at low fix rates the window reaches
back to this many)"""
MAX_AGE_S = 2.0
"""A vehicle whose newest fix is older than this gets no intents (it left, or its uplink is silent) [s]"""
MAX_FIXES = 64
"""Most fixes of the window used (the newest)"""
LONG_WINDOW_S = 30.0
"""Speed history looked at for how long a vehicle has kept its speed [s]"""
MAX_LONG_FIXES = 400
"""Most fixes of that history used (the newest)"""
IDM = (1.5, 2.0, 2.0, 1.0)
"""Generic intelligent-driver-model parameters of the MOBIL inputs: ``a`` [m/s^2], ``b`` [m/s^2], ``s0`` [m], ``T`` [s]
(a textbook car, Treiber & Kesting; the twin does not know each driver's)"""
SPEED_CHANGE_MPS = 2.0
"""A speed this much above or below the present one counts as another speed regime [m/s]"""
VEHICLE_LENGTH_M = 5.0
"""Length assumed for bumper gaps (the twin does not know the cars' lengths) [m]"""
GAP_CAP_M = 100.0
"""Gaps are capped here; no vehicle in a lane counts as this gap [m]"""
HIDDEN = 64
"""Hidden units per layer of the learned model"""
WEIGHTS_FILE = "intention_weights.npz"
"""The shipped weights, in this package"""
SHIPPED_WEIGHTS = {"round2": "intention_weights_round2.npz"}
"""Earlier weights shipped beside the current ones, by name (``twin.intention.weights = "round2"``): round 2's,
trained on ``envs/highway-trial-r2.toml`` (the world of the round-2 study and of the shipped RL policies)"""

OWN_FEATURES = (
    "speed",  # own speed / 30 [m/s]
    "p_aggressive",  # the twin's posterior that the driver is aggressive [-]
    "observed",  # time the twin has observed the driver, min(t, 120) / 120 [-]
    "lead_gap",  # bumper gap to the leader in its lane / 50, capped [m]
    "lead_dv",  # own speed minus the leader's / 5 [m/s]
    "follow_gap",  # bumper gap to the follower in its lane / 50 [m]
    "follow_dv",  # follower's speed minus own / 5 [m/s]
    "ego_same_lane",  # 1 when the ego is in its lane
    "ego_dx_same",  # (own x - ego x) / 50 when the ego is in its lane [m]
    "ego_dv_same",  # (own speed - ego speed) / 5 when the ego is in its lane [m/s]
    "n_fixes",  # fixes in the window / 20 [-]
    "accel",  # speed over the last 0.5 s minus over the window's first 0.5 s, per second / 2 [m/s^2]
    "since_lane_change",  # time since the twin last saw the vehicle change lane, min(t, 30) / 30 [s]
    "since_faster",  # time since it last went 2 m/s faster than now, min(t, 30) / 30 (1: not in 30 s) [s]
    "since_slower",  # time since it last went 2 m/s slower than now, min(t, 30) / 30 [s]
)
"""The inputs that do not depend on the side, in order (each with its scale)"""
SIDE_FEATURES = (
    "offset_05",  # lateral offset from the lane centre toward the side, mean over 0.5 s [m]
    "offset_1",  # ... over 1 s [m]
    "offset_2",  # ... over 2 s [m]
    "vlat_03",  # lateral speed toward the side from speed * sin(course), mean over 0.3 s [m/s]
    "vlat_06",  # ... over 0.6 s [m/s]
    "vlat_12",  # ... over 1.2 s [m/s]
    "vlat_fit",  # least-squares slope of the positions over 1 s, toward the side [m/s]
    "side_lead_gap",  # bumper gap to the nearest vehicle ahead in the side lane / 50 [m]
    "side_lead_dv",  # own speed minus its speed / 5 [m/s]
    "side_follow_gap",  # bumper gap to the nearest vehicle behind in the side lane / 50 [m]
    "side_follow_dv",  # its speed minus own / 5 [m/s]
    "ego_in_side",  # 1 when the ego is in the side lane
    "ego_dx_side",  # (own x - ego x) / 50 when the ego is in the side lane [m]
    "ego_dv_side",  # (own speed - ego speed) / 5 when the ego is in the side lane [m/s]
    "ego_gap_side",  # (own x - ego x - length) / 10, clipped to [-3, 3], when the ego is in the side lane [m]
    "ego_is_side_follower",  # 1 when the ego is the nearest vehicle behind in the side lane
    "mobil_incentive",  # IDM braking term (generic IDM) in the side lane minus in its own lane / 3 [m/s^2]
    "mobil_follower",  # IDM braking term the side lane's follower would get behind it / 3 [m/s^2]
)
"""The inputs seen from one side (left: lane - 1, right: lane + 1), lateral ones signed toward it"""
SIDES = (-1, 1)
"""Index 0 of a side axis is the left side (lane index - 1), index 1 the right (lane index + 1)"""


@dataclass(frozen=True)
class LaneChangeIntent:
    """The twin's estimate that a vehicle changes lane within a horizon.

    :param horizon_s: the horizon ``H`` [s]
    :param p_change: probability that the vehicle's lane changes within ``H`` [-]
    :param target_lane: the lane it most likely moves to if it changes (the lane id,
        ``lane_index[2]`` of the twin's map: the more likely of its neighbouring lanes), or
        :data:`NO_LANE` when it has none
    :param p_target: probability that it moves to ``target_lane`` within ``H`` [-] (at most
        ``p_change``; 0 with :data:`NO_LANE`)
    """

    horizon_s: float
    p_change: float
    target_lane: int = NO_LANE
    p_target: float = 0.0


# ----------------------------------------------------------------------------- inputs
@dataclass(frozen=True)
class IntentionInputs:
    """What the model sees of every vehicle it judges (all from the cloud's store and records).

    :param vehicle_ids: the vehicles, shape ``(N,)``
    :param t_s: the twin time of the estimate [s]
    :param lane: each vehicle's lane by the twin (from its fixes of the last 0.5 s), ``(N,)``
    :param own: the side-independent inputs, ``(N, len(OWN_FEATURES))``
    :param side: the inputs seen from the left and from the right, ``(N, 2, len(SIDE_FEATURES))``
    :param side_ok: whether the left / right neighbouring lane exists, ``(N, 2)``
    """

    vehicle_ids: np.ndarray
    t_s: float
    lane: np.ndarray
    own: np.ndarray
    side: np.ndarray
    side_ok: np.ndarray

    def __len__(self) -> int:
        return len(self.vehicle_ids)

    @staticmethod
    def empty(t_s: float) -> IntentionInputs:
        """Intention inputs for no vehicle.

        :param t_s: twin time [s]
        :return: inputs for no vehicle at twin time ``t_s``
        """
        return IntentionInputs(np.zeros(0, dtype=np.int64), t_s, np.zeros(0, dtype=np.int64),
                               np.zeros((0, len(OWN_FEATURES))), np.zeros((0, 2, len(SIDE_FEATURES))),
                               np.zeros((0, 2), dtype=bool))


def p_aggressive(rec: DriverRecord | None, prior: float) -> float:
    """The twin's posterior that a driver is aggressive.

    :param rec: the tagger's record of the driver (``None``: none yet)
    :param prior: the prior probability of an aggressive driver [-]
    :return: the twin's posterior that a driver is aggressive (``prior`` without a record)
    """
    if rec is None:
        return prior
    return float(rec.confidence) if rec.tag == AGGRESSIVE else 1.0 - float(rec.confidence)


def _since_lane_change(rec: DriverRecord | None, now_s: float) -> float:
    """Time since the tagger last judged a lane change of the driver, ``min(t, 30) / 30`` (1 without any).

    The tagger judges a crossing some seconds after it and marks it counted until one second past it.
    """
    if rec is None or not math.isfinite(rec.counted_until_s):
        return 1.0
    return min(max(now_s - (rec.counted_until_s - 1.0), 0.0), 30.0) / 30.0


def _gather(store: FixStore, now_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The last ``WINDOW_S`` of fixes of every vehicle with a recent fix, and the times and speeds of its
    last ``LONG_WINDOW_S``, right-aligned.

    :return: the ids ``(N,)``, the rows ``(N, K, 5)`` (``t, x, y, speed, heading``) and ``(N, L, 2)``
        (``t, speed``), NaN-padded on the left
    """
    ids, blocks, longs = [], [], []
    for vid in store.vehicle_ids():
        h = store.history(vid)
        if len(h) < MIN_FIXES or now_s - h[-1, 0] > MAX_AGE_S:
            continue
        t = h[:, 0]
        lo = min(int(t.searchsorted(t[-1] - WINDOW_S, side="right")), len(h) - MIN_FIXES)  # at low rates: 3 fixes
        block = h[max(lo, len(h) - MAX_FIXES):]
        ids.append(vid)
        blocks.append(block)
        lo = int(t.searchsorted(t[-1] - LONG_WINDOW_S, side="right"))
        longs.append(h[max(lo, len(h) - MAX_LONG_FIXES):, [0, 3]])
    if not ids:
        return np.zeros(0, dtype=np.int64), np.zeros((0, 0, 5)), np.zeros((0, 0, 2))
    return np.asarray(ids, dtype=np.int64), _right_aligned(blocks), _right_aligned(longs)


def _right_aligned(blocks: list[np.ndarray]) -> np.ndarray:
    """Stack ``(k_i, C)`` blocks into ``(N, max k_i, C)``, NaN-padded on the left."""
    k = max(len(b) for b in blocks)
    out = np.full((len(blocks), k, blocks[0].shape[1]), np.nan)
    for i, b in enumerate(blocks):
        out[i, k - len(b):] = b
    return out


def _time_since(t: np.ndarray, hit: np.ndarray, t_last: np.ndarray) -> np.ndarray:
    """Per row, ``t_last`` minus the last time ``hit`` was true, ``min(., LONG_WINDOW_S) / LONG_WINDOW_S``
    (1 when it never was in the history)."""
    last = np.where(hit, t, -np.inf).max(axis=1)
    return np.minimum(t_last - last, LONG_WINDOW_S) / LONG_WINDOW_S


def _clip(a: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """``np.clip`` (the same values) without its overhead on small arrays."""
    return np.minimum(np.maximum(a, lo), hi)


def _window_mean(values: np.ndarray, in_window: np.ndarray) -> np.ndarray:
    """Row means of ``values`` over ``in_window`` (each row has at least its newest fix in it)."""
    return np.where(in_window, values, 0.0).sum(axis=1) / in_window.sum(axis=1)


def _neighbours(x: np.ndarray, lane: np.ndarray, offset: int) -> tuple[np.ndarray, np.ndarray]:
    """For each vehicle, the nearest vehicle ahead and behind in lane ``lane + offset``.

    :return: indices of the leader and of the follower (``-1`` when none), ``(N,)`` each
    """
    n = len(x)
    dx = x[None, :] - x[:, None]  # dx[i, j] = x_j - x_i
    same = lane[None, :] == (lane[:, None] + offset)
    np.fill_diagonal(same, False)
    ahead = np.where(same & (dx >= 0), dx, np.inf)
    behind = np.where(same & (dx < 0), -dx, np.inf)
    lead = ahead.argmin(axis=1) if n else np.zeros(0, dtype=np.int64)
    follow = behind.argmin(axis=1) if n else np.zeros(0, dtype=np.int64)
    rows = np.arange(n)
    lead = np.where(np.isfinite(ahead[rows, lead]), lead, -1)
    follow = np.where(np.isfinite(behind[rows, follow]), follow, -1)
    return lead, follow


def _gap_features(x: np.ndarray, v: np.ndarray, lead: np.ndarray, follow: np.ndarray) -> np.ndarray:
    """Leader gap, leader speed difference, follower gap, follower speed difference (scaled), ``(N, 4)``."""
    has_lead, has_follow = lead >= 0, follow >= 0
    gap_lead = np.where(has_lead, x[lead] - x - VEHICLE_LENGTH_M, GAP_CAP_M)
    gap_follow = np.where(has_follow, x - x[follow] - VEHICLE_LENGTH_M, GAP_CAP_M)
    dv_lead = np.where(has_lead, v - v[lead], 0.0)
    dv_follow = np.where(has_follow, v[follow] - v, 0.0)
    return np.stack([
        _clip(gap_lead, -VEHICLE_LENGTH_M, GAP_CAP_M) / 50.0, _clip(dv_lead / 5.0, -3.0, 3.0),
        _clip(gap_follow, -VEHICLE_LENGTH_M, GAP_CAP_M) / 50.0, _clip(dv_follow / 5.0, -3.0, 3.0),
    ], axis=1)


def idm_interaction(v: np.ndarray, lead: np.ndarray, gap: np.ndarray, v_lead: np.ndarray) -> np.ndarray:
    """The braking term of the intelligent driver model, ``-a (s* / s)^2`` with
    ``s* = s0 + v T + v (v - v_lead) / (2 sqrt(a b))``, generic parameters ``IDM`` (0 without a leader) [m/s^2].

    :param v: own speed [m/s]
    :param lead: index of the leader (``-1``: none)
    :param gap: bumper gap to it [m]
    :param v_lead: its speed [m/s]
    :return: the braking term of each vehicle, not below ``-3 b`` [m/s^2]
    """
    a, b, s0, t_h = IDM
    s_star = np.maximum(s0 + v * t_h + v * (v - v_lead) / (2.0 * math.sqrt(a * b)), 0.0)
    term = -a * (s_star / np.maximum(gap, 0.5)) ** 2
    return np.where(lead >= 0, np.maximum(term, -3.0 * b), 0.0)


def _mobil(x: np.ndarray, v: np.ndarray, lead: np.ndarray, s_lead: np.ndarray, s_follow: np.ndarray) -> np.ndarray:
    """MOBIL's two ingredients toward one side, from the twin's picture: own IDM braking term in the side lane
    minus in its own lane (the incentive), and the braking term the side lane's follower would get behind it
    (the safety criterion), both scaled by 1/3 [m/s^2]. ``(N, 2)``."""
    safe = lambda i: np.where(i >= 0, i, 0)  # noqa: E731  (the index where a vehicle exists)
    own = idm_interaction(v, lead, x[safe(lead)] - x - VEHICLE_LENGTH_M, v[safe(lead)])
    there = idm_interaction(v, s_lead, x[safe(s_lead)] - x - VEHICLE_LENGTH_M, v[safe(s_lead)])
    me = np.arange(len(x))
    follower = np.where(s_follow >= 0, idm_interaction(v[safe(s_follow)], me, x - x[safe(s_follow)] - VEHICLE_LENGTH_M, v),
                        0.0)
    return np.column_stack([(there - own) / 3.0, follower / 3.0])


def _windows(t: np.ndarray) -> Callable[[float], np.ndarray]:
    """The masks of each row's recent fixes, by window length.

    :return: ``window(w)``: the mask of each row's fixes less than ``w`` [s] older than its newest (always in)
    """
    valid = ~np.isnan(t)
    age = t[:, -1:] - t

    def window(w: float) -> np.ndarray:
        m = valid & (age < w - 1e-9)
        m[:, -1] = True
        return m

    return window


def _present(rows: np.ndarray, w05: np.ndarray, now_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Each vehicle's position along the road and speed now: its fixes of the last 0.5 s moved to ``now_s`` at their
    speed and course, averaged [m], and their mean speed [m/s]."""
    t, x, v, heading = rows[:, :, 0], rows[:, :, 1], rows[:, :, 3], rows[:, :, 4]
    return _window_mean(x + v * np.cos(heading) * (now_s - t), w05), _window_mean(v, w05)


@dataclass(frozen=True)
class TwinPicture:
    """The cloud's picture of the road now, from the fixes and the tagger's records only: every vehicle with enough
    recent fixes (the ego included), as the intention inputs see it.

    :param vehicle_ids: the vehicles, ``(N,)``
    :param t_s: twin time [s]
    :param x_m: position along the road: the last 0.5 s of fixes moved to ``t_s`` at their speed, averaged, ``(N,)`` [m]
    :param y_m: lateral position, mean of the last 0.5 s of fixes, ``(N,)`` [m]
    :param speed_mps: speed, mean of the last 0.5 s, ``(N,)`` [m/s]
    :param lateral_speed_mps: ``speed sin(course)``, mean of the last 0.6 s (positive: toward higher lane ids),
        ``(N,)`` [m/s]
    :param p_aggressive: the tagger's posterior that the driver is aggressive, ``(N,)`` [-]
    :param p_move: the twin's estimate that the vehicle moves to its left / right lane within the intention model's
        shortest horizon, ``(N, 2)`` [-] (:meth:`with_moves`; ``None``: not given)
    :param p_chase: the twin's estimate that the driver is chasing the ego (has a cut-in attempt open on it),
        ``(N,)`` [-] (:meth:`with_chases`, from :class:`~dt_highway.twin.chase.ChaseDetector`; ``None``: not given)
    """

    vehicle_ids: np.ndarray
    t_s: float
    x_m: np.ndarray
    y_m: np.ndarray
    speed_mps: np.ndarray
    lateral_speed_mps: np.ndarray
    p_aggressive: np.ndarray
    p_move: np.ndarray | None = None
    p_chase: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.vehicle_ids)

    def with_chases(self, vehicle_ids: np.ndarray, p_chase: np.ndarray) -> TwinPicture:
        """This picture with the vehicles' probabilities of chasing the ego.

        :param vehicle_ids: the vehicles estimated, ``(M,)``
        :param p_chase: their probability of chasing the ego, ``(M,)`` [-]
        :return: this picture with :attr:`p_chase` for ``vehicle_ids`` (0 for a vehicle not among them, such as
        the ego)
        """
        index = {int(v): k for k, v in enumerate(np.asarray(vehicle_ids).tolist())}
        out = np.zeros(len(self))
        for i, vid in enumerate(self.vehicle_ids.tolist()):
            k = index.get(int(vid))
            if k is not None:
                out[i] = float(p_chase[k])
        return replace(self, p_chase=out)

    def with_moves(self, table: IntentTable) -> TwinPicture:
        """This picture with the vehicles' lane-change probabilities.

        :param table: the intention estimate (its first horizon is used)
        :return: this picture with :attr:`p_move` from an intention estimate (0 for a vehicle it did not judge,
        such as the ego)
        """
        p_move = np.zeros((len(self), 2))
        for i, vid in enumerate(self.vehicle_ids.tolist()):
            k = table._index.get(int(vid))
            if k is not None:
                p_move[i] = table.probs[k, 0, 1:]
        return replace(self, p_move=p_move)


def twin_picture(store: FixStore, records: dict[int, DriverRecord], now_s: float,
                 prior_aggressive: float = 0.2) -> TwinPicture:
    """The cloud's picture of every vehicle with enough recent fixes (:class:`TwinPicture`).

    :param store: the cloud's fix histories
    :param records: the tagger's driver records (read only)
    :param now_s: twin time [s]
    :param prior_aggressive: posterior used for a driver without a record [-]
    :return: the picture (no vehicle when none has enough recent fixes)
    """
    ids, rows, _ = _gather(store, now_s)
    if len(ids) == 0:
        z = np.zeros(0)
        return TwinPicture(ids, now_s, z, z, z, z, z)
    window = _windows(rows[:, :, 0])
    w05 = window(0.5)
    x_now, v_now = _present(rows, w05, now_s)
    y05 = _window_mean(rows[:, :, 2], w05)
    vlat = _window_mean(rows[:, :, 3] * np.sin(rows[:, :, 4]), window(0.6))
    p_aggr = np.array([p_aggressive(records.get(int(i)), prior_aggressive) for i in ids])
    return TwinPicture(ids, now_s, x_now, y05, v_now, vlat, p_aggr)


def intention_inputs(
    store: FixStore,
    records: dict[int, DriverRecord],
    road: HighwayMap,
    now_s: float,
    ego_id: int = 0,
    prior_aggressive: float = 0.2,
) -> IntentionInputs:
    """The model's inputs for every vehicle with enough recent fixes (see the module docstring).

    :param store: the cloud's fix histories
    :param records: the tagger's driver records (read only)
    :param road: the twin's map
    :param now_s: twin time [s]
    :param ego_id: the id of the ego (the vehicle the twin serves) [-]
    :param prior_aggressive: posterior used for a driver without a record [-]
    :return: the inputs (the ego is among the vehicles judged only as a neighbour: it is left out)
    """
    ids, rows, long = _gather(store, now_s)
    if len(ids) == 0:
        return IntentionInputs.empty(now_s)
    t, x, y, v, heading = (rows[:, :, k] for k in range(5))
    valid = ~np.isnan(t)
    t_last = t[:, -1]
    window = _windows(t)
    w05, w1, w2 = window(0.5), window(1.0), valid
    x_now, v_now = _present(rows, w05, now_s)
    t_first = np.nanmin(t, axis=1)
    first = valid & (t < t_first[:, None] + 0.5)
    span = _window_mean(t, w05) - _window_mean(t, first)
    accel = np.where(span > 0.5, (v_now - _window_mean(v, first)) / np.where(span > 0.5, span, 1.0), 0.0)
    t_long, v_long = long[:, :, 0], long[:, :, 1]
    with np.errstate(invalid="ignore"):  # NaN padding compares False
        since_faster = _time_since(t_long, v_long >= v_now[:, None] + SPEED_CHANGE_MPS, t_last)
        since_slower = _time_since(t_long, v_long <= v_now[:, None] - SPEED_CHANGE_MPS, t_last)
    y05, y1, y2 = _window_mean(y, w05), _window_mean(y, w1), _window_mean(y, w2)
    vlat = v * np.sin(heading)
    vlat03, vlat06, vlat12 = (_window_mean(vlat, window(w)) for w in (0.3, 0.6, 1.2))
    # least-squares slope of y over 1 s (0 with fewer than 3 fixes)
    n1 = w1.sum(axis=1)
    tc = np.where(w1, t - _window_mean(t, w1)[:, None], 0.0)
    yc = np.where(w1, y - y1[:, None], 0.0)
    den = (tc * tc).sum(axis=1)
    slope = np.where((n1 >= 3) & (den > 0), (tc * yc).sum(axis=1) / np.where(den > 0, den, 1.0), 0.0)

    lane = road.lane_of(y05)
    centre = road.lane_centre_y_m(lane)
    p_aggr = np.array([p_aggressive(records.get(int(i)), prior_aggressive) for i in ids])
    observed = np.array([min(records[int(i)].observed_s, 120.0) / 120.0 if int(i) in records else 0.0 for i in ids])
    since = np.array([_since_lane_change(records.get(int(i)), now_s) for i in ids])

    lead, follow = _neighbours(x_now, lane, 0)
    own_gaps = _gap_features(x_now, v_now, lead, follow)
    ego_idx = np.flatnonzero(ids == ego_id)
    if len(ego_idx):
        e = int(ego_idx[0])
        ego_dx, ego_dv, ego_rel = x_now - x_now[e], v_now - v_now[e], lane[e] - lane
    else:
        ego_dx, ego_dv, ego_rel = np.zeros(len(ids)), np.zeros(len(ids)), np.full(len(ids), 99)
    same = (ego_rel == 0).astype(float)
    own = np.column_stack([
        v_now / 30.0, p_aggr, observed, own_gaps,
        same, same * _clip(ego_dx / 50.0, -2.0, 2.0), same * _clip(ego_dv / 5.0, -3.0, 3.0),
        valid.sum(axis=1) / 20.0, _clip(accel / 2.0, -3.0, 3.0), since, since_faster, since_slower,
    ])
    side = np.zeros((len(ids), 2, len(SIDE_FEATURES)))
    side_ok = np.zeros((len(ids), 2), dtype=bool)
    for k, s in enumerate(SIDES):
        s_lead, s_follow = _neighbours(x_now, lane, s)
        in_side = (ego_rel == s).astype(float)
        ego_follows = (s_follow == ego_idx[0]).astype(float) if len(ego_idx) else np.zeros(len(ids))
        side[:, k] = np.column_stack([
            s * (y05 - centre), s * (y1 - centre), s * (y2 - centre),
            s * vlat03, s * vlat06, s * vlat12, s * slope,
            _gap_features(x_now, v_now, s_lead, s_follow),
            in_side, in_side * _clip(ego_dx / 50.0, -2.0, 2.0), in_side * _clip(ego_dv / 5.0, -3.0, 3.0),
            in_side * _clip((ego_dx - VEHICLE_LENGTH_M) / 10.0, -3.0, 3.0), ego_follows,
            _mobil(x_now, v_now, lead, s_lead, s_follow),
        ])
        side_ok[:, k] = (lane + s >= 0) & (lane + s < road.n_lanes)
    keep = ids != ego_id
    return IntentionInputs(ids[keep], now_s, lane[keep], own[keep], side[keep], side_ok[keep])


# ----------------------------------------------------------------------------- models
class IntentionModel(Protocol):
    """Maps inputs to the probabilities of staying, moving left and moving right within each horizon."""

    @property
    def horizons_s(self) -> tuple[float, ...]:
        """The horizons answered for [s]."""
        ...

    def predict(self, inputs: IntentionInputs) -> np.ndarray:
        """The lane-change probabilities of the inputs' vehicles.

        :param inputs: the model's inputs
        :return: ``(N, len(horizons_s), 3)``: P(stay), P(left), P(right) within each horizon
        """
        ...


def choice_probabilities(utility: np.ndarray, side_ok: np.ndarray) -> np.ndarray:
    """Softmax of ``(0, u_left, u_right)`` with missing sides dropped.

    :param utility: ``(N, 2, H)``: utility of moving to the left / right side within each horizon
    :param side_ok: ``(N, 2)``: whether each side has a lane
    :return: ``(N, H, 3)``: P(stay), P(left), P(right)
    """
    u = np.where(side_ok[:, :, None], utility, -np.inf)  # (N, 2, H)
    top = np.maximum(0.0, u.max(axis=1))  # (N, H)
    e_stay = np.exp(-top)
    e_side = np.exp(u - top[:, None, :])
    total = e_stay + e_side.sum(axis=1)
    return np.stack([e_stay / total, e_side[:, 0] / total, e_side[:, 1] / total], axis=2)


def _softplus(a: np.ndarray) -> np.ndarray:
    return np.logaddexp(0.0, a)


@dataclass(frozen=True)
class LearnedIntention:
    """The learned utility (see the module docstring); weights from a ``.npz`` file.

    :param trained_horizons_s: the horizons the network was trained for [s]
    :param horizons_s: the horizons to answer for (within the trained range; utilities are
        interpolated linearly between trained horizons) [s]
    :param mean: input normalisation, ``(F,)``
    :param scale: input normalisation, ``(F,)``
    :param layers: ``(W, b)`` of each layer, the last with one output per trained horizon
    """

    trained_horizons_s: tuple[float, ...]
    horizons_s: tuple[float, ...]
    mean: np.ndarray
    scale: np.ndarray
    layers: tuple[tuple[np.ndarray, np.ndarray], ...]
    meta: dict[str, str] = field(default_factory=dict)

    @staticmethod
    def load(path: str | Path | None, horizons_s: tuple[float, ...]) -> LearnedIntention:
        """Read weights written by :func:`save_weights` (``None``: the shipped ones; a name of
        :data:`SHIPPED_WEIGHTS`: those earlier shipped weights).

        :param path: the ``.npz`` file, a name of :data:`SHIPPED_WEIGHTS`, or ``None`` (the shipped weights)
        :param horizons_s: the horizons to answer for [s]
        :return: the model
        :raises ValueError: when the file is not intention weights, was made for other inputs, or
            does not cover ``horizons_s``
        """
        if path is None or str(path) in SHIPPED_WEIGHTS:
            name = WEIGHTS_FILE if path is None else SHIPPED_WEIGHTS[str(path)]
            ref = resources.files("dt_highway.twin").joinpath(name)
            with resources.as_file(ref) as p:
                return LearnedIntention._from_npz(p, horizons_s)
        return LearnedIntention._from_npz(Path(path), horizons_s)

    @staticmethod
    def _from_npz(path: Path, horizons_s: tuple[float, ...]) -> LearnedIntention:
        arrays, layers, meta = read_weights(path, "intention")
        own = tuple(str(s) for s in arrays.get("own_features", ()))
        side = tuple(str(s) for s in arrays.get("side_features", ()))
        if own != OWN_FEATURES or side != SIDE_FEATURES:
            raise ValueError(f"intention weights {path} were trained for other inputs (retrain: dt-highway train-intent)")
        trained = tuple(float(h) for h in arrays["horizons_s"])
        lo, hi = trained[0], trained[-1]
        bad = [h for h in horizons_s if not lo - 1e-9 <= h <= hi + 1e-9]
        if bad:
            raise ValueError(f"the learned intention model covers horizons {lo:g}-{hi:g} s (got {bad[0]:g})")
        return LearnedIntention(trained, tuple(horizons_s), arrays["mean"], arrays["scale"], layers, meta)

    def utility(self, inputs: IntentionInputs) -> np.ndarray:
        """The network's utility of a lane change to each side.

        :param inputs: the model's inputs
        :return: ``(N, 2, len(horizons_s))`` utilities of moving to each side within each horizon
        """
        n = len(inputs)
        x = np.concatenate([np.repeat(inputs.own[:, None, :], 2, axis=1), inputs.side], axis=2).reshape(2 * n, -1)
        a = (x - self.mean) / self.scale
        for w, b in self.layers[:-1]:
            a = np.tanh(a @ w + b)
        w, b = self.layers[-1]
        raw = a @ w + b  # (2N, trained H)
        z = np.cumsum(np.concatenate([raw[:, :1], _softplus(raw[:, 1:])], axis=1), axis=1)
        return (z @ self.interpolation).reshape(n, 2, len(self.horizons_s))

    @cached_property
    def interpolation(self) -> np.ndarray:
        """``(trained, asked)``: linear interpolation from the trained horizons to ``horizons_s`` (as ``np.interp``)."""
        trained = np.asarray(self.trained_horizons_s)
        return np.stack([np.interp(self.horizons_s, trained, e) for e in np.eye(len(trained))])

    def predict(self, inputs: IntentionInputs) -> np.ndarray:
        """The lane-change probabilities of the inputs' vehicles.

        :param inputs: the model's inputs
        :return: ``(N, len(horizons_s), 3)`` probabilities of keeping the lane, moving left, moving right
        """
        if len(inputs) == 0:
            return np.zeros((0, len(self.horizons_s), 3))
        return choice_probabilities(self.utility(inputs), inputs.side_ok)


def save_weights(path: str | Path, horizons_s: tuple[float, ...], mean: np.ndarray, scale: np.ndarray,
                 layers: list[tuple[np.ndarray, np.ndarray]], meta: dict[str, str] | None = None) -> None:
    """Write the learned model's weights as a ``.npz`` of plain arrays (no pickles).

    :param path: the ``.npz`` file to write (its folder is created)
    :param horizons_s: the horizons the network was trained for [s]
    :param mean: input normalisation, ``(F,)``
    :param scale: input normalisation, ``(F,)``
    :param layers: ``(W, b)`` of each layer, ``W`` as ``(in, out)``, the last with one output per horizon
    :param meta: how the weights were made
    """
    write_weights(path, {
        "horizons_s": np.asarray(horizons_s, dtype=np.float64), "mean": np.asarray(mean, dtype=np.float64),
        "scale": np.asarray(scale, dtype=np.float64),
        "own_features": np.asarray(OWN_FEATURES), "side_features": np.asarray(SIDE_FEATURES),
    }, layers, meta)


@dataclass(frozen=True)
class PhysicsIntention:
    """Lateral motion and gap acceptance, no training (see the module docstring).

    :param horizons_s: the horizons [s]
    :param lane_width_m: lane width [m]
    :param sigma_v_mps: uncertainty of the lateral speed estimate [m/s]
    :param sigma_y_m: uncertainty of the lateral offset estimate [m]
    :param min_gap_s: a side lane's follower or leader nearer than this time gap makes a move unlikely, for a
        driver the twin thinks normal (scaled by ``1 - P(aggressive)``: an aggressive driver takes small gaps) [s]
    :param refused: the factor on such a move's probability [-]
    :param moving_mps: a vehicle already moving toward a side at least this fast is not held back by the gap
        (a lane change under way is not called off) [m/s]
    """

    horizons_s: tuple[float, ...]
    lane_width_m: float = 4.0
    sigma_v_mps: float = 0.25
    sigma_y_m: float = 0.3
    min_gap_s: float = 0.5
    refused: float = 0.2
    moving_mps: float = 0.5

    def predict(self, inputs: IntentionInputs) -> np.ndarray:
        """The lane-change probabilities of the inputs' vehicles, from their lateral motion and gaps.

        :param inputs: the model's inputs
        :return: ``(N, len(horizons_s), 3)`` probabilities of keeping the lane, moving left, moving right
        """
        if len(inputs) == 0:
            return np.zeros((0, len(self.horizons_s), 3))
        off = inputs.side[:, :, SIDE_FEATURES.index("offset_05")]
        vlat = inputs.side[:, :, SIDE_FEATURES.index("vlat_06")]
        speed = np.maximum(inputs.own[:, OWN_FEATURES.index("speed")] * 30.0, 1.0)[:, None]
        gap_lead = inputs.side[:, :, SIDE_FEATURES.index("side_lead_gap")] * 50.0
        gap_follow = inputs.side[:, :, SIDE_FEATURES.index("side_follow_gap")] * 50.0
        min_gap = (self.min_gap_s * (1.0 - inputs.own[:, OWN_FEATURES.index("p_aggressive")]))[:, None] * speed
        too_close = ((gap_lead < min_gap) | (gap_follow < min_gap)) & (vlat < self.moving_mps)
        accept = np.where(too_close, self.refused, 1.0)
        to_boundary = self.lane_width_m / 2 - off  # (N, 2)
        h = np.asarray(self.horizons_s)[None, None, :]
        z = (vlat[:, :, None] * h - to_boundary[:, :, None]) / (self.sigma_v_mps * h + self.sigma_y_m)
        p_side = 0.5 * (1.0 + _erf(z / math.sqrt(2.0))) * accept[:, :, None]  # (N, 2, H)
        p_side = np.where(inputs.side_ok[:, :, None], p_side, 0.0)
        total = p_side.sum(axis=1)  # (N, H)
        norm = np.maximum(total, 1.0)
        p_side = p_side / norm[:, None, :]
        p_stay = 1.0 - p_side.sum(axis=1)
        return np.stack([p_stay, p_side[:, 0], p_side[:, 1]], axis=2)


_erf = np.vectorize(math.erf, otypes=[float])


def make_model(config: IntentionConfig) -> IntentionModel:
    """The model a ``twin.intention`` section asks for.

    :param config: the ``twin.intention`` section
    :return: the physics or the learned model, for ``config.horizons_s``
    :raises ValueError: when learned weights cannot be read or do not fit
    """
    horizons = tuple(config.horizons_s)
    if config.model == "physics":
        return PhysicsIntention(horizons)
    return LearnedIntention.load(config.weights, horizons)


# ----------------------------------------------------------------------------- the estimator
@dataclass
class IntentTable:
    """One estimate of every judged vehicle: the model's probabilities, turned into intents on demand.

    :param inputs: what the model saw
    :param probs: ``(N, len(horizons_s), 3)``: P(stay), P(left), P(right)
    :param horizons_s: the horizons [s]
    """

    inputs: IntentionInputs
    probs: np.ndarray
    horizons_s: tuple[float, ...]
    _index: dict[int, int] = field(default_factory=dict)
    _made: dict[int, tuple[LaneChangeIntent, ...]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self._index = {int(v): i for i, v in enumerate(self.inputs.vehicle_ids)}

    @property
    def t_s(self) -> float:
        """Twin time of the estimate [s]."""
        return self.inputs.t_s

    def __contains__(self, vehicle_id: int) -> bool:
        return vehicle_id in self._index

    def intents(self, vehicle_id: int) -> tuple[LaneChangeIntent, ...]:
        """One vehicle's lane-change intents.

        :param vehicle_id: the vehicle
        :return: the vehicle's intents, shortest horizon first (empty when it was not judged)
        """
        made = self._made.get(vehicle_id)
        if made is not None:
            return made
        i = self._index.get(vehicle_id)
        if i is None:
            return ()
        p_change, target, p_target = self._lists
        made = self._made[vehicle_id] = tuple(
            LaneChangeIntent(h, c, t, pt) for h, c, t, pt in zip(self.horizons_s, p_change[i], target[i], p_target[i],
                                                               strict=True)
        )
        return made

    @cached_property
    def _lists(self) -> tuple[list[list[float]], list[list[int]], list[list[float]]]:
        """``p_change``, ``target_lane`` and ``p_target`` of every vehicle and horizon, as Python lists
        (made once per estimate: the intents of a view are built from them)."""
        p = self.probs  # (N, H, 3)
        ok = self.inputs.side_ok[:, None, :]  # (N, 1, 2)
        some = ok.any(axis=2)
        right = ok[:, :, 1] & (~ok[:, :, 0] | (p[:, :, 2] > p[:, :, 1]))
        p_change = np.where(some, np.clip(1.0 - p[:, :, 0], 0.0, 1.0), 0.0)
        target = np.where(some, self.inputs.lane[:, None] + np.where(right, 1, -1), NO_LANE)
        p_target = np.where(some, np.where(right, p[:, :, 2], p[:, :, 1]), 0.0)
        return p_change.tolist(), target.astype(int).tolist(), p_target.tolist()

    def arrays(self, horizon_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Everything at the horizon nearest ``horizon_s``, as arrays (for evaluation).

        :param horizon_s: the horizon asked for [s]
        :return: vehicle ids, p_change, target lane, p_target, each ``(N,)``
        """
        k = int(np.argmin([abs(h - horizon_s) for h in self.horizons_s]))
        p = self.probs[:, k]
        ok = self.inputs.side_ok
        right = ok[:, 1] & (~ok[:, 0] | (p[:, 2] > p[:, 1]))
        target = np.where(ok.any(axis=1), self.inputs.lane + np.where(right, 1, -1), NO_LANE)
        p_target = np.where(ok.any(axis=1), np.where(right, p[:, 2], p[:, 1]), 0.0)
        return self.inputs.vehicle_ids, np.clip(1.0 - p[:, 0], 0.0, 1.0), target, p_target


class IntentionEstimator:
    """Runs the configured model on the cloud's data.

    :param config: the ``twin.intention`` section
    :param road: the twin's map
    :param prior_aggressive: the tagger's prior (for drivers without a record) [-]
    :raises ValueError: when the model cannot be made (see :func:`make_model`)
    """

    def __init__(self, config: IntentionConfig, road: HighwayMap, prior_aggressive: float = 0.2) -> None:
        self.config = config
        self.road = road
        self.prior_aggressive = prior_aggressive
        self.model = make_model(config)

    def estimate(self, store: FixStore, records: dict[int, DriverRecord], now_s: float, ego_id: int = 0) -> IntentTable:
        """Estimate the lane-change intention of the vehicles in the store.

        :param store: the cloud's fix histories
        :param records: the tagger's driver records (read only)
        :param now_s: twin time [s]
        :param ego_id: the ego's id (a neighbour in the inputs, not judged itself)
        :return: the intents of every vehicle with enough recent fixes at twin time ``now_s``
        """
        inputs = intention_inputs(store, records, self.road, now_s, ego_id, self.prior_aggressive)
        return IntentTable(inputs, self.model.predict(inputs), tuple(self.config.horizons_s))

"""The twin's tagger: sudden lane changes from GNSS history, and the driver's tag.

Only the received fix history is used (never the simulator's driver types).

1. **Lane changes.** The lateral position (the twin knows the map: lane centres) is
   smoothed with a moving average of ``smoothing_s``; a lane change is the smoothed
   position crossing a lane boundary by more than ``hysteresis_m``.
2. **How sudden.** A ramp ``y(t) = a + dy * clip((t - t0) / T + 1/2, 0, 1)`` with the known
   lane offset ``dy`` is fitted by least squares (grid over mid-time ``t0`` and duration
   ``T``) to the *raw* fixes within ``fit_window_s`` of the crossing. Its mean lateral speed
   ``|dy| / T`` is robust to GNSS noise where differentiating the fixes is not (1 m of noise
   at 10 Hz gives ~14 m/s of noise on a finite difference). The change is **sudden** when
   that speed exceeds ``sudden_lateral_speed_mps`` or when the accepted time gap to the
   new follower (another connected vehicle, from its own fixes) is below ``sudden_gap_s``.
3. **Tag.** Sudden lane changes are modelled as a Poisson process whose rate is
   ``rate_aggressive_per_min`` for an aggressive driver and ``rate_normal_per_min`` for a
   normal one. After ``n`` sudden changes in ``T`` observed minutes the log-likelihood ratio
   is ``n log(ra / rn) - (ra - rn) T``; with the prior this gives the posterior probability
   that the driver is aggressive. The tag is ``aggressive`` when it exceeds ``threshold``;
   the confidence is the posterior probability of the tag given.
4. **Evidence model** (``model = "evidence"``, for a population without two clean classes such as
   the continuum of drivers). The same lane changes plus the driver's longitudinal behaviour, sampled
   at every tagger update from the latest second of fixes of every connected vehicle: its speed, its
   speed against the median of the traffic the twin sees, and its time headway to the connected
   vehicle ahead in its lane (when within ``FOLLOW_RANGE_M``). The probability is a logistic model of
   the ten features :data:`EVIDENCE_FEATURES` whose weights were fitted on simulated training seeds
   (``dt-highway train-tagger``; shipped as ``tagger_evidence.json``); the tag and confidence follow
   from it as in 3.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import overload

import numpy as np

from dt_highway.config import ConfigError, TaggerConfig
from dt_highway.labels import AGGRESSIVE, NORMAL
from dt_highway.twin.store import FixStore


@dataclass(frozen=True)
class HighwayMap:
    """What the cloud knows of the road: straight parallel lanes.

    :param lane_width_m: lane width [m]
    :param n_lanes: number of lanes
    :param first_lane_y_m: lateral position of lane 0's centre [m]
    """

    lane_width_m: float
    n_lanes: int
    first_lane_y_m: float = 0.0

    def lane_of(self, y_m: np.ndarray | float) -> np.ndarray:
        """The lane at lateral position(s).

        :param y_m: lateral position(s) [m]
        :return: the index of the lane whose centre is nearest to ``y_m``.
        """
        k = np.rint((np.asarray(y_m, dtype=float) - self.first_lane_y_m) / self.lane_width_m)
        return np.clip(k, 0, self.n_lanes - 1).astype(int)

    @overload
    def lane_centre_y_m(self, lane: int) -> float: ...

    @overload
    def lane_centre_y_m(self, lane: np.ndarray) -> np.ndarray: ...

    def lane_centre_y_m(self, lane: np.ndarray | int) -> np.ndarray | float:
        """The lateral position of a lane's centre [m].

        :param lane: a lane index, or an array of them
        :return: the lateral position of lane ``lane``'s centre [m] (an array for an array of lanes).
        """
        return self.first_lane_y_m + lane * self.lane_width_m

    def lane_of_one(self, y_m: float) -> int:
        """The lane at one lateral position, in plain Python.

        :param y_m: lateral position [m]
        :return: ``int(lane_of(y_m))`` for one finite position, without numpy's per-call cost
        (``round`` rounds half to even, as ``np.rint``).
        """
        k = (float(y_m) - self.first_lane_y_m) / self.lane_width_m
        if k != k or abs(k) > 1e9:  # NaN or absurd: numpy's answer
            return int(self.lane_of(y_m))
        return min(max(round(k), 0), self.n_lanes - 1)


@dataclass(frozen=True)
class LaneChange:
    """A lane change the twin saw.

    :param t_cross_s: time the smoothed track crossed the lane boundary [s]
    :param from_lane: lane index before
    :param to_lane: lane index after
    :param duration_s: fitted duration of the lateral move [s] (NaN: too few fixes to time it)
    :param lateral_speed_mps: mean lateral speed, lane width / duration [m/s] (NaN likewise)
    :param gap_s: accepted time gap to the new follower [s] (inf when none was seen, NaN when
        the fixes are too noisy to tell lanes apart)
    :param sudden: whether the change counts as sudden
    """

    t_cross_s: float
    from_lane: int
    to_lane: int
    duration_s: float
    lateral_speed_mps: float
    gap_s: float
    sudden: bool


def median(a: np.ndarray) -> float:
    """``float(np.median(a))`` of a non-empty 1-D array, the same value (the middle element, or
    the mean of the two middle ones; NaN if any is NaN) at a tenth of ``np.median``'s cost,
    which the twin pays several times per vehicle and update.

    :param a: the values, 1-D, not empty
    :return: their median
    """
    n = len(a)
    k = n // 2
    if n % 2:
        part = np.partition(a, (k, n - 1))
        value = float(part[k])
    else:
        part = np.partition(a, (k - 1, k, n - 1))
        value = float((part[k - 1] + part[k]) / 2)
    if part[-1] != part[-1]:  # NaN sorts last (the last place is partitioned too): np.median gives NaN
        return math.nan
    return value


def moving_average(t_s: np.ndarray, y: np.ndarray, window_s: float) -> np.ndarray:
    """Centred moving average over a time window (handles uneven sampling).

    :param t_s: sample times, sorted [s]
    :param y: values
    :param window_s: full window width [s]
    :return: smoothed values, same length
    """
    if len(y) == 0:
        return y.astype(float)
    csum = np.empty(len(y) + 1)
    csum[0] = 0.0
    np.cumsum(y, dtype=float, out=csum[1:])
    half = window_s / 2
    lo = t_s.searchsorted(t_s - half, side="left")
    hi = t_s.searchsorted(t_s + half, side="right")
    return (csum[hi] - csum[lo]) / (hi - lo)


def boundary_crossings(
    t_s: np.ndarray, y_smooth: np.ndarray, road: HighwayMap, hysteresis_m: float
) -> list[tuple[float, int, int]]:
    """Lane changes of a smoothed lateral track.

    :param t_s: sample times, sorted [s]
    :param y_smooth: smoothed lateral positions [m]
    :param road: the map
    :param hysteresis_m: how far past a lane boundary the track must go for a crossing to count [m]
    :return: ``(t_cross_s, from_lane, to_lane)`` for each crossing confirmed by the hysteresis
    """
    if len(t_s) == 0:
        return []
    w = road.lane_width_m
    lane = road.lane_of_one(y_smooth[0])
    out: list[tuple[float, int, int]] = []
    i = 1
    while i < len(t_s):
        # the next sample beyond the current lane's boundaries (+ hysteresis); found for all
        # samples at once, the same comparisons as a sample-by-sample scan
        upper = road.first_lane_y_m + (lane + 0.5) * w
        lower = road.first_lane_y_m + (lane - 0.5) * w
        rest = y_smooth[i:]
        up = rest > upper + hysteresis_m if lane < road.n_lanes - 1 else np.zeros(len(rest), dtype=bool)
        down = rest < lower - hysteresis_m if lane > 0 else np.zeros(len(rest), dtype=bool)
        hit = np.flatnonzero(up | down)
        if len(hit) == 0:
            break
        i += int(hit[0])
        if up[hit[0]]:
            new, boundary = lane + 1, upper
        else:
            new, boundary = lane - 1, lower
        # last sample still on the old side of the boundary, then interpolate the crossing
        j = i
        while j > 0 and (y_smooth[j - 1] - boundary) * (new - lane) > 0:
            j -= 1
        if j == 0:
            t_c = float(t_s[0])
        else:
            y0, y1 = y_smooth[j - 1] - boundary, y_smooth[j] - boundary
            frac = y0 / (y0 - y1) if y0 != y1 else 0.0
            t_c = float(t_s[j - 1] + frac * (t_s[j] - t_s[j - 1]))
        out.append((t_c, lane, new))
        lane = new
        i += 1
    return out


_DURATIONS_S = np.geomspace(0.3, 10.0, 48)
_OFFSETS_S = np.arange(-2.0, 2.0001, 0.05)


def fit_ramp(t_s: np.ndarray, y: np.ndarray, t_guess_s: float, dy_m: float) -> tuple[float, float]:
    """Least-squares fit of a lateral ramp of known height to raw samples.

    :param t_s: sample times [s]
    :param y: raw lateral positions [m]
    :param t_guess_s: first guess of the ramp's mid-time [s]
    :param dy_m: signed height of the ramp (lane offset) [m]
    :return: ``(t_mid_s, duration_s)``
    """
    t0 = t_guess_s + _OFFSETS_S[:, None, None]  # (O, 1, 1)
    dur = _DURATIONS_S[None, :, None]  # (1, D, 1)
    r = np.clip((t_s[None, None, :] - t0) / dur + 0.5, 0.0, 1.0) * dy_m  # (O, D, N)
    resid = y[None, None, :] - r
    resid -= resid.mean(axis=2, keepdims=True)  # best offset a for each (t0, T)
    sse = np.einsum("odn,odn->od", resid, resid)
    o, d = np.unravel_index(int(np.argmin(sse)), sse.shape)
    return float(t_guess_s + _OFFSETS_S[o]), float(_DURATIONS_S[d])


def accepted_gap_s(
    store: FixStore, vehicle_id: int, t_s: float, x_m: float, to_lane: int, road: HighwayMap,
    vehicle_length_m: float = 5.0,
) -> float:
    """Time gap the new follower is left with, from the other vehicles' own fixes.

    :param store: the fix store
    :param vehicle_id: the vehicle that changes lane
    :param t_s: time of the crossing [s]
    :param x_m: its position along the road then [m]
    :param to_lane: the lane it moves to
    :param road: the map
    :param vehicle_length_m: length assumed for the bumper gap [m]
    :return: bumper gap / follower speed [s] for the nearest vehicle behind in ``to_lane``
        at time ``t_s``; ``inf`` when no connected vehicle was there
    """
    best = math.inf
    for other in store.vehicle_ids():
        if other == vehicle_id:
            continue
        h = store.history(other)
        if len(h) < 2 or not h[0, 0] <= t_s <= h[-1, 0]:
            continue
        xo = float(np.interp(t_s, h[:, 0], h[:, 1]))
        yo = float(np.interp(t_s, h[:, 0], h[:, 2]))
        if int(road.lane_of(yo)) != to_lane or xo >= x_m:
            continue
        vo = max(float(np.interp(t_s, h[:, 0], h[:, 3])), 1.0)
        best = min(best, max(x_m - xo - vehicle_length_m, 0.0) / vo)
    return best


def posterior_aggressive(n_sudden: int, observed_s: float, cfg: TaggerConfig) -> float:
    """Posterior probability that a driver is aggressive (Poisson-rate likelihood ratio).

    :param n_sudden: sudden lane changes seen
    :param observed_s: time the driver was observed [s]
    :param cfg: tagger configuration (rates, prior)
    :return: probability in (0, 1)
    """
    ra, rn = cfg.rate_aggressive_per_min / 60.0, cfg.rate_normal_per_min / 60.0
    log_odds = (
        math.log(cfg.prior_aggressive / (1.0 - cfg.prior_aggressive))
        + n_sudden * math.log(ra / rn)
        - (ra - rn) * observed_s
    )
    return 1.0 / (1.0 + math.exp(-max(min(log_odds, 50.0), -50.0)))


@dataclass
class DriverRecord:
    """What the twin knows of one driver (bounded: evidence keeps the last ``max_evidence``).

    :param vehicle_id: stable id
    :param first_seen_s: twin time the record was made: the first analysis of the driver's
        fixes (within one tagger update of the first fix's arrival) [s]
    :param observed_s: time with fixes [s]
    :param n_lane_changes: lane changes seen
    :param n_sudden: sudden lane changes seen
    :param tag: ``"aggressive"`` or ``"normal"``
    :param confidence: posterior probability of ``tag``
    :param first_aggressive_s: twin time the tag first became aggressive [s] (or None)
    :param evidence: the last sudden lane changes (with their times)

    The evidence model's tallies (kept in every record, filled by the tagger's ``evidence`` model only):
    ``n_timed`` lane changes whose lateral speed was timed, the largest of those speeds
    ``max_lateral_speed_mps`` [m/s], the smallest accepted gap ``min_gap_s`` [s]; ``n_samples``
    traffic samples (:meth:`Tagger.observe_traffic`) with the sums of speed [m/s], squared speed
    [m^2/s^2] and speed minus the traffic's median [m/s], ``n_following`` samples with a leader
    within ``FOLLOW_RANGE_M`` and the sum of the time headways to it ``headway_sum_s`` [s].
    """

    vehicle_id: int
    first_seen_s: float
    observed_s: float = 0.0
    n_lane_changes: int = 0
    n_sudden: int = 0
    tag: str = NORMAL
    confidence: float = 0.0
    first_aggressive_s: float | None = None
    evidence: list[LaneChange] = field(default_factory=list)
    last_fix_s: float = -math.inf
    counted_until_s: float = -math.inf
    n_timed: int = 0
    max_lateral_speed_mps: float = 0.0
    min_gap_s: float = math.inf
    n_samples: int = 0
    speed_sum: float = 0.0
    speed_sq_sum: float = 0.0
    speed_rel_sum: float = 0.0
    n_following: int = 0
    headway_sum_s: float = 0.0


SAMPLE_WINDOW_S = 1.0
"""A traffic sample averages each vehicle's fixes of this last stretch [s]"""
FOLLOW_RANGE_M = 60.0
"""A vehicle ahead in the same lane within this bumper gap is the leader of a headway sample [m]"""
VEHICLE_LENGTH_M = 5.0
"""Length assumed for bumper gaps (the twin does not know the cars' lengths) [m]"""
EVIDENCE_WEIGHTS_FILE = "tagger_evidence.json"
"""The shipped weights of the evidence model, in this package"""
EVIDENCE_FEATURES = (
    "log_max_lateral_speed",  # log of the largest timed lateral speed of its lane changes (log 0.5 m/s if none) [log m/s]
    "has_timed_change",  # 1 when a lane change was timed
    "lane_changes_per_min",  # lane changes per observed minute [1/min]
    "sudden_per_min",  # sudden lane changes per observed minute [1/min]
    "min_gap",  # smallest accepted time gap to the new follower, capped at 3 s [s]
    "speed_rel",  # mean speed minus the traffic's median [m/s]
    "speed",  # mean speed [m/s]
    "headway",  # mean time headway while following, capped at 3 s (3 if never) [s]
    "following_share",  # share of samples with a leader within FOLLOW_RANGE_M [-]
    "speed_sd",  # standard deviation of the sampled speeds [m/s]
)
"""The evidence model's inputs, in order (:func:`evidence_features`)"""
EVIDENCE_FULL_S = 30.0
"""Observation after which the evidence model speaks alone (its training drivers were observed >= 30 s) [s]"""
_GAP_CAP_S = 3.0


def evidence_features(rec: DriverRecord) -> np.ndarray:
    """The evidence model's inputs of one driver (:data:`EVIDENCE_FEATURES`) from its record.

    :param rec: the driver's record
    :return: ``(len(EVIDENCE_FEATURES),)`` features
    """
    minutes = max(rec.observed_s, 1.0) / 60.0
    n = max(rec.n_samples, 1)
    mean_v = rec.speed_sum / n
    return np.array([
        math.log(rec.max_lateral_speed_mps) if rec.n_timed and rec.max_lateral_speed_mps > 0 else math.log(0.5),
        float(rec.n_timed > 0),
        rec.n_lane_changes / minutes,
        rec.n_sudden / minutes,
        min(rec.min_gap_s, _GAP_CAP_S),
        rec.speed_rel_sum / n,
        mean_v,
        min(rec.headway_sum_s / rec.n_following, _GAP_CAP_S) if rec.n_following else _GAP_CAP_S,
        rec.n_following / n,
        math.sqrt(max(rec.speed_sq_sum / n - mean_v * mean_v, 0.0)),
    ])


@dataclass(frozen=True)
class EvidenceModel:
    """Logistic model of P(aggressive) from :data:`EVIDENCE_FEATURES`:
    ``sigmoid(bias + weights . (features - mean) / scale)``.

    :param mean: the training features' means
    :param scale: their standard deviations
    :param weights: one weight per feature
    :param bias: the intercept
    """

    mean: np.ndarray
    scale: np.ndarray
    weights: np.ndarray
    bias: float

    @staticmethod
    def load(path: str | Path | None = None) -> EvidenceModel:
        """Read weights written by :meth:`save` (``None``: the shipped file).

        :param path: the JSON file (``None``: the shipped one)
        :return: the model
        :raises ConfigError: one line, when the file is missing, not JSON, or names other features
        """
        file = Path(__file__).with_name(EVIDENCE_WEIGHTS_FILE) if path is None else Path(path)
        try:
            d = json.loads(file.read_text())
            names = tuple(d["features"])
            model = EvidenceModel(np.asarray(d["mean"], float), np.asarray(d["scale"], float),
                                  np.asarray(d["weights"], float), float(d["bias"]))
        except KeyError as e:
            raise ConfigError(f"twin.tagger.evidence_weights: {file} has no {e} (a file of dt-highway train-tagger "
                              "holds features, mean, scale, weights and bias)") from None
        except (OSError, ValueError, TypeError) as e:
            what = "not an object of features, mean, scale, weights and bias" if isinstance(e, TypeError) else e
            raise ConfigError(f"twin.tagger.evidence_weights: cannot read {file} ({what})") from None
        if names != EVIDENCE_FEATURES or not (len(model.mean) == len(model.scale) == len(model.weights) == len(names)):
            raise ConfigError(f"twin.tagger.evidence_weights: {file} holds other features than {', '.join(EVIDENCE_FEATURES)}")
        return model

    def save(self, path: str | Path, **meta: object) -> None:
        """Write the weights (and ``meta``, e.g. the training seeds) as JSON.

        :param path: the JSON file to write (its folder is created)
        :param meta: entries written beside the weights
        """
        d = {"features": list(EVIDENCE_FEATURES), "mean": self.mean.tolist(), "scale": self.scale.tolist(),
             "weights": self.weights.tolist(), "bias": self.bias, **meta}
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        Path(path).write_text(json.dumps(d, indent=1) + "\n")

    def probability(self, features: np.ndarray, observed_s: float = math.inf, prior: float = 0.2) -> float:
        """P(aggressive) for one driver's features. The model was fitted on drivers observed for at least
        ``EVIDENCE_FULL_S``; before that its log-odds are blended with the prior's, in proportion to the
        time observed (a few seconds of fixes do not make a verdict).

        :param features: :func:`evidence_features`
        :param observed_s: how long the driver has been observed [s]
        :param prior: the prior probability of an aggressive driver [-]
        :return: the probability, in (0, 1)
        """
        s = self.bias + float(self.weights @ ((features - self.mean) / self.scale))
        share = min(max(observed_s / EVIDENCE_FULL_S, 0.0), 1.0)
        s = share * s + (1.0 - share) * math.log(prior / (1.0 - prior))
        return 1.0 / (1.0 + math.exp(-max(min(s, 50.0), -50.0)))


class Tagger:
    """Keeps a :class:`DriverRecord` per vehicle and updates it from the store.

    :param config: tagger configuration
    :param road: the map (lane geometry)
    """

    MAX_OBSERVED_GAP_S = 2.0
    """A silence longer than this between fixes does not count as observed time [s]"""
    MIN_SMOOTHING_SAMPLES = 5
    """The smoothing window spans at least this many fixes (matters at low fix rates)"""
    HYSTERESIS_SIGMAS = 2.5
    """A crossing must exceed this many standard deviations of the smoothed lateral position
    (and at least ``hysteresis_m``): with poor fixes the twin misses lane changes rather
    than inventing them"""
    MIN_INTERVALS_PER_MOVE = 3.0
    """The lateral speed is judged only if a move at the sudden threshold spans this many fix
    intervals (at 1 Hz it does not: only the gap criterion is left)"""
    GAP_MAX_SIGMA_M = 0.5
    """The gap criterion is used only if the smoothed lateral position is this precise [m]"""
    MIN_FIT_SAMPLES = 4
    """Fewest fixes in the fit window to estimate a lane change's lateral speed"""
    MAX_JUMP_M = 30.0
    """A move this far from where the last fix and speed predict starts a new track [m]"""

    def __init__(self, config: TaggerConfig, road: HighwayMap) -> None:
        self.config = config
        self.road = road
        self.records: dict[int, DriverRecord] = {}
        self.evidence_model = EvidenceModel.load(config.evidence_weights) if config.model == "evidence" else None
        self.tracks_traffic = self.evidence_model is not None
        """Whether :meth:`observe_traffic` tallies the drivers' longitudinal behaviour (the evidence model's
        inputs; a training harness switches it on with the ``sudden`` model too)"""
        self.on_lane_change: Callable[[int, LaneChange], None] | None = None
        """Optional callback, called with (vehicle_id, lane change) for every judged change"""

    def record(self, vehicle_id: int, now_s: float) -> DriverRecord:
        """A vehicle's driver record, made on first use.

        :param vehicle_id: the vehicle
        :param now_s: twin time [s] (a new record's ``first_seen_s``)
        :return: the record of a vehicle, created (with the prior's tag) when new.
        """
        rec = self.records.get(vehicle_id)
        if rec is None:
            rec = self.records[vehicle_id] = DriverRecord(vehicle_id, first_seen_s=now_s)
            self._retag(rec, now_s)
        return rec

    def update(self, store: FixStore, vehicle_id: int, now_s: float) -> DriverRecord:
        """Analyse a vehicle's history again and refresh its tag.

        :param store: the fix store
        :param vehicle_id: the vehicle
        :param now_s: twin time [s]
        :return: its record
        """
        cfg = self.config
        rec = self.record(vehicle_id, now_s)
        h = store.history(vehicle_id)
        if len(h) == 0:
            return rec
        t, x, y = h[:, 0], h[:, 1], h[:, 2]
        # observed time: new fixes since last update, silences capped
        new = t[t.searchsorted(rec.last_fix_s, side="right"):]  # t is sorted: the fixes after the last one seen
        if len(new):
            step = np.empty(len(new))
            step[0] = new[0] - (rec.last_fix_s if math.isfinite(rec.last_fix_s) else new[0])
            step[1:] = new[1:] - new[:-1]
            rec.observed_s += float(np.minimum(step, self.MAX_OBSERVED_GAP_S, out=step).sum())
            rec.last_fix_s = float(new[-1])
        # analyse only the newest stretch without silences or jumps (a vehicle may leave and
        # come back elsewhere)
        dt = t[1:] - t[:-1]  # np.diff, without its per-call cost
        dt_median = median(dt) if len(dt) else math.nan
        max_gap = max(self.MAX_OBSERVED_GAP_S, 3.0 * dt_median) if len(dt) else self.MAX_OBSERVED_GAP_S
        jump = np.hypot((x[1:] - x[:-1]) - h[1:, 3] * dt, y[1:] - y[:-1])
        gaps = ((dt > max_gap) | (jump > self.MAX_JUMP_M)).nonzero()[0]
        if len(gaps):
            start = int(gaps[-1]) + 1
            t, x, y = t[start:], x[start:], y[start:]
            dt_median = median(t[1:] - t[:-1]) if len(t) >= 2 else math.nan
        if len(t) < 2:
            self._retag(rec, now_s)
            return rec
        # at low fix rates, average at least MIN_SMOOTHING_SAMPLES fixes
        dt_fix = dt_median
        window = max(cfg.smoothing_s, self.MIN_SMOOTHING_SAMPLES * dt_fix)
        ys = moving_average(t, y, window)
        half = cfg.fit_window_s
        need = min(half, 2.5)
        sigma_smoothed = self._smoothed_sigma_m(y, window / dt_fix)
        hysteresis = max(cfg.hysteresis_m, self.HYSTERESIS_SIGMAS * sigma_smoothed)
        # what these fixes can tell: a move as short as the sudden threshold must span
        # several fix intervals to be timed; gaps need lanes that are told apart reliably
        can_time = self.road.lane_width_m / cfg.sudden_lateral_speed_mps >= self.MIN_INTERVALS_PER_MOVE * dt_fix
        can_gap = sigma_smoothed <= self.GAP_MAX_SIGMA_M
        crossings = boundary_crossings(t, ys, self.road, hysteresis)
        for k, (t_c, lane_from, lane_to) in enumerate(crossings):
            if t_c <= rec.counted_until_s:
                continue
            if t[-1] < t_c + need:
                break  # not enough samples after the crossing yet: judge it at a later update
            rec.counted_until_s = t_c + 1.0
            if t_c - t[0] < need:
                continue  # the history starts in the middle of this lane change
            # fit window: +-fit_window_s, but never past half-way to a neighbouring crossing
            # (a driver who goes back and forth would otherwise look like one fast ramp)
            lo = t_c - half if k == 0 else max(t_c - half, (crossings[k - 1][0] + t_c) / 2)
            hi = t_c + half if k == len(crossings) - 1 else min(t_c + half, (crossings[k + 1][0] + t_c) / 2)
            sel = (t >= lo) & (t <= hi)
            dy = (lane_to - lane_from) * self.road.lane_width_m
            if can_time and sel.sum() >= self.MIN_FIT_SAMPLES:
                _, dur = fit_ramp(t[sel], y[sel], t_c, dy)
                speed = abs(dy) / dur
            else:  # too few fixes to time the move: only the accepted gap can tell
                dur, speed = math.nan, math.nan
            x_c = float(np.interp(t_c, t, x))
            gap = accepted_gap_s(store, vehicle_id, t_c, x_c, lane_to, self.road) if can_gap else math.nan
            sudden = bool(speed > cfg.sudden_lateral_speed_mps or gap < cfg.sudden_gap_s)  # NaN compares False
            lc = LaneChange(t_c, lane_from, lane_to, dur, speed, gap, sudden)
            rec.n_lane_changes += 1
            if speed == speed:  # timed (not NaN)
                rec.n_timed += 1
                rec.max_lateral_speed_mps = max(rec.max_lateral_speed_mps, speed)
            if gap == gap:
                rec.min_gap_s = min(rec.min_gap_s, gap)
            if self.on_lane_change is not None:
                self.on_lane_change(vehicle_id, lc)
            if sudden:
                rec.n_sudden += 1
                rec.evidence.append(lc)
                del rec.evidence[: -cfg.max_evidence]
        self._retag(rec, now_s)
        return rec

    @staticmethod
    def _smoothed_sigma_m(y: np.ndarray, n_window: float) -> float:
        """Standard deviation of the smoothed lateral position [m], from the track itself.

        The GNSS noise is estimated from the fix-to-fix differences (robust: the median
        absolute difference ignores the few samples of a lane change) and divided by the
        square root of the number of fixes the smoothing window averages (``n_window``).
        """
        if len(y) < 3:
            return 0.0
        sigma = 1.4826 * median(np.abs(y[1:] - y[:-1])) / math.sqrt(2.0)
        return sigma / math.sqrt(max(1.0, n_window))

    def observe_traffic(self, store: FixStore, now_s: float) -> None:
        """One traffic sample for every vehicle with a fix in the last second: speed, speed against
        the median of those vehicles, time headway to the nearest of them ahead in its lane (the evidence
        model's inputs; positions and speeds are means over that second of fixes).

        :param store: the fix store
        :param now_s: twin time [s]
        """
        rows = []
        for vid in store.vehicle_ids():
            h = store.history(vid)
            if len(h) == 0 or h[-1, 0] < now_s - SAMPLE_WINDOW_S:
                continue
            last = h[h[:, 0].searchsorted(h[-1, 0] - SAMPLE_WINDOW_S, side="right"):]
            rows.append((vid, float(last[:, 1].mean()), float(last[:, 2].mean()), float(last[:, 3].mean())))
        if not rows:
            return
        x = np.array([r[1] for r in rows])
        v = np.array([r[3] for r in rows])
        lane = self.road.lane_of(np.array([r[2] for r in rows]))
        v_median = median(v)
        for i, (vid, _, _, _) in enumerate(rows):
            rec = self.record(vid, now_s)
            rec.n_samples += 1
            rec.speed_sum += v[i]
            rec.speed_sq_sum += v[i] * v[i]
            rec.speed_rel_sum += v[i] - v_median
            ahead = np.where((lane == lane[i]) & (x > x[i]), x, np.inf)
            j = int(np.argmin(ahead))
            gap = ahead[j] - x[i] - VEHICLE_LENGTH_M
            if math.isfinite(gap) and gap < FOLLOW_RANGE_M:
                rec.n_following += 1
                rec.headway_sum_s += gap / max(v[i], 1.0)

    def _retag(self, rec: DriverRecord, now_s: float) -> None:
        if self.evidence_model is not None:
            p = self.evidence_model.probability(evidence_features(rec), rec.observed_s, self.config.prior_aggressive)
        else:
            p = posterior_aggressive(rec.n_sudden, rec.observed_s, self.config)
        if p >= self.config.threshold:
            rec.tag, rec.confidence = AGGRESSIVE, p
            if rec.first_aggressive_s is None:
                rec.first_aggressive_s = now_s
        else:
            rec.tag, rec.confidence = NORMAL, 1.0 - p

"""Surrogate safety metrics of the ego, sampled at simulation frequency (paper section IV-C).

Every definition, with its unit (the README's "Safety metrics" section repeats them):

* **leader**: the nearest vehicle ahead of the ego that overlaps the ego's lane laterally
  (its body reaches into the lane band; a vehicle cutting in counts from its first overlap).
* **gap** ``g`` [m]: bumper to bumper, ``x_leader - x_ego - (L_leader + L_ego) / 2``.
* **closing speed** ``dv`` [m/s]: ``v_ego - v_leader`` along the road; > 0 when closing in.
* **TTC** [s]: ``g / dv`` when ``dv > 0``, infinite when not closing or without a leader;
  0 when the vehicles already overlap (``g <= 0`` and closing).
* **DRAC** [m/s^2]: deceleration rate to avoid the crash, ``dv^2 / (2 g)`` when closing, else 0.
* **time headway** [s]: ``g / v_ego`` (with a leader and ``v_ego > 0.1 m/s``).
* **speed variance** [(km/h)^2]: sample variance (N - 1) of the ego's speed in km/h over the
  trial's simulation steps; its SD [km/h]; mean speed [km/h].
* **mean TTC** [s]: mean of the TTC samples that are closing and below ``ttc_cap_s`` (10 s);
  **minimum TTC** [s] over the trial, capped at ``ttc_cap_s`` (a trial that never closes below
  10 s scores 10 s, so that trial means stay meaningful).
* **TET** [s] and **TIT** [s^2] (Minderhoud & Bovy 2001) with threshold ``TTC* = 3 s``:
  ``TET = sum dt [0 <= TTC <= TTC*]``, ``TIT = sum dt (TTC* - TTC) [0 <= TTC <= TTC*]`` (the
  integral over the samples, one simulation step ``dt`` each).
* **hard braking**: onsets of ego deceleration of at least 3 m/s^2 (about 0.3 g).
* **lane changes**: changes of the ego's lane index; **collisions**: onsets of the ego's crash.
* **cut-in**: a vehicle becomes the leader by moving into the ego's lane (the ego kept its
  lane) with a gap below ``cut_in_range_m`` (60 m). For each: the ego's minimum TTC to that
  vehicle while it stays the leader (at most ``cut_in_window_s``, 10 s), and the ego's
  **reaction time**: from the cut-in to the first sample with the ego decelerating at
  ``reaction_decel_mps2`` (1 m/s^2) or more, within the window (NaN when it never does).

The per-step samples come from :class:`SafetyMonitor` (inside the env, from the simulator's
state: metrics are evaluation, not what a driver is shown); :func:`trial_metrics` turns a
trial's samples into the numbers above.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

if TYPE_CHECKING:
    from highway_env.vehicle.kinematics import Vehicle

TTC_STAR_S = 3.0
"""TET/TIT threshold TTC* [s] (SUMO's SSM device default)"""
TTC_CAP_S = 10.0
"""Mean TTC counts closing samples below this [s]"""
HARD_BRAKE_MPS2 = 3.0
"""Deceleration that counts as hard braking [m/s^2]"""
REACTION_DECEL_MPS2 = 1.0
"""Deceleration that counts as the ego's reaction to a cut-in [m/s^2]"""
CUT_IN_RANGE_M = 60.0
"""A vehicle entering the ego's lane closer than this gap is a cut-in [m]"""
CUT_IN_WINDOW_S = 10.0
"""A cut-in's minimum TTC and reaction time are looked for within this time [s]"""
MS_TO_KMH = 3.6


def time_to_collision(gap_m: float, closing_mps: float) -> float:
    """TTC [s]: ``gap / closing speed``; infinite when not closing, 0 when already overlapping."""
    if not closing_mps > 0.0:
        return math.inf
    return max(gap_m, 0.0) / closing_mps


def drac(gap_m: float, closing_mps: float) -> float:
    """Deceleration rate to avoid the crash [m/s^2]: ``dv^2 / (2 gap)`` when closing, else 0."""
    if not closing_mps > 0.0:
        return 0.0
    if gap_m <= 0.0:
        return math.inf
    return closing_mps * closing_mps / (2.0 * gap_m)


def time_exposed(ttc_s: np.ndarray, dt_s: float, ttc_star_s: float = TTC_STAR_S) -> tuple[float, float]:
    """TET [s] and TIT [s^2] of a TTC series sampled every ``dt_s`` (Minderhoud & Bovy 2001).

    :param ttc_s: TTC per sample [s] (inf: no conflict)
    :param dt_s: sample period [s]
    :param ttc_star_s: threshold TTC* [s]
    :return: ``(TET, TIT)``
    """
    ttc = np.asarray(ttc_s, dtype=float)
    exposed = (ttc >= 0.0) & (ttc <= ttc_star_s)
    return float(exposed.sum() * dt_s), float(np.where(exposed, ttc_star_s - ttc, 0.0).sum() * dt_s)


@dataclass
class SafetySample:
    """The ego's safety state at one simulation step.

    :param t_s: simulation time [s]
    :param x_m: ego position along the road [m]
    :param y_m: ego lateral position [m]
    :param lane: ego lane index
    :param speed_mps: ego speed [m/s]
    :param accel_mps2: ego acceleration over the last step [m/s^2]
    :param leader_id: the leader's id (-1: none)
    :param gap_m: bumper-to-bumper gap to the leader [m] (inf: none)
    :param closing_mps: closing speed on the leader [m/s] (0: none)
    :param ttc_s: time to collision [s]
    :param drac_mps2: deceleration rate to avoid the crash [m/s^2]
    :param headway_s: time headway [s] (inf: none)
    :param crashed: the ego has crashed
    """

    t_s: float
    x_m: float
    y_m: float
    lane: int
    speed_mps: float
    accel_mps2: float
    leader_id: int
    gap_m: float
    closing_mps: float
    ttc_s: float
    drac_mps2: float
    headway_s: float
    crashed: bool

    def to_dict(self) -> dict[str, Any]:
        """The sample as a flat dict."""
        return asdict(self)


@dataclass
class CutIn:
    """A vehicle that moved into the ego's lane ahead of it.

    :param t_s: time of the first overlap [s]
    :param vehicle_id: the cutting vehicle
    :param gap_m: gap at that moment [m]
    """

    t_s: float
    vehicle_id: int
    gap_m: float


@dataclass
class SafetyMonitor:
    """Samples the ego's leader, gap, TTC and the like at every simulation step, and spots cut-ins.

    :param lane_width_m: lane width [m]
    :param cut_in_range_m: largest gap at which a lane entry counts as a cut-in [m]
    """

    lane_width_m: float = 4.0
    cut_in_range_m: float = CUT_IN_RANGE_M
    _prev_speed: float | None = field(default=None, repr=False)
    _prev_lane: int | None = field(default=None, repr=False)
    _in_lane: set[int] = field(default_factory=set, repr=False)

    def reset(self) -> None:
        """Start a new episode."""
        self._prev_speed, self._prev_lane, self._in_lane = None, None, set()

    def sample(self, t_s: float, dt_s: float, ego: Vehicle, lane_centre_y_m: float, others: Sequence[Vehicle],
               ids: Sequence[int]) -> tuple[SafetySample, list[CutIn]]:
        """One step's sample.

        :param t_s: simulation time [s]
        :param dt_s: simulation step [s]
        :param ego: the ego (highway-env vehicle: ``position``, ``velocity``, ``speed``,
            ``lane_index``, ``LENGTH``, ``crashed``)
        :param lane_centre_y_m: lateral position of the centre of the ego's lane [m]
        :param others: the other vehicles
        :param ids: their ids
        :return: the sample and the cut-ins that started at this step
        """
        ex, ey = float(ego.position[0]), float(ego.position[1])
        lane = int(ego.lane_index[2]) if ego.lane_index else -1
        lane_y = lane_centre_y_m
        speed = float(ego.speed)
        accel = 0.0 if self._prev_speed is None else (speed - self._prev_speed) / dt_s
        v_ego = float(ego.velocity[0])
        leader, best = -1, math.inf
        lead_v = 0.0
        in_lane: set[int] = set()
        gaps: dict[int, float] = {}
        for v, vid in zip(others, ids, strict=True):
            dx = float(v.position[0]) - ex
            if dx <= 0.0:
                continue
            if abs(float(v.position[1]) - lane_y) >= (self.lane_width_m + v.WIDTH) / 2:
                continue
            gap = dx - (v.LENGTH + ego.LENGTH) / 2
            in_lane.add(vid)
            gaps[vid] = gap
            if gap < best:
                leader, best, lead_v = vid, gap, float(v.velocity[0])
        closing = v_ego - lead_v if leader >= 0 else 0.0
        ttc = time_to_collision(best, closing) if leader >= 0 else math.inf
        cut_ins = []
        kept_lane = self._prev_lane is None or self._prev_lane == lane
        if kept_lane and self._prev_lane is not None and leader >= 0 and leader not in self._in_lane \
                and best < self.cut_in_range_m:
            cut_ins.append(CutIn(t_s, leader, best))
        self._in_lane = in_lane
        self._prev_lane, self._prev_speed = lane, speed
        sample = SafetySample(
            t_s=t_s, x_m=ex, y_m=ey, lane=lane, speed_mps=speed, accel_mps2=accel, leader_id=leader,
            gap_m=best, closing_mps=closing, ttc_s=ttc, drac_mps2=drac(best, closing) if leader >= 0 else 0.0,
            headway_s=best / speed if leader >= 0 and speed > 0.1 else math.inf, crashed=bool(ego.crashed),
        )
        return sample, cut_ins


def _onsets(flags: np.ndarray) -> int:
    """Number of False -> True transitions (a True first sample counts)."""
    f = np.asarray(flags, dtype=bool)
    if not len(f):
        return 0
    return int(f[0]) + int(np.count_nonzero(f[1:] & ~f[:-1]))


def cut_in_outcomes(steps: pd.DataFrame, cut_ins: Sequence[dict[str, Any]], window_s: float = CUT_IN_WINDOW_S,
                    reaction_decel_mps2: float = REACTION_DECEL_MPS2) -> list[dict[str, Any]]:
    """For each cut-in: the ego's minimum TTC to the cutting vehicle and its reaction time.

    :param steps: the trial's samples (columns of :class:`SafetySample`)
    :param cut_ins: cut-in events with ``t_s`` and ``vehicle_id``
    :param window_s: how long after the cut-in to look [s]
    :param reaction_decel_mps2: deceleration that counts as a reaction [m/s^2]
    :return: per cut-in: ``t_s``, ``vehicle_id``, ``min_ttc_s``, ``reaction_s``
    """
    t = steps["t_s"].to_numpy(float)
    out = []
    for ev in cut_ins:
        t0, vid = float(ev["t_s"]), int(ev["vehicle_id"])
        win = (t >= t0) & (t <= t0 + window_s)
        led = win & (steps["leader_id"].to_numpy() == vid)
        # while it stays the leader, from the cut-in on
        idx = np.flatnonzero(win)
        if len(idx):
            lead_run = led[idx]
            stop = np.argmin(lead_run) if not lead_run.all() else len(lead_run)
            run = idx[:stop]
        else:
            run = idx
        min_ttc = float(steps["ttc_s"].to_numpy(float)[run].min()) if len(run) else math.inf
        brake = np.flatnonzero(win & (steps["accel_mps2"].to_numpy(float) <= -reaction_decel_mps2))
        reaction = float(t[brake[0]] - t0) if len(brake) else math.nan
        out.append({"t_s": t0, "vehicle_id": vid, "min_ttc_s": min_ttc, "reaction_s": reaction})
    return out


def trial_metrics(steps: pd.DataFrame, dt_s: float, cut_ins: Sequence[dict[str, Any]] = (),
                  ttc_star_s: float = TTC_STAR_S, ttc_cap_s: float = TTC_CAP_S,
                  hard_brake_mps2: float = HARD_BRAKE_MPS2) -> dict[str, Any]:
    """Every metric of one trial from its per-step samples (definitions: module docstring).

    :param steps: the samples, one row per simulation step (columns of :class:`SafetySample`)
    :param dt_s: simulation step [s]
    :param cut_ins: the trial's cut-in events (``t_s``, ``vehicle_id``)
    :param ttc_star_s: TET/TIT threshold [s]
    :param ttc_cap_s: mean TTC counts closing samples below this; minimum TTCs are capped
        at it (a trial or cut-in that never closes below it scores the cap) [s]
    :param hard_brake_mps2: deceleration that counts as hard braking [m/s^2]
    :return: flat dict of metrics (units in the names)
    """
    n = len(steps)
    speed_kmh = steps["speed_mps"].to_numpy(float) * MS_TO_KMH
    ttc = steps["ttc_s"].to_numpy(float)
    closing = steps["closing_mps"].to_numpy(float)
    capped = ttc[(closing > 0) & (ttc < ttc_cap_s)]
    tet, tit = time_exposed(ttc, dt_s, ttc_star_s)
    hw = steps["headway_s"].to_numpy(float)
    hw = hw[np.isfinite(hw)]
    lanes = steps["lane"].to_numpy()
    outcomes = cut_in_outcomes(steps, cut_ins)
    cut_ttc = [min(o["min_ttc_s"], ttc_cap_s) for o in outcomes]
    reactions = [o["reaction_s"] for o in outcomes if math.isfinite(o["reaction_s"])]
    return {
        "duration_s": n * dt_s,
        "n_samples": n,
        "speed_mean_kmh": float(speed_kmh.mean()) if n else math.nan,
        "speed_variance_kmh2": float(speed_kmh.var(ddof=1)) if n > 1 else math.nan,
        "speed_sd_kmh": float(speed_kmh.std(ddof=1)) if n > 1 else math.nan,
        "ttc_mean_s": float(capped.mean()) if len(capped) else math.nan,
        "ttc_min_s": float(min(ttc.min(), ttc_cap_s)) if n else ttc_cap_s,
        "tet_s": tet,
        "tit_s2": tit,
        "drac_max_mps2": float(steps["drac_mps2"].max()) if n else 0.0,
        "headway_mean_s": float(hw.mean()) if len(hw) else math.nan,
        "headway_min_s": float(hw.min()) if len(hw) else math.nan,
        "collisions": _onsets(steps["crashed"].to_numpy(bool)),
        "hard_brakes": _onsets(steps["accel_mps2"].to_numpy(float) <= -hard_brake_mps2),
        "lane_changes": int(np.count_nonzero(lanes[1:] != lanes[:-1])) if n > 1 else 0,
        "cut_ins": len(outcomes),
        "cut_in_ttc_min_s": float(min(cut_ttc)) if cut_ttc else math.nan,
        "cut_in_ttc_mean_s": float(np.mean(cut_ttc)) if cut_ttc else math.nan,
        "reaction_mean_s": float(np.mean(reactions)) if reactions else math.nan,
    }

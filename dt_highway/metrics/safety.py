"""Surrogate safety metrics of the ego, sampled at simulation frequency (paper section IV-C).

Every definition, with its unit (the docs' "Safety metrics" page shows this text):

* **samples**: one after each simulation step, at ``t = dt, 2 dt, ..., T`` (the state the
  step produced); the state at reset (``t = 0``) primes the monitor (previous speed, lane, who
  is in the lane) and is not a sample. A trial of ``T`` s at ``f`` Hz has ``T f`` samples
  (120 s at 15 Hz: 1800; one decision's steps more when highway-env's clock, a float sum, falls just
  short of ``T``: a keyboard trial, 30 decisions a second, of 10 or 120 s has 301 or 3601) and lasts
  ``duration_s = n dt``; a crash, which ends the episode,
  is always the last sample.
* **footprint** of a vehicle: its rectangle (``LENGTH`` x ``WIDTH``, turned by its heading);
  its longitudinal and lateral **extents** are the half sizes of that rectangle's box along and
  across the road, ``(L/2)|cos h| + (W/2)|sin h|`` and ``(L/2)|sin h| + (W/2)|cos h|``.
* **the ego's path**: the band of the ego's width along the road, ``y_ego +/- W_ego / 2``.
* **leader**: the nearest vehicle ahead (centre ahead of the ego's) whose lateral extent
  overlaps the ego's path (its body reaches into the ego's body band; not the lane band: while
  the ego changes lanes a car 5 m ahead across its path leads, not one 47 m ahead in the lane).
* **gap** ``g`` [m]: bumper to bumper, ``x_leader - x_ego - ext_long_leader - L_ego / 2``.
* **closing speed** ``dv`` [m/s]: ``v_ego - v_leader`` along the road; > 0 when closing in.
* **contact** (``ttc_contact``): ``g <= 0`` with a leader, the leader's box overlaps the ego's
  body: the 1-D measure's collision state. Then ``ttc_s`` and ``drac_mps2`` are NaN (not 0):
  a contact is not a TTC sample and does not count in TET/TIT, mean or minimum TTC.
* **TTC** [s]: ``g / dv`` when ``dv > 0``, infinite when not closing or without a leader,
  NaN in contact.
* **DRAC** [m/s^2]: deceleration rate to avoid the crash, ``dv^2 / (2 g)`` when closing, else
  0; NaN in contact. A trial's maximum DRAC is capped at :data:`DRAC_CAP_MPS2` (10 m/s^2, about 1 g).
* **time headway** [s]: ``g / v_ego`` (with a leader and ``v_ego > 0.1 m/s``).
* **2-D TTC** (``ttc2d_s``, ``ttc2d_id``) [s]: the smallest, over the vehicles within
  ``range_2d_m`` (100 m, centre to centre), of the time until the ego's footprint and theirs
  first touch, both keeping their velocity (:mod:`dt_highway.metrics.ttc2d`; Jiao 2023); inf
  when none is on a collision course; ``ttc2d_id`` the vehicle it is to (-1: none). When the
  ego's rectangle already touches another (``ttc2d_contact``) it is NaN and ``ttc2d_id`` is
  that vehicle.
* **speed variance** [(km/h)^2]: sample variance (N - 1) of the ego's speed in km/h over the
  trial's samples; its SD [km/h]; mean speed [km/h].
* **mean TTC** [s]: mean of the TTC samples that are closing and below ``ttc_cap_s`` (10 s);
  **minimum TTC** [s] over the trial, capped at ``ttc_cap_s`` (a trial that never closes below
  10 s scores 10 s, so that trial means stay meaningful); the same cap for the minimum 2-D TTC.
* **TET** [s] and **TIT** [s^2] (Minderhoud & Bovy 2001) with threshold ``TTC* = 3 s``:
  ``TET = sum dt [0 <= TTC <= TTC*]``, ``TIT = sum dt (TTC* - TTC) [0 <= TTC <= TTC*]`` (the
  integral over the samples, one simulation step ``dt`` each); ``tet2d_s``, ``tit2d_s2`` the
  same on the 2-D TTC. Contact samples (NaN) are not exposed samples.
* **conflicts** (``conflicts_2d``): onsets of ``2-D TTC < 1.5 s`` (``conflict_ttc_s``; a 2-D
  contact counts as below); per trial and per hour of trial time (``conflicts_2d_per_h``).
* **hard braking**: onsets of ego deceleration of at least 3 m/s^2 (about 0.3 g).
* **lane changes**: changes of the ego's lane index.
* **cut-in**: a vehicle ahead that enters the ego's lane (its lateral extent first reaches
  into the ego's lane band) while the ego keeps its lane (same lane index as the step before
  and no lane change under way: target lane = lane), and then enters the ego's path as its
  new leader with a gap below ``cut_in_range_m`` (60 m). The cut-in's time ``t_s`` is that
  first overlap with the ego's path (the moment it becomes the leader); the event also holds
  ``t_lane_s``, when it entered the lane. Keying on the lane band for the entry keeps the ego's
  own lane changes and lane-keeping drift from making cut-ins; keying on the path for the
  time matches the leader rule. For each cut-in, within ``cut_in_window_s`` (10 s):

  - **minimum TTC** to that vehicle while it stays the leader (contact samples left out;
    ``contact`` says whether there were any);
  - **reaction time**: from the cut-in to the first sample with the ego decelerating at
    ``reaction_decel_mps2`` (1 m/s^2) or more (NaN when it never does);
  - **PET** [s] along the ego's path (:func:`pet_along_path`): over every spot of the path the
    cutting car's rear passed while it led, the time from its rear leaving the spot to the
    ego's front reaching it, minimised; inf when the ego reaches none within the window, 0
    after a contact. The cutting car is ahead in the path while it leads, so it is always the
    first at a spot (the ego first would be a contact). Trials report its minimum and median
    over cut-ins, each capped at ``ttc_cap_s``.
* **collision**: onset of the ego's crash. Its **partner** is the vehicle whose footprint
  overlaps the ego's deepest (else the nearest crashed one); its **kind**: ``cut_in`` when the
  partner cut in in front of the ego within the last ``cut_in_collision_s`` (5 s); otherwise
  from the faces that met (:func:`~dt_highway.metrics.ttc2d.contact_axis`: the axis whose
  projections met last, going back at the current velocities): front/rear faces, ``rear_end``
  (``striker``: ``ego`` ran into a vehicle ahead, ``partner`` hit the ego from behind), sides,
  ``side_swipe``; ``lane_changer``: who was changing lanes (``ego``, ``partner``, ``both``,
  ``none``: lane index != target lane index, or lateral speed >= ``lane_change_mps``, 0.3 m/s).
  The trial log's ``collision`` event holds ``partner_id``, ``partner_type`` (its true driver
  type), ``collision_kind`` (the event's own ``kind`` is ``collision``), ``lane_changer`` and
  ``striker``; the trial metrics the first collision's as ``collision_kind``,
  ``collision_partner_id``, ``collision_partner_type``, ``collision_lane_changer``,
  ``collision_striker``. A trial is **cut short** (``cut_short``) when it ended before its
  configured duration with a collision.

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

from dt_highway.metrics.ttc2d import HEADING, LENGTH, VX, VY, WIDTH, X, Y, contact_axis, penetration_depth_m, ttc_2d_many

if TYPE_CHECKING:
    from highway_env.vehicle.kinematics import Vehicle

TTC_STAR_S = 3.0
"""TET/TIT threshold TTC* [s] (SUMO's SSM device default)"""
TTC_CAP_S = 10.0
"""Mean TTC counts closing samples below this; minimum TTC, 2-D TTC and PET are capped at it [s]"""
DRAC_CAP_MPS2 = 10.0
"""A trial's maximum DRAC is capped here [m/s^2]: about 1 g, the most a car brakes on dry asphalt (tyre-road
friction about 1); above it braking cannot avoid the crash, and in the last samples before a contact
``dv^2 / (2 gap)`` grows without bound (1e13 m/s^2 was seen), which would swamp any mean over trials"""
CONFLICT_TTC_S = 1.5
"""A conflict is an onset of 2-D TTC below this [s]"""
RANGE_2D_M = 100.0
"""2-D TTC is computed to the vehicles within this distance of the ego, centre to centre [m]"""
HARD_BRAKE_MPS2 = 3.0
"""Deceleration that counts as hard braking [m/s^2]"""
REACTION_DECEL_MPS2 = 1.0
"""Deceleration that counts as the ego's reaction to a cut-in [m/s^2]"""
CUT_IN_RANGE_M = 60.0
"""A vehicle entering the ego's path closer than this gap is a cut-in [m]"""
CUT_IN_WINDOW_S = 10.0
"""A cut-in's minimum TTC, reaction time and PET are looked for within this time [s]"""
CUT_IN_COLLISION_S = 5.0
"""A collision with a vehicle that cut in front of the ego this recently is of kind ``cut_in`` [s]"""
LANE_CHANGE_MPS = 0.3
"""A vehicle moving sideways at least this fast is changing lanes (collision kinds) [m/s]"""
MS_TO_KMH = 3.6
COLLISION_KINDS = ("rear_end", "side_swipe", "cut_in", "unknown")
"""Kinds of collision (module docstring)"""


def time_to_collision(gap_m: float, closing_mps: float) -> float:
    """TTC [s]: ``gap / closing speed``; infinite when not closing, NaN when already in contact (``gap <= 0``).

    :param gap_m: bumper-to-bumper gap [m]
    :param closing_mps: closing speed (> 0: closing) [m/s]
    :return: the TTC [s]
    """
    if gap_m <= 0.0:
        return math.nan
    if not closing_mps > 0.0:
        return math.inf
    return gap_m / closing_mps


def drac(gap_m: float, closing_mps: float) -> float:
    """Deceleration rate to avoid the crash [m/s^2]: ``dv^2 / (2 gap)`` when closing, else 0; NaN in contact.

    :param gap_m: bumper-to-bumper gap [m]
    :param closing_mps: closing speed (> 0: closing) [m/s]
    :return: the DRAC [m/s^2]
    """
    if gap_m <= 0.0:
        return math.nan
    if not closing_mps > 0.0:
        return 0.0
    return closing_mps * closing_mps / (2.0 * gap_m)


def time_exposed(ttc_s: np.ndarray, dt_s: float, ttc_star_s: float = TTC_STAR_S) -> tuple[float, float]:
    """TET [s] and TIT [s^2] of a TTC series sampled every ``dt_s`` (Minderhoud & Bovy 2001).

    :param ttc_s: TTC per sample [s] (inf: no conflict; NaN: contact, not exposed)
    :param dt_s: sample period [s]
    :param ttc_star_s: threshold TTC* [s]
    :return: ``(TET, TIT)``
    """
    ttc = np.asarray(ttc_s, dtype=float)
    exposed = (ttc >= 0.0) & (ttc <= ttc_star_s)
    return float(exposed.sum() * dt_s), float(np.where(exposed, ttc_star_s - ttc, 0.0).sum() * dt_s)


def pet_along_path(t_first_s: np.ndarray, first_rear_m: np.ndarray, t_second_s: np.ndarray,
                   second_front_m: np.ndarray) -> float:
    """Post-encroachment time [s] of two road users one behind the other on a path (1-D).

    The first occupies the path at the times ``t_first_s``, its rear at ``first_rear_m`` (along
    the path); the second's front is at ``second_front_m`` at ``t_second_s``. For each spot
    ``x`` between the first's rear at its first and last sample that the second's front
    reaches: PET(x) = (second's front reaches x) - (first's rear leaves x), both interpolated
    linearly between samples; the PET is the minimum over those spots (it is at a sample
    point of one of the two tracks, the functions being piecewise linear), floored at 0.
    Positions are made non-decreasing (nobody reverses on a highway).

    :param t_first_s: sample times of the first [s], increasing
    :param first_rear_m: its rear's position [m]
    :param t_second_s: sample times of the second [s], increasing
    :param second_front_m: its front's position [m] (same origin)
    :return: PET [s]; ``math.inf`` when the second reaches no such spot
    """
    t1, t2 = np.asarray(t_first_s, float), np.asarray(t_second_s, float)
    if not len(t1) or not len(t2):
        return math.inf
    rear = np.maximum.accumulate(np.asarray(first_rear_m, float))
    front = np.maximum.accumulate(np.asarray(second_front_m, float))
    lo, hi = rear[0], min(rear[-1], front[-1])
    if hi < lo:
        return math.inf
    xs = np.concatenate((rear, front, [lo, hi]))
    xs = xs[(xs >= lo) & (xs <= hi)]
    pet = np.interp(xs, front, t2) - np.interp(xs, rear, t1)
    return float(max(pet.min(), 0.0))


@dataclass
class Collision:
    """The ego's crash at its onset (kinds: module docstring).

    :param partner_id: the vehicle it crashed with (-1: none found)
    :param kind: ``rear_end``, ``side_swipe``, ``cut_in`` or ``unknown``
    :param lane_changer: who was changing lanes: ``ego``, ``partner``, ``both`` or ``none``
    :param striker: for a front/rear contact, who ran into whom: ``ego`` (into the vehicle
        ahead) or ``partner`` (into the ego from behind); ``None`` for a side contact
    """

    partner_id: int
    kind: str
    lane_changer: str
    striker: str | None


@dataclass
class SafetySample:
    """The ego's safety state after one simulation step.

    :param t_s: simulation time [s]
    :param x_m: ego position along the road [m]
    :param y_m: ego lateral position [m]
    :param lane: ego lane index
    :param speed_mps: ego speed [m/s]
    :param accel_mps2: ego acceleration over the last step [m/s^2]
    :param leader_id: the leader's id (-1: none)
    :param gap_m: bumper-to-bumper gap to the leader [m] (inf: none)
    :param closing_mps: closing speed on the leader [m/s] (0: none)
    :param ttc_s: time to collision [s] (inf: not closing; NaN: contact)
    :param drac_mps2: deceleration rate to avoid the crash [m/s^2] (NaN: contact)
    :param headway_s: time headway [s] (inf: none)
    :param crashed: the ego has crashed
    :param ttc_contact: the leader's box overlaps the ego's body (gap <= 0): collision state
    :param ttc2d_s: the smallest 2-D TTC to a vehicle within range [s] (inf: none; NaN: contact)
    :param ttc2d_id: the vehicle of that 2-D TTC, or the one in contact (-1: none)
    :param ttc2d_contact: the ego's rectangle touches another's
    :param collision: at the crash onset only: its partner and kind (not a ``steps.csv`` column)
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
    ttc_contact: bool = False
    ttc2d_s: float = math.inf
    ttc2d_id: int = -1
    ttc2d_contact: bool = False
    collision: Collision | None = None

    def to_dict(self) -> dict[str, Any]:
        """The sample as a flat dict (``collision`` a dict or ``None``).

        :return: field name -> value
        """
        return asdict(self)


@dataclass
class CutIn:
    """A vehicle that entered the ego's path ahead of it from the next lane.

    :param t_s: time of its first overlap with the ego's path (it became the leader) [s]
    :param vehicle_id: the cutting vehicle
    :param gap_m: gap at that moment [m]
    :param t_lane_s: when it entered the ego's lane (first overlap with the lane band) [s]
    """

    t_s: float
    vehicle_id: int
    gap_m: float
    t_lane_s: float = math.nan

    def to_dict(self) -> dict[str, Any]:
        """The cut-in as a flat dict.

        :return: field name -> value
        """
        return asdict(self)


def footprint_rows(vehicles: Sequence[Vehicle]) -> np.ndarray:
    """The footprints of highway-env vehicles, a row each (:func:`dt_highway.metrics.ttc2d.footprint_array`'s columns).

    The velocity is the speed along the heading, as highway-env's ``Vehicle.velocity`` property
    computes it (here for all vehicles at once: a fifth of the cost), unless the object stores a
    ``velocity`` of its own (an attribute, not a property), which is then used.

    :param vehicles: objects with ``position``, ``LENGTH``, ``WIDTH``, ``heading``, ``speed``
    :return: ``(N, 7)`` array ``x [m], y [m], length [m], width [m], heading [rad], vx [m/s], vy [m/s]``
    """
    n = len(vehicles)
    cols = np.array([(v.position[0], v.position[1], v.LENGTH, v.WIDTH, v.heading, v.speed) for v in vehicles],
                    dtype=float).reshape(n, 6)
    rows = np.empty((n, 7))
    rows[:, :VX] = cols[:, :VX]
    rows[:, VX], rows[:, VY] = cols[:, 5] * np.cos(cols[:, HEADING]), cols[:, 5] * np.sin(cols[:, HEADING])
    for i, v in enumerate(vehicles):
        stored = getattr(v, "__dict__", {}).get("velocity")
        if stored is not None:
            rows[i, VX:] = stored
    return rows


def _changing_lanes(vehicle: Vehicle, row: np.ndarray, lateral_mps: float) -> bool:
    """A lane change under way: target lane != lane, or moving sideways at ``lateral_mps`` or more."""
    target = getattr(vehicle, "target_lane_index", None)
    return (target is not None and target != vehicle.lane_index) or abs(float(row[VY])) >= lateral_mps


@dataclass
class _Scene:
    """One step's geometry, the ego against the others (arrays over the others)."""

    ego: np.ndarray
    rows: np.ndarray
    ids: np.ndarray
    dx: np.ndarray
    gap: np.ndarray
    in_path: np.ndarray
    in_lane: np.ndarray


@dataclass
class SafetyMonitor:
    """Samples the ego's leader, gap, TTC, 2-D TTC and the like after every simulation step, and
    spots cut-ins and collisions (definitions: the module docstring).

    :param lane_width_m: lane width [m]
    :param cut_in_range_m: largest gap at which an entry into the ego's path counts as a cut-in [m]
    :param range_2d_m: 2-D TTC to the vehicles within this distance [m]
    :param cut_in_collision_s: a crash with a vehicle that cut in this recently is a ``cut_in`` [s]
    :param lane_change_mps: lateral speed from which a vehicle counts as changing lanes [m/s]
    """

    lane_width_m: float = 4.0
    cut_in_range_m: float = CUT_IN_RANGE_M
    range_2d_m: float = RANGE_2D_M
    cut_in_collision_s: float = CUT_IN_COLLISION_S
    lane_change_mps: float = LANE_CHANGE_MPS
    _prev_speed: float | None = field(default=None, repr=False)
    _prev_lane: int | None = field(default=None, repr=False)
    _prev_crashed: bool = field(default=False, repr=False)
    _in_lane: set[int] = field(default_factory=set, repr=False)
    _in_path: set[int] = field(default_factory=set, repr=False)
    _entered: dict[int, float] = field(default_factory=dict, repr=False)
    _recent_cut_ins: dict[int, float] = field(default_factory=dict, repr=False)

    def reset(self) -> None:
        """Start a new episode."""
        self._prev_speed, self._prev_lane, self._prev_crashed = None, None, False
        self._in_lane, self._in_path, self._entered, self._recent_cut_ins = set(), set(), {}, {}

    def _scene(self, ego: Vehicle, lane_centre_y_m: float, others: Sequence[Vehicle], ids: Sequence[int]) -> _Scene:
        e = footprint_rows([ego])[0]
        rows = footprint_rows(others)
        c, s = np.abs(np.cos(rows[:, HEADING])), np.abs(np.sin(rows[:, HEADING]))
        ext_long = rows[:, LENGTH] / 2 * c + rows[:, WIDTH] / 2 * s
        ext_lat = rows[:, LENGTH] / 2 * s + rows[:, WIDTH] / 2 * c
        dx = rows[:, X] - e[X]
        ahead = dx > 0.0
        in_path = ahead & (np.abs(rows[:, Y] - e[Y]) < e[WIDTH] / 2 + ext_lat)
        in_lane = ahead & (np.abs(rows[:, Y] - lane_centre_y_m) < self.lane_width_m / 2 + ext_lat)
        return _Scene(e, rows, np.asarray(ids, dtype=int).reshape(len(rows)), dx, dx - ext_long - e[LENGTH] / 2,
                      in_path, in_lane)

    def _ttc_2d(self, sc: _Scene) -> tuple[float, int, bool]:
        """The smallest 2-D TTC to a vehicle within range, its id, and whether it is a contact."""
        near = np.flatnonzero(np.hypot(sc.dx, sc.rows[:, Y] - sc.ego[Y]) <= self.range_2d_m)
        if not len(near):
            return math.inf, -1, False
        ttc = ttc_2d_many(sc.ego[None, :], sc.rows[near])
        k = int(np.argmin(ttc))
        if ttc[k] == 0.0:  # touching: ttc_2d is exactly 0 then (and only then)
            return math.nan, int(sc.ids[near[k]]), True
        return (float(ttc[k]), int(sc.ids[near[k]]), False) if ttc[k] < math.inf else (math.inf, -1, False)

    def _cut_ins(self, t_s: float, sc: _Scene, leader: int, gap: float, kept_lane: bool) -> list[CutIn]:
        """Track who entered the ego's lane while it kept it; a cut-in when one of them enters the path as leader."""
        in_lane = {int(i) for i in sc.ids[sc.in_lane]}
        if kept_lane:
            for vid in in_lane - self._in_lane:
                self._entered[vid] = t_s
            self._entered = {vid: t for vid, t in self._entered.items() if vid in in_lane}
        else:
            self._entered = {}
        cut_ins = []
        if kept_lane and leader >= 0 and leader not in self._in_path and leader in self._entered \
                and gap < self.cut_in_range_m:
            cut_ins.append(CutIn(t_s, leader, gap, self._entered.pop(leader)))
            self._recent_cut_ins[leader] = t_s
        self._in_lane, self._in_path = in_lane, {int(i) for i in sc.ids[sc.in_path]}
        self._recent_cut_ins = {v: t for v, t in self._recent_cut_ins.items() if t_s - t <= self.cut_in_collision_s}
        return cut_ins

    def _collision(self, t_s: float, sc: _Scene, ego: Vehicle, others: Sequence[Vehicle]) -> Collision:
        """The partner and kind of a crash (module docstring)."""
        ego_lc = _changing_lanes(ego, sc.ego, self.lane_change_mps)
        k = -1
        if len(sc.rows):
            depth = penetration_depth_m(sc.ego[None, :], sc.rows)
            crashed = np.array([bool(getattr(v, "crashed", False)) for v in others])
            if depth.max() >= 0.0:
                k = int(np.argmax(depth))
            elif crashed.any():
                k = int(np.flatnonzero(crashed)[np.argmax(depth[crashed])])
        if k < 0:
            return Collision(-1, "unknown", "ego" if ego_lc else "none", None)
        partner = int(sc.ids[k])
        partner_lc = _changing_lanes(others[k], sc.rows[k], self.lane_change_mps)
        lane_changer = {(True, True): "both", (True, False): "ego", (False, True): "partner"}.get((ego_lc, partner_lc),
                                                                                                 "none")
        longitudinal = int(contact_axis(sc.ego[None, :], sc.rows[k:k + 1])[0]) in (0, 2)
        h = sc.ego[HEADING]
        ahead = (sc.rows[k, X] - sc.ego[X]) * math.cos(h) + (sc.rows[k, Y] - sc.ego[Y]) * math.sin(h) > 0.0
        striker = ("ego" if ahead else "partner") if longitudinal else None
        if partner in self._recent_cut_ins:
            kind = "cut_in"
        else:
            kind = "rear_end" if longitudinal else "side_swipe"
        return Collision(partner, kind, lane_changer, striker)

    def sample(self, t_s: float, dt_s: float, ego: Vehicle, lane_centre_y_m: float, others: Sequence[Vehicle],
               ids: Sequence[int]) -> tuple[SafetySample, list[CutIn]]:
        """One step's sample.

        :param t_s: simulation time [s]
        :param dt_s: simulation step [s]
        :param ego: the ego (highway-env vehicle: ``position``, ``velocity``, ``speed``, ``heading``,
            ``lane_index``, ``target_lane_index`` (optional), ``LENGTH``, ``WIDTH``, ``crashed``)
        :param lane_centre_y_m: lateral position of the centre of the ego's lane [m]
        :param others: the other vehicles (the same attributes)
        :param ids: their ids
        :return: the sample and the cut-ins that started at this step
        """
        lane = int(ego.lane_index[2]) if ego.lane_index else -1
        speed = float(ego.speed)
        accel = 0.0 if self._prev_speed is None else (speed - self._prev_speed) / dt_s
        sc = self._scene(ego, lane_centre_y_m, others, ids)
        leader, gap, closing = -1, math.inf, 0.0
        if sc.in_path.any():
            k = int(np.flatnonzero(sc.in_path)[np.argmin(sc.gap[sc.in_path])])
            leader, gap, closing = int(sc.ids[k]), float(sc.gap[k]), float(sc.ego[VX] - sc.rows[k, VX])
        ttc2d, ttc2d_id, contact_2d = self._ttc_2d(sc)
        target = getattr(ego, "target_lane_index", None)
        kept_lane = self._prev_lane == lane and (target is None or target == ego.lane_index)
        cut_ins = self._cut_ins(t_s, sc, leader, gap, kept_lane)
        crashed = bool(ego.crashed)
        collision = self._collision(t_s, sc, ego, others) if crashed and not self._prev_crashed else None
        self._prev_lane, self._prev_speed, self._prev_crashed = lane, speed, crashed
        sample = SafetySample(
            t_s=t_s, x_m=float(sc.ego[X]), y_m=float(sc.ego[Y]), lane=lane, speed_mps=speed, accel_mps2=accel,
            leader_id=leader, gap_m=gap, closing_mps=closing,
            ttc_s=time_to_collision(gap, closing) if leader >= 0 else math.inf,
            drac_mps2=drac(gap, closing) if leader >= 0 else 0.0,
            headway_s=gap / speed if leader >= 0 and speed > 0.1 else math.inf, crashed=crashed,
            ttc_contact=leader >= 0 and gap <= 0.0, ttc2d_s=ttc2d, ttc2d_id=ttc2d_id, ttc2d_contact=contact_2d,
            collision=collision,
        )
        return sample, cut_ins


def _onsets(flags: np.ndarray) -> int:
    """Number of False -> True transitions (a True first sample counts)."""
    f = np.asarray(flags, dtype=bool)
    if not len(f):
        return 0
    return int(f[0]) + int(np.count_nonzero(f[1:] & ~f[:-1]))


def _column(steps: pd.DataFrame, name: str, default: float) -> np.ndarray:
    """A numeric column, or ``default`` everywhere when the log has none (an older log)."""
    if name in steps:
        return steps[name].to_numpy(float)
    return np.full(len(steps), default)


def _leading_run(t: np.ndarray, leader: np.ndarray, t0: float, vid: int, window_s: float) -> tuple[np.ndarray, np.ndarray]:
    """The window's samples, and those from the cut-in on while the vehicle stays the leader."""
    win = (t >= t0) & (t <= t0 + window_s)
    idx = np.flatnonzero(win)
    lead_run = leader[idx] == vid
    stop = int(np.argmin(lead_run)) if not lead_run.all() else len(lead_run)
    return win, idx[:stop]


def cut_in_outcomes(steps: pd.DataFrame, cut_ins: Sequence[dict[str, Any]], window_s: float = CUT_IN_WINDOW_S,
                    reaction_decel_mps2: float = REACTION_DECEL_MPS2) -> list[dict[str, Any]]:
    """For each cut-in: the ego's minimum TTC to the cutting vehicle, its reaction time and the PET.

    :param steps: the trial's samples (columns of :class:`SafetySample`)
    :param cut_ins: cut-in events with ``t_s`` and ``vehicle_id``
    :param window_s: how long after the cut-in to look [s]
    :param reaction_decel_mps2: deceleration that counts as a reaction [m/s^2]
    :return: per cut-in: ``t_s``, ``vehicle_id``, ``min_ttc_s`` (inf: never closing, contact
        samples left out), ``contact`` (a contact while it led), ``reaction_s``, ``pet_s``
        (NaN in a log without positions)
    """
    t = steps["t_s"].to_numpy(float)
    leader = steps["leader_id"].to_numpy()
    ttc = steps["ttc_s"].to_numpy(float)
    accel = steps["accel_mps2"].to_numpy(float)
    has_path = "x_m" in steps and "gap_m" in steps
    x, gap = _column(steps, "x_m", math.nan), _column(steps, "gap_m", math.nan)
    out = []
    for ev in cut_ins:
        t0, vid = float(ev["t_s"]), int(ev["vehicle_id"])
        win, run = _leading_run(t, leader, t0, vid, window_s)
        finite = ttc[run][~np.isnan(ttc[run])]
        contact = bool(np.any(gap[run] <= 0.0)) if has_path else bool(np.isnan(ttc[run]).any())
        min_ttc = float(finite.min()) if len(finite) else math.inf
        brake = np.flatnonzero(win & (accel <= -reaction_decel_mps2))
        reaction = float(t[brake[0]] - t0) if len(brake) else math.nan
        if not has_path:
            pet = math.nan
        elif contact:
            pet = 0.0
        else:  # the ego's centre stands for its front: the same shift on both tracks
            pet = pet_along_path(t[run], x[run] + gap[run], t[win], x[win])
        out.append({"t_s": t0, "vehicle_id": vid, "min_ttc_s": min_ttc, "contact": contact, "reaction_s": reaction,
                    "pet_s": pet})
    return out


def _ttc_2d_metrics(steps: pd.DataFrame, dt_s: float, ttc_star_s: float, ttc_cap_s: float,
                    conflict_ttc_s: float) -> dict[str, Any]:
    """2-D TTC's minimum, TET/TIT and conflicts (NaN in a log without the column)."""
    n = len(steps)
    hours = n * dt_s / 3600.0
    if "ttc2d_s" not in steps:
        keys = ("ttc2d_min_s", "tet2d_s", "tit2d_s2", "ttc2d_contact_s", "conflicts_2d", "conflicts_2d_per_h")
        return dict.fromkeys(keys, math.nan)
    ttc = steps["ttc2d_s"].to_numpy(float)
    contact = np.isnan(ttc)
    tet, tit = time_exposed(ttc, dt_s, ttc_star_s)
    finite = ttc[~contact]
    conflicts = _onsets(contact | (ttc < conflict_ttc_s))
    return {
        "ttc2d_min_s": float(min(finite.min(), ttc_cap_s)) if len(finite) else ttc_cap_s,
        "tet2d_s": tet,
        "tit2d_s2": tit,
        "ttc2d_contact_s": float(contact.sum() * dt_s),
        "conflicts_2d": conflicts,
        "conflicts_2d_per_h": conflicts / hours if hours > 0 else math.nan,
    }


def _cut_in_metrics(steps: pd.DataFrame, cut_ins: Sequence[dict[str, Any]], ttc_cap_s: float) -> dict[str, Any]:
    outcomes = cut_in_outcomes(steps, cut_ins) if len(steps) else []
    cut_ttc = [min(o["min_ttc_s"], ttc_cap_s) for o in outcomes]
    reactions = [o["reaction_s"] for o in outcomes if math.isfinite(o["reaction_s"])]
    pets = [min(o["pet_s"], ttc_cap_s) for o in outcomes if not math.isnan(o["pet_s"])]
    return {
        "cut_ins": len(outcomes),
        "cut_in_ttc_min_s": float(min(cut_ttc)) if cut_ttc else math.nan,
        "cut_in_ttc_mean_s": float(np.mean(cut_ttc)) if cut_ttc else math.nan,
        "cut_in_contacts": sum(o["contact"] for o in outcomes),
        "reaction_mean_s": float(np.mean(reactions)) if reactions else math.nan,
        "pet_min_s": float(min(pets)) if pets else math.nan,
        "pet_median_s": float(np.median(pets)) if pets else math.nan,
    }


def collision_label(kind: str | None, striker: str | None = None, lane_changer: str | None = None) -> str:
    """A short readable label of a collision's kind (for tables): e.g. ``rear_end: ego struck``.

    :param kind: :data:`COLLISION_KINDS`
    :param striker: ``ego`` or ``partner`` (rear-ends)
    :param lane_changer: ``ego``, ``partner``, ``both`` or ``none`` (side-swipes)
    :return: the label
    """
    if kind == "rear_end":
        return "rear_end: ego struck" if striker == "ego" else "rear_end: struck from behind"
    if kind == "side_swipe":
        return {"ego": "side_swipe: ego's lane change", "partner": "side_swipe: partner's lane change",
                "both": "side_swipe: both changing lanes"}.get(str(lane_changer), "side_swipe: no lane change")
    return str(kind or "unknown")


def _collision_metrics(steps: pd.DataFrame, dt_s: float, collisions: Sequence[dict[str, Any]] | None,
                       planned_duration_s: float | None) -> dict[str, Any]:
    """Number of collisions, the first one's partner and kind, and whether it cut the trial short."""
    crashed = steps["crashed"].to_numpy(bool) if len(steps) else np.zeros(0, bool)
    if collisions is None:  # samples straight from the env: the crash onset carries its collision
        collisions = [c for c in (steps["collision"] if "collision" in steps else []) if isinstance(c, dict)]
    first = collisions[0] if collisions else {}
    # an event's kind is "collision", its collision's kind is "collision_kind"; the samples' collision has "kind"
    kind = first.get("collision_kind") or (first.get("kind") if first.get("kind") in COLLISION_KINDS else None)
    ended_crashed = bool(len(crashed) and crashed[-1])
    if planned_duration_s is not None:
        short = ended_crashed and len(steps) * dt_s < planned_duration_s - dt_s / 2
    else:
        short = ended_crashed
    return {
        "collisions": _onsets(crashed),
        "collision_kind": (kind or "unknown") if first else "",
        "collision_partner_id": first.get("partner_id", -1) if first else -1,
        "collision_partner_type": first.get("partner_type") or "",
        "collision_lane_changer": first.get("lane_changer") or "",
        "collision_striker": first.get("striker") or "",
        "cut_short": bool(short),
    }


def trial_metrics(steps: pd.DataFrame, dt_s: float, cut_ins: Sequence[dict[str, Any]] = (),
                  ttc_star_s: float = TTC_STAR_S, ttc_cap_s: float = TTC_CAP_S,
                  hard_brake_mps2: float = HARD_BRAKE_MPS2, *, collisions: Sequence[dict[str, Any]] | None = None,
                  planned_duration_s: float | None = None, conflict_ttc_s: float = CONFLICT_TTC_S,
                  drac_cap_mps2: float = DRAC_CAP_MPS2) -> dict[str, Any]:
    """Every metric of one trial from its per-step samples (definitions: module docstring).

    :param steps: the samples, one row per simulation step (columns of :class:`SafetySample`)
    :param dt_s: simulation step [s]
    :param cut_ins: the trial's cut-in events (``t_s``, ``vehicle_id``)
    :param ttc_star_s: TET/TIT threshold [s]
    :param ttc_cap_s: mean TTC counts closing samples below this; minimum TTCs and PETs are
        capped at it (a trial or cut-in that never closes below it scores the cap) [s]
    :param hard_brake_mps2: deceleration that counts as hard braking [m/s^2]
    :param collisions: the trial's collision events (``partner_id``, ``partner_type``,
        ``collision_kind``, ``lane_changer``, ``striker``); ``None``: from the samples' ``collision``
        column (samples straight from the env: ``kind`` for the collision's kind), none without it
    :param planned_duration_s: the trial's configured duration [s] (``cut_short``: it ended
        earlier with a crash); ``None``: a trial that ends crashed counts as cut short
    :param conflict_ttc_s: a conflict is an onset of 2-D TTC below this [s]
    :param drac_cap_mps2: the maximum DRAC is capped at this (:data:`DRAC_CAP_MPS2`) [m/s^2]
    :return: flat dict of metrics (units in the names)
    """
    n = len(steps)
    speed_kmh = steps["speed_mps"].to_numpy(float) * MS_TO_KMH
    ttc = steps["ttc_s"].to_numpy(float)
    finite_ttc = ttc[~np.isnan(ttc)]
    closing = steps["closing_mps"].to_numpy(float)
    capped = ttc[(closing > 0) & (ttc < ttc_cap_s)]
    tet, tit = time_exposed(ttc, dt_s, ttc_star_s)
    hw = steps["headway_s"].to_numpy(float)
    hw = hw[np.isfinite(hw)]
    drac_v = steps["drac_mps2"].to_numpy(float)
    drac_v = drac_v[~np.isnan(drac_v)]
    lanes = steps["lane"].to_numpy()
    return {
        "duration_s": round(n * dt_s, 9),
        "n_samples": n,
        "speed_mean_kmh": float(speed_kmh.mean()) if n else math.nan,
        "speed_variance_kmh2": float(speed_kmh.var(ddof=1)) if n > 1 else math.nan,
        "speed_sd_kmh": float(speed_kmh.std(ddof=1)) if n > 1 else math.nan,
        "ttc_mean_s": float(capped.mean()) if len(capped) else math.nan,
        "ttc_min_s": float(min(finite_ttc.min(), ttc_cap_s)) if len(finite_ttc) else ttc_cap_s,
        "tet_s": tet,
        "tit_s2": tit,
        "ttc_contact_s": float(np.isnan(ttc).sum() * dt_s),
        "drac_max_mps2": float(min(drac_v.max(), drac_cap_mps2)) if len(drac_v) else 0.0,
        "headway_mean_s": float(hw.mean()) if len(hw) else math.nan,
        "headway_min_s": float(hw.min()) if len(hw) else math.nan,
        **_ttc_2d_metrics(steps, dt_s, ttc_star_s, ttc_cap_s, conflict_ttc_s),
        "hard_brakes": _onsets(steps["accel_mps2"].to_numpy(float) <= -hard_brake_mps2),
        "lane_changes": int(np.count_nonzero(lanes[1:] != lanes[:-1])) if n > 1 else 0,
        **_collision_metrics(steps, dt_s, collisions, planned_duration_s),
        **_cut_in_metrics(steps, cut_ins, ttc_cap_s),
    }

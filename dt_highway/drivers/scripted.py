"""Scripted drivers of the ego: plain IDM, a human-like driver, and a random one.

All drive through the ``"Driver"`` action (:mod:`dt_highway.env.actions`): one
decision per policy step, ``[acceleration m/s^2, lane request]``.

What a driver perceives (its :class:`~dt_highway.drivers.perception.Perception`, filled by the
env's senses, :mod:`dt_highway.env.senses`): the vehicles around it as a person in the driver's seat sees them
(positions and speeds of the nearest vehicle ahead and behind in its lane and the lanes
beside it; never their driver type), and, in the ADAS condition, the overlay: the boxes the
fusion marked "aggressive driver" on the camera image. A person knows which car a marker
sits on by looking at it, so the human-like driver takes the car whose visible outline in
the image best matches the marker's box (IoU >= 0.3): when the fusion put the label on the
wrong car, the driver is wary of the wrong car, and a missing marker warns of nothing.

The human-like driver (parameters in ``agents/human.toml``):

* car following: the Intelligent Driver Model (Treiber, Hennecke & Helbing 2000, Phys. Rev.
  E 62, 1805; their highway values ``T = 1.6 s``, ``s0 = 2 m``, ``a = 0.73 m/s^2``,
  ``b = 1.67 m/s^2``, ``delta = 4``), desired speed from the file;
* human limits after the Human Driver Model (Treiber, Kesting & Helbing 2006, Physica A 360,
  71): a reaction time ``T'`` (it acts on what it saw ``T'`` ago, anticipating the gap
  over ``T'`` at the closing speed it saw), and estimation errors that wander slowly
  (Wiener-like, correlation time 20 s): relative distance error ``V_s = 0.1``, inverse-TTC
  error ``r_c = 0.01 1/s``;
* lane changes: MOBIL (Kesting, Treiber & Helbing 2007, Transp. Res. Rec. 1999, 86) with
  politeness 0.2, threshold 0.2 m/s^2, safe braking 4 m/s^2, and at most one lane change per
  ``min_lane_change_interval_s``;
* in the ADAS condition, while a marked car is ahead in its lane or beside it (in a lane
  next to it, from ``alert_behind_m`` behind to ``alert_ahead_m`` ahead) and for
  ``alert_hold_s`` after: it keeps a longer time gap (``T x alert_headway_factor``), lowers
  its desired speed (``x alert_speed_factor``), reacts faster (``T' x alert_reaction_factor``:
  a warned driver is primed to brake), and eases off to leave room in front of itself for a
  marked car ahead in the next lane, as if that car were already in front (it expects the
  cut-in): it then decelerates by at most ``alert_ease_off_mps2`` (lifting off the throttle,
  not braking for a car that is not yet in its lane). These responses are our assumptions
  about a warned driver, not fitted to the paper's results.

  The ease-off limit was added after the first 30-pair study (docs: safety study): with comfortable
  braking (1.67 m/s^2) allowed there, the warned driver matched its speed to a marked car
  hovering in the next lane, and an aggressive driver positioning itself for a cut-in slowed
  with it, so that the ego went from 68 to 35 km/h with its own lane clear ahead: not what a
  person does on a highway.
* a threat cue ("CUTTING IN", ``overlay.mode = threat`` or ``both``): the driver reads the label
  and the side it names, and takes for the cutting-in car the marked car it sees on that side
  (in the lane next to it on that side, or already in its own lane) whose distance best matches
  the one printed on the mark. While the cue is shown and for ``alert_hold_s`` after, it

  - **covers the brake**: its foot leaves the throttle (no acceleration above 0) and its reaction
    time becomes ``T' x THREAT_REACTION_FACTOR``. The factor is Green's (2000, "How long does it
    take to stop? Methodological analysis of driver perception-brake times", Transportation
    Human Factors 2(3), 195-216) ratio of the brake reaction time of a driver who expects the
    signal (about 0.70-0.75 s) to that of an unexpected but common one such as a lead car's brake
    lights (about 1.25 s; a surprise event: about 1.5 s): 0.73 / 1.25 = 0.58, rounded to 0.6, so
    ``T' = 1.0 s`` becomes 0.6 s (shorter than the 0.7 s of the driver-type warning, which is our
    assumption, not a measured value);
  - **opens the gap** to that car: while it is ahead (in the next lane or already in the own
    lane) the driver follows it as if it were its leader, with the warned time gap
    (``T x alert_headway_factor``), braking up to IDM's comfortable deceleration ``b``
    (``THREAT_BRAKE`` x ``b``, 1.67 m/s^2 in the file; Treiber, Hennecke & Helbing 2000) instead of
    only lifting off the throttle (``alert_ease_off_mps2``): the twin predicts this car will
    move in within the horizon, so the driver makes room before it does. That braking level is
    our assumption (a comfortable, not an emergency, deceleration).

  The driver-type cue ("AGGRESSIVE DRIVER") keeps the response above; both apply when a car
  carries both.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any, TypeVar

import numpy as np

from dt_highway.agent_config import HumanParams, RandomParams
from dt_highway.drivers.base import ACCEL_MAX_MPS2, ACCEL_MIN_MPS2, Driver
from dt_highway.drivers.idm import IDMParams, idm_accel
from dt_highway.drivers.perception import Perception, Seen, SenseRequest, Surroundings

_P = TypeVar("_P")


def _settings(value: object, kind: type[_P], driver: str) -> _P:
    """A driver's parameters, of their type (a dict is refused: its mistakes would surface mid-trial)."""
    if not isinstance(value, kind):
        raise TypeError(f"{driver} takes {kind.__name__} (got {type(value).__name__}): {kind.__name__}(**values), "
                        "or a driver file with make_driver / load_driver")
    return value


class IDMDriver(Driver):
    """Plain IDM: perfect perception, no delay, stays in its lane, ignores the overlay.

    :param name: driver name
    :param idm: IDM parameters
    """

    senses = SenseRequest(surroundings=True)

    def __init__(self, name: str, idm: IDMParams) -> None:
        super().__init__(name)
        self.idm = _settings(idm, IDMParams, "IDMDriver")

    def params(self) -> dict[str, Any]:
        """The IDM parameters (for the trial log).

        :return: ``{"idm": the parameters by name}``
        """
        return {"idm": self.idm.model_dump()}

    def act(self, perception: Perception) -> np.ndarray:
        """IDM's acceleration behind the car ahead in the ego's lane; never changes lane.

        :param perception: what the driver perceives now (its surroundings)
        :return: the action ``[acceleration m/s^2, 0]``
        """
        s = _surroundings(perception)
        lead = s.ahead[0]
        a = idm_accel(s.speed_mps, lead.gap_m, s.speed_mps - lead.speed_mps, self.idm)
        return np.array([np.clip(a, ACCEL_MIN_MPS2, ACCEL_MAX_MPS2), 0.0])


class RandomDriver(Driver):
    """Random pedals (uniform in ``[accel_min, accel_max]`` [m/s^2]) and the odd random lane change.

    :param name: driver name
    :param params: its parameters (:class:`~dt_highway.agent_config.RandomParams`; None: the defaults)
    """

    def __init__(self, name: str, params: RandomParams | None = None) -> None:
        super().__init__(name)
        self.p = _settings(params, RandomParams, "RandomDriver") if params is not None else RandomParams()
        self.accel_min_mps2, self.accel_max_mps2 = self.p.accel_min_mps2, self.p.accel_max_mps2
        self.lane_change_prob = self.p.lane_change_prob
        self.rng = np.random.default_rng(0)

    def params(self) -> dict[str, Any]:
        """The driver's parameters (for the trial log).

        :return: the parameters by name
        """
        return self.p.model_dump()

    def reset(self, seed: int) -> None:
        """Seed the random choices.

        :param seed: seed of the random choices
        """
        self.rng = np.random.default_rng(seed)

    def act(self, perception: Perception) -> np.ndarray:
        """A uniform random acceleration, and a lane change with probability ``lane_change_prob``.

        :param perception: what the driver perceives now (not looked at)
        :return: the action ``[acceleration m/s^2, lane -1/0/+1]``
        """
        a = self.rng.uniform(self.accel_min_mps2, self.accel_max_mps2)
        lane = float(self.rng.choice([-1.0, 1.0])) if self.rng.random() < self.lane_change_prob else 0.0
        return np.array([a, lane])


class HumanDriver(Driver):
    """A human-like driver: IDM with reaction time, estimation errors and MOBIL lane changes;
    in the ADAS condition it responds to the overlay (module docstring).

    :param name: driver name
    :param params: its parameters (:class:`~dt_highway.agent_config.HumanParams`; None: the defaults)
    """

    senses = SenseRequest(surroundings=True, marks=True)
    THREAT_REACTION_FACTOR = 0.6
    """Reaction time multiplier under a threat cue [-]: expected / unexpected brake reaction time,
    0.73 s / 1.25 s (Green 2000), rounded"""
    THREAT_BRAKE = 1.0
    """Strongest deceleration used to open the gap to a cutting-in car, as a multiple of IDM's
    comfortable deceleration ``b`` [-] (our assumption: comfortable braking)"""

    def __init__(self, name: str, params: HumanParams | None = None) -> None:
        super().__init__(name)
        self.p = _settings(params, HumanParams, "HumanDriver") if params is not None else HumanParams()
        self.rng = np.random.default_rng(0)
        self._memory: deque[Surroundings] = deque()
        self._w = np.zeros(2)
        self._last_change_s = -math.inf
        self._alert_until_s = -math.inf
        self._threat_until_s: dict[int, float] = {}
        self._t_prev: float | None = None
        self.reaction_s = self.p.reaction_time_s
        """The reaction time used at the last decision [s]"""

    def params(self) -> dict[str, Any]:
        """The driver's parameters (for the trial log).

        :return: the parameters by name
        """
        return self.p.model_dump()

    def reset(self, seed: int) -> None:
        """Seed the error processes and forget what the driver saw, its last lane change and any alert.

        :param seed: seed of the estimation errors
        """
        self.rng = np.random.default_rng(seed)
        self._memory.clear()
        self._w = self.rng.normal(0.0, 1.0, 2)  # stationary start of the error processes
        self._last_change_s = -math.inf
        self._alert_until_s = -math.inf
        self._threat_until_s = {}
        self._t_prev = None
        self.reaction_s = self.p.reaction_time_s

    def _advance_errors(self, dt: float) -> None:
        """Ornstein-Uhlenbeck step of the two unit-variance estimation errors."""
        tau = self.p.error_correlation_s
        decay = math.exp(-dt / tau)
        self._w = self._w * decay + math.sqrt(1.0 - decay * decay) * self.rng.normal(0.0, 1.0, 2)

    def _estimate(self, seen: Seen, delay_s: float, closing_mps: float) -> tuple[float, float]:
        """A gap and closing speed as the driver estimates them now from what it saw ``delay_s`` ago."""
        if not math.isfinite(seen.gap_m):
            return math.inf, 0.0
        gap = seen.gap_m * math.exp(self.p.distance_error * self._w[0])
        closing = closing_mps - seen.gap_m * self.p.inverse_ttc_error_per_s * self._w[1]
        return max(gap - delay_s * closing, 0.1), closing  # anticipation over the reaction time

    @staticmethod
    def threat_cars(perception: Perception, now: Surroundings) -> set[int]:
        """The cars a person takes the "CUTTING IN" cues for: for each such mark, the marked car on
        the side the label names (the lane next to the driver's on that side, or its own lane)
        whose distance best matches the one printed on the mark (the nearest when none is printed).

        :param perception: what the driver perceives (marks, the cars it sees them on)
        :param now: its surroundings now
        :return: their ids
        """
        out = set()
        for mark in perception.marks:
            if not mark.is_cut_in:
                continue
            lanes = (mark.side, 0) if mark.side else (-1, 0, 1)
            seen = [vid for vid in perception.cars_under_marks if vid in now.x_of and now.x_of[vid][1] in lanes]
            if seen:
                shown = mark.distance_m
                out.add(min(seen, key=lambda vid: abs(now.x_of[vid][0] - shown) if shown is not None
                            else abs(now.x_of[vid][0])))
        return out

    def _warnings(self, perception: Perception, now: Surroundings) -> tuple[bool, set[int]]:
        """Update the warning state: whether the driver is warned, and the cutting-in cars it watches."""
        p = self.p
        marked = perception.cars_under_marks
        near = [vid for vid in marked if vid in now.x_of and (
            (now.x_of[vid][1] == 0 and 0 < now.x_of[vid][0] <= p.alert_ahead_m)
            or (abs(now.x_of[vid][1]) == 1 and -p.alert_behind_m <= now.x_of[vid][0] <= p.alert_ahead_m))]
        for vid in self.threat_cars(perception, now):
            self._threat_until_s[vid] = now.t_s + p.alert_hold_s
        self._threat_until_s = {vid: t for vid, t in self._threat_until_s.items() if now.t_s <= t}
        if near:
            self._alert_until_s = max(self._alert_until_s, now.t_s + p.alert_hold_s)
        if self._threat_until_s:
            self._alert_until_s = max(self._alert_until_s, *self._threat_until_s.values())
        return now.t_s <= self._alert_until_s, set(self._threat_until_s)

    def act(self, perception: Perception) -> np.ndarray:
        """The human-like driver's acceleration and lane choice at this step, from what it perceives.

        :param perception: what the driver perceives now (its surroundings and the overlay's marks)
        :return: the action ``[acceleration m/s^2, lane -1/0/+1]``
        """
        p = self.p
        now = _surroundings(perception)
        dt = 0.0 if self._t_prev is None else now.t_s - self._t_prev
        self._t_prev = now.t_s
        self._advance_errors(dt)
        self._memory.append(now)
        marked = perception.cars_under_marks
        alert, threats = self._warnings(perception, now)
        factor = self.THREAT_REACTION_FACTOR if threats else p.alert_reaction_factor if alert else 1.0
        delay = self.reaction_s = p.reaction_time_s * factor
        while len(self._memory) > 1 and self._memory[1].t_s <= now.t_s - delay + 1e-9:
            self._memory.popleft()
        seen = self._memory[0]  # what it saw a reaction time ago
        age = now.t_s - seen.t_s
        v = seen.speed_mps
        v0 = p.idm.desired_speed_mps * (p.alert_speed_factor if alert else 1.0)
        t_gap = p.idm.time_headway_s * (p.alert_headway_factor if alert else 1.0)
        lead = seen.ahead[0]
        gap, closing = self._estimate(lead, age, v - lead.speed_mps)
        accel = idm_accel(v, gap, closing, p.idm, v0, t_gap)
        if alert and p.anticipate_cut_in:
            for off in (-1, 1):
                other = seen.ahead[off]
                if other.vehicle_id in marked and other.gap_m <= p.alert_ahead_m:
                    g, c = self._estimate(other, age, v - other.speed_mps)
                    shadow = idm_accel(v, g, c, p.idm, v0, t_gap)
                    accel = min(accel, max(shadow, -p.alert_ease_off_mps2))
        if threats:
            accel = min(accel, self._open_gap(seen, threats, age, v, v0, t_gap))
        may_change = now.t_s - self._last_change_s >= p.min_lane_change_interval_s
        lane = self._lane_change(seen, accel, v, v0, t_gap, age) if may_change else 0
        if lane:
            self._last_change_s = now.t_s
        return np.array([np.clip(accel, ACCEL_MIN_MPS2, ACCEL_MAX_MPS2), float(lane)])

    def _open_gap(self, seen: Surroundings, threats: set[int], age: float, v: float, v0: float, t_gap: float) -> float:
        """Under a threat cue: foot off the throttle, and the gap opened to a cutting-in car ahead
        as if it were the leader (comfortable braking at most) [m/s^2]."""
        accel = 0.0  # covers the brake
        for off in (-1, 0, 1):
            other = seen.ahead[off]
            if other.vehicle_id in threats:
                g, c = self._estimate(other, age, v - other.speed_mps)
                shadow = idm_accel(v, g, c, self.p.idm, v0, t_gap)
                accel = min(accel, max(shadow, -self.THREAT_BRAKE * self.p.idm.comfort_decel_mps2))
        return accel

    def _lane_change(self, seen: Surroundings, accel_now: float, v: float, v0: float, t_gap: float, age: float) -> int:
        """MOBIL: the side lane whose incentive beats the threshold, if safe for its new follower."""
        p = self.p
        best, best_gain = 0, p.lane_change_threshold_mps2
        for off in (-1, 1):
            if not 0 <= seen.lane + off < seen.n_lanes:
                continue
            lead, follow = seen.ahead[off], seen.behind[off]
            if lead.gap_m < 2.0 or follow.gap_m < 2.0:
                continue
            g, c = self._estimate(lead, age, v - lead.speed_mps)
            a_new = idm_accel(v, g, c, p.idm, v0, t_gap)
            if math.isfinite(follow.gap_m):
                # the new follower's braking, behind us instead of behind its old leader
                a_f_new = idm_accel(follow.speed_mps, follow.gap_m, follow.speed_mps - v, p.idm)
                lead_gap = lead.gap_m if math.isfinite(lead.gap_m) else math.inf
                a_f_old = idm_accel(follow.speed_mps, follow.gap_m + 5.0 + lead_gap,
                                    follow.speed_mps - lead.speed_mps, p.idm)
            else:
                a_f_new = a_f_old = 0.0
            if a_f_new < -p.safe_decel_mps2:
                continue
            gain = a_new - accel_now + p.politeness * (a_f_new - a_f_old)
            if gain > best_gain:
                best, best_gain = off, gain
        return best


def _surroundings(perception: Perception) -> Surroundings:
    """The surroundings a scripted driver acts on (it asks for them in its ``senses``)."""
    if perception.surroundings is None:
        raise ValueError("this driver looks around: perceive with its senses (surroundings = True)")
    return perception.surroundings

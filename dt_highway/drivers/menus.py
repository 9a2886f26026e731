"""The ``DiscreteDriver`` action menus, on the driver's side: a menu index in, the ``Driver``
action ``[acceleration m/s^2, lane -1/0/+1]`` out, from what the driver perceives.

Raw pedals: entry ``k < len(accels_mps2)`` keeps the lane with that acceleration; the last
two ask for one lane left, one lane right, with no acceleration.

The assisted menu (:class:`AssistedMenu`), for RL drivers: choose a desired speed or a lane,
IDM keeps the gap. With the raw pedals a policy must learn car following, braking for
cut-ins included, before it can learn anything about the traffic around it; in the trial
highway (aggressive drivers cutting in several times a minute) that takes far more training
than the questions need. The assisted menu leaves the tactical choices to the policy, the way
a driver with adaptive cruise control makes them:

* ``k < len(speeds_mps)``: set the desired speed to ``speeds_mps[k]`` [m/s] and keep the lane;
* the last two: change one lane left / right, if it is safe (below), else keep the lane.

Every decision the acceleration is the Intelligent Driver Model's (Treiber, Hennecke &
Helbing 2000) toward the leader in the ego's lane (and in the target lane during a lane
change), with the chosen desired speed; a car ahead whose body already reaches into the
ego's lane (one cutting in, :attr:`~dt_highway.drivers.perception.Perception.entering`)
counts as the leader from then on. A lane change is taken only if MOBIL's safety criterion
holds (Kesting, Treiber & Helbing 2007): the new follower would not have to brake harder than
``safe_decel_mps2``, nor would the ego behind its new leader.

The delayed assisted menu (``reaction_time_s > 0``, the ``assisted-delayed`` training setting)
keeps the gap the way a driver who has not been warned does, so that foresight pays: a car that
newly appears in the lane ahead, closer than the car it follows (one cutting in, or its body
reaching into the lane), is followed only ``reaction_time_s`` after it first appeared, the
perception-reaction time to an unexpected event (about 1.0-1.5 s: Johansson & Rumar 1971 measured
brake reaction times to an unexpected signal ~35 % longer than to an expected one; Green 2000
puts the unexpected-event reaction at ~1.25 s); until then it keeps following the car it followed
(its gap as seen now, its speed as last seen). A leader of the lane the ego itself moved into is
expected (no delay). Its braking is limited to ``brake_limit_mps2`` (~4 m/s^2 is comfortable
hard braking, 6 hard, 8 an emergency stop on dry asphalt). A policy warned of the cut-in can
pre-empt: choose a lower speed (the IDM's free-road term brakes for it at once), or change lane,
before the car reaches the lane. With ``reaction_time_s = 0`` and the brake limit at
:data:`~dt_highway.drivers.base.ACCEL_MIN_MPS2` (the defaults) the menu is the undelayed one, exactly.

Both menus read only a :class:`~dt_highway.drivers.perception.Perception`: a policy driver
turns its choice into pedals itself, and the training envs'
:class:`~dt_highway.env.actions.DiscreteDriverAction` asks the env's senses for the same
perception and calls the same menu.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from dt_highway.agent_config import DEFAULT_DISCRETE_ACCELS_MPS2, DEFAULT_SPEEDS_MPS
from dt_highway.drivers.base import ACCEL_MAX_MPS2, ACCEL_MIN_MPS2
from dt_highway.drivers.idm import IDMParams, idm_accel
from dt_highway.drivers.perception import Perception, Seen, SenseRequest, Surroundings


@dataclass
class AssistedMenu:
    """The assisted menu's state (the desired speed) and its mapping to ``Driver`` actions.

    :param speeds_mps: desired speeds to choose from [m/s]
    :param idm: the car-following model (its ``desired_speed_mps`` is replaced by the choice)
    :param safe_decel_mps2: MOBIL's ``b_safe`` [m/s^2]
    :param reaction_time_s: perception-reaction time to a car newly in the lane ahead [s] (0: none)
    :param brake_limit_mps2: hardest braking of the gap keeping [m/s^2]
    """

    SENSES = SenseRequest(surroundings=True, entering=True)
    """What the menu reads of a perception"""

    speeds_mps: tuple[float, ...] = DEFAULT_SPEEDS_MPS
    idm: IDMParams = field(default_factory=lambda: IDMParams(time_headway_s=1.2, min_gap_m=2.0,
                                                             max_accel_mps2=1.5, comfort_decel_mps2=2.0))
    safe_decel_mps2: float = 3.0
    reaction_time_s: float = 0.0
    brake_limit_mps2: float = -ACCEL_MIN_MPS2
    desired_mps: float = math.nan
    _first_seen: dict[int, float] = field(default_factory=dict, init=False, repr=False)
    """delayed: when each car ahead in the lane was first seen there [s], by id"""
    _followed: tuple[int, float, float] | None = field(default=None, init=False, repr=False)
    """delayed: the car followed (id, longitudinal offset minus gap [m], speed last seen [m/s])"""
    _lane: int | None = field(default=None, init=False, repr=False)
    """delayed: the ego's lane at the last decision"""

    def __post_init__(self) -> None:
        self.speeds_mps = tuple(float(v) for v in self.speeds_mps)
        if not self.speeds_mps or not all(0 < v <= 45 for v in self.speeds_mps):
            raise ValueError(f"speeds_mps must be a non-empty list of speeds in (0, 45] m/s "
                             f"(got {list(self.speeds_mps)})")
        if not (math.isfinite(self.reaction_time_s) and 0 <= self.reaction_time_s <= 3):
            raise ValueError(f"reaction_time_s must be in [0, 3] s (got {self.reaction_time_s})")
        if not (math.isfinite(self.brake_limit_mps2) and 0 < self.brake_limit_mps2 <= -ACCEL_MIN_MPS2):
            raise ValueError(f"brake_limit_mps2 must be in (0, {-ACCEL_MIN_MPS2}] m/s^2 (got {self.brake_limit_mps2})")
        self.reset()

    @property
    def size(self) -> int:
        """Number of choices [-]."""
        return len(self.speeds_mps) + 2

    def reset(self) -> None:
        """Start an episode at the middle desired speed (and, delayed, with nothing seen yet)."""
        self.desired_mps = self.speeds_mps[len(self.speeds_mps) // 2]
        self._first_seen, self._followed, self._lane = {}, None, None

    def action(self, perception: Perception, k: int) -> np.ndarray:
        """The ``Driver`` action ``[acceleration m/s^2, lane -1/0/+1]`` of choice ``k`` now.

        :param perception: what the driver perceives now (:attr:`SENSES`: surroundings, entering)
        :param k: the choice, ``0 .. size - 1``
        :return: the action ``[acceleration m/s^2, lane -1/0/+1]``
        :raises ValueError: on a choice outside the menu, or a perception without the surroundings
        """
        if not 0 <= k < self.size:
            raise ValueError(f"an assisted action is an integer in 0..{self.size - 1} (got {k})")
        s = perception.surroundings
        if s is None:
            raise ValueError("the assisted menu reads the surroundings: perceive with AssistedMenu.SENSES")
        lane = 0
        if k < len(self.speeds_mps):
            self.desired_mps = self.speeds_mps[k]
        else:
            off = -1 if k == len(self.speeds_mps) else 1
            if 0 <= s.lane + off < s.n_lanes and self._safe(s, off):
                lane = off
        if self.reaction_time_s > 0:
            lead_gap, lead_speed = self._delayed_leader(perception.time_s, s, perception.entering)
        else:
            lead_gap, lead_speed = s.ahead[0].gap_m, s.ahead[0].speed_mps
            cutter = perception.entering
            if cutter is not None and cutter.gap_m < lead_gap:  # a car coming into the lane ahead counts as the leader
                lead_gap, lead_speed = cutter.gap_m, cutter.speed_mps
        accel = idm_accel(s.speed_mps, lead_gap, s.speed_mps - lead_speed, self.idm, self.desired_mps)
        if lane:
            new_lead = s.ahead[lane]
            accel = min(accel, idm_accel(s.speed_mps, new_lead.gap_m, s.speed_mps - new_lead.speed_mps, self.idm,
                                         self.desired_mps))
        accel = max(accel, -self.brake_limit_mps2)
        return np.array([float(np.clip(accel, ACCEL_MIN_MPS2, ACCEL_MAX_MPS2)), float(lane)])

    def _delayed_leader(self, t_s: float, s: Surroundings, cutter: Seen | None) -> tuple[float, float]:
        """The leader the delayed gap keeping follows now: ``(gap [m], speed [m/s])`` (module docstring).

        :param t_s: time [s]
        :param s: the surroundings
        :param cutter: the nearest car ahead reaching into the lane, if any
        """
        candidates = [c for c in (s.ahead[0], cutter) if c is not None and c.vehicle_id >= 0 and math.isfinite(c.gap_m)]
        followed = self._followed
        followed_gap = math.inf
        if followed is not None and followed[0] in s.x_of and s.x_of[followed[0]][0] > 0:
            followed_gap = s.x_of[followed[0]][0] - followed[1]
        expected = self._lane != s.lane  # the first decision, or the lane the ego moved into: its cars are expected
        seen = {}
        for c in candidates:
            first = self._first_seen.get(c.vehicle_id)
            if first is None:  # new in the lane ahead: unexpected only if closer than the car followed
                first = -math.inf if expected or c.gap_m >= followed_gap else t_s
            seen[c.vehicle_id] = first
        self._first_seen, self._lane = seen, s.lane
        noticed = [c for c in candidates if t_s - seen[c.vehicle_id] >= self.reaction_time_s - 1e-6]
        if noticed:
            lead = min(noticed, key=lambda c: c.gap_m)
            dx = s.x_of.get(lead.vehicle_id, (lead.gap_m, 0))[0]
            self._followed = (lead.vehicle_id, dx - lead.gap_m, lead.speed_mps)
            return lead.gap_m, lead.speed_mps
        if candidates and followed is not None and math.isfinite(followed_gap):
            return followed_gap, followed[2]  # still following the car it followed, as if the new one were not there
        self._followed = None
        return math.inf, 0.0

    def _safe(self, s: Surroundings, off: int) -> bool:
        """MOBIL's safety criterion for a change into lane offset ``off``."""
        follower, leader = s.behind[off], s.ahead[off]
        if follower.gap_m <= 0 or leader.gap_m <= 0:
            return False  # side by side with someone in that lane
        if math.isfinite(follower.gap_m):
            a_f = idm_accel(follower.speed_mps, follower.gap_m, follower.speed_mps - s.speed_mps, self.idm,
                            max(follower.speed_mps, 1.0))
            if a_f < -self.safe_decel_mps2:
                return False
        a_me = idm_accel(s.speed_mps, leader.gap_m, s.speed_mps - leader.speed_mps, self.idm, self.desired_mps)
        return a_me >= -self.safe_decel_mps2


class DiscreteMenu:
    """The ``DiscreteDriver`` menu: raw pedals, or the assisted menu (module docstring).

    :param accels_mps2: raw pedals: the accelerations to choose from [m/s^2], within the limits
    :param assist: the assisted menu instead of raw pedals
    :param speeds_mps: assisted: the desired speeds to choose from [m/s]
    :param accel_min_mps2: hardest braking allowed in the menu [m/s^2]
    :param accel_max_mps2: strongest acceleration allowed in the menu [m/s^2]
    :param reaction_time_s: assisted: the gap keeping's reaction time to a car newly in the lane [s] (0: none)
    :param brake_limit_mps2: assisted: the gap keeping's hardest braking [m/s^2]
    :raises ValueError: one line, on a bad list
    """

    def __init__(self, accels_mps2: Sequence[float] = DEFAULT_DISCRETE_ACCELS_MPS2, assist: bool = False,
                 speeds_mps: Sequence[float] | None = None,
                 accel_min_mps2: float = ACCEL_MIN_MPS2, accel_max_mps2: float = ACCEL_MAX_MPS2,
                 reaction_time_s: float = 0.0, brake_limit_mps2: float = -ACCEL_MIN_MPS2) -> None:
        self.assisted: AssistedMenu | None = None
        self.menu: list[tuple[float, float]] = []
        if not assist and (reaction_time_s != 0.0 or brake_limit_mps2 != -ACCEL_MIN_MPS2):
            raise ValueError("reaction_time_s and brake_limit_mps2 are settings of the assisted menu (assist = true)")
        if assist:
            try:
                self.assisted = AssistedMenu(tuple(speeds_mps if speeds_mps is not None else DEFAULT_SPEEDS_MPS),
                                             reaction_time_s=float(reaction_time_s),
                                             brake_limit_mps2=float(brake_limit_mps2))
            except TypeError:
                raise ValueError(f"speeds_mps must be a list of speeds [m/s] (got {speeds_mps!r})") from None
            return
        try:
            accels = [float(a) for a in accels_mps2]
        except (TypeError, ValueError):
            raise ValueError(f"accels_mps2 must be a list of numbers [m/s^2] (got {accels_mps2!r})") from None
        if not accels or not all(accel_min_mps2 <= a <= accel_max_mps2 for a in accels):
            raise ValueError(f"accels_mps2 must be a non-empty list within [{accel_min_mps2}, "
                             f"{accel_max_mps2}] m/s^2 (got {accels})")
        self.menu = [(a, 0.0) for a in accels] + [(0.0, -1.0), (0.0, 1.0)]

    @property
    def size(self) -> int:
        """Number of entries [-]."""
        return self.assisted.size if self.assisted is not None else len(self.menu)

    @property
    def senses(self) -> SenseRequest:
        """What the menu reads of a perception (nothing for raw pedals)."""
        return AssistedMenu.SENSES if self.assisted is not None else SenseRequest()

    def reset(self) -> None:
        """Start an episode (the assisted menu's desired speed goes back to its middle value)."""
        if self.assisted is not None:
            self.assisted.reset()

    def choice(self, index: int | np.integer | np.ndarray) -> int:
        """The entry ``index`` names (an int, or a one-element array as a policy returns it).

        :param index: the menu index, an int or an array whose first element is it
        :return: the entry, ``0 .. size - 1``
        :raises ValueError: outside ``0 .. size - 1``
        """
        k = int(np.asarray(index).reshape(-1)[0])
        if not 0 <= k < self.size:
            raise ValueError(f"a DiscreteDriver action is an integer in 0..{self.size - 1} (got {index!r})")
        return k

    def action(self, k: int, perception: Perception | None = None) -> np.ndarray:
        """The ``Driver`` action ``[acceleration m/s^2, lane -1..1]`` of entry ``k`` now.

        :param k: the entry (:meth:`choice`)
        :param perception: what the driver perceives now (:attr:`senses`; raw pedals need none)
        :return: the action ``[acceleration m/s^2, lane -1..1]``
        """
        if self.assisted is not None:
            if perception is None:
                raise ValueError("the assisted menu needs the driver's perception (its senses)")
            return self.assisted.action(perception, k)
        return np.array(self.menu[k], dtype=float)

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

Both menus read only a :class:`~dt_highway.drivers.perception.Perception`: a policy driver
turns its choice into pedals itself, and the training envs'
:class:`~dt_highway.env.actions.DiscreteDriverAction` asks the env's senses for the same
perception and calls the same menu.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from dt_highway.agent_config import DEFAULT_DISCRETE_ACCELS_MPS2, DEFAULT_SPEEDS_MPS
from dt_highway.drivers.base import ACCEL_MAX_MPS2, ACCEL_MIN_MPS2
from dt_highway.drivers.idm import IDMParams, idm_accel
from dt_highway.drivers.perception import Perception, SenseRequest, Surroundings


@dataclass
class AssistedMenu:
    """The assisted menu's state (the desired speed) and its mapping to ``Driver`` actions.

    :param speeds_mps: desired speeds to choose from [m/s]
    :param idm: the car-following model (its ``desired_speed_mps`` is replaced by the choice)
    :param safe_decel_mps2: MOBIL's ``b_safe`` [m/s^2]
    """

    SENSES = SenseRequest(surroundings=True, entering=True)
    """What the menu reads of a perception"""

    speeds_mps: tuple[float, ...] = DEFAULT_SPEEDS_MPS
    idm: IDMParams = field(default_factory=lambda: IDMParams(time_headway_s=1.2, min_gap_m=2.0,
                                                             max_accel_mps2=1.5, comfort_decel_mps2=2.0))
    safe_decel_mps2: float = 3.0
    desired_mps: float = math.nan

    def __post_init__(self) -> None:
        self.speeds_mps = tuple(float(v) for v in self.speeds_mps)
        if not self.speeds_mps or not all(0 < v <= 45 for v in self.speeds_mps):
            raise ValueError(f"speeds_mps must be a non-empty list of speeds in (0, 45] m/s "
                             f"(got {list(self.speeds_mps)})")
        self.reset()

    @property
    def size(self) -> int:
        """Number of choices [-]."""
        return len(self.speeds_mps) + 2

    def reset(self) -> None:
        """Start an episode at the middle desired speed."""
        self.desired_mps = self.speeds_mps[len(self.speeds_mps) // 2]

    def action(self, perception: Perception, k: int) -> np.ndarray:
        """The ``Driver`` action ``[acceleration m/s^2, lane -1/0/+1]`` of choice ``k`` now.

        :param perception: what the driver perceives now (:attr:`SENSES`: surroundings, entering)
        :param k: the choice, ``0 .. size - 1``
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
        lead_gap, lead_speed = s.ahead[0].gap_m, s.ahead[0].speed_mps
        cutter = perception.entering
        if cutter is not None and cutter.gap_m < lead_gap:  # a car coming into the lane ahead counts as the leader
            lead_gap, lead_speed = cutter.gap_m, cutter.speed_mps
        accel = idm_accel(s.speed_mps, lead_gap, s.speed_mps - lead_speed, self.idm, self.desired_mps)
        if lane:
            new_lead = s.ahead[lane]
            accel = min(accel, idm_accel(s.speed_mps, new_lead.gap_m, s.speed_mps - new_lead.speed_mps, self.idm,
                                         self.desired_mps))
        return np.array([float(np.clip(accel, ACCEL_MIN_MPS2, ACCEL_MAX_MPS2)), float(lane)])

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
    :raises ValueError: one line, on a bad list
    """

    def __init__(self, accels_mps2: Any = DEFAULT_DISCRETE_ACCELS_MPS2, assist: bool = False, speeds_mps: Any = None,
                 accel_min_mps2: float = ACCEL_MIN_MPS2, accel_max_mps2: float = ACCEL_MAX_MPS2) -> None:
        self.assisted: AssistedMenu | None = None
        self.menu: list[tuple[float, float]] = []
        if assist:
            try:
                self.assisted = AssistedMenu(tuple(speeds_mps if speeds_mps is not None else DEFAULT_SPEEDS_MPS))
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

    def choice(self, index: Any) -> int:
        """The entry ``index`` names (an int, or a one-element array as a policy returns it).

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
        """
        if self.assisted is not None:
            if perception is None:
                raise ValueError("the assisted menu needs the driver's perception (its senses)")
            return self.assisted.action(perception, k)
        return np.array(self.menu[k], dtype=float)

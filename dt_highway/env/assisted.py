"""An assisted action menu for RL drivers: choose a desired speed or a lane, IDM keeps the gap.

With the raw pedals (:class:`~dt_highway.env.actions.DiscreteDriverAction`'s
accelerations) a policy must learn car following, braking for cut-ins included, before it
can learn anything about the traffic around it; in the trial highway (aggressive drivers
cutting in several times a minute) that takes far more training than the questions need.
The assisted menu leaves the tactical choices to the policy, the way a driver with adaptive
cruise control makes them:

* ``k < len(speeds_mps)``: set the desired speed to ``speeds_mps[k]`` [m/s] and keep the lane;
* the last two: change one lane left / right, if it is safe (below), else keep the lane.

Every decision the acceleration is the Intelligent Driver Model's (Treiber, Hennecke &
Helbing 2000) toward the leader in the ego's lane (and in the target lane during a lane
change), with the chosen desired speed; a car ahead whose body already reaches into the
ego's lane (one cutting in) counts as the leader from then on. A lane change is taken only if MOBIL's safety
criterion holds (Kesting, Treiber & Helbing 2007): the new follower would not have to brake
harder than ``safe_decel_mps2``, nor would the ego behind its new leader. The result is the
``Driver`` action ``[acceleration, lane]`` like every driver's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from dt_highway.drivers.base import ACCEL_MAX_MPS2, ACCEL_MIN_MPS2
from dt_highway.drivers.idm import IDMParams, idm_accel
from dt_highway.env.senses import look_around

DEFAULT_SPEEDS_MPS = (18.0, 23.0, 27.0, 31.0)
"""Desired speeds of the assisted menu [m/s] (65, 83, 97, 112 km/h)"""


@dataclass
class AssistedMenu:
    """The assisted menu's state (the desired speed) and its mapping to ``Driver`` actions.

    :param speeds_mps: desired speeds to choose from [m/s]
    :param idm: the car-following model (its ``desired_speed_mps`` is replaced by the choice)
    :param safe_decel_mps2: MOBIL's ``b_safe`` [m/s^2]
    """

    speeds_mps: tuple[float, ...] = DEFAULT_SPEEDS_MPS
    idm: IDMParams = field(default_factory=lambda: IDMParams(time_headway_s=1.2, min_gap_m=2.0,
                                                             max_accel_mps2=1.5, comfort_decel_mps2=2.0))
    safe_decel_mps2: float = 3.0
    desired_mps: float = math.nan

    def __post_init__(self) -> None:
        self.speeds_mps = tuple(float(v) for v in self.speeds_mps)
        if not self.speeds_mps or not all(0 < v <= 45 for v in self.speeds_mps):
            raise ValueError(f"speeds_mps must be a non-empty list of speeds in (0, 45] m/s (got {list(self.speeds_mps)})")
        self.reset()

    @property
    def size(self) -> int:
        """Number of choices [-]."""
        return len(self.speeds_mps) + 2

    def reset(self) -> None:
        """Start an episode at the middle desired speed."""
        self.desired_mps = self.speeds_mps[len(self.speeds_mps) // 2]

    def action(self, env: Any, k: int) -> np.ndarray:
        """The ``Driver`` action ``[acceleration m/s^2, lane -1/0/+1]`` of choice ``k`` now.

        :param env: the env (unwrapped)
        :param k: the choice, ``0 .. size - 1``
        :raises ValueError: on a choice outside the menu
        """
        if not 0 <= k < self.size:
            raise ValueError(f"an assisted action is an integer in 0..{self.size - 1} (got {k})")
        s = look_around(env)
        lane = 0
        if k < len(self.speeds_mps):
            self.desired_mps = self.speeds_mps[k]
        else:
            off = -1 if k == len(self.speeds_mps) else 1
            if 0 <= s.lane + off < s.n_lanes and self._safe(s, off):
                lane = off
        lead_gap, lead_speed = s.ahead[0].gap_m, s.ahead[0].speed_mps
        cutter = self._entering(env)
        if cutter is not None and cutter[0] < lead_gap:  # a car coming into the lane ahead counts as the leader
            lead_gap, lead_speed = cutter
        accel = idm_accel(s.speed_mps, lead_gap, s.speed_mps - lead_speed, self.idm, self.desired_mps)
        if lane:
            new_lead = s.ahead[lane]
            accel = min(accel, idm_accel(s.speed_mps, new_lead.gap_m, s.speed_mps - new_lead.speed_mps, self.idm,
                                         self.desired_mps))
        return np.array([float(np.clip(accel, ACCEL_MIN_MPS2, ACCEL_MAX_MPS2)), float(lane)])

    ENTERING_RANGE_M = 80.0
    """How far ahead a car entering the ego's lane is looked for [m]"""

    def _entering(self, env: Any) -> tuple[float, float] | None:
        """The nearest car ahead whose body already reaches into the ego's lane while its centre
        is still in the next one (a car changing into the lane, as a driver sees it drift in):
        ``(bumper gap [m], speed [m/s])``, or ``None``."""
        ego = env.vehicle
        lane = env.road.network.get_lane(ego.lane_index)
        ex = float(ego.position[0])
        centre_y = float(lane.position(ex, 0.0)[1])
        best: tuple[float, float] | None = None
        for v in env.road.vehicles:
            if v is ego:
                continue
            dx = float(v.position[0]) - ex
            if not 0.0 < dx < self.ENTERING_RANGE_M:
                continue
            if abs(float(v.position[1]) - centre_y) >= lane.width_at(0.0) / 2 + v.WIDTH / 2:
                continue  # not in the lane, not even in part
            gap = dx - (v.LENGTH + ego.LENGTH) / 2
            if best is None or gap < best[0]:
                best = (gap, float(v.speed))
        return best

    def _safe(self, s: Any, off: int) -> bool:
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

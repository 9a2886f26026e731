"""How a driver controls the ego: a continuous acceleration and lane changes.

highway-env's ``DiscreteMetaAction`` moves the ego between five target speeds, which is no way
to study speed keeping. The ``"Driver"`` action type gives the driver the pedals instead:
an acceleration command [m/s^2] (throttle > 0, brake < 0), held until the next decision,
and a lane-change request (-1 left, 0 keep, +1 right) that highway-env's lateral controller
carries out (lane keeping included). Scripted drivers, the keyboard and policies all drive
through it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from gymnasium import spaces
from highway_env.envs.common.action import ActionType
from highway_env.road.road import LaneIndex, Road, Route
from highway_env.utils import Vector
from highway_env.vehicle.controller import ControlledVehicle
from highway_env.vehicle.kinematics import Vehicle

from dt_highway.drivers.base import ACCEL_MAX_MPS2, ACCEL_MIN_MPS2
from dt_highway.drivers.menus import DEFAULT_DISCRETE_ACCELS_MPS2, DiscreteMenu
from dt_highway.env.senses import perceive

if TYPE_CHECKING:
    from dt_highway.env.core import DTHighwayEnv


def check_action(space: spaces.Space, action: Any, kind: str = "") -> None:
    """Refuse, in one line, an action the env's action space cannot hold, before highway-env acts
    on it (it would fail deep inside, or carry a NaN into the ego's state for good).

    A ``Discrete`` space takes one integer in its range, a scalar (a float only when whole: ``2.0``;
    not a string, not ``[2]``); a ``Box`` finite numbers in its shape (outside the bounds is clipped by
    the action type, as highway-env does). Other spaces are left to their action type.

    :param space: the env's action space
    :param action: what was passed to ``step``
    :param kind: the action type's name, for the message
    :raises ValueError: naming the action, the space and what it takes
    """
    name = f"{kind} " if kind else ""
    try:
        raw = np.asarray(action)
        a = raw.astype(float) if raw.dtype.kind in "biuf" else None  # "1" is no number
    except (TypeError, ValueError):  # a ragged list
        a = None
    if isinstance(space, spaces.Discrete):
        first, last = int(space.start), int(space.start + space.n - 1)
        ok = (a is not None and a.ndim == 0 and math.isfinite(a) and float(a).is_integer() and first <= a <= last)
        if not ok:
            raise ValueError(f"action {action!r} is not in the {name}action space {space}: "
                             f"one integer {first}..{last}")
    elif isinstance(space, spaces.Box):
        size = int(np.prod(space.shape))
        if a is None or a.shape != space.shape or not np.isfinite(a).all():
            raise ValueError(f"action {action!r} is not in the {name}action space {space}: "
                             f"{size} finite number{'s' if size > 1 else ''} in shape {space.shape}")


class DrivenVehicle(ControlledVehicle):
    """The ego under a driver: commanded acceleration, lane changes, lane keeping.

    The acceleration command is held between decisions; speed never goes below 0.

    :param road: the road the ego drives on
    :param position: the ego's position ``(x, y)`` [m]
    :param heading: the ego's heading [rad]
    :param speed: the ego's speed [m/s]
    :param target_lane_index: the lane to follow (default: the lane it is on)
    :param target_speed: highway-env's target speed [m/s] (default: ``speed``); the pedals follow the acceleration
        command, not this
    :param route: highway-env's route of lanes to follow, or ``None``
    """

    MIN_SPEED = 0.0  # [m/s] no reversing on a highway
    target_lane_index: LaneIndex

    def __init__(self, road: Road, position: Vector, heading: float = 0, speed: float = 0,
                 target_lane_index: LaneIndex | None = None, target_speed: float | None = None,
                 route: Route | None = None) -> None:
        super().__init__(road, position, heading, speed, target_lane_index, target_speed, route)
        self.accel_command_mps2 = 0.0
        self.lane_change_requests = 0
        self.steering_command_rad: float | None = None
        """A steering angle set by the driver [rad]; ``None``: highway-env's lane keeping steers"""

    def command(self, accel_mps2: float, lane_change: int = 0) -> None:
        """Set the pedals and, optionally, ask for a lane change.

        :param accel_mps2: acceleration [m/s^2], clipped to ``[ACCEL_MIN_MPS2, ACCEL_MAX_MPS2]``
        :param lane_change: -1 one lane left, +1 one lane right, 0 keep the lane
        """
        if not np.isfinite(accel_mps2):
            raise ValueError(f"the acceleration command must be a finite number [m/s^2] (got {accel_mps2})")
        self.accel_command_mps2 = float(np.clip(accel_mps2, ACCEL_MIN_MPS2, ACCEL_MAX_MPS2))
        if lane_change:
            _from, _to, _id = self.target_lane_index
            n_lanes = len(self.road.network.graph[_from][_to])
            target = (_from, _to, int(np.clip(_id + int(np.sign(lane_change)), 0, n_lanes - 1)))
            if target != self.target_lane_index and self.road.network.get_lane(target).is_reachable_from(self.position):
                self.target_lane_index = target
                self.lane_change_requests += 1

    def act(self, action: Any = None) -> None:
        """Lane keeping (or changing) by the steering controller, the commanded acceleration
        on the pedals (called by highway-env at every simulation step).

        :param action: a dict with ``acceleration`` [m/s^2] and ``lane_change`` (-1, 0, +1) to :meth:`command` first;
            anything else is ignored (the held command drives)
        """
        if isinstance(action, dict):
            self.command(action.get("acceleration", self.accel_command_mps2), action.get("lane_change", 0))
        if self.steering_command_rad is not None:  # the driver steers: no lane keeping
            self.target_lane_index = self.lane_index
            steering = self.steering_command_rad
        else:
            self.follow_road()
            steering = self.steering_control(self.target_lane_index)
        steering = float(np.clip(steering, -self.MAX_STEERING_ANGLE, self.MAX_STEERING_ANGLE))
        accel = self.accel_command_mps2
        if self.speed <= 0.0:
            accel = max(accel, 0.0)
        Vehicle.act(self, {"steering": steering, "acceleration": accel})


class DriverAction(ActionType):
    """Action ``[acceleration, lane]``: acceleration [m/s^2] in ``[accel_min, accel_max]``
    and a lane request in ``[-1, 1]`` (<= -0.5: one lane left, >= 0.5: one lane right).
    With ``steering = true`` the second value steers instead: ``[-1, 1]`` times
    ``steering_max_rad`` (positive to the right), and the ego keeps no lane by itself.

    :param env: the env
    :param accel_min_mps2: hardest braking [m/s^2]
    :param accel_max_mps2: strongest acceleration [m/s^2]
    :param steering: the second value is a steering command, not a lane request
    :param steering_max_rad: steering angle at full lock [rad]
    :param kwargs: no other options are taken: any raises ``ValueError``
    """

    def __init__(self, env: DTHighwayEnv, accel_min_mps2: float = ACCEL_MIN_MPS2, accel_max_mps2: float = ACCEL_MAX_MPS2,
                 steering: bool = False, steering_max_rad: float = 0.05, **kwargs: Any) -> None:
        if kwargs:
            raise ValueError(f"the Driver action takes accel_min_mps2, accel_max_mps2, steering and steering_max_rad "
                             f"only (got {sorted(kwargs)})")
        if not 0 < steering_max_rad <= 1.0:
            raise ValueError(f"the Driver action needs 0 < steering_max_rad <= 1 rad (got {steering_max_rad})")
        self.steering = bool(steering)
        self.steering_max_rad = float(steering_max_rad)
        if not accel_min_mps2 < 0 < accel_max_mps2:
            raise ValueError(f"the Driver action needs accel_min_mps2 < 0 < accel_max_mps2 "
                             f"(got {accel_min_mps2}, {accel_max_mps2})")
        super().__init__(env)
        self.accel_min_mps2 = float(accel_min_mps2)
        self.accel_max_mps2 = float(accel_max_mps2)

    def space(self) -> spaces.Space:
        """The continuous action space.

        :return: ``Box([accel_min, -1], [accel_max, 1])``: acceleration [m/s^2] and lane -1..1
        """
        return spaces.Box(np.array([self.accel_min_mps2, -1.0], dtype=np.float32),
                          np.array([self.accel_max_mps2, 1.0], dtype=np.float32), dtype=np.float32)

    @property
    def vehicle_class(self) -> type:
        """The ego's class: :class:`DrivenVehicle`."""
        return DrivenVehicle

    def act(self, action: Any) -> None:
        """Hold the acceleration (clipped to the limits) and request the lane change of ``[acceleration m/s^2, lane -1..1]``.

        :param action: ``[acceleration m/s^2, lane -1..1]`` (with ``steering = true``: ``[acceleration m/s^2,
            steering -1..1]``)
        :raises ValueError: one line, on an action of another shape or not finite
        """
        a = np.asarray(action, dtype=float).reshape(-1)
        if a.shape != (2,) or not np.isfinite(a).all():
            raise ValueError(f"a Driver action is [acceleration m/s^2, lane -1..1] (got {action!r})")
        accel = float(np.clip(a[0], self.accel_min_mps2, self.accel_max_mps2))
        if self.steering:
            self.controlled_vehicle.steering_command_rad = float(np.clip(a[1], -1.0, 1.0)) * self.steering_max_rad
            self.controlled_vehicle.command(accel, 0)
            self.last_action = a
            return
        lane = -1 if a[1] <= -0.5 else (1 if a[1] >= 0.5 else 0)
        self.controlled_vehicle.command(accel, lane)
        self.last_action = a


class DiscreteDriverAction(DriverAction):
    """The ``Driver`` action as a finite menu, for value-based agents (DQN) and discrete PPO.

    Raw pedals (``assist = false``): action ``k < len(accels)`` keeps the lane with
    acceleration ``accels[k]`` [m/s^2]; the last two ask for one lane left, one lane right,
    with no acceleration. Assisted (``assist = true``,
    :class:`~dt_highway.drivers.menus.AssistedMenu`): action ``k < len(speeds)`` sets the
    desired speed, the last two change lane when it is safe, and the Intelligent Driver Model
    keeps the gap. Either way each choice is the ``Driver`` action :meth:`driver_action`
    returns, computed by the driver-side menu (:class:`~dt_highway.drivers.menus.DiscreteMenu`)
    from the perception the env's senses give it, so a policy trained on it drives anywhere a
    ``Driver`` action is taken.

    :param env: the env
    :param accels_mps2: raw pedals: the accelerations to choose from [m/s^2], within the Driver limits
    :param assist: the assisted menu instead of raw pedals
    :param speeds_mps: assisted: the desired speeds to choose from [m/s]
    :param reaction_time_s: assisted: the gap keeping's reaction time to a car newly in the lane [s]
        (0: none; the delayed menu of :class:`~dt_highway.drivers.menus.AssistedMenu`)
    :param brake_limit_mps2: assisted: the gap keeping's hardest braking [m/s^2]
    :param kwargs: passed to :class:`DriverAction` (``accel_min_mps2``, ``accel_max_mps2``; ``steering`` must stay
        false)
    """

    def __init__(self, env: DTHighwayEnv, accels_mps2: Sequence[float] = DEFAULT_DISCRETE_ACCELS_MPS2,
                 assist: bool = False, speeds_mps: Sequence[float] | None = None, reaction_time_s: float = 0.0,
                 brake_limit_mps2: float = -ACCEL_MIN_MPS2,
                 **kwargs: Any) -> None:
        super().__init__(env, **kwargs)
        if self.steering:
            raise ValueError("the DiscreteDriver action requests lanes: steering = true is not available")
        self.choices = DiscreteMenu(accels_mps2, assist, speeds_mps, self.accel_min_mps2, self.accel_max_mps2,
                                    reaction_time_s, brake_limit_mps2)

    def space(self) -> spaces.Discrete:
        """The discrete action space.

        :return: one choice per menu entry
        """
        return spaces.Discrete(self.choices.size)

    def reset(self) -> None:
        """Start an episode (the assisted menu's desired speed goes back to its middle value)."""
        self.choices.reset()

    def driver_action(self, index: int | np.integer | np.ndarray) -> np.ndarray:
        """The ``Driver`` action ``[acceleration m/s^2, lane -1..1]`` of menu entry ``index`` now.

        :param index: the menu entry, an int or an array whose first element is it (as a policy returns it)
        :return: the action ``[acceleration m/s^2, lane -1..1]``
        """
        k = self.choices.choice(index)
        perception = perceive(self.env, self.choices.senses) if self.choices.assisted is not None else None
        return self.choices.action(k, perception)

    def act(self, action: Any) -> None:
        """Carry out the menu entry ``action`` names (see :meth:`driver_action`).

        :param action: the menu entry, an int or an array whose first element is it
        """
        super().act(self.driver_action(action))

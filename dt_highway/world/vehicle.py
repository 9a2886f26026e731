"""highway-env's IDM/MOBIL vehicle with its per-step arithmetic on plain floats.

highway-env computes each vehicle's decision and motion with numpy on two-element arrays
(lane coordinates with ``np.dot``, velocities as ``speed * [cos, sin]``, ``np.clip`` and
``np.power`` on single numbers). With 50 vehicles at 15 Hz those calls, each a few
microseconds of numpy overhead for one or two numbers, are most of a simulation step.
:class:`FastIDMVehicle` keeps highway-env's models and their order of operations (IDM,
Treiber et al. 2000; MOBIL, Kesting et al. 2007; highway-env's steering controller and
kinematic bicycle) and evaluates them with Python floats and :mod:`math`.

The results are highway-env's up to rounding: ``math`` and numpy's own elementary
functions (``arcsin``, ``arctan``, ``tan``, ``power`` with a non-integer exponent) and
numpy's two-element ``dot`` (which may fuse a multiply-add) differ in the last bit for a
few percent of arguments. ``dt-highway bench sim`` prints how far the same vehicles end
up apart after 30 s of simulated time, and a test bounds it at 1e-6 m.

Objects whose class overrides the pieces used here (a lane other than a straight one, a
vehicle with its own ``velocity``, ``lane_distance_to``, ``polygon`` or collision check)
go through highway-env's code, or their own. Only our env uses these classes; highway-env is not patched.
"""

from __future__ import annotations

import math

import numpy as np
from highway_env.road.lane import AbstractLane, StraightLane
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.controller import ControlledVehicle
from highway_env.vehicle.kinematics import Vehicle
from highway_env.vehicle.objects import RoadObject

_PI = math.pi


def clip(x: float, lo: float, hi: float) -> float:
    """``np.clip`` for one float: the same value (NaN stays NaN) without numpy's per-call cost.

    :param x: the value
    :param lo: lower bound
    :param hi: upper bound
    :return: ``x`` clipped to ``[lo, hi]``
    """
    return lo if x < lo else hi if x > hi else x


def not_zero(x: float, eps: float = 1e-2) -> float:
    """highway-env's ``utils.not_zero``: ``x``, or ``+-eps`` when ``|x| <= eps``.

    :param x: the value
    :param eps: smallest magnitude returned
    :return: ``x``, or ``eps`` with ``x``'s sign (``+eps`` for 0) when ``|x| <= eps``
    """
    if abs(x) > eps:
        return x
    return eps if x >= 0 else -eps


def wrap_to_pi(x: float) -> float:
    """An angle wrapped to [-pi, pi) [rad] (highway-env's ``utils.wrap_to_pi``; Python's ``%``
    is numpy's ``remainder`` for floats).

    :param x: the angle [rad]
    :return: the same angle in [-pi, pi) [rad]
    """
    return ((x + _PI) % (2 * _PI)) - _PI


# ---------------------------------------------------------------------------------- lanes
def _lane_floats(lane: StraightLane) -> tuple[float, float, float, float, float, float]:
    """A straight lane's start, direction and lateral direction as floats, read once per lane."""
    cached = lane.__dict__.get("_dt_floats")
    if cached is None or cached[0] is not lane.start or cached[1] is not lane.direction:
        values = (float(lane.start[0]), float(lane.start[1]), float(lane.direction[0]), float(lane.direction[1]),
                  float(lane.direction_lateral[0]), float(lane.direction_lateral[1]))
        cached = (lane.start, lane.direction, values)
        lane.__dict__["_dt_floats"] = cached
    return cached[2]


def local_coordinates(lane: AbstractLane, x: float, y: float) -> tuple[float, float]:
    """A position's (longitudinal, lateral) coordinates on a lane [m].

    :param lane: the lane
    :param x: the position's x [m]
    :param y: the position's y [m]
    :return: ``(longitudinal, lateral)`` [m]
    """
    if type(lane) is StraightLane:
        sx, sy, dx, dy, lx, ly = _lane_floats(lane)
        d0, d1 = x - sx, y - sy
        return d0 * dx + d1 * dy, d0 * lx + d1 * ly
    s, r = lane.local_coordinates((x, y))
    return float(s), float(r)


def longitudinal(lane: AbstractLane, x: float, y: float) -> float:
    """A position's longitudinal coordinate on a lane [m].

    :param lane: the lane
    :param x: the position's x [m]
    :param y: the position's y [m]
    :return: the longitudinal coordinate [m]
    """
    if type(lane) is StraightLane:
        sx, sy, dx, dy, _, _ = _lane_floats(lane)
        return (x - sx) * dx + (y - sy) * dy
    return float(lane.local_coordinates((x, y))[0])


# ---------------------------------------------------------------------------------- classes
_STOCK: dict[type, tuple[bool, bool, bool, bool, bool]] = {}


def _stock(cls: type[RoadObject]) -> tuple[bool, bool, bool, bool, bool]:
    """Per class, once: (is a highway-env ``Vehicle``; its ``velocity``/``direction`` are
    highway-env's; its ``lane_distance_to`` is highway-env's; its ``polygon`` is highway-env's;
    its collision check, ``handle_collisions`` and ``_is_colliding``, is highway-env's)."""
    flags = _STOCK.get(cls)
    if flags is None:
        kinematic = cls.velocity in (Vehicle.velocity, RoadObject.velocity) and cls.direction is RoadObject.direction
        flags = _STOCK[cls] = (
            issubclass(cls, Vehicle),
            kinematic,
            cls.lane_distance_to is RoadObject.lane_distance_to
            or cls.lane_distance_to is FastIDMVehicle.lane_distance_to,
            cls.polygon is RoadObject.polygon,
            cls.handle_collisions is RoadObject.handle_collisions and cls._is_colliding is RoadObject._is_colliding,
        )
    return flags


def velocity(obj: RoadObject) -> tuple[float, float]:
    """An object's velocity ``speed * (cos heading, sin heading)`` [m/s].

    :param obj: the road object
    :return: ``(vx, vy)`` [m/s] (the object's own ``velocity`` when its class overrides it)
    """
    if (_STOCK.get(type(obj)) or _stock(type(obj)))[1]:
        speed, heading = obj.speed, obj.heading
        return speed * math.cos(heading), speed * math.sin(heading)
    vx, vy = obj.velocity
    return float(vx), float(vy)


def lane_distance(obj: RoadObject, other: RoadObject) -> float:
    """``obj.lane_distance_to(other)``: the signed distance along ``obj``'s lane [m].

    :param obj: the object whose lane the distance is measured along
    :param other: the object the distance is measured to
    :return: ``other``'s longitudinal position minus ``obj``'s [m]
    """
    if not (_STOCK.get(type(obj)) or _stock(type(obj)))[2]:
        return float(obj.lane_distance_to(other))
    lane = obj.lane
    ox, oy = other.position.tolist()
    x, y = obj.position.tolist()
    if type(lane) is StraightLane:
        sx, sy, dx, dy, _, _ = _lane_floats(lane)
        return ((ox - sx) * dx + (oy - sy) * dy) - ((x - sx) * dx + (y - sy) * dy)
    return longitudinal(lane, ox, oy) - longitudinal(lane, x, y)


def surely_apart(a: RoadObject, b: RoadObject, dt: float, margin: float) -> bool:
    """Whether highway-env's collision check of ``a`` against ``b`` is sure to find neither
    contact nor contact within the step (so that it would change nothing).

    The same separating-axis test as highway-env's ``are_polygons_intersecting`` (the four
    edge normals of the two rectangles, ``a`` swept by the relative displacement), with
    each rectangle projected from its centre and half extents: a pair counts as apart only
    if some axis separates it by more than ``margin`` [m] now and some axis does after the
    sweep. :return: ``False`` when in doubt (the caller then runs highway-env's check).

    :param a: the object whose collision check would run (``a.handle_collisions(b)``)
    :param b: the other object
    :param dt: the simulation step [s]
    :param margin: how far an axis must separate the pair [m]
    """
    fa, fb = _stock(type(a)), _stock(type(b))
    # both rectangles and velocities are highway-env's, and so is the check ``a`` would run
    # (highway-env calls only ``a.handle_collisions(b)``, hence ``a._is_colliding``)
    if not (fa[1] and fa[3] and fa[4] and fb[1] and fb[3]):
        return False
    ax, ay = a.position.tolist()
    bx, by = b.position.tolist()
    ca, sa = math.cos(a.heading), math.sin(a.heading)
    cb, sb = math.cos(b.heading), math.sin(b.heading)
    mx = (a.speed * ca - b.speed * cb) * dt  # relative displacement of a in the step [m]
    my = (a.speed * sa - b.speed * sb) * dt
    hla, hwa, hlb, hwb = a.LENGTH / 2, a.WIDTH / 2, b.LENGTH / 2, b.WIDTH / 2
    apart_now = apart_swept = False
    for nx, ny in ((ca, sa), (-sa, ca), (cb, sb), (-sb, cb)):
        ra = hla * abs(ca * nx + sa * ny) + hwa * abs(-sa * nx + ca * ny)
        rb = hlb * abs(cb * nx + sb * ny) + hwb * abs(-sb * nx + cb * ny)
        centre_gap = (bx - ax) * nx + (by - ay) * ny  # b's centre minus a's, along the axis
        gap = abs(centre_gap) - ra - rb
        if gap > margin:
            apart_now = True
        sweep = mx * nx + my * ny  # a's interval widens by this on its side
        toward = sweep if centre_gap > 0 else -sweep
        if gap - max(toward, 0.0) > margin:
            apart_swept = True
        if apart_now and apart_swept:
            return True
    return False


class FastIDMVehicle(IDMVehicle):
    """highway-env's :class:`~highway_env.vehicle.behavior.IDMVehicle`, computed with floats.

    The same decisions (MOBIL every ``LANE_CHANGE_DELAY``, IDM toward the leader in the
    current and target lanes), the same steering controller and kinematic bicycle; only the
    arithmetic is done on Python floats (see the module docstring for how close it is).
    Random draws at creation (``create_random``, ``randomize_behavior``) are highway-env's.
    """

    # highway-env's state, set in its constructor (declared for the type checker)
    speed: float
    heading: float
    crashed: bool
    impact: np.ndarray | None

    def act(self, action: dict | str | None = None) -> None:
        """Decide steering [rad] and acceleration [m/s2] (MOBIL for the lane, IDM for the speed).

        :param action: unused (as in highway-env's ``IDMVehicle``: the vehicle decides for itself)
        """
        if self.crashed:
            return
        self.follow_road()
        if self.enable_lane_change:
            self.change_lane_policy()
        steering = clip(self.steering_control(self.target_lane_index), -self.MAX_STEERING_ANGLE,
                        self.MAX_STEERING_ANGLE)
        front, rear = self.road.neighbour_vehicles(self, self.lane_index)
        acc = self.acceleration(ego_vehicle=self, front_vehicle=front, rear_vehicle=rear)
        if self.lane_index != self.target_lane_index:  # changing lane: mind both leaders
            front, rear = self.road.neighbour_vehicles(self, self.target_lane_index)
            acc = min(acc, self.acceleration(ego_vehicle=self, front_vehicle=front, rear_vehicle=rear))
        self.action = {"steering": steering, "acceleration": clip(acc, -self.ACC_MAX, self.ACC_MAX)}

    def follow_road(self) -> None:
        """At the end of a lane, switch to the next one (highway-env's rule)."""
        lane = self.road.network.get_lane(self.target_lane_index)
        x, y = self.position.tolist()
        if longitudinal(lane, x, y) > lane.length - lane.VEHICLE_LENGTH / 2:
            super().follow_road()

    def acceleration(self, ego_vehicle: ControlledVehicle, front_vehicle: Vehicle = None,
                     rear_vehicle: Vehicle = None) -> float:
        """IDM acceleration of ``ego_vehicle`` behind ``front_vehicle``, with this driver's gains [m/s2].

        :param ego_vehicle: the vehicle whose acceleration is computed
        :param front_vehicle: its leader (``None``: free road)
        :param rear_vehicle: its follower (unused, as in highway-env)
        :return: the acceleration [m/s2] (0 when ``ego_vehicle`` is not a highway-env ``Vehicle``)
        """
        if not ego_vehicle or not (_STOCK.get(type(ego_vehicle)) or _stock(type(ego_vehicle)))[0]:
            return 0
        target = getattr(ego_vehicle, "target_speed", 0)
        lane = ego_vehicle.lane
        if lane and lane.speed_limit is not None:
            target = clip(target, 0, lane.speed_limit)
        speed = ego_vehicle.speed
        ratio = (0 if speed < 0 else speed) / abs(not_zero(target))  # max(speed, 0) / |target|
        acc = self.COMFORT_ACC_MAX * (1 - ratio ** self.DELTA)
        if front_vehicle:
            gap = self.desired_gap(ego_vehicle, front_vehicle) / not_zero(lane_distance(ego_vehicle, front_vehicle))
            acc -= self.COMFORT_ACC_MAX * (gap * gap)
        return acc

    def desired_gap(self, ego_vehicle: Vehicle, front_vehicle: Vehicle = None, projected: bool = True) -> float:
        """IDM's desired gap ``s* = s0 + v T + v dv / (2 sqrt(a b))`` [m].

        :param ego_vehicle: the following vehicle
        :param front_vehicle: its leader
        :param projected: whether ``dv`` is the closing velocity projected on the ego's heading (else the
            difference of the two speeds)
        :return: the desired gap [m]
        """
        speed = ego_vehicle.speed
        if not projected:
            dv = speed - front_vehicle.speed
        elif (_STOCK.get(type(ego_vehicle)) or _stock(type(ego_vehicle)))[1]:
            # the closing speed projected on the ego's heading
            heading = ego_vehicle.heading
            dx, dy = math.cos(heading), math.sin(heading)
            fx, fy = velocity(front_vehicle)
            dv = (speed * dx - fx) * dx + (speed * dy - fy) * dy
        else:
            ex, ey = velocity(ego_vehicle)
            fx, fy = velocity(front_vehicle)
            dx, dy = (float(c) for c in ego_vehicle.direction)
            dv = (ex - fx) * dx + (ey - fy) * dy
        ab = -self.COMFORT_ACC_MAX * self.COMFORT_ACC_MIN
        return self.DISTANCE_WANTED + speed * self.TIME_WANTED + speed * dv / (2 * math.sqrt(ab))

    def lane_distance_to(self, other: RoadObject, lane: AbstractLane = None) -> float:
        """Signed distance to another object along a lane (this vehicle's by default) [m].

        :param other: the object the distance is measured to
        :param lane: the lane measured along (``None``: this vehicle's)
        :return: ``other``'s longitudinal position minus this vehicle's [m] (NaN without ``other``)
        """
        if not other:
            return math.nan
        lane = lane or self.lane
        ox, oy = other.position.tolist()
        x, y = self.position.tolist()
        return longitudinal(lane, ox, oy) - longitudinal(lane, x, y)

    def steering_control(self, target_lane_index: tuple) -> float:
        """highway-env's lane-following steering: lateral offset -> lateral speed -> heading
        -> heading rate -> steering angle [rad].

        :param target_lane_index: the lane to follow
        :return: the steering angle [rad]
        """
        lane = self.road.network.get_lane(target_lane_index)
        x, y = self.position.tolist()
        s, r = local_coordinates(lane, x, y)
        speed = self.speed
        lane_heading = float(lane.heading_at(s + speed * self.TAU_PURSUIT))
        heading_command = math.asin(clip(-self.KP_LATERAL * r / not_zero(speed), -1, 1))
        heading_ref = lane_heading + clip(heading_command, -_PI / 4, _PI / 4)
        heading_rate = self.KP_HEADING * wrap_to_pi(heading_ref - self.heading)
        slip = math.asin(clip(self.LENGTH / 2 / not_zero(speed) * heading_rate, -1, 1))
        return float(clip(math.atan(2 * math.tan(slip)), -self.MAX_STEERING_ANGLE, self.MAX_STEERING_ANGLE))

    def step(self, dt: float) -> None:
        """Advance the decision timer and the kinematic bicycle by ``dt`` [s] (highway-env's
        ``Vehicle.step``: clip the action, move, apply a collision impact, update the lane).

        :param dt: the time step [s]
        """
        self.timer += dt
        action = self.action
        speed = self.speed
        if self.crashed:
            action["steering"] = 0
            action["acceleration"] = -1.0 * speed
        steering = action["steering"] = float(action["steering"])
        acc = float(action["acceleration"])
        if speed > self.MAX_SPEED:
            acc = min(acc, 1.0 * (self.MAX_SPEED - speed))
        elif speed < self.MIN_SPEED:
            acc = max(acc, 1.0 * (self.MIN_SPEED - speed))
        action["acceleration"] = acc
        beta = math.atan(1 / 2 * math.tan(steering))
        heading = self.heading
        position = self.position
        x, y = position.tolist()
        position[0] = x + speed * math.cos(heading + beta) * dt
        position[1] = y + speed * math.sin(heading + beta) * dt
        if self.impact is not None:
            position += self.impact
            self.crashed = True
            self.impact = None
        self.heading = heading + speed * math.sin(beta) / (self.LENGTH / 2) * dt
        self.speed = speed + acc * dt
        self.on_state_update()

"""Traffic with driver types: stable ids, normal and aggressive drivers, cut-ins.

highway-env's ``AggressiveVehicle`` is only a preset of controller gains and nothing marks
a vehicle as aggressive; here every NPC carries a ground-truth driver type that only the
simulator knows (the twin must infer it from GNSS fixes).

* **normal** drivers: IDM + courteous MOBIL (politeness 0.5), gentle lane changes
  (lateral speed <= 1 m/s, a 4 m lane change takes about 4-5 s).
* **aggressive** drivers: short time headway, no politeness, small accepted gaps, short
  lane-change delay, fast lane changes (lateral speed up to 3 m/s, about 1.5-2 s), and
  **cut-ins**: at a Poisson rate they pick a vehicle in a neighbouring lane that they are
  just ahead of (the ego preferred) and change into its lane with a small gap.

With ``traffic.population = "continuum"`` the drivers are not two classes: each draws its own
parameters (:class:`~dt_highway.world.continuum.DriverProfile`) from stated distributions
correlated through a latent aggressiveness, and the aggressive ones are the top share by that
score (:mod:`dt_highway.world.continuum`). Every driver carries its profile; a vehicle takes its
gains, lateral speed and cut-in rate from it (in the two-class world, the type's preset values).

Vehicle ids are stable for the whole episode (and, through :class:`DriverPopulation`,
across the episodes of one env): the ego is 0, NPCs are drivers ``1..population_size``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from highway_env import utils
from highway_env.road.road import LaneIndex, Road
from highway_env.vehicle.kinematics import Vehicle

from dt_highway.config import DriverParams, TrafficConfig
from dt_highway.labels import AGGRESSIVE, NORMAL
from dt_highway.world.continuum import DriverProfile, draw_traits, profile_of, top_share
from dt_highway.world.vehicle import FastIDMVehicle, clip, local_coordinates, wrap_to_pi

DRIVER_TYPES = (NORMAL, AGGRESSIVE)
EGO_ID = 0


def vehicle_id(vehicle: Vehicle) -> int:
    """A road object's stable vehicle id.

    :param vehicle: a vehicle or other road object
    :return: the stable integer id of a vehicle (ego 0), or -1 for a foreign object.
    """
    return int(getattr(vehicle, "dt_id", -1))


def driver_type(vehicle: Vehicle) -> str | None:
    """A vehicle's true driver type.

    :param vehicle: a vehicle on the road
    :return: the ground-truth driver type of an NPC, ``None`` for the ego. Evaluation only.
    """
    return getattr(vehicle, "dt_driver_type", None)


def aggressiveness(vehicle: Vehicle) -> float | None:
    """A vehicle's true latent aggressiveness.

    :param vehicle: a vehicle on the road
    :return: the latent aggressiveness of a continuum driver's vehicle, ``None`` for the ego and in
        the two-class world. Evaluation only.
    """
    return getattr(vehicle, "dt_aggressiveness", None)


@dataclass(frozen=True)
class Driver:
    """One member of the driver population (ground truth).

    :param driver_id: stable id, also the vehicle id while this driver is on the road
    :param driver_type: ``"normal"`` or ``"aggressive"``
    :param desired_speed_mps: IDM desired speed [m/s] (``profile.desired_speed_mps``)
    :param connected: whether the vehicle uploads GNSS fixes to the cloud twin
    :param profile: the driver's own parameters
    :param aggressiveness: latent aggressiveness ``z`` (continuum population), ``None`` in the two-class world
    """

    driver_id: int
    driver_type: str
    desired_speed_mps: float
    connected: bool
    profile: DriverProfile
    aggressiveness: float | None = None


def _connected(n: int, connected_fraction: float, rng: np.random.Generator) -> np.ndarray:
    """Exactly ``round(connected_fraction * n)`` connected drivers, drawn from ``rng``."""
    connected = np.zeros(n, dtype=bool)
    connected[rng.permutation(n)[: int(round(connected_fraction * n))]] = True
    return connected


class DriverPopulation:
    """A fixed, seeded set of drivers that NPC vehicles are drawn from.

    The share of aggressive drivers is exact (``round(fraction * size)``); which drivers are
    aggressive and which are connected is drawn from ``rng``. Two-class population
    (``traffic.population = "two_class"``): the types are shuffled, then the connected drivers
    drawn, then each driver's desired speed, uniform in its type's range. Continuum: the latent
    scores ``z`` are drawn, then the connected drivers, then each parameter for all drivers
    (:func:`~dt_highway.world.continuum.draw_traits`); the top share by ``z`` is aggressive.

    :param config: traffic configuration
    :param connected_fraction: share of connected drivers [-]
    :param rng: the population's random generator
    """

    def __init__(self, config: TrafficConfig, connected_fraction: float, rng: np.random.Generator) -> None:
        self.drivers: dict[int, Driver] = {}
        if config.population == "continuum":
            self._draw_continuum(config, connected_fraction, rng)
        else:
            self._draw_two_class(config, connected_fraction, rng)

    def _draw_two_class(self, config: TrafficConfig, connected_fraction: float, rng: np.random.Generator) -> None:
        n = config.population_size
        n_aggr = int(round(config.aggressive_fraction * n))
        types = np.array([AGGRESSIVE] * n_aggr + [NORMAL] * (n - n_aggr))
        rng.shuffle(types)
        connected = _connected(n, connected_fraction, rng)
        for i in range(n):
            aggressive = types[i] == AGGRESSIVE
            params = config.aggressive if aggressive else config.normal
            lo, hi = params.target_speed_mps
            speed = float(rng.uniform(lo, hi))
            profile = DriverProfile.from_preset(params, speed, config.cut_in_rate_per_min if aggressive else 0.0)
            self.drivers[i + 1] = Driver(i + 1, str(types[i]), speed, bool(connected[i]), profile)

    def _draw_continuum(self, config: TrafficConfig, connected_fraction: float, rng: np.random.Generator) -> None:
        n = config.population_size
        z = rng.standard_normal(n)
        aggressive = top_share(z, config.aggressive_fraction)
        connected = _connected(n, connected_fraction, rng)
        traits = draw_traits(config.continuum, z, rng)
        for i in range(n):
            profile = profile_of(traits, i, config.continuum.lateral_settle_m)
            self.drivers[i + 1] = Driver(i + 1, AGGRESSIVE if aggressive[i] else NORMAL, profile.desired_speed_mps,
                                         bool(connected[i]), profile, float(z[i]))

    def __len__(self) -> int:
        return len(self.drivers)

    def __getitem__(self, driver_id: int) -> Driver:
        return self.drivers[driver_id]


class TypedDriverVehicle(FastIDMVehicle):
    """An IDM/MOBIL vehicle whose gains come from its driver's profile (:meth:`apply_params`), plus cut-ins.

    The lateral controller is a lateral-speed-limited lane follower: desired lateral speed
    ``-offset / lateral_time_constant_s`` clipped to ``max_lateral_speed_mps``, turned into a
    heading reference, tracked by a proportional heading loop and a kinematic bicycle
    inversion. The limit on lateral speed is what makes a lane change gentle or sudden.

    :param road: the road the vehicle drives on
    :param position: initial position [m]
    :param heading: initial heading [rad]
    :param speed: initial speed [m/s]
    :param kwargs: highway-env's ``IDMVehicle`` options (``target_lane_index``, ``target_speed``, ``route``,
        ``enable_lane_change``, ``timer``)
    """

    MAX_LATERAL_SPEED_MPS = 1.0

    def __init__(self, road: Road, position: Sequence[float] | np.ndarray, heading: float = 0, speed: float = 0,
                 **kwargs: Any) -> None:
        super().__init__(road, position, heading, speed, **kwargs)
        self.dt_id = -1
        self.dt_driver_type = NORMAL
        self.dt_aggressiveness: float | None = None
        self.clock_s = 0.0
        self.cut_in: CutInPolicy | None = None

    def apply_params(self, params: DriverParams | DriverProfile) -> None:
        """Set this vehicle's IDM/MOBIL gains and lateral speed limit from a driver's parameters.

        :param params: a driver type's preset (two-class world) or a driver's own profile
        """
        self.TIME_WANTED = params.time_headway_s
        self.DISTANCE_WANTED = params.min_gap_m
        self.COMFORT_ACC_MAX = params.comfort_acc_mps2
        self.COMFORT_ACC_MIN = -params.comfort_dec_mps2
        self.POLITENESS = params.politeness
        self.LANE_CHANGE_MIN_ACC_GAIN = params.lane_change_min_gain_mps2
        self.LANE_CHANGE_MAX_BRAKING_IMPOSED = params.max_braking_imposed_mps2
        self.LANE_CHANGE_DELAY = params.lane_change_delay_s
        self.KP_LATERAL = 1.0 / params.lateral_time_constant_s
        self.MAX_LATERAL_SPEED_MPS = params.max_lateral_speed_mps

    def randomize_behavior(self) -> None:
        """Keep the driver type's gains (highway-env's version would only redraw DELTA)."""

    def steering_control(self, target_lane_index: LaneIndex) -> float:
        """Steer toward the target lane with this driver's lateral gain and lateral speed limit.

        :param target_lane_index: the lane to follow
        :return: the steering angle [rad]
        """
        lane = self.road.network.get_lane(target_lane_index)
        x, y = self.position.tolist()
        s, offset = local_coordinates(lane, x, y)
        speed = max(abs(self.speed), 1e-3)
        lateral_speed = clip(-self.KP_LATERAL * offset, -self.MAX_LATERAL_SPEED_MPS, self.MAX_LATERAL_SPEED_MPS)
        heading_ref = float(lane.heading_at(s + self.speed * self.TAU_PURSUIT)) + math.asin(
            clip(lateral_speed / speed, -0.7, 0.7)
        )
        heading_rate = self.KP_HEADING * wrap_to_pi(heading_ref - self.heading)
        # kinematic bicycle: heading rate = v sin(beta) / (L/2), tan(delta) = 2 tan(beta)
        beta = math.asin(clip(heading_rate * (self.LENGTH / 2) / speed, -1.0, 1.0))
        return float(clip(math.atan(2.0 * math.tan(beta)), -self.MAX_STEERING_ANGLE, self.MAX_STEERING_ANGLE))

    def change_lane_policy(self) -> None:
        """MOBIL, except while a dangerous cut-in is under way: the driver neither aborts it nor weaves on."""
        if self.cut_in is not None and self.cut_in.committed(self.clock_s):
            return
        super().change_lane_policy()

    def act(self, action: dict | str | None = None) -> None:
        """Try a cut-in when one is due, then highway-env's IDM and MOBIL, then a dangerous cut-in's brake.

        :param action: unused (as in highway-env's ``IDMVehicle``: the vehicle decides for itself)
        """
        if self.cut_in is not None and not self.crashed:
            self.cut_in.maybe_cut_in(self)
        super().act(action)
        if self.cut_in is not None and not self.crashed:
            brake = self.cut_in.brake_acceleration(self)
            if brake is not None:
                self.action["acceleration"] = min(self.action["acceleration"], brake)

    def step(self, dt: float) -> None:
        """Advance the driver's clock and the vehicle by ``dt`` [s].

        :param dt: the time step [s]
        """
        self.clock_s += dt
        super().step(dt)


def _bumper_gap_m(front: Vehicle, rear: Vehicle) -> float:
    """Gap from ``rear``'s front bumper to ``front``'s rear bumper along the road [m]."""
    return float(front.position[0] - rear.position[0]) - (front.LENGTH + rear.LENGTH) / 2.0


@dataclass(frozen=True)
class BrakePlan:
    """The brake that follows a dangerous cut-in.

    :param lane_index: the victim's lane, where the brake starts
    :param start_s: when the lane change started (the driver's clock) [s]
    :param target_speed_mps: brake until this slow [m/s]
    """

    lane_index: LaneIndex
    start_s: float
    target_speed_mps: float


@dataclass
class CutInPolicy:
    """When and in front of whom a driver cuts in (an aggressive one in the two-class world; in the
    continuum, every driver at its own rate).

    Attempts arrive as a Poisson process of rate ``rate_per_min``; an attempt stays open for
    ``patience_s`` until a victim qualifies: a vehicle in a neighbouring lane that this
    driver is just ahead of, with a bumper gap in ``gap_m`` and not much faster than this
    driver. The ego is chosen with probability ``ego_preference`` when it qualifies, and
    while an attempt is open a driver within ``search_range_m`` of the ego adjusts its
    speed to reach the window just ahead of it (for up to ``chase_patience_s``). An
    attempt that finds no victim ends in a *lane hop* (weaving): a sudden change into the
    neighbouring lane with the most room ahead, if the new follower would not have to
    brake harder than the driver's ``max_braking_imposed_mps2``.

    A share ``dangerous_share`` of the attempts (drawn when the attempt is scheduled) are the
    paper's near-miss cut-in (section IV-C, Fig. 5): the victim must be just behind this driver
    in the neighbouring lane, with a bumper gap in ``dangerous_gap_m``; the lane change goes at
    the driver's full lateral speed and, once this driver's centre is in the victim's lane
    (highway-env's ``lane_index``; with ``brake_in_lane_only`` off, from the start of the lane
    change), it brakes at ``brake_mps2`` until it is ``speed_drop_mps`` slower than the victim was
    at the start (or ``BRAKE_TIMEOUT_S`` has passed), then drives on.
    """

    rate_per_min: float
    gap_m: tuple[float, float]
    search_range_m: float
    ego_preference: float
    rng: np.random.Generator
    on_cut_in: Callable[[TypedDriverVehicle, Vehicle], None] | None = None
    on_lane_hop: Callable[[TypedDriverVehicle], None] | None = None
    patience_s: float = 5.0
    chase_patience_s: float = 0.0
    next_attempt_s: float = field(default=float("inf"))
    desired_speed_mps: float | None = None
    dangerous_share: float = 0.0
    dangerous_gap_m: tuple[float, float] = (1.0, 8.0)
    brake_mps2: float = 3.0
    speed_drop_mps: float = 4.0
    brake_in_lane_only: bool = True
    """Whether a dangerous cut-in's brake waits until this driver's centre is in the victim's lane
    (else it starts with the lane change)"""
    dangerous: bool = False
    """Whether the open (or next) attempt is the dangerous manoeuvre"""
    brake: BrakePlan | None = None
    """The brake after a dangerous cut-in, while it is due or under way"""
    committed_until_s: float = -math.inf
    """After a dangerous cut-in's brake, the driver keeps the lane until this time (its clock) [s]"""

    CHASE_SPEED_MPS = 5.0
    """How much faster than the ego a driver who wants to cut in front of it goes [m/s]"""
    BRAKE_TIMEOUT_S = 6.0
    """A dangerous cut-in's brake is given up this long after the lane change started [s]"""
    KEEP_LANE_S = 3.0
    """After a dangerous cut-in's brake, the driver keeps the victim's lane this long [s]"""
    MATCHED_SPEED_MPS = 2.0
    """A dangerous cut-in's victim drives within this of the cutting driver's speed [m/s]"""

    def committed(self, now_s: float) -> bool:
        """Whether a dangerous cut-in is under way (lane change, brake, then ``KEEP_LANE_S``): no MOBIL then.

        :param now_s: the driver's clock [s]
        :return: whether the driver is committed to the cut-in
        """
        return self.brake is not None or now_s < self.committed_until_s

    def schedule(self, now_s: float) -> None:
        """Draw the time of the next attempt after ``now_s`` [s] (and, with dangerous cut-ins on, its style).

        :param now_s: the driver's clock [s]
        """
        if self.rate_per_min <= 0:
            self.next_attempt_s = float("inf")
        else:
            self.next_attempt_s = now_s + float(self.rng.exponential(60.0 / self.rate_per_min))
            if self.dangerous_share > 0:
                self.dangerous = bool(self.rng.random() < self.dangerous_share)

    @property
    def chasing_ego(self) -> bool:
        """Whether the open attempt has set the driver's speed to reach the cut-in window just ahead of the ego
        (the *chase*, which the cloud can see in the driver's speed)."""
        return self.desired_speed_mps is not None

    @property
    def gap_window_m(self) -> tuple[float, float]:
        """The bumper gap ahead of the victim that the open attempt accepts [m]."""
        return self.dangerous_gap_m if self.dangerous else self.gap_m

    def brake_acceleration(self, me: TypedDriverVehicle) -> float | None:
        """The deceleration command of a dangerous cut-in's brake at this step [m/s^2], ``None`` when none is due.

        :param me: the driver this policy drives
        :return: ``-brake_mps2`` [m/s^2] while the brake is due, else ``None``
        """
        plan = self.brake
        if plan is None:
            return None
        if me.target_lane_index != plan.lane_index or me.clock_s - plan.start_s > self.BRAKE_TIMEOUT_S \
                or (me.speed <= plan.target_speed_mps
                    and (me.lane_index == plan.lane_index or not self.brake_in_lane_only)):
            self.brake = None  # done, or the lane change was given up (a crash), or it took too long
            self.committed_until_s = me.clock_s + self.KEEP_LANE_S
            return None
        if self.brake_in_lane_only and me.lane_index != plan.lane_index:
            return None  # not in the victim's lane yet
        return -self.brake_mps2

    def maybe_cut_in(self, me: TypedDriverVehicle) -> None:
        """Start a cut-in in front of a victim in a neighbouring lane when an attempt is open and the gap fits;
        past the attempt's patience, weave into a safe neighbouring lane instead.

        :param me: the driver this policy drives
        """
        now = me.clock_s
        if now < self.next_attempt_s or me.lane_index != me.target_lane_index:
            return
        chasing = self._chase_ego(me)
        if now > self.next_attempt_s + (self.chase_patience_s if chasing else self.patience_s):
            # nobody to cut in front of: weave into a neighbouring lane instead, when it is
            # safe by the driver's own (aggressive) MOBIL criterion
            self._lane_hop(me)
            self._end_attempt(me, now)
            return
        victims = self._candidates(me)
        if not victims:
            return
        egos = [v for v in victims if vehicle_id(v) == EGO_ID]
        if egos and self.rng.random() < self.ego_preference:
            victim = egos[0]
        else:
            victim = victims[int(self.rng.integers(len(victims)))]
        me.target_lane_index = victim.lane_index
        me.timer = 0.0
        if self.dangerous:
            self.brake = BrakePlan(victim.lane_index, now, float(victim.speed) - self.speed_drop_mps)
        if self.on_cut_in is not None:
            self.on_cut_in(me, victim)
        self._end_attempt(me, now)

    def _end_attempt(self, me: TypedDriverVehicle, now: float) -> None:
        if self.desired_speed_mps is not None:
            me.target_speed = self.desired_speed_mps
            self.desired_speed_mps = None
        self.schedule(now)

    def _chase_ego(self, me: TypedDriverVehicle) -> bool:
        """With an open attempt and the ego within ``search_range_m`` in this or a
        neighbouring lane, adjust speed to reach the cut-in window just ahead of the ego:
        faster when behind it (MOBIL takes the driver out of the ego's own lane), slower
        when too far ahead in a neighbouring lane. :return: whether positioning."""
        if self.ego_preference <= 0 or self.chase_patience_s <= 0:
            return False
        ego = next((v for v in me.road.vehicles if vehicle_id(v) == EGO_ID), None)
        if ego is None or ego.crashed:
            return False
        same_lane = ego.lane_index == me.lane_index
        if not same_lane and ego.lane_index not in me.road.network.side_lanes(me.lane_index):
            return False
        dx = me.position[0] - ego.position[0]
        if not -self.search_range_m < dx < self.search_range_m or (same_lane and dx > 0):
            return False
        if self.desired_speed_mps is None:
            self.desired_speed_mps = me.target_speed
        gap = _bumper_gap_m(me, ego)
        lo, hi = self.gap_window_m
        if gap < lo:
            me.target_speed = max(self.desired_speed_mps, ego.speed + self.CHASE_SPEED_MPS)
        elif gap > hi:
            me.target_speed = max(ego.speed - self.CHASE_SPEED_MPS / 2, 5.0)
        else:
            me.target_speed = ego.speed + 1.0
        return True

    def _lane_hop(self, me: TypedDriverVehicle) -> None:
        best, best_gap = None, -1.0
        for lane_index in me.road.network.side_lanes(me.lane_index):
            front, rear = me.road.neighbour_vehicles(me, lane_index)
            braking = -me.LANE_CHANGE_MAX_BRAKING_IMPOSED
            if rear is not None and me.acceleration(ego_vehicle=rear, front_vehicle=me) < braking:
                continue
            gap = me.lane_distance_to(front) if front is not None else math.inf
            if gap > max(self.gap_m[0] + me.LENGTH, best_gap):
                best, best_gap = lane_index, gap
        if best is not None:
            me.target_lane_index = best
            me.timer = 0.0
            if self.on_lane_hop is not None:
                self.on_lane_hop(me)

    def _candidates(self, me: TypedDriverVehicle) -> list[Vehicle]:
        side = set(me.road.network.side_lanes(me.lane_index))
        lo, hi = self.gap_window_m
        out = []
        for v in me.road.vehicles:
            if v is me or v.crashed or v.lane_index not in side:
                continue
            dx = me.position[0] - v.position[0]
            if not 0.0 < dx < self.search_range_m:
                continue
            gap = _bumper_gap_m(me, v)
            if not lo <= gap <= hi:
                continue
            if self.dangerous and abs(v.speed - me.speed) > self.MATCHED_SPEED_MPS:
                continue  # the near miss starts at about the victim's speed: the brake makes the closing
            if v.speed <= me.speed + 3.0:
                out.append(v)
        return out


def cut_in_policy(
    config: TrafficConfig,
    rate_per_min: float,
    rng: np.random.Generator,
    on_cut_in: Callable[[TypedDriverVehicle, Vehicle], None] | None = None,
    on_lane_hop: Callable[[TypedDriverVehicle], None] | None = None,
) -> CutInPolicy:
    """A driver's cut-in policy with the ``traffic`` section's settings (its first attempt not yet scheduled).

    :param config: the traffic section (gaps, range, ego preference, chase time, dangerous cut-ins)
    :param rate_per_min: the driver's attempt rate [1/min]
    :param rng: the policy's random generator
    :param on_cut_in: called at each cut-in (the traffic's event log)
    :param on_lane_hop: called at each lane hop
    :return: the policy (call :meth:`CutInPolicy.schedule` to schedule its first attempt)
    """
    return CutInPolicy(
        rate_per_min=rate_per_min,
        gap_m=config.cut_in_gap_m,
        search_range_m=config.cut_in_range_m,
        ego_preference=config.cut_in_ego_preference,
        chase_patience_s=config.cut_in_chase_s,
        rng=rng,
        on_cut_in=on_cut_in,
        on_lane_hop=on_lane_hop,
        dangerous_share=config.dangerous.share,
        dangerous_gap_m=config.dangerous.gap_m,
        brake_mps2=config.dangerous.brake_mps2,
        speed_drop_mps=config.dangerous.speed_drop_mps,
        brake_in_lane_only=config.dangerous.brake_onset == "in_lane",
    )


@dataclass
class TrafficEvent:
    """Something that happened in traffic (ground truth, for evaluation and logs).

    :param time_s: simulation time [s]
    :param kind: ``"cut_in"``, ``"lane_hop"``, ``"spawn"``, ``"despawn"``
    :param vehicle_id: the acting vehicle
    :param other_id: the victim of a cut-in, else -1
    :param driver_type: the acting vehicle's true driver type
    :param style: a cut-in's manoeuvre, ``"gentle"`` or ``"dangerous"``; else empty
    """

    time_s: float
    kind: str
    vehicle_id: int
    other_id: int = -1
    driver_type: str | None = None
    style: str = ""


class TrafficManager:
    """Creates NPCs from the driver population around the ego, and keeps traffic around it.

    Vehicles that drift farther than ``recycle_distance_m`` from the ego leave the road and
    another driver of the population (not on the road now) enters at the opposite edge, so
    that traffic density around the ego stays the same for hours of simulated time. Crashed
    NPCs are towed away after ``crashed_removal_s``.

    :param config: traffic configuration
    :param population: drivers to draw NPCs from
    :param rng: this component's random generator
    """

    MIN_SPAWN_GAP_M = 25.0
    """Smallest centre-to-centre distance to any vehicle in the lane when spawning [m]"""
    REENTRY_COOLDOWN_S = 120.0
    """A driver who left the road re-enters no sooner than this [s]"""

    def __init__(self, config: TrafficConfig, population: DriverPopulation, rng: np.random.Generator) -> None:
        self.config = config
        self.population = population
        self.rng = rng
        self.time_s = 0.0
        self.events: list[TrafficEvent] = []
        self._crash_time: dict[int, float] = {}
        self._left_at: dict[int, float] = {}
        self._owed_ahead = 0
        self._owed_behind = 0

    # ------------------------------------------------------------------ creation
    def make_vehicle(
        self, road: Road, driver: Driver, lane_index: LaneIndex, x_m: float, speed_mps: float
    ) -> TypedDriverVehicle:
        """Create one NPC of ``driver`` on ``lane_index`` at longitudinal position ``x_m``.

        :param road: the road it will drive on
        :param driver: the population member who drives it
        :param lane_index: its lane
        :param x_m: its longitudinal position on the lane [m]
        :param speed_mps: its initial speed [m/s]
        :return: the vehicle, with its driver's parameters (and a cut-in policy at a positive rate); the caller
            puts it on the road
        """
        lane = road.network.get_lane(lane_index)
        v = TypedDriverVehicle(
            road, lane.position(x_m, 0.0), lane.heading_at(x_m), speed_mps,
            target_lane_index=lane_index, target_speed=driver.desired_speed_mps,
        )
        profile = driver.profile
        v.apply_params(profile)
        v.DELTA = 4.0
        v.timer = float(self.rng.uniform(0, profile.lane_change_delay_s))
        v.dt_id = driver.driver_id
        v.dt_driver_type = driver.driver_type
        v.dt_aggressiveness = driver.aggressiveness
        v.dt_connected = driver.connected
        v.clock_s = self.time_s
        if profile.cut_in_rate_per_min > 0:
            v.cut_in = cut_in_policy(self.config, profile.cut_in_rate_per_min, self.rng, self._record_cut_in,
                                     self._record_lane_hop)
            v.cut_in.schedule(self.time_s)
        return v

    def _record_cut_in(self, me: TypedDriverVehicle, victim: Vehicle) -> None:
        style = "dangerous" if me.cut_in is not None and me.cut_in.brake is not None else "gentle"
        self.events.append(TrafficEvent(self.time_s, "cut_in", me.dt_id, vehicle_id(victim), me.dt_driver_type, style))

    def _record_lane_hop(self, me: TypedDriverVehicle) -> None:
        self.events.append(TrafficEvent(self.time_s, "lane_hop", me.dt_id, -1, me.dt_driver_type))

    def _free_drivers(self, road: Road) -> list[int]:
        on_road = {vehicle_id(v) for v in road.vehicles}
        cutoff = self.time_s - self.REENTRY_COOLDOWN_S
        self._left_at = {i: t for i, t in self._left_at.items() if t > cutoff}
        # population ids are 1..size in order: the free ones, ascending
        return sorted(self.population.drivers.keys() - on_road - self._left_at.keys())

    def remove(self, v: Vehicle) -> None:
        """Note that ``v`` was taken off the road by the env; a driver re-enters at the far edge behind.

        :param v: the vehicle taken off the road
        """
        self._leave(v)
        self._owed_behind += 1

    def _leave(self, v: Vehicle) -> None:
        vid = vehicle_id(v)
        self._left_at[vid] = self.time_s
        self._crash_time.pop(vid, None)
        self.events.append(TrafficEvent(self.time_s, "despawn", vid, driver_type=driver_type(v)))

    def populate(self, road: Road, ego: Vehicle, count: int) -> None:
        """Place ``count`` NPCs between ``spawn_behind_m`` behind and ``spawn_ahead_m`` ahead of the ego.

        :param road: the road the NPCs are added to
        :param ego: the ego vehicle
        :param count: how many NPCs (at most the drivers free to enter)
        """
        lanes = road.network.lanes_list()
        lane_indices = [road.network.get_closest_lane_index(lane.position(0, 0)) for lane in lanes]
        free = self._free_drivers(road)
        count = min(count, len(free))
        chosen: np.ndarray | list[int] = self.rng.choice(free, size=count, replace=False) if count else []
        per_lane: list[int] = utils.near_split(count, num_bins=len(lanes)) if count else []
        x0 = ego.position[0] - self.config.spawn_behind_m
        span = self.config.spawn_behind_m + self.config.spawn_ahead_m
        k = 0
        for lane_index, n in zip(lane_indices, per_lane, strict=False):  # no NPCs: no bins
            if n == 0:
                continue
            slot = span / n
            for j in range(n):
                x = x0 + (j + float(self.rng.uniform(0.25, 0.75))) * slot
                if lane_index == ego.lane_index and abs(x - ego.position[0]) < self.MIN_SPAWN_GAP_M:
                    x = ego.position[0] + np.sign(x - ego.position[0] + 1e-9) * self.MIN_SPAWN_GAP_M
                driver = self.population[int(chosen[k])]
                k += 1
                speed = min(driver.desired_speed_mps, float(self.rng.uniform(22.0, 26.0)))
                road.vehicles.append(self.make_vehicle(road, driver, lane_index, x, speed))

    # ------------------------------------------------------------------ upkeep
    def recycle(self, road: Road, ego: Vehicle) -> None:
        """Remove far or long-crashed NPCs and re-enter as many drivers at the far edges.

        :param road: the road
        :param ego: the ego vehicle
        """
        if not self.config.recycle:
            return
        ex = ego.position[0]
        removed_behind = removed_ahead = 0
        keep = []
        for v in road.vehicles:
            vid = vehicle_id(v)
            if v is ego or vid == EGO_ID:
                keep.append(v)
                continue
            dx = v.position[0] - ex
            if v.crashed:
                t0 = self._crash_time.setdefault(vid, self.time_s)
                if self.time_s - t0 >= self.config.crashed_removal_s:
                    removed_behind += dx < 0
                    removed_ahead += dx >= 0
                    self._leave(v)
                    continue
            if dx < -self.config.recycle_distance_m:
                removed_behind += 1
                self._leave(v)
                continue
            if dx > self.config.recycle_distance_m:
                removed_ahead += 1
                self._leave(v)
                continue
            keep.append(v)
        if removed_behind or removed_ahead:
            road.vehicles[:] = keep
        # vehicles that fell behind re-enter ahead, and the other way round; an entry that
        # finds no room (or no free driver) is retried at the next step
        self._owed_ahead += removed_behind
        self._owed_behind += removed_ahead
        while self._owed_ahead and self._spawn_at_edge(road, ego, ahead=True):
            self._owed_ahead -= 1
        while self._owed_behind and self._spawn_at_edge(road, ego, ahead=False):
            self._owed_behind -= 1

    def _spawn_at_edge(self, road: Road, ego: Vehicle, ahead: bool) -> bool:
        free = self._free_drivers(road)
        if not free:
            return False
        lanes = road.network.lanes_list()
        edge = self.config.spawn_ahead_m if ahead else -self.config.spawn_behind_m
        x = float(ego.position[0]) + edge
        # lanes with a vehicle within MIN_SPAWN_GAP_M of the entry point (one pass over the road)
        occupied = {v.lane_index for v in road.vehicles if abs(float(v.position[0]) - x) < self.MIN_SPAWN_GAP_M}
        for lane_id in self.rng.permutation(len(lanes)):
            lane = lanes[int(lane_id)]
            lane_index = road.network.get_closest_lane_index(lane.position(x, 0))
            if lane_index in occupied:
                continue
            driver = self.population[int(self.rng.choice(free))]
            # enter at the speed of the flow the vehicle joins
            speed = float(np.clip(ego.speed, 18.0, driver.desired_speed_mps))
            road.vehicles.append(self.make_vehicle(road, driver, lane_index, x, speed))
            self.events.append(TrafficEvent(self.time_s, "spawn", driver.driver_id, driver_type=driver.driver_type))
            return True
        return False

    def drain_events(self) -> list[TrafficEvent]:
        """Take the traffic events since the last call.

        :return: the events since the last call (and forget them: memory stays flat).
        """
        out, self.events = self.events, []
        return out

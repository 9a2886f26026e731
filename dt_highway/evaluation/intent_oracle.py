"""The oracle of ``twin-eval --intent --oracle``: how far ahead lane changes can be foreseen at all.

Evaluation only: it reads the simulator's whole state, which the twin never sees. At an estimate's
time the oracle copies the road (every vehicle with its driver's parameters, its MOBIL timer, its
target lane, an open cut-in attempt and its brake plan) and simulates it ``rollouts`` times for the
longest horizon, with the ego's autopilot and the other drivers' own models. What is still to be
drawn is drawn afresh in every copy from its own random generator: the time of each driver's next
cut-in attempt (a Poisson process, so a fresh exponential wait is what the driver's past tells) and
its style, the victim of an attempt. So the copies share everything that is decided and differ in
what is not; the share of copies in which a vehicle's centre has moved to the lane on its left
(right) within ``H`` is its ``P(left)`` (``P(right)``), scored like any model's estimates.

An estimate of the best any predictor could do from the full state, drivers' minds included, not a
proof of it: the probabilities carry the Monte-Carlo error of ``rollouts`` copies (steps of
``1 / rollouts``), an estimate within ``period_s`` of the last run reuses its futures (shifted by the
time since, and sides counted from the estimate's own lanes), and the oracle sees the state of the
moment the cloud's estimate is recorded (the cloud's own inputs are older by the uplink latency,
0.1 s by default). With a driver at the wheel (``--driver``) the driver's next decisions are not
simulated: the copies' ego follows its controller's last targets (measured only with the autopilot).

**What the twin lacks** (``OracleSettings.hide``): the oracle can be denied parts of the state, one at a time or
together, to measure which of them the foresight comes from. Each is replaced, in every copy, by what a twin that
has only the cloud's data could assume:

* ``positions``: every other vehicle's position along the road and its speed carry the error of one GNSS fix
  (Gaussian, ``sigma_position_m`` and ``sigma_speed_mps``: ``twin-eval`` passes its uplink's, by default 1 m and
  0.2 m/s; drawn per copy and vehicle; the lateral position is kept, so that the lanes stay as they are);
* ``speeds``: each driver's desired speed (IDM's ``v0``, the one per-driver parameter of the two-class world;
  its driver type's gains are the type's presets) is taken to be its present speed (as the copy has it);
* ``timers``: each driver's MOBIL decision timer is drawn uniformly in ``[0, its decision period)``;
* ``attempts``: whether a cut-in attempt is open, and the speed its driver chases the ego with, are unknown:
  every attempt not yet in motion (no brake plan) is closed, the driver goes back to its desired speed, and
  its next attempt is a fresh draw from the Poisson process;
* ``unseen_attempts``: the same, except for a driver who is chasing the ego (its speed set to reach the window
  just ahead of it): that attempt is known, as a twin that read the chase from the fixes without fail would know it.

**The twin's own picture** (``OracleSettings.start = "picture"``): instead of the simulator's state, each copy starts
from what the cloud knows (:class:`~dt_highway.twin.intention.TwinPicture`: every vehicle's position, speed and lateral
motion from its fixes, the tagger's posterior that its driver is aggressive) and simulates it with the simulator's own
driver models: a twin with a perfect traffic model and the cloud's data. Per copy, each driver's type is drawn from the
tagger's posterior and gets its type's presets (``traffic.normal`` / ``traffic.aggressive``) with its present speed as
its desired speed, a MOBIL timer drawn in its decision period, and, if aggressive, a cut-in policy whose next attempt is a
fresh draw; a vehicle is put at its lateral position, headed along its lateral speed. Whether it is already moving
to a neighbouring lane is drawn per copy from the twin's own estimate of a move within its shortest horizon
(``picture.p_move``, from the intention network, which reads the lateral motion of the fixes); a picture without
one judges it from the fixes alone (more than :data:`MOVING_OFFSET_M` off its lane's centre and moving outward faster
than :data:`MOVING_LATERAL_MPS`; 1 m fixes make that judgement poor). The ego is an IDM car keeping its lane at its
present speed. The road's geometry is the simulator's (the twin knows the map). Whether an aggressive driver has a
cut-in attempt open on the ego is drawn per copy from the twin's chase detector (``picture.p_chase``, from
:class:`~dt_highway.twin.chase.ChaseDetector`: the driver is aggressive and chasing with that probability, and its
attempt is then open from the start of the copy); ``hide = {"chases"}`` leaves it out (every attempt a fresh draw).
The copies share the picture and differ in what the cloud does not know.

**Parts of the truth put back into the picture** (``OracleSettings.reveal``, starting from the picture only): to
measure what a better twin could gain, the picture can take parts of the simulator's state instead of the twin's
estimates of them:

* ``chases``: who is chasing the ego is the simulator's chase state (``p_chase`` 1 for a driver whose open attempt
  has set its speed to reach the window just ahead of the ego, else 0), as a chase detector without fault would have
  it;
* ``lateral``: every vehicle's lateral position and lateral speed are the simulator's, and whether it is moving to
  a neighbouring lane (``p_move``) is the lane it is steering to, as a twin that read the lateral state exactly
  would have them;
* ``types``: every driver's tagged type is the simulator's (``p_aggressive`` 1 or 0), as a tagger without fault
  would have it; a driver judged chasing the ego (``p_chase``) is still aggressive in that share of the copies,
  since the copies give cut-ins to aggressive drivers only (the copies still give a driver its type's presets,
  with its present speed as its desired speed);
* ``positions``: every vehicle's position along the road and speed are the simulator's, without the fixes' noise;
* ``attempts``: every open cut-in attempt is the simulator's (:class:`OpenAttempt`: how long it has been open, so
  when the driver gives up and weaves; its style, near miss or not; a near miss's brake under way, its driver
  steering to the victim's lane, and the lane kept after it), its driver aggressive in every copy; this gives the
  chases too (a driver without an open attempt chases no one). A copy still draws every attempt not yet open, as
  the state's oracle does.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, fields
from typing import TYPE_CHECKING, Literal

import numpy as np
from highway_env.road.road import Road, RoadNetwork

from dt_highway.choices import HIDEABLE, PICTURE_HIDEABLE, PICTURE_REVEALABLE, STARTS
from dt_highway.twin.chase import ChaseDetector
from dt_highway.twin.intention import TwinPicture
from dt_highway.world.continuum import DriverProfile
from dt_highway.world.road import FastRoad
from dt_highway.world.traffic import EGO_ID, BrakePlan, CutInPolicy, TypedDriverVehicle, cut_in_policy, vehicle_id

if TYPE_CHECKING:
    from dt_highway.config import TrafficConfig
    from dt_highway.twin.tagger import HighwayMap

ORACLE_PERIOD_S = 0.2
"""The oracle runs at most this often; an estimate in between reuses the last run [s]"""
GIVES_CHASES = frozenset({"chases", "attempts"})
"""The parts of :data:`PICTURE_REVEALABLE` that make the picture's chases the simulator's (open attempts give them)"""
MOVING_OFFSET_M = 0.5
"""A pictured vehicle this far off its lane's centre ... [m]"""
MOVING_LATERAL_MPS = 0.3
"""... and moving outward faster than this is changing lane [m/s]"""


@dataclass(frozen=True)
class OracleSettings:
    """How the oracle estimates.

    :param rollouts: simulated futures per estimate (>= 1)
    :param period_s: the oracle runs at most this often [s]
    :param seed: seed of the copies' random generators
    :param hide: the parts of the state the oracle is denied (names of :data:`HIDEABLE`; starting from the picture,
        of :data:`PICTURE_HIDEABLE`)
    :param sigma_position_m: with ``positions`` hidden, the error of a vehicle's position along the road [m]
    :param sigma_speed_mps: with ``positions`` hidden, the error of its speed [m/s]
    :param start: what the copies start from: ``"state"`` (the simulator's) or ``"picture"`` (the twin's)
    :param reveal: starting from the picture, the parts of the simulator's state put into it instead of the twin's
        estimates (names of :data:`PICTURE_REVEALABLE`)
    """

    rollouts: int = 8
    period_s: float = ORACLE_PERIOD_S
    seed: int = 0
    hide: frozenset[str] = frozenset()
    sigma_position_m: float = 1.0
    sigma_speed_mps: float = 0.2
    start: Literal["state", "picture"] = "state"
    reveal: frozenset[str] = frozenset()

    def __post_init__(self) -> None:
        if self.rollouts < 1:
            raise ValueError(f"the oracle needs at least 1 rollout (got {self.rollouts})")
        if self.start not in STARTS:
            raise ValueError(f"the oracle cannot start from {self.start!r} (it can start from: {', '.join(STARTS)})")
        allowed = HIDEABLE if self.start == "state" else PICTURE_HIDEABLE
        unknown = sorted(set(self.hide) - set(allowed))
        if unknown:
            raise ValueError(f"the oracle starting from the {'twin' if self.start == 'picture' else 'simulator'}'s "
                             f"{self.start} cannot hide {', '.join(unknown)} (it can hide: {', '.join(allowed)})")
        if self.reveal and self.start != "picture":
            raise ValueError("only the oracle starting from the twin's picture can be given parts of the simulator's "
                             f"state (it starts from the {self.start}; it already has all of it)")
        unknown = sorted(set(self.reveal) - set(PICTURE_REVEALABLE))
        if unknown:
            raise ValueError(f"the picture cannot be given the simulator's {', '.join(unknown)} "
                             f"(it can be given: {', '.join(PICTURE_REVEALABLE)})")
        both = sorted(set(self.reveal) & set(self.hide))
        if both:
            raise ValueError(f"{', '.join(both)} cannot be both hidden and given to the oracle")
        if "attempts" in self.reveal and "chases" in self.hide:
            raise ValueError("attempts cannot be given with chases hidden (the simulator's open attempts give its "
                             "chases too)")

    @property
    def chases_given(self) -> bool:
        """Whether the picture's chases are the simulator's (``chases`` or ``attempts`` given)."""
        return bool(GIVES_CHASES & self.reveal)


@dataclass(frozen=True)
class OpenAttempt:
    """A driver's cut-in attempt as the simulator has it now (evaluation only: ``reveal`` ``attempts``), in times
    from now.

    :param dangerous: whether the open attempt is the paper's near miss (with none open: the next one's, not used)
    :param open_for_s: how long it has been open [s] (its patience runs from then); ``None``: none open
    :param brake: a near miss's brake under way, its ``start_s`` from now (negative: started before) [s]
    :param committed_for_s: how much longer the driver keeps its lane after a near miss's brake [s]
    """

    dangerous: bool
    open_for_s: float | None
    brake: BrakePlan | None = None
    committed_for_s: float = 0.0

    @classmethod
    def of(cls, policy: CutInPolicy, clock_s: float) -> OpenAttempt | None:
        """A driver's cut-in attempt as its policy in the simulator has it now.

        :param policy: the driver's cut-in policy in the simulator
        :param clock_s: its driver's clock now [s]
        :return: the attempt of ``policy`` at its driver's ``clock_s`` [s] (``None``: no attempt open, no brake
        under way, no lane kept: nothing that a fresh draw would not give)
        """
        is_open = clock_s >= policy.next_attempt_s
        if not is_open and policy.brake is None and policy.committed_until_s <= clock_s:
            return None
        brake = policy.brake
        return cls(policy.dangerous, clock_s - policy.next_attempt_s if is_open else None,
                   None if brake is None else BrakePlan(brake.lane_index, brake.start_s - clock_s,
                                                        brake.target_speed_mps),
                   max(policy.committed_until_s - clock_s, 0.0))

    def apply(self, policy: CutInPolicy) -> None:
        """Put this attempt into a copy's fresh ``policy`` (its driver's clock at 0, its next attempt drawn: kept,
        style and all, when none is open).

        :param policy: the copy's fresh cut-in policy (changed in place)
        """
        if self.open_for_s is not None:
            policy.dangerous = self.dangerous
            policy.next_attempt_s = -self.open_for_s
        policy.brake = self.brake
        policy.committed_until_s = self.committed_for_s


@dataclass(frozen=True)
class RevealedPicture(TwinPicture):
    """The twin's picture with the simulator's open cut-in attempts (evaluation only: ``reveal`` ``attempts``).

    :param attempts: per vehicle id, its driver's :class:`OpenAttempt` (a vehicle not in it has none)
    """

    attempts: Mapping[int, OpenAttempt] = field(default_factory=dict)

    @classmethod
    def of(cls, picture: TwinPicture, attempts: Mapping[int, OpenAttempt]) -> RevealedPicture:
        """A twin's picture with its drivers' open cut-in attempts.

        :param picture: the twin's picture
        :param attempts: per vehicle id, its driver's open attempt
        :return: ``picture`` with ``attempts``
        """
        return cls(**{f.name: getattr(picture, f.name) for f in fields(picture)}, attempts=attempts)


def _policies(road: Road) -> list[CutInPolicy]:
    return [p for v in road.vehicles if isinstance(p := getattr(v, "cut_in", None), CutInPolicy)]


def copy_road(road: Road, rng: np.random.Generator, settings: OracleSettings | None = None) -> Road:
    """A copy of ``road`` whose future draws are fresh: every cut-in policy draws from ``rng``, a driver
    whose next attempt has not opened yet waits a new exponential time (and draws its style anew), and
    the copy reports no traffic events.

    :param road: the simulator's road (left untouched)
    :param rng: the copy's random generator
    :param settings: what the copy hides (``settings.hide``; ``None``: nothing)
    :return: the copy
    """
    memo: dict[int, object] = {}
    for p in _policies(road):
        memo[id(p.rng)] = rng
        for hook in (p.on_cut_in, p.on_lane_hop):
            if hook is not None:
                memo[id(hook)] = None
    out = copy.deepcopy(road, memo)
    for v in out.vehicles:
        policy = getattr(v, "cut_in", None)
        if isinstance(policy, CutInPolicy) and v.clock_s < policy.next_attempt_s:
            policy.schedule(v.clock_s)  # memoryless: the wait from now is a fresh draw
    if settings is not None and settings.hide:
        for v in out.vehicles:
            if isinstance(v, TypedDriverVehicle) and vehicle_id(v) != EGO_ID:
                _hide(v, settings, rng)
    return out


def _hide(v: TypedDriverVehicle, settings: OracleSettings, rng: np.random.Generator) -> None:
    """Replace what ``settings.hide`` names of one copied driver by what the twin could assume (module docstring)."""
    policy = v.cut_in
    if "positions" in settings.hide:
        v.position[0] += settings.sigma_position_m * float(rng.standard_normal())
        v.speed = float(v.speed) + settings.sigma_speed_mps * float(rng.standard_normal())
    chasing = policy is not None and policy.chasing_ego  # the cloud sees it match the ego's speed
    unseen = "attempts" in settings.hide or ("unseen_attempts" in settings.hide and not chasing)
    if unseen and policy is not None and policy.brake is None:
        if policy.desired_speed_mps is not None:  # chasing the ego: back to its own speed
            v.target_speed = policy.desired_speed_mps
            policy.desired_speed_mps = None
        policy.schedule(v.clock_s)
    if "speeds" in settings.hide:
        if policy is not None and policy.desired_speed_mps is not None:
            policy.desired_speed_mps = float(v.speed)
        else:
            v.target_speed = float(v.speed)
    if "timers" in settings.hide:
        v.timer = float(rng.uniform(0.0, v.LANE_CHANGE_DELAY))


Futures = dict[int, list[tuple[float, int]]]
"""Per vehicle id, one ``(time [s], new lane)`` per copy in which it changed lane (the first change)"""


def rollout_changes(road: Road, vehicle_ids: np.ndarray, horizon_s: float, dt_s: float, rollouts: int,
                    rng: np.random.Generator, settings: OracleSettings | None = None) -> Futures:
    """Simulate ``rollouts`` copies of ``road`` (:func:`copy_road`) for ``horizon_s`` and note each vehicle's first
    lane change (its centre's lane, as the evaluation's labels).

    :param road: the simulator's road now (left untouched)
    :param vehicle_ids: the vehicles to follow
    :param horizon_s: how long to simulate [s]
    :param dt_s: the simulation step [s]
    :param rollouts: simulated futures
    :param rng: draws the copies' generators
    :param settings: what the copies hide (``None``: nothing)
    :return: per vehicle, the ``(time from now [s], new lane)`` of every copy in which it changed lane
    """
    return first_changes(lambda g: copy_road(road, g, settings), vehicle_ids, horizon_s, dt_s, rollouts, rng)


def first_changes(make_copy: Callable[[np.random.Generator], Road], vehicle_ids: np.ndarray, horizon_s: float,
                  dt_s: float, rollouts: int, rng: np.random.Generator) -> Futures:
    """Simulate ``rollouts`` copies made by ``make_copy`` (each given its own generator, drawn from ``rng``) for
    ``horizon_s`` and note each vehicle's first lane change (see :func:`rollout_changes`).

    :param make_copy: makes one copy of the road from its generator
    :param vehicle_ids: the vehicles to follow
    :param horizon_s: how long to simulate [s]
    :param dt_s: the simulation step [s]
    :param rollouts: simulated futures
    :param rng: draws the copies' generators
    :return: per vehicle, the ``(time from now [s], new lane)`` of every copy in which it changed lane
    """
    wanted = set(vehicle_ids.tolist())
    out: Futures = {vid: [] for vid in wanted}
    steps = int(math.ceil(horizon_s / dt_s - 1e-9))
    for _ in range(rollouts):
        sim = make_copy(np.random.default_rng(int(rng.integers(2**63))))
        tracked = {vehicle_id(v): (v, int(v.lane_index[2])) for v in sim.vehicles if vehicle_id(v) in wanted}
        for step in range(1, steps + 1):
            sim.act()
            sim.step(dt_s)
            for vid, (v, lane0) in list(tracked.items()):
                lane = int(v.lane_index[2])
                if lane != lane0:
                    out[vid].append((step * dt_s, lane))
                    del tracked[vid]
    return out


def intents_from_futures(futures: Futures, rollouts: int, vehicle_ids: np.ndarray, lanes: np.ndarray,
                         horizons_s: tuple[float, ...], elapsed_s: float = 0.0) -> np.ndarray:
    """The ``(N, len(horizons_s), 3)`` probabilities of stay / left / right within each horizon, for an estimate made
    ``elapsed_s`` after the futures were simulated.

    Sides are counted from the estimate's lane, as a model's are: a change into ``lanes[i] - 1`` is *left*, into
    ``lanes[i] + 1`` *right*; a change into the estimate's own lane (it already puts the vehicle there) or two lanes
    away counts as staying. A change the futures put before the estimate counts as imminent.

    :param futures: from :func:`rollout_changes`
    :param rollouts: how many copies ``futures`` were simulated with
    :param vehicle_ids: the estimate's vehicles, ``(N,)`` (a vehicle without futures stays)
    :param lanes: each one's lane by the estimate, ``(N,)`` (left = a lower lane id)
    :param horizons_s: the horizons [s]
    :param elapsed_s: time from the simulation of the futures to the estimate [s]
    :return: the probabilities ``(N, len(horizons_s), 3)``: stay, left, right
    """
    probs = np.zeros((len(vehicle_ids), len(horizons_s), 3))
    probs[:, :, 0] = 1.0
    horizons = np.asarray(horizons_s) + 1e-9
    for i, (vid, lane) in enumerate(zip(vehicle_ids.tolist(), lanes.tolist(), strict=True)):
        for t, new_lane in futures.get(vid, []):
            side = {lane - 1: 1, lane + 1: 2}.get(new_lane, 0)
            if side == 0:
                continue
            within = horizons >= t - elapsed_s
            probs[i, within, 0] -= 1.0 / rollouts
            probs[i, within, side] += 1.0 / rollouts
    return np.clip(probs, 0.0, 1.0)


def picture_road(network: RoadNetwork, picture: TwinPicture, road_map: HighwayMap, traffic: TrafficConfig,
                 rng: np.random.Generator, ego_id: int = EGO_ID) -> Road:
    """A road that starts from the twin's picture, driven by the simulator's driver models (module docstring).

    :param network: the road's geometry (the simulator's; the twin knows the map)
    :param picture: what the cloud knows now
    :param road_map: the twin's map (lane centres, for the lane of each pictured vehicle)
    :param traffic: the driver types' presets and the cut-in settings
    :param rng: the copy's random generator (types, timers, attempts)
    :param ego_id: the ego's id (an IDM car keeping its lane)
    :return: the copy
    """
    road = FastRoad(network=network, vehicles=[], np_random=np.random.RandomState(int(rng.integers(2**31))),
                    record_history=False)
    lanes = np.clip(road_map.lane_of(picture.y_m), 0, road_map.n_lanes - 1).astype(int)
    attempts = picture.attempts if isinstance(picture, RevealedPicture) else {}
    for i, vid in enumerate(picture.vehicle_ids.tolist()):
        x, y, speed, vlat = (float(a[i]) for a in (picture.x_m, picture.y_m, picture.speed_mps,
                                                    picture.lateral_speed_mps))
        lane = int(lanes[i])
        lane_index = ("0", "1", lane)
        offset = y - road_map.lane_centre_y_m(lane)
        side = _moving(picture, i, offset, vlat, rng)
        side = side if 0 <= lane + side < road_map.n_lanes else 0
        aggressive, chasing = _type(picture, i, vid != ego_id, rng)
        attempt = attempts.get(vid)
        aggressive = aggressive or attempt is not None
        if attempt is not None and attempt.brake is not None:
            side = int(attempt.brake.lane_index[2]) - lane  # a near miss under way steers to its victim's lane
        params = traffic.aggressive if aggressive else traffic.normal
        profile = DriverProfile.from_preset(params, speed, traffic.cut_in_rate_per_min if aggressive else 0.0)
        lane_obj = road.network.get_lane(lane_index)
        heading = lane_obj.heading_at(x) + math.asin(float(np.clip(vlat / max(speed, 1.0), -0.5, 0.5)))
        v = TypedDriverVehicle(road, lane_obj.position(x, offset), heading, speed,
                               target_lane_index=("0", "1", lane + side), target_speed=speed)
        v.apply_params(profile)
        v.DELTA = 4.0
        v.timer = float(rng.uniform(0.0, profile.lane_change_delay_s))
        v.dt_id = vid
        if vid == ego_id:
            v.enable_lane_change = False
        elif aggressive:
            v.cut_in = cut_in_policy(traffic, profile.cut_in_rate_per_min, rng)
            v.cut_in.schedule(0.0)  # the next attempt: a fresh draw ...
            if attempt is not None:
                attempt.apply(v.cut_in)  # ... or the simulator's open attempt (``reveal`` ``attempts``) ...
            elif chasing:
                v.cut_in.next_attempt_s = 0.0  # ... or, if the twin judged it chasing the ego, open now
        road.vehicles.append(v)
    return road


def _type(picture: TwinPicture, i: int, judged: bool, rng: np.random.Generator) -> tuple[bool, bool]:
    """Whether a pictured vehicle's driver is aggressive in this copy, and whether it is chasing the ego: one draw
    ``u``, aggressive when ``u < max(p_aggressive, p_chase)``, chasing when ``u < p_chase`` (a chasing driver is an
    aggressive one; the ego, not ``judged``, is neither and draws nothing)."""
    if not judged:
        return False, False
    u = float(rng.random())
    p_chase = float(picture.p_chase[i]) if picture.p_chase is not None else 0.0
    return u < max(float(picture.p_aggressive[i]), p_chase), u < p_chase


def _moving(picture: TwinPicture, i: int, offset_m: float, lateral_speed_mps: float, rng: np.random.Generator) -> int:
    """The side a pictured vehicle is moving to in this copy (-1 left, +1 right, 0 none): drawn from the twin's
    ``p_move`` when the picture has it, else judged from its offset and lateral speed."""
    if picture.p_move is not None:
        p_left, p_right = (float(p) for p in picture.p_move[i])
        u = float(rng.random())
        return -1 if u < p_left else 1 if u < p_left + p_right else 0
    if abs(lateral_speed_mps) > MOVING_LATERAL_MPS and abs(offset_m) > MOVING_OFFSET_M and offset_m * lateral_speed_mps > 0:
        return int(np.sign(lateral_speed_mps))
    return 0


class Oracle:
    """Simulates futures for the recorder (:func:`rollout_changes`) at most every ``settings.period_s``, and turns
    them into each estimate's probabilities (:func:`intents_from_futures`).

    :param settings: rollouts, period, seed, what is hidden and what the copies start from
    :param horizons_s: the intention model's horizons [s]
    :param traffic: the driver types and cut-in settings (needed to start from the twin's picture)
    :param road_map: the twin's map (needed to start from the twin's picture)
    :raises ValueError: when the copies start from the picture without ``traffic`` and ``road_map``
    """

    def __init__(self, settings: OracleSettings, horizons_s: tuple[float, ...], traffic: TrafficConfig | None = None,
                 road_map: HighwayMap | None = None) -> None:
        if settings.start == "picture" and (traffic is None or road_map is None):
            raise ValueError("an oracle that starts from the twin's picture needs the traffic settings and the map")
        self.settings = settings
        self.horizons_s = horizons_s
        self.traffic = traffic
        self.road_map = road_map
        self.chase: ChaseDetector | None = None
        """The twin's chase detector the picture's ``p_chase`` comes from (``None``: starting from the state, or
        ``chases`` hidden or given)"""
        if settings.start == "picture" and "chases" not in settings.hide and not settings.chases_given:
            self.chase = ChaseDetector.load()
        self.rng = np.random.default_rng(settings.seed)
        self._last_t = -math.inf
        self._futures: Futures = {}

    def estimate(self, road: Road, t_s: float, dt_s: float, vehicle_ids: np.ndarray, lanes: np.ndarray,
                 picture: TwinPicture | Callable[[], TwinPicture] | None = None) -> np.ndarray:
        """The oracle's lane-change probabilities, from simulated futures.

        :param road: the simulator's road now (left untouched)
        :param t_s: simulation time now [s]
        :param dt_s: the simulation step [s]
        :param vehicle_ids: the estimate's vehicles, ``(N,)``
        :param lanes: each one's lane by the estimate, ``(N,)``
        :param picture: the twin's picture now, or a function that makes it (needed when the copies start from it)
        :return: the ``(N, H, 3)`` probabilities for ``vehicle_ids`` (in ``lanes``) at simulation time ``t_s`` [s]
        (starting from the twin's ``picture`` of now, when the settings say so: a vehicle that is not in the last
        run's picture stays; a function that makes the picture is called only when the oracle runs)
        """
        if self.settings.start == "picture":
            if picture is None:
                raise ValueError("this oracle starts from the twin's picture: pass it")
            if t_s - self._last_t >= self.settings.period_s - 1e-9:
                self._last_t = t_s
                self._futures = self._from_picture(road.network, picture() if callable(picture) else picture, dt_s)
            return intents_from_futures(self._futures, self.settings.rollouts, vehicle_ids, lanes, self.horizons_s,
                                        t_s - self._last_t)
        if t_s - self._last_t >= self.settings.period_s - 1e-9:
            self._futures, self._last_t = {}, t_s
        todo = np.array([v for v in vehicle_ids.tolist() if v not in self._futures], dtype=np.int64)
        if len(todo):  # a vehicle new since the last run: its futures from now, as if simulated then
            futures = rollout_changes(road, todo, max(self.horizons_s), dt_s, self.settings.rollouts, self.rng,
                                      self.settings)
            elapsed = t_s - self._last_t
            self._futures.update({v: [(t + elapsed, lane) for t, lane in f] for v, f in futures.items()})
        return intents_from_futures(self._futures, self.settings.rollouts, vehicle_ids, lanes, self.horizons_s,
                                    t_s - self._last_t)

    def _from_picture(self, network: RoadNetwork, picture: TwinPicture, dt_s: float) -> Futures:
        assert self.traffic is not None and self.road_map is not None  # checked in __init__
        traffic, road_map = self.traffic, self.road_map
        if not (picture.vehicle_ids == EGO_ID).any():
            return {}  # without the ego's fixes the copies have no ego to chase or to keep away from
        return first_changes(lambda g: picture_road(network, picture, road_map, traffic, g), picture.vehicle_ids,
                             max(self.horizons_s), dt_s, self.settings.rollouts, self.rng)

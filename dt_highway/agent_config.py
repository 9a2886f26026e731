"""Configuration models of the files in ``agents/``: scripted driver files and RL training files.

They are the configuration of the ego's driver, as :mod:`dt_highway.config` is the env's, and
follow its rules: pydantic models, every default and range written once (here), unknown keys,
wrong types and out-of-range values refused with one :class:`~dt_highway.config.ConfigError`
line naming the key (:func:`~dt_highway.config.config_error`, the env tree's error path).
They live in a module of their own because the training file's model builds the env
configuration of a condition (:mod:`dt_highway.conditions`, which imports
:mod:`dt_highway.config`), so :mod:`dt_highway.config` cannot hold it without an import cycle.

Driver files (``agents/<name>.toml``) name their ``kind``: ``human``
(:class:`HumanParams`), ``idm`` (an ``[idm]`` table of :class:`IDMParams`) or ``random``
(:class:`RandomParams`); anything left out keeps the default below. The drivers
(:mod:`dt_highway.drivers.scripted`) take these frozen models as their parameters.

Training files (``kind = "rl"``): :class:`TrainConfig`.
"""

from __future__ import annotations

import math
import numbers
from pathlib import Path
from typing import Annotated, Any, Literal, get_args

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, TypeAdapter, ValidationError, model_validator

from dt_highway.conditions import condition_config
from dt_highway.config import (
    ConfigError,
    DTConfig,
    FrozenSettings,
    TypedValues,
    config_error,
    find_file,
    load_config,
    read_toml,
)
from dt_highway.jsonio import finite_number, whole_number

# ----------------------------------------------------------------------------- the Driver action's limits
ACCEL_MIN_MPS2 = -8.0
"""Hardest braking a driver can command [m/s^2] (about 0.8 g, a full stop on dry asphalt)"""
ACCEL_MAX_MPS2 = 3.0
"""Strongest acceleration a driver can command [m/s^2]"""
DEFAULT_DISCRETE_ACCELS_MPS2 = (-6.0, -3.0, -1.0, 0.0, 1.0, 2.0)
"""Accelerations of the ``DiscreteDriver`` action, keeping the lane [m/s^2]"""
DEFAULT_SPEEDS_MPS = (18.0, 23.0, 27.0, 31.0)
"""Desired speeds of the assisted menu [m/s] (65, 83, 97, 112 km/h)"""


# ----------------------------------------------------------------------------- numbers of driver files
# Small validators rather than pydantic's strict types: the same one-line wording as the rest of the
# configuration ("must be a finite number >= 0"), numpy numbers taken (strict int refuses np.int64), and true/false
# refused as a number, which lax pydantic would read as 1/0.
def _non_negative(value: Any) -> float:
    number = finite_number(value)
    if number is None or number < 0:
        raise ValueError("must be a finite number >= 0")
    return number


def _finite(value: Any) -> float:
    number = finite_number(value)
    if number is None:
        raise ValueError("must be a finite number")
    return number


def _flag(value: Any) -> bool:
    if not isinstance(value, bool):
        raise ValueError("must be true or false")
    return value


NonNegative = Annotated[float, BeforeValidator(_non_negative)]
"""A finite number >= 0 (an integer is taken as the same float; ``true`` is not a number)"""
Finite = Annotated[float, BeforeValidator(_finite)]
"""A finite number of either sign"""
Flag = Annotated[bool, BeforeValidator(_flag)]
"""``true`` or ``false``, nothing else"""


# ----------------------------------------------------------------------------- scripted drivers
class IDMParams(FrozenSettings):
    """Intelligent Driver Model (Treiber, Hennecke & Helbing 2000, Phys. Rev. E 62, 1805).

    :param desired_speed_mps: ``v0`` [m/s], > 0
    :param time_headway_s: ``T`` [s], > 0
    :param min_gap_m: ``s0`` [m]
    :param max_accel_mps2: ``a`` [m/s^2], > 0
    :param comfort_decel_mps2: ``b`` [m/s^2], > 0
    :param delta: acceleration exponent [-], > 0
    """

    desired_speed_mps: NonNegative = Field(default=30.0, gt=0)
    time_headway_s: NonNegative = Field(default=1.6, gt=0)
    min_gap_m: NonNegative = 2.0
    max_accel_mps2: NonNegative = Field(default=0.73, gt=0)
    comfort_decel_mps2: NonNegative = Field(default=1.67, gt=0)
    delta: NonNegative = Field(default=4.0, gt=0)  # 0: (v/v0)^0 = 1, no acceleration on a free road


class HumanParams(FrozenSettings):
    """The human-like driver's parameters (:mod:`dt_highway.drivers.scripted` gives their sources).

    :param idm: car following
    :param reaction_time_s: ``T'`` [s]
    :param distance_error: relative distance estimation error ``V_s`` [-]
    :param inverse_ttc_error_per_s: ``r_c`` [1/s]
    :param error_correlation_s: correlation time of the estimation errors [s]
    :param politeness: MOBIL ``p`` [-]
    :param lane_change_threshold_mps2: MOBIL ``Delta a_th`` [m/s^2]
    :param safe_decel_mps2: MOBIL ``b_safe`` [m/s^2]
    :param min_lane_change_interval_s: least time between two lane changes [s]
    :param alert_headway_factor: time gap multiplier while warned [-]
    :param alert_speed_factor: desired speed multiplier while warned [-]
    :param alert_reaction_factor: reaction time multiplier while warned [-]
    :param alert_ahead_m: a marked car this far ahead (own or next lane) warns [m]
    :param alert_behind_m: a marked car in the next lane this far behind warns [m]
    :param alert_hold_s: the warning lasts this long after the marker is gone [s]
    :param anticipate_cut_in: keep a gap behind a marked car in the next lane
    :param alert_ease_off_mps2: strongest deceleration that gap-keeping uses [m/s^2]
    """

    idm: IDMParams = IDMParams(desired_speed_mps=27.0)
    reaction_time_s: NonNegative = 1.0
    distance_error: NonNegative = 0.1
    inverse_ttc_error_per_s: NonNegative = 0.01
    error_correlation_s: NonNegative = 20.0
    politeness: NonNegative = 0.2
    lane_change_threshold_mps2: NonNegative = 0.2
    safe_decel_mps2: NonNegative = 4.0
    min_lane_change_interval_s: NonNegative = 10.0
    alert_headway_factor: NonNegative = 1.4
    alert_speed_factor: NonNegative = 0.95
    alert_reaction_factor: NonNegative = 0.7
    alert_ahead_m: NonNegative = 60.0
    alert_behind_m: NonNegative = 10.0
    alert_hold_s: NonNegative = 3.0
    anticipate_cut_in: Flag = True
    alert_ease_off_mps2: NonNegative = 0.5


class RandomParams(FrozenSettings):
    """The random driver's parameters.

    :param accel_min_mps2: least acceleration [m/s^2]
    :param accel_max_mps2: largest acceleration [m/s^2], > ``accel_min_mps2``
    :param lane_change_prob: chance of a lane request per decision, in [0, 1] [-]
    """

    accel_min_mps2: Finite = -2.0
    accel_max_mps2: Finite = 2.0
    lane_change_prob: Finite = Field(default=0.02, ge=0, le=1)

    @model_validator(mode="after")
    def _range(self) -> RandomParams:
        if not self.accel_min_mps2 < self.accel_max_mps2:
            raise ValueError(f"a random driver needs accel_min_mps2 < accel_max_mps2 "
                             f"(got {self.accel_min_mps2} and {self.accel_max_mps2})")
        return self


class HumanDriverFile(HumanParams):
    """``kind = "human"``: the :class:`HumanParams` at the top level of the file."""

    kind: Literal["human"]

    def params(self) -> HumanParams:
        """The human driver's parameters this file gives, as :class:`HumanParams`.

        :return: the driver's parameters (the file without its ``kind``)
        """
        return HumanParams.model_validate(self.model_dump(exclude={"kind"}))


class IDMDriverFile(FrozenSettings):
    """``kind = "idm"``: the :class:`IDMParams` in an ``[idm]`` table."""

    kind: Literal["idm"]
    idm: IDMParams = IDMParams()


class RandomDriverFile(RandomParams):
    """``kind = "random"``: the :class:`RandomParams` at the top level of the file."""

    kind: Literal["random"]

    def params(self) -> RandomParams:
        """The random driver's parameters this file gives, as :class:`RandomParams`.

        :return: the driver's parameters (the file without its ``kind``)
        """
        return RandomParams.model_validate(self.model_dump(exclude={"kind"}))


DriverFile = Annotated[HumanDriverFile | IDMDriverFile | RandomDriverFile, Field(discriminator="kind")]
"""A scripted driver file, told apart by its ``kind``"""
_DRIVER_FILES: dict[str, type[FrozenSettings]] = {
    get_args(m.model_fields["kind"].annotation)[0]: m for m in (HumanDriverFile, IDMDriverFile, RandomDriverFile)
}
DRIVER_KINDS: tuple[str, ...] = tuple(_DRIVER_FILES)
"""The ``kind`` of a scripted driver file"""
_DRIVER_FILE: TypeAdapter[HumanDriverFile | IDMDriverFile | RandomDriverFile] = TypeAdapter(DriverFile)


def parse_driver_file(tree: dict[str, Any]) -> HumanDriverFile | IDMDriverFile | RandomDriverFile:
    """Validate a parsed driver file.

    :param tree: the file's contents (``kind`` and parameters)
    :return: the file's model
    :raises ConfigError: one line, on an unknown kind, key or a bad value (a training file,
        ``kind = "rl"``, is refused with how to train it)
    """
    kind = tree.get("kind") if isinstance(tree, dict) else None
    if kind == "rl":
        raise ConfigError("this is an RL training config: train it (dt-highway train --config FILE --out "
                          "agents/NAME.zip) and drive with the .zip")
    if kind not in DRIVER_KINDS:
        kinds = ", ".join(repr(k) for k in DRIVER_KINDS)
        raise ConfigError(f"a driver file needs kind = one of {kinds} (got {kind!r})")
    try:
        return _DRIVER_FILE.validate_python(tree)
    except ValidationError as exc:
        raise config_error(exc, _DRIVER_FILES[kind], prefix="", skip=1) from None


# ----------------------------------------------------------------------------- reward terms of training files
class CollisionCost(TypedValues):
    """Cost of a collision of the ego, by its kind (:data:`~dt_highway.metrics.safety.COLLISION_KINDS`,
    as the trial logs classify it) [-, per collision].

    :param cut_in: with a vehicle that cut in front of the ego within the last 5 s
    :param rear_end: front to rear (either striker)
    :param side_swipe: side contact
    :param unknown: no partner found
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    cut_in: float = Field(0.0, ge=0, description="cost of a cut-in collision [-]")
    rear_end: float = Field(0.0, ge=0, description="cost of a rear-end collision [-]")
    side_swipe: float = Field(0.0, ge=0, description="cost of a side-swipe collision [-]")
    unknown: float = Field(0.0, ge=0, description="cost of a collision of unknown kind [-]")


class TTCCost(TypedValues):
    """Exposure to a small 2-D time to collision (Jiao 2023, as the trial logs' ``ttc2d_s``), after
    Minderhoud & Bovy's (2001) TET/TIT with threshold ``TTC*``.

    :param weight: cost per unit of exposure [1/s] (``tet``) or [1/s^2] (``tit``)
    :param threshold_s: ``TTC*`` [s]
    :param mode: ``tet``: time exposed, ``sum dt [TTC <= TTC*]`` [s]; ``tit``: time integrated,
        ``sum dt (TTC* - TTC) [TTC <= TTC*]`` [s^2]
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    weight: float = Field(0.0, ge=0, description="cost per second (tet) or second^2 (tit) of exposure")
    threshold_s: float = Field(3.0, gt=0, le=10, description="TTC* [s]")
    mode: Literal["tet", "tit"] = Field("tet", description="tet: time exposed; tit: time-integrated TTC deficit")


class BrakingCost(TypedValues):
    """Hard braking: ``sum dt max(0, -a - threshold)`` over the simulation steps, the speed shed
    beyond the threshold deceleration [m/s].

    :param weight: cost per m/s [s/m]
    :param threshold_mps2: deceleration from which braking costs [m/s^2]
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    weight: float = Field(0.0, ge=0, description="cost per m/s shed beyond the threshold [s/m]")
    threshold_mps2: float = Field(3.0, ge=0, le=10, description="deceleration from which braking costs [m/s^2]")


class ProgressReward(TypedValues):
    """Progress: ``distance``, the metres the ego travelled along the road [m]; or ``speed``,
    ``sum dt max(0, 1 - |v - v*| / v*)``, time near the target speed ``v*`` [s].

    :param weight: reward per metre [1/m] (``distance``) or per second at the target speed [1/s] (``speed``)
    :param mode: ``distance`` or ``speed``
    :param target_mps: ``v*`` [m/s] (``speed``)
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    weight: float = Field(0.0, ge=0, description="reward per metre (distance) or per second at v* (speed)")
    mode: Literal["distance", "speed"] = Field("distance", description="distance: metres travelled; speed: time near v*")
    target_mps: float = Field(27.0, gt=0, le=45, description="speed: the target speed v* [m/s]")


class JerkCost(TypedValues):
    """Comfort: longitudinal jerk, ``sum dt |j|`` = ``sum |a_k - a_(k-1)|`` over the simulation steps,
    the total variation of the acceleration [m/s^2].

    :param weight: cost per m/s^2 of acceleration change [s^2/m]
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    weight: float = Field(0.0, ge=0, description="cost per m/s^2 of acceleration change [s^2/m]")


class RewardConfig(TypedValues):
    """The training reward (``[reward]`` of a training file; :mod:`dt_highway.rl.rewards` computes it).

    ``reward = highway * r_highway + progress - collision - ttc2d - hard_braking - jerk`` per
    policy step, each term summed over the step's simulation steps. The defaults are highway-env's
    reward alone, exactly (the shipped policies' reward). Example::

        [reward]
        highway = 1.0
        collision = {cut_in = 20.0, rear_end = 20.0, side_swipe = 20.0, unknown = 20.0}
        ttc2d = {weight = 1.0, threshold_s = 3.0, mode = "tet"}

    :param highway: weight of highway-env's own reward (``collision_reward``, ``high_speed_reward``... of the scenario) [-]
    :param collision: cost per collision, by kind
    :param ttc2d: exposure to a small 2-D TTC
    :param hard_braking: braking beyond a threshold
    :param progress: distance travelled or time near a target speed
    :param jerk: comfort
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    highway: float = Field(1.0, ge=0, description="weight of highway-env's reward [-]")
    collision: CollisionCost = Field(default_factory=CollisionCost, description="cost per collision, by kind")
    ttc2d: TTCCost = Field(default_factory=TTCCost, description="2-D TTC exposure (TET/TIT)")
    hard_braking: BrakingCost = Field(default_factory=BrakingCost, description="braking beyond a threshold")
    progress: ProgressReward = Field(default_factory=ProgressReward, description="distance or speed toward a target")
    jerk: JerkCost = Field(default_factory=JerkCost, description="longitudinal jerk")

    def is_highway_only(self) -> bool:
        """Whether this is highway-env's reward alone, unscaled (the default: no wrapper needed).

        :return: whether every term equals the default's
        """
        return self == RewardConfig()


# ----------------------------------------------------------------------------- algorithm hyperparameters
def _real(value: Any) -> float | None:
    """A number from TOML or Python (numpy scalars too) as a float, ``None`` for anything else (``true``, text)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        return None
    return float(value)


def _whole(low: int) -> Any:
    def check(value: Any) -> int:
        number = whole_number(value)
        if number is None or number < low:
            raise ValueError(f"must be a whole number >= {low}")
        return number
    return BeforeValidator(check)


def _number(low: float, high: float | None = None, low_open: bool = False, schedule: bool = False,
            infinite: bool = False) -> Any:
    """A number in [low, high] ((low, high] with ``low_open``); a callable too with ``schedule`` (from
    Python: stable-baselines3 takes a schedule of the training progress), +inf too with ``infinite``."""
    above = f"> {low:g}" if low_open else f">= {low:g}"
    allowed = f"a number {above}" + (f" and <= {high:g}" if high is not None else "") + (
        " (or a schedule, from Python)" if schedule else "")

    def check(value: Any) -> Any:
        if schedule and callable(value):
            return value
        number = _real(value)
        if (number is None or math.isnan(number) or (math.isinf(number) and not (infinite and number > 0))
                or number < low or (low_open and number == low) or (high is not None and number > high)):
            raise ValueError(f"must be {allowed}")
        return number
    return BeforeValidator(check)


def _train_freq(value: Any) -> Any:
    if (number := whole_number(value)) is not None and number >= 1:
        return number
    if isinstance(value, (list, tuple)) and len(value) == 2:  # [4, "step"], SB3's TrainFreq too
        count, unit = whole_number(value[0]), getattr(value[1], "value", value[1])
        if count is not None and count >= 1 and unit in ("step", "episode"):
            return (count, unit)
    raise ValueError('must be a whole number >= 1 or [N, "step"] / [N, "episode"]')


def _gradient_steps(value: Any) -> int:
    number = whole_number(value)
    if number is None:
        raise ValueError("must be a whole number (-1: as many as the env steps of the rollout; 0: no training)")
    return number


Probability = Annotated[float, _number(0.0, 1.0)]
Positive = Annotated[float, _number(0.0, low_open=True)]
NonNegativeNumber = Annotated[float, _number(0.0)]
Schedule = Annotated[Any, _number(0.0, low_open=True, schedule=True)]
"""A number > 0, or (from Python) a schedule of the training progress"""
GradientNorm = Annotated[float, _number(0.0, low_open=True, infinite=True)]
"""A number > 0; ``inf`` clips nothing"""


class PPOHyperparameters(TypedValues):
    """PPO's hyperparameters with their allowed ranges and stable-baselines3's defaults (``[hyperparameters]``
    of a training file), checked before any env is built: stable-baselines3 takes most of them as given
    (``gamma = 2`` or ``clip_range = -0.2`` would train, ``gamma = "0.9"`` fail after the first rollout).
    Keys not listed here go to the algorithm as they are, which refuses those it does not take."""

    model_config = ConfigDict(extra="allow")

    learning_rate: Schedule = 3e-4
    n_steps: Annotated[int, _whole(1)] = 2048
    batch_size: Annotated[int, _whole(1)] = 64
    n_epochs: Annotated[int, _whole(1)] = 10
    gamma: Probability = 0.99
    gae_lambda: Probability = 0.95
    clip_range: Schedule = 0.2
    clip_range_vf: Schedule | None = None
    normalize_advantage: Flag = True
    ent_coef: NonNegativeNumber = 0.0
    vf_coef: NonNegativeNumber = 0.5
    max_grad_norm: GradientNorm = 0.5
    target_kl: Positive | None = None
    stats_window_size: Annotated[int, _whole(1)] = 100

    @model_validator(mode="after")
    def _batch(self) -> PPOHyperparameters:
        if self.batch_size < 2 and self.normalize_advantage:  # one sample has no spread to normalise by
            raise ValueError("hyperparameters.batch_size = 1 needs normalize_advantage = false")
        return self


class DQNHyperparameters(TypedValues):
    """DQN's hyperparameters with their allowed ranges and stable-baselines3's defaults (see
    :class:`PPOHyperparameters`)."""

    model_config = ConfigDict(extra="allow")

    learning_rate: Schedule = 1e-4
    buffer_size: Annotated[int, _whole(1)] = 1_000_000
    learning_starts: Annotated[int, _whole(0)] = 100
    batch_size: Annotated[int, _whole(1)] = 32
    tau: Annotated[float, _number(0.0, 1.0, low_open=True)] = 1.0
    gamma: Probability = 0.99
    train_freq: Annotated[Any, BeforeValidator(_train_freq)] = 4
    gradient_steps: Annotated[int, BeforeValidator(_gradient_steps)] = 1
    optimize_memory_usage: Flag = False
    n_steps: Annotated[int, _whole(1)] = 1
    target_update_interval: Annotated[int, _whole(1)] = 10_000
    exploration_fraction: Probability = 0.1
    exploration_initial_eps: Probability = 1.0
    exploration_final_eps: Probability = 0.05
    max_grad_norm: GradientNorm = 10
    stats_window_size: Annotated[int, _whole(1)] = 100

    @model_validator(mode="after")
    def _memory(self) -> DQNHyperparameters:
        kwargs = getattr(self, "replay_buffer_kwargs", None) or {}
        if not self.optimize_memory_usage:
            return self
        if not isinstance(kwargs, dict) or bool(kwargs.get("handle_timeout_termination", True)):
            raise ValueError("hyperparameters.optimize_memory_usage = true needs replay_buffer_kwargs = "
                             "{handle_timeout_termination = false} (stable-baselines3 supports only the two together)")
        if self.n_steps > 1:
            raise ValueError(f"hyperparameters.optimize_memory_usage = true needs n_steps = 1 (got {self.n_steps}): "
                             "stable-baselines3's n-step replay buffer does not support it")
        return self


HYPERPARAMETERS: dict[str, type[BaseModel]] = {"PPO": PPOHyperparameters, "DQN": DQNHyperparameters}
"""The checked hyperparameters of each algorithm"""
SET_BY_THE_FILE = {"policy": "the training file's observation sets it", "env": "the training file's scenario sets it",
                   "seed": "use the training file's seed", "device": "training runs on the CPU",
                   "verbose": "dt-highway shows the progress", "policy_kwargs": "use the [policy_kwargs] table"}
"""Algorithm arguments a training file sets itself, and why they are not hyperparameters"""


def check_hyperparameters(algorithm: str, values: dict[str, Any]) -> str | None:
    """What is wrong with a training file's ``[hyperparameters]`` (``None``: nothing).

    :param algorithm: ``PPO`` or ``DQN``
    :param values: the table
    :return: one line naming each bad key and what is allowed
    """
    mistakes = [f"hyperparameters.{key} cannot be set here: {SET_BY_THE_FILE[key]}"
                for key in values if key in SET_BY_THE_FILE]
    try:
        HYPERPARAMETERS[algorithm].model_validate({k: v for k, v in values.items() if k not in SET_BY_THE_FILE})
    except ValidationError as exc:
        mistakes += [f"hyperparameters.{'.'.join(str(p) for p in e['loc'])} = {e.get('input')!r}: "
                     f"{e['msg'].removeprefix('Value error, ')}" if e["loc"] else e["msg"].removeprefix("Value error, ")
                     for e in exc.errors()]
    return "; ".join(mistakes) or None


# ----------------------------------------------------------------------------- training files
OBSERVATIONS = ("kinematics", "adas", "adas-threat", "vision")
ALGORITHMS = ("PPO", "DQN")
VISION_CAMERA = {"width_px": 128, "height_px": 72}
"""Camera size of the vision setting unless the scenario or ``set`` says otherwise [px]"""


class TrainConfig(TypedValues):
    """What ``dt-highway train`` trains: an RL training file (``agents/<name>.toml``, ``kind = "rl"``).

    A training file names the algorithm, the observation setting and the scenario; everything
    left out keeps the defaults below. A short example (the shipped ones are in ``agents/``)::

        kind = "rl"
        algorithm = "PPO"
        observation = "kinematics"      # kinematics | adas | vision
        scenario = "envs/highway-trial.toml"
        timesteps = 200000
        [hyperparameters]               # passed to the stable-baselines3 algorithm
        learning_rate = 0.0003

    Observation settings:

    * ``kinematics`` (baseline): highway-env's Kinematics observation of the nearest vehicles
      (``presence, x, y, vx, vy``, relative to the ego, normalised).
    * ``adas`` (ADAS-aware): the same plus ``marked``, 1 where the ADAS overlay shows an
      "aggressive driver" marker on that car (:class:`~dt_highway.env.OverlayKinematics`):
      the twin's verdict as delivered through the fusion and the overlay, never ground truth.
      It trains in the ADAS condition (camera and fusion on).
    * ``adas-threat``: ``adas`` plus ``cut_in_warned`` (1 where a mark on that car reads "cutting in")
      and ``side`` (the side the label says it comes from: -1 left, +1 right, 0 not said), from
      the marks as drawn (:class:`~dt_highway.env.OverlayKinematics` with ``threat = true``). It
      trains in the ``adas-threat`` condition (the overlay's ``threat`` mode).
    * ``vision``: the ego camera's ``rgb`` image (and ``depth`` with ``depth = true``) for a CNN
      policy (stable-baselines3's ``MultiInputPolicy``); the camera is made small for it.

    Actions (``action``): the ``DiscreteDriver`` menu
    (:class:`~dt_highway.env.actions.DiscreteDriverAction`): ``pedals``, keep the lane with
    one of ``accels_mps2`` or ask for one lane left or right; ``assisted``
    (:class:`~dt_highway.drivers.menus.AssistedMenu`), choose one of ``speeds_mps`` as desired
    speed or a lane change (taken when safe), the Intelligent Driver Model keeping the gap;
    ``assisted-delayed``, the same menu whose gap keeping reacts like a driver who was not warned:
    a car newly in the lane ahead is followed only ``reaction_time_s`` after it appeared, and it
    brakes at most ``brake_limit_mps2``.

    Reward (``[reward]``, :class:`RewardConfig`): highway-env's reward by default; safety terms
    (collisions by kind, 2-D TTC exposure, hard braking, progress, jerk) with their weights.
    """

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    kind: Literal["rl"] = "rl"
    algorithm: Literal["PPO", "DQN"] = Field("PPO", description="stable-baselines3 algorithm")
    observation: Literal["kinematics", "adas", "adas-threat", "vision"] = Field("kinematics",
                                                                                description="observation setting")
    depth: bool = Field(False, description="vision: also the depth image")
    scenario: str = Field("envs/highway-trial.toml", description="scenario file the policy trains on")
    set: list[str] = Field(default_factory=list, description="dotted.key=value overrides of the scenario")
    timesteps: int = Field(200_000, gt=0, description="env steps to train for [-]")
    n_envs: int = Field(2, ge=1, le=64, description="parallel envs (SubprocVecEnv when > 1) [-]")
    seed: int = Field(0, ge=0, description="seed of the model and of the training envs")
    vehicles_count: int = Field(7, ge=2, le=30, description="kinematics/adas: observed vehicles, ego included [-]")
    see_behind: bool = Field(True, description="kinematics/adas: observe vehicles behind too")
    action: Literal["pedals", "assisted", "assisted-delayed"] = Field(
        "pedals",
        description="pedals: choose accelerations; assisted: choose a desired speed or a lane, IDM keeps the gap; "
        "assisted-delayed: the same, IDM reacting like an unwarned driver",
    )
    reaction_time_s: float = Field(1.2, ge=0, le=3, description="assisted-delayed: time before the gap keeping "
                                   "responds to a car newly in the lane ahead [s]")
    brake_limit_mps2: float = Field(6.0, gt=0, le=-ACCEL_MIN_MPS2, description="assisted-delayed: hardest braking "
                                    "of the gap keeping [m/s^2]")
    reward: RewardConfig = Field(default_factory=RewardConfig, description="the training reward's terms")
    accels_mps2: list[float] = Field(default_factory=lambda: list(DEFAULT_DISCRETE_ACCELS_MPS2),
                                     description="pedals: accelerations of the action menu [m/s^2]")
    speeds_mps: list[float] = Field(default_factory=lambda: list(DEFAULT_SPEEDS_MPS),
                                    description="assisted: desired speeds of the action menu [m/s]")
    eval_every_steps: int = Field(20_000, gt=0, description="evaluate on held-out seeds this often [steps]")
    eval_episodes: int = Field(4, ge=1, description="episodes per evaluation [-]")
    eval_seed: int = Field(100_000, ge=0, description="first seed of the evaluation episodes")
    checkpoint_every_steps: int = Field(50_000, gt=0, description="save a checkpoint this often [steps]")
    hyperparameters: dict[str, Any] = Field(default_factory=dict, description="keyword arguments of the algorithm")
    policy_kwargs: dict[str, Any] = Field(default_factory=dict, description="policy_kwargs of the algorithm")

    @model_validator(mode="after")
    def _menus(self) -> TrainConfig:
        if not self.accels_mps2 or not all(ACCEL_MIN_MPS2 <= a <= ACCEL_MAX_MPS2 for a in self.accels_mps2):
            raise ValueError(f"accels_mps2 must be a non-empty list within [{ACCEL_MIN_MPS2}, {ACCEL_MAX_MPS2}] m/s^2")
        if not self.speeds_mps or not all(0 < v <= 45 for v in self.speeds_mps):
            raise ValueError("speeds_mps must be a non-empty list of speeds in (0, 45] m/s")
        mistakes = check_hyperparameters(self.algorithm, self.hyperparameters)
        if mistakes:
            raise ValueError(mistakes)
        n_steps = whole_number(self.hyperparameters.get("n_steps", 2048))
        if (self.algorithm == "PPO" and n_steps is not None and n_steps * self.n_envs < 2
                and self.hyperparameters.get("normalize_advantage", True)):
            raise ValueError(f"hyperparameters.n_steps = {n_steps} with n_envs = {self.n_envs} gives rollouts of one "
                             "step, which PPO cannot normalise: n_steps x n_envs must be >= 2")
        freq = self.hyperparameters.get("train_freq")
        if self.algorithm == "DQN" and isinstance(freq, (list, tuple)) and self.n_envs > 1 and (
                getattr(freq[1], "value", freq[1]) == "episode"):
            raise ValueError(f"hyperparameters.train_freq = {list(freq)!r} counts episodes, which stable-baselines3 "
                             f"does in one env only: set n_envs = 1 (got {self.n_envs})")
        return self

    def env_config(self, condition: str | None = None) -> DTConfig:
        """The env configuration of this policy: its scenario and overrides, its observation
        and action, in the condition it trains in (or ``condition``: ``baseline``/``adas``).

        :param condition: the condition to run in (``None``: the one of the observation, ``adas``, ``adas-threat``
            or ``baseline``)
        :return: the loaded env configuration
        :raises ConfigError: on a bad scenario or override
        """
        condition = condition or {"adas": "adas", "adas-threat": "adas-threat"}.get(self.observation, "baseline")
        extra = condition_config(condition)
        extra["highway"] = {"observation": self.observation_config(), "action": self.action_config()}
        if self.observation == "vision":
            extra["camera"] = {**VISION_CAMERA, "enabled": True}
        return load_config(self.scenario, list(self.set), extra)

    def observation_config(self) -> dict[str, Any]:
        """The ``highway.observation`` table of this setting.

        :return: the table (``Camera``, ``OverlayKinematics`` or ``Kinematics``)
        """
        if self.observation == "vision":
            return {"type": "Camera", "depth": self.depth}
        kind = "OverlayKinematics" if self.observation in ("adas", "adas-threat") else "Kinematics"
        table: dict[str, Any] = {"type": kind, "vehicles_count": self.vehicles_count, "see_behind": self.see_behind}
        if self.observation == "adas-threat":
            table["threat"] = True
        return table

    def action_config(self) -> dict[str, Any]:
        """The ``highway.action`` table: the discrete menu over the Driver action.

        :return: the table (``DiscreteDriver``, with speeds for the assisted actions, accelerations for pedals)
        """
        if self.action == "assisted-delayed":
            return {"type": "DiscreteDriver", "assist": True, "speeds_mps": list(self.speeds_mps),
                    "reaction_time_s": self.reaction_time_s, "brake_limit_mps2": self.brake_limit_mps2}
        if self.action == "assisted":
            return {"type": "DiscreteDriver", "assist": True, "speeds_mps": list(self.speeds_mps)}
        return {"type": "DiscreteDriver", "accels_mps2": list(self.accels_mps2)}


def parse_train_config(tree: dict[str, Any], where: str = "training config") -> TrainConfig:
    """Validate a parsed training file.

    :param tree: the file's contents
    :param where: the file, for the message
    :return: the validated configuration
    :raises ConfigError: one line naming each bad key and what is allowed
    """
    try:
        return TrainConfig.model_validate(tree)
    except ValidationError as exc:
        raise config_error(exc, TrainConfig, prefix=f"{where}: ") from None


def load_train_config(path: str | Path) -> TrainConfig:
    """Read and validate ``agents/<name>.toml`` (``kind = "rl"``).

    ``agents/NAME`` or a bare ``NAME`` missing here is read from the checkout's ``agents/``
    (:func:`~dt_highway.config.find_file`); the scenario it names likewise from ``envs/``, when it is read.

    :param path: the training file, or the name of one in ``agents/``
    :return: the validated configuration
    :raises ConfigError: on a missing or unreadable file, or bad contents
    """
    p = Path(find_file(path, "agents"))
    tree = read_toml(p, "training config")
    if tree.get("kind") != "rl":
        raise ConfigError(f"{p}: a training config needs kind = \"rl\" (got {tree.get('kind')!r}; "
                          f"scripted drivers are not trained)")
    return parse_train_config(tree, str(p))

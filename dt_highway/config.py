"""One typed, validated configuration tree for dt-highway.

Layers, later ones win: the defaults below, then a scenario file (``envs/*.toml``),
then ``--set dotted.key=value`` overrides (or a nested dict given to ``gym.make``).
Dicts are merged **deeply**: ``{"twin": {"uplink": {"rate_hz": 5}}}`` changes one value
and keeps every other default (highway-env's ``configure`` replaces nested dicts whole).

Every mistake a user can make (unknown key, wrong type, out-of-range value, unreadable
TOML) raises :class:`ConfigError`, a ``ValueError`` whose message is one line naming the
dotted key and what is allowed.

The ``highway`` section holds highway-env's own configuration keys with their usual
meaning; for convenience those keys are also accepted at the top level of a dict, as a
highway-env user would write them (``config={"lanes_count": 3}``).

The components' settings (:class:`FrozenSettings`: the simulated detector's error model, the
fusion's and the renderer's settings) take the defaults and ranges of the values a user sets
from these sections (:func:`section_field`). The files in ``agents/`` (driver and training
files) have their models in :mod:`dt_highway.agent_config`, with the same error path
(:func:`config_error`).
"""

from __future__ import annotations

import copy
import math
import tomllib
import types
import typing
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any, Literal, TypeVar, get_args

import numpy as np
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    SerializerFunctionWrapHandler,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_serializer,
    model_validator,
)
from pydantic_core import PydanticCustomError

from dt_highway.choices import POPULATIONS as POPULATIONS  # re-exported: its home before dt_highway.choices
from dt_highway.errors import ConfigError
from dt_highway.jsonio import finite_number

_S = TypeVar("_S", bound=BaseModel)


def _plain(annotation: Any) -> tuple[Any, ...]:
    """The types a field may hold: its union's members but ``None`` (the annotation itself when it is no union)."""
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        return tuple(a for a in typing.get_args(annotation) if a is not type(None))
    return (annotation,)


def _kind(value: Any) -> str:
    return "text" if isinstance(value, str) else "true/false"


def check_scalar(annotation: Any, value: Any) -> None:
    """Refuse true/false or text where a number goes (also as a list's or tuple's item), and anything but
    true/false where a switch goes: pydantic's lax reading would take ``true`` as 1, ``"3"`` as 3 and ``"off"``
    as false. ``None`` and numpy's numbers and booleans pass.

    :param annotation: the field's type
    :param value: the value given
    :raises PydanticCustomError: naming what the key takes
    """
    types_ = _plain(annotation)
    if value is None or not types_:
        return
    if all(t in (int, float) for t in types_):
        if isinstance(value, (bool, np.bool_, str)):
            raise PydanticCustomError("not_a_number", "must be {number}, not {kind}",
                                      {"number": "a whole number" if float not in types_ else "a number",
                                       "kind": _kind(value)})
    elif types_ == (bool,):
        if not isinstance(value, (bool, np.bool_)):
            raise PydanticCustomError("not_a_switch", "must be true or false", {})
    elif len(types_) == 1 and typing.get_origin(types_[0]) in (list, tuple) and isinstance(value, (list, tuple)):
        items = {a for a in typing.get_args(types_[0]) if a is not Ellipsis}
        bad = next((v for v in value if isinstance(v, (bool, np.bool_, str))), None)
        if items and items <= {int, float} and bad is not None:
            raise PydanticCustomError("not_numbers", "must be a list of numbers, without {kind}", {"kind": _kind(bad)})


class TypedValues(BaseModel):
    """Base of the models read from files and ``--set``: a number key refuses true/false and text, and a
    switch anything but true/false (:func:`check_scalar`). pydantic would read ``true`` as 1, ``"3"`` as 3 and
    ``"off"`` as false, so ``lanes_count = true`` made one lane; TOML and ``--set`` give numbers and switches
    their own types."""

    @field_validator("*", mode="before")
    @classmethod
    def _a_number_is_a_number(cls, value: Any, info: ValidationInfo) -> Any:
        if info.field_name is not None:
            check_scalar(cls.model_fields[info.field_name].annotation, value)
        return value


class _Section(TypedValues):
    """Base of every config section: unknown keys are errors, and a configuration cannot change once
    validated (a change goes through :func:`merge`, which checks the rules across sections too)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    def __setattr__(self, name: str, value: Any) -> None:
        """Refused, in one line: a section set on its own would skip the rules across sections (fusion
        needs the camera...) and the env would not see it."""
        shown = " ".join(repr(value).split())
        raise ConfigError(f"the configuration cannot be changed in place ({type(self).__name__}.{name} = "
                          f"{shown if len(shown) <= 60 else shown[:57] + '...'}): pass the change to "
                          "env.unwrapped.configure({'section': {'key': value}}) (applied at the next reset), "
                          "gym.make(..., config=...) or dt_highway.config.merge")

    def __delattr__(self, name: str) -> None:
        """Refused, as :meth:`__setattr__`."""
        raise ConfigError(f"the configuration cannot be changed in place (del {type(self).__name__}.{name}): pass "
                          "the change to env.unwrapped.configure({...}), gym.make(..., config=...) or "
                          "dt_highway.config.merge")


class FrozenSettings(BaseModel):
    """Base of the settings objects the components take (a driver's parameters, the simulated
    detector's error model, the fusion's and the renderer's settings): unknown keys are errors,
    values are checked when the object is made and cannot change afterwards."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        """Fields by keyword, or by position in their declared order (as the dataclasses these
        settings once were). Made from a configuration, a mistake is the tree's one-line
        :class:`ConfigError`; made by hand, pydantic's ``ValidationError`` (a ``ValueError``)
        names each bad field.

        :param args: field values in their declared order
        :param kwargs: field values by name
        :raises pydantic.ValidationError: on an unknown field, a wrong type or an out-of-range value
        :raises TypeError: on more positional values than fields, or a field given twice
        """
        if args:
            names = list(type(self).model_fields)
            if len(args) > len(names):
                raise TypeError(f"{type(self).__name__} takes at most {len(names)} values ({', '.join(names)}); "
                                f"got {len(args)}")
            twice = sorted(set(names[: len(args)]) & kwargs.keys())
            if twice:
                raise TypeError(f"{type(self).__name__} got {twice[0]!r} both by position and by keyword")
            kwargs = {**dict(zip(names, args, strict=False)), **kwargs}
        super().__init__(**kwargs)


def section_field(section: type[BaseModel], name: str) -> Any:
    """One field of a config section (its default, range and description), for a settings
    model that takes that value from the section: the default and the range stay written once,
    in the section (``th: float = section_field(FusionConfig, "th")``).

    :param section: the config section model (:class:`FusionConfig`)
    :param name: the field's name
    :return: a copy of the section's field definition
    """
    return copy.deepcopy(section.model_fields[name])


HIGHWAY_ENV_OBSERVATION_TYPES = (
    "TimeToCollision", "Kinematics", "OccupancyGrid", "KinematicsGoal", "GrayscaleObservation",
    "AttributesObservation", "MultiAgentObservation", "TupleObservation", "LidarObservation", "ExitObservation",
)
"""Observation types of highway-env 1.12's ``observation_factory``"""
HIGHWAY_ENV_ACTION_TYPES = ("ContinuousAction", "DiscreteAction", "DiscreteMetaAction", "MultiAgentAction")
"""Action types of highway-env 1.12's ``action_factory``"""
NOT_ON_THIS_HIGHWAY = {"KinematicsGoal": "it needs a goal, as on highway-env's parking env",
                       "ExitObservation": "it needs an exit lane, as on highway-env's exit env"}
"""highway-env observation types that cannot observe this env's straight highway, and why"""
OBSERVATION_TYPES = (*(t for t in HIGHWAY_ENV_OBSERVATION_TYPES if t not in NOT_ON_THIS_HIGHWAY),
                     "Camera", "OverlayKinematics")
"""Every ``highway.observation.type``: highway-env's (but :data:`NOT_ON_THIS_HIGHWAY`) and ours
(:mod:`dt_highway.env.observations`)"""
ACTION_TYPES = (*HIGHWAY_ENV_ACTION_TYPES, "Driver", "DiscreteDriver")
"""Every ``highway.action.type``: highway-env's and ours (:mod:`dt_highway.env.actions`)"""


KINEMATICS_OPTIONS = ("type", "features", "vehicles_count", "features_range", "absolute", "order", "normalize", "clip",
                      "see_behind", "observe_intentions", "include_obstacles")
"""Keys of a Kinematics observation table (highway-env 1.12's ``KinematicObservation``; ``OverlayKinematics``
also takes ``threat``)"""


MAX_OBSERVED = 1000
"""Most rows of a Kinematics observation: 10 million made each observation 200 MB of zeros"""


def _check_kinematics_options(table: dict[str, Any]) -> None:
    """Refuse what highway-env's Kinematics would silently accept or fail on later: an unknown
    option, ``vehicles_count`` below 1 or above :data:`MAX_OBSERVED`, an ``order`` other than
    sorted/shuffled, ``features`` that is not a non-empty list of names (``[]`` fell back to the
    defaults, ``"xy"`` read as ``x``, ``y``),
    a ``features_range`` that is not ``{name: [low, high]}`` with low < high, and a switch that is
    not true or false."""
    overlay = table.get("type") == "OverlayKinematics"
    allowed = (*KINEMATICS_OPTIONS, "threat") if overlay else KINEMATICS_OPTIONS
    for key in table:
        if key not in allowed:
            raise PydanticCustomError("unknown_option", "not a Kinematics option (allowed: {allowed})",
                                      {"key": key, "got": table[key], "allowed": ", ".join(allowed)})
    if overlay and not isinstance(table.get("threat", False), bool):  # the threat-cue columns (OverlayKinematics)
        raise PydanticCustomError("bad_option", "must be true or false", {"key": "threat", "got": table["threat"]})
    count = table.get("vehicles_count", 5)
    if isinstance(count, bool) or not isinstance(count, int) or not 1 <= count <= MAX_OBSERVED:
        raise PydanticCustomError("bad_option", f"must be a whole number from 1 to {MAX_OBSERVED} (the road holds at "
                                  "most 501 vehicles; more rows are zeros)", {"key": "vehicles_count", "got": count})
    if table.get("order", "sorted") not in ("sorted", "shuffled"):
        raise PydanticCustomError("bad_option", "must be 'sorted' or 'shuffled'", {"key": "order", "got": table["order"]})
    features = table.get("features", ["presence"])
    if not isinstance(features, list) or not features or not all(isinstance(f, str) and f for f in features):
        raise PydanticCustomError("bad_option", "must be a non-empty list of feature names, e.g. [\"presence\", \"x\", \"y\"]",
                                  {"key": "features", "got": features})
    ranges = table.get("features_range", {})
    if ranges is not None and (not isinstance(ranges, dict) or not all(_low_high(r) for r in ranges.values())):
        raise PydanticCustomError("bad_option", "must be {feature: [low, high]} with low < high",
                                  {"key": "features_range", "got": ranges})
    for switch in ("absolute", "normalize", "clip", "see_behind", "observe_intentions", "include_obstacles"):
        if not isinstance(table.get(switch, False), bool):
            raise PydanticCustomError("bad_option", "must be true or false", {"key": switch, "got": table[switch]})


def _low_high(value: Any) -> bool:
    """Whether ``value`` is ``[low, high]``, two finite numbers with low < high."""
    return (isinstance(value, list | tuple) and len(value) == 2
            and all(finite_number(v) is not None for v in value) and value[0] < value[1])


# ----------------------------------------------------------------------------- highway-env
class HighwayConfig(_Section):
    """highway-env's own keys (see ``highway_env.envs.highway_env.HighwayEnv.default_config``)."""

    lanes_count: int = Field(4, ge=1, le=10, description="number of lanes [-]")
    vehicles_count: int = Field(40, ge=0, le=500, description="NPC vehicles on the road at once [-]")
    duration: float = Field(40.0, gt=0, description="episode length [s]")
    simulation_frequency: int = Field(15, ge=1, le=200, description="physics steps per second [Hz]")
    policy_frequency: int = Field(1, ge=1, le=200, description="agent decisions per second [Hz]")
    speed_limit: float = Field(30.0, gt=0, description="lane speed limit [m/s]")
    road_length: float = Field(1.0e6, gt=100, le=1.0e8, description="length of the straight road [m]")
    initial_lane_id: int | None = Field(None, ge=0, description="ego's starting lane (None: random)")
    ego_speed: float = Field(25.0, ge=0, le=40, description="ego's initial speed [m/s]")
    ego_spacing: float = Field(2.0, gt=0, description="stock traffic only: ego spacing ratio [-]")
    vehicles_density: float = Field(1.0, gt=0, description="stock traffic only: NPC density ratio [-]")
    observation: dict[str, Any] = Field(default_factory=lambda: {"type": "Kinematics"})
    action: dict[str, Any] = Field(default_factory=lambda: {"type": "DiscreteMetaAction"})
    collision_reward: float = Field(-1.0, description="reward of a collision; with normalize_reward, mapped to 0 "
                                    "and must be below high_speed_reward + right_lane_reward (mapped to 1) [-]")
    right_lane_reward: float = 0.1
    high_speed_reward: float = 0.4
    lane_change_reward: float = 0.0
    reward_speed_range: tuple[float, float] = (20.0, 30.0)
    normalize_reward: bool = Field(True, description="map the reward from [collision_reward, high_speed_reward + "
                                   "right_lane_reward] to [0, 1]")
    offroad_terminal: bool = False
    screen_width: int = Field(600, ge=16, le=8192, description="top-down render width [px]")
    screen_height: int = Field(150, ge=16, le=8192, description="top-down render height [px]")
    centering_position: tuple[float, float] = Field(
        (0.3, 0.5), description="where the ego is drawn on the top-down view: [x, y], each a share of the screen in [0, 1]")
    scaling: float = Field(5.5, ge=0.02, le=100, description="top-down render scale [px/m]")
    show_trajectories: bool = False
    render_agent: bool = True
    offscreen_rendering: bool | None = None
    manual_control: bool = False
    real_time_rendering: bool = False

    @field_validator("observation", "action")
    @classmethod
    def _known_type(cls, table: dict[str, Any], info: ValidationInfo) -> dict[str, Any]:
        allowed = OBSERVATION_TYPES if info.field_name == "observation" else ACTION_TYPES
        if info.field_name == "observation" and str(table.get("type")) in NOT_ON_THIS_HIGHWAY:
            raise PydanticCustomError(
                "unknown_type", "{why} (allowed: {allowed})",
                {"key": "type", "got": table["type"], "why": NOT_ON_THIS_HIGHWAY[table["type"]],
                 "allowed": ", ".join(allowed)},
            )
        if "type" in table and table["type"] not in allowed:
            raise PydanticCustomError(
                "unknown_type", "not a highway-env or dt-highway {what} type (allowed: {allowed})",
                {"key": "type", "got": table["type"], "what": info.field_name, "allowed": ", ".join(allowed)},
            )
        if info.field_name == "observation" and table.get("type", "Kinematics") in ("Kinematics", "OverlayKinematics"):
            _check_kinematics_options(table)
        return table

    @model_validator(mode="after")
    def _consistent(self) -> HighwayConfig:
        if self.simulation_frequency % self.policy_frequency:
            raise ValueError(
                "simulation_frequency must be a multiple of policy_frequency "
                f"(got {self.simulation_frequency} and {self.policy_frequency})"
            )
        if self.initial_lane_id is not None and self.initial_lane_id >= self.lanes_count:
            raise ValueError(f"initial_lane_id must be < lanes_count = {self.lanes_count} (got {self.initial_lane_id})")
        low, high = self.reward_speed_range
        if not (math.isfinite(low) and math.isfinite(high) and low < high):  # the speed reward divides by high - low
            raise ValueError(f"reward_speed_range must be [low, high] m/s with low < high (got {[low, high]})")
        worst, best = self.collision_reward, self.high_speed_reward + self.right_lane_reward
        if self.normalize_reward and not (math.isfinite(best - worst) and worst < best):  # it divides by best - worst
            raise ValueError("normalize_reward needs collision_reward < high_speed_reward + right_lane_reward "
                             f"(got {worst:g} and {best:g}): they are the rewards mapped to 0 and 1")
        if not all(0 <= c <= 1 for c in self.centering_position):
            raise ValueError("centering_position must be [x, y], each a share of the screen in [0, 1] "
                             f"(got {list(self.centering_position)})")
        return self


# ----------------------------------------------------------------------------- traffic
class DriverParams(_Section):
    """IDM (longitudinal) + MOBIL (lateral) parameters of one driver type."""

    time_headway_s: float = Field(1.5, gt=0, le=5, description="IDM desired time gap [s]")
    min_gap_m: float = Field(10.0, ge=0, description="IDM jam distance, bumper to bumper + length [m]")
    comfort_acc_mps2: float = Field(3.0, gt=0, description="IDM maximum acceleration [m/s^2]")
    comfort_dec_mps2: float = Field(5.0, gt=0, description="IDM comfortable deceleration [m/s^2]")
    politeness: float = Field(0.5, ge=0, le=1, description="MOBIL politeness factor [-]")
    lane_change_min_gain_mps2: float = Field(0.2, description="MOBIL acceleration gain threshold [m/s^2]")
    max_braking_imposed_mps2: float = Field(2.0, gt=0, description="MOBIL safety criterion [m/s^2]")
    lane_change_delay_s: float = Field(1.0, gt=0, description="time between lane-change decisions [s]")
    lateral_time_constant_s: float = Field(
        1.0, gt=0, description="lateral position controller time constant: smaller = faster lane change [s]"
    )
    max_lateral_speed_mps: float = Field(
        1.0, gt=0, le=8, description="largest lateral speed while changing lane [m/s]"
    )
    target_speed_mps: tuple[float, float] = Field((22.0, 28.0), description="range of desired speeds [m/s]")

    @model_validator(mode="after")
    def _speeds(self) -> DriverParams:
        lo, hi = self.target_speed_mps
        if not 0 < lo <= hi <= 40:
            raise ValueError(f"target_speed_mps must be [low, high] with 0 < low <= high <= 40 (got {[lo, hi]})")
        return self


def _normal_driver() -> DriverParams:
    return DriverParams()


def _aggressive_driver() -> DriverParams:
    return DriverParams(
        time_headway_s=0.7,
        min_gap_m=7.0,
        comfort_acc_mps2=4.0,
        comfort_dec_mps2=7.0,
        politeness=0.0,
        lane_change_min_gain_mps2=0.05,
        max_braking_imposed_mps2=6.0,
        lane_change_delay_s=0.3,
        lateral_time_constant_s=0.35,
        max_lateral_speed_mps=3.0,
        target_speed_mps=(27.0, 32.0),
    )


_CORR_Z = "correlation of the copula variable with the latent aggressiveness z [-]"
_LOW = "smallest value drawn (draws below are clipped) [the parameter's unit]"
_HIGH = "largest value drawn (draws above are clipped) [the parameter's unit]"


def _check_order(low: float, centre_name: str, centre: float, high: float) -> None:
    if not low <= centre <= high:
        raise ValueError(f"low <= {centre_name} <= high is required (got {low}, {centre}, {high})")


class NormalTrait(_Section):
    """One driver parameter of the continuum population (:mod:`dt_highway.world.continuum`),
    drawn as ``mean + sd u`` clipped to ``[low, high]``, where ``u = corr_z z + sqrt(1 - corr_z^2) e``
    is a standard normal copula variable (``z`` the latent aggressiveness, ``e`` independent noise).
    ``mean``, ``sd``, ``low`` and ``high`` are in the parameter's unit (its name's)."""

    mean: float = Field(description="mean (and median) before clipping [the parameter's unit]")
    sd: float = Field(ge=0, description="standard deviation before clipping [the parameter's unit]")
    low: float = Field(description=_LOW)
    high: float = Field(description=_HIGH)
    corr_z: float = Field(ge=-1, le=1, description=_CORR_Z)

    @model_validator(mode="after")
    def _ordered(self) -> NormalTrait:
        _check_order(self.low, "mean", self.mean, self.high)
        return self


class LogNormalTrait(_Section):
    """One positive driver parameter of the continuum population, drawn as ``median exp(log_sd u)``
    clipped to ``[low, high]`` (``u`` as in :class:`NormalTrait`). ``median``, ``low`` and ``high``
    are in the parameter's unit (its name's)."""

    median: float = Field(gt=0, description="median before clipping [the parameter's unit]")
    log_sd: float = Field(ge=0, le=3, description="standard deviation of the natural logarithm [-]")
    low: float = Field(description=_LOW)
    high: float = Field(description=_HIGH)
    corr_z: float = Field(ge=-1, le=1, description=_CORR_Z)

    @model_validator(mode="after")
    def _ordered(self) -> LogNormalTrait:
        _check_order(self.low, "median", self.median, self.high)
        return self


CONTINUUM_LIMITS: dict[str, tuple[float, float]] = {
    "desired_speed_mps": (1.0, 40.0),
    "time_headway_s": (0.1, 5.0),
    "min_gap_m": (0.0, 50.0),
    "comfort_acc_mps2": (0.1, 10.0),
    "comfort_dec_mps2": (0.1, 10.0),
    "politeness": (0.0, 1.0),
    "lane_change_min_gain_mps2": (0.0, 5.0),
    "max_braking_imposed_mps2": (0.1, 10.0),
    "lane_change_delay_s": (0.05, 10.0),
    "max_lateral_speed_mps": (0.1, 8.0),
    "cut_in_rate_per_min": (0.0, 60.0),
}
"""Physically meaningful ``[low, high]`` of each continuum parameter (as :class:`DriverParams`' ranges)"""


class ContinuumConfig(_Section):
    """The continuum population's distributions (``traffic.population = "continuum"``).

    Each parameter's median, spread, clipping range and correlation with the latent
    aggressiveness; where the numbers come from is in :mod:`dt_highway.world.continuum`.
    """

    desired_speed_mps: NormalTrait = Field(default_factory=lambda: NormalTrait(
        mean=26.0, sd=2.5, low=20.0, high=34.0, corr_z=0.5))
    time_headway_s: LogNormalTrait = Field(default_factory=lambda: LogNormalTrait(
        median=1.3, log_sd=0.3, low=0.5, high=2.5, corr_z=-0.6))
    min_gap_m: NormalTrait = Field(default_factory=lambda: NormalTrait(
        mean=9.0, sd=1.0, low=6.0, high=12.0, corr_z=-0.4))
    comfort_acc_mps2: LogNormalTrait = Field(default_factory=lambda: LogNormalTrait(
        median=3.0, log_sd=0.2, low=1.5, high=5.0, corr_z=0.4))
    comfort_dec_mps2: LogNormalTrait = Field(default_factory=lambda: LogNormalTrait(
        median=5.0, log_sd=0.15, low=3.5, high=8.0, corr_z=0.4))
    politeness: NormalTrait = Field(default_factory=lambda: NormalTrait(
        mean=0.35, sd=0.2, low=0.0, high=1.0, corr_z=-0.6))
    lane_change_min_gain_mps2: LogNormalTrait = Field(default_factory=lambda: LogNormalTrait(
        median=0.15, log_sd=0.5, low=0.02, high=0.6, corr_z=-0.5))
    max_braking_imposed_mps2: LogNormalTrait = Field(default_factory=lambda: LogNormalTrait(
        median=3.0, log_sd=0.35, low=1.5, high=7.0, corr_z=0.6))
    lane_change_delay_s: LogNormalTrait = Field(default_factory=lambda: LogNormalTrait(
        median=0.8, log_sd=0.4, low=0.2, high=2.5, corr_z=-0.5))
    max_lateral_speed_mps: LogNormalTrait = Field(default_factory=lambda: LogNormalTrait(
        median=0.8, log_sd=0.5, low=0.3, high=3.5, corr_z=0.8))
    cut_in_rate_per_min: LogNormalTrait = Field(default_factory=lambda: LogNormalTrait(
        median=0.5, log_sd=1.0, low=0.0, high=10.0, corr_z=0.8))
    lateral_settle_m: float = Field(
        1.0, gt=0, le=4, description="a lane change leaves its lateral speed limit this far from the new lane's "
        "centre and settles exponentially, time constant lateral_settle_m / max_lateral_speed_mps [m]")

    @model_validator(mode="before")
    @classmethod
    def _partial_traits(cls, data: Any) -> Any:
        """A parameter's table may give some keys only (``--set traffic.continuum.politeness.mean=0.2``):
        the others keep that parameter's defaults."""
        if not isinstance(data, dict):
            return data
        out = dict(data)
        for name in CONTINUUM_LIMITS:
            given = out.get(name)
            factory = cls.model_fields[name].default_factory
            if isinstance(given, dict) and factory is not None:
                out[name] = {**factory().model_dump(), **given}  # type: ignore[call-arg]
        return out

    @model_validator(mode="after")
    def _physical(self) -> ContinuumConfig:
        for name, (lo, hi) in CONTINUUM_LIMITS.items():
            trait: NormalTrait | LogNormalTrait = getattr(self, name)
            if trait.low < lo:
                raise PydanticCustomError("out_of_range", "must be >= {bound}",
                                          {"key": f"{name}.low", "got": trait.low, "bound": lo})
            if trait.high > hi:
                raise PydanticCustomError("out_of_range", "must be <= {bound}",
                                          {"key": f"{name}.high", "got": trait.high, "bound": hi})
        return self

    def traits(self) -> dict[str, NormalTrait | LogNormalTrait]:
        """The distributions of the continuum drivers' parameters.

        :return: the parameters' distributions by name, in the order they are drawn
        """
        return {name: getattr(self, name) for name in CONTINUUM_LIMITS}


class DangerousCutInConfig(_Section):
    """The paper's near-miss cut-in (its section IV-C and Fig. 5), as a share of the cut-in attempts.

    A dangerous attempt waits for a victim (the ego preferred) that it is beside or just ahead
    of in the neighbouring lane, with a bumper gap in ``gap_m``; it changes lane at its driver's
    full lateral speed and brakes at ``brake_mps2`` down to the victim's speed at the start minus
    ``speed_drop_mps``, so that the victim closes on it; the brake starts once its centre is in the
    victim's lane (``brake_onset = "in_lane"``) or with the lane change (``"lane_change"``: the
    cutter enters the lane already slower than the victim, which closes on it from the first
    moment, before any reaction). The other attempts are the gentler cut-ins of
    ``traffic.cut_in_*``. The section appears in a dumped configuration only when it differs from
    its default (``share = 0``: no dangerous cut-ins, the world of earlier versions).
    """

    share: float = Field(0.0, ge=0, le=1, description="share of cut-in attempts that are the dangerous manoeuvre [-]")
    gap_m: tuple[float, float] = Field(
        (1.0, 8.0), description="bumper gap ahead of the victim when the dangerous lane change starts [m]"
    )
    brake_mps2: float = Field(3.0, ge=0, le=9, description="the cutter's deceleration once it is in the victim's lane "
                              "[m/s^2]")
    speed_drop_mps: float = Field(
        4.0, ge=0, le=20, description="the cutter brakes to the victim's speed at the start minus this [m/s]"
    )
    brake_onset: Literal["in_lane", "lane_change"] = Field(
        "in_lane", description="when the brake starts: once the cutter's centre is in the victim's lane "
        "(in_lane) or as its lane change starts (lane_change: it enters the lane already slower than the victim)"
    )

    @model_validator(mode="after")
    def _gap(self) -> DangerousCutInConfig:
        lo, hi = self.gap_m
        if not 0 <= lo < hi:
            raise ValueError(f"gap_m must be [low, high] with 0 <= low < high (got {list(self.gap_m)})")
        return self


_DEFAULT_DANGEROUS = DangerousCutInConfig()


class TrafficConfig(_Section):
    """NPC population: driver types, aggressive behaviour, spawning and recycling.

    ``population = "two_class"`` (the default) is the world of two driver types with the fixed
    ``normal`` / ``aggressive`` parameters; ``"continuum"`` draws every driver's parameters from
    the ``continuum`` section's distributions, correlated through a latent aggressiveness, and the
    top ``aggressive_fraction`` by that score are the aggressive ones (:mod:`dt_highway.world.continuum`).
    The ``population`` and ``continuum`` keys appear in a dumped configuration only when one of
    them differs from its default, so that files written before they existed stay byte-identical.
    """

    population: Literal["two_class", "continuum"] = Field(
        "two_class", description="two_class: the normal / aggressive presets; continuum: drivers drawn from "
        "the continuum section's distributions with a latent aggressiveness"
    )
    aggressive_fraction: float = Field(
        0.2, ge=0, le=1, description="share of aggressive drivers (continuum: the top share by latent score) [-]"
    )
    cut_in_rate_per_min: float = Field(
        4.0, ge=0, description="how often an aggressive driver tries a cut-in (or, with no victim, a lane hop); "
        "two_class only, the continuum draws continuum.cut_in_rate_per_min per driver [1/min]"
    )
    cut_in_gap_m: tuple[float, float] = Field(
        (4.0, 20.0), description="bumper gap ahead of the victim that a cut-in accepts [m]"
    )
    cut_in_range_m: float = Field(
        60.0, gt=0, description="cut-ins look for a victim within this distance behind [m]"
    )
    cut_in_chase_s: float = Field(
        0.0, ge=0, le=120,
        description="an open attempt may spend this long positioning itself just ahead of the ego "
        "(0: aggressive drivers do not seek the ego out) [s]",
    )
    cut_in_ego_preference: float = Field(
        0.7, ge=0, le=1, description="probability that a cut-in picks the ego when it is a candidate [-]"
    )
    driver_types: bool = Field(
        True,
        description="False: stock highway-env traffic (its spawning, plain IDMVehicle NPCs, no recycling)",
    )
    recycle: bool = Field(True, description="re-enter NPCs that drift far from the ego, remove crashed ones")
    fast_road: bool = Field(
        True, description="the fast traffic core: highway-env's Road, IDM vehicles and Kinematics observation with "
        "their hot paths replaced (the same trajectories up to rounding); False: highway-env's own Road, IDMVehicle "
        "and observation (our typed drivers compute on floats either way)"
    )
    crashed_removal_s: float = Field(5.0, gt=0, description="a crashed NPC is towed away after this long [s]")
    population_size: int = Field(
        300, ge=1, le=100_000, description="distinct drivers (stable ids) the NPCs are drawn from [-]"
    )
    population_seed: int | None = Field(
        None, ge=0, description="seed of the driver population (None: derived from the env seed)"
    )
    spawn_behind_m: float = Field(150.0, ge=0, description="road behind the ego filled at reset [m]")
    spawn_ahead_m: float = Field(350.0, gt=0, description="road ahead of the ego filled at reset [m]")
    recycle_distance_m: float = Field(
        400.0, gt=50, description="NPCs farther than this from the ego re-enter at the other edge [m]"
    )
    normal: DriverParams = Field(default_factory=_normal_driver)
    aggressive: DriverParams = Field(default_factory=_aggressive_driver)
    continuum: ContinuumConfig = Field(default_factory=ContinuumConfig)
    dangerous: DangerousCutInConfig = Field(default_factory=DangerousCutInConfig)

    @model_serializer(mode="wrap")
    def _dump(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        out: dict[str, Any] = handler(self)
        if self.dangerous == _DEFAULT_DANGEROUS:
            out.pop("dangerous", None)
        if self.population == "two_class" and self.continuum == _DEFAULT_CONTINUUM:
            out.pop("population", None)
            out.pop("continuum", None)
        return out

    @model_validator(mode="after")
    def _gap_range(self) -> TrafficConfig:
        lo, hi = self.cut_in_gap_m
        if not 0 <= lo < hi:
            raise ValueError(f"cut_in_gap_m must be [low, high] with 0 <= low < high (got {list(self.cut_in_gap_m)})")
        if max(self.spawn_ahead_m, self.spawn_behind_m) >= self.recycle_distance_m:
            raise ValueError(
                f"spawn_ahead_m and spawn_behind_m must be < recycle_distance_m = {self.recycle_distance_m} "
                f"(got {self.spawn_ahead_m} and {self.spawn_behind_m})"
            )
        return self


_DEFAULT_CONTINUUM = ContinuumConfig()


# ----------------------------------------------------------------------------- twin
class LinkConfig(_Section):
    """A one-way radio link: rate, latency and loss."""

    rate_hz: float = Field(10.0, gt=0, le=1000, description="messages per second [Hz]")
    latency_mean_s: float = Field(0.1, ge=0, le=10, description="mean latency [s]")
    latency_jitter_s: float = Field(0.02, ge=0, le=10, description="latency standard deviation [s]")
    loss_prob: float = Field(0.01, ge=0, lt=1, description="probability that a message is lost [-]")


class UplinkConfig(LinkConfig):
    """Vehicle -> cloud GNSS fixes."""

    noise_sigma_m: float = Field(1.0, ge=0, le=50, description="GNSS horizontal noise, per axis [m]")
    speed_noise_sigma_mps: float = Field(0.2, ge=0, le=20, description="GNSS speed noise [m/s]")
    heading_noise_sigma_rad: float = Field(0.02, ge=0, le=3.2, description="GNSS course noise [rad]")
    antenna_height_m: float = Field(1.5, ge=0, description="antenna height above the road [m]")


class DownlinkConfig(LinkConfig):
    """Cloud -> ego twin views (its own defaults: 50 ms, 10 ms jitter, no loss)."""

    latency_mean_s: float = Field(0.05, ge=0, le=10, description="mean latency [s]")
    latency_jitter_s: float = Field(0.01, ge=0, le=10, description="latency standard deviation [s]")
    loss_prob: float = Field(0.0, ge=0, lt=1, description="probability that a message is lost [-]")
    radius_m: float = Field(200.0, gt=0, le=1.0e12, description="vehicles within this distance of the ego are sent [m]")


class StoreConfig(_Section):
    """The cloud's per-vehicle fix history."""

    window_s: float = Field(30.0, gt=0, description="fix history kept per vehicle [s]")
    persist_across_episodes: bool = Field(
        True, description="keep each driver's evidence and tag across resets of one env"
    )
    path: str | None = Field(
        None,
        description="SQLite file that keeps the drivers' evidence across processes "
        "(set traffic.population_seed too, so that the ids mean the same drivers); written at env.close(), at a "
        "seeded reset and when Python exits; one env at a time (on POSIX systems a second is refused)",
    )

    @field_validator("path")
    @classmethod
    def _a_file(cls, path: str | None) -> str | None:
        if path and Path(path).exists() and not Path(path).is_file():  # a directory, /dev/null...
            what = "a directory" if Path(path).is_dir() else "not a regular file"
            raise PydanticCustomError("not_a_file", "must name a SQLite file, new or existing (this is {what})",
                                      {"got": path, "what": what})
        if path and not Path(path).parent.is_dir():
            raise PydanticCustomError("no_folder", "must name a SQLite file in an existing folder ({folder} is none)",
                                      {"got": path, "folder": str(Path(path).parent)})
        return path


class TaggerConfig(_Section):
    """Sudden-lane-change detector and the Poisson-rate driver classifier (see twin/tagger.py)."""

    update_hz: float = Field(2.0, gt=0, description="how often each history is re-analysed [Hz]")
    smoothing_s: float = Field(1.0, gt=0, description="moving-average window on lateral position [s]")
    hysteresis_m: float = Field(0.6, ge=0, description="lane-boundary hysteresis for lane-change detection [m]")
    fit_window_s: float = Field(5.0, gt=0, description="samples either side of a crossing used in the ramp fit [s]")
    sudden_lateral_speed_mps: float = Field(
        1.8, gt=0, description="a lane change whose fitted mean lateral speed exceeds this is sudden [m/s]"
    )
    sudden_gap_s: float = Field(
        0.8, ge=0, description="a lane change accepting a time gap below this to the new follower is sudden [s]"
    )
    rate_aggressive_per_min: float = Field(
        1.0, ge=1e-6, le=600, description="twin's model: sudden changes of an aggressive driver [1/min]")
    rate_normal_per_min: float = Field(
        0.2, ge=1e-6, le=600, description="twin's model: sudden changes of a normal driver [1/min]")
    prior_aggressive: float = Field(0.2, gt=0, lt=1, description="twin's prior share of aggressive drivers [-]")
    threshold: float = Field(0.6, gt=0, lt=1, description="posterior above which the tag is 'aggressive' [-]")
    max_evidence: int = Field(20, ge=1, description="sudden lane changes kept as evidence per driver [-]")
    model: Literal["sudden", "evidence"] = Field(
        "sudden",
        description="'sudden': the Poisson count of sudden lane changes (two-class world); 'evidence': a logistic "
        "model of the driver's behaviour (lane changes, speed, time headway), fitted on simulated training seeds",
    )
    evidence_weights: str | None = Field(
        None, description="JSON weights of the 'evidence' model (None: the shipped tagger_evidence.json)"
    )

    @model_validator(mode="after")
    def _rates(self) -> TaggerConfig:
        if self.rate_aggressive_per_min <= self.rate_normal_per_min:
            raise ValueError("rate_aggressive_per_min must be larger than rate_normal_per_min")
        if self.evidence_weights is not None and not Path(self.evidence_weights).is_file():  # checked unused too
            raise ValueError(f"evidence_weights file not found: {self.evidence_weights} (a .json file of dt-highway "
                             "train-tagger)")
        return self

    @model_serializer(mode="wrap")
    def _dump(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        out: dict[str, Any] = handler(self)
        if self.model == "sudden" and self.evidence_weights is None:  # dumps as before the evidence model
            out.pop("model", None)
            out.pop("evidence_weights", None)
        return out


INTENTION_MODELS = ("learned", "physics")
"""``twin.intention.model``: the shipped network, or lateral motion + gap acceptance (see twin/intention.py)"""


class IntentionConfig(_Section):
    """The twin's lane-change intention (:mod:`dt_highway.twin.intention`): for every connected vehicle,
    P(it changes lane within H) and into which lane, from the cloud's data only.

    The section appears in a dumped configuration only when it differs from its default.
    """

    enabled: bool = Field(True, description="estimate the intention and send it on the downlink beside the tag")
    model: Literal["learned", "physics"] = Field(
        "learned", description="'learned': the shipped network; 'physics': lateral motion + gap acceptance"
    )
    horizons_s: tuple[float, ...] = Field(
        (1.0, 2.0, 3.0), description="horizons H, increasing (1 to 8 of them; the shipped network covers 0.5-4 s) [s]"
    )
    update_hz: float = Field(10.0, gt=0, le=100, description="how often the intentions are estimated [Hz]")
    operating_horizon_s: float = Field(
        3.0, gt=0, description="the horizon a warning is read at (one of horizons_s) [s]"
    )
    threshold: float = Field(
        0.65, gt=0, lt=1, description="operating threshold: warn when P(change within the operating horizon) >= this "
        "(the lowest with cut-in warning precision >= 0.80 on 30 validation episodes from seed 2000 of "
        "envs/highway-trial.toml, twin-eval --intent, counting a warning right when its car entered the ego's lane; "
        "counted as issue 19 does, right only when it cut in, no threshold reaches 0.80 there) [-]"
    )
    weights: str | None = Field(
        None, description="learned: weights file (.npz from dt-highway train-intent; None: the shipped weights; "
        "'round2': round 2's shipped weights, trained on envs/highway-trial-r2.toml)"
    )

    @model_validator(mode="after")
    def _horizons(self) -> IntentionConfig:
        h = self.horizons_s
        if not 1 <= len(h) <= 8 or any(not 0 < x <= 10 for x in h) or any(b <= a for a, b in zip(h, h[1:], strict=False)):
            raise ValueError(f"horizons_s must be 1 to 8 increasing values in (0, 10] s (got {list(h)})")
        if not any(abs(x - self.operating_horizon_s) < 1e-9 for x in h):
            raise ValueError(f"operating_horizon_s must be one of horizons_s {list(h)} (got {self.operating_horizon_s})")
        if self.weights is not None and self.weights != "round2" and not Path(self.weights).is_file():
            raise ValueError(f"weights file not found: {self.weights} (a .npz file, or 'round2')")
        return self


_DEFAULT_INTENTION = IntentionConfig()


class TwinConfig(_Section):
    """The cloud digital twin: uplink, store, tagger, intention, downlink."""

    enabled: bool = True
    connected_fraction: float = Field(1.0, ge=0, le=1, description="share of NPCs that upload fixes [-]")
    preroll_s: float = Field(
        60.0, ge=0, le=3600, description="traffic runs and the twin listens this long before t = 0 [s]"
    )
    in_observation: bool = Field(
        False, description="add each observed vehicle's delivered twin tag to the Kinematics observation"
    )
    in_observation_intent: bool = Field(
        False, description="with in_observation: also the delivered lane-change intention at the operating horizon "
        "(columns twin_p_change, twin_target_dlane)"
    )
    uplink: UplinkConfig = Field(default_factory=UplinkConfig)
    downlink: DownlinkConfig = Field(default_factory=DownlinkConfig)
    store: StoreConfig = Field(default_factory=StoreConfig)
    tagger: TaggerConfig = Field(default_factory=TaggerConfig)
    intention: IntentionConfig = Field(default_factory=IntentionConfig)

    @model_validator(mode="after")
    def _intent_columns(self) -> TwinConfig:
        if self.in_observation_intent and not self.in_observation:
            raise ValueError("in_observation_intent = true needs in_observation = true (its columns follow the tag's)")
        if self.in_observation_intent and not self.intention.enabled:
            raise ValueError("in_observation_intent = true needs intention.enabled = true (its columns carry the "
                             "intention; without it they would stay 0)")
        return self

    @model_serializer(mode="wrap")
    def _dump(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        out: dict[str, Any] = handler(self)
        if self.intention == _DEFAULT_INTENTION:
            out.pop("intention", None)
        if not self.in_observation_intent:  # dumps as before the key existed
            out.pop("in_observation_intent", None)
        return out


# ----------------------------------------------------------------------------- ego
class EgoConfig(_Section):
    """The ego vehicle."""

    autopilot: bool = Field(
        False, description="the ego follows its lane with IDM by itself and actions are ignored (data generation)"
    )
    autopilot_speed_mps: float = Field(25.0, gt=0, le=40, description="the autopilot's desired speed [m/s]")


# ----------------------------------------------------------------------------- camera
class CameraMountConfig(_Section):
    """Where the camera sits on the ego (the ego's frame: x forward, y right, z up)."""

    forward_m: float = Field(0.5, ge=-10, le=10, description="ahead of the ego's centre [m]")
    lateral_m: float = Field(0.0, ge=-5, le=5, description="right of the ego's centre [m]")
    height_m: float = Field(1.3, gt=0, le=10, description="above the road [m]")
    pitch_deg: float = Field(3.0, ge=-60, le=60, description="optical axis below the horizon [deg] (positive looks down)")
    yaw_deg: float = Field(0.0, ge=-180, le=180, description="optical axis right of the ego's heading [deg]")


class CameraConfig(_Section):
    """The ego's synthetic RGB + depth camera (:mod:`dt_highway.camera`)."""

    enabled: bool = Field(False, description="render a camera frame every policy step")
    width_px: int = Field(640, ge=16, le=4096, description="image width [px]")
    height_px: int = Field(360, ge=16, le=4096, description="image height [px]")
    hfov_deg: float = Field(90.0, ge=5, le=170, description="horizontal field of view [deg]")
    cx_px: float | None = Field(None, description="principal point u [px] (None: the image centre)")
    cy_px: float | None = Field(None, description="principal point v [px] (None: the image centre)")
    mount: CameraMountConfig = Field(default_factory=CameraMountConfig)
    near_m: float = Field(0.1, gt=0, le=10, description="near plane: nothing nearer is drawn [m]")
    max_range_m: float = Field(200.0, gt=0, le=2000, description="farthest distance drawn; depth saturates there [m]")
    vehicle_height_m: float = Field(1.5, ge=0.5, le=5, description="height of the cars [m]")
    detail_min_px: float = Field(
        10.0, ge=0, description="lights, plates and wheels are drawn on vehicles at least this wide on screen [px]"
    )

    @model_validator(mode="after")
    def _consistent(self) -> CameraConfig:
        if self.max_range_m <= self.near_m:
            raise ValueError(f"max_range_m must exceed near_m = {self.near_m} (got {self.max_range_m})")
        if self.cx_px is not None and not 0 <= self.cx_px <= self.width_px - 1:
            raise ValueError(f"cx_px must lie in the image, 0..{self.width_px - 1} (got {self.cx_px})")
        if self.cy_px is not None and not 0 <= self.cy_px <= self.height_px - 1:
            raise ValueError(f"cy_px must lie in the image, 0..{self.height_px - 1} (got {self.cy_px})")
        return self


# ----------------------------------------------------------------------------- perception and fusion
class DetectorConfig(_Section):
    """The detector that finds vehicles in the camera frame (:mod:`dt_highway.perception.detect`)."""

    kind: Literal["simulated", "learned"] = Field(
        "simulated",
        description="'simulated': ground truth plus realistic errors; 'learned': the trained network on the RGB image",
    )
    weights: str | None = Field(
        None, description="learned: weights file, relative to the working directory (None: the shipped weights)"
    )
    min_score: float = Field(0.3, gt=0, le=1, description="learned: least score of a detection, in (0, 1] [-]")
    scale: Literal["resize", "native"] = Field(
        "resize", description="learned: resize frames to the network's input size, or read them at their own size"
    )
    jitter: float = Field(0.03, ge=0, le=0.5, description="box edge noise, fraction of the box's size [-]")
    miss_height_px: float = Field(6.0, ge=0, description="visible height missed half of the time [px]")
    miss_visibility: float = Field(0.25, ge=0, le=1, description="visibility missed half of the time [-]")
    merge_overlap: float = Field(0.5, gt=0, le=1, description="overlap (of the smaller box) from which boxes may merge [-]")
    merge_prob: float = Field(0.5, ge=0, le=1, description="probability that such a pair comes out as one box [-]")
    false_positives_per_frame: float = Field(0.05, ge=0, le=20, description="mean spurious boxes per frame [-]")

    @model_validator(mode="after")
    def _weights_file(self) -> DetectorConfig:
        if self.weights is not None and not Path(self.weights).is_file():
            raise ValueError(f"weights file not found: {self.weights} (a .pt file from dt-highway detector train; "
                             "unset: the shipped weights)")
        if self.weights is not None and not zipfile.is_zipfile(self.weights):  # the rest is checked when it loads
            raise ValueError(f"{self.weights} is not a detector weights file: not a torch zip archive (truncated, or "
                             "another format; a .pt file from dt-highway detector train)")
        return self


FusionMethod = Literal["baseline", "fusion", "joint", "tracked"]
"""The fusion's matching methods (:mod:`dt_highway.perception.fusion`)"""
FUSION_METHODS: tuple[str, ...] = get_args(FusionMethod)


class FusionConfig(_Section):
    """Camera + twin fusion and the ADAS output (:mod:`dt_highway.perception.fusion`)."""

    enabled: bool = Field(False, description="run detector and fusion every step; overlay items in info['adas']")
    method: FusionMethod = Field("tracked", description="matching method")
    th: float = Field(0.2, ge=0, lt=1, description="Algorithm 1: box resize threshold [-]")
    n_samples: int = Field(20, ge=1, le=10000, description="Algorithm 1: sample points per box [-]")
    fallback: Literal["none", "nearest"] = Field("none", description="Algorithm 2 when no box holds the anchor")
    anchor_height_m: float = Field(0.75, ge=0, le=5, description="height of the GNSS point [m]")
    near_face_m: float = Field(2.5, ge=0, le=20, description="joint/tracked: GNSS point to near face [m]")
    continuity_bonus: float = Field(0.5, ge=0, le=10, description="tracked: cost taken off keeping a track [-]")


OVERLAY_MODES = ("type", "threat", "both")
"""``overlay.mode``: cars the twin tags aggressive, cars it predicts will cut into the ego's lane, or either"""


class OverlayConfig(_Section):
    """What the driver sees of the fusion's output: steady marks (:mod:`dt_highway.overlay`).

    ``mode`` chooses the cars marked (:mod:`dt_highway.env.adas`): ``type``, every car the twin tags
    aggressive; ``threat``, every car whose lane-change intention at ``horizon_s`` has
    ``p_change >= threshold`` into the ego's lane (by default the twin's operating point,
    ``twin.intention.operating_horizon_s`` and ``twin.intention.threshold``); ``both``, either. At most ``max_marks`` marks are
    shown (nearest first; in ``both``, threats first), none for a car beyond ``max_range_m``, in
    every mode. ``sham`` (the placebo condition) shows as many marks, alike, on cars drawn at random.
    """

    onset_frames: int = Field(2, ge=1, le=100, description="consecutive fusion frames before a mark shows [-]")
    hold_s: float = Field(1.0, ge=0, le=10,
                          description="a mark stays this long after its vehicle stops qualifying or is lost [s]")
    mode: Literal["type", "threat", "both"] = Field("type", description="which cars are marked: type, threat or both")
    horizon_s: float | None = Field(None, gt=0, le=10, description="threat: the intention horizon read, one of "
                                    "twin.intention.horizons_s (None: twin.intention.operating_horizon_s) [s]")
    threshold: float | None = Field(None, gt=0, le=1, description="threat: least p_change of a lane change into the "
                                    "ego's lane, in (0, 1] (0 would mark every car; None: twin.intention.threshold) [-]")
    max_marks: int = Field(3, ge=1, le=50, description="most marks shown at once (nearest first) [-]")
    max_range_m: float = Field(100.0, gt=0, le=2000, description="no mark for a car farther than this [m]")
    sham: bool = Field(False, description="placebo: the same number of marks, alike, on cars drawn at random")


# ----------------------------------------------------------------------------- root
class DTConfig(_Section):
    """The whole configuration of a dt-highway env."""

    highway: HighwayConfig = Field(default_factory=HighwayConfig)
    ego: EgoConfig = Field(default_factory=EgoConfig)
    traffic: TrafficConfig = Field(default_factory=TrafficConfig)
    twin: TwinConfig = Field(default_factory=TwinConfig)
    camera: CameraConfig = Field(default_factory=CameraConfig)
    detector: DetectorConfig = Field(default_factory=DetectorConfig)
    fusion: FusionConfig = Field(default_factory=FusionConfig)
    overlay: OverlayConfig = Field(default_factory=OverlayConfig)

    @model_validator(mode="after")
    def _camera_for_observation(self) -> DTConfig:
        if self.highway.observation.get("type") == "Camera" and not self.camera.enabled:
            raise ValueError("highway.observation.type = 'Camera' needs camera.enabled = true")
        if self.fusion.enabled and not self.camera.enabled:
            raise ValueError("fusion.enabled = true needs camera.enabled = true")
        if self.fusion.enabled and not self.twin.enabled:
            raise ValueError("fusion.enabled = true needs twin.enabled = true")
        horizons = self.twin.intention.horizons_s
        if self.overlay.horizon_s is not None and not any(abs(h - self.overlay.horizon_s) < 1e-9 for h in horizons):
            raise ValueError(f"overlay.horizon_s must be one of twin.intention.horizons_s {list(horizons)} (got "
                             f"{self.overlay.horizon_s}): the twin estimates the intention at those horizons only")
        if self.fusion.enabled and self.overlay.mode != "type" and not self.twin.intention.enabled:
            raise ValueError(f"overlay.mode = {self.overlay.mode!r} needs twin.intention.enabled = true (its threat marks "
                             "read the twin's lane-change intention; without it none would show)")
        return self

    def to_dict(self) -> dict[str, Any]:
        """This configuration as plain data.

        :return: the resolved tree as plain Python values (TOML/JSON friendly).
        """
        return self.model_dump(mode="json")


SECTIONS = tuple(DTConfig.model_fields)


# ----------------------------------------------------------------------------- errors
def _model_at(loc: tuple[Any, ...], root: type[BaseModel] = DTConfig) -> type[BaseModel] | None:
    """The section model found by following ``loc`` from the root, if it is one."""
    model: type[BaseModel] = root
    for part in loc:
        field = model.model_fields.get(str(part))
        if field is None:
            return None
        ann = field.annotation
        if isinstance(ann, type) and issubclass(ann, BaseModel):
            model = ann
        else:
            return None
    return model


def _describe(err: Any, root: type[BaseModel] = DTConfig, skip: int = 0, at: tuple[str, ...] = ()) -> str:
    loc = at + tuple(err["loc"])[skip:]
    dotted = ".".join(str(p) for p in loc) or "<root>"
    kind = err["type"]
    if kind == "extra_forbidden":
        parent = _model_at(loc[:-1], root)
        allowed = ", ".join(parent.model_fields) if parent else "?"
        return f"unknown key '{dotted}' (allowed here: {allowed})"
    value = err.get("input")
    shown = repr(value) if not isinstance(value, dict) else "a table"
    msg = err["msg"]
    if msg.startswith("Value error, "):
        msg = msg[len("Value error, "):]
    ctx = err.get("ctx") or {}
    if "key" in ctx:  # one key of a free-form table: highway.observation.type
        return f"{dotted}.{ctx['key']} = {ctx['got']!r}: {msg}"
    if kind in {"greater_than_equal", "greater_than", "less_than_equal", "less_than"}:
        op = {"greater_than_equal": ">=", "greater_than": ">", "less_than_equal": "<=", "less_than": "<"}[kind]
        bound = next(iter(ctx.values()), "?")
        return f"{dotted} = {shown} is out of range: must be {op} {bound}"
    if isinstance(value, dict) and kind == "value_error":
        return f"{dotted}: {msg}" if loc else msg
    if kind == "model_type" or kind == "dict_type":
        return f"{dotted} must be a table of keys (got {shown})"
    return f"{dotted} = {shown}: {msg}"


def config_error(
    exc: ValidationError, root: type[BaseModel] = DTConfig, prefix: str = "invalid configuration: ", skip: int = 0
) -> ConfigError:
    """The one-line :class:`ConfigError` of a failed validation: every mistake with its dotted
    key and what is allowed, joined by ``"; "``.

    :param exc: pydantic's error
    :param root: the model validated (where dotted keys start)
    :param prefix: put before the mistakes (the file or the tree they are in)
    :param skip: leading parts of each error's location to leave out (a tagged union's tag)
    :return: the error to raise (``raise config_error(exc) from None``)
    """
    return ConfigError(prefix + "; ".join(_describe(e, root, skip) for e in exc.errors()))


def _raise_config_error(exc: ValidationError) -> None:
    raise config_error(exc) from None


def validate_section(section: type[_S], where: str, **values: Any) -> _S:
    """A config section made from keyword values, refused with the tree's one-line error (for a
    component that takes a section's values as arguments: the overlay's stabiliser).

    :param section: the section model (:class:`OverlayConfig`)
    :param where: its dotted key in the tree (``"overlay"``)
    :param values: its values; missing ones take the section's defaults
    :return: the validated section
    :raises ConfigError: naming ``where.key`` and what is allowed
    """
    try:
        return section.model_validate(values)
    except ValidationError as exc:
        at = tuple(where.split("."))
        raise ConfigError("invalid configuration: " + "; ".join(_describe(e, at=at) for e in exc.errors())) from None


# ----------------------------------------------------------------------------- merging
def deep_merge(base: dict[str, Any], update: dict[str, Any]) -> dict[str, Any]:
    """Merge ``update`` into a copy of ``base``, recursing into nested dicts.

    A table that names another ``type`` than the one below it (``highway.observation``) replaces it
    whole: the options below were the other type's.

    :param base: the lower layer
    :param update: the higher layer (wins on conflicts)
    :return: a new dict
    """
    out = copy.deepcopy(base)
    for key, value in update.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict) and not _another_type(out[key], value):
            out[key] = deep_merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


_SHARED_OPTIONS = ({"Kinematics", "OverlayKinematics"}, {"ContinuousAction", "DiscreteAction"})
"""Types that read the same options (but ``speed_range``, which DiscreteAction does not): a switch between
them keeps the options set"""


def _another_type(old: dict[str, Any], new: dict[str, Any]) -> bool:
    """Whether ``new`` is a table of another ``type`` than ``old`` (an observation or action table): its
    options were the old type's, so the new table replaces it whole."""
    if not (isinstance(new.get("type"), str) and isinstance(old.get("type"), str)) or new["type"] == old["type"]:
        return False  # not both named (a bad name is refused by the validation that follows)
    return not any(old["type"] in group and new["type"] in group for group in _SHARED_OPTIONS)


def _lift_highway_keys(tree: dict[str, Any]) -> dict[str, Any]:
    """Move highway-env keys given at the top level into the ``highway`` section.

    :raises ConfigError: on a key given there and in the section with another value (in one layer: a later
        layer's top-level key replaces an earlier layer's section key, as :func:`load_config` merges them)
    """
    if not isinstance(tree, dict):
        raise ConfigError(f"configuration must be a table of keys (got {type(tree).__name__})")
    out: dict[str, Any] = {}
    lifted: dict[str, Any] = {}
    for key, value in tree.items():
        if key not in SECTIONS and key in HighwayConfig.model_fields:
            lifted[key] = value
        else:
            out[key] = value
    if lifted:
        hw = out.get("highway", {})
        if not isinstance(hw, dict):
            raise ConfigError(f"highway must be a table of keys (got {hw!r})")
        twice = [k for k in lifted if k in hw and hw[k] != lifted[k]]
        if twice:  # the top-level value won without a word
            k = twice[0]
            raise ConfigError(f"{k} is given at the top level ({lifted[k]!r}) and as highway.{k} ({hw[k]!r}): give it once")
        out["highway"] = deep_merge(hw, lifted)
    return out


def validate(tree: dict[str, Any]) -> DTConfig:
    """Validate a (partial) tree on top of the defaults.

    :param tree: nested dict; missing keys take their defaults
    :return: the validated configuration
    :raises ConfigError: with a one-line message naming each bad key
    """
    tree = _lift_highway_keys(tree)
    try:
        return DTConfig.model_validate(tree)
    except ValidationError as exc:
        _raise_config_error(exc)
        raise  # unreachable, for type checkers


def merge(config: DTConfig, update: dict[str, Any] | DTConfig | None) -> DTConfig:
    """Deep-merge a nested dict into an existing configuration and validate the result.

    :param config: the configuration
    :param update: a (partial) tree, or a whole :class:`DTConfig` (:func:`load_config`'s), which replaces it
    :return: the new configuration
    :raises ConfigError: one line naming each bad key
    """
    if isinstance(update, DTConfig):
        return update
    if not update:
        return config
    return validate(deep_merge(config.to_dict(), _lift_highway_keys(update)))


def set_highway_keys(config: DTConfig, values: dict[str, Any]) -> DTConfig:
    """Set highway-env keys the way highway-env's flat config dict does
    (``env.unwrapped.config["lanes_count"] = 2``): each value replaces the ``highway`` section's
    old one whole (a table too), and the result is validated like any other layer.

    :param config: the configuration
    :param values: highway-env keys and their new values
    :return: the new configuration
    :raises ConfigError: one line naming ``highway.<key>``, for an unknown key or a bad value
        (another section's name is refused with how to set it)
    """
    sections = [k for k in values if k in SECTIONS and k != "highway"]
    if sections:
        key = sections[0]
        raise ConfigError(f"env.unwrapped.config holds highway-env's keys (the 'highway' section) only: set '{key}' "
                          f"with env.unwrapped.configure({{'{key}': {{...}}}}) or gym.make(..., config=...)")
    tree = config.to_dict()
    tree["highway"].update(copy.deepcopy(values))
    return validate(tree)



# ----------------------------------------------------------------------------- files and --set
CHECKOUT = Path(__file__).resolve().parents[1]
"""The project's folder when it runs from a source checkout (``agents/``, ``envs/`` beside the package)."""


def find_file(path: str | Path, folder: str) -> str:
    """A driver, training or scenario file as given, or, when ``folder/NAME`` or a bare ``NAME``
    does not exist here, the checkout's ``folder/NAME``: the documented ``envs/highway-trial.toml``
    works from any folder. Any other path (``agnets/idm.toml``, ``../envs/x.toml``) is taken as it is.

    :param path: the file as the user named it
    :param folder: ``agents`` or ``envs``
    :return: the path to read (``path`` itself when neither exists: the error names what was typed)
    """
    p = Path(path)
    if p.exists() or p.parent not in (Path("."), Path(folder)):
        return str(p)
    alt = CHECKOUT / folder / p.name
    return str(alt) if alt.exists() else str(p)


def read_scenario(path: str | Path) -> dict[str, Any]:
    """Read a TOML scenario file.

    :param path: file path (``envs/highway-trial.toml``; ``envs/NAME`` or a bare ``NAME`` missing
        here is read from the checkout's ``envs/``, :func:`find_file`)
    :return: the nested dict it holds (not yet validated)
    :raises ConfigError: if the file is missing or is not valid TOML
    """
    p = Path(find_file(path, "envs"))
    if not p.is_file():
        what = "is not a file" if p.exists() else "does not exist"  # a directory, /dev/null...
        raise ConfigError(f"scenario file '{p}' {what}: give a TOML file, e.g. envs/highway-trial.toml")
    try:
        with p.open("rb") as fh:
            return tomllib.load(fh)
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"scenario file '{p}' is not valid TOML: {exc}") from None
    except OSError as exc:
        raise ConfigError(f"scenario file '{p}' cannot be read: {exc.strerror}") from None


def read_toml(path: str | Path, what: str) -> dict[str, Any]:
    """Read a TOML file a user names (a driver file, a training file).

    :param path: the file
    :param what: what it is, for the message (``"driver file"``)
    :return: the nested dict it holds (not yet validated)
    :raises ConfigError: one line, if it is missing, unreadable or not valid TOML
    """
    p = Path(path)
    try:
        return tomllib.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"{what} not found: {p}") from None
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as err:
        raise ConfigError(f"cannot read {what} {p}: {err}") from None


def read_user_file(path: str | Path, parse: Callable[[str], Any], parse_errors: type[Exception] | tuple[type[Exception], ...],
                   missing: str, unreadable: str, malformed: str) -> Any:
    """Read and parse a file a user names (UTF-8 text), every failure a one-line :class:`ConfigError`
    in the caller's words. The messages are :meth:`str.format` templates of ``path`` (the file) and
    ``err`` (the exception, its attributes too: ``{err.msg}``).

    :param path: the file
    :param parse: text to data (``json.loads``, ``tomllib.loads``)
    :param parse_errors: what ``parse`` raises on bad content (``json.JSONDecodeError``...)
    :param missing: the message when the file does not exist
    :param unreadable: the message when it cannot be read or is not UTF-8
    :param malformed: the message when ``parse`` fails
    :return: what ``parse`` made of it (not yet validated)
    :raises ConfigError: one of the three messages
    """
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError as err:
        raise ConfigError(missing.format(path=p, err=err)) from None
    except (OSError, UnicodeDecodeError) as err:
        raise ConfigError(unreadable.format(path=p, err=err)) from None
    try:
        return parse(text)
    except parse_errors as err:
        raise ConfigError(malformed.format(path=p, err=err)) from None


def parse_override(text: str, option: str = "--set") -> dict[str, Any]:
    """Turn ``"a.b.c=value"`` into ``{"a": {"b": {"c": value}}}``.

    The value is read as a TOML value (``5``, ``0.5``, ``true``, ``[1, 2]``, ``"text"``);
    anything that is not valid TOML is taken as a plain string.

    :param text: the override, ``dotted.key=value``
    :param option: the command-line option the text came from (named in the error)
    :return: a one-key nested dict (:func:`dotted_tree`)
    :raises ConfigError: when there is no ``=`` or the key is empty
    """
    if "=" not in text:
        raise ConfigError(f"{option} expects dotted.key=value (got '{text}')")
    key, raw = text.split("=", 1)
    key = key.strip()
    parts = key.split(".")
    if not key or any(not p for p in parts):
        raise ConfigError(f"{option} has an empty key part in '{text}'")
    raw = raw.strip()
    try:
        value: Any = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw
    return dotted_tree(key, value)


def override_value(text: str, key: str, option: str = "--set") -> Any:
    """The value the override ``text`` gives the dotted ``key``, set by name or inside a table it sets
    (``overlay={mode="threat"}``); ``None`` when it does not set it.

    :param text: the override, ``dotted.key=value``
    :param key: the dotted key looked for (``"overlay.mode"``)
    :param option: the command-line option the text came from (named in the error)
    :return: the value it sets, or ``None``
    :raises ConfigError: as :func:`parse_override`
    """
    tree: Any = parse_override(text, option)
    for part in key.split("."):
        tree = tree.get(part) if isinstance(tree, dict) else None
    return tree


def dotted_tree(key: str, value: Any) -> dict[str, Any]:
    """Turn ``("a.b.c", value)`` into ``{"a": {"b": {"c": value}}}`` (a one-key layer to merge).

    :param key: the dotted key
    :param value: the value at its end
    :return: the nested dict
    """
    parts = key.split(".")
    tree: dict[str, Any] = {parts[-1]: value}
    for part in reversed(parts[:-1]):
        tree = {part: tree}
    return tree


def check_overrides(overrides: object) -> tuple[str, ...]:
    """The ``--set`` strings of a Python call, checked: a list (or tuple) of ``dotted.key=value`` strings.

    :param overrides: what the caller passed as overrides
    :return: them, as a tuple
    :raises ConfigError: one line, for a lone string (it would be read letter by letter), a dict or a list of other
        things
    """
    if isinstance(overrides, str):
        raise ConfigError(f"overrides must be a list of 'dotted.key=value' strings (got the string {overrides!r}: "
                          "put it in a list)")
    if not isinstance(overrides, (list, tuple)) or not all(isinstance(o, str) for o in overrides):
        got = type(overrides).__name__ if not isinstance(overrides, (list, tuple)) else \
            f"a {type(overrides).__name__} holding {next(type(o).__name__ for o in overrides if not isinstance(o, str))}"
        raise ConfigError(f"overrides must be a list of 'dotted.key=value' strings, e.g. ['highway.duration=60'] "
                          f"(got {got})")
    return tuple(overrides)


def load_config(
    scenario: str | Path | None = None,
    overrides: list[str] | tuple[str, ...] = (),
    extra: dict[str, Any] | None = None,
) -> DTConfig:
    """Resolve the configuration: defaults <- scenario file <- ``extra`` dict <- ``--set`` overrides.

    :param scenario: optional TOML scenario file
    :param overrides: ``dotted.key=value`` strings
    :param extra: optional nested dict (e.g. a command's own settings)
    :return: the validated configuration
    :raises ConfigError: on any bad layer
    """
    overrides = check_overrides(overrides)
    if scenario is not None and not isinstance(scenario, (str, Path)):
        raise ConfigError(f"scenario must be a TOML file's path (got {type(scenario).__name__}): pass a tree as extra")
    if extra is not None and not isinstance(extra, dict):
        raise ConfigError(f"extra must be a table of keys (got {type(extra).__name__})")
    tree: dict[str, Any] = {}
    if scenario is not None:
        tree = deep_merge(tree, _lift_highway_keys(read_scenario(scenario)))
    if extra:
        tree = deep_merge(tree, _lift_highway_keys(extra))
    layer: dict[str, Any] = {}  # the --set values as one layer: a type named after its options keeps them
    for text in overrides:
        layer = deep_merge(layer, parse_override(text))
    return validate(deep_merge(tree, _lift_highway_keys(layer)))  # a top-level key of --set beats the scenario's


"""``dt-highway-v0``: highway-env's highway with driver types and a cloud digital twin.

The env subclasses ``highway_env.envs.HighwayEnv``. On top of it:

* its configuration is the typed tree of :mod:`dt_highway.config`, merged deeply;
* NPCs are typed drivers (:mod:`dt_highway.world.traffic`) with stable ids drawn from a driver
  population that persists across the episodes of one env;
* every simulation step (not only every policy step), connected vehicles upload GNSS
  fixes, the cloud twin stores and tags them, and the downlink delivers the twin's view to
  the ego (:mod:`dt_highway.twin`);
* before ``t = 0`` the traffic runs for ``twin.preroll_s`` with the ego on an IDM
  autopilot, so that the twin has heard the drivers before the episode starts.

``info`` holds ``time_s`` (episode clock [s]), ``ego`` (the ego's state), ``twin`` (the
view the ego last received; never ground truth), and, under ``ground_truth``, the
simulator's truth (driver types, positions, cut-ins; with ``traffic.population = "continuum"`` also
each driver's latent ``aggressiveness``) for evaluation only.
"""

from __future__ import annotations

import inspect
import math
import os
import site
import sysconfig
import traceback
import weakref
from collections.abc import Callable, Iterator
from pathlib import Path
from types import FrameType
from typing import Any

import numpy as np
from gymnasium import error as gym_error
from highway_env.envs.common.action import action_factory
from highway_env.envs.common.observation import (
    KinematicObservation,
    MultiAgentObservation,
    ObservationType,
    OccupancyGridObservation,
    TupleObservation,
    observation_factory,
)
from highway_env.envs.highway_env import HighwayEnv
from highway_env.road.lane import StraightLane
from highway_env.road.road import Road, RoadNetwork
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.kinematics import Vehicle

from dt_highway import ENV_ID as ENV_ID  # re-exported: defined here before import dt_highway stopped importing the env
from dt_highway.camera.pinhole import Intrinsics, Mount, PinholeCamera, Pose
from dt_highway.camera.render import (
    CameraImage,
    CameraRenderer,
    RenderSettings,
)
from dt_highway.camera.scene import RoadScene, VehicleSet
from dt_highway.camera.truth import CameraTruth
from dt_highway.config import (
    NOT_ON_THIS_HIGHWAY,
    CameraConfig,
    ConfigError,
    DTConfig,
    HighwayConfig,
    merge,
    set_highway_keys,
)
from dt_highway.env.actions import DiscreteDriverAction, DriverAction, check_action
from dt_highway.env.adas import AdasPipeline
from dt_highway.env.flat_config import FlatConfig
from dt_highway.env.observations import (
    CameraObservation,
    OverlayKinematics,
    TwinTaggedKinematics,
)
from dt_highway.metrics.safety import CutIn, SafetyMonitor
from dt_highway.overlay import OverlayStabilizer
from dt_highway.perception import Detector, Fusion, SimulatedDetector
from dt_highway.twin.cloud import CloudTwin, Downlink, TwinView
from dt_highway.twin.tagger import HighwayMap
from dt_highway.twin.uplink import Uplink, VehicleState
from dt_highway.world.observation import FastKinematicObservation, check_feature_names
from dt_highway.world.road import FastRoad
from dt_highway.world.traffic import (
    EGO_ID,
    DriverPopulation,
    TrafficEvent,
    TrafficManager,
    aggressiveness,
    driver_type,
    vehicle_id,
)
from dt_highway.world.vehicle import FastIDMVehicle, velocity


def make_camera(cfg: CameraConfig, scene: RoadScene) -> CameraRenderer:
    """Build the renderer described by a ``camera`` config section for a road.

    :param cfg: the ``camera`` section (image size, field of view, mount, render settings)
    :param scene: the road to draw
    :return: the renderer
    """
    m = cfg.mount
    camera = PinholeCamera(
        Intrinsics.from_fov(cfg.width_px, cfg.height_px, math.radians(cfg.hfov_deg), cfg.cx_px, cfg.cy_px),
        Mount(m.forward_m, m.lateral_m, m.height_m, math.radians(m.pitch_deg), math.radians(m.yaw_deg)),
        near_m=cfg.near_m,
    )
    settings = RenderSettings(max_range_m=cfg.max_range_m, vehicle_height_m=cfg.vehicle_height_m,
                              detail_min_px=cfg.detail_min_px)
    return CameraRenderer(camera, scene, settings)


def _uplink_state(v: Vehicle) -> VehicleState:
    """A connected vehicle's true state at the end of a step, as its GNSS unit measures it."""
    x_m, y_m = v.position.tolist()
    vx_mps, vy_mps = velocity(v)
    return VehicleState(vehicle_id(v), x_m, y_m, vx_mps, vy_mps, float(v.speed), float(v.heading))


def _init_options(cls: type) -> set[str]:
    """The named arguments of the ``__init__`` of ``cls`` (the options a highway-env type reads: none
    of highway-env 1.12's types hands a named option on to its base)."""
    init = next(vars(base)["__init__"] for base in cls.__mro__ if "__init__" in vars(base))
    return {name for name, param in inspect.signature(init).parameters.items()
            if name not in ("self", "env") and param.kind not in (param.VAR_POSITIONAL, param.VAR_KEYWORD)}


_NESTED_TABLES = {"observation_config": False, "observation_configs": True, "action_config": False}
"""Options of highway-env's multi-agent and tuple types that hold tables of other types (True: a list of them)"""
_HIGHWAY_ENV_ERRORS = (TypeError, ValueError, IndexError, KeyError, ZeroDivisionError, AttributeError)
"""What highway-env raises on options it cannot use"""


HIGHWAY_ENV_OBSERVATIONS = "highway_env.envs.common.observation"
"""highway-env's module of observation types"""
_LIBRARIES = tuple({os.path.realpath(p) + os.sep for p in (
    *(sysconfig.get_paths()[k] for k in ("stdlib", "platstdlib", "purelib", "platlib")),
    *site.getsitepackages(), site.getusersitepackages())})


def _module(frame: FrameType) -> str:
    return str(frame.f_globals.get("__name__", ""))


def _owner(frame: FrameType) -> str | None:
    """``highway-env``, ``ours`` (this package, or code outside the installed libraries: a test, a user's
    subclass) or ``None`` (another library: numpy, the standard library), by the frame's module and file."""
    package = _module(frame).split(".")[0]
    if package in ("highway_env", "dt_highway"):
        return "highway-env" if package == "highway_env" else "ours"
    filename = frame.f_code.co_filename
    if not os.path.isabs(filename) or {"site-packages", "dist-packages"} & set(Path(filename).parts):
        return None
    return None if os.path.realpath(filename).startswith(_LIBRARIES) else "ours"


def _highway_env_fault(err: BaseException, through: str | None = None) -> bool:
    """Whether ``err`` was raised by highway-env's code (or a library it called) rather than by ours
    that highway-env called: the deepest frame that is highway-env's or ours is highway-env's.

    :param through: a module the error must also have passed through (highway-env's observation module)
    """
    frames = [frame for frame, _ in traceback.walk_tb(err.__traceback__)]
    if isinstance(err, ConfigError) or (through is not None and through not in map(_module, frames)):
        return False
    owners = [owner for owner in map(_owner, frames) if owner is not None]
    return bool(owners) and owners[-1] == "highway-env"


def _speeds_ok(speeds: Any) -> bool:
    """Whether DiscreteMetaAction's ``target_speeds`` (a list, tuple or array) can be used: highway-env maps a
    speed onto them by their first and last, so they need two or more, increasing."""
    if isinstance(speeds, (str, bytes, dict)):
        return False
    try:
        values = np.asarray(speeds, dtype=float)
    except (TypeError, ValueError):
        return False
    return values.ndim == 1 and values.size >= 2 and bool(np.all(np.isfinite(values)) and values[0] >= 0
                                                          and np.all(np.diff(values) > 0))


def _highway_env_says(err: BaseException) -> str:
    """The end of a one-line error about highway-env's options: what it raised, on one line."""
    return f"({type(err).__name__}: {' '.join(str(err).split())}); its options are in highway-env's documentation"


def _observation_leaves(where: str, table: dict[str, Any],
                        obs: ObservationType) -> Iterator[tuple[str, dict[str, Any], ObservationType]]:
    """highway-env's observation and those nested in its multi-agent and tuple types, each with its table
    and dotted key (``highway.observation.observation_configs[1]``)."""
    if isinstance(obs, MultiAgentObservation):  # every agent's observation is made from the one table
        for agent in obs.agents_observation_types[:1]:
            yield from _observation_leaves(f"{where}.observation_config", table.get("observation_config", {}), agent)
    elif isinstance(obs, TupleObservation):
        for i, (sub, part) in enumerate(zip(table.get("observation_configs", []), obs.observation_types, strict=False)):
            yield from _observation_leaves(f"{where}.observation_configs[{i}]", sub, part)
    else:
        yield where, table, obs


def _with_tuples(table: dict[str, Any]) -> dict[str, Any]:
    """``table`` with a TOML list where highway-env wants a tuple (``observation_shape``) made one, nested tables too."""
    out = {k: _with_tuples(v) if isinstance(v, dict) else v for k, v in table.items()}
    if isinstance(out.get("observation_shape"), list):
        out["observation_shape"] = tuple(out["observation_shape"])
    if isinstance(out.get("observation_configs"), list):
        out["observation_configs"] = [_with_tuples(t) if isinstance(t, dict) else t for t in out["observation_configs"]]
    return out


def _highway_env_type(env: Any, where: str, factory: Callable[[Any, dict], Any], table: dict[str, Any]) -> Any:
    """A highway-env observation or action type made from ``table``, its space made once to try it,
    and the tables nested in it tried alike: highway-env takes the options unchecked.

    :param where: the table's dotted key, for the message (``highway.observation``)
    :raises ConfigError: naming the type, its options and what highway-env said
    """
    kind = table.get("type")
    if str(kind) in NOT_ON_THIS_HIGHWAY:
        raise ConfigError(f"{where}.type = {kind!r}: {NOT_ON_THIS_HIGHWAY[str(kind)]}")
    if table.get("target_speeds") is not None and not _speeds_ok(table["target_speeds"]):
        raise ConfigError(f"{where}.target_speeds = {table['target_speeds']!r}: must be 2 or more speeds >= 0 m/s "
                          "in increasing order")  # DiscreteMetaAction's, read only when the ego is made
    try:
        with np.errstate(all="ignore"):  # a bad option's own warnings would come before the error
            made = factory(env, table)
            made.space()
    except _HIGHWAY_ENV_ERRORS as err:
        if not _highway_env_fault(err):
            raise
        options = {k: v for k, v in table.items() if k != "type"}
        raise ConfigError(f"{where}: highway-env cannot make type '{kind}' with {options or 'no options'} "
                          + _highway_env_says(err)) from None
    known = _init_options(type(made))
    unknown = sorted(set(table) - known - {"type"})
    if unknown:  # highway-env's types take **kwargs and drop what they do not know
        raise ConfigError(f"{where}: highway-env's {type(made).__name__} does not read {', '.join(map(repr, unknown))} "
                          f"(its options: {', '.join(sorted(known))})")
    for key, many in _NESTED_TABLES.items():
        nested = table.get(key)
        for i, sub in enumerate(nested if many and isinstance(nested, list) else [nested]):
            if isinstance(sub, dict):
                _highway_env_type(env, f"{where}.{key}" + (f"[{i}]" if many else ""), factory, sub)
    return made


class DTHighwayEnv(HighwayEnv):
    """The dt-highway environment (see the module docstring).

    :param config: a (partial) nested configuration tree, merged deeply over the defaults;
        highway-env keys may also be given at the top level; or a whole :class:`~dt_highway.config.DTConfig`
        (``dt_highway.load_config("envs/highway-trial.toml")``)
    :param render_mode: ``None``, ``"human"`` or ``"rgb_array"`` (highway-env's top-down view)
    """

    metadata: dict[str, Any] = {"render_modes": ["human", "rgb_array"], "render_fps": 15}
    config: dict[str, Any]
    """highway-env's flat configuration, derived from ``dt_config``
    (a :class:`~dt_highway.env.flat_config.FlatConfig`)"""
    POPULATION_STREAM = 0x5EED_D21E
    """Mixed with the world seed so the population's stream differs from the episode's"""

    def __init__(self, config: dict | DTConfig | None = None, render_mode: str | None = None) -> None:
        self.dt_config = DTConfig()
        self.population: DriverPopulation | None = None
        self.twin: CloudTwin | None = None
        self._twin_closer: weakref.finalize | None = None
        """Closes the twin (writing ``twin.store.path``) at :meth:`close`, or when the env is collected or the
        interpreter exits without a close (a script or notebook that never calls it keeps what the twin learnt)"""
        self.uplink: Uplink | None = None
        self.downlink: Downlink | None = None
        self.traffic: TrafficManager | None = None
        self.twin_view: TwinView | None = None
        self.sim_time_s = 0.0
        self.twin_offset_s = 0.0
        self._built_for: tuple[str, str, int] | None = None
        self._world_seed: int | None = None
        self._events: list[TrafficEvent] = []
        self._aimed_cut_ins: dict[int, tuple[float, str]] = {}  # driver -> (time [s], style) of its last cut-in on the ego
        self.camera: CameraRenderer | None = None
        self._camera_key: tuple[str, RoadScene] | None = None
        self._frame: tuple[CameraImage, CameraTruth] | None = None
        self._frame_key: tuple[int, int] | None = None
        self._episode = 0
        self.pipeline: AdasPipeline | None = None
        self.detector: Detector | SimulatedDetector | None = None
        self.fusion: Fusion | None = None
        self.overlay: OverlayStabilizer | None = None
        self.adas: dict[str, Any] | None = None
        self._adas_key: tuple[int, int] | None = None
        self.safety = SafetyMonitor(lane_width_m=StraightLane.DEFAULT_WIDTH)
        self._safety_on = False
        self._safety_samples: list[dict[str, Any]] = []
        self._cut_ins: list[dict[str, Any]] = []
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None (got {render_mode!r})")
        self._constructing = True  # highway-env's constructor resets once: that episode is never driven
        try:
            super().__init__(config, render_mode)
        finally:
            self._constructing = False

    # ------------------------------------------------------------------ configuration
    @classmethod
    def default_config(cls) -> dict:
        """The env's default configuration, in highway-env's flat form.

        :return: highway-env's flat configuration of the default :class:`~dt_highway.config.DTConfig`
        """
        return cls._flat_highway_config(DTConfig())

    @staticmethod
    def _flat_highway_config(cfg: DTConfig) -> dict:
        flat = HighwayEnv.default_config()
        flat.update(cfg.highway.model_dump())
        flat["observation"] = dict(cfg.highway.observation)
        flat["action"] = dict(cfg.highway.action)
        if cfg.traffic.fast_road:  # highway-env's IDM/MOBIL with float arithmetic (same draws, same models)
            flat["other_vehicles_type"] = "dt_highway.world.vehicle.FastIDMVehicle"
        return flat

    def configure(self, config: dict | DTConfig | None) -> None:
        """Deep-merge a (partial) tree into the configuration and validate it (a whole
        :class:`~dt_highway.config.DTConfig`, as :func:`~dt_highway.config.load_config` gives, replaces it).

        ``self.config``, highway-env's flat dict, is derived from the tree; editing it
        (``env.unwrapped.config["lanes_count"] = 2``) edits the tree the same validated way
        (:class:`~dt_highway.env.flat_config.FlatConfig`).

        :param config: a (partial) tree or a whole :class:`~dt_highway.config.DTConfig`; ``None`` or empty: no change
        :raises ConfigError: on unknown keys, wrong types or out-of-range values
        """
        self.dt_config = merge(self.dt_config, config)
        self._show_config()
        super().configure(None)  # highway-env's own checks (the OFFSCREEN_RENDERING deprecation warning)

    def edit_highway_config(self, values: dict[str, Any]) -> None:
        """Apply edits of ``self.config`` (highway-env keys) to the tree, validated.

        :param values: keys and their new values (each replaces the old value whole)
        :raises ConfigError: one line naming ``highway.<key>``
        """
        fixed = sorted(k for k in values if k in self.config and k not in HighwayConfig.model_fields)
        if fixed:  # in the flat dict, but derived by the env (its traffic, its one ego), not part of the tree
            raise ConfigError(f"env.unwrapped.config['{fixed[0]}'] is set by dt-highway-v0 itself (its traffic and its "
                              f"one ego) and cannot be changed: use traffic.fast_road / traffic.driver_types instead")
        self.dt_config = set_highway_keys(self.dt_config, values)
        self._show_config()

    def _show_config(self) -> None:
        """Derive ``self.config`` from the tree (in place, so a reference to it stays live)."""
        flat = self._flat_highway_config(self.dt_config)
        if flat["offscreen_rendering"] is None:
            flat["offscreen_rendering"] = self.render_mode != "human"
        if isinstance(self.config, FlatConfig):
            self.config.refresh(flat)
        else:
            self.config = FlatConfig(self, flat)

    def _apply_nested_config_edits(self) -> None:
        """Edits made inside a table of ``self.config`` (``config["observation"]["type"] = ...``),
        which the dict does not see, applied to the tree like any edit (before a reset)."""
        flat = dict(self.config)
        self._show_config()
        changed = {k: v for k, v in flat.items() if k not in self.config or self.config[k] != v}
        if changed:
            self.edit_highway_config(changed)

    def define_spaces(self) -> None:
        """Build the observation type (highway-env's, ours, or the camera's) and the action type, and their spaces."""
        obs_cfg = dict(self.config["observation"])
        self._highway_env_observation: dict[str, Any] | None = None  # highway-env's own type: its table
        if obs_cfg.get("type") == "Camera":
            obs_cfg.pop("type")
            try:
                self.observation_type = CameraObservation(self, **obs_cfg)
            except TypeError:
                raise ConfigError(
                    f"highway.observation for type 'Camera' takes only 'depth' (got {sorted(obs_cfg)})"
                ) from None
        elif obs_cfg.get("type") == "OverlayKinematics":
            self.observation_type = self._kinematics(OverlayKinematics, obs_cfg)
        elif self.dt_config.twin.in_observation:
            if obs_cfg.get("type", "Kinematics") != "Kinematics":
                raise ConfigError("twin.in_observation needs highway.observation.type = 'Kinematics'")
            self.observation_type = self._kinematics(TwinTaggedKinematics, obs_cfg)
        elif obs_cfg.get("type") == "Kinematics" and self.dt_config.traffic.fast_road:
            self.observation_type = self._kinematics(FastKinematicObservation, obs_cfg)
        else:
            table = _with_tuples(self.config["observation"])
            self.observation_type = _highway_env_type(self, "highway.observation", observation_factory, table)
            self._highway_env_observation = table
        act_cfg = dict(self.config["action"])
        if act_cfg.get("type") in ("Driver", "DiscreteDriver"):
            kind = act_cfg.pop("type")
            try:
                self.action_type = (DriverAction if kind == "Driver" else DiscreteDriverAction)(self, **act_cfg)
            except (TypeError, ValueError) as err:
                raise ConfigError(f"highway.action: {err}") from None
        else:
            self.action_type = _highway_env_type(self, "highway.action", action_factory, dict(self.config["action"]))
        self.observation_space = self.observation_type.space()
        self.action_space = self.action_type.space()

    def _kinematics(self, cls: type, obs_cfg: dict[str, Any]) -> FastKinematicObservation:
        """A Kinematics observation of ours from the ``highway.observation`` table.

        :raises ConfigError: on options it does not take
        """
        kwargs = {k: v for k, v in obs_cfg.items() if k != "type"}
        try:
            return cls(self, **kwargs)
        except (TypeError, ValueError) as err:
            raise ConfigError(f"highway.observation for type '{obs_cfg.get('type', 'Kinematics')}': {err}") from None

    # ------------------------------------------------------------------ reset
    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[Any, dict]:
        """Start an episode.

        A reset **with** a ``seed`` starts the env's world over: the driver population is
        drawn again from that seed (or from ``traffic.population_seed`` when set) and the
        twin forgets what it learnt (it reloads ``twin.store.path`` when one is set), so the
        same seed gives the same episode, byte for byte. A reset **without** a seed continues
        the world: same drivers, and the twin keeps their evidence and tags when
        ``twin.store.persist_across_episodes`` is on (the default), as a cloud service would.

        :param seed: seed of every random generator of the episode: a Python ``int`` >= 0, as Gymnasium's
        :param options: ``{"config": {...}}`` deep-merges a partial configuration first
        :return: observation and info
        :raises gymnasium.error.Error: a ``seed`` that is no Python ``int`` >= 0, or ``options`` with another key
            than ``config`` (one line, before any change)
        """
        if options is not None and (not isinstance(options, dict) or set(options) - {"config"}):
            raise gym_error.Error(f"reset(options=...) takes None or {{'config': {{...}}}} (got {options!r})")
        if seed is not None:
            if not isinstance(seed, int) or seed < 0:  # Gymnasium's own rule, said before int() truncates 1.5
                raise gym_error.Error(f"reset(seed=...) must be a Python int >= 0 (got {seed!r} of type "
                                      f"{type(seed).__name__})")
            self._built_for = None
            self._world_seed = int(seed)
        self._apply_nested_config_edits()
        try:
            out = super().reset(seed=seed, options=options)
        except _HIGHWAY_ENV_ERRORS as err:  # options highway-env takes but cannot observe with (weights = [1])
            table = getattr(self, "_highway_env_observation", None)
            if table is None or not _highway_env_fault(err, through=HIGHWAY_ENV_OBSERVATIONS):
                raise
            if isinstance(err, KeyError):  # a features name no row has (a nested table's too): say which
                self._check_highway_env_features()
            options = {k: v for k, v in table.items() if k != "type"}
            raise ConfigError(f"highway.observation: highway-env cannot observe with type '{table.get('type')}' and "
                              f"{options or 'no options'} " + _highway_env_says(err)) from None
        self._check_highway_env_features()
        return out

    def _check_highway_env_features(self) -> None:
        """Refuse feature names highway-env's own Kinematics and OccupancyGrid would leave unused (an unknown
        ``features_range`` key; an OccupancyGrid feature), those nested in its multi-agent and tuple types
        included: our Kinematics checks its own at its first observation."""
        table = getattr(self, "_highway_env_observation", None)
        if table is None or self.vehicle is None:
            return
        columns = set(self.vehicle.to_dict())
        for where, sub, obs in _observation_leaves("highway.observation", table, self.observation_type):
            if isinstance(obs, (KinematicObservation, OccupancyGridObservation)):
                also = ("on_road",) if isinstance(obs, OccupancyGridObservation) else ()  # a layer the grid draws
                check_feature_names(where, str(sub.get("type")), obs.features, obs.features_range, columns, also)

    def _component_rngs(self) -> dict[str, np.random.Generator]:
        seed = int(self.np_random.integers(2**63 - 1))
        names = ("traffic", "uplink", "downlink", "detector", "fusion", "overlay")  # appended: the others keep their streams
        seeds = np.random.SeedSequence(seed).spawn(len(names))
        return {n: np.random.default_rng(s) for n, s in zip(names, seeds, strict=True)}

    def _build_persistent(self) -> None:
        """Population and twin live across episodes; rebuilt only when their config changes."""
        twin = self.dt_config.twin
        key = (
            self.dt_config.traffic.model_dump_json(),
            f"{twin.enabled}|{twin.connected_fraction}|{twin.store.model_dump_json()}|{twin.tagger.model_dump_json()}",
            self.dt_config.highway.lanes_count,
        )
        if key == self._built_for:
            if self.twin is not None:
                self.twin.config = twin  # links, radius, pre-roll: no need to forget the drivers
                if twin.store.path and self._twin_closer is None:  # after a close: take the file again
                    self.twin.reopen()
                    self._twin_closer = weakref.finalize(self, self.twin.close)
            return
        self._close_twin()
        tcfg = self.dt_config.traffic
        if tcfg.population_seed is not None:
            pop_seed = np.random.SeedSequence(tcfg.population_seed)
        elif self._world_seed is not None:
            pop_seed = np.random.SeedSequence([self._world_seed, self.POPULATION_STREAM])
        else:
            pop_seed = np.random.SeedSequence()  # unseeded env: fresh entropy
        self.population = DriverPopulation(
            tcfg, self.dt_config.twin.connected_fraction if self.dt_config.twin.enabled else 0.0,
            np.random.default_rng(pop_seed),
        )
        hw = self.dt_config.highway
        self.road_map = HighwayMap(StraightLane.DEFAULT_WIDTH, hw.lanes_count)
        self.twin = CloudTwin(self.dt_config.twin, self.road_map) if self.dt_config.twin.enabled else None
        if self.twin is not None and self.dt_config.twin.store.path:
            self._twin_closer = weakref.finalize(self, self.twin.close)
        self._built_for = key

    def _close_twin(self) -> None:
        """Close the twin (once): it writes its store file, when one is configured, and lets it go (a reset after
        this one takes it again and reads it)."""
        if self._twin_closer is not None:
            self._twin_closer()
            self._twin_closer = None
        elif self.twin is not None:
            self.twin.close()

    def _reset(self) -> None:
        self._safety_on = False
        self._build_persistent()
        cfg = self.dt_config
        self._create_road()
        if not cfg.traffic.driver_types:
            # highway-env's own traffic draws first, as in HighwayEnv._reset: a seed then gives
            # stock highway-v0's vehicles, speeds and behaviours exactly
            super()._create_vehicles()
        rngs = self._component_rngs()
        assert self.population is not None  # built by _build_persistent
        self.traffic = TrafficManager(cfg.traffic, self.population, rngs["traffic"])
        self.uplink = Uplink(cfg.twin.uplink, rngs["uplink"])
        self.downlink = Downlink(cfg.twin.downlink, rngs["downlink"])
        self.twin_view = None
        self._events = []
        self._aimed_cut_ins = {}
        # no pre-roll for the constructor's episode: gymnasium asks for a reset before the first step, and a seeded
        # one draws the world again, so that episode is never driven (its pre-roll took ~2 s of every gym.make)
        run_preroll = cfg.traffic.driver_types and not self._constructing
        preroll_steps = int(round(cfg.twin.preroll_s * cfg.highway.simulation_frequency)) if run_preroll else 0
        preroll = preroll_steps / cfg.highway.simulation_frequency
        self.sim_time_s = -preroll
        if self.twin is not None:
            self.twin.start_episode()
            # the twin clock runs on across episodes: this episode starts 1 s after the last (the constructor's
            # episode, never driven, leaves it where it was: a make and close leaves a twin store as it found it)
            self.twin_offset_s = self.twin.now_s + (0.0 if self._constructing else 1.0 + preroll)
            self.twin.now_s = self.twin_now_s
        if cfg.traffic.driver_types:
            self._create_typed_vehicles()
            if preroll_steps > 0:
                self._preroll(preroll_steps)
        else:
            connected = self.traffic.rng.random(len(self.road.vehicles)) < cfg.twin.connected_fraction
            for i, v in enumerate(self.road.vehicles):
                v.dt_id = i
                v.dt_connected = cfg.twin.enabled and bool(connected[i])
            self.vehicle.dt_connected = cfg.twin.enabled
            if cfg.ego.autopilot:
                self._swap_ego(self._autopilot_from(self.vehicle))
        self.sim_time_s = 0.0
        self._events = []
        if hasattr(self.action_type, "reset"):  # an action with state (the assisted menu's desired speed)
            self.action_type.reset()
        self._episode += 1
        self._frame, self._frame_key = None, None
        self._build_camera()
        self.adas = None
        if cfg.fusion.enabled:
            assert self.camera is not None  # the config refuses fusion without the camera
            self.pipeline = AdasPipeline.from_config(cfg, self.camera.camera, rngs["detector"], rngs["fusion"],
                                                     rngs["overlay"], self.road_map)
            self.detector, self.fusion, self.overlay = self.pipeline.detector, self.pipeline.fusion, self.pipeline.overlay
        else:
            self.pipeline = None
            self.detector, self.fusion = None, None
        self.safety.reset()
        self._safety_samples, self._cut_ins = [], []
        self._safety_on = True
        self._sample_safety(log=False)  # the state at t = 0 primes the monitor; samples follow each step

    def _build_camera(self) -> None:
        """The camera renderer for this road (kept across episodes while nothing changes)."""
        cfg = self.dt_config.camera
        if not cfg.enabled:
            self.camera, self._camera_key = None, None
            return
        scene = RoadScene.from_road(self.road)
        key = (cfg.model_dump_json(), scene)
        if key != self._camera_key:
            self.camera = make_camera(cfg, scene)
            self._camera_key = key

    def camera_image(self) -> CameraImage:
        """The ego camera's image at the current simulation step, rendered once per step.

        Observation, ``info`` and any caller (fusion, overlay, recorder, a driver's senses)
        share this one rendering; call it as often as needed.

        :return: RGB, planar depth [m], the pose and the time (no ground truth)
        :raises RuntimeError: if the camera is off (``camera.enabled = false``) or before ``reset``
        """
        return self._camera_frame()[0]

    def camera_truth(self) -> CameraTruth:
        """The ground truth of this step's camera image (instance ids, boxes per vehicle): for
        evaluation, training labels and the simulated detector only, never for what a driver,
        the fusion or the overlay is given.

        :return: the instance map and the ground truth per drawn vehicle
        :raises RuntimeError: if the camera is off (``camera.enabled = false``) or before ``reset``
        """
        return self._camera_frame()[1]

    def _camera_frame(self) -> tuple[CameraImage, CameraTruth]:
        """This step's rendering (image and truth), made on the first call of the step."""
        if self.camera is None:
            raise RuntimeError("the camera is off: set camera.enabled = true (and reset) to get frames")
        key = (self._episode, self.steps)
        if self._frame is None or self._frame_key != key:
            ego = self.vehicle
            pose = Pose(float(ego.position[0]), float(ego.position[1]), float(ego.heading))
            self._frame = self.camera.render(pose, VehicleSet.from_road(self.road, exclude=ego), self.sim_time_s)
            self._frame_key = key
        return self._frame

    def _create_road(self) -> None:
        hw = self.dt_config.highway
        road_class = FastRoad if self.dt_config.traffic.fast_road else Road
        self.road = road_class(
            network=RoadNetwork.straight_road_network(hw.lanes_count, length=hw.road_length, speed_limit=hw.speed_limit),
            np_random=self.np_random,
            record_history=self.config["show_trajectories"],
            neighbour_vehicles_connected_lanes=self.config["neighbour_vehicles_connected_lanes"],
        )

    def _create_typed_vehicles(self) -> None:
        hw = self.dt_config.highway
        assert self.traffic is not None  # made by _reset before the vehicles
        lane_id = hw.initial_lane_id if hw.initial_lane_id is not None else int(self.traffic.rng.integers(hw.lanes_count))
        lane_id = min(lane_id, hw.lanes_count - 1)
        lane_index = ("0", "1", lane_id)
        lane = self.road.network.get_lane(lane_index)
        x = self.dt_config.traffic.spawn_behind_m + 50.0
        ego = self.action_type.vehicle_class(self.road, lane.position(x, 0), lane.heading_at(x), hw.ego_speed)
        ego.dt_id = EGO_ID
        ego.dt_connected = self.dt_config.twin.enabled
        self.controlled_vehicles = [ego]
        self.road.vehicles.append(ego)
        if self.dt_config.ego.autopilot:
            self._swap_ego(self._autopilot_from(ego))
        self.traffic.time_s = self.sim_time_s
        self.traffic.populate(self.road, ego, hw.vehicles_count)

    def _preroll(self, n_steps: int) -> None:
        """Run traffic (ego on the IDM autopilot) for ``n_steps`` simulation steps before t = 0.

        The ego cannot be hit during the pre-roll (a cut-in there would end the episode before
        it starts); NPCs still see it and keep their distance. Any NPC left overlapping it at
        the end is taken off the road.
        """
        autopilot = self.dt_config.ego.autopilot
        if not autopilot:
            self._swap_ego(self._autopilot_from(self.vehicle))
        self.vehicle.collidable = False
        for _ in range(n_steps):
            self._sim_step()
        self.vehicle.collidable = True
        if not autopilot:
            stand_in = self.vehicle
            ego = self.action_type.vehicle_class(self.road, stand_in.position, stand_in.heading, stand_in.speed)
            ego.dt_id, ego.dt_connected = EGO_ID, stand_in.dt_connected
            self._swap_ego(ego)
        self._clear_around_ego()

    def _clear_around_ego(self) -> None:
        """Take off the road NPCs that overlap the ego (or will within one step), so that t = 0 starts clean."""
        ego = self.vehicle
        dt = 1.0 / self.config["simulation_frequency"]
        keep = []
        for v in self.road.vehicles:
            if v is not ego and abs(v.position[0] - ego.position[0]) < 2 * v.LENGTH:
                intersecting, will_intersect, _ = ego._is_colliding(v, dt)
                if intersecting or will_intersect:
                    if self.traffic is not None:
                        self.traffic.remove(v)
                    if self.uplink is not None:
                        self.uplink.forget(vehicle_id(v))
                    continue
            keep.append(v)
        self.road.vehicles[:] = keep

    def _autopilot_from(self, ego: Vehicle) -> IDMVehicle:
        """An IDM vehicle (no lane changes) in the ego's place and state."""
        pilot_class = FastIDMVehicle if self.dt_config.traffic.fast_road else IDMVehicle
        pilot = pilot_class(
            self.road, ego.position, ego.heading, ego.speed, target_lane_index=ego.lane_index,
            target_speed=self.dt_config.ego.autopilot_speed_mps, enable_lane_change=False,
        )
        pilot.dt_id, pilot.dt_connected = EGO_ID, getattr(ego, "dt_connected", False)
        return pilot

    def _swap_ego(self, new: Vehicle) -> None:
        self.road.vehicles[self.road.vehicles.index(self.vehicle)] = new
        self.controlled_vehicles = [new]

    # ------------------------------------------------------------------ stepping
    @property
    def twin_now_s(self) -> float:
        """Twin clock [s] at the current simulation time."""
        return self.twin_offset_s + self.sim_time_s

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict]:
        """highway-env's step, after a check that the action fits the action space
        (:func:`~dt_highway.env.actions.check_action`), unless the ego drives itself
        (``ego.autopilot``, ``manual_control``): a bad action changes nothing, not even the clock.

        :param action: the ego's action in the action space (not used when the ego drives itself)
        :return: gymnasium's ``(observation, reward, terminated, truncated, info)``
        :raises ValueError: one line, on an action the action space cannot hold
        """
        if not self.config["manual_control"] and not self.dt_config.ego.autopilot:
            check_action(self.action_space, action, type(self.action_type).__name__)
        return super().step(action)

    def _simulate(self, action: Any = None) -> None:
        frames = int(self.config["simulation_frequency"] // self.config["policy_frequency"])
        for frame in range(frames):
            if action is not None and not self.config["manual_control"] and not self.dt_config.ego.autopilot and frame == 0:
                self.action_type.act(action)
            self._sim_step()
            if frame < frames - 1:
                self._automatic_rendering()
        self.enable_auto_render = False

    def _sim_step(self) -> None:
        """One physics step, then the twin's uplink, cloud and downlink at the new time."""
        dt = 1.0 / self.config["simulation_frequency"]
        self.road.act()
        self.road.step(dt)
        self.steps += 1
        t_prev = self.twin_now_s
        self.sim_time_s += dt
        if self.traffic is not None and self.dt_config.traffic.driver_types:
            self.traffic.time_s = self.sim_time_s
            self.traffic.recycle(self.road, self.vehicle)
            for ev in self.traffic.drain_events():
                if ev.kind == "despawn" and self.uplink is not None:
                    self.uplink.forget(ev.vehicle_id)
                if ev.kind == "cut_in" and ev.other_id == EGO_ID:
                    self._aimed_cut_ins[ev.vehicle_id] = (ev.time_s, ev.style)
                self._events.append(ev)
        if self.twin is not None:
            now = self.twin_now_s
            states = [
                _uplink_state(v)
                for v in self.road.vehicles
                if getattr(v, "dt_connected", False)
            ]
            assert self.uplink is not None and self.downlink is not None  # made with the twin in _reset
            self.twin.receive(self.uplink.sample(t_prev, now, states))
            self.twin.advance(now)
            self.twin_view = self.downlink.step(self.twin, EGO_ID, now)
        if self._safety_on:
            self._sample_safety()

    def _sample_safety(self, log: bool = True) -> None:
        """The ego's leader, gap, TTC, 2-D TTC... after this simulation step (evaluation: from the simulator's state).

        :param log: keep the sample (``False``: only prime the monitor, at reset)
        """
        ego = self.vehicle
        others = [v for v in self.road.vehicles if v is not ego]
        lane_y = float(self.road.network.get_lane(ego.lane_index).position(float(ego.position[0]), 0.0)[1])
        sample, cut_ins = self.safety.sample(round(self.sim_time_s, 9), 1.0 / self.config["simulation_frequency"], ego, lane_y,
                                             others, [vehicle_id(v) for v in others])
        if not log:
            return
        row = sample.to_dict()
        by_id = {vehicle_id(v): v for v in others} if cut_ins or sample.collision else {}
        if sample.collision is not None:  # the crash partner's true type: evaluation (logs, report) only
            partner = by_id.get(sample.collision.partner_id)
            row["collision"]["partner_type"] = driver_type(partner) if partner is not None else None
        self._safety_samples.append(row)
        for c in cut_ins:
            # the cutting driver's true type is for evaluation (logs, report) only
            self._cut_ins.append({**c.to_dict(), "driver_type": driver_type(by_id[c.vehicle_id]),
                                  "maneuver": self._maneuver(c)})

    AIMED_CUT_IN_S = 8.0
    """A lane entry in front of the ego is the traffic's cut-in on it when that driver aimed one at it this recently [s]"""

    def _maneuver(self, cut_in: CutIn) -> str:
        """The traffic's manoeuvre behind a lane entry in front of the ego (evaluation): ``gentle`` or
        ``dangerous`` for a cut-in the driver aimed at the ego, else empty (a lane change of its own)."""
        aimed = self._aimed_cut_ins.get(cut_in.vehicle_id)
        if aimed is None or not 0.0 <= cut_in.t_s - aimed[0] <= self.AIMED_CUT_IN_S:
            return ""
        return aimed[1]

    # ------------------------------------------------------------------ info
    def _info(self, obs: Any, action: Any = None) -> dict:
        info = super()._info(obs, action)
        ego = self.vehicle
        info["time_s"] = float(self.sim_time_s)
        info["ego"] = {
            "id": EGO_ID,
            "x_m": float(ego.position[0]),
            "y_m": float(ego.position[1]),
            "speed_mps": float(ego.speed),
            "heading_rad": float(ego.heading),
            "lane": int(ego.lane_index[2]) if ego.lane_index else -1,
            "crashed": bool(ego.crashed),
        }
        info["twin"] = self._twin_info()
        info["ground_truth"] = {
            "vehicles": {
                vehicle_id(v): {
                    "driver_type": driver_type(v),
                    "connected": bool(getattr(v, "dt_connected", False)),
                    "x_m": float(v.position[0]),
                    "y_m": float(v.position[1]),
                    "speed_mps": float(v.speed),
                    "lane": int(v.lane_index[2]) if v.lane_index else -1,
                    "crashed": bool(v.crashed),
                }
                for v in self.road.vehicles
                if v is not ego
            },
            "events": [ev.__dict__.copy() for ev in self._events],
        }
        if self.dt_config.traffic.population == "continuum":  # the latent score, only where there is one
            for v in self.road.vehicles:
                if v is not ego:
                    info["ground_truth"]["vehicles"][vehicle_id(v)]["aggressiveness"] = aggressiveness(v)
        if self.camera is not None:
            # the camera's ground truth (instance boxes); the images are on camera_image()
            info["ground_truth"]["camera"] = [t.to_dict() for t in self.camera_truth().vehicles.values()]
        if self.fusion is not None:
            info["adas"] = self.adas_output()
        # safety samples of every simulation step since the last info (evaluation)
        info["safety"] = {"samples": self._safety_samples, "cut_ins": self._cut_ins}
        self._safety_samples, self._cut_ins = [], []
        self._events = []
        return info

    def adas_output(self) -> dict[str, Any] | None:
        """The ADAS output of this step (detector, fusion, overlay), computed once per step
        for whoever asks first (the observation, ``info``).

        :return: see :meth:`_run_fusion`; ``None`` when the fusion is off
        """
        if self.fusion is None:
            return None
        key = (self._episode, self.steps)
        if self.adas is None or self._adas_key != key:
            self.adas = self._run_fusion()
            self._adas_key = key
        return self.adas

    def _run_fusion(self) -> dict[str, Any]:
        """The ADAS pipeline on this step's frame and twin view (see :class:`~dt_highway.env.adas.AdasPipeline`)."""
        view = self.twin_view.vehicles if self.twin_view is not None else ()
        image, truth = self._camera_frame()
        assert self.pipeline is not None  # adas_output() runs this only with the fusion on
        lane = self.vehicle.lane_index  # the ego knows its own lane (threat marks: cars cutting into it)
        return self.pipeline.run(image, truth, view, self.twin_now_s, self.sim_time_s, int(lane[2]) if lane else -1)

    def _twin_info(self) -> list[dict[str, Any]] | None:
        """The delivered twin view with times on the episode clock [s] and ages [s], and each vehicle's
        lane-change intents (``horizon_s``, ``p_change``, ``target_lane``, ``p_target``; empty without any)."""
        view = self.twin_view
        if view is None:
            return None
        now = self.twin_now_s
        return [
            {
                "vehicle_id": v.vehicle_id,
                "t_fix_s": v.t_fix_s - self.twin_offset_s,
                "age_s": now - v.t_fix_s,
                "x_m": v.x_m,
                "y_m": v.y_m,
                "speed_mps": v.speed_mps,
                "heading_rad": v.heading_rad,
                "tag": v.tag,
                "confidence": v.confidence,
                "n_sudden": v.n_sudden,
                "intents": [
                    {"horizon_s": i.horizon_s, "p_change": i.p_change, "target_lane": i.target_lane, "p_target": i.p_target}
                    for i in v.intents
                ],
            }
            for v in view.vehicles
        ]

    def close(self) -> None:
        """Write the twin's drivers to its store file (when one is configured), then close highway-env's window."""
        self._close_twin()
        super().close()

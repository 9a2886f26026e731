"""A trained policy as a driver of the ego (``--driver agents/<name>.zip``).

The policy sees what it was trained on, computed by the env side from the env it drives in
(whatever that env's own observation is) and handed to it in its
:class:`~dt_highway.drivers.perception.Perception`: its Kinematics rows, the overlay's marks
(ADAS-aware policies; zeros in the baseline condition, where there is no overlay), or the
camera. Its discrete choice is turned into the ``Driver`` action ``[acceleration, lane]`` that
every driver uses.

stable-baselines3 model files are pickles: loading one can run code. Load only policies
you trust (the ones shipped under ``agents/`` or trained yourself).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from gymnasium import spaces

from dt_highway.config import ConfigError
from dt_highway.drivers.base import Driver
from dt_highway.drivers.menus import DiscreteMenu
from dt_highway.drivers.perception import ObservationSpec, Perception, SenseRequest
from dt_highway.rl.config import TrainConfig, parse_train_config
from dt_highway.rl.files import read_policy_meta, sha256, sidecar_path

TRAINED_SETTINGS = ("lanes_count", "policy_frequency", "simulation_frequency")
"""``highway`` settings a policy must drive with as it was trained with them"""
KINEMATICS_FEATURES = ("presence", "x", "y", "vx", "vy")
"""highway-env's Kinematics columns when the observation names none (its ``features`` default)"""
OVERLAY_FEATURES = ("marked",)
"""The columns an ``OverlayKinematics`` observation appends from the overlay, last (the env's ``EXTRA_FEATURES``)"""
THREAT_FEATURES = ("cut_in_warned", "side")
"""The threat cue's columns after them with ``threat = true`` (the env's ``THREAT_FEATURES``)"""


class PolicyDriver(Driver):
    """Drives with a stable-baselines3 policy (deterministic actions).

    Its :attr:`senses` declare what it was trained on (its metadata's observation, camera size
    and decision rate; with the assisted menu also the surroundings the menu reads); the env
    side makes that observation of the env it drives in, or refuses in one line
    (:class:`~dt_highway.env.seat.DriverSeat`). Each decision its menu index becomes the
    ``Driver`` action on this side (:class:`~dt_highway.drivers.menus.DiscreteMenu`).

    :param name: the driver's name (the model file's stem)
    :param model: the loaded model
    :param config: its training configuration
    :param meta: the metadata saved beside it
    """

    def __init__(self, name: str, model: Any, config: TrainConfig, meta: dict[str, Any]) -> None:
        super().__init__(name)
        self.model, self.config, self.meta = model, config, meta
        obs_cfg = dict(self._trained("highway", "observation")) or config.observation_config()
        kind = obs_cfg.pop("type", None)
        self.action_settings: dict[str, Any] = (dict(self._trained("highway", "action"))
                                                or config.action_config())
        self.action_settings.pop("type", None)
        assisted = bool(self.action_settings.get("assist", False))
        trained = {key: self._trained("highway", key) for key in TRAINED_SETTINGS}
        spec = ObservationSpec(name, kind, obs_cfg, self._trained("camera"),
                               {key: value for key, value in trained.items() if value != {}}, model.observation_space)
        self.senses = SenseRequest(surroundings=assisted, entering=assisted, observation=spec)
        self.menu: DiscreteMenu | None = None
        self.overlay_features: tuple[str, ...] = ()
        """its observation's columns that come from the overlay (none without marks)"""
        self.features: tuple[str, ...] = ()
        """its observation's column names (Kinematics-type observations; empty for the camera)"""
        if kind in ("Kinematics", "OverlayKinematics"):
            self.overlay_features = (OVERLAY_FEATURES + (THREAT_FEATURES if obs_cfg.get("threat") else ())
                                     if kind == "OverlayKinematics" else ())
            self.features = tuple(obs_cfg.get("features") or KINEMATICS_FEATURES) + self.overlay_features
        self.zeroed: tuple[int, ...] = ()
        """indices of the observation's columns set to 0 before the policy sees them (:meth:`zero_columns`)"""

    def zero_columns(self, names: tuple[str, ...] | list[str]) -> None:
        """Zero these columns of every observation before the policy sees it (an ablation: e.g. the
        overlay's columns, :attr:`overlay_features`, while the env runs the same condition).

        :param names: column names of :attr:`features`; empty: zero nothing
        :raises ConfigError: one line, on a name its observation does not have
        """
        unknown = [n for n in names if n not in self.features]
        if unknown:
            raise ConfigError(f"policy {self.name}: no observation column {', '.join(unknown)} to zero "
                              f"(its columns: {', '.join(self.features) or 'none, a camera observation'})")
        shape: tuple[int, ...] = tuple(getattr(self.model.observation_space, "shape", None) or ())
        if names and (len(shape) != 2 or shape[-1] != len(self.features)):
            raise ConfigError(f"policy {self.name}: its observation {shape} does not have the columns "
                              f"{', '.join(self.features)}: cannot zero {', '.join(names)}")
        self.zeroed = tuple(self.features.index(n) for n in names)

    def params(self) -> dict[str, Any]:
        """The policy's algorithm, observation, action, timesteps trained and package versions (for the trial log).

        :return: those by name
        """
        return {"algorithm": self.config.algorithm, "observation": self.config.observation, "action": self.config.action,
                "timesteps": self.meta.get("timesteps_done"), "versions": self.meta.get("versions")}

    def config_overrides(self) -> dict[str, Any]:
        """A vision policy needs the camera on, in either condition (its frames are resized to
        the size it was trained on, so the detector and fusion keep the study's camera).

        :return: the camera switched on for a vision policy, else nothing
        """
        return {"camera": {"enabled": True}} if self.config.observation == "vision" else {}

    def _trained(self, *keys: str) -> Any:
        value: Any = self.meta.get("env_config", {})
        for k in keys:
            value = value.get(k, {}) if isinstance(value, dict) else {}
        return value

    def reset(self, seed: int) -> None:
        """Start an episode with a fresh action menu, the one the policy was trained with, and
        check it is the menu its network chooses from.

        :param seed: unused (the policy acts deterministically)
        :raises ConfigError: one line, on a menu its metadata cannot make or of another size
        """
        settings = dict(self.action_settings)
        try:
            if settings.pop("steering", False):
                raise ValueError("the DiscreteDriver action requests lanes: steering = true is not available")
            settings.pop("steering_max_rad", None)
            self.menu = DiscreteMenu(**settings)
        except (TypeError, ValueError) as err:
            raise ConfigError(f"policy {self.name}: its metadata's observation or action settings: {err}") from None
        menu_space = spaces.Discrete(self.menu.size)
        if menu_space != self.model.action_space:
            raise ConfigError(f"policy {self.name} chooses from {self.model.action_space}, but its metadata's action "
                              f"menu has {menu_space}")

    def act(self, perception: Perception) -> np.ndarray:
        """The policy's action on the observation in ``perception`` (deterministic), as a ``Driver`` action.

        :param perception: what the driver perceives now (its observation; with the assisted menu its surroundings)
        :return: the action ``[acceleration m/s^2, lane -1..1]``
        """
        if self.menu is None:
            self.reset(0)
        assert self.menu is not None
        if perception.observation is None:
            raise ValueError(f"policy {self.name} acts on its observation: perceive with its senses (a DriverSeat)")
        observation = perception.observation
        if self.zeroed:
            observation = np.array(observation, copy=True)
            observation[..., list(self.zeroed)] = 0
        action, _ = self.model.predict(observation, deterministic=True)
        return self.menu.action(self.menu.choice(action), perception)


def load_policy(path: str | Path) -> PolicyDriver:
    """Load ``agents/<name>.zip`` and the ``agents/<name>.json`` written beside it by training.

    Only load files you trust: stable-baselines3 model files are pickles.

    :param path: the model file ``agents/<name>.zip``
    :return: the policy as a driver, named after the file's stem
    :raises ConfigError: one line, on a missing or foreign file, or a damaged model
    """
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"policy file not found: {p}")
    side = sidecar_path(p)
    meta = read_policy_meta(p)
    config = parse_train_config(meta.get("train_config", {}), str(side))
    if meta.get("model_sha256") and meta["model_sha256"] != sha256(p):
        raise ConfigError(f"{side} describes another model file than {p.name} (its SHA-256 differs): "
                          f"train again, or restore the pair")
    import stable_baselines3 as sb3  # lazy: stable-baselines3 (~1.3 s)

    try:
        model = getattr(sb3, config.algorithm).load(str(p), device="cpu")
    except Exception as err:  # noqa: BLE001 - a damaged or foreign zip: say so in one line
        raise ConfigError(f"cannot load {p} as a {config.algorithm} model: {type(err).__name__}: {err}") from None
    n = len(config.speeds_mps) + 2 if config.action.startswith("assisted") else len(config.accels_mps2) + 2
    if not isinstance(model.action_space, spaces.Discrete) or model.action_space.n != n:
        raise ConfigError(f"{p} chooses from {model.action_space}, but its training file's menu has {n} entries")
    return PolicyDriver(p.stem, model, config, meta)

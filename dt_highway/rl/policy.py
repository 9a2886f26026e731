"""A trained policy as a driver of the ego (``--driver agents/<name>.zip``).

The policy sees what it was trained on, computed from the env it drives in (whatever that
env's own observation is): its Kinematics rows, the overlay's marks (ADAS-aware policies;
zeros in the baseline condition, where there is no overlay), or the camera. Its discrete
choice is turned into the ``Driver`` action ``[acceleration, lane]`` that every driver uses.

stable-baselines3 model files are pickles: loading one can run code. Load only policies
you trust (the ones shipped under ``agents/`` or trained yourself).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from dt_highway.config import ConfigError
from dt_highway.drivers.scripted import Driver
from dt_highway.rl.config import TrainConfig, parse_train_config
from dt_highway.rl.train import sidecar_path


class PolicyDriver(Driver):
    """Drives with a stable-baselines3 policy (deterministic actions).

    :param name: the driver's name (the model file's stem)
    :param model: the loaded model
    :param config: its training configuration
    :param meta: the metadata saved beside it
    """

    def __init__(self, name: str, model: Any, config: TrainConfig, meta: dict[str, Any]) -> None:
        super().__init__(name)
        self.model, self.config, self.meta = model, config, meta
        self.needs_camera = config.observation in ("adas", "vision")
        self.observer: Any = None
        self.menu = [(a, 0.0) for a in config.accels_mps2] + [(0.0, -1.0), (0.0, 1.0)]

    def params(self) -> dict[str, Any]:
        return {"algorithm": self.config.algorithm, "observation": self.config.observation,
                "timesteps": self.meta.get("timesteps_done"), "versions": self.meta.get("versions")}

    def config_overrides(self) -> dict[str, Any]:
        """A vision policy needs the camera it was trained with, in either condition."""
        if self.config.observation != "vision":
            return {}
        cam = self.meta.get("env_config", {}).get("camera", {})
        return {"camera": {"enabled": True, **{k: cam[k] for k in ("width_px", "height_px", "hfov_deg") if k in cam}}}

    def reset(self, env: Any, seed: int) -> None:
        """Bind the policy's observation to this env and check it is the one it was trained on.

        :raises ConfigError: if the env gives another observation space
        """
        from dt_highway.env import CameraObservation, OverlayKinematics
        from dt_highway.fastobs import FastKinematicObservation

        obs_cfg = self.config.observation_config()
        kind = obs_cfg.pop("type")
        cls = {"Kinematics": FastKinematicObservation, "OverlayKinematics": OverlayKinematics,
               "Camera": CameraObservation}[kind]
        if kind == "Camera" and env.camera is None:
            raise ConfigError(f"policy {self.name} looks through the camera: run it with camera.enabled = true")
        self.observer = cls(env, **obs_cfg)
        space = self.observer.space()
        if not _same_space(space, self.model.observation_space):
            raise ConfigError(f"policy {self.name} was trained on observations {self.model.observation_space}, but "
                              f"this env gives {space} (another observation setting, vehicles_count or camera size)")

    def act(self, env: Any, obs: Any, info: dict[str, Any]) -> np.ndarray:
        if self.observer is None:
            self.reset(env, 0)
        action, _ = self.model.predict(self.observer.observe(), deterministic=True)
        return np.array(self.menu[int(np.asarray(action).reshape(-1)[0])], dtype=float)


def _same_space(a: Any, b: Any) -> bool:
    """Whether the env's space ``a`` is the model's ``b`` (stable-baselines3 stores images
    channels-first and transposes channels-last observations itself)."""
    from gymnasium import spaces
    from stable_baselines3.common.preprocessing import is_image_space, is_image_space_channels_first
    from stable_baselines3.common.vec_env import VecTransposeImage

    if isinstance(a, spaces.Dict) and isinstance(b, spaces.Dict):
        return a.keys() == b.keys() and all(_same_space(a[k], b[k]) for k in a.keys())
    if isinstance(a, spaces.Box) and is_image_space(a) and not is_image_space_channels_first(a):
        a = VecTransposeImage.transpose_space(a)
    return type(a) is type(b) and getattr(a, "shape", None) == getattr(b, "shape", None) and \
        getattr(a, "dtype", None) == getattr(b, "dtype", None)


def load_policy(path: str | Path) -> PolicyDriver:
    """Load ``agents/<name>.zip`` and the ``agents/<name>.json`` written beside it by training.

    Only load files you trust: stable-baselines3 model files are pickles.

    :raises ConfigError: one line, on a missing or foreign file, or a damaged model
    """
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"policy file not found: {p}")
    side = sidecar_path(p)
    try:
        meta = json.loads(side.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"{p}: no {side.name} beside it (the metadata dt-highway train writes): "
                          f"not a dt-highway policy") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise ConfigError(f"cannot read {side}: {err}") from None
    if not isinstance(meta, dict) or meta.get("format") != "dt-highway policy 1":
        raise ConfigError(f"{side} is not the metadata of a dt-highway policy")
    config = parse_train_config(meta.get("train_config", {}), str(side))
    import stable_baselines3 as sb3

    try:
        model = getattr(sb3, config.algorithm).load(str(p), device="cpu")
    except Exception as err:  # noqa: BLE001 - a damaged or foreign zip: say so in one line
        raise ConfigError(f"cannot load {p} as a {config.algorithm} model: {type(err).__name__}: {err}") from None
    return PolicyDriver(p.stem, model, config, meta)

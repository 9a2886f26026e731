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
from dt_highway.drivers.base import Driver
from dt_highway.rl.config import TrainConfig, parse_train_config
from dt_highway.rl.files import FORMAT, sha256, sidecar_path


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
        self.actions: Any = None

    def params(self) -> dict[str, Any]:
        return {"algorithm": self.config.algorithm, "observation": self.config.observation, "action": self.config.action,
                "timesteps": self.meta.get("timesteps_done"), "versions": self.meta.get("versions")}

    def config_overrides(self) -> dict[str, Any]:
        """A vision policy needs the camera on, in either condition (its frames are resized to
        the size it was trained on, so the detector and fusion keep the study's camera)."""
        return {"camera": {"enabled": True}} if self.config.observation == "vision" else {}

    def _trained(self, *keys: str) -> Any:
        value: Any = self.meta.get("env_config", {})
        for k in keys:
            value = value.get(k, {}) if isinstance(value, dict) else {}
        return value

    def reset(self, env: Any, seed: int) -> None:
        """Bind the policy's observation and action menu to this env, and check the env is one
        it can drive: the same observation space, lanes and decision rate as in training.

        :raises ConfigError: one line, on any mismatch
        """
        from dt_highway.env import OverlayKinematics
        from dt_highway.env.actions import DiscreteDriverAction
        from dt_highway.world.observation import FastKinematicObservation

        for key in ("lanes_count", "policy_frequency", "simulation_frequency"):
            trained, here = self._trained("highway", key), env.config.get(key)
            if trained != {} and trained != here:
                raise ConfigError(f"policy {self.name} was trained with highway.{key} = {trained}; this env has {here}")
        obs_cfg = dict(self._trained("highway", "observation")) or self.config.observation_config()
        kind = obs_cfg.pop("type", None)
        if obs_cfg.get("order", "sorted") != "sorted":
            raise ConfigError(f"policy {self.name}: only sorted observations are supported (got order = {obs_cfg['order']!r})")
        try:
            if kind == "Camera":
                cam = self._trained("camera")
                self.observer = ResizedCamera(env, (int(cam.get("width_px", 128)), int(cam.get("height_px", 72))),
                                              depth=bool(obs_cfg.get("depth", False)))
            elif kind in ("Kinematics", "OverlayKinematics"):
                cls = OverlayKinematics if kind == "OverlayKinematics" else FastKinematicObservation
                self.observer = cls(env, **obs_cfg)
            else:
                raise ConfigError(f"policy {self.name}: unknown observation type {kind!r} in its metadata")
            act_cfg = dict(self._trained("highway", "action")) or self.config.action_config()
            act_cfg.pop("type", None)
            self.actions = DiscreteDriverAction(env, **act_cfg)  # the menu it was trained with, on this env
        except (TypeError, ValueError) as err:
            raise ConfigError(f"policy {self.name}: its metadata's observation or action settings: {err}") from None
        space = self.observer.space()
        if not _same_space(space, self.model.observation_space):
            raise ConfigError(f"policy {self.name} was trained on observations {self.model.observation_space}, but "
                              f"this env gives {space} (another observation setting, vehicles_count or camera size)")
        if self.actions.space() != self.model.action_space:
            raise ConfigError(f"policy {self.name} chooses from {self.model.action_space}, but its metadata's action "
                              f"menu has {self.actions.space()}")

    def act(self, env: Any, obs: Any, info: dict[str, Any]) -> np.ndarray:
        if self.observer is None:
            self.reset(env, 0)
        action, _ = self.model.predict(self.observer.observe(), deterministic=True)
        return self.actions.driver_action(action)


class ResizedCamera:
    """A vision policy's view: the ego camera's frame at the size it was trained on, with the
    ADAS overlay drawn on it when there is one (what a driver sees on the screen).

    :param env: the env (camera on)
    :param size: ``(width, height)`` [px] the policy takes
    :param depth: also the depth image (``uint8``, as :class:`~dt_highway.env.CameraObservation`)
    """

    def __init__(self, env: Any, size: tuple[int, int], depth: bool = False) -> None:
        if not env.dt_config.camera.enabled:
            raise ConfigError("a vision policy looks through the camera: run it with camera.enabled = true")
        self.env, self.size, self.depth = env, size, depth

    def space(self) -> Any:
        from gymnasium import spaces

        w, h = self.size
        parts = {"rgb": spaces.Box(0, 255, shape=(h, w, 3), dtype=np.uint8)}
        if self.depth:
            parts["depth"] = spaces.Box(0, 255, shape=(h, w, 1), dtype=np.uint8)
        return spaces.Dict(parts)

    def observe(self) -> dict[str, np.ndarray]:
        import cv2

        from dt_highway.camera.render import depth_to_uint8
        from dt_highway.overlay import draw_overlay

        frame = self.env.camera_frame()
        rgb = frame.rgb
        adas = self.env.adas_output()
        if adas is not None and adas["overlay"]:
            rgb = draw_overlay(rgb, adas["overlay"])
        same = rgb.shape[1] == self.size[0] and rgb.shape[0] == self.size[1]
        out = {"rgb": rgb if same else cv2.resize(rgb, self.size, interpolation=cv2.INTER_AREA)}
        if self.depth:
            d = depth_to_uint8(frame.depth_m, self.env.dt_config.camera.max_range_m)
            out["depth"] = (d if same else cv2.resize(d, self.size, interpolation=cv2.INTER_AREA))[..., None]
        return out


def _same_space(a: Any, b: Any) -> bool:
    """Whether the env's space ``a`` is the model's ``b`` (stable-baselines3 stores images
    channels-first and transposes channels-last observations itself)."""
    from gymnasium import spaces
    from stable_baselines3.common.preprocessing import (
        is_image_space,
        is_image_space_channels_first,
    )
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
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise ConfigError(f"{side} is not the metadata of a dt-highway policy")
    config = parse_train_config(meta.get("train_config", {}), str(side))
    if meta.get("model_sha256") and meta["model_sha256"] != sha256(p):
        raise ConfigError(f"{side} describes another model file than {p.name} (its SHA-256 differs): "
                          f"train again, or restore the pair")
    import stable_baselines3 as sb3

    try:
        model = getattr(sb3, config.algorithm).load(str(p), device="cpu")
    except Exception as err:  # noqa: BLE001 - a damaged or foreign zip: say so in one line
        raise ConfigError(f"cannot load {p} as a {config.algorithm} model: {type(err).__name__}: {err}") from None
    from gymnasium import spaces

    n = len(config.speeds_mps) + 2 if config.action == "assisted" else len(config.accels_mps2) + 2
    if not isinstance(model.action_space, spaces.Discrete) or model.action_space.n != n:
        raise ConfigError(f"{p} chooses from {model.action_space}, but its training file's menu has {n} entries")
    return PolicyDriver(p.stem, model, config, meta)

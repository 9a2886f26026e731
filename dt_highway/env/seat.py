"""A driver's seat in an env: the senses a driver declared, bound to the env it drives.

The harness (a study trial, an evaluation) puts a driver in the seat and hands it what the seat
perceives, decision by decision::

    seat = DriverSeat(env.unwrapped, driver.senses)   # a policy is checked against the env here
    driver.reset(seed)
    action = driver.act(seat.perceive())

For a trained policy the seat makes the observation it was trained on from this env
(:class:`~dt_highway.world.observation.FastKinematicObservation`,
:class:`~dt_highway.env.observations.OverlayKinematics` or
:class:`~dt_highway.env.observations.ResizedCamera`), after checking the env is one it can
drive: the same lanes and decision rate, and the same observation space. Everything else a
driver perceives comes from :func:`~dt_highway.env.senses.perceive`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import gymnasium as gym
from gymnasium import spaces

from dt_highway.config import ConfigError
from dt_highway.drivers.perception import ObservationSpec, Perception, SenseRequest
from dt_highway.env.core import DTHighwayEnv
from dt_highway.env.observations import OverlayKinematics, ResizedCamera
from dt_highway.env.senses import perceive
from dt_highway.world.observation import FastKinematicObservation


class DriverSeat:
    """A driver's senses bound to an env.

    :param env: a ``dt-highway-v0`` env, wrapped (``gym.make``) or not
    :param request: what the driver looks at (its ``senses``)
    :raises ConfigError: one line, when the env cannot show a policy what it was trained on
    :raises TypeError: if ``env`` is not a ``dt-highway-v0`` env
    """

    def __init__(self, env: gym.Env, request: SenseRequest) -> None:
        u = env.unwrapped
        if not isinstance(u, DTHighwayEnv):
            raise TypeError(f"a driver's seat is in a dt-highway-v0 env (got {type(u).__name__})")
        self.env: DTHighwayEnv = u
        self.request = request
        self.observer = policy_observer(u, request.observation) if request.observation is not None else None

    def perceive(self, overlay: Sequence[Mapping[str, Any]] | None = None) -> Perception:
        """What the driver perceives now.

        :param overlay: overlay items to see instead of this step's ADAS output (tests); ``None``: the env's
        :return: the perception of the driver's senses (a policy's observation included)
        """
        observation = self.observer.observe() if self.observer is not None else None
        return perceive(self.env, self.request, observation, overlay)


def policy_observer(env: DTHighwayEnv, spec: ObservationSpec) -> FastKinematicObservation | ResizedCamera:
    """The observation a policy was trained on, made of this env, once the env is checked to be
    one it can drive: the same observation space, lanes and decision rate as in training.

    :param env: the env (unwrapped)
    :param spec: what the policy was trained on
    :return: the observation to give the policy (``observe()`` it each decision)
    :raises ConfigError: one line, on any mismatch
    """
    for key, trained in spec.trained.items():
        here = env.config.get(key)
        if trained != here:
            raise ConfigError(f"policy {spec.policy} was trained with highway.{key} = {trained}; this env has {here}")
    options = dict(spec.options)
    if options.get("order", "sorted") != "sorted":
        raise ConfigError(f"policy {spec.policy}: only sorted observations are supported "
                          f"(got order = {options['order']!r})")
    observer: FastKinematicObservation | ResizedCamera
    try:
        if spec.kind == "Camera":
            cam = spec.camera
            observer = ResizedCamera(env, (int(cam.get("width_px", 128)), int(cam.get("height_px", 72))),
                                     depth=bool(options.get("depth", False)))
        elif spec.kind in ("Kinematics", "OverlayKinematics"):
            cls = OverlayKinematics if spec.kind == "OverlayKinematics" else FastKinematicObservation
            observer = cls(env, **options)
            observer.names_from = f"policy {spec.policy}: its metadata's observation"
            observer.check_ranges = False  # an unused range it was trained with does no harm
        else:
            raise ConfigError(f"policy {spec.policy}: unknown observation type {spec.kind!r} in its metadata")
    except (TypeError, ValueError) as err:
        raise ConfigError(f"policy {spec.policy}: its metadata's observation or action settings: {err}") from None
    space = observer.space()
    if not _same_space(space, spec.space):
        raise ConfigError(f"policy {spec.policy} was trained on observations {spec.space}, but "
                          f"this env gives {space} (another observation setting, vehicles_count or camera size)")
    return observer


def _same_space(a: Any, b: Any) -> bool:
    """Whether the env's space ``a`` is the model's ``b`` (stable-baselines3 stores images
    channels-first and transposes channels-last observations itself)."""
    from stable_baselines3.common.preprocessing import (  # lazy: stable-baselines3 (~1.3 s)
        is_image_space,
        is_image_space_channels_first,
    )
    from stable_baselines3.common.vec_env import VecTransposeImage  # lazy: stable-baselines3 (~1.3 s)

    if isinstance(a, spaces.Dict) and isinstance(b, spaces.Dict):
        return a.keys() == b.keys() and all(_same_space(a[k], b[k]) for k in a.keys())
    if isinstance(a, spaces.Box) and is_image_space(a) and not is_image_space_channels_first(a):
        a = VecTransposeImage.transpose_space(a)
    return type(a) is type(b) and getattr(a, "shape", None) == getattr(b, "shape", None) and \
        getattr(a, "dtype", None) == getattr(b, "dtype", None)

"""What every driver of the ego is: the :class:`Driver` base and the pedal limits of the
``Driver`` action ``[acceleration m/s^2, lane request]`` all of them drive through."""

from __future__ import annotations

from typing import Any

import numpy as np

ACCEL_MIN_MPS2 = -8.0
"""Hardest braking a driver can command [m/s^2] (about 0.8 g, a full stop on dry asphalt)"""
ACCEL_MAX_MPS2 = 3.0
"""Strongest acceleration a driver can command [m/s^2]"""


class Driver:
    """Base of the ego's drivers.

    :param name: the driver's name (its file's stem)
    """

    needs_camera = False
    """The driver looks at the overlay (ADAS condition)"""

    def __init__(self, name: str) -> None:
        self.name = name

    def params(self) -> dict[str, Any]:
        """The driver's resolved parameters (recorded in each trial's metadata)."""
        return {}

    def config_overrides(self) -> dict[str, Any]:
        """What the driver needs in the env's configuration, whatever the condition (a camera
        of a given size for a vision policy); merged over the condition's settings."""
        return {}

    def reset(self, env: Any, seed: int) -> None:
        """Start a trial.

        :param env: the env (unwrapped)
        :param seed: seed of the driver's own randomness
        """

    def act(self, env: Any, obs: Any, info: dict[str, Any]) -> np.ndarray:
        """One decision: ``[acceleration m/s^2, lane request -1..1]``."""
        raise NotImplementedError

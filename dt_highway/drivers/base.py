"""What every driver of the ego is: the :class:`Driver` base and the pedal limits of the
``Driver`` action ``[acceleration m/s^2, lane request]`` all of them drive through.

A driver declares what it looks at (:attr:`Driver.senses`, a
:class:`~dt_highway.drivers.perception.SenseRequest`) and acts on a
:class:`~dt_highway.drivers.perception.Perception` holding just that: it never receives the
env, its ``info`` or any ground truth. The harness (a study trial, an evaluation) asks the
env side for the perception (:class:`~dt_highway.env.seat.DriverSeat`) and passes it::

    seat = DriverSeat(env.unwrapped, driver.senses)
    driver.reset(seed)
    action = driver.act(seat.perceive())
"""

from __future__ import annotations

from typing import Any

import numpy as np

from dt_highway.agent_config import ACCEL_MAX_MPS2, ACCEL_MIN_MPS2  # noqa: F401 - re-exported: the Driver action's limits
from dt_highway.drivers.perception import Perception, SenseRequest


class Driver:
    """Base of the ego's drivers.

    :param name: the driver's name (its file's stem)
    """

    senses: SenseRequest = SenseRequest()
    """What the driver looks at: the env side fills only these parts of its perception"""

    def __init__(self, name: str) -> None:
        self.name = name

    def params(self) -> dict[str, Any]:
        """The driver's resolved parameters (recorded in each trial's metadata).

        :return: the parameters by name (none for the base class)
        """
        return {}

    def config_overrides(self) -> dict[str, Any]:
        """What the driver needs in the env's configuration, whatever the condition (a camera
        of a given size for a vision policy); merged over the condition's settings.

        :return: the env settings to merge, as a nested dict (none for the base class)
        """
        return {}

    def reset(self, seed: int) -> None:
        """Start a trial.

        :param seed: seed of the driver's own randomness
        """

    def act(self, perception: Perception) -> np.ndarray:
        """One decision: ``[acceleration m/s^2, lane request -1..1]``.

        :param perception: what the driver perceives now (the parts :attr:`senses` asks for)
        :return: the action ``[acceleration m/s^2, lane request -1..1]``
        """
        raise NotImplementedError

"""Drivers of the ego: scripted (IDM, human-like, random) from ``agents/*.toml``.

A driver file names its ``kind`` and its parameters; anything left out keeps the default
of :class:`~dt_highway.agent_config.HumanParams` / ``IDMParams`` / ``RandomParams`` (the
driver files' models, with the other configuration models)::

    kind = "human"
    reaction_time_s = 1.0
    [idm]
    desired_speed_mps = 27.0

Trained policies (``agents/<name>.zip``, :mod:`dt_highway.rl`) load through the same
:func:`load_driver`; their training configs (``kind = "rl"``) are not drivers themselves.

Every driver declares what it looks at (``Driver.senses``, a :class:`SenseRequest`) and acts
on a :class:`Perception`: never on the env, its ``info`` or any ground truth
(:class:`~dt_highway.env.seat.DriverSeat` makes the perception on the env side).
"""

from __future__ import annotations

from dt_highway.drivers.base import ACCEL_MAX_MPS2, ACCEL_MIN_MPS2, Driver
from dt_highway.drivers.files import KINDS, load_driver, make_driver
from dt_highway.drivers.idm import IDMParams, idm_accel
from dt_highway.drivers.menus import AssistedMenu, DiscreteMenu
from dt_highway.drivers.perception import (
    Mark,
    ObservationSpec,
    OwnState,
    Perception,
    Seen,
    SenseRequest,
    Surroundings,
)
from dt_highway.drivers.scripted import (
    HumanDriver,
    HumanParams,
    IDMDriver,
    RandomDriver,
)

__all__ = [
    "ACCEL_MAX_MPS2", "ACCEL_MIN_MPS2", "KINDS", "AssistedMenu", "DiscreteMenu", "Driver", "HumanDriver", "HumanParams",
    "IDMDriver", "IDMParams", "Mark", "ObservationSpec", "OwnState", "Perception", "RandomDriver", "Seen",
    "SenseRequest", "Surroundings", "idm_accel", "load_driver", "make_driver",
]

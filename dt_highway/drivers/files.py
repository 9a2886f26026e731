"""Driver files: ``agents/<name>.toml`` (scripted drivers) and ``agents/<name>.zip`` (trained
policies), turned into :class:`~dt_highway.drivers.base.Driver` objects."""


from __future__ import annotations

from pathlib import Path
from typing import Any

from dt_highway.agent_config import DRIVER_KINDS, HumanDriverFile, IDMDriverFile, parse_driver_file
from dt_highway.config import ConfigError, find_file, read_toml
from dt_highway.drivers.base import Driver
from dt_highway.drivers.policy import load_policy
from dt_highway.drivers.scripted import HumanDriver, IDMDriver, RandomDriver

KINDS = DRIVER_KINDS


def make_driver(tree: dict[str, Any], name: str = "driver") -> Driver:
    """A driver from a parsed driver file (validated by :func:`~dt_highway.agent_config.parse_driver_file`).

    :param tree: the file's contents (``kind`` and parameters)
    :param name: the driver's name
    :return: the scripted driver (human-like, IDM or random, as ``kind`` says)
    :raises ConfigError: on an unknown kind, key or bad value
    """
    spec = parse_driver_file(tree)
    if isinstance(spec, HumanDriverFile):
        return HumanDriver(name, spec.params())
    if isinstance(spec, IDMDriverFile):
        return IDMDriver(name, spec.idm)
    return RandomDriver(name, spec.params())


def load_driver(path: str | Path) -> Driver:
    """A driver from its file: ``agents/<name>.toml`` (scripted) or ``agents/<name>.zip`` (a trained
    policy; a pickle: load only files you trust).

    ``agents/NAME`` or a bare ``NAME`` missing here is read from the checkout's ``agents/``
    (:func:`~dt_highway.config.find_file`).

    :param path: the driver file (``.toml`` or ``.zip``), or a name under ``agents/``
    :return: the driver, named after the file's stem
    :raises ConfigError: on a missing or unreadable file, or bad contents
    """
    p = Path(find_file(path, "agents"))
    if p.suffix == ".zip":
        return load_policy(p)
    tree = read_toml(p, "driver file")
    try:
        return make_driver(tree, p.stem)
    except ConfigError as err:
        raise ConfigError(f"{p}: {err}") from None

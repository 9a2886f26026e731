"""Driver files: ``agents/<name>.toml`` (scripted drivers) and ``agents/<name>.zip`` (trained
policies), turned into :class:`~dt_highway.drivers.base.Driver` objects."""


from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

from dt_highway.config import ConfigError, read_toml
from dt_highway.drivers.base import Driver
from dt_highway.drivers.idm import IDMParams
from dt_highway.drivers.scripted import (
    HumanDriver,
    HumanParams,
    IDMDriver,
    RandomDriver,
)

KINDS = ("human", "idm", "random")


def _build(cls: Any, tree: dict[str, Any], where: str) -> Any:
    """A dataclass from a TOML table: unknown keys, wrong types and negative numbers refused."""
    fields = {f.name: f for f in dataclasses.fields(cls)}
    kwargs: dict[str, Any] = {}
    for key, value in tree.items():
        if key not in fields:
            raise ConfigError(f"unknown key '{where}{key}' (allowed here: {', '.join(sorted(fields))})")
        default = getattr(cls(), key)
        if dataclasses.is_dataclass(default):
            if not isinstance(value, dict):
                raise ConfigError(f"'{where}{key}' must be a table")
            kwargs[key] = _build(type(default), value, f"{where}{key}.")
        elif isinstance(default, bool):
            if not isinstance(value, bool):
                raise ConfigError(f"'{where}{key}' must be true or false (got {value!r})")
            kwargs[key] = value
        else:
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
                raise ConfigError(f"'{where}{key}' must be a finite number >= 0 (got {value!r})")
            kwargs[key] = float(value)
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as err:
        raise ConfigError(f"{where or 'driver'}: {err}") from None


def make_driver(tree: dict[str, Any], name: str = "driver") -> Driver:
    """A driver from a parsed driver file.

    :param tree: the file's contents (``kind`` and parameters)
    :param name: the driver's name
    :raises ConfigError: on an unknown kind, key or bad value
    """
    tree = dict(tree)
    kind = tree.pop("kind", None)
    if kind == "rl":
        raise ConfigError("this is an RL training config: train it (dt-highway train --config FILE --out "
                          "agents/NAME.zip) and drive with the .zip")
    if kind not in KINDS:
        raise ConfigError(f"a driver file needs kind = one of {', '.join(repr(k) for k in KINDS)} (got {kind!r})")
    if kind == "human":
        params = _build(HumanParams, tree, "")
        if params.idm.desired_speed_mps <= 0:
            raise ConfigError("'idm.desired_speed_mps' must be > 0")
        return HumanDriver(name, params)
    if kind == "idm":
        idm = _build(IDMParams, tree.pop("idm", {}), "idm.")
        if tree:
            raise ConfigError(f"unknown key '{sorted(tree)[0]}' (allowed here: idm, kind)")
        if idm.desired_speed_mps <= 0:
            raise ConfigError("'idm.desired_speed_mps' must be > 0")
        return IDMDriver(name, idm)
    allowed = {"accel_min_mps2", "accel_max_mps2", "lane_change_prob"}
    for key, value in tree.items():
        if key not in allowed:
            raise ConfigError(f"unknown key '{key}' (allowed here: {', '.join(sorted(allowed))}, kind)")
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ConfigError(f"'{key}' must be a finite number (got {value!r})")
    d = RandomDriver(name, **{k: float(v) for k, v in tree.items()})
    if not d.accel_min_mps2 < d.accel_max_mps2 or not 0 <= d.lane_change_prob <= 1:
        raise ConfigError("a random driver needs accel_min_mps2 < accel_max_mps2 and 0 <= lane_change_prob <= 1")
    return d


def load_driver(path: str | Path) -> Driver:
    """A driver from its file: ``agents/<name>.toml`` (scripted) or ``agents/<name>.zip`` (a trained
    policy; a pickle: load only files you trust).

    :raises ConfigError: on a missing or unreadable file, or bad contents
    """
    p = Path(path)
    if p.suffix == ".zip":
        from dt_highway.drivers.policy import load_policy

        return load_policy(p)
    tree = read_toml(p, "driver file")
    try:
        return make_driver(tree, p.stem)
    except ConfigError as err:
        raise ConfigError(f"{p}: {err}") from None

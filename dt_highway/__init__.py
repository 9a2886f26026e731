"""dt-highway: a Gymnasium highway environment (extending highway-env) with a cloud digital
twin that tags aggressive drivers, for human-in-the-loop and agent studies of
connected-vehicle ADAS.

``import dt_highway`` registers ``dt-highway-v0``; in a subprocess use the
``"dt_highway:dt-highway-v0"`` id form so that the child imports (and registers) it too.

The package's names below are imported when first used (PEP 562), so that ``import dt_highway``
and ``dt-highway --help`` do not pay for highway-env, matplotlib and scipy (about 2 s) before
they are needed; ``gym.make("dt-highway-v0")`` imports the env.
"""

from __future__ import annotations

import importlib
import pkgutil
from typing import TYPE_CHECKING, Any

import gymnasium as gym

from dt_highway._version import __version__
from dt_highway.errors import ConfigError

ENV_ID = "dt-highway-v0"
"""The Gymnasium id of the env, registered on ``import dt_highway``"""

if TYPE_CHECKING:
    from dt_highway.config import DTConfig, load_config
    from dt_highway.env import DTHighwayEnv
    from dt_highway.metrics.trial_log import Trial, load_trial

_LAZY = {"DTConfig": "dt_highway.config", "load_config": "dt_highway.config",
         "DTHighwayEnv": "dt_highway.env", "Trial": "dt_highway.metrics.trial_log",
         "load_trial": "dt_highway.metrics.trial_log"}
"""Each public name imported on first use, by the module that defines it"""

if ENV_ID not in gym.registry:
    # Without gymnasium's passive checker: the env checks its own resets, actions and observations (one-line
    # errors), and gymnasium 1.4's checker breaks every later step of an env whose first reset was refused
    # (its unpack of the data it never got raises TypeError while the simulation goes on). Asked for
    # (gym.make(..., disable_env_checker=False)), it is there; gymnasium's check_env passes on the env.
    gym.register(id=ENV_ID, entry_point="dt_highway.env:DTHighwayEnv", disable_env_checker=True)


def __getattr__(name: str) -> Any:
    """A public name of the package, or one of its modules (``dt_highway.env`` after ``import dt_highway``, as
    when the package imported the env itself), imported on first use (PEP 562)."""
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
    elif name in _submodules():
        value = importlib.import_module(f"{__name__}.{name}")
    else:
        raise AttributeError(f"module '{__name__}' has no attribute '{name}'")
    globals()[name] = value
    return value


def _submodules() -> set[str]:
    """The package's modules and sub-packages by name (``env``, ``config``...)."""
    return {m.name for m in pkgutil.iter_modules(__path__)}


def __dir__() -> list[str]:
    return sorted({*globals(), *_LAZY, *_submodules()})


__all__ = ["ConfigError", "DTConfig", "DTHighwayEnv", "ENV_ID", "Trial", "load_config", "load_trial", "__version__"]

"""dt-highway: a Gymnasium highway environment (extending highway-env) with a cloud digital
twin that tags aggressive drivers, for human-in-the-loop and agent studies of
connected-vehicle ADAS.

``import dt_highway`` registers ``dt-highway-v0``; in a subprocess use the
``"dt_highway:dt-highway-v0"`` id form so that the child imports (and registers) it too.
"""

from __future__ import annotations

import gymnasium as gym

from dt_highway._version import __version__
from dt_highway.config import ConfigError, DTConfig, load_config
from dt_highway.env import ENV_ID, DTHighwayEnv
from dt_highway.metrics.trial_log import Trial, load_trial

if ENV_ID not in gym.registry:
    # Without gymnasium's passive checker: the env checks its own resets, actions and observations (one-line
    # errors), and gymnasium 1.4's checker breaks every later step of an env whose first reset was refused
    # (its unpack of the data it never got raises TypeError while the simulation goes on). Asked for
    # (gym.make(..., disable_env_checker=False)), it is there; gymnasium's check_env passes on the env.
    gym.register(id=ENV_ID, entry_point="dt_highway.env:DTHighwayEnv", disable_env_checker=True)

__all__ = ["ConfigError", "DTConfig", "DTHighwayEnv", "ENV_ID", "Trial", "load_config", "load_trial", "__version__"]

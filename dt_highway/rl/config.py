"""Training configuration of an RL driver (``agents/<name>.toml``, ``kind = "rl"``).

The model, :class:`~dt_highway.agent_config.TrainConfig`, lives with the other configuration
models in :mod:`dt_highway.agent_config` (its docstring describes the file); this module
keeps the names importable from :mod:`dt_highway.rl`.
"""

from __future__ import annotations

from dt_highway.agent_config import (
    ALGORITHMS,
    OBSERVATIONS,
    VISION_CAMERA,
    TrainConfig,
    load_train_config,
    parse_train_config,
)

__all__ = ["ALGORITHMS", "OBSERVATIONS", "VISION_CAMERA", "TrainConfig", "load_train_config", "parse_train_config"]

"""RL drivers with stable-baselines3: training configs and training (``dt-highway train``).
A trained policy drives as :class:`~dt_highway.drivers.policy.PolicyDriver`; any driver is
evaluated by :mod:`dt_highway.evaluation.rl` (``dt-highway evaluate``).

Model files (``.zip``) are pickles: load only the ones you trust.
"""

from dt_highway.rl.config import (
    ALGORITHMS,
    OBSERVATIONS,
    TrainConfig,
    load_train_config,
)

__all__ = ["ALGORITHMS", "OBSERVATIONS", "TrainConfig", "load_train_config"]

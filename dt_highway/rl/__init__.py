"""RL drivers with stable-baselines3: training configs, training, trained policies as drivers,
and the evaluation of any driver (``dt-highway train``, ``dt-highway evaluate``).

Model files (``.zip``) are pickles: load only the ones you trust.
"""

from dt_highway.rl.config import (
    ALGORITHMS,
    OBSERVATIONS,
    TrainConfig,
    load_train_config,
)

__all__ = ["ALGORITHMS", "OBSERVATIONS", "TrainConfig", "load_train_config"]

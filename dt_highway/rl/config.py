"""Training configuration of an RL driver (``agents/<name>.toml``, ``kind = "rl"``).

A training file names the algorithm, the observation setting and the scenario; everything
left out keeps the defaults below. Example (``agents/ppo-baseline.toml``)::

    kind = "rl"
    algorithm = "PPO"
    observation = "kinematics"      # kinematics | adas | vision
    scenario = "envs/highway-trial.toml"
    timesteps = 200000
    [hyperparameters]               # passed to the stable-baselines3 algorithm
    learning_rate = 0.0003

Observation settings:

* ``kinematics`` (baseline): highway-env's Kinematics observation of the nearest vehicles
  (``presence, x, y, vx, vy``, relative to the ego, normalised).
* ``adas`` (ADAS-aware): the same plus ``marked``, 1 where the ADAS overlay shows an
  "aggressive driver" marker on that car (:class:`~dt_highway.env.OverlayKinematics`):
  the twin's verdict as delivered through the fusion and the overlay, never ground truth.
  It trains in the ADAS condition (camera and fusion on).
* ``vision``: the ego camera's ``rgb`` image (and ``depth`` with ``depth = true``) for a CNN
  policy (stable-baselines3's ``MultiInputPolicy``); the camera is made small for it.

Actions (``action``): the ``DiscreteDriver`` menu
(:class:`~dt_highway.env.actions.DiscreteDriverAction`): ``pedals``, keep the lane with
one of ``accels_mps2`` or ask for one lane left or right; ``assisted``
(:class:`~dt_highway.env.assisted.AssistedMenu`), choose one of ``speeds_mps`` as desired
speed or a lane change (taken when safe), the Intelligent Driver Model keeping the gap.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from dt_highway.conditions import condition_config
from dt_highway.config import ConfigError, DTConfig, load_config, read_toml
from dt_highway.env.actions import (
    ACCEL_MAX_MPS2,
    ACCEL_MIN_MPS2,
    DEFAULT_DISCRETE_ACCELS_MPS2,
)
from dt_highway.env.assisted import DEFAULT_SPEEDS_MPS

OBSERVATIONS = ("kinematics", "adas", "vision")
ALGORITHMS = ("PPO", "DQN")
VISION_CAMERA = {"width_px": 128, "height_px": 72}
"""Camera size of the vision setting unless the scenario or ``set`` says otherwise [px]"""


class TrainConfig(BaseModel):
    """What ``dt-highway train`` trains (see the module docstring)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    kind: Literal["rl"] = "rl"
    algorithm: Literal["PPO", "DQN"] = Field("PPO", description="stable-baselines3 algorithm")
    observation: Literal["kinematics", "adas", "vision"] = Field("kinematics", description="observation setting")
    depth: bool = Field(False, description="vision: also the depth image")
    scenario: str = Field("envs/highway-trial.toml", description="scenario file the policy trains on")
    set: list[str] = Field(default_factory=list, description="dotted.key=value overrides of the scenario")
    timesteps: int = Field(200_000, gt=0, description="env steps to train for [-]")
    n_envs: int = Field(2, ge=1, le=64, description="parallel envs (SubprocVecEnv when > 1) [-]")
    seed: int = Field(0, ge=0, description="seed of the model and of the training envs")
    vehicles_count: int = Field(7, ge=2, le=30, description="kinematics/adas: observed vehicles, ego included [-]")
    see_behind: bool = Field(True, description="kinematics/adas: observe vehicles behind too")
    action: Literal["pedals", "assisted"] = Field(
        "pedals", description="pedals: choose accelerations; assisted: choose a desired speed or a lane, IDM keeps the gap"
    )
    accels_mps2: list[float] = Field(default_factory=lambda: list(DEFAULT_DISCRETE_ACCELS_MPS2),
                                     description="pedals: accelerations of the action menu [m/s^2]")
    speeds_mps: list[float] = Field(default_factory=lambda: list(DEFAULT_SPEEDS_MPS),
                                    description="assisted: desired speeds of the action menu [m/s]")
    eval_every_steps: int = Field(20_000, gt=0, description="evaluate on held-out seeds this often [steps]")
    eval_episodes: int = Field(4, ge=1, description="episodes per evaluation [-]")
    eval_seed: int = Field(100_000, ge=0, description="first seed of the evaluation episodes")
    checkpoint_every_steps: int = Field(50_000, gt=0, description="save a checkpoint this often [steps]")
    hyperparameters: dict[str, Any] = Field(default_factory=dict, description="keyword arguments of the algorithm")
    policy_kwargs: dict[str, Any] = Field(default_factory=dict, description="policy_kwargs of the algorithm")

    @model_validator(mode="after")
    def _menus(self) -> TrainConfig:
        if not self.accels_mps2 or not all(ACCEL_MIN_MPS2 <= a <= ACCEL_MAX_MPS2 for a in self.accels_mps2):
            raise ValueError(f"accels_mps2 must be a non-empty list within [{ACCEL_MIN_MPS2}, {ACCEL_MAX_MPS2}] m/s^2")
        if not self.speeds_mps or not all(0 < v <= 45 for v in self.speeds_mps):
            raise ValueError("speeds_mps must be a non-empty list of speeds in (0, 45] m/s")
        return self

    def env_config(self, condition: str | None = None) -> DTConfig:
        """The env configuration of this policy: its scenario and overrides, its observation
        and action, in the condition it trains in (or ``condition``: ``baseline``/``adas``).

        :raises ConfigError: on a bad scenario or override
        """
        condition = condition or ("adas" if self.observation == "adas" else "baseline")
        extra = condition_config(condition)
        extra["highway"] = {"observation": self.observation_config(), "action": self.action_config()}
        if self.observation == "vision":
            extra["camera"] = {**VISION_CAMERA, "enabled": True}
        return load_config(self.scenario, list(self.set), extra)

    def observation_config(self) -> dict[str, Any]:
        """The ``highway.observation`` table of this setting."""
        if self.observation == "vision":
            return {"type": "Camera", "depth": self.depth}
        kind = "OverlayKinematics" if self.observation == "adas" else "Kinematics"
        return {"type": kind, "vehicles_count": self.vehicles_count, "see_behind": self.see_behind}

    def action_config(self) -> dict[str, Any]:
        """The ``highway.action`` table: the discrete menu over the Driver action."""
        if self.action == "assisted":
            return {"type": "DiscreteDriver", "assist": True, "speeds_mps": list(self.speeds_mps)}
        return {"type": "DiscreteDriver", "accels_mps2": list(self.accels_mps2)}


def parse_train_config(tree: dict[str, Any], where: str = "training config") -> TrainConfig:
    """Validate a parsed training file.

    :raises ConfigError: one line naming the key and what is allowed
    """
    try:
        return TrainConfig.model_validate(tree)
    except ValidationError as err:
        e = err.errors()[0]
        key = ".".join(str(p) for p in e["loc"]) or "(top level)"
        raise ConfigError(f"{where}: '{key}': {e['msg']}") from None


def load_train_config(path: str | Path) -> TrainConfig:
    """Read and validate ``agents/<name>.toml`` (``kind = "rl"``).

    :raises ConfigError: on a missing or unreadable file, or bad contents
    """
    p = Path(path)
    tree = read_toml(p, "training config")
    if tree.get("kind") != "rl":
        raise ConfigError(f"{p}: a training config needs kind = \"rl\" (got {tree.get('kind')!r}; "
                          f"scripted drivers are not trained)")
    return parse_train_config(tree, str(p))

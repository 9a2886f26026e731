"""Train an RL driver with stable-baselines3 (``dt-highway train``).

The envs are ``gym.make("dt_highway:dt-highway-v0", config=...)`` (the id form that
``SubprocVecEnv`` children can import), each wrapped in ``Monitor``; evaluation runs on a
separate env with held-out seeds every ``eval_every_steps``; checkpoints and a CSV log of
stable-baselines3's training statistics go to ``<out>.d/``; TensorBoard logs optionally.
Beside the model ``<out>.zip`` goes ``<out>.json``: the training configuration, the
resolved env configuration, the package versions and the evaluations, which is what
:func:`~dt_highway.rl.policy.load_policy` reads to drive with it.
"""

from __future__ import annotations

import json
import math
import os
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

from dt_highway.config import ConfigError
from dt_highway.rl.config import TrainConfig

ENV_ID = "dt_highway:dt-highway-v0"


def sidecar_path(model_path: str | Path) -> Path:
    """Where the metadata of a policy lives: ``agents/x.zip`` -> ``agents/x.json``."""
    return Path(model_path).with_suffix(".json")


def versions() -> dict[str, str]:
    """Versions of the packages a policy file depends on."""
    from importlib.metadata import PackageNotFoundError, version

    out = {}
    for pkg in ("dt-highway", "stable-baselines3", "torch", "gymnasium", "highway-env", "numpy"):
        try:
            out[pkg] = version(pkg)
        except PackageNotFoundError:
            out[pkg] = "unknown"
    return out


def _make_env(env_config: dict[str, Any], seed: int):  # noqa: ANN202 - a factory for the vec env
    def build() -> Any:
        import gymnasium as gym
        from stable_baselines3.common.monitor import Monitor

        env = gym.make(ENV_ID, config=env_config)
        env.reset(seed=seed)
        return Monitor(env)

    return build


def _policy_name(cfg: TrainConfig) -> str:
    return "MultiInputPolicy" if cfg.observation == "vision" else "MlpPolicy"


def build_model(cfg: TrainConfig, env: Any, tensorboard_dir: str | None = None) -> Any:
    """The stable-baselines3 model of a training configuration.

    :raises ConfigError: on hyperparameters the algorithm does not take
    """
    import stable_baselines3 as sb3

    algo = getattr(sb3, cfg.algorithm)
    kwargs = dict(cfg.hyperparameters)
    if cfg.policy_kwargs:
        kwargs["policy_kwargs"] = dict(cfg.policy_kwargs)
    try:
        return algo(_policy_name(cfg), env, seed=cfg.seed, device="cpu", verbose=0, tensorboard_log=tensorboard_dir,
                    **kwargs)
    except (TypeError, ValueError, AssertionError) as err:
        raise ConfigError(f"{cfg.algorithm} does not accept these hyperparameters or policy_kwargs: {err}") from None


def train(cfg: TrainConfig, out: str | Path, timesteps: int | None = None, n_envs: int | None = None,
          tensorboard_dir: str | None = None, progress: bool = True) -> dict[str, Any]:
    """Train a policy and save it with its metadata.

    :param cfg: training configuration
    :param out: model file to write (``.zip``)
    :param timesteps: override of ``cfg.timesteps``
    :param n_envs: override of ``cfg.n_envs``
    :param tensorboard_dir: write TensorBoard logs there (needs the ``tensorboard`` package)
    :param progress: show a progress bar
    :return: the metadata written beside the model
    :raises ConfigError: on a bad configuration, output path or missing TensorBoard
    """
    from stable_baselines3.common.callbacks import CallbackList, CheckpointCallback, EvalCallback
    from stable_baselines3.common.logger import configure
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    out = Path(out)
    if out.suffix != ".zip":
        raise ConfigError(f"--out must name a .zip file (got {out})")
    if tensorboard_dir is not None:
        try:
            import tensorboard  # noqa: F401
        except ImportError:
            raise ConfigError("--tensorboard needs the tensorboard package: pip install 'dt-highway[tensorboard]'") from None
    if timesteps is not None:
        cfg = cfg.model_copy(update={"timesteps": int(timesteps)})
    if n_envs is not None:
        cfg = cfg.model_copy(update={"n_envs": int(n_envs)})
    if cfg.timesteps <= 0 or not 1 <= cfg.n_envs <= 64:
        raise ConfigError(f"timesteps must be > 0 and n_envs in 1..64 (got {cfg.timesteps}, {cfg.n_envs})")
    env_cfg = cfg.env_config()  # ConfigError on a bad scenario or override, before any process starts
    if cfg.observation != "vision":
        import torch

        torch.set_num_threads(1)  # a small MLP: one thread is fastest, and leaves the other cores to the envs
    env_dict = env_cfg.to_dict()
    work = out.with_suffix(".d")
    work.mkdir(parents=True, exist_ok=True)
    factories = [_make_env(env_dict, cfg.seed + i) for i in range(cfg.n_envs)]
    venv = SubprocVecEnv(factories, start_method="spawn") if cfg.n_envs > 1 else DummyVecEnv(factories)
    eval_env = DummyVecEnv([_make_env(env_dict, cfg.eval_seed)])
    try:
        venv.seed(cfg.seed)
        eval_env.seed(cfg.eval_seed)
        model = build_model(cfg, venv, tensorboard_dir)
        model.set_logger(configure(str(work), ["csv"] + (["tensorboard"] if tensorboard_dir else [])))
        per_env = max(1, cfg.eval_every_steps // cfg.n_envs)
        evaluator = EvalCallback(eval_env, n_eval_episodes=cfg.eval_episodes, eval_freq=per_env,
                                 log_path=str(work), best_model_save_path=str(work), deterministic=True, verbose=0)
        callbacks = [evaluator, CheckpointCallback(max(1, cfg.checkpoint_every_steps // cfg.n_envs), str(work),
                                                   name_prefix="checkpoint")]
        if progress:
            callbacks.append(_Progress(cfg.timesteps))
        t0 = time.perf_counter()
        interrupted = False
        try:
            with warnings.catch_warnings():  # subprocess training envs, an in-process evaluation env: intended
                warnings.filterwarnings("ignore", message="Training and eval env are not of the same type")
                model.learn(cfg.timesteps, callback=CallbackList(callbacks))
        except KeyboardInterrupt:
            interrupted = True  # keep what was learned: saved below, marked as interrupted
        wall = time.perf_counter() - t0
        tmp = out.with_name(out.stem + ".tmp.zip")
        model.save(tmp)
        os.replace(tmp, out)
    finally:
        venv.close()
        eval_env.close()
    evals = []
    if evaluator.evaluations_timesteps:
        for t, r, n in zip(evaluator.evaluations_timesteps, evaluator.evaluations_results,
                           evaluator.evaluations_length):
            evals.append({"timesteps": int(t), "mean_return": float(np.mean(r)), "mean_length": float(np.mean(n))})
    meta = {
        "format": "dt-highway policy 1",
        "algorithm": cfg.algorithm,
        "observation": cfg.observation,
        "train_config": cfg.model_dump(),
        "env_config": env_dict,
        "versions": versions(),
        "timesteps_done": int(model.num_timesteps),
        "interrupted": interrupted,
        "wall_time_s": round(wall, 1),
        "steps_per_s": round(model.num_timesteps / wall, 1) if wall > 0 else math.nan,
        "evaluations": evals,
        "checkpoints": str(work),
    }
    sidecar = sidecar_path(out)
    tmp = sidecar.with_name(sidecar.name + ".tmp")
    tmp.write_text(json.dumps(meta, indent=2, default=str), encoding="utf-8")
    os.replace(tmp, sidecar)
    return meta


class _Progress(BaseCallback):
    """A tqdm bar over the training steps (stable-baselines3's own bar needs ``rich``)."""

    def __init__(self, total: int) -> None:
        super().__init__()
        self.total = total

    def _on_training_start(self) -> None:
        from tqdm.auto import tqdm

        self.bar = tqdm(total=self.total, unit="step", desc="training", dynamic_ncols=True)

    def _on_step(self) -> bool:
        n = self.training_env.num_envs
        if self.bar.n + n > self.bar.total:  # the algorithm finishes its last rollout
            self.bar.total = self.bar.n + n
        self.bar.update(n)
        return True

    def _on_training_end(self) -> None:
        self.bar.close()

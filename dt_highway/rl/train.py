"""Train an RL driver with stable-baselines3 (``dt-highway train``).

The envs are ``gym.make("dt_highway:dt-highway-v0", config=...)`` (the id form that
``SubprocVecEnv`` children can import), each wrapped in ``Monitor`` and given a new seed at
every episode (a fresh driver population and twin, as a study trial gets): env ``i`` of
``n`` plays seeds ``seed * 1_000_000 + i + k n``. They run :func:`lean_env_config`'s configuration
(what the observation and the reward do not read, off: the same observations and rewards, less
work), ``n > 1`` of them as ``SubprocVecEnv`` worker processes of one torch and one OpenCV thread
each (``dt-highway bench train`` measures both paths). Every ``eval_every_steps`` the policy drives
``eval_episodes`` held-out episodes (seeds ``eval_seed ..``, the same ones each time), and
the best one is kept. Checkpoints and a CSV log of stable-baselines3's statistics go to
``<out>.d/``; TensorBoard logs optionally. Beside the model ``<out>.zip`` goes
``<out>.json``: the training configuration, the resolved env configuration, the package
versions, the evaluations and the model file's SHA-256, which is what
:func:`~dt_highway.drivers.policy.load_policy` reads to drive with it; and the training curve,
``<out>.curve.csv`` and ``.curve.png`` (:mod:`dt_highway.rl.curves`).
"""

from __future__ import annotations

import inspect
import json
import multiprocessing
import os
import shutil
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import gymnasium as gym
import numpy as np
import stable_baselines3 as sb3
import torch
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import (
    BaseCallback,
    CallbackList,
    CheckpointCallback,
)
from stable_baselines3.common.logger import Logger, make_output_format
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecEnv
from tqdm.auto import tqdm

from dt_highway.agent_config import RewardConfig, parse_train_config
from dt_highway.config import ConfigError, DTConfig, merge
from dt_highway.interrupts import interrupted_by_user
from dt_highway.rl.config import TrainConfig
from dt_highway.rl.curves import write_curve
from dt_highway.rl.files import FORMAT, sha256, sidecar_path, versions
from dt_highway.rl.preroll import PrerollAhead, Reseed, ahead_ok
from dt_highway.rl.rewards import RewardTermsLogger, SafetyReward

ENV_ID = "dt_highway:dt-highway-v0"
VISION_DQN_BUFFER = 20_000
"""DQN's replay buffer with image observations unless ``buffer_size`` is given [transitions] (~1.5 GB)"""


def _make_env(env_config: dict[str, Any], first_seed: int, stride: int,
              reward: RewardConfig | None = None, ahead: bool = False) -> Callable[[], gym.Env]:
    """A factory of one of the vec env's envs (what ``SubprocVecEnv`` sends to its worker);
    ``reward``: the training file's reward (:class:`~dt_highway.rl.rewards.SafetyReward`; ``None``
    or highway-env's alone: the env's own reward, unwrapped); ``ahead``: in a worker process, each
    episode's start is computed ahead by a helper (:class:`~dt_highway.rl.preroll.PrerollAhead`,
    the same seeds and episodes as :class:`Reseed`; only for :func:`~dt_highway.rl.preroll.ahead_ok`
    configurations)."""

    def build() -> gym.Env:
        worker = multiprocessing.parent_process() is not None
        if worker:  # a SubprocVecEnv worker: one thread, the cores are the workers'
            torch.set_num_threads(1)
            cv2.setNumThreads(1)
        if ahead and worker:
            env: gym.Env = PrerollAhead(env_config, first_seed, stride)
        else:
            env = Reseed(gym.make(ENV_ID, config=env_config), first_seed, stride)
        if reward is not None and not reward.is_highway_only():
            env = SafetyReward(env, reward)
        return Monitor(env)

    return build


LEAN_OBSERVATION_TYPES = ("Kinematics", "OverlayKinematics")
"""Observation types whose needs :func:`lean_env_config` knows (any other keeps the whole simulation)"""


def lean_env_config(env_config: DTConfig) -> tuple[DTConfig, list[str]]:
    """The configuration the training envs run: the parts of the simulation that neither the
    policy's observation nor the reward reads, switched off (``dt-highway train``'s cheap path).

    * the cloud twin (uplink, store, tagger, intention, downlink), when the observation is
      highway-env's ``Kinematics`` alone (fusion off, ``twin.in_observation`` off): data flows one
      way and nothing in the world reads the twin, so traffic, observations and rewards are the same;
    * the twin's intention estimate, when the observation reads only the type marks
      (``OverlayKinematics`` without ``threat``, ``overlay.mode = "type"``) or the twin's tags
      (``twin.in_observation``): neither the tagger nor a type mark reads it.

    The camera, detector, fusion and overlay of the ``adas`` setting, and the safety samples the
    reward reads, run as in a study. ``tests/test_bench_train.py`` checks that observations and
    rewards are identical on seeded episodes, and ``dt-highway bench train`` checks it on each run.

    :param env_config: the env configuration of the training file (:meth:`TrainConfig.env_config`)
    :return: the configuration to train with, and what was switched off (empty: nothing)
    """
    obs = dict(env_config.highway.observation)
    kind = obs.get("type", "Kinematics")
    if kind not in LEAN_OBSERVATION_TYPES or obs.get("threat", False) or not env_config.twin.enabled:
        return env_config, []
    twin = env_config.twin
    if kind == "Kinematics" and not twin.in_observation and not env_config.fusion.enabled:
        return merge(env_config, {"twin": {"enabled": False}}), ["twin.enabled"]
    type_marks_only = kind == "Kinematics" or env_config.overlay.mode == "type"
    if type_marks_only and twin.intention.enabled:
        return merge(env_config, {"twin": {"intention": {"enabled": False}}}), ["twin.intention.enabled"]
    return env_config, []


def _policy_name(cfg: TrainConfig) -> str:
    return "MultiInputPolicy" if cfg.observation == "vision" else "MlpPolicy"


def build_model(cfg: TrainConfig, env: VecEnv) -> BaseAlgorithm:
    """The stable-baselines3 model of a training configuration.

    :param cfg: training configuration
    :param env: the vectorised training env
    :return: the model, untrained
    :raises ConfigError: on hyperparameters the algorithm does not take
    """
    algo = getattr(sb3, cfg.algorithm)
    kwargs = dict(cfg.hyperparameters)
    if isinstance(kwargs.get("train_freq"), list):  # TOML has no tuple: [4, "step"]
        kwargs["train_freq"] = tuple(kwargs["train_freq"])
    if cfg.algorithm == "DQN" and cfg.observation == "vision":
        # SB3's default replay buffer (a million transitions) would hold ~74 GB of 128x72 RGB-D pairs
        kwargs.setdefault("buffer_size", VISION_DQN_BUFFER)
    if cfg.policy_kwargs:
        kwargs["policy_kwargs"] = dict(cfg.policy_kwargs)
    try:
        return algo(_policy_name(cfg), env, seed=cfg.seed, device="cpu", verbose=0, **kwargs)
    except (TypeError, ValueError, AssertionError) as err:
        raise ConfigError(f"{cfg.algorithm} does not accept these hyperparameters or policy_kwargs: {err}") from None


def rollout_steps(cfg: TrainConfig) -> int:
    """The env steps stable-baselines3 collects between two checks of the step budget: its
    ``learn`` stops only at the end of such a chunk, so it trains a multiple of it.

    PPO (on-policy): ``n_steps`` per env times ``n_envs``; DQN (off-policy): ``train_freq``
    steps per env times ``n_envs`` (one step per env when ``train_freq`` counts episodes).

    :param cfg: training configuration
    :return: the chunk [env steps]
    """
    algo = getattr(sb3, cfg.algorithm)
    defaults = inspect.signature(algo).parameters
    try:
        if issubclass(algo, OnPolicyAlgorithm):
            return max(1, int(cfg.hyperparameters.get("n_steps", defaults["n_steps"].default))) * cfg.n_envs
        freq = cfg.hyperparameters.get("train_freq", defaults["train_freq"].default)
        if isinstance(freq, (list, tuple)):
            freq = int(freq[0]) if len(freq) == 2 and str(freq[1]) == "step" else 1
        return max(1, int(freq)) * cfg.n_envs
    except (TypeError, ValueError):  # a value the algorithm refuses (build_model says so)
        return cfg.n_envs


def round_timesteps(cfg: TrainConfig) -> tuple[TrainConfig, str | None]:
    """The configuration with ``timesteps`` rounded up to a whole number of :func:`rollout_steps`
    (what stable-baselines3 trains anyway), and the line that says so (``None``: no change).

    :param cfg: training configuration
    :return: the configuration to train, the message
    """
    chunk = rollout_steps(cfg)
    total = -(-cfg.timesteps // chunk) * chunk
    if total == cfg.timesteps:
        return cfg, None
    per = "n_steps" if issubclass(getattr(sb3, cfg.algorithm), OnPolicyAlgorithm) else "train_freq"
    message = (f"--timesteps {cfg.timesteps} rounded up to {total}: {cfg.algorithm} trains whole rollouts of {chunk} "
               f"steps ({per} {chunk // cfg.n_envs} x {cfg.n_envs} env{'s' if cfg.n_envs > 1 else ''})")
    return TrainConfig.model_validate({**cfg.model_dump(), "timesteps": total}), message


class HeldOutEval(BaseCallback):
    """Every ``every`` steps: ``episodes`` deterministic episodes on seeds ``seed ..``; keeps
    the best model (mean return) as ``<dir>/best_model.zip``.

    :param env_config: the env configuration
    :param every: period [env steps]
    :param episodes: episodes per evaluation
    :param seed: first seed
    :param directory: where the best model goes
    :param reward: the training file's reward (``None``: the env's own)
    """

    def __init__(self, env_config: dict[str, Any], every: int, episodes: int, seed: int, directory: Path,
                 reward: RewardConfig | None = None) -> None:
        super().__init__()
        self.env: gym.Env = gym.make(ENV_ID, config=env_config)
        if reward is not None and not reward.is_highway_only():
            self.env = SafetyReward(self.env, reward)
        self.every, self.episodes, self.seed, self.directory = every, episodes, seed, directory
        self.results: list[dict[str, Any]] = []
        self.best = -np.inf
        self._next = every

    def _on_step(self) -> bool:
        if self.num_timesteps >= self._next:
            self._next += self.every
            self.run()
        return True

    def run(self) -> dict[str, Any]:
        """One evaluation now; :return: its summary (also appended to ``results``)."""
        returns, lengths, crashes = [], [], 0
        for k in range(self.episodes):
            obs, _ = self.env.reset(seed=self.seed + k)
            total, n = 0.0, 0
            while True:
                action, _ = self.model.predict(obs, deterministic=True)
                obs, reward, terminated, truncated, info = self.env.step(action)
                total += float(reward)
                n += 1
                if terminated or truncated:
                    break
            returns.append(total)
            lengths.append(n)
            crashes += int(bool(info["crashed"]))  # the env's step info (the ego's own crash), not its internals
        summary = {"timesteps": int(self.num_timesteps), "mean_return": float(np.mean(returns)),
                   "mean_length": float(np.mean(lengths)), "collision_rate": crashes / self.episodes}
        self.results.append(summary)
        self.logger.record("eval/mean_return", summary["mean_return"])
        self.logger.record("eval/collision_rate", summary["collision_rate"])
        if summary["mean_return"] > self.best:
            self.best = summary["mean_return"]
            self.model.save(self.directory / "best_model.zip")
        return summary


class _Progress(BaseCallback):
    """A tqdm bar over the training steps (stable-baselines3's own bar needs ``rich``)."""

    def __init__(self, total: int) -> None:
        super().__init__()
        self.total = total

    def _on_training_start(self) -> None:
        self.bar = tqdm(total=self.total, unit="step", desc="training", dynamic_ncols=True, file=sys.stderr, leave=False)

    def _on_step(self) -> bool:
        self.bar.update(min(self.training_env.num_envs, self.bar.total - self.bar.n))  # one bar, never past its total
        return True

    def _on_training_end(self) -> None:
        self.bar.close()


def _close(venv: VecEnv) -> None:
    """Close a vec env whose workers may already be gone (Ctrl-C reaches them too)."""
    try:
        venv.close()
    except (EOFError, BrokenPipeError, ConnectionError, OSError):
        pass


def _save(model: BaseAlgorithm, out: Path, meta: dict[str, Any]) -> None:
    """Write the model, its metadata (``meta`` plus the model file's SHA-256, in ``meta`` too) and its
    training curve: the model first (as a temporary), then the metadata naming its hash, then both
    in place; the curve from the log in ``meta["checkpoints"]``."""
    tmp_model = out.with_name(out.stem + ".tmp.zip")
    model.save(tmp_model)
    meta["model_sha256"] = sha256(tmp_model)
    sidecar = sidecar_path(out)
    tmp_meta = sidecar.with_name(sidecar.name + ".tmp")
    tmp_meta.write_text(json.dumps(meta, indent=2), encoding="utf-8")
    os.replace(tmp_model, out)
    os.replace(tmp_meta, sidecar)
    try:
        write_curve(out, Path(meta["checkpoints"]) / "progress.csv")
    except ConfigError as err:  # stopped before the first rollout ended: no curve to draw
        print(f"no training curve: {err}", file=sys.stderr)


def _learn(model: BaseAlgorithm, timesteps: int, callback: CallbackList) -> bool:
    """``model.learn``, stopped by Ctrl-C (also one that arrives inside numba code, see :mod:`dt_highway.interrupts`).

    :return: whether it was interrupted (what was learned is kept)
    """
    try:
        model.learn(timesteps, callback=callback)
    except (KeyboardInterrupt, SystemError) as err:
        if not interrupted_by_user(err):
            raise
        return True
    return False


def train(cfg: TrainConfig, out: str | Path, timesteps: int | None = None, n_envs: int | None = None,
          tensorboard_dir: str | None = None, progress: bool = True, lean: bool = True) -> dict[str, Any]:
    """Train a policy and save it with its metadata and training curve.

    :param cfg: training configuration
    :param out: model file to write (``.zip``); ``<out>.json``, ``<out>.curve.csv``, ``<out>.curve.png``
        and ``<out>.d/`` go beside it
    :param timesteps: override of ``cfg.timesteps`` (both rounded up to whole rollouts, :func:`round_timesteps`,
        with a line on stderr)
    :param n_envs: override of ``cfg.n_envs``
    :param tensorboard_dir: also write TensorBoard logs there (needs the ``tensorboard`` package)
    :param progress: show a progress bar
    :param lean: train and evaluate in :func:`lean_env_config`'s configuration (same observations and
        rewards, less work; the metadata's ``env_config`` stays the full one the policy drives in,
        ``lean_switched_off`` names what was off)
    :return: the metadata written beside the model (``interrupted`` if stopped by Ctrl-C)
    :raises ConfigError: on a bad configuration, output path or missing TensorBoard
    """
    out = Path(out)
    if out.suffix != ".zip":
        raise ConfigError(f"--out must name a .zip file (got {out})")
    if tensorboard_dir is not None:
        try:
            import tensorboard  # lazy: optional extra (pip install dt-highway[tensorboard]) # noqa: F401
        except ImportError:
            raise ConfigError(
                "--tensorboard needs the tensorboard package: pip install 'dt-highway[tensorboard]'"
            ) from None
    updates = {k: int(v) for k, v in (("timesteps", timesteps), ("n_envs", n_envs)) if v is not None}
    if updates:
        cfg = parse_train_config({**cfg.model_dump(), **updates}, "training config with " + ", ".join(
            f"{k} = {v}" for k, v in updates.items()))
    env_cfg = cfg.env_config()  # ConfigError on a bad scenario or override
    env_dict = env_cfg.to_dict()
    run_cfg, switched_off = lean_env_config(env_cfg) if lean else (env_cfg, [])
    run_dict = run_cfg.to_dict()
    # the evaluation env is built here, in this process: a setting the env refuses is a
    # one-line error now, not a traceback in a worker process
    try:
        evaluator = HeldOutEval(run_dict, cfg.eval_every_steps, cfg.eval_episodes, cfg.eval_seed, out.with_suffix(".d"),
                                cfg.reward)
    except ValueError as err:
        raise ConfigError(str(err)) from None
    if cfg.observation != "vision":
        torch.set_num_threads(1)  # a small MLP: one thread is fastest, and leaves the other cores to the envs
    work = out.with_suffix(".d")
    if work.exists():
        shutil.rmtree(work)  # checkpoints of an earlier run of this file: not this run's
    work.mkdir(parents=True)
    ahead = lean and cfg.n_envs > 1 and ahead_ok(run_cfg)
    factories = [_make_env(run_dict, cfg.seed * 1_000_000 + i, cfg.n_envs, cfg.reward, ahead) for i in range(cfg.n_envs)]
    venv = SubprocVecEnv(factories, start_method="spawn") if cfg.n_envs > 1 else DummyVecEnv(factories)
    interrupted = False
    try:
        model = build_model(cfg, venv)
        cfg, rounded = round_timesteps(cfg)  # what stable-baselines3 would train anyway: said, and the bar's total
        if rounded:
            print(rounded, file=sys.stderr)
        formats = [make_output_format("csv", str(work))]
        if tensorboard_dir is not None:
            formats.append(make_output_format("tensorboard", tensorboard_dir))
        model.set_logger(Logger(str(work), formats))
        callbacks = [evaluator, CheckpointCallback(max(1, cfg.checkpoint_every_steps // cfg.n_envs), str(work),
                                                   name_prefix="checkpoint")]
        if not cfg.reward.is_highway_only():
            callbacks.append(RewardTermsLogger())
        if progress:
            callbacks.append(_Progress(cfg.timesteps))
        t0 = time.perf_counter()
        interrupted = _learn(model, cfg.timesteps, CallbackList(callbacks))  # keep what was learned if interrupted
        wall = time.perf_counter() - t0
    finally:
        _close(venv)
    if not evaluator.results or evaluator.results[-1]["timesteps"] != model.num_timesteps:
        if not interrupted:
            evaluator.run()  # the final policy's held-out numbers
    evaluator.env.close()
    meta = {
        "format": FORMAT,
        "algorithm": cfg.algorithm,
        "observation": cfg.observation,
        "action": cfg.action,
        "train_config": cfg.model_dump(),
        "env_config": env_dict,
        "lean_switched_off": switched_off,
        "preroll_ahead": ahead,
        "versions": versions(),
        "timesteps_done": int(model.num_timesteps),
        "interrupted": interrupted,
        "wall_time_s": round(wall, 1),
        "steps_per_s": round(model.num_timesteps / wall, 1) if wall > 0 else None,
        "evaluations": evaluator.results,
        "checkpoints": str(work),
    }
    _save(model, out, meta)
    return meta

"""A policy's training curve: ``<model>.curve.csv`` and ``<model>.curve.png`` beside the model.

``dt-highway train`` writes them at the end of a run, and ``dt-highway rl-curve MODEL.zip``
re-draws them from the run's stable-baselines3 log (``<model>.d/progress.csv``, the folder the
metadata's ``checkpoints`` names) and the metadata's held-out evaluations.

One CSV row per PPO rollout (every ``n_steps x n_envs`` env steps): the env steps so far, the
wall time [s], the mean return and length of the last 100 training episodes (stable-baselines3's
``rollout/ep_rew_mean`` and ``ep_len_mean``), the mean of each reward term per decision
(``reward/<term>``, from :class:`~dt_highway.rl.rewards.RewardTermsLogger`); and one row per
held-out evaluation, at the step it ran: its mean return and collision rate (the other columns
empty). The PNG plots the training return with its 10-rollout moving mean and the evaluations'
returns (top) and their collision rates (bottom).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from dt_highway.config import ConfigError
from dt_highway.rl.files import read_policy_meta

COLUMNS = {
    "time/total_timesteps": "timesteps",
    "time/time_elapsed": "wall_time_s",
    "rollout/ep_rew_mean": "train_return_mean",
    "rollout/ep_len_mean": "train_length_mean",
}
"""stable-baselines3's log columns kept, and their names in the curve CSV"""
SMOOTH_ROLLOUTS = 10
"""Window of the training return's moving mean on the PNG [rollouts]"""


def curve_paths(model_path: str | Path) -> tuple[Path, Path]:
    """Where a policy's curve goes: ``agents/x.zip`` -> ``agents/x.curve.csv``, ``agents/x.curve.png``.

    :param model_path: the policy's model file
    :return: the CSV and the PNG
    """
    model_path = Path(model_path)
    return model_path.with_suffix(".curve.csv"), model_path.with_suffix(".curve.png")


def training_curve(progress_csv: str | Path, evaluations: list[dict[str, Any]] | None = None) -> pd.DataFrame:
    """The curve table of a training run.

    :param progress_csv: stable-baselines3's CSV log of the run (``<model>.d/progress.csv``)
    :param evaluations: the metadata's held-out evaluations (``timesteps``, ``mean_return``,
        ``collision_rate``): rows of their own at their ``timesteps`` (training columns empty)
    :return: one row per rollout: ``timesteps``, ``wall_time_s``, ``train_return_mean``,
        ``train_length_mean``, ``reward/<term>`` [per decision], ``eval_mean_return``, ``eval_collision_rate``
    :raises ConfigError: when the log is missing or has no rollout rows
    """
    path = Path(progress_csv)
    if not path.is_file():
        raise ConfigError(f"training log not found: {path} (dt-highway train writes it to <model>.d/progress.csv)")
    try:
        log = pd.read_csv(path)
    except pd.errors.EmptyDataError:  # stopped before the first rollout ended
        log = pd.DataFrame()
    except (UnicodeDecodeError, pd.errors.ParserError) as err:
        raise ConfigError(f"{path} is not a stable-baselines3 training log (a CSV file): {type(err).__name__}") from None
    if "time/total_timesteps" not in log.columns or log.empty:
        raise ConfigError(f"{path} is not a stable-baselines3 training log with rollouts (no time/total_timesteps)")
    terms = sorted(c for c in log.columns if c.startswith("reward/"))
    keep = [c for c in COLUMNS if c in log.columns]
    curve = log[keep + terms].rename(columns=COLUMNS).reset_index(drop=True)
    if evaluations:
        evals = pd.DataFrame({"timesteps": [int(e["timesteps"]) for e in evaluations],
                              "eval_mean_return": [float(e["mean_return"]) for e in evaluations],
                              "eval_collision_rate": [float(e["collision_rate"]) for e in evaluations]})
        curve = pd.concat([curve, evals], ignore_index=True).sort_values("timesteps", kind="stable")
    else:
        curve = curve.assign(eval_mean_return=np.nan, eval_collision_rate=np.nan)
    curve = curve.reset_index(drop=True)
    return curve


def plot_curve(curve: pd.DataFrame, title: str, png: str | Path) -> None:
    """Draw a curve table (:func:`training_curve`) to a PNG.

    :param curve: the table
    :param title: the figure's title (e.g. the policy's name and setting)
    :param png: the file to write
    """
    matplotlib.use("Agg")
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(8, 6), sharex=True, height_ratios=[2, 1])
    steps = curve["timesteps"] / 1000
    train = curve.dropna(subset=["train_return_mean"]) if "train_return_mean" in curve else curve.iloc[:0]
    if len(train):
        top.plot(train["timesteps"] / 1000, train["train_return_mean"], color="#9ecae1", lw=1,
                 label="training episodes (mean of last 100)")
        smooth = train["train_return_mean"].rolling(SMOOTH_ROLLOUTS, min_periods=1).mean()
        top.plot(train["timesteps"] / 1000, smooth, color="#08519c", lw=2, label=f"moving mean of {SMOOTH_ROLLOUTS} rollouts")
    evals = curve.dropna(subset=["eval_mean_return"])
    top.plot(evals["timesteps"] / 1000, evals["eval_mean_return"], "o", color="#d94801", label="held-out evaluation")
    top.set_ylabel("episode return")
    top.legend(loc="best", fontsize=8, framealpha=0.9)
    top.grid(alpha=0.3)
    top.set_title(title)
    bottom.bar(evals["timesteps"] / 1000, evals["eval_collision_rate"], width=max(1.0, float(steps.max()) / 60),
               color="#d94801")
    bottom.plot(evals["timesteps"] / 1000, evals["eval_collision_rate"], "o", color="#d94801", ms=4,
                clip_on=False)  # a rate of 0 shows as a dot on the axis, not as nothing
    bottom.set_ylim(0, 1)
    bottom.set_ylabel("eval collision rate")
    bottom.set_xlabel("env steps [thousands]")
    bottom.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(png, dpi=110)
    plt.close(fig)


def write_curve(model_path: str | Path, progress_csv: str | Path | None = None) -> tuple[Path, Path]:
    """Write a policy's curve CSV and PNG beside it, from its training log and metadata.

    :param model_path: the policy (``.zip``, with its ``.json`` metadata beside it)
    :param progress_csv: the training log (default: ``progress.csv`` in the metadata's
        ``checkpoints`` folder, else in ``<model>.d/``)
    :return: the CSV and PNG written
    :raises ConfigError: on a missing metadata file or training log
    """
    model_path = Path(model_path)
    meta = read_policy_meta(model_path)
    if progress_csv is None:
        folders = [Path(meta["checkpoints"])] if meta.get("checkpoints") else []
        folders.append(model_path.with_suffix(".d"))
        found = [f / "progress.csv" for f in folders if (f / "progress.csv").is_file()]
        progress_csv = found[0] if found else folders[-1] / "progress.csv"
    curve = training_curve(progress_csv, meta.get("evaluations"))
    csv_path, png_path = curve_paths(model_path)
    curve.to_csv(csv_path, index=False, float_format="%.6g")
    title = f"{model_path.stem}: {meta.get('algorithm', '?')}, {meta.get('observation', '?')}, {meta.get('action', '?')}"
    plot_curve(curve, title, png_path)
    return csv_path, png_path

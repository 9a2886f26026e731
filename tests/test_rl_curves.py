"""A policy's training curve: the CSV rows from stable-baselines3's log and the evaluations, the PNG, errors."""

import json
import re

import pandas as pd
import pytest

from dt_highway.cli import main
from dt_highway.config import ConfigError
from dt_highway.rl.curves import curve_paths, training_curve, write_curve
from dt_highway.rl.files import FORMAT

LOG = """time/total_timesteps,time/time_elapsed,rollout/ep_rew_mean,rollout/ep_len_mean,reward/ttc2d,train/loss
1024,6,,,-0.04,
2048,11,300.5,480,-0.01,1.5
3072,17,310.0,490,-0.02,1.2
"""
EVALS = [{"timesteps": 1500, "mean_return": 250.0, "mean_length": 400, "collision_rate": 0.4},
         {"timesteps": 3072, "mean_return": 320.0, "mean_length": 500, "collision_rate": 0.2}]


def _policy(tmp_path, evaluations=EVALS, log=LOG):
    model = tmp_path / "p.zip"
    model.write_bytes(b"not read")
    work = tmp_path / "p.d"
    work.mkdir()
    (work / "progress.csv").write_text(log)
    model.with_suffix(".json").write_text(json.dumps({"format": FORMAT, "algorithm": "PPO", "observation": "adas-threat",
                                                      "action": "assisted-delayed", "checkpoints": str(work),
                                                      "evaluations": evaluations}))
    return model


def test_rollout_rows_keep_the_log_and_evaluations_get_rows_of_their_own(tmp_path):
    curve = training_curve(_policy(tmp_path).with_suffix(".d") / "progress.csv", EVALS)
    assert list(curve.columns) == ["timesteps", "wall_time_s", "train_return_mean", "train_length_mean", "reward/ttc2d",
                                   "eval_mean_return", "eval_collision_rate"]  # train/* left out
    assert curve["timesteps"].tolist() == [1024, 1500, 2048, 3072, 3072]  # the log's rows, then an eval's at its step
    assert curve["train_return_mean"].iloc[2] == 300.5 and pd.isna(curve["train_return_mean"].iloc[1])
    assert curve["eval_mean_return"].iloc[1] == 250.0 and curve["eval_collision_rate"].iloc[4] == 0.2
    assert curve["eval_mean_return"].notna().sum() == 2 and curve["reward/ttc2d"].iloc[0] == -0.04


def test_write_curve_writes_csv_and_png_beside_the_model(tmp_path):
    model = _policy(tmp_path)
    csv_path, png_path = write_curve(model)
    assert (csv_path, png_path) == curve_paths(model) == (tmp_path / "p.curve.csv", tmp_path / "p.curve.png")
    assert len(pd.read_csv(csv_path)) == 5 and png_path.read_bytes()[:4] == b"\x89PNG"


def test_missing_files_are_one_line_errors(tmp_path, capsys):
    with pytest.raises(ConfigError, match="metadata"):
        write_curve(tmp_path / "none.zip")
    model = _policy(tmp_path, log="time/total_timesteps,rollout/ep_rew_mean\n")
    with pytest.raises(ConfigError, match="no time/total_timesteps|with rollouts"):
        write_curve(model)
    (tmp_path / "p.d" / "progress.csv").write_text("")  # Ctrl-C before the first rollout: an empty log
    with pytest.raises(ConfigError, match="with rollouts"):
        write_curve(model)
    (tmp_path / "p.d" / "progress.csv").unlink()
    with pytest.raises(ConfigError, match="training log not found"):
        write_curve(model)
    assert main(["rl-curve", str(tmp_path / "p.toml")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "MODEL must be a policy .zip" in err


@pytest.mark.parametrize(("meta", "progress", "message"), [
    ("{not json", None, "cannot read .*p.json: Expecting property name"),
    ("[1]", None, "p.json is not the metadata of a dt-highway policy"),
    (None, bytes(range(256)) * 4, "progress.csv is not a stable-baselines3 training log"),
])
def test_damaged_files_are_one_line_errors(tmp_path, capsys, meta, progress, message):
    model = _policy(tmp_path)
    if meta is not None:
        model.with_suffix(".json").write_text(meta)
    if progress is not None:
        (tmp_path / "p.d" / "progress.csv").write_bytes(progress)
    assert main(["rl-curve", str(model)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and re.search(message, err), err

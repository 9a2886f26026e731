"""The last user mistakes of issue 21, each a one-line error (or a one-line note) before any work
starts: a directory or /dev/null where a file is wanted, a detector training that has nothing
left to do, RL step budgets that are not whole rollouts, and the driving benchmark's display."""

import os
import shutil
import subprocess
import sys
import time

import pytest

from dt_highway.cli import main
from dt_highway.config import ConfigError, load_config
from dt_highway.evaluation.rl import evaluate
from dt_highway.rl.config import TrainConfig, load_train_config
from dt_highway.rl.train import rollout_steps, round_timesteps
from dt_highway.study import plan as study_plan

TINY = ["--set", "highway.vehicles_count=10", "--set", "highway.duration=4", "--set", "twin.preroll_s=4",
        "--set", "highway.lanes_count=3", "--set", "traffic.population_size=40"]


def one_line(capsys, code, must_contain):
    """The command returned 2 and said one line on stderr, holding ``must_contain``."""
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert code == 2 and len(err) == 1, err
    assert must_contain in err[0], err[0]
    return err[0]


@pytest.mark.parametrize("where", ["dir", "/dev/null"])
def test_twin_store_path_must_be_a_file(tmp_path, capsys, where):
    path = str(tmp_path) if where == "dir" else where
    code = main(["run", "--episodes", "1", "--quiet", "--out", str(tmp_path / "o"), "--set", f"twin.store.path={path}",
                 *TINY])
    line = one_line(capsys, code, f"twin.store.path = '{path}': must name a SQLite file, new or existing")
    assert ("a directory" if where == "dir" else "not a regular file") in line
    with pytest.raises(ConfigError, match="twin.store.path"):
        load_config(overrides=[f"twin.store.path={path}"])
    assert load_config(overrides=[f"twin.store.path={tmp_path / 'new.sqlite'}"]).twin.store.path  # a new file is fine


@pytest.mark.parametrize("where", ["dir", "/dev/null"])
def test_scenario_must_be_a_file(tmp_path, capsys, where):
    path = str(tmp_path) if where == "dir" else where
    one_line(capsys, main(["twin-eval", "--scenario", path, "--quiet"]), f"scenario file '{path}' is not a file")
    one_line(capsys, main(["twin-eval", "--scenario", str(tmp_path / "nope.toml"), "--quiet"]), "does not exist")


SMALL = ["--width", "64", "--height", "64", "--batch", "2", "--quiet"]


@pytest.mark.parametrize("fresh", [True, False])
def test_detector_train_out_a_directory_is_refused_before_training(tmp_path, capsys, fresh):
    weights = tmp_path / "weights"
    weights.mkdir()
    (weights / "keep.txt").write_text("x")
    t0 = time.perf_counter()
    code = main(["detector", "train", "--out", str(weights), "--max-steps", "1", *SMALL, *(["--fresh"] if fresh else [])])
    one_line(capsys, code, f"{weights} is a directory: --out names the weights file to write, e.g. {weights / 'detector.pt'}")
    assert time.perf_counter() - t0 < 20  # nothing was trained
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["keep.txt", "weights"]  # and nothing left behind


def _checkpoint(path, steps, elapsed_s):
    """A checkpoint of a 64 x 64 RGB detector that has done ``steps`` steps in ``elapsed_s``."""
    import torch

    from dt_highway.perception.learned.model import Architecture

    torch.save({"arch": Architecture(width_px=64, height_px=64).to_dict(), "model": {}, "optimizer": {},
                "step": steps, "elapsed_s": elapsed_s, "next_seed": 0, "rendered": 2 * steps,
                "generator": torch.Generator().get_state()}, path)


def test_detector_train_resumed_with_nothing_left_to_do_says_so(tmp_path, capsys):
    out = tmp_path / "det.pt"
    ckpt = tmp_path / "det.pt.ckpt"
    _checkpoint(ckpt, steps=5, elapsed_s=30.0)
    before = ckpt.read_bytes()
    code = main(["detector", "train", "--out", str(out), "--max-steps", "3", *SMALL])
    one_line(capsys, code, f"nothing to train: {ckpt} already holds 5 steps, --max-steps 3 is reached "
                           "(raise it to train on, or pass --fresh to start over)")
    code = main(["detector", "train", "--out", str(out), "--max-steps", "5", *SMALL])
    one_line(capsys, code, "already holds 5 steps, --max-steps 5 is reached")
    code = main(["detector", "train", "--out", str(out), "--minutes", "0.25", *SMALL])  # 15 s of the 30 s done
    one_line(capsys, code, f"nothing to train: {ckpt} already trained 0.50 min, --minutes 0.25 is reached")
    assert not out.exists() and ckpt.read_bytes() == before  # untouched


def test_rl_timesteps_are_rounded_up_to_whole_rollouts_with_one_line():
    cfg = load_train_config("agents/ppo-baseline.toml")  # PPO, n_steps 1024, 1 env
    assert rollout_steps(cfg) == 1024
    rounded, message = round_timesteps(TrainConfig.model_validate({**cfg.model_dump(), "timesteps": 256}))
    assert rounded.timesteps == 1024
    assert message == "--timesteps 256 rounded up to 1024: PPO trains whole rollouts of 1024 steps (n_steps 1024 x 1 env)"
    two = TrainConfig.model_validate({**cfg.model_dump(), "timesteps": 2049, "n_envs": 2})
    assert round_timesteps(two)[0].timesteps == 4096  # rollouts of 2 x 1024
    exact = TrainConfig.model_validate({**cfg.model_dump(), "timesteps": 3072})
    assert round_timesteps(exact) == (exact, None)
    dqn = TrainConfig.model_validate({**cfg.model_dump(), "algorithm": "DQN", "hyperparameters": {}, "n_envs": 3,
                                      "timesteps": 100})
    assert rollout_steps(dqn) == 4 * 3  # DQN's default train_freq: 4 steps per env
    assert round_timesteps(dqn)[0].timesteps == 108


def _bench(env_extra, drop=("SDL_VIDEODRIVER", "DISPLAY", "WAYLAND_DISPLAY")):
    env = {k: v for k, v in os.environ.items() if k not in drop} | env_extra
    return subprocess.run([sys.executable, "-m", "dt_highway.cli", "bench", "drive", "--duration", "0.5", "--vehicles",
                           "5", "--width", "320", "--height", "180", "--condition", "baseline"],
                          capture_output=True, text=True, env=env)


def _unused_display() -> str:
    """A display number no X server on this machine holds (a fixed one met another session's Xvfb)."""
    n = next(n for n in range(177, 400) if not os.path.exists(f"/tmp/.X{n}-lock")
             and not os.path.exists(f"/tmp/.X11-unix/X{n}"))
    return f":{n}"


def test_bench_drive_says_which_video_driver_it_used():
    headless = _bench({})
    assert headless.returncode == 0, headless.stderr
    assert headless.stdout.rstrip().endswith("; video driver offscreen")  # no display: offscreen
    nobody = _unused_display()
    unreachable = _bench({"DISPLAY": nobody})  # honoured, but nothing answers there: SDL falls back, and we say so
    assert unreachable.returncode == 0, unreachable.stderr
    assert unreachable.stdout.rstrip().endswith(f"video driver offscreen (the display {nobody} was not used)")
    forced = _bench({"DISPLAY": nobody, "SDL_VIDEODRIVER": "x11"})
    assert forced.returncode == 2 and "Traceback" not in forced.stderr
    assert forced.stderr.strip().splitlines()[-1] == (
        "dt-highway bench drive: error: cannot open the driving window with SDL_VIDEODRIVER=x11 (x11 not available): "
        "run headless with SDL_VIDEODRIVER=offscreen, or fix the display")


@pytest.mark.skipif(shutil.which("Xvfb") is None, reason="needs Xvfb for a real X display")
def test_bench_drive_opens_its_window_on_the_display():
    xvfb = subprocess.Popen(["Xvfb", ":93", "-screen", "0", "800x600x24"], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    try:
        time.sleep(1.0)
        shown = _bench({"DISPLAY": ":93"})
    finally:
        xvfb.terminate()
        xvfb.wait()
    assert shown.returncode == 0, shown.stderr
    assert shown.stdout.rstrip().endswith("; video driver x11")


# ----------------------------------------------------------------------------- the Python API's arguments
@pytest.mark.parametrize(("call", "words"), [
    (lambda: load_config(None, "highway.duration=3"),
     "overrides must be a list of 'dotted.key=value' strings (got the string 'highway.duration=3': put it in a list)"),
    (lambda: load_config(None, {"highway.duration": 3}), "(got dict)"),
    (lambda: load_config(None, None), "(got NoneType)"),
    (lambda: load_config(None, ["highway.duration=3", 3]), "(got a list holding int)"),
    (lambda: load_config({"highway": {}}), "scenario must be a TOML file's path (got dict): pass a tree as extra"),
    (lambda: study_plan("x", "agents/idm.toml", ["baseline"], 1, 0, overrides="highway.duration=3"),
     "put it in a list"),
    (lambda: study_plan("x", "agents/idm.toml", None, 1, 0), "conditions must be a list of names"),
    (lambda: evaluate("agents/idm.toml", 1.5, 0), "--episodes must be a whole number >= 1 (got 1.5)"),
    (lambda: evaluate("agents/idm.toml", 1, None), "--seed must be a whole number >= 0 (got None)"),
    (lambda: evaluate(3, 1, 0), "the driver must be a file's path"),
    (lambda: evaluate("agents/idm.toml", 1, 0, overrides="highway.duration=3"), "put it in a list"),
])
def test_the_python_calls_say_what_is_wrong_with_an_argument(call, words):
    """A lone string was read letter by letter ('--set expects dotted.key=value (got 'h')', at each trial), a dict
    lost its values, a float count or a None seed was a TypeError deep inside."""
    with pytest.raises(ConfigError) as err:
        call()
    assert words in str(err.value) and "\n" not in str(err.value)


def _api_calls():
    import numpy as np
    import pandas as pd

    from dt_highway import load_trial
    from dt_highway.camera.pinhole import Intrinsics
    from dt_highway.camera.render import depth_to_uint8
    from dt_highway.drivers.scripted import HumanDriver
    from dt_highway.overlay import ShamOverlay, draw_overlay
    from dt_highway.report import summarise
    frame = np.zeros((48, 64, 3), np.uint8)
    return [
        (lambda: load_trial(None), TypeError, "load_trial reads a trial's directory: a path (got NoneType)"),
        (lambda: draw_overlay(frame, [{"vehicle_id": 1}]), ValueError, "overlay mark 0 has no 'box' [px]"),
        (lambda: draw_overlay(frame.astype(float), []), ValueError, "uint8 (H, W, 3) RGB frame (got float64"),
        (lambda: HumanDriver("h", {"reaction_time_s": 1.0}), TypeError, "HumanDriver takes HumanParams (got dict)"),
        (lambda: summarise(pd.DataFrame(), {}), ValueError, "summarise takes the metrics and data collect(study_dir)"),
        (lambda: ShamOverlay(np.random.default_rng(0), hold_s=-1), ConfigError, "overlay.hold_s = -1 is out of range"),
        (lambda: ShamOverlay(0), TypeError, "numpy.random.Generator (got int)"),
        (lambda: Intrinsics.from_fov(float("nan"), 48, 1.0), ValueError, "width_px must be a whole number of pixels"),
        (lambda: Intrinsics(64, 48, -1.0, 1.0, 1.0, 1.0), ValueError, "fx_px must be a finite number > 0"),
        (lambda: depth_to_uint8(np.ones((2, 2)), 0.0), ValueError, "max_range_m must be a finite number > 0 [m]"),
    ]


@pytest.mark.parametrize("case", _api_calls(), ids=lambda case: case[2][:40])
def test_library_calls_refuse_what_they_cannot_use_in_one_line(case):
    """Each was a KeyError, AttributeError, ZeroDivisionError, an all-NaN camera or a silent float64 frame."""
    call, kind, words = case
    with pytest.raises(kind) as err:
        call()
    assert words in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize("settings", [["twin.intention.weights={bad}.npz"],
                                      ["twin.tagger.model=evidence", "twin.tagger.evidence_weights={bad}.json"]])
def test_a_twin_model_file_that_cannot_be_read_stops_a_study_before_its_first_trial(tmp_path, capsys, settings):
    """Each trial failed on it, one after the other, and the study wrote a report of none."""
    bad = tmp_path / "bad"
    for ext in (".npz", ".json"):
        (tmp_path / f"bad{ext}").write_text("{}" if ext == ".json" else "garbage")
    args = [a for s in settings for a in ("--set", s.format(bad=bad))]
    code = main(["study", "--quick", "--out", str(tmp_path / "s"), "--quiet", *args])
    line = one_line(capsys, code, "twin.")
    assert ("cannot read intention weights" in line) or ("has no 'features'" in line)
    assert not (tmp_path / "s").exists()

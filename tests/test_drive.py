"""The keyboard driving window, replayed from key scripts, headless (SDL offscreen)."""

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from PIL import Image

from dt_highway.cli import main
from dt_highway.metrics.trial_log import load_trial
from dt_highway.overlay import MARK_RGB

FAST = ["--set", "highway.vehicles_count=16", "--set", "twin.preroll_s=20", "--set", "camera.width_px=480",
        "--set", "camera.height_px=270", "--set", "highway.simulation_frequency=15", "--no-minimap"]  # trials default to 30 Hz
SCRIPT = "0.2 down UP\n1.0 up UP\n1.2 down LEFT\n1.3 up LEFT\n1.6 down DOWN\n2.0 up DOWN\n"


def _drive(tmp_path, condition, *extra):
    keys = tmp_path / "keys.txt"
    keys.write_text(SCRIPT)
    args = ["drive", "--participant", "P01", "--condition", condition, "--duration", "2.4", "--out", str(tmp_path / "s"),
            "--keys-from", str(keys), "--screenshot-every", "1", "--seed", "3", *FAST, *extra]
    assert main(args) == 0
    return load_trial(tmp_path / "s" / "trials" / f"P01-{condition}")


def test_a_replayed_trial_is_logged_completely_with_the_scripted_keys(tmp_path):
    trial = _drive(tmp_path, "adas")
    assert trial.meta["status"] == "completed" and trial.meta["participant"] == "P01"
    assert trial.meta["condition"] == "adas" and trial.meta["driver"] == "keyboard"
    keys = [(e["t_s"], e["kind"], e["key"]) for e in trial.events if e["kind"].startswith("key_")]
    expected = [(float(t), f"key_{a}", k) for t, a, k in (line.split() for line in SCRIPT.splitlines())]
    assert keys == expected
    steps = trial.steps
    assert len(steps) == 36 and steps["t_s"].max() == pytest.approx(2.4)  # 15 Hz, one row per simulation step
    held = steps.set_index("t_s")["keys"].fillna("")
    assert held.loc[0.6:0.9].eq("UP").all() and held.loc[1.7:1.9].eq("DOWN").all() and held.loc[2.1:].eq("").all()
    accel = steps["action_accel_mps2"].to_numpy()  # row k: t = k / 15 s
    assert accel[round(0.9 * 15)] > 1.0 and accel[round(2.0 * 15)] < -2.0  # throttle, then brake, ramped
    assert any(e["kind"] == "lane_change" for e in trial.events)
    assert sorted(p.name for p in (trial.path / "screenshots").iterdir()) == [
        "t0000.00s.png", "t0001.00s.png", "t0002.00s.png"]


def test_the_adas_screenshot_differs_from_the_baseline_one_where_the_overlay_is(tmp_path):
    adas, base = _drive(tmp_path, "adas", "--seed", "4"), _drive(tmp_path, "baseline", "--seed", "4")  # a tagged car ahead
    a = np.asarray(Image.open(adas.path / "screenshots" / "t0001.00s.png").convert("RGB"))
    b = np.asarray(Image.open(base.path / "screenshots" / "t0001.00s.png").convert("RGB"))
    assert np.array_equal(adas.steps["x_m"], base.steps["x_m"])  # the same drive: only what is shown differs
    shown = adas.steps["overlay_ids"].fillna("").astype(str).iloc[15]  # t = 1 s
    assert shown  # marks were on screen at 1 s
    diff = (a != b).any(axis=-1)
    diff[:40, :220] = False  # the condition's name, top left
    assert diff.sum() > 200
    red = (a == MARK_RGB).all(axis=-1) | (a == 255).all(axis=-1)  # the marks' boxes, banners and their text
    assert red[diff].mean() > 0.6
    assert not diff[-60:].any()  # the HUD is the same


def test_a_sigkilled_keyboard_trial_is_readable_and_aborted(tmp_path):
    keys = tmp_path / "keys.txt"
    keys.write_text("0.1 down UP\n")
    out = tmp_path / "s"
    # the world without near-miss cut-ins: a crash in the first seconds would end the trial before the kill
    proc = subprocess.Popen([sys.executable, "-m", "dt_highway.cli", "drive", "--participant", "P02", "--condition",
                             "baseline", "--duration", "60", "--out", str(out), "--keys-from", str(keys), *FAST,
                             "--scenario", "envs/highway-trial-v1.toml"],
                            env={**os.environ, "SDL_VIDEODRIVER": "offscreen"}, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    steps = out / "trials" / "P02-baseline" / "steps.csv"
    deadline = time.time() + 120
    seen = 0.0
    while time.time() < deadline and seen < 3.0:
        time.sleep(0.2)
        if steps.exists():
            lines = steps.read_text().splitlines()
            if len(lines) > 2:
                try:
                    seen = float(lines[-2].split(",")[0])
                except ValueError:
                    pass
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert seen >= 3.0
    trial = load_trial(out / "trials" / "P02-baseline")
    assert trial.meta["status"] == "aborted"
    assert trial.steps["t_s"].max() >= seen - 1.0
    assert [e["key"] for e in trial.events if e["kind"] == "key_down"] == ["UP"]


def test_bad_drive_inputs_are_one_line(tmp_path, capsys):
    bad = tmp_path / "bad.txt"
    bad.write_text("0.5 press UP\n")
    base = ["drive", "--condition", "adas", "--out", str(tmp_path / "s")]
    assert main([*base, "--participant", "P01", "--keys-from", str(bad)]) == 2
    assert "bad.txt:1: action must be 'down' or 'up'" in capsys.readouterr().err
    assert main([*base, "--participant", "../x"]) == 2
    assert "--participant must be" in capsys.readouterr().err
    assert not (tmp_path / "s").exists()


def test_condition_order_is_counterbalanced_by_participant():
    from dt_highway.hmi.session import condition_order

    assert condition_order("P01") == ("baseline", "adas") and condition_order("P02") == ("adas", "baseline")
    assert condition_order("anna") == condition_order("anna") and set(condition_order("anna")) == {"baseline", "adas"}
    from pathlib import Path

    from dt_highway.hmi.drive import DriveOptions
    from dt_highway.hmi.session import session_plan

    plan = session_plan(DriveOptions("P02", "baseline", Path("o"), screenshots=Path("shots"), seed=5), 30.0)
    assert [(t.condition, t.practice, t.opts.seed, t.opts.duration_s) for t in plan] == [
        ("adas", True, 1005, 30.0), ("baseline", True, 1006, 30.0), ("adas", False, 5, None), ("baseline", False, 5, None)]
    assert [t.opts.screenshots.name for t in plan] == [  # no overwriting
        "P02-practice-adas", "P02-practice-baseline", "P02-adas", "P02-baseline"]


def test_a_session_runs_practice_and_both_conditions_resumes_and_reports_by_participant(tmp_path, capsys):
    keys = tmp_path / "keys.txt"
    keys.write_text("0.1 down UP\n0.8 up UP\n")
    out = tmp_path / "study"
    args = ["--duration", "1.5", "--practice-duration", "1", "--out", str(out), "--keys-from", str(keys), *FAST]
    for p in ("P01", "P02"):
        assert main(["session", "--participant", p, *args]) == 0
    trials = sorted(d.name for d in (out / "trials").iterdir())
    assert trials == ["P01-adas", "P01-baseline", "P01-practice-adas", "P01-practice-baseline",
                      "P02-adas", "P02-baseline", "P02-practice-adas", "P02-practice-baseline"]
    practice = load_trial(out / "trials" / "P02-practice-adas")
    assert practice.meta["practice"] and practice.meta["condition"] == "adas"  # P02 starts with ADAS
    assert practice.meta["seed"] == 1000 and load_trial(out / "trials" / "P02-adas").meta["seed"] == 0
    # a trial that was killed reads as aborted: the session runs it again, and only it, in P01-adas-retry1
    meta = out / "trials" / "P01-adas" / "meta.json"
    m = json.loads(meta.read_text())
    meta.write_text(json.dumps({**m, "status": "running", "pid": 2 ** 22 + 12345}))
    capsys.readouterr()
    assert main(["session", "--participant", "P01", *args]) == 0
    said = capsys.readouterr().out
    assert "P01-practice-adas: already completed, skipped" in said and "P01-baseline: already completed" in said
    assert "| Trial 2 of 2 | adas | attempt 2 |" in said
    assert load_trial(out / "trials" / "P01-adas-retry1").meta["status"] == "completed"
    assert main(["report", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["conditions"]["baseline"]["n"] == 2 and summary["conditions"]["adas"]["n"] == 2  # no practice
    assert summary["paired_tests"]["speed_mean_kmh"]["n_pairs"] == 2


def test_pause_stops_the_trial_clock_and_esc_quits_as_aborted(tmp_path):
    keys = tmp_path / "keys.txt"
    keys.write_text("0.5 down P\n0.6 up P\n1.5 down P\n1.6 up P\n")  # paused for 1 s of wall time
    out = tmp_path / "s"
    base = ["drive", "--participant", "P03", "--duration", "1.5", "--out", str(out), "--keys-from", str(keys), *FAST]
    t0 = time.monotonic()
    assert main([*base, "--condition", "baseline"]) == 0
    assert time.monotonic() - t0 > 2.3  # 1.5 s of driving + 1 s of pause (+ set-up)
    trial = load_trial(out / "trials" / "P03-baseline")
    assert trial.meta["status"] == "completed" and len(trial.steps) == 23  # ceil(1.5 * 15): the pause added none
    keys.write_text("0.5 down UP\n1.0 down ESC\n")
    assert main([*base, "--condition", "adas"]) == 1
    quit_ = load_trial(out / "trials" / "P03-adas")
    assert quit_.meta["status"] == "aborted" and quit_.meta["end_reason"] == "quit by the participant"
    assert quit_.steps["t_s"].max() == pytest.approx(1.0)


def test_the_interactive_path_start_screen_keys_and_esc_with_confirmation(tmp_path):
    """Without a script: the start screen waits for Enter, keys come from pygame's events, the
    first Esc asks, the second quits; events are posted as a person would press the keys."""
    import pygame

    from dt_highway.hmi.drive import DriveOptions, run_drive

    plan = {1: (pygame.KEYDOWN, pygame.K_RETURN), 2: (pygame.KEYDOWN, pygame.K_RETURN),
            3: (pygame.KEYDOWN, pygame.K_RETURN), 4: (pygame.KEYDOWN, pygame.K_RETURN),
            10: (pygame.KEYDOWN, pygame.K_UP), 25: (pygame.KEYUP, pygame.K_UP),
            30: (pygame.KEYDOWN, pygame.K_ESCAPE), 31: (pygame.KEYDOWN, pygame.K_ESCAPE)}  # paused: no new picture
    shown = []

    def press(img):
        shown.append(img)
        kind, key = plan.get(len(shown), (pygame.KEYDOWN, pygame.K_RETURN) if len(shown) > 31 else (None, None))
        if kind is not None:
            pygame.event.post(pygame.event.Event(kind, key=key))

    overrides = [a for a in FAST if a not in ("--set", "--no-minimap")]
    result = run_drive(DriveOptions("P04", "adas", tmp_path / "s", scenario="envs/highway-trial.toml",
                                    overrides=overrides, duration_s=30.0), on_frame=press)
    assert result["status"] == "aborted" and result["end_reason"] == "quit by the participant"
    trial = load_trial(tmp_path / "s" / "trials" / "P04-adas")
    assert [(e["kind"], e["key"]) for e in trial.events if e["kind"].startswith("key_")] == [
        ("key_down", "UP"), ("key_up", "UP"), ("key_down", "ESC"), ("key_down", "ESC")]
    assert trial.meta["status"] == "aborted" and trial.steps["t_s"].max() < 30
    assert (trial.steps["keys"].fillna("") == "UP").any()


def test_steering_mode_steers_the_ego_across_the_lane(tmp_path):
    keys = tmp_path / "keys.txt"
    keys.write_text("0.2 down RIGHT\n1.2 up RIGHT\n")
    out = tmp_path / "s"
    assert main(["drive", "--participant", "P05", "--condition", "baseline", "--duration", "2", "--out", str(out),
                 "--keys-from", str(keys), "--steering", *FAST]) == 0
    steps = load_trial(out / "trials" / "P05-baseline").steps
    steer = steps["action_lane"].to_numpy()  # the steering command in steering mode
    # row k is the step that ends at t = (k + 1) / 15
    assert steer[:3].max() == 0.0 and steer[round(1.2 * 15) - 1] == pytest.approx(1.0) and steer[-1] == 0.0
    assert steps["y_m"].iloc[-1] > steps["y_m"].iloc[0] + 1.0  # drifted right: no lane keeping pulled it back


def test_an_error_in_the_simulation_ends_the_trial_as_aborted_and_is_raised(tmp_path, monkeypatch):
    from dt_highway.env import DTHighwayEnv
    from dt_highway.hmi.drive import DriveOptions, run_drive
    from dt_highway.hmi.keys import KeyScript

    real_step = DTHighwayEnv.step

    def failing_step(self, action):
        if self.steps >= 10:
            raise RuntimeError("simulated failure")
        return real_step(self, action)

    monkeypatch.setattr(DTHighwayEnv, "step", failing_step)
    overrides = [a for a in FAST if a not in ("--set", "--no-minimap")]
    with pytest.raises(RuntimeError, match="simulated failure"):
        run_drive(DriveOptions("P06", "baseline", tmp_path / "s", scenario="envs/highway-trial.toml",
                               overrides=overrides, duration_s=5.0, keys_from=KeyScript([])))
    trial = load_trial(tmp_path / "s" / "trials" / "P06-baseline")
    assert trial.meta["status"] == "aborted" and "simulated failure" in trial.meta["end_reason"]

"""The keyboard trial for participants (issue 20): keys held through the countdown, event times
at their real moment with the wall clock, pauses and signals logged, crash feedback and policy,
participant screens (no condition names, no paths, Enter-only end screen), window size and
scaling, the mirror hook. Headless (SDL offscreen), scripted keys or posted pygame events."""

import json
import os
import signal
import sys
import threading
import time
import types
from dataclasses import replace
from datetime import datetime
from pathlib import Path

import numpy as np
import pygame
import pytest

from dt_highway.cli import main
from dt_highway.config import ConfigError
from dt_highway.hmi import briefing, crash, drive, picture, screens
from dt_highway.hmi.drive import (
    CRASH_BANNER_S,
    MIRROR_FRACTION,
    QUIT_LINES,
    DriveOptions,
    Hud,
    _trial_config,
    _Window,
    beep_samples,
    compose_frame,
    crash_layer,
    dialog,
    held_at_start,
    parse_size,
    run_drive,
    trial_name,
)
from dt_highway.hmi.keys import KeyEvent, KeyScript
from dt_highway.metrics.trial_log import check_trial, load_trial

QUIET = ["highway.vehicles_count=16", "twin.preroll_s=20", "camera.width_px=480", "camera.height_px=270"]
V1 = "envs/highway-trial-v1.toml"  # no near-miss cut-ins: no crash in the first seconds


def _opts(tmp_path, participant="P01", condition="adas", **kw):
    base = {"scenario": V1, "overrides": list(QUIET), "duration_s": 1.5, "simulation_hz": 15, "minimap": False}
    return DriveOptions(participant, condition, tmp_path / "s", **{**base, **kw})


def _spy_text(monkeypatch):
    """Every text drawn on the participant's pictures (``screens._text``) and full screens (the session's
    renderer, ``briefing.TextFont.render``: one entry per line drawn)."""
    texts = []
    real = screens._text

    def spy(img, text, *a, **k):
        texts.append(text)
        return real(img, text, *a, **k)

    for module in (screens, picture, crash):  # each draws with the helper it imported
        monkeypatch.setattr(module, "_text", spy)
    real_render = briefing.TextFont.render

    def render(font, text, *a, **k):
        texts.append(text)
        return real_render(font, text, *a, **k)

    monkeypatch.setattr(briefing.TextFont, "render", render)
    return texts


def _keys(trial):
    return [(e["t_s"], e["kind"], e["key"]) for e in trial.events if e["kind"].startswith("key_")]


def _no_release_without_press(trial):
    held = set()
    for e in trial.events:
        if e["kind"] == "key_down":
            held.add(e["key"])
        elif e["kind"] == "key_up":
            assert e["key"] in held, f"{e['key']} released at {e['t_s']} s without a press"
            held.discard(e["key"])


# ------------------------------------------------------------------------------------ 1. countdown
def test_held_at_start_keeps_the_driving_keys_still_down():
    evs = [KeyEvent(-2.5, True, "UP"), KeyEvent(-2.0, True, "DOWN"), KeyEvent(-1.0, False, "DOWN"),
           KeyEvent(-0.8, True, "P"), KeyEvent(-0.5, True, "LEFT")]
    assert held_at_start(evs) == {"UP": -2.5, "LEFT": -0.5}  # DOWN was released, P is not a driving key


def test_a_key_held_through_the_countdown_acts_and_is_logged_at_t0_and_pauses_are_logged(tmp_path):
    script = KeyScript([KeyEvent(-1.2, True, "UP"), KeyEvent(-0.6, True, "DOWN"), KeyEvent(-0.4, False, "DOWN"),
                        KeyEvent(0.4, False, "UP"), KeyEvent(0.6, True, "P"), KeyEvent(0.7, False, "P"),
                        KeyEvent(1.6, True, "P"), KeyEvent(1.7, False, "P")])  # paused 1.0 s of wall time
    result = run_drive(_opts(tmp_path, keys_from=script), say=lambda s: None)
    trial = load_trial(result["directory"])
    # a script's pause lasts in wall time: its keys during the pause keep the script's times; 1.7 s is after the end
    assert _keys(trial) == [(0.0, "key_down", "UP"), (0.4, "key_up", "UP"), (0.6, "key_down", "P"),
                            (0.7, "key_up", "P"), (1.6, "key_down", "P")]
    first = next(e for e in trial.events if e["kind"] == "key_down")
    assert first["pressed_at_s"] == -1.2
    _no_release_without_press(trial)
    accel = trial.steps["action_accel_mps2"].to_numpy()
    # the throttle from the first step: coast -0.3 m/s^2 plus 2.5 m/s^3 for 1/15 s (without the carry-over: -0.3)
    assert accel[0] == pytest.approx(-0.3 + 2.5 / 15) and accel[5] == pytest.approx(-0.3 + 6 * 2.5 / 15)
    assert trial.steps["keys"].fillna("").iloc[0] == "UP"
    starts = [e for e in trial.events if e["kind"] == "pause_start"]
    ends = [e for e in trial.events if e["kind"] == "pause_end"]
    assert len(starts) == len(ends) == 1 and starts[0]["t_s"] == pytest.approx(0.6) and starts[0]["reason"] == "P"
    assert ends[0]["duration_s"] == pytest.approx(1.0, abs=0.08)
    assert trial.meta["paused_s"] == pytest.approx(1.0, abs=0.08) and len(trial.meta["pauses"]) == 1
    walls = {e["kind"]: datetime.fromisoformat(e["wall_time"]) for e in (starts[0], ends[0])}
    assert (walls["pause_end"] - walls["pause_start"]).total_seconds() == pytest.approx(1.0, abs=0.08)
    assert all("wall_time" in e for e in trial.events)  # every event, the recorder's too
    # how much of real time the trial kept, pauses left out: not judged on a trial this short (under 10 s)
    assert "realtime_ratio" in trial.meta and trial.meta["realtime_ratio"] is result["realtime_ratio"] is None


def test_a_trial_that_did_not_keep_real_time_is_said():
    assert drive.realtime_ratio(30.0, 32.5) == 0.923 and drive.realtime_ratio(30.0, 41.0, paused_s=11.0) == 1.0
    assert drive.realtime_ratio(1.45, 1.55) is None  # too short to judge: a step's lag would read as slow motion
    assert drive.realtime_ratio(9.0, 25.0, paused_s=16.0) is None
    assert drive.slow_trial_line(1.0) is None and drive.slow_trial_line(None) is None
    assert drive.is_slow(0.947) and not drive.is_slow(0.95) and not drive.is_slow(None)
    line = drive.slow_trial_line(0.62)
    assert line is not None and "0.620 of real time" in line and "slow motion" in line
    edge = drive.slow_trial_line(0.947)  # below 0.95, and not rounded up to it
    assert edge is not None and "0.947 of real time" in edge


def test_a_script_built_in_code_that_ends_paused_ends_the_trial(tmp_path):
    """KeyScript.parse refuses a file that ends paused; one built in code stopped the trial for ever."""
    script = KeyScript([KeyEvent(0.3, True, "P"), KeyEvent(0.4, False, "P")])
    result = run_drive(_opts(tmp_path, keys_from=script), say=lambda s: None)
    trial = load_trial(result["directory"])
    assert trial.meta["status"] == "aborted" and trial.meta["end_reason"] == "the key script ended with the trial paused"


def test_key_events_after_the_trials_end_are_said_not_dropped_silently(tmp_path):
    said: list[str] = []
    script = KeyScript([KeyEvent(0.2, True, "UP"), KeyEvent(0.5, False, "UP"), KeyEvent(9.0, True, "LEFT"),
                        KeyEvent(9.1, False, "LEFT")])
    run_drive(_opts(tmp_path, keys_from=script), say=said.append)
    assert said[-1] == "  the key script's last 2 events (from 9 s) came after the trial's end: not used"


def _interactive(tmp_path, plan, *, condition="sham", label="Trial 2", duration_s=30.0, captions=None):
    """Run an interactive trial; ``plan[n]`` lists the pygame events posted after the n-th frame shown."""
    shown = []

    def on_frame(img):
        shown.append(img)
        if captions is not None:
            captions.append(pygame.display.get_caption()[0])
        for kind, key in plan.get(len(shown), ()):
            pygame.event.post(pygame.event.Event(kind, key=key) if key is not None else pygame.event.Event(kind))

    lines = []
    result = run_drive(_opts(tmp_path, condition=condition, display_label=label, duration_s=duration_s),
                       on_frame=on_frame, say=lines.append)
    return result, shown, lines


def test_the_env_is_made_under_preparing_and_keys_pressed_meanwhile_do_not_start_the_trial(tmp_path, monkeypatch):
    # gym.make takes seconds (the twin's models): the screen before must not stand frozen meanwhile, and an Enter
    # pressed then (impatient, or meant for the screen before) must not answer the keys screen
    texts = _spy_text(monkeypatch)
    real_make = drive.gym.make
    seen_before_make = []

    def make(*a, **k):
        seen_before_make.append(list(texts))
        pygame.event.post(pygame.event.Event(pygame.KEYDOWN, key=pygame.K_RETURN))
        return real_make(*a, **k)

    monkeypatch.setattr(drive.gym, "make", make)
    shown = []

    def on_frame(img):
        shown.append(img)
        if len(shown) == 2:  # the keys screen: Esc, so the trial never starts
            pygame.event.post(pygame.event.Event(pygame.KEYDOWN, key=pygame.K_ESCAPE))

    lines: list[str] = []
    result = run_drive(_opts(tmp_path), on_frame=on_frame, say=lines.append)
    assert seen_before_make == [["Preparing the trial..."]]
    assert result["status"] == "not started" and result["end_reason"] == "quit before the start"
    # the experimenter is not sent to a folder that was never written
    assert not Path(result["directory"]).exists() and lines[0].endswith("nothing saved") and "->" not in lines[0]


def test_the_keys_screen_shows_the_sessions_legend_drawn_as_its_screens(tmp_path, monkeypatch):
    """A session's protocol translates the keys' legend: the trial's keys screen showed the built-in English one,
    in another font (OpenCV's Hershey, which cannot draw an umlaut)."""
    from dt_highway.hmi.briefing import Protocol, Screen, load_protocol, render_screen
    from dt_highway.hmi.session import session_plan

    legend = [("Pfeil hoch", "Gas geben (halten)"), ("Pfeil runter", "bremsen (halten)"), ("Esc", "Fahrt beenden (Rückfrage)")]
    protocol = Protocol.model_validate({**load_protocol().model_dump(), "legend": legend})
    trials = session_plan(DriveOptions("P01", "adas", tmp_path / "s"), conditions=["baseline", "sham"], protocol=protocol)
    assert all(t.opts.legend == tuple(legend) for t in trials)
    texts = _spy_text(monkeypatch)
    shown = []

    def on_frame(img):
        shown.append(img)
        if len(shown) == 2:  # the keys screen: Esc, so the trial never starts
            pygame.event.post(pygame.event.Event(pygame.KEYDOWN, key=pygame.K_ESCAPE))

    opts = replace(trials[-1].opts, scenario=V1, overrides=list(QUIET), duration_s=1.5, minimap=False)
    result = run_drive(opts, on_frame=on_frame, say=lambda s: None)
    assert result["status"] == "not started"
    assert {"Pfeil hoch", "Gas geben (halten)", "Fahrt beenden (Rückfrage)", "Press Enter to start"} <= set(texts)
    assert "throttle (hold)" not in texts
    title = f"{trials[-1].label}: the keys"
    expected = render_screen(shown[1].shape[1::-1], Screen(title=title, keys=True), legend, "Press Enter to start")
    np.testing.assert_array_equal(shown[1], expected)  # the session's renderer: its font, colours and layout


def test_a_modifier_key_does_not_answer_the_quit_question(tmp_path, monkeypatch):
    # Shift, Ctrl, Alt (sent again when the window gets the focus back with Alt+Tab) leave the question up;
    # Enter, 1 s later, answers it
    monkeypatch.setattr(screens, "END_SCREEN_S", 0.2)  # "Trial saved" is not what is tested: not 10 s of it
    down = pygame.KEYDOWN
    go_on = threading.Timer(1.0, lambda: pygame.event.post(pygame.event.Event(down, key=pygame.K_RETURN)))
    plan = {2: [pygame.K_RETURN], 20: [pygame.K_ESCAPE],
            21: [pygame.K_LSHIFT, pygame.K_LCTRL, pygame.K_LALT, pygame.K_CAPSLOCK]}  # 21: the question
    shown = []

    def on_frame(img):
        shown.append(img)
        for key in plan.get(len(shown), ()):
            pygame.event.post(pygame.event.Event(down, key=key))
        if len(shown) == 21:
            go_on.start()

    try:
        result = run_drive(_opts(tmp_path, condition="sham", duration_s=3.0), on_frame=on_frame, say=lambda s: None)
    finally:
        go_on.cancel()
    trial = load_trial(result["directory"])
    ends = [e for e in trial.events if e["kind"] == "pause_end"]
    assert result["status"] == "completed" and len(ends) == 1 and ends[0]["duration_s"] >= 0.9


def test_a_signal_while_a_scripted_trial_is_prepared_stops_it_before_the_start(tmp_path, monkeypatch):
    real_make = drive.gym.make

    def make(*a, **k):
        os.kill(os.getpid(), signal.SIGINT)  # Ctrl-C while the env is made (in the preparing thread)
        return real_make(*a, **k)

    monkeypatch.setattr(drive.gym, "make", make)
    lines: list[str] = []
    result = run_drive(_opts(tmp_path, keys_from=KeyScript([])), say=lines.append)
    assert result["status"] == "not started" and result["end_reason"] == "SIGINT"
    assert lines[0].endswith("nothing saved") and not Path(result["directory"]).exists()


def test_the_window_reads_its_events_while_the_trial_is_prepared(tmp_path, monkeypatch):
    # a close during the seconds the env takes is seen (the window answers; it is not frozen)
    real_make = drive.gym.make

    def make(*a, **k):
        pygame.event.post(pygame.event.Event(pygame.QUIT))
        time.sleep(0.3)  # the window's thread reads it meanwhile
        assert not pygame.event.peek(pygame.QUIT)
        return real_make(*a, **k)

    monkeypatch.setattr(drive.gym, "make", make)
    result = run_drive(_opts(tmp_path), say=lambda s: None)
    assert result["status"] == "not started" and result["end_reason"] == "window closed"


def test_any_key_but_esc_answers_the_quit_question_go_on_enter_and_space_included(tmp_path, monkeypatch):
    # the question says "any other key: go on"; Enter, a letter and Space are not trial keys, and answered it too
    monkeypatch.setattr(screens, "END_SCREEN_S", 0.2)  # "Trial saved" is not what is tested: not 10 s of it
    down = pygame.KEYDOWN
    plan = {2: [(down, pygame.K_RETURN)],  # the keys screen
            20: [(down, pygame.K_ESCAPE)], 21: [(down, pygame.K_RETURN)],  # the question (frame 21), then Enter
            30: [(down, pygame.K_ESCAPE)], 31: [(down, pygame.K_SPACE)],
            40: [(down, pygame.K_ESCAPE)], 41: [(down, pygame.K_a)],
            50: [(down, pygame.K_ESCAPE)], 51: [(down, pygame.K_ESCAPE)]}
    # a trial stuck at the question would never end: Esc after 15 s quits it (and the test fails, not hangs)
    stuck = threading.Timer(15.0, lambda: pygame.event.post(pygame.event.Event(down, key=pygame.K_ESCAPE)))
    stuck.start()
    try:
        result, shown, _ = _interactive(tmp_path, plan)
    finally:
        stuck.cancel()
    assert result["status"] == "aborted" and result["end_reason"] == "quit by the participant"
    trial = load_trial(result["directory"])
    starts = [e for e in trial.events if e["kind"] == "pause_start"]
    ends = [e for e in trial.events if e["kind"] == "pause_end"]  # the last when the trial ended
    assert len(starts) == len(ends) == 4 and {e["reason"] for e in starts} == {"Esc"}
    assert len(shown) > 51  # the trial went on after each answer
    # only the trial's keys are logged as keys
    assert {k[2] for k in _keys(trial)} == {"ESC"}


def test_a_practice_trial_ends_on_practice_saved_not_trial_saved(tmp_path, monkeypatch):
    # the briefing says practices do not count: the screen after one does not call it a trial
    titles = []
    orig_card = screens.card

    def card(size, title, lines, **kw):
        titles.append(title)
        if title.endswith("saved"):
            pygame.event.post(pygame.event.Event(pygame.KEYDOWN, key=pygame.K_RETURN))
        return orig_card(size, title, lines, **kw)

    monkeypatch.setattr(screens, "card", card)
    shown = []

    def on_frame(img):
        shown.append(img)
        if len(shown) == 2:  # the keys screen
            pygame.event.post(pygame.event.Event(pygame.KEYDOWN, key=pygame.K_RETURN))

    result = run_drive(_opts(tmp_path, practice=True, duration_s=1.0), on_frame=on_frame, say=lambda s: None)
    assert result["status"] == "completed" and titles[-1] == "Practice saved" and "Trial saved" not in titles


def test_interactive_keys_held_through_the_countdown_sub_step_times_and_enter_only_end_screen(tmp_path, monkeypatch):
    down, up = pygame.KEYDOWN, pygame.KEYUP
    texts = _spy_text(monkeypatch)
    end_shown = []
    orig_card = screens.card

    def card(size, title, lines, **kw):  # on the end screen: a stray arrow and a letter first, Enter only 0.6 s later
        if title == "Trial saved":
            end_shown.append(time.monotonic())
            pygame.event.post(pygame.event.Event(down, key=pygame.K_UP))
            pygame.event.post(pygame.event.Event(down, key=pygame.K_a))
            threading.Timer(0.6, lambda: pygame.event.post(pygame.event.Event(down, key=pygame.K_RETURN))).start()
        return orig_card(size, title, lines, **kw)

    monkeypatch.setattr(screens, "card", card)  # the end screen's (hmi.screens)
    plan = {2: [(down, pygame.K_RETURN)],  # the keys screen
            3: [(down, pygame.K_UP)],  # during "3": held through the countdown
            12: [(down, pygame.K_LEFT)], 14: [(up, pygame.K_LEFT)], 20: [(up, pygame.K_UP)],
            30: [(down, pygame.K_ESCAPE)], 31: [(down, pygame.K_ESCAPE)]}  # paused: no new picture after the question
    captions = []
    result, shown, lines = _interactive(tmp_path, plan, captions=captions)
    t_end = time.monotonic()
    assert result["status"] == "aborted" and result["end_reason"] == "quit by the participant"
    trial = load_trial(result["directory"])
    keys = _keys(trial)
    assert keys[0] == (0.0, "key_down", "UP") and trial.events[[e["kind"] for e in trial.events].index("key_down")][
        "pressed_at_s"] < -1.0  # pressed during "3"
    assert [k[1:] for k in keys] == [("key_down", "UP"), ("key_down", "LEFT"), ("key_up", "LEFT"), ("key_up", "UP"),
                                     ("key_down", "ESC"), ("key_down", "ESC")]
    _no_release_without_press(trial)
    times = [k[0] for k in keys]
    assert times == sorted(times)
    on_grid = [abs(t * 15 - round(t * 15)) < 1e-3 for t in times[1:4]]
    assert not all(on_grid)  # times at the moment, not rounded to the 67 ms step
    walls = [datetime.fromisoformat(e["wall_time"]) for e in trial.events if e["kind"] in ("key_down", "key_up")]
    dt_wall = (walls[3] - walls[1]).total_seconds()  # LEFT down -> UP up: no pause between
    assert dt_wall == pytest.approx(times[3] - times[1], abs=0.07)
    # the screens: a neutral label, never the condition, never a path; the title is dt-highway
    said = " | ".join(texts).lower()
    assert "trial 2" in said and "sham" not in said and "adas" not in said and "baseline" not in said
    assert "trials/" not in said and str(tmp_path).lower() not in said and "p01-" not in said
    assert set(captions) == {"dt-highway"}
    assert any(t == "Quit the trial?" for t in texts)
    # "Trial saved" waited for Enter: the arrow and the letter did not dismiss it
    assert len(end_shown) == 1 and t_end - end_shown[0] >= 0.55
    # the experimenter's line in the terminal
    lines = [line for line in lines if not line.startswith("  warning:")]  # a slow machine's warning, if any
    assert len(lines) == 1 and lines[0].startswith("P01 sham: aborted (quit by the participant), ")
    assert "0 crashes" in lines[0] and " of 30 s" in lines[0] and str(tmp_path) in lines[0]


# ------------------------------------------------------------------------------------ 2. window close, signals
def test_a_window_manager_close_ends_the_trial_within_a_second(tmp_path):
    posted = []
    n = [0]

    def on_frame(img):
        n[0] += 1
        if n[0] == 2:  # the keys screen
            pygame.event.post(pygame.event.Event(pygame.KEYDOWN, key=pygame.K_RETURN))
        if n[0] == 15:  # in the trial: the window manager closes the window
            posted.append(time.monotonic())
            pygame.event.post(pygame.event.Event(pygame.QUIT))

    result = run_drive(_opts(tmp_path, duration_s=30.0), on_frame=on_frame, say=lambda s: None)
    took = time.monotonic() - posted[0]
    assert result["status"] == "aborted" and result["end_reason"] == "window closed"
    assert took < 1.0, took
    trial = load_trial(result["directory"])
    assert [e["kind"] for e in trial.events if e["kind"] == "window_closed"] == ["window_closed"]


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_sigterm_and_sigint_end_the_trial_as_such(tmp_path, sig):
    before = {s: signal.getsignal(s) for s in (signal.SIGTERM, signal.SIGINT)}
    n = [0]

    def on_frame(img):
        n[0] += 1
        if n[0] == 15:
            os.kill(os.getpid(), sig)

    result = run_drive(_opts(tmp_path, keys_from=KeyScript([]), duration_s=30.0), on_frame=on_frame, say=lambda s: None)
    name = signal.Signals(sig).name
    assert result["status"] == "aborted" and result["end_reason"] == name
    trial = load_trial(result["directory"])
    assert trial.meta["end_reason"] == name and trial.meta["status"] == "aborted"
    assert [e["signal"] for e in trial.events if e["kind"] == "signal"] == [name]
    assert trial.steps["t_s"].max() < 5.0
    assert {s: signal.getsignal(s) for s in before} == before  # handlers given back


def test_sigterm_to_a_drive_process_is_logged_as_sigterm(tmp_path):
    import subprocess

    out = tmp_path / "s"
    keys = tmp_path / "k.txt"
    keys.write_text("0.1 down UP\n")
    proc = subprocess.Popen([sys.executable, "-m", "dt_highway.cli", "drive", "--participant", "P09", "--condition",
                             "baseline", "--duration", "60", "--out", str(out), "--keys-from", str(keys),
                             "--scenario", V1, *[a for o in QUIET for a in ("--set", o)], "--no-minimap"],
                            env={**os.environ, "SDL_VIDEODRIVER": "offscreen"}, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    steps = out / "trials" / "P09-baseline" / "steps.csv"
    deadline = time.time() + 120
    while time.time() < deadline and not (steps.exists() and len(steps.read_text().splitlines()) > 20):
        time.sleep(0.2)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=30)
    assert proc.returncode == 1
    meta = json.loads((out / "trials" / "P09-baseline" / "meta.json").read_text())
    assert meta["status"] == "aborted" and meta["end_reason"] == "SIGTERM"
    assert "P09 baseline: aborted (SIGTERM)" in err


# ------------------------------------------------------------------------------------ 3. crashes
CRASH = {"scenario": "envs/highway-trial.toml", "seed": 4, "duration_s": 2.4,
         "keys_from": None}  # this seed's traffic hits the ego at 1.7 s under the script below (15 Hz)
CRASH_SCRIPT = "0.2 down UP\n1.0 up UP\n1.2 down LEFT\n1.3 up LEFT\n1.6 down DOWN\n2.0 up DOWN\n"


def _crash_run(tmp_path, on_crash, duration_s, frames=None):
    opts = _opts(tmp_path, **{**CRASH, "keys_from": KeyScript.parse(CRASH_SCRIPT), "duration_s": duration_s,
                              "on_crash": on_crash, "screenshot_every_s": 0.1})
    lines = []
    result = run_drive(opts, on_frame=None if frames is None else frames.append, say=lines.append)
    return result, load_trial(result["directory"]), lines


def test_a_crash_under_end_is_shown_and_flagged_not_completed(tmp_path):
    frames = []
    t0 = time.monotonic()
    result, trial, lines = _crash_run(tmp_path, "end", 2.4, frames)
    assert result["status"] == "ended_by_collision" and result["collisions"] == 1
    meta = trial.meta
    assert meta["status"] == "ended_by_collision" and meta["cut_short"] is True and meta["end_reason"] == "collision"
    assert meta["collision"]["count"] == 1 and meta["collision"]["policy"] == "end"
    t_crash = meta["collision"]["t_s"][0]
    assert t_crash == pytest.approx(trial.steps["t_s"].max()) and t_crash < 2.4
    assert [e["t_s"] for e in trial.collisions] == [pytest.approx(t_crash)]
    banner = [f for f in frames if (f[int(f.shape[0] * 0.22) + 2] == (200, 20, 20)).all(axis=-1).mean() > 0.5]
    # the flash is a new picture every window frame, the banner after it one picture (drawn once, not redrawn)
    assert len(banner) >= 5 and not any(banner[i] is banner[i + 1] for i in range(len(banner) - 1))
    assert time.monotonic() - t0 > t_crash + CRASH_BANNER_S - 0.2
    assert "1 crash," in lines[0] and "ended_by_collision" in lines[0]
    # the report takes it as data, flagged: cut short by a collision, never silently paired
    assert check_trial(trial) is None
    metrics = trial.metrics()
    assert metrics["cut_short"] is True or metrics["cut_short"] == 1


def test_a_crash_under_continue_puts_the_ego_back_and_counts_it(tmp_path):
    result, trial, _ = _crash_run(tmp_path, "continue", 4.0)
    meta = trial.meta
    assert result["status"] == "completed" and meta["status"] == "completed" and meta["cut_short"] is False
    n = meta["collision"]["count"]
    assert n >= 1 and n == len(trial.collisions) and meta["collision"]["policy"] == "continue"
    resets = [e for e in trial.events if e["kind"] == "ego_reset"]
    assert len(resets) == n and resets[0]["t_s"] == pytest.approx(meta["collision"]["t_s"][0])
    s = trial.steps.set_index("t_s")
    assert s.index.max() == pytest.approx(4.0)  # the whole trial
    after = s.loc[resets[0]["t_s"] + 0.01:resets[0]["t_s"] + 0.5]
    assert not after["crashed"].any()
    assert after["x_m"].iloc[0] == pytest.approx(resets[0]["x_m"], abs=3.0)
    assert resets[0]["lane"] == after["lane"].iloc[0]  # lane ids counted as in steps.csv (0 = leftmost)
    assert after["speed_mps"].iloc[0] == pytest.approx(resets[0]["speed_mps"], abs=1.0)
    gap = after["gap_m"].iloc[0]
    assert not gap < max(30.0, 2.0 * resets[0]["speed_mps"]) - 3.0  # a clear gap ahead (NaN: no leader)


def test_the_crash_layer_flashes_red_then_shows_the_banner_then_nothing():
    img = np.full((360, 640, 3), 100, np.uint8)
    first, later, gone = crash_layer(img, 0.0), crash_layer(img, 1.0), crash_layer(img, CRASH_BANNER_S + 0.01)
    assert first[5, 5, 0] > 150 and first[5, 5, 1] < 80  # red tint at the crash: 100 -> 0.5 * 100 + 0.5 * 255
    assert tuple(later[5, 5]) == (100, 100, 100)  # the flash faded after 0.5 s
    assert tuple(later[int(360 * 0.22) + 2, 5]) == (200, 20, 20)  # the banner is still up
    assert gone is img and tuple(img[5, 5]) == (100, 100, 100)


def test_the_beep_is_made_for_the_mixer_format_and_is_silent_without_a_device(monkeypatch):
    s = beep_samples(44100, -16, 2, 880.0, 0.35)
    assert s.shape == (15435, 2) and s.dtype == np.int16 and s[:, 0].tolist() == s[:, 1].tolist()
    assert 0.39 * 32767 < np.abs(s).max() <= 0.4 * 32767 + 1 and s[0, 0] == 0
    assert beep_samples(22050, 32, 1).dtype == np.float32
    with pytest.raises(ValueError, match="sample format"):
        beep_samples(44100, 24, 1)
    pygame.mixer.quit()
    monkeypatch.setenv("SDL_AUDIODRIVER", "dummy")
    try:
        beep = drive.CrashBeep()
        assert beep.sound is not None and beep.play()
    finally:
        pygame.mixer.quit()
    monkeypatch.setenv("SDL_AUDIODRIVER", "nosuchdriver")
    silent = drive.CrashBeep()
    assert silent.sound is None and silent.play() is False
    assert drive.CrashBeep(enabled=False).sound is None


def test_a_bad_crash_policy_is_one_line(tmp_path, capsys):
    with pytest.raises(ConfigError, match="--on-crash must be one of end, continue"):
        run_drive(_opts(tmp_path, on_crash="stop"))
    with pytest.raises(SystemExit, match="2"):
        main(["drive", "--participant", "P01", "--condition", "adas", "--out", str(tmp_path / "s"), "--on-crash", "stop"])
    assert "--on-crash" in capsys.readouterr().err


def test_a_trial_already_in_its_folder_is_kept_unless_forced(tmp_path, capsys):
    held = drive.trial_dir(tmp_path / "s", "P01", "adas", False)
    held.mkdir(parents=True)
    (held / "meta.json").write_text(json.dumps({"status": "completed"}))
    (held / "steps.csv").write_text("t_s\n0.0\n")
    with pytest.raises(ConfigError, match=r"P01-adas holds a trial already \(status completed\): pass --force"):
        run_drive(_opts(tmp_path, keys_from=KeyScript.parse("")))
    assert main(["drive", "--participant", "P01", "--condition", "adas", "--out", str(tmp_path / "s"),
                 "--keys-from", os.devnull]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "holds a trial already" in err
    assert (held / "steps.csv").read_text() == "t_s\n0.0\n"  # nothing touched
    # a set-up practice trial is not in a folder a session would take for its own practice trial
    assert drive.trial_dir(tmp_path, "P01", "adas", True).name == "P01-practice" != trial_name("P01", "adas", True)
    (held / "questionnaires.json").write_text("{}")  # the old trial's answers: replaced with it
    result = run_drive(_opts(tmp_path, keys_from=KeyScript.parse(""), force=True))
    assert result["status"] == "completed" and load_trial(held).meta["status"] == "completed"
    assert len(load_trial(held).steps) > 1 and not (held / "questionnaires.json").exists()


# ------------------------------------------------------------------------------------ 4. screens
@pytest.mark.parametrize("size", [(480, 270), (640, 360), (1920, 1080)])
def test_the_quit_question_and_the_pause_text_do_not_overlap(size):
    w, h = size
    img = np.zeros((h, w, 3), np.uint8)
    rects = dialog(img, QUIT_LINES)
    assert len(rects) == 3
    for i, a in enumerate(rects):
        assert 0 <= a[0] < a[2] <= w and 0 <= a[1] < a[3] <= h
        for b in rects[i + 1:]:
            assert a[3] <= b[1] or b[3] <= a[1] or a[2] <= b[0] or b[2] <= a[0], (a, b)


def test_the_quit_question_replaces_the_pause_text(monkeypatch):
    texts = _spy_text(monkeypatch)
    snap = drive._Snapshot(np.zeros((270, 480, 3), np.uint8), None, Hud(90, 2, 3, 30, "Trial 1", True), None, 3)
    trial = types.SimpleNamespace(paused=True, confirm_quit=False)
    drive._window_frame(trial, snap)
    assert "PAUSED" in texts and "Quit the trial?" not in texts
    texts.clear()
    trial.confirm_quit = True
    drive._window_frame(trial, snap)
    assert "Quit the trial?" in texts and "PAUSED" not in texts


def test_practice_shows_practice_and_the_label_is_what_the_caller_says(tmp_path):
    assert DriveOptions("P1", "adas", tmp_path).label == "Trial"
    assert DriveOptions("P1", "adas", tmp_path, practice=True).label == "Practice"
    assert DriveOptions("P1", "sham", tmp_path, display_label="Trial 3").label == "Trial 3"


# ------------------------------------------------------------------------------------ 5. view
def test_size_is_validated_in_one_line(tmp_path, capsys):
    assert parse_size("1280x720") == (1280, 720) and parse_size(" 800X600 ") == (800, 600)
    for bad in ("1280", "10x10", "axb", "99999x1", "1280x720x3", ""):
        with pytest.raises(ConfigError, match=r"--size must be WIDTHxHEIGHT in pixels, width 160\.\.4096"):
            parse_size(bad)
    with pytest.raises(SystemExit, match="2"):
        main(["drive", "--participant", "P01", "--condition", "adas", "--out", str(tmp_path / "s"), "--size", "big"])
    err = capsys.readouterr().err
    assert "--size must be WIDTHxHEIGHT" in err and len(err.strip().splitlines()) == 1


def test_the_frame_is_scaled_to_a_resized_window_and_to_fullscreen():
    img = np.full((180, 320, 3), (10, 200, 30), np.uint8)
    try:
        win = _Window((320, 180))
        assert pygame.display.get_caption()[0] == "dt-highway"
        pygame.display.set_mode((640, 480), pygame.RESIZABLE)  # as the window manager would resize it
        pygame.event.post(pygame.event.Event(pygame.WINDOWSIZECHANGED, x=640, y=480))
        win.events()
        win.show(img)
        screen = pygame.surfarray.array3d(pygame.display.get_surface()).transpose(1, 0, 2)
        assert screen.shape == (480, 640, 3)
        # 320x180 times 2 = 640x360, centred: black bars of 60 px above and below
        assert tuple(screen[59, 320]) == (0, 0, 0) and tuple(screen[60, 320]) == (10, 200, 30)
        assert tuple(screen[419, 320]) == (10, 200, 30) and tuple(screen[420, 320]) == (0, 0, 0)
    finally:
        pygame.quit()
    try:
        win = _Window((320, 180), fullscreen=True)
        fw, fh = pygame.display.get_surface().get_size()
        win.show(img)
        screen = pygame.surfarray.array3d(pygame.display.get_surface()).transpose(1, 0, 2)
        k = min(fw / 320, fh / 180)
        top = (fh - round(180 * k)) // 2
        assert tuple(screen[top + 2, fw // 2]) == (10, 200, 30) and (top == 0 or tuple(screen[top - 2, fw // 2]) == (0, 0, 0))
    finally:
        pygame.quit()


def _count_flips(monkeypatch):
    flips = []
    real = pygame.display.flip
    monkeypatch.setattr(pygame.display, "flip", lambda: (flips.append(time.monotonic()), real())[1])
    return flips


def test_an_unchanged_picture_is_not_flipped_again_but_a_new_one_a_resize_and_an_expose_are(monkeypatch):
    flips = _count_flips(monkeypatch)
    img = np.full((180, 320, 3), 40, np.uint8)
    seen = []
    try:
        win = _Window((320, 180), on_frame=seen.append)
        assert win.show(img) is True and win.show(img) is False and win.show(img) is False
        assert len(flips) == 1 and seen == [img]
        same_content = img.copy()  # another picture (the window does not compare pixels)
        assert win.show(same_content) is True and win.show(same_content) is False and len(flips) == 2
        pygame.display.set_mode((640, 480), pygame.RESIZABLE)  # as the window manager would resize it
        pygame.event.post(pygame.event.Event(pygame.WINDOWSIZECHANGED, x=640, y=480))
        win.events()
        assert win.show(same_content) is True and len(flips) == 3  # the new size: drawn again
        pygame.event.post(pygame.event.Event(pygame.WINDOWEXPOSED))
        win.events()
        assert win.show(same_content) is True and win.show(same_content) is False and len(flips) == 4
        assert len(seen) == 4 == win.flips
    finally:
        pygame.quit()


def test_a_trial_flips_once_per_simulation_step_while_keys_are_read_at_the_window_rate(tmp_path, monkeypatch):
    flips = _count_flips(monkeypatch)
    events = []
    real_get = pygame.event.get
    monkeypatch.setattr(pygame.event, "get", lambda *a, **k: (events.append(1), real_get(*a, **k))[1])
    result = run_drive(_opts(tmp_path, keys_from=KeyScript([KeyEvent(0.2, True, "UP")]), duration_s=2.0, fps=60),
                       say=lambda _: None)
    n_steps = round(result["trial_sim_s"] * 15)
    assert result["status"] == "completed" and 30 <= n_steps <= 31
    # 15 Hz for 2 s: the picture of t = 0 and of each step, each flipped once (no crash in this trial)
    assert len(flips) == result["frames"] == len(result["frame_ms"]) <= n_steps + 1
    assert len(flips) >= 25  # every step's picture was shown (some may be passed over under load)
    assert len(events) > 2 * len(flips)  # the events were read at up to 60 frames/s meanwhile


def test_trials_simulate_at_30_hz_unless_told_otherwise(tmp_path):
    cfg, overrides, f = _trial_config(DriveOptions("P1", "adas", tmp_path, scenario="envs/highway-trial.toml"))
    assert f == 30 and cfg.highway.simulation_frequency == 30 and cfg.highway.policy_frequency == 30
    assert overrides[0] == "highway.simulation_frequency=30"
    cfg, _, f = _trial_config(DriveOptions("P1", "adas", tmp_path, scenario="envs/highway-trial.toml",
                                           overrides=["highway.simulation_frequency=15"], size=(1280, 720)))
    assert f == 15 and cfg.highway.policy_frequency == 15  # the caller's --set wins
    assert (cfg.camera.width_px, cfg.camera.height_px) == (1280, 720)
    cfg, _, f = _trial_config(DriveOptions("P1", "adas", tmp_path, scenario="envs/highway-trial.toml", simulation_hz=None))
    assert f == 15  # the scenario's
    with pytest.raises(ConfigError, match=r"offscreen_rendering = false is not for keyboard trials"):
        _trial_config(DriveOptions("P1", "adas", tmp_path, scenario="envs/highway-trial.toml",
                                   overrides=["highway.offscreen_rendering=false"]))


def test_a_trial_closes_its_window_unless_asked_to_keep_it_for_a_session(tmp_path):
    script = "0.1 down UP\n0.5 up UP\n"
    run_drive(_opts(tmp_path / "a", keys_from=KeyScript.parse(script)), say=lambda s: None)
    assert not pygame.display.get_init() or pygame.display.get_surface() is None  # dt-highway drive: closed
    try:
        run_drive(_opts(tmp_path / "b", keys_from=KeyScript.parse(script)), say=lambda s: None, keep_window=True)
        window = pygame.display.get_surface()
        assert window is not None
        run_drive(_opts(tmp_path / "c", keys_from=KeyScript.parse(script)), say=lambda s: None, keep_window=True)
        assert pygame.display.get_surface() is window  # the next trial draws in the same window
    finally:
        pygame.quit()


def test_the_mirror_hook_draws_what_render_mirrors_returns(tmp_path, monkeypatch):
    calls = []

    def render_mirrors(env, size):
        calls.append(size)
        return np.full((size[1], size[0], 3), (255, 0, 255), np.uint8)

    monkeypatch.setattr(drive, "render_mirrors", render_mirrors)
    result = run_drive(_opts(tmp_path, keys_from=KeyScript([]), duration_s=0.5, mirrors=True, screenshot_every_s=0.5),
                       say=lambda s: None)
    mw, mh = round(480 * MIRROR_FRACTION[0]), round(270 * MIRROR_FRACTION[1])
    assert calls and set(calls) == {(mw, mh)}
    from PIL import Image

    last = sorted((Path(result["directory"]) / "screenshots").iterdir())[-1]  # t0000.53s.png: the step after 0.5 s
    shot = np.asarray(Image.open(last).convert("RGB"))
    magenta = (shot == (255, 0, 255)).all(axis=-1)
    ys, xs = np.nonzero(magenta)
    assert magenta.sum() >= 0.9 * mw * mh and abs((xs.min() + xs.max()) / 2 - 240) <= 2 and ys.min() < 20


def test_compose_frame_never_draws_the_condition(monkeypatch):
    texts = _spy_text(monkeypatch)
    compose_frame(np.zeros((270, 480, 3), np.uint8), None, Hud(100.0, 1, 3, 12.0, "Trial 1"))
    assert "Trial 1" in texts and not any("adas" in t.lower() or "baseline" in t.lower() for t in texts)


def test_a_near_cars_warning_is_not_hidden_under_the_mirror_or_the_trial_label():
    """A car close by, its box reaching the top of the picture: the label goes inside the box below the
    mirror and the trial's label (drawn over the picture afterwards), so its amber banner is seen."""
    from dt_highway.overlay import THREAT_RGB
    mark = {"vehicle_id": 1, "box": [0.0, 40.0, 220.0, 300.0], "label": "cutting in from left", "confidence": 0.8,
            "distance_m": 5.0, "cue": "threat", "side": "left"}
    img = compose_frame(np.full((360, 640, 3), 90, np.uint8), [mark], Hud(40.0, 2, 3, 30.0, "Trial 1"),
                        mirror=np.zeros((60, 380, 3), np.uint8))
    inside = (img[46:294, 6:214] == THREAT_RGB).all(axis=-1)  # within the box's outline
    assert inside.sum() > 1500  # the banner's fill (about 150 x 35 px); above the box it would be hidden



def test_a_near_cars_box_stops_at_the_hud_band():
    """The HUD's darkened band is drawn over the picture's bottom: a box of a car close by ends at the band's top
    edge instead of running on under the speed readout."""
    from dt_highway.overlay import MARK_RGB
    mark = {"vehicle_id": 1, "box": [100.0, 150.0, 400.0, 359.0], "label": "aggressive driver", "distance_m": 6.0,
            "cue": "type"}
    img = compose_frame(np.full((360, 640, 3), 90, np.uint8), [mark], Hud(40.0, 2, 3, 30.0, "Trial 1"))
    top = 360 - picture.hud_band_height((640, 360))
    band = img[top + 1:, 90:410].astype(int)
    dimmed_mark = (np.asarray(MARK_RGB) * 0.45).astype(int)
    assert not (np.abs(band - dimmed_mark).sum(axis=-1) < 30).any()  # no box line under the band
    edge = (img[top - 3:top, 100:400] == MARK_RGB).all(axis=-1)  # the box's bottom edge, just above it
    assert edge.mean(axis=1).max() > 0.9

# ------------------------------------------------------------------------------------------ a wheel (issue 20)
WHEEL_CAL = {"device": "test wheel",  # throttle resting at -1 (pressed: +1), brake resting at +1 (pressed: -1)
             "steer": {"axis": 0, "min": -1.0, "centre": 0.0, "max": 1.0, "deadzone": 0.0},
             "throttle": {"axis": 1, "min": -1.0, "centre": -1.0, "max": 1.0, "deadzone": 0.03},
             "brake": {"axis": 2, "min": -1.0, "centre": 1.0, "max": 1.0, "deadzone": 0.03}}


@pytest.fixture
def virtual_wheel():
    from dt_highway.hmi.joystick import VirtualJoystick

    pygame.display.init()
    pygame.joystick.init()
    dev = VirtualJoystick(n_axes=3)
    for axis, value in enumerate((0.0, -1.0, 1.0)):  # at rest
        dev.set_axis(axis, value)
    yield dev
    dev.close()
    pygame.quit()


def test_a_wheel_drives_the_trial_throttle_held_and_one_lane_change_per_turn(tmp_path, virtual_wheel):
    cal = tmp_path / "wheel.json"
    cal.write_text(json.dumps(WHEEL_CAL))
    virtual_wheel.set_axis(1, 1.0)  # full throttle, held from before the start
    frames = []

    def on_frame(_img):
        frames.append(1)
        if len(frames) == 20:  # the wheel turned 0.7 to the right (past 0.5) and held there
            virtual_wheel.set_axis(0, 0.7)

    opts = _opts(tmp_path, "P01", "baseline", duration_s=3.0, keys_from=KeyScript([]), wheel=virtual_wheel.index,
                 wheel_calibration=cal)
    result = run_drive(opts, on_frame=on_frame, say=lambda _: None)
    assert result["status"] == "completed"
    trial = load_trial(result["directory"])
    steps = trial.steps.iloc[1:]  # row 0: the state at t = 0, before any action
    # full throttle: coast -0.3 + 1 * (2.5 + 0.3) = 2.5 m/s^2 at every step (SDL keeps 16 bits: within 1e-3)
    assert np.allclose(steps["action_accel_mps2"], 2.5, atol=1e-3)
    assert steps["speed_mps"].iloc[-1] > trial.steps["speed_mps"].iloc[0] + 4.0
    # one lane request (to the right) for one turn held past the threshold
    assert list(steps["action_lane"][steps["action_lane"] != 0]) == [1.0]
    assert "wheel:steer=+0.700,throttle=1.000,brake=0.000" in set(steps["keys"])
    assert steps["keys"].iloc[0] == "wheel:steer=+0.000,throttle=1.000,brake=0.000"
    lane_changes = [e for e in trial.events if e["kind"] == "lane_change"]
    assert len(lane_changes) == 1 and lane_changes[0]["to_lane"] == lane_changes[0]["from_lane"] + 1
    assert trial.meta["wheel"]["calibration"]["throttle"]["axis"] == 1
    assert trial.meta["driver_params"]["wheel"] == virtual_wheel.index


def test_a_missing_wheel_calibration_runs_the_calibration_screen_and_saves_it(tmp_path, virtual_wheel, monkeypatch):
    from dt_highway.hmi.joystick import Calibration

    seen = []

    def fake_screen(device, save_to=None, window=None, **_):  # what a person would have made on the screen
        seen.append((device.get_numaxes(), window is not None))
        cal = Calibration.model_validate(WHEEL_CAL)
        cal.save(save_to)
        return cal

    monkeypatch.setattr(drive, "calibration_screen", fake_screen)
    cal = tmp_path / "cal" / "wheel.json"
    opts = _opts(tmp_path, "P01", "baseline", duration_s=0.5, keys_from=KeyScript([]), wheel=virtual_wheel.index,
                 wheel_calibration=cal)
    assert run_drive(opts, say=lambda _: None)["status"] == "completed"
    assert seen == [(3, True)] and Calibration.load(cal).device == "test wheel"


def test_a_wheel_that_is_not_there_is_one_line_naming_the_option(tmp_path, capsys):
    rc = main(["drive", "--participant", "P01", "--condition", "baseline", "--out", str(tmp_path / "s"),
               "--scenario", V1, "--duration", "1", "--keys-from", os.devnull, "--wheel", "7"])
    err = capsys.readouterr().err.strip()
    assert rc != 0 and len(err.splitlines()) == 1
    assert "--wheel 7: joystick 7 not found" in err
    with pytest.raises(ConfigError, match="--wheel 7: joystick 7 not found"):
        run_drive(_opts(tmp_path, keys_from=KeyScript([]), wheel=7), say=lambda _: None)
    # a session: before its briefing (no window, no trial directory)
    rc = main(["session", "--participant", "P01", "--out", str(tmp_path / "t"), "--keys-from", os.devnull, "--wheel", "7"])
    err = capsys.readouterr().err.strip()
    assert rc != 0 and len(err.splitlines()) == 1 and "--wheel 7: joystick 7 not found" in err
    assert not (tmp_path / "t" / "trials").exists()
    # --wheel without an index: device 0; --wheel-calibration alone is refused
    rc = main(["drive", "--participant", "P01", "--condition", "baseline", "--out", str(tmp_path / "u"),
               "--keys-from", os.devnull, "--wheel-calibration", "w.json"])
    assert rc != 0 and "--wheel-calibration FILE needs --wheel" in capsys.readouterr().err


def test_a_key_script_file_may_press_keys_during_the_countdown(tmp_path):
    # the DriveOptions docstring: "events at negative times are keys pressed during the countdown", in a file too
    script = KeyScript.parse("-2.5 down UP   # held through the countdown\n-1 down LEFT\n-0.5 up LEFT\n0.3 up UP\n")
    assert [e.t_s for e in script.events] == [-2.5, -1.0, -0.5, 0.3]
    result = run_drive(_opts(tmp_path, "P01", "baseline", duration_s=1.0, keys_from=script), say=lambda s: None)
    trial = load_trial(result["directory"])
    # UP held at 0 s: pressed then (when: -2.5 s); LEFT pressed and released in the countdown: no lane change
    assert _keys(trial) == [(0.0, "key_down", "UP"), (0.3, "key_up", "UP")]
    assert next(e for e in trial.events if e["kind"] == "key_down")["pressed_at_s"] == -2.5
    accel = trial.steps["action_accel_mps2"].to_numpy()
    assert accel[0] == pytest.approx(-0.3 + 2.5 / 15)  # the throttle from the first step (15 Hz)
    assert not (trial.steps["action_lane"] != 0).any()


def test_drive_that_did_not_start_prints_that_nothing_was_saved(tmp_path, monkeypatch, capsys):
    not_started = {"directory": str(tmp_path / "s" / "trials" / "P01-adas"), "status": "not started",
                   "end_reason": "quit before the start", "frames": 0, "screenshots": 0}
    monkeypatch.setattr("dt_highway.hmi.drive.run_drive", lambda opts: not_started)
    assert main(["drive", "--participant", "P01", "--condition", "adas", "--out", str(tmp_path / "s")]) == 1
    out = capsys.readouterr().out
    assert out.strip() == "trial not started (quit before the start): nothing saved"

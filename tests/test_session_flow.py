"""A participant's whole session, scripted: the protocol's screens, practice in every condition,
neutral labels, every attempt kept (retry folders), aborted attempts in the report, SIGTERM,
questionnaires between trials; and the protocol file's checks (one-line errors)."""

import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pygame
import pytest

from dt_highway.cli import find_file_or_default, main
from dt_highway.config import ConfigError
from dt_highway.hmi.briefing import DEFAULT_PROTOCOL, TextFont, load_protocol, render_screen
from dt_highway.hmi.drive import DriveOptions, run_drive, trial_dir, trial_settings
from dt_highway.hmi.keys import KeyScript
from dt_highway.hmi.session import STAGING, attempt_dirs, run_session, session_plan, status_line
from dt_highway.metrics.trial_log import TrialWriter, load_trial

SETS = ["highway.vehicles_count=16", "twin.preroll_s=20", "camera.width_px=480", "camera.height_px=270",
        "highway.simulation_frequency=15"]
FAST = [x for s in SETS for x in ("--set", s)] + ["--no-minimap"]
KEYS = "0.1 down UP\n0.8 up UP\n"
DISTRUST = ("deceptive", "underhanded", "suspicious", "wary", "harmful")
TRUSTING = ("confident", "security", "integrity", "dependable", "reliable", "trust", "familiar")
ANSWERS = {"nasa_tlx": {"mental": 20, "physical": 40, "temporal": 60, "performance": 80, "effort": 10, "frustration": 30},
           "trust_jian2000": {**dict.fromkeys(DISTRUST, 2), **dict.fromkeys(TRUSTING, 5)}}
TLX = (20 + 40 + 60 + 80 + 10 + 30) / 6  # 40.0: raw TLX, the plain mean
TRUST = (5 * (8 - 2) + 7 * 5) / 12  # 5.4167: distrust items 1-5 reversed (8 - rating), then the mean


def _base(out: Path, participant: str = "P01", **kw) -> DriveOptions:
    return DriveOptions(participant, "baseline", out, scenario=find_file_or_default(None), overrides=list(SETS),
                        duration_s=3.0, minimap=False, keys_from=KeyScript.parse(KEYS), **kw)  # the CLI's scenario


def _fake_drive(abort: set[str], calls: list[tuple]):
    """A trial without a window: a log with no steps, ``aborted`` for the attempts named in ``abort``."""

    def drive(opts: DriveOptions) -> dict:
        attempt = Path(opts.out).name  # the staging folder is named after the attempt
        calls.append((attempt, opts.condition, opts.practice, opts.seed, opts.duration_s, opts.display_label))
        d = trial_dir(opts.out, opts.participant, opts.condition, opts.practice)
        status, why = ("aborted", "quit by the participant") if attempt in abort else ("completed", "time limit")
        with TrialWriter(d, {"participant": opts.participant, "condition": opts.condition, "practice": opts.practice,
                             "seed": opts.seed, "display_label": opts.display_label, "scenario": opts.scenario,
                             "overrides": trial_settings(opts)["--set"]}) as log:
            log.close(status, why)
        return {"directory": str(d), "status": status, "end_reason": why, "trial_sim_s": 1.0, "collisions": 0}

    return drive


def _no_q(size, names, directory, answers):
    raise AssertionError("no questionnaire expected")


# ----------------------------------------------------------------------------- the protocol file
@pytest.mark.parametrize("old, new, message", [
    ('name = "default"', 'name = "default"\ncolour = "red"', "unknown key 'colour' (allowed here: name, practice_duration_s"),
    ('title = "Welcome"', 'title = "Welcome"\nimage = "x.png"',
     "unknown key 'briefing.0.image' (allowed here: title, text, keys, marks_example)"),
    ('title = "{label}"\ntext = """This trial', 'title = "{condition}"\ntext = """This trial',
     "trial.title: unknown placeholder {condition} (allowed: {label}, {number}, {total}, {duration})"),
    ("The marks are advice only", "The sham marks are advice only",
     "overlay.text: mentions 'sham': a participant must not be told which overlay is the placebo"),
    ("practice_duration_s = 30.0", "practice_duration_s = -1", "practice_duration_s = -1: Input should be greater than 0"),
    ('[end]\ntitle = "Thank you!"', '[finish]\ntitle = "Thank you!"', "end missing (the end of the session)"),
    ('overlay = ["nasa_tlx", "trust_jian2000"]', 'overlay = ["nasa_tlx", "nasa_tlx"]',
     "questionnaires.overlay: names a questionnaire twice"),
])
def test_a_bad_protocol_file_is_one_line_naming_the_key(tmp_path, old, new, message):
    text = DEFAULT_PROTOCOL.read_text(encoding="utf-8")
    assert text.count(old) == 1
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace(old, new), encoding="utf-8")
    with pytest.raises(ConfigError) as err:
        load_protocol(bad)
    assert str(err.value).startswith(f"protocol file {bad}: ") and message in str(err.value)
    assert "\n" not in str(err.value)


def test_a_protocol_without_keys_is_refused(tmp_path):
    """Every trial's keys screen and the briefing's show the protocol's legend: an empty one left them blank."""
    text = DEFAULT_PROTOCOL.read_text(encoding="utf-8")
    start = text.index("legend = [")
    end = text.index("]\n", text.index('["Esc"', start)) + 2
    bad = tmp_path / "bad.toml"
    bad.write_text(text[:start] + "legend = []\n" + text[end:], encoding="utf-8")
    with pytest.raises(ConfigError, match=r"legend = \[\]: List should have at least 1 item"):
        load_protocol(bad)


def test_the_cli_refuses_a_bad_protocol_before_any_window(tmp_path, capsys):
    bad = tmp_path / "p.toml"
    bad.write_text('name = "x"\n', encoding="utf-8")
    assert main(["session", "--participant", "P01", "--out", str(tmp_path / "s"), "--protocol", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"dt-highway session: error: protocol file {bad}: overlay missing") and "\n" not in err
    no = tmp_path / "no.json"
    assert main(["session", "--participant", "P01", "--out", str(tmp_path / "s"), "--answers-from", str(no)]) == 2
    assert capsys.readouterr().err == f"dt-highway session: error: answers file {no} does not exist\n"
    assert not (tmp_path / "s").exists()


@pytest.mark.parametrize(("answers", "message"), [
    ({"nasa_tlx": ANSWERS["nasa_tlx"]}, "no table 'trust_jian2000' (for trial P01-adas)"),
    ({**ANSWERS, "P01-adas": {"nasa_tlx": {**ANSWERS["nasa_tlx"], "effort": 101}}},
     "nasa_tlx.effort = "),
    ({**ANSWERS, "P01-baseline": {"nasa_tlx": {k: v for k, v in ANSWERS["nasa_tlx"].items() if k != "effort"}}},
     "nasa_tlx.effort missing"),
])
def test_an_answers_file_missing_an_answer_is_refused_before_any_trial(tmp_path, capsys, answers, message):
    # the answers of every trial's questionnaires are checked at the start, not after the trials before
    f = tmp_path / "a.json"
    f.write_text(json.dumps(answers))
    calls: list[tuple] = []
    with pytest.raises(ConfigError, match=re.escape(f"answers file {f}: ") + r".*" + re.escape(message)):
        run_session(_base(tmp_path / "s"), 2.0, say=lambda _: None, drive=_fake_drive(set(), calls),
                    questionnaires=_no_q, answers_from=f)
    assert calls == [] and not (tmp_path / "s").exists()


def test_a_resumed_session_needs_answers_only_for_the_questionnaires_still_to_ask(tmp_path):
    base, asked, calls = _base(tmp_path / "s"), [], []

    def answered(size, names, directory, answers):
        asked.append(directory.name)
        (directory / "questionnaires.json").write_text(json.dumps({"completed": True, "scores": {}}))
        return {"completed": True, "scores": {}}

    first = tmp_path / "a1.json"
    first.write_text(json.dumps(ANSWERS))
    out = run_session(base, 2.0, say=lambda _: None, drive=_fake_drive({"P01-adas"}, calls), questionnaires=answered,
                      answers_from=first)
    assert out.stopped and asked == ["P01-baseline"]  # the baseline's questionnaires are answered; the ADAS trial stopped
    rest = tmp_path / "a2.json"
    rest.write_text(json.dumps({"P01-adas": ANSWERS}))  # answers for what is left only
    assert run_session(base, 2.0, say=lambda _: None, drive=_fake_drive(set(), calls), questionnaires=answered,
                       answers_from=rest).complete
    assert asked == ["P01-baseline", "P01-adas-retry1"]


def test_the_packaged_protocol_reads_and_names_the_shipped_questionnaires():
    p = load_protocol()
    assert p.practice_duration_s == 30.0 and len(p.briefing) == 3 and p.briefing[2].keys
    assert p.questionnaires.for_condition(False) == ["nasa_tlx"]
    assert p.questionnaires.for_condition(True) == ["nasa_tlx", "trust_jian2000"]
    assert p.trial.fill(label="Trial 2 of 4", duration="2 minutes").title == "Trial 2 of 4"


# ----------------------------------------------------------------------------- the plan
def test_practice_in_every_condition_in_the_participant_order_with_neutral_labels(tmp_path):
    conds = ("baseline", "adas-threat", "sham")
    plan = session_plan(_base(tmp_path, "P02", seed=7), None, conds)
    # Williams square of 3: rows 012, 120, 201 and their mirrors; P02 drives row 1 (adas-threat, sham, baseline)
    assert [(t.name, t.label, t.condition, t.practice, t.opts.seed, t.opts.duration_s, t.opts.display_label)
            for t in plan] == [
        ("P02-practice-adas-threat", "Practice 1 of 3", "adas-threat", True, 1007, 30.0, "Practice 1 of 3"),
        ("P02-practice-sham", "Practice 2 of 3", "sham", True, 1008, 30.0, "Practice 2 of 3"),
        ("P02-practice-baseline", "Practice 3 of 3", "baseline", True, 1009, 30.0, "Practice 3 of 3"),
        ("P02-adas-threat", "Trial 1 of 3", "adas-threat", False, 7, 3.0, "Trial 1 of 3"),
        ("P02-sham", "Trial 2 of 3", "sham", False, 7, 3.0, "Trial 2 of 3"),
        ("P02-baseline", "Trial 3 of 3", "baseline", False, 7, 3.0, "Trial 3 of 3"),
    ]
    assert [t.opts.duration_s for t in session_plan(_base(tmp_path, "P02"), 12.5, conds)][:3] == [12.5] * 3


def test_the_status_line_names_what_the_experimenter_needs():
    plan = session_plan(_base(Path("o"), "P03"), None, ("baseline", "adas"))
    line = status_line("P03", plan[3], 1, {"status": "aborted", "reason": "SIGTERM", "trial_sim_s": 61.25,
                                           "pauses": [{"duration_s": 2.0}]}, 2)
    assert line.split(" ", 1)[1] == "P03 | Trial 2 of 2 | adas | attempt 2 | 61.2 s | 2 crashes | 1 pause | aborted (SIGTERM)"
    slow = status_line("P03", plan[3], 0, {"status": "completed", "reason": "time limit", "trial_sim_s": 120.0,
                                           "realtime_ratio": 0.62}, 0)
    assert slow.split(" ", 1)[1] == ("P03 | Trial 2 of 2 | adas | attempt 1 | 120.0 s | 0 crashes | SLOW: 0.620 of real time"
                                     " | completed (time limit)")
    on_time = status_line("P03", plan[3], 0, {"status": "completed", "reason": "time limit", "trial_sim_s": 120.0,
                                              "realtime_ratio": 0.99}, 0)
    assert "SLOW" not in on_time


# ----------------------------------------------------------------------------- blind screens
def _screens(out: Path, conds: tuple[str, ...]) -> list[tuple[str, np.ndarray]]:
    calls: list[tuple] = []
    base = _base(out, screenshot_every_s=100.0, screenshots=out / "shots", size=(480, 270))
    out.mkdir(parents=True)
    (out / "a.json").write_text(json.dumps(ANSWERS))
    outcome = run_session(base, None, say=lambda _: None, conditions=conds, drive=_fake_drive(set(), calls),
                          questionnaires=lambda *a: {"completed": True, "scores": {}}, answers_from=out / "a.json")
    assert outcome.complete and outcome.stopped is None
    files = sorted((out / "shots" / "P01-screens").glob("*.png"))
    return [(f.stem.split("-", 1)[1], cv2.imread(str(f))) for f in files]


def test_adas_and_sham_sessions_show_identical_screens_in_the_protocol_order(tmp_path):
    real = _screens(tmp_path / "real", ("baseline", "adas-threat"))
    sham = _screens(tmp_path / "sham", ("baseline", "sham"))
    assert [n for n, _ in real] == ["briefing-1", "briefing-2", "briefing-3", "before-P01-practice-baseline", "overlay",
                                    "before-P01-practice-adas-threat", "after-practice", "before-P01-baseline",
                                    "before-P01-adas-threat", "end"]
    assert len(sham) == len(real)
    for (a, img_a), (b, img_b) in zip(real, sham, strict=True):
        assert a.replace("adas-threat", "sham") == b
        assert img_a.shape == (270, 480, 3) and np.array_equal(img_a, img_b), a  # pixel for pixel: nothing tells them apart
    # the overlay explanation comes once, before the first trial with the overlay (P02 starts with it)
    first = _screens(tmp_path / "p02", ("baseline", "adas"))
    assert [n for n, _ in first].count("overlay") == 1


# ----------------------------------------------------------------------------- the window
def test_a_stopped_trial_is_offered_again_in_the_window_and_every_attempt_kept(tmp_path):
    """Not scripted: the screens wait for Enter (posted here), the stopped screen's Enter drives it again."""
    calls: list[tuple] = []
    said: list[str] = []
    base = DriveOptions("P01", "baseline", tmp_path, overrides=list(SETS), duration_s=3.0, size=(320, 180))
    stop = threading.Event()

    def press_enter() -> None:
        while not stop.is_set():
            try:
                if pygame.display.get_init():
                    pygame.event.post(pygame.event.Event(pygame.KEYDOWN, key=pygame.K_RETURN))
            except pygame.error:
                pass
            time.sleep(0.12)

    presser = threading.Thread(target=press_enter, daemon=True)
    presser.start()
    try:
        outcome = run_session(base, 1.0, say=said.append, drive=_fake_drive({"P01-adas", "P01-adas-retry1"}, calls),
                              questionnaires=lambda size, names, d, a: {"completed": True,
                                                                        "scores": dict.fromkeys(names, 1.0)})
    finally:
        stop.set()
        presser.join()
    assert outcome.complete
    assert [c[0] for c in calls] == ["P01-practice-baseline", "P01-practice-adas", "P01-baseline", "P01-adas",
                                     "P01-adas-retry1", "P01-adas-retry2"]
    assert [d.name for _, d in attempt_dirs(tmp_path, "P01-adas")] == ["P01-adas", "P01-adas-retry1", "P01-adas-retry2"]
    assert [load_trial(d).meta["status"] for _, d in attempt_dirs(tmp_path, "P01-adas")] == ["aborted", "aborted", "completed"]
    assert not (tmp_path / STAGING).exists() or not any((tmp_path / STAGING).iterdir())
    log = [json.loads(x) for x in (tmp_path / "sessions" / "P01.jsonl").read_text().splitlines()]
    assert [e["screen"] for e in log if e["event"] == "screen"].count("stopped-P01-adas") == 2
    assert [(e["trial"], e["attempt"], e["status"]) for e in log if e["event"] == "attempt"][-3:] == [
        ("P01-adas", 0, "aborted"), ("P01-adas", 1, "aborted"), ("P01-adas", 2, "completed")]
    assert [s.split(" | ")[-1] for s in said if "| attempt" in s][3:] == [
        "aborted (quit by the participant)", "aborted (quit by the participant)", "completed (time limit)"]


def test_a_trial_whose_process_died_is_kept_and_the_next_attempt_goes_to_retry1(tmp_path):
    """A session killed mid-trial leaves the trial in the staging folder, ``running`` with a dead pid."""
    staged = tmp_path / STAGING / "P01-adas" / "trials" / "P01-adas"
    with TrialWriter(staged, {"participant": "P01", "condition": "adas", "practice": False, "seed": 0}):
        pass
    meta = json.loads((staged / "meta.json").read_text())
    (staged / "meta.json").write_text(json.dumps({**meta, "status": "running", "pid": 2 ** 22 + 12345}))
    calls: list[tuple] = []
    said: list[str] = []
    outcome = run_session(_base(tmp_path), 1.0, say=said.append, drive=_fake_drive(set(), calls), questionnaires=_no_q)
    assert said[0] == "P01-adas: left by a process that died, kept as aborted"
    assert said[1].startswith("session of P01 in ") and said[1].endswith(": practice baseline, adas, then baseline, adas")
    assert load_trial(tmp_path / "trials" / "P01-adas").meta["status"] == "aborted"
    assert [c[0] for c in calls] == ["P01-practice-baseline", "P01-practice-adas", "P01-baseline", "P01-adas-retry1"]
    assert outcome.complete and not (tmp_path / STAGING).exists()


def test_attempts_are_found_by_name_not_by_prefix(tmp_path):
    for name in ("P01-adas", "P01-adas-retry2", "P01-adas-threat", "P01-adas-threat-retry1", "P01-adas-retryx"):
        (tmp_path / "trials" / name).mkdir(parents=True)
    assert [(k, d.name) for k, d in attempt_dirs(tmp_path, "P01-adas")] == [(0, "P01-adas"), (2, "P01-adas-retry2")]
    assert [k for k, _ in attempt_dirs(tmp_path, "P01-adas-threat")] == [0, 1]


def test_an_error_in_a_trial_is_kept_as_an_aborted_attempt_and_raised(tmp_path):
    def crashing(opts: DriveOptions) -> dict:
        with TrialWriter(trial_dir(opts.out, opts.participant, opts.condition, opts.practice),
                         {"participant": opts.participant, "condition": opts.condition, "practice": opts.practice}):
            raise RuntimeError("boom")

    said: list[str] = []
    with pytest.raises(RuntimeError, match="boom"):
        run_session(_base(tmp_path), 1.0, say=said.append, drive=crashing, questionnaires=_no_q)
    meta = load_trial(tmp_path / "trials" / "P01-practice-baseline").meta
    assert (meta["status"], meta["end_reason"]) == ("aborted", "RuntimeError: boom")
    assert said[-1].endswith("| Practice 1 of 2 | baseline | attempt 1 | - s | 0 crashes | aborted "
                             "(error: RuntimeError: boom)")
    log = [json.loads(x) for x in (tmp_path / "sessions" / "P01.jsonl").read_text().splitlines()]
    assert log[-1]["event"] == "end" and log[-1]["stopped"] == "RuntimeError: boom"


def test_sigterm_at_a_screen_ends_the_session_and_says_so(tmp_path):
    calls: list[tuple] = []
    base = DriveOptions("P01", "baseline", tmp_path, overrides=list(SETS), duration_s=3.0, size=(320, 180))
    before = signal.getsignal(signal.SIGTERM)  # another test of the run may have left its own handler
    timer = threading.Timer(1.0, os.kill, (os.getpid(), signal.SIGTERM))
    timer.start()
    try:
        outcome = run_session(base, 1.0, say=lambda _: None, drive=_fake_drive(set(), calls), questionnaires=_no_q)
    finally:
        timer.cancel()
    assert outcome.stopped == "SIGTERM" and calls == [] and not outcome.complete  # it waited at the first briefing screen
    log = [json.loads(x) for x in (tmp_path / "sessions" / "P01.jsonl").read_text().splitlines()]
    assert [(e["event"], e.get("answer")) for e in log[1:]] == [("screen", "closed"), ("end", None)]
    assert log[-1]["stopped"] == "SIGTERM"
    assert signal.getsignal(signal.SIGTERM) is before  # the session's handler is gone, the one before is back


# ----------------------------------------------------------------------------- a whole session
def _abort_drive(abort: set[str]):
    """The real driving window; the attempts named in ``abort`` get a script that presses Esc at 0.5 s."""

    def drive(opts: DriveOptions) -> dict:
        if Path(opts.out).name in abort:
            opts = replace(opts, keys_from=KeyScript.parse("0.5 down ESC\n"))
        return run_drive(opts, say=lambda _: None)

    return drive


def _sigterm_run(out: Path, keys: Path) -> subprocess.CompletedProcess:
    """``dt-highway session`` in a child process, SIGTERM once its trial runs."""
    env = {**os.environ, "SDL_VIDEODRIVER": "offscreen"}
    cmd = [sys.executable, "-m", "dt_highway.cli", "session", "--participant", "P01", "--duration", "3",
           "--out", str(out), "--keys-from", str(keys), *FAST]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    steps = out / STAGING / "P01-adas-retry2" / "trials" / "P01-adas" / "steps.csv"
    t_end = time.monotonic() + 120
    while time.monotonic() < t_end and proc.poll() is None:
        if steps.exists() and len(steps.read_text().splitlines()) > 3:  # the trial is running
            proc.send_signal(signal.SIGTERM)
            break
        time.sleep(0.05)
    out_text, err_text = proc.communicate(timeout=60)
    return subprocess.CompletedProcess(cmd, proc.returncode, out_text, err_text)


def test_a_whole_scripted_session_keeps_every_attempt_and_the_report_lists_the_aborted_ones(tmp_path, capsys,
                                                                                           monkeypatch):
    out = tmp_path / "study"
    keys = tmp_path / "keys.txt"
    keys.write_text(KEYS)
    answers = tmp_path / "answers.json"
    answers.write_text(json.dumps(ANSWERS))
    said: list[str] = []
    # 1: practice in both conditions, baseline, then Esc in the ADAS trial: the session stops there
    first = run_session(_base(out), 2.0, say=said.append, drive=_abort_drive({"P01-adas"}), answers_from=answers)
    assert first.stopped == "P01-adas aborted (quit by the participant)" and not first.complete
    assert [t["status"] for t in first.trials] == ["completed", "completed", "completed", "stopped"]
    # 2: run again: the finished trials are skipped, the ADAS trial's next attempt goes to -retry1 (aborted too)
    second = run_session(_base(out), 2.0, say=said.append, drive=_abort_drive({"P01-adas-retry1"}), answers_from=answers)
    assert [t["status"] for t in second.trials] == ["skipped", "skipped", "skipped", "stopped"]
    # 3: SIGTERM while the third attempt runs
    term = _sigterm_run(out, keys)
    assert term.returncode == 1 and "Traceback" not in term.stderr, term.stderr
    assert "attempt 3 |" in term.stdout and "aborted (SIGTERM)" in term.stdout and "stopped: SIGTERM" in term.stdout
    # 4: the CLI drives the fourth attempt to its end, with the questionnaires and the end screen
    shots = tmp_path / "shots"
    closed: list[str] = []  # the window closes once, at the end: never between screens, the trial and questionnaires
    real_quit, real_display_quit = pygame.quit, pygame.display.quit

    def quit_all() -> None:
        closed.append("pygame.quit")
        monkeypatch.setattr(pygame.display, "quit", real_display_quit)  # pygame.quit calls it too
        real_quit()

    monkeypatch.setattr(pygame, "quit", quit_all)
    monkeypatch.setattr(pygame.display, "quit", lambda: (closed.append("display.quit"), real_display_quit())[1])
    opened: list[tuple] = []  # pygame-ce makes a new window at every set_mode: one for the whole session
    real_set_mode = pygame.display.set_mode
    monkeypatch.setattr(pygame.display, "set_mode", lambda *a, **k: (opened.append(a), real_set_mode(*a, **k))[1])
    assert main(["session", "--participant", "P01", "--duration", "3", "--out", str(out), "--keys-from", str(keys),
                 "--answers-from", str(answers), "--screenshot-every", "100", "--screenshots", str(shots), *FAST]) == 0
    monkeypatch.undo()
    assert closed == ["pygame.quit"] and len(opened) == 1
    said_cli = capsys.readouterr().out
    assert "P01-practice-baseline: already completed, skipped" in said_cli and "4 of 4 trials done" in said_cli

    trials = sorted(d.name for d in (out / "trials").iterdir())
    assert trials == ["P01-adas", "P01-adas-retry1", "P01-adas-retry2", "P01-adas-retry3", "P01-baseline",
                      "P01-practice-adas", "P01-practice-baseline"]
    metas = {n: load_trial(out / "trials" / n).meta for n in trials}
    assert [(metas[n]["status"], metas[n]["end_reason"]) for n in trials[:4]] == [
        ("aborted", "quit by the participant"), ("aborted", "quit by the participant"), ("aborted", "SIGTERM"),
        ("completed", "time limit")]
    # neutral labels in the window; practice in both conditions, in P01's order (baseline, adas)
    assert {n: metas[n]["display_label"] for n in trials} == {
        "P01-adas": "Trial 2 of 2", "P01-adas-retry1": "Trial 2 of 2", "P01-adas-retry2": "Trial 2 of 2",
        "P01-adas-retry3": "Trial 2 of 2", "P01-baseline": "Trial 1 of 2", "P01-practice-adas": "Practice 2 of 2",
        "P01-practice-baseline": "Practice 1 of 2"}
    assert [(metas[n]["condition"], metas[n]["practice"], metas[n]["seed"]) for n in trials[4:]] == [
        ("baseline", False, 0), ("adas", True, 1001), ("baseline", True, 1000)]
    # questionnaires after the trials that count: NASA-TLX after each, trust only after the overlay trial
    q_base = json.loads((out / "trials" / "P01-baseline" / "questionnaires.json").read_text())
    q_adas = json.loads((out / "trials" / "P01-adas-retry3" / "questionnaires.json").read_text())
    assert q_base["scores"] == pytest.approx({"nasa_tlx": TLX})
    assert q_adas["scores"] == pytest.approx({"nasa_tlx": TLX, "trust_jian2000": TRUST})
    assert [n for n in trials if (out / "trials" / n / "questionnaires.json").exists()] == ["P01-adas-retry3", "P01-baseline"]
    ends = [json.loads(x) for x in (out / "sessions" / "P01.jsonl").read_text().splitlines() if '"event": "end"' in x]
    assert [e["stopped"] for e in ends] == ["P01-adas aborted (quit by the participant)",
                                            "P01-adas aborted (quit by the participant)", "SIGTERM", None]
    assert [p.name for p in sorted((shots / "P01-screens").glob("*.png"))] == ["01-before-P01-adas.png", "02-end.png"]

    # the report: practice left out, the aborted attempts listed with their reasons and the attempt that replaced them
    assert main(["report", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["conditions"]["baseline"]["n"] == 1 and summary["conditions"]["adas"]["n"] == 1
    assert summary["aborted_trials"] == [
        {"trial": "P01-adas", "participant": "P01", "condition": "adas", "end_reason": "quit by the participant",
         "retried_in": "P01-adas-retry3"},
        {"trial": "P01-adas-retry1", "participant": "P01", "condition": "adas", "end_reason": "quit by the participant",
         "retried_in": "P01-adas-retry3"},
        {"trial": "P01-adas-retry2", "participant": "P01", "condition": "adas", "end_reason": "SIGTERM",
         "retried_in": "P01-adas-retry3"}]
    assert summary["excluded"] == []
    assert "3 aborted attempts" in (out / "report.html").read_text()


def test_screens_fit_a_small_window_and_show_no_path(tmp_path):
    p = load_protocol()
    img = render_screen((320, 180), p.briefing[0], p.legend, p.continue_hint)
    assert img.shape == (180, 320, 3) and img.dtype == np.uint8
    texts = [p.name, *(s.title + s.text for s in (*p.briefing, p.overlay, p.practice, p.trial, p.stopped, p.end))]
    path = re.compile(r"(^|\s)(/|\.\.?/|~/)\w|\\|\.(toml|json|jsonl|csv|png)\b|trials/|runs/")
    assert not any(path.search(t) for t in texts) and path.search("see runs/x") and path.search("in /tmp/x")


# ------------------------------------------------------------------------ even letter spacing (issue 20)
@pytest.mark.parametrize("px", [24, 39, 70])
def test_screen_text_is_spaced_by_the_letters_advances_without_the_fonts_kerning(px):
    # pygame.font (SDL_ttf) kerns freesansbold's pairs 1-4 px apart ("a bout", "sa fe", "bot tom" at 39-70 px);
    # the screens' font adds no space between parts of a word
    pygame.font.init()
    font = TextFont(px)
    for a, b in (("a", "bout"), ("sa", "fe"), ("contin", "ue"), ("bot", "tom"), ("c", "ut")):
        assert font.size(a + b)[0] == font.size(a)[0] + font.size(b)[0], (a, b)


def test_screens_are_drawn_without_pygame_font(monkeypatch):
    def no_font(*_a, **_k):
        raise AssertionError("the screens use TextFont (no kerning), not pygame.font.Font")

    protocol = load_protocol(DEFAULT_PROTOCOL)
    monkeypatch.setattr(pygame.font, "Font", no_font)
    img = render_screen((640, 360), protocol.briefing[1], hint="Press Enter to continue", note="End the session?")
    assert img.shape == (360, 640, 3) and (img != img[0, 0]).any()


def test_the_reports_console_lines_line_up_for_long_condition_names(tmp_path, capsys):
    from dt_highway.cli import _print_summary

    cond = {"n": 4, "speed_variance_kmh2": {"mean": 12.5}, "ttc_mean_s": {"mean": None}, "collisions": 0,
            "cut_ins": 3, "cut_ins_marked_in_time": 1}
    path = tmp_path / "summary.json"
    path.write_text(json.dumps({"conditions": {"baseline": cond, "adas-threat": cond, "sham": cond}}))
    _print_summary(path)
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 3 and {line.index("n=") for line in lines} == {2 + len("adas-threat") + 1}
    assert lines[0].startswith("  baseline    n=  4")


def test_closing_the_window_at_the_end_screen_is_the_sessions_normal_end(tmp_path, monkeypatch):
    from dt_highway.hmi.briefing import ScreenWindow

    ask = ScreenWindow.ask

    def close_at_the_end(self, name, *a, **k):
        return "closed" if name == "end" else ask(self, name, *a, **k)

    monkeypatch.setattr(ScreenWindow, "ask", close_at_the_end)
    calls: list[tuple] = []
    outcome = run_session(_base(tmp_path), 1.0, say=lambda _: None, conditions=["baseline", "adas"],
                          drive=_fake_drive(set(), calls), questionnaires=lambda *a: None)
    assert outcome.complete and outcome.stopped is None and len(calls) == 4
    log = [json.loads(x) for x in (tmp_path / "sessions" / "P01.jsonl").read_text().splitlines()]
    assert (log[-2]["event"], log[-2]["screen"], log[-2]["answer"]) == ("screen", "end", "closed")
    assert log[-1]["event"] == "end" and log[-1]["stopped"] is None


def test_a_session_resumed_with_other_trial_settings_is_refused_before_any_window(tmp_path):
    out = tmp_path / "study"
    said: list[str] = []
    first = run_session(_base(out), 2.0, say=said.append, drive=_fake_drive({"P01-adas"}, []), questionnaires=lambda *a: None)
    assert [t["status"] for t in first.trials] == ["completed", "completed", "completed", "stopped"]
    shown: list = []
    with pytest.raises(ConfigError, match=r"^P01-baseline was driven with other settings \(--set .*'highway.duration=3.0'\]"
                                          r", now .*'highway.duration=5.0'\]\): go on with the settings"):
        run_session(replace(_base(out), duration_s=5.0), 2.0, say=said.append, drive=_fake_drive(set(), []),
                    questionnaires=lambda *a: None, on_frame=shown.append)
    assert shown == []  # refused before the first screen
    # another practice length and window size are the same trials: it goes on
    again = run_session(replace(_base(out), size=(320, 180)), 5.0, say=said.append, drive=_fake_drive(set(), []),
                        questionnaires=lambda *a: None)
    assert again.complete

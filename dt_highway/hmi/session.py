"""The session of a participant: the briefing, a short practice trial in every condition of the
session, then the conditions (``baseline`` and ``adas`` unless told otherwise; any of
:data:`~dt_highway.conditions.CONDITIONS`, ``sham`` among them) in counterbalanced order, each
followed by its questionnaires, and an end screen. What the participant reads comes from a
protocol file (:mod:`dt_highway.hmi.briefing`).

Order: a balanced Latin square (Williams 1949, Aust. J. Sci. Res. A 2, 149): with ``k`` conditions
its rows are the orders, ``k`` of them for even ``k`` and ``2k`` for odd ``k`` (the square and its
mirror image); over a full set of rows every condition is driven equally often in every position
and follows every other condition equally often (first-order carry-over balanced). Participant
``n`` (the number its id ends in: P01, P02...) drives row ``(n - 1) mod rows``; an id without a
trailing number gets ``n`` from a stable checksum of the id. With ``baseline`` and ``adas`` that is
the old rule: odd participants AB, even ones BA. Recruit participants in multiples of the number of
rows for full balance. The practice trials follow the same order, one per condition (so every
participant practises with the overlay when the session has it), each ``practice_duration_s`` long.

Blind: the participant never reads a condition's name. Trials are named by neutral numbers
(``Practice 1 of 2``, ``Trial 2 of 4``: the protocol's ``trial_label``), which the driving window
shows instead of the condition; the overlay is explained once, before the first trial with it,
by the same screen for every overlay condition (the sham ones too).

Seeds: every condition uses the session's traffic seed (the paired design of the scripted studies);
practice trial ``i`` uses seed ``+ 1000 + i``.

Attempts: every attempt of a trial is kept. The first goes to ``<out>/trials/<participant>-<condition>``
(practice: ``<participant>-practice-<condition>``), the next ones to ``...-retry1``, ``...-retry2``;
no folder is ever written twice. A trial stopped before its end (Esc, the window closed, SIGTERM,
SIGINT, an error) stays as it is, ``aborted`` with its reason; the participant is offered to drive
it again (Enter) or to end the session (Esc). Running the session again skips the trials already
completed (and the briefing, when one was) and goes on with the next attempt of the others.
A trial is driven in a staging folder (``<out>/.attempts/<name>``) and moved to ``trials/`` when it
ends; a trial whose process died is moved there at the next start of a session in that folder.

The experimenter's side: one status line per attempt in the terminal (clock time, participant,
neutral label, condition, attempt, time driven, crashes, status) and a session log
``<out>/sessions/<participant>.jsonl`` (the plan, every screen with the time it was shown,
every attempt, the questionnaires, the end).
"""

from __future__ import annotations

import json
import re
import shutil
import signal
import time
import zlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from types import FrameType
from typing import Any

import numpy as np
import pygame

from dt_highway.conditions import check_condition, check_mode_override, shows_overlay
from dt_highway.config import ConfigError, load_config
from dt_highway.hmi.briefing import ENTER, Protocol, Screen, ScreenWindow, format_duration, load_protocol, render_screen
from dt_highway.hmi.drive import (
    DriveOptions,
    SignalScope,
    drive_config,
    is_slow,
    run_drive,
    trial_dir,
    trial_name,
    trial_settings,
)
from dt_highway.hmi.keys import KeyScript
from dt_highway.hmi.questionnaire import (
    load_answers,
    load_questionnaire,
    read_results,
    run_questionnaires,
    scripted_answers,
)
from dt_highway.jsonio import json_safe
from dt_highway.metrics.trial_log import load_trial

PRACTICE_SEED_OFFSET = 1000
"""Practice trial ``i`` (from 0) uses the session's seed plus this plus ``i``"""


DEFAULT_CONDITIONS = ("baseline", "adas")
"""A session's conditions unless told otherwise"""

STAGING = ".attempts"
"""The folder (in the study directory) where a trial is driven before it moves to ``trials/``"""

SESSIONS = "sessions"
"""The folder (in the study directory) of the session logs"""

FINISHED = ("completed", "ended_by_collision")  # trial_log.FINISHED_STATUSES (the wall keeps hmi from importing it)
"""A trial's statuses that need no other attempt (a collision that ended the trial is an outcome, not an abort)"""

DriveFn = Callable[[DriveOptions], dict[str, Any]]
"""Runs one trial (:func:`~dt_highway.hmi.drive.run_drive`)"""

QuestionnaireFn = Callable[[tuple[int, int], list[str], Path, Path | None], dict[str, Any]]
"""Asks the questionnaires after a trial (:func:`~dt_highway.hmi.questionnaire.run_questionnaires`)"""


def balanced_latin_square(k: int) -> list[list[int]]:
    """The rows of a balanced Latin square (Williams design) of ``k`` treatments ``0..k-1``.

    The first row is ``0, 1, k-1, 2, k-2, ...``; row ``r`` adds ``r`` mod ``k``; for odd ``k`` the
    mirror images of those rows follow (``2k`` rows).

    :param k: number of treatments, >= 1
    :return: the rows (each a permutation of ``range(k)``)
    """
    first, lo, hi = [0], 1, k - 1
    while len(first) < k:
        first.append(lo)
        lo += 1
        if len(first) < k:
            first.append(hi)
            hi -= 1
    rows = [[(c + r) % k for c in first] for r in range(k)]
    return rows + [row[::-1] for row in rows] if k % 2 else rows


def check_conditions(conditions: Sequence[str]) -> tuple[str, ...]:
    """A session's conditions, checked: known, no repeats, at least two.

    :param conditions: the conditions' names
    :return: the checked names, in the given order
    :raises ConfigError: one line naming the problem
    """
    out = tuple(check_condition(c) for c in conditions)
    if len(set(out)) != len(out):
        raise ConfigError(f"--conditions names a condition twice (got {','.join(out)})")
    if len(out) < 2:
        raise ConfigError(f"a session needs at least two conditions (got {','.join(out) or 'none'})")
    return out


def condition_order(participant: str, conditions: Sequence[str] = DEFAULT_CONDITIONS) -> tuple[str, ...]:
    """The counterbalanced order of a participant's conditions (module docstring).

    :param participant: participant id (its trailing number picks the row)
    :param conditions: the session's conditions
    :return: the conditions in the participant's order
    :raises ConfigError: on unknown or repeated conditions
    """
    conds = check_conditions(conditions)
    m = re.search(r"(\d+)$", participant)
    n = int(m.group(1)) if m else zlib.crc32(participant.encode("utf-8"))
    rows = balanced_latin_square(len(conds))
    return tuple(conds[i] for i in rows[(n - 1) % len(rows)])


# ----------------------------------------------------------------------------- the plan
@dataclass(frozen=True)
class SessionTrial:
    """One trial of a session's plan.

    :param opts: the trial's options (condition, practice, seed, duration, neutral label)
    :param name: its first attempt's folder name (``P01-adas``, ``P01-practice-adas``)
    :param label: its neutral name, the only one the participant reads (``Trial 2 of 4``)
    :param number: its number among the trials of its kind (practice or not), from 1
    :param total: how many trials of its kind the session has
    """

    opts: DriveOptions
    name: str
    label: str
    number: int
    total: int

    @property
    def practice(self) -> bool:
        """A practice trial (not in the report, no questionnaires)."""
        return self.opts.practice

    @property
    def condition(self) -> str:
        """Its condition (never shown to the participant)."""
        return self.opts.condition


def attempt_name(name: str, attempt: int) -> str:
    """The folder name of attempt ``attempt`` (0: the first) of trial ``name``: ``P01-adas-retry2``.

    :param name: the trial's first attempt's folder name (:func:`~dt_highway.hmi.drive.trial_name`)
    :param attempt: the attempt's number (0: the first)
    :return: the folder name
    """
    return name if attempt == 0 else f"{name}-retry{attempt}"


def attempt_dirs(out: Path, name: str) -> list[tuple[int, Path]]:
    """The attempts of trial ``name`` found under ``<out>/trials``, in order.

    :param out: the study directory
    :param name: the trial's first attempt's folder name
    :return: ``(attempt, folder)`` pairs
    """
    pattern = re.compile(re.escape(name) + r"(?:-retry(\d+))?")
    found = []
    for d in (Path(out) / "trials").glob(f"{name}*"):
        m = pattern.fullmatch(d.name)
        if m and d.is_dir():
            found.append((int(m.group(1) or 0), d))
    return sorted(found)


def _status(d: Path) -> str | None:
    try:
        return load_trial(d).meta.get("status")
    except (OSError, ValueError):  # FileNotFoundError, TrialLogError: no trial there
        return None


def completed_attempt(out: Path, name: str) -> Path | None:
    """The attempt of trial ``name`` that finished (:data:`FINISHED`), or ``None``.

    :param out: the study directory
    :param name: the trial's first attempt's folder name
    :return: that attempt's folder (the first one found), or ``None``
    """
    return next((d for _, d in attempt_dirs(out, name) if _status(d) in FINISHED), None)


def session_plan(base: DriveOptions, practice_duration_s: float | None = None,
                 conditions: Sequence[str] = DEFAULT_CONDITIONS, protocol: Protocol | None = None) -> list[SessionTrial]:
    """The trials of a session: a practice trial in every condition, then the conditions, both in
    the participant's order.

    :param base: options shared by the trials (participant, out, scenario, seed...)
    :param practice_duration_s: each practice trial's length [s] (``None``: the protocol's)
    :param conditions: the session's conditions
    :param protocol: the session's protocol (its labels and practice length; ``None``: the default one)
    :return: the practice trials, then the trials that count
    :raises ConfigError: on unknown or repeated conditions, or an ``overlay.mode`` override beside a condition that
        names its mode
    """
    protocol = protocol or load_protocol()
    order = condition_order(base.participant, conditions)
    check_mode_override(order, base.overrides)
    practice_s = practice_duration_s if practice_duration_s is not None else protocol.practice_duration_s
    k = len(order)
    trials = []
    for practice in (True, False):
        for i, cond in enumerate(order):
            label = (protocol.practice_label if practice else protocol.trial_label).format(
                number=i + 1, total=k, label="", duration="")
            opts = (replace(base, condition=cond, practice=True, seed=base.seed + PRACTICE_SEED_OFFSET + i,
                            duration_s=practice_s) if practice else replace(base, condition=cond, practice=False))
            opts = replace(opts, display_label=label, legend=tuple((key, what) for key, what in protocol.legend))
            trials.append(SessionTrial(opts, trial_name(base.participant, cond, practice),
                                       label, i + 1, k))
    if base.screenshots is not None:  # one folder per trial, or their screenshots would overwrite each other
        trials = [replace(t, opts=replace(t.opts, screenshots=base.screenshots / t.name)) for t in trials]
    return trials


def recover_staged(out: Path) -> list[Path]:
    """Move the trials left in the staging folder (their process died) to ``trials/``.

    :param out: the study directory
    :return: the folders moved there (they read as ``aborted``)
    """
    moved = []
    for stage in sorted((Path(out) / STAGING).glob("*")):
        inner = [d for d in (stage / "trials").glob("*") if d.is_dir()]
        final = Path(out) / "trials" / stage.name
        if len(inner) == 1 and not final.exists():
            final.parent.mkdir(parents=True, exist_ok=True)
            inner[0].rename(final)
            moved.append(final)
        _remove_staging(stage)
    return moved


def _remove_staging(stage: Path) -> None:
    """Remove an attempt's staging folder, and the staging root when it is empty."""
    shutil.rmtree(stage, ignore_errors=True)
    try:
        stage.parent.rmdir()
    except OSError:  # another attempt's folder is there, or it is gone
        pass


def status_line(participant: str, trial: SessionTrial, attempt: int, result: dict[str, Any], crashes: int) -> str:
    """The experimenter's line about one attempt.

    :param participant: the participant's id
    :param trial: the trial
    :param attempt: the attempt (0: the first)
    :param result: what :func:`~dt_highway.hmi.drive.run_drive` returned, with ``reason``
    :param crashes: the collisions logged in the attempt
    :return: e.g. ``12:03:44 P01 | Trial 2 of 4 | adas-threat | attempt 1 | 120.0 s | 1 crash | completed (time limit)``
        (with ``| SLOW: 0.620 of real time`` when the trial kept less than :data:`~dt_highway.hmi.drive.REALTIME_WARN_BELOW`)
    """
    sim = result.get("trial_sim_s")
    driven = f"{sim:.1f} s" if isinstance(sim, (int, float)) else "- s"
    pauses = len(result.get("pauses") or [])
    ratio = result.get("realtime_ratio")
    slow = isinstance(ratio, (int, float)) and is_slow(ratio)
    return (f"{time.strftime('%H:%M:%S')} {participant} | {trial.label} | {trial.condition} | attempt {attempt + 1} | "
            f"{driven} | {crashes} crash{'' if crashes == 1 else 'es'}"
            + (f" | {pauses} pause{'' if pauses == 1 else 's'}" if pauses else "")
            + (f" | SLOW: {ratio:.3f} of real time" if slow else "")
            + f" | {result['status']} ({result['reason']})")


# ----------------------------------------------------------------------------- signals
class _Signals(SignalScope):
    """SIGTERM and SIGINT during a session: the first is noted and the window asked to close
    (the trial running ends as when its window is closed; a screen ends the session); a second
    SIGINT raises ``KeyboardInterrupt``. A handler the driving window installs for its trial
    takes precedence while it runs."""

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        name = signal.Signals(signum).name
        if self.received == "SIGINT" and name == "SIGINT":
            raise KeyboardInterrupt
        self.received = self.received or name
        try:
            pygame.event.post(pygame.event.Event(pygame.QUIT))
        except pygame.error:  # no window open
            pass


def _signal_in(reason: str) -> str | None:
    m = re.search(r"\bSIG(TERM|INT)\b", reason)
    return m.group(0) if m else None


# ----------------------------------------------------------------------------- the session
@dataclass
class SessionOutcome:
    """What a session did.

    :param trials: per planned trial: ``name``, ``label``, ``condition``, ``practice``, ``status``
        (``completed``, ``skipped``: finished before, ``stopped``, ``not run``) and ``directory`` (its
        finished attempt)
    :param attempts: every attempt driven: the driving window's result with ``trial``, ``attempt``,
        ``reason`` and ``crashes``
    :param stopped: why the session ended before its end (``None``: it did not)
    """

    trials: list[dict[str, Any]] = field(default_factory=list)
    attempts: list[dict[str, Any]] = field(default_factory=list)
    stopped: str | None = None

    @property
    def complete(self) -> bool:
        """Every planned trial is completed."""
        return bool(self.trials) and all(t["status"] in ("completed", "skipped") for t in self.trials)


class _Stop(Exception):
    """The session ends here (the reason is the message)."""


class _Session:
    """One run of :func:`run_session` (state shared by its steps)."""

    def __init__(self, base: DriveOptions, plan: list[SessionTrial], protocol: Protocol, say: Callable[[str], object],
                 drive: DriveFn, questionnaires: QuestionnaireFn, answers_from: Path | None, signals: _Signals,
                 on_frame: Callable[[np.ndarray], None] | None) -> None:
        self.base, self.plan, self.protocol, self.say = base, plan, protocol, say
        self.drive, self.ask_questionnaires, self.answers_from, self.signals = drive, questionnaires, answers_from, signals
        self.out = Path(base.out)
        self.scripted = base.keys_from is not None
        self.size = _window_size(base, plan[0].condition)
        shots = base.screenshots / f"{base.participant}-screens" if base.screenshots is not None else None
        self.window = ScreenWindow(self.size, fullscreen=base.fullscreen, scripted=self.scripted, save_dir=shots,
                                   on_frame=on_frame, stop_requested=lambda: signals.received is not None)
        self.outcome = SessionOutcome()
        self.log_path = self.out / SESSIONS / f"{base.participant}.jsonl"

    # ------------------------------------------------------------ records
    def log(self, event: str, **fields: Any) -> None:
        """Append one line to the session log."""
        self.log_path.parent.mkdir(parents=True, exist_ok=True)
        with self.log_path.open("a", encoding="utf-8") as fh:
            fh.write(json.dumps(json_safe({"event": event, "time": time.strftime("%Y-%m-%dT%H:%M:%S%z"), **fields}),
                                allow_nan=False) + "\n")

    def screen(self, name: str, screen: Screen, choices: dict[int, str] | None = None, hint: str | None = None,
               confirm: bool = True) -> str:
        """Show one screen and wait for its answer (``next``, ``back``, ``quit``, ``closed``).

        :raises _Stop: when the window was closed or the session ended there
        """
        p = self.protocol
        choices = choices or {ENTER[0]: "next", ENTER[1]: "next"}
        hint = p.continue_hint if hint is None else hint
        t0 = time.monotonic()
        answer = self.window.ask(name, lambda size, note: render_screen(size, screen, p.legend, hint, note), choices,
                                 "Esc again: end the session. Enter: go on." if confirm else "")
        self.log("screen", screen=name, answer=answer, shown_s=round(time.monotonic() - t0, 3))
        if answer == "closed":
            raise _Stop(self.signals.received or "window closed")
        if answer == "quit":
            raise _Stop(f"ended at the screen {name}")
        return answer

    # ------------------------------------------------------------ steps
    def briefing(self) -> None:
        """The briefing screens; Backspace goes back."""
        screens = self.protocol.briefing
        i = 0
        while i < len(screens):
            back = {pygame.K_BACKSPACE: "back"} if i else {}
            hint = self.protocol.continue_hint + (f"    {self.protocol.back_hint}" if i else "")
            answer = self.screen(f"briefing-{i + 1}", screens[i], {ENTER[0]: "next", ENTER[1]: "next", **back}, hint)
            i = i - 1 if answer == "back" else i + 1

    def before(self, t: SessionTrial, first_main: bool, explain_overlay: bool) -> None:
        """The screens before a trial: after the practice, the overlay's explanation, the trial's own."""
        p = self.protocol
        n_main = sum(not x.practice for x in self.plan)
        main_duration = format_duration(_duration_s(self.base, t.condition))
        if first_main and p.after_practice is not None and any(x.practice for x in self.plan):
            self.screen("after-practice", p.after_practice.fill(total=n_main, duration=main_duration))
        if explain_overlay:
            self.screen("overlay", p.overlay.fill())
        screen = p.practice if t.practice else p.trial
        duration = _duration_s(self.base, t.condition) if not t.practice else t.opts.duration_s or 0.0
        self.screen(f"before-{t.name}", screen.fill(label=t.label, number=t.number, total=t.total,
                                                    duration=format_duration(duration)))

    def attempt(self, t: SessionTrial) -> dict[str, Any]:
        """Drive the trial's next attempt into its own folder.

        :return: the driving window's result with ``trial``, ``attempt``, ``reason``, ``crashes``
        """
        have = attempt_dirs(self.out, t.name)
        k = have[-1][0] + 1 if have else 0
        name = attempt_name(t.name, k)
        final, stage = self.out / "trials" / name, self.out / STAGING / name
        shutil.rmtree(stage, ignore_errors=True)
        opts = replace(t.opts, out=stage)
        if opts.screenshots is not None:
            opts = replace(opts, screenshots=opts.screenshots.with_name(name))
        if opts.keys_from is not None:  # each trial replays the script from its start
            opts = replace(opts, keys_from=KeyScript(opts.keys_from.events))
        t0 = time.monotonic()
        result: dict[str, Any] = {"status": "aborted", "end_reason": "error"}
        try:
            result = dict(self.drive(opts))
        except BaseException as err:  # recorded as the attempt's reason, then raised again
            result = {"status": "aborted", "end_reason": f"error: {type(err).__name__}: {err}"}
            raise
        finally:
            staged = trial_dir(stage, t.opts.participant, t.condition, t.practice)
            if staged.is_dir():
                final.parent.mkdir(parents=True, exist_ok=True)
                staged.rename(final)
            _remove_staging(stage)
            self.record(t, k, final, result, time.monotonic() - t0)
        return self.outcome.attempts[-1]

    def record(self, t: SessionTrial, k: int, final: Path, result: dict[str, Any], wall_s: float) -> None:
        """The attempt's status line, its line in the session log and in the outcome."""
        sig = self.signals.received
        reason = str(result.get("end_reason") or "")
        if sig is not None and result.get("status") not in FINISHED and sig not in reason:
            reason = f"{sig} ({reason})" if reason else sig
        crashes = result.get("collisions")
        if not isinstance(crashes, int):  # counted in the log
            try:
                crashes = len(load_trial(final).collisions) if final.is_dir() else 0
            except (OSError, ValueError):
                crashes = 0
        entry = {**result, "trial": t.name, "attempt": k, "directory": str(final) if final.is_dir() else None,
                 "reason": reason, "crashes": crashes}
        entry.pop("frame_ms", None)
        self.outcome.attempts.append(entry)
        self.say(status_line(self.base.participant, t, k, entry, crashes))
        self.log("attempt", trial=t.name, label=t.label, condition=t.condition, practice=t.practice, attempt=k,
                 directory=entry["directory"], status=entry["status"], reason=reason, crashes=crashes,
                 sim_s=result.get("trial_sim_s"), wall_s=round(wall_s, 3), realtime_ratio=result.get("realtime_ratio"))

    def drive_until_done(self, t: SessionTrial) -> Path:
        """Attempts until one is completed; after a stopped one the participant may drive it again.

        :return: the completed attempt's folder
        :raises _Stop: when the session ends instead
        """
        while True:
            a = self.attempt(t)
            if a["status"] in FINISHED:
                return Path(a["directory"])
            why = self.signals.received or _signal_in(a["reason"])
            if why is not None or a["reason"] == "window closed" or self.scripted:
                raise _Stop(why or f"{t.name} {a['status']} ({a['reason']})")
            self.screen(f"stopped-{t.name}", self.protocol.stopped.fill(label=t.label),
                        {ENTER[0]: "again", ENTER[1]: "again", pygame.K_ESCAPE: "quit"}, hint="", confirm=False)

    def questionnaires(self, t: SessionTrial, directory: Path) -> None:
        """The questionnaires after a trial that counts (not when they were answered already).

        :raises _Stop: when the participant closed their window
        """
        names = self.protocol.questionnaires.for_condition(shows_overlay(t.condition))
        done = read_results(directory)
        if t.practice or not names or (done is not None and done.get("completed")):
            return
        if self.scripted and self.answers_from is None:
            self.say(f"{t.name}: questionnaires {', '.join(names)} not asked (a key script drives the session: "
                     "give --answers-from FILE)")
            return
        self.window.open()  # the questionnaires use the session's window
        result = self.ask_questionnaires(self.size, names, directory, self.answers_from)
        self.log("questionnaires", trial=t.name, names=names, completed=result.get("completed"),
                 scores=result.get("scores"))
        self.say(f"{time.strftime('%H:%M:%S')} {self.base.participant} | {t.label} | questionnaires "
                 + ", ".join(f"{k} {v:.1f}" for k, v in (result.get("scores") or {}).items())
                 + ("" if result.get("completed") else " | not finished"))
        if not result.get("completed"):
            raise _Stop(self.signals.received or f"questionnaires after {t.name} not finished")

    def check_same_settings(self, done: Mapping[str, Path | None]) -> None:
        """Refuse to go on with a session whose completed trials were driven with other settings (another
        ``--duration``, ``--seed``, ``--scenario`` or ``--set``): its trials would not be alike. Practice
        trials are not compared (they are not analysed; ``--practice-duration`` may change).

        :raises ConfigError: one line naming the trial and what differs, before any window opens
        """
        for t in self.plan:
            d = done[t.name]
            if d is None or t.practice:
                continue
            try:
                was = trial_settings(meta=load_trial(d).meta)
            except (OSError, ValueError):
                continue  # unreadable: it was not counted as completed either
            now = trial_settings(t.opts)
            differ = [f"{k} {was[k]!r}, now {now[k]!r}" for k in was if was[k] != now[k]]
            if differ:
                raise ConfigError(f"{d.name} was driven with other settings ({'; '.join(differ)}): go on with the "
                                  "settings the session started with, or use another --out")

    def check_same_conditions(self) -> None:
        """Refuse to go on with a participant's session in other conditions, or in another order, than it started
        with (another ``--conditions``, or the same ones typed in another order): the trials would leave the
        participant's counterbalanced order. The first ``start`` in the participant's session log says how it
        started; an unreadable log is not compared.

        :raises ConfigError: one line naming both orders, before any window opens
        """
        try:
            lines = self.log_path.read_text(encoding="utf-8").splitlines() if self.log_path.is_file() else []
            start = next((e for e in map(json.loads, lines) if e.get("event") == "start"), None)
            was = [t["condition"] for t in start["plan"] if not t["practice"]] if start else None
        except (OSError, ValueError, TypeError, KeyError, AttributeError):  # a damaged log: not compared
            return
        now = [t.condition for t in self.plan if not t.practice]
        if was is not None and was != now:
            raise ConfigError(f"{self.base.participant}'s session started with the conditions {', '.join(was)} (in "
                              f"that order); --conditions gives {', '.join(now)}: go on with the conditions it started "
                              "with, or use another --out")

    def end_screen(self) -> None:
        """The end screen, until Enter; the session is over already, so closing the window (or a
        SIGTERM) there is its normal end, not a stop."""
        try:
            self.screen("end", self.protocol.end.fill(), hint="", confirm=False)
        except _Stop:
            pass

    def run(self) -> SessionOutcome:
        """The whole session (module docstring)."""
        self.check_same_conditions()
        done = {t.name: completed_attempt(self.out, t.name) for t in self.plan}
        self.check_same_settings(done)
        self.say(f"session of {self.base.participant} in {self.base.out} (protocol {self.protocol.name}): practice "
                 f"{', '.join(t.condition for t in self.plan if t.practice) or 'none'}, then "
                 f"{', '.join(t.condition for t in self.plan if not t.practice)}")
        self.log("start", participant=self.base.participant, protocol=self.protocol.name,
                 plan=[{"trial": t.name, "label": t.label, "condition": t.condition, "practice": t.practice,
                        "seed": t.opts.seed, "duration_s": t.opts.duration_s} for t in self.plan],
                 already_completed=[n for n, d in done.items() if d is not None])
        explained = any(d is not None and shows_overlay(t.condition) for t, d in zip(self.plan, done.values(), strict=True))
        try:
            if not any(done.values()):
                self.briefing()
            for i, t in enumerate(self.plan):
                entry = {"trial": t.name, "label": t.label, "condition": t.condition, "practice": t.practice,
                         "status": "not run", "directory": None}
                self.outcome.trials.append(entry)
                d = done[t.name]
                if d is None:
                    entry["status"] = "stopped"
                    first_main = not t.practice and (i == 0 or self.plan[i - 1].practice)
                    self.before(t, first_main, shows_overlay(t.condition) and not explained)
                    explained = explained or shows_overlay(t.condition)
                    d = self.drive_until_done(t)
                else:
                    self.say(f"{d.name}: already completed, skipped")
                entry["status"], entry["directory"] = ("completed" if done[t.name] is None else "skipped"), str(d)
                self.questionnaires(t, d)
            self.end_screen()
        except _Stop as stop:
            self.outcome.stopped = str(stop)
            self.outcome.trials.extend({"trial": t.name, "label": t.label, "condition": t.condition,
                                        "practice": t.practice, "status": "not run", "directory": None}
                                       for t in self.plan[len(self.outcome.trials):])
        except BaseException as err:  # an error, a second Ctrl-C: logged as the session's end, then raised again
            self.outcome.stopped = f"{type(err).__name__}: {err}" if str(err) else type(err).__name__
            raise
        finally:
            self.window.close()
            self.log("end", stopped=self.outcome.stopped,
                     completed=[t["trial"] for t in self.outcome.trials if t["status"] in ("completed", "skipped")])
        return self.outcome


def _duration_s(base: DriveOptions, condition: str) -> float:
    """A trial's length [s]: ``--duration``, else the scenario's."""
    if base.duration_s is not None:
        return float(base.duration_s)
    return float(load_config(base.scenario, list(base.overrides), drive_config(condition)).highway.duration)


def _window_size(base: DriveOptions, condition: str) -> tuple[int, int]:
    """The driving window's size ``(width, height)`` [px] (``--size``, else the camera's), for the session's screens."""
    if base.size is not None:
        return int(base.size[0]), int(base.size[1])
    cfg = load_config(base.scenario, list(base.overrides), drive_config(condition))
    return cfg.camera.width_px, cfg.camera.height_px


def _drive_quietly(opts: DriveOptions) -> dict[str, Any]:
    """Drive one attempt of the session.

    :func:`~dt_highway.hmi.drive.run_drive` without its own status line (the session prints one
    per attempt, with the attempt's folder rather than the staging one), leaving the window open for the session's
    next screen (closed at the session's end).

    :param opts: the attempt
    :return: what :func:`~dt_highway.hmi.drive.run_drive` returns
    """
    return run_drive(opts, say=lambda _line: None, keep_window=True)


def check_questionnaires(protocol: Protocol) -> None:
    """Read every questionnaire the protocol names, before the session starts.

    :param protocol: the session's protocol
    :raises ConfigError: one line, on an unknown name or a bad file
    """
    for name in {*protocol.questionnaires.baseline, *protocol.questionnaires.overlay}:
        load_questionnaire(name)


def check_answers(data: Mapping[str, Any], plan: Sequence[SessionTrial], protocol: Protocol,
                  out: Path | None = None, where: str = "answers") -> None:
    """Check a scripted answers table against every questionnaire the session will still ask after
    its trials, before the session starts.

    :param data: the table (:func:`~dt_highway.hmi.questionnaire.load_answers`)
    :param plan: the session's trials (:func:`session_plan`)
    :param protocol: the session's protocol (which questionnaires follow which trials)
    :param out: the study directory of a resumed session: trials whose questionnaires were answered
        there are not asked again, so need no answers (``None``: check every trial)
    :param where: the file, for the error message
    :raises ConfigError: one line naming the trial, the questionnaire and the missing or bad item
    """
    for t in plan:
        done = completed_attempt(out, t.name) if out is not None and not t.practice else None
        if t.practice or (done is not None and (read_results(done) or {}).get("completed")):
            continue
        for name in protocol.questionnaires.for_condition(shows_overlay(t.condition)):
            scripted_answers(data, load_questionnaire(name), t.name, where=where)


def run_session(base: DriveOptions, practice_duration_s: float | None = None,
                say: Callable[[str], object] = print,
                conditions: Sequence[str] = DEFAULT_CONDITIONS, protocol: Protocol | None = None,
                answers_from: Path | None = None, drive: DriveFn = _drive_quietly,
                questionnaires: QuestionnaireFn = run_questionnaires,
                on_frame: Callable[[np.ndarray], None] | None = None) -> SessionOutcome:
    """Run a participant's session (module docstring): the trials not completed yet, with the
    protocol's screens, the questionnaires and a status line per attempt, after a line with the
    session's plan once every check has passed.

    :param base: shared options (``condition`` and ``practice`` are ignored: the plan sets them)
    :param practice_duration_s: each practice trial's length [s] (``None``: the protocol's)
    :param say: where the experimenter's lines go
    :param conditions: the session's conditions
    :param protocol: what the participant reads (``None``: the default protocol)
    :param answers_from: scripted questionnaire answers (:func:`~dt_highway.hmi.questionnaire.load_answers`)
    :param drive: runs one trial (tests replace it)
    :param questionnaires: asks the questionnaires (tests replace it)
    :param on_frame: called with every session screen shown (not the trials' frames)
    :return: what was done
    :raises ConfigError: on unknown conditions, questionnaires or a bad answers file, before any window opens
    """
    protocol = protocol or load_protocol()
    plan = session_plan(base, practice_duration_s, conditions, protocol)
    check_questionnaires(protocol)
    if answers_from is not None:  # a file that cannot be read or misses an answer fails now, not after a trial
        check_answers(load_answers(answers_from), plan, protocol, Path(base.out), where=f"answers file {answers_from}")
    for moved in recover_staged(Path(base.out)):
        say(f"{moved.name}: left by a process that died, kept as aborted")
    with _Signals() as signals:
        session = _Session(base, plan, protocol, say, drive, questionnaires, answers_from, signals, on_frame)
        return session.run()


__all__ = ["DEFAULT_CONDITIONS", "FINISHED", "PRACTICE_SEED_OFFSET", "SESSIONS", "STAGING", "SessionOutcome", "SessionTrial",
           "attempt_dirs", "attempt_name", "balanced_latin_square", "check_answers", "check_conditions",
           "check_questionnaires", "completed_attempt", "condition_order", "recover_staged", "run_session", "session_plan",
           "status_line", "trial_name"]

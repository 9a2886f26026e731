"""The driving window: a participant drives the ego from the first-person camera view.

One trial: the scenario's highway with the ego under the keyboard (:mod:`dt_highway.hmi.keys`),
the synthetic camera as the main picture, in the overlay conditions the overlay's steady marks
drawn on it (:func:`dt_highway.overlay.draw_overlay`, from the fusion's output only), a HUD
(speed in km/h, lane, time left, a neutral label such as "Trial 2": never the condition's name),
highway-env's top-down view as a mini-map (M toggles it) and, with ``mirrors``, the rear-view
mirror image of :func:`dt_highway.hmi.mirror.render_mirrors`. The
simulation is locked to the wall clock at its configured frequency (trials default to
:data:`TRIAL_SIMULATION_HZ`, one decision per simulation step); the window reads its events (the keys)
at up to ``fps`` frames per second and draws the composed picture, scaled to the window (resizable,
or fullscreen), only when it changed: at most once per simulation step outside the crash flash.

Input: keys held through the 3-2-1 countdown act at t = 0 and are logged as pressed at t = 0
(``pressed_at_s``: when, before the start). A key is logged at the moment the window received it
(trial time to 0.1 ms, within the simulation step it fell in, and ``wall_time``, ISO 8601 UTC);
every event of the log carries ``wall_time``. Pauses are logged (``pause_start``, ``pause_end``
with ``duration_s``), SIGTERM and SIGINT end the trial as such (``signal`` events), a window
closed by the window manager ends it at once. With ``wheel`` a joystick or wheel drives instead
(:mod:`dt_highway.hmi.joystick`, read once per simulation step, its values logged in the ``keys``
column: :func:`wheel_text`); a missing calibration file runs the calibration screen first.

Crashes: a red flash and a "COLLISION" banner (:data:`CRASH_BANNER_S`), a beep when a sound
device is there (silent without); ``on_crash`` ``end`` ends the trial (status
``ended_by_collision``, ``cut_short``), ``continue`` puts the ego back in its lane ahead of the
crash with a clear gap at the speed of traffic (:func:`place_ego_after_crash`) and counts the
crash. The metadata's ``collision`` holds the count and the times.

Every trial is logged like a scripted one (:mod:`dt_highway.metrics.trial_log`), plus every key press
and release and the keys held at each step. ``--keys-from`` replays a key script (no prompts or
confirmations then), ``--screenshot-every`` saves PNGs of what the participant saw. Participants
never see a file path: paths and a one-line status per trial go to the terminal (and a warning line when the
trial did not keep real time: :func:`realtime_ratio`).
Headless: ``SDL_VIDEODRIVER=offscreen``.
"""

from __future__ import annotations

import json
import math
import queue
import shutil
import sys
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import cv2
import gymnasium as gym
import numpy as np
import pygame  # without its banner: gymnasium, which dt_highway imports first, sets PYGAME_HIDE_SUPPORT_PROMPT

from dt_highway.choices import CRASH_POLICIES
from dt_highway.conditions import condition_config
from dt_highway.config import ConfigError, DTConfig, deep_merge, load_config
from dt_highway.env.core import DTHighwayEnv
from dt_highway.hmi.crash import (
    CRASH_BANNER_S,
    CRASH_FLASH_S,
    CrashBeep,
    CrashView,
    beep_samples,
    crash_layer,
    place_ego_after_crash,
)
from dt_highway.hmi.joystick import Calibration, CalibrationError, JoystickInput, calibration_screen, open_joystick
from dt_highway.hmi.keys import KeyEvent, KeyScript, Pedals, Steering
from dt_highway.hmi.mirror import render_mirrors
from dt_highway.hmi.picture import MIRROR_FRACTION, Hud, compose_frame, hud_band_height
from dt_highway.hmi.screens import (
    END_SCREEN_S,
    LEGEND,
    PAUSE_LINES,
    QUIT_LINES,
    _end_screen,
    _start_screens,
    card,
    dialog,
    show_card,
)
from dt_highway.hmi.window import (
    DRIVING_KEYS,
    PYGAME_KEYS,
    SIZE_LIMITS_PX,
    WINDOW_TITLE,
    SignalScope,
    _key_names,
    _Signals,
    _Window,
    parse_size,
)
from dt_highway.metrics.trial_log import TrialRecorder, TrialWriter

__all__ = [  # this module's own, and (re-exported) what moved to crash, picture, screens, window and dt_highway.choices
    "CRASH_BANNER_S", "CRASH_FLASH_S", "CRASH_POLICIES", "DRIVING_KEYS", "END_SCREEN_S", "LEGEND", "MIRROR_FRACTION",
    "PAUSE_LINES", "PYGAME_KEYS", "QUIT_LINES", "REALTIME_MIN_S", "REALTIME_WARN_BELOW", "SIZE_LIMITS_PX",
    "TRIAL_SIMULATION_HZ", "WINDOW_TITLE", "CrashBeep", "DriveOptions", "Hud", "SignalScope", "beep_samples", "card",
    "compose_frame", "crash_layer", "dialog", "drive_config", "held_at_start", "hud_band_height", "open_wheel",
    "parse_size", "place_ego_after_crash", "is_slow", "realtime_ratio", "run_drive", "show_card", "slow_trial_line",
    "check_free", "trial_dir", "trial_name", "trial_settings", "wall_time", "wheel_calibration_path", "wheel_text",
]

TRIAL_SIMULATION_HZ = 30
"""Keyboard trials' simulation frequency unless told otherwise [Hz] (``highway.simulation_frequency``;
``highway.policy_frequency`` follows it). ``dt-highway bench drive`` here (2 cores, load ~0.5): 30 Hz kept real
time at 640x360 and 1280x720 (simulated / wall 0.999, 61 frames/s, frame p99 5.2 / 11.4 ms)"""

REALTIME_WARN_BELOW = 0.95
"""A trial whose simulated time is less than this share of its wall time (pauses left out) ran in slow motion:
the experimenter is told (:func:`realtime_ratio`) [-]"""

REALTIME_MIN_S = 10.0
"""The wall time [s] (pauses left out) a trial must run for its :func:`realtime_ratio` to be judged: the
simulation lags the clock by up to one step and the window's loop ends a moment after the last step, about
0.05-0.1 s, which would read as slow motion in a trial stopped after a second or two"""

def wall_time(t_mono: float | None = None) -> str:
    """The wall clock, ISO 8601 in UTC to the millisecond.

    :param t_mono: a moment of :func:`time.monotonic` [s] (``None``: now)
    :return: e.g. ``2026-11-24T01:02:03.456+00:00``
    """
    epoch = time.time() - (0.0 if t_mono is None else time.monotonic() - t_mono)
    return datetime.fromtimestamp(epoch, UTC).isoformat(timespec="milliseconds")


def drive_config(condition: str, steering: bool = False) -> dict[str, Any]:
    """What a keyboard trial changes in the configuration: the ``Driver`` action with one
    decision per simulation step (the keys act at once), the camera in every condition (it is
    the participant's view, and the observation), the fusion and its overlay as the condition says
    (:func:`~dt_highway.conditions.condition_config`: ``adas``, ``adas-threat``, ``sham``...).

    :param condition: the trial's condition (``baseline``, ``adas``...)
    :param steering: Left/Right steer instead of changing lanes (the ``Driver`` action's ``steering``)
    :return: the settings, a nested dict to merge over the scenario's
    :raises ConfigError: on an unknown condition (one line naming the allowed ones)
    """
    cond = condition_config(condition)
    # the window shows the camera frame: as observation it costs nothing more (one rendering
    # per step), where highway-env's Kinematics table would cost ~10 ms a step with 50 vehicles
    action: dict[str, Any] = {"type": "Driver", "steering": True} if steering else {"type": "Driver"}
    return deep_merge(cond, {"highway": {"action": action, "observation": {"type": "Camera"}}, "camera": {"enabled": True}})


@dataclass
class DriveOptions:
    """One keyboard trial.

    :param participant: participant id
    :param condition: one of :data:`~dt_highway.conditions.CONDITIONS` (``baseline``, ``adas``, ``sham``...)
    :param out: the study directory (the trial goes to ``<out>/trials/<participant>-<condition>``)
    :param practice: a practice trial (``<participant>-practice``; left out of the report)
    :param scenario: scenario file
    :param overrides: ``--set`` strings (they win over ``simulation_hz`` and ``size``)
    :param duration_s: trial length [s] (``None``: the scenario's)
    :param seed: traffic seed
    :param keys_from: a key script to replay instead of the keyboard (events at negative times are keys
        pressed during the countdown)
    :param screenshot_every_s: save a screenshot this often [s of trial time] (``None``: never)
    :param screenshots: where screenshots go (default ``<trial>/screenshots``)
    :param fps: most window frames per second: how often keys are read [1/s]; a picture is drawn only when
        it changed (at most the simulation rate, outside the crash flash)
    :param minimap: show the mini-map at the start
    :param steering: Left/Right steer (self-centring) instead of changing lanes
    :param display_label: what the participant is told the trial is (``Trial 2``...): never the condition's
        name; a practice trial with the default label shows ``Practice``
    :param on_crash: ``end`` the trial on a crash, or ``continue`` (the ego put back on the road, the crash counted)
    :param size: the window and camera size ``(width, height)`` [px] (``None``: the configuration's camera size)
    :param fullscreen: fill the screen (the picture scaled, its aspect kept)
    :param simulation_hz: simulation frequency [Hz] (``None``: the scenario's); decisions follow it
    :param mirrors: draw the rear-view mirror (needs :mod:`dt_highway.hmi.mirror`; none without it)
    :param sound: beep on a crash when a sound device is there
    :param wheel: drive with this joystick or wheel (its index among those connected; ``None``: the keyboard):
        its pedals give the acceleration, its wheel the lane changes (or the steering with ``steering``),
        read once per simulation step (:class:`~dt_highway.hmi.joystick.JoystickInput`); P, M and Esc stay on the keyboard
    :param wheel_calibration: the wheel's calibration file (``None``: ``<out>/wheel-calibration.json``); when
        missing, the calibration screen runs first and saves it there
    :param force: replace a trial already in the trial's folder, the whole folder, once the new trial starts
        (else :func:`run_drive` refuses, before the window opens)
    :param legend: the keys' legend on the screen before the trial: ``(key, what it does)`` pairs (a session
        passes its protocol's)
    """

    participant: str
    condition: str
    out: Path
    practice: bool = False
    scenario: str | None = None
    overrides: list[str] = field(default_factory=list)
    duration_s: float | None = None
    seed: int = 0
    keys_from: KeyScript | None = None
    screenshot_every_s: float | None = None
    screenshots: Path | None = None
    fps: int = 60
    minimap: bool = True
    steering: bool = False
    display_label: str = "Trial"
    on_crash: str = "end"
    size: tuple[int, int] | None = None
    fullscreen: bool = False
    simulation_hz: int | None = TRIAL_SIMULATION_HZ
    mirrors: bool = False
    sound: bool = True
    wheel: int | None = None
    wheel_calibration: Path | None = None
    force: bool = False
    legend: tuple[tuple[str, str], ...] = LEGEND

    @property
    def label(self) -> str:
        """The label shown to the participant."""
        return "Practice" if self.practice and self.display_label == "Trial" else self.display_label


def trial_name(participant: str, condition: str, practice: bool) -> str:
    """The folder name of a trial's first attempt: ``P01-adas``, ``P01-practice-adas``.

    :param participant: participant id
    :param condition: the trial's condition
    :param practice: a practice trial
    :return: the folder name
    """
    return f"{participant}-practice-{condition}" if practice else f"{participant}-{condition}"


def trial_dir(out: Path, participant: str, condition: str, practice: bool) -> Path:
    """Where a keyboard trial is logged: ``<out>/trials/<participant>-<condition>``, a practice trial in
    ``<participant>-practice`` (a name no session gives, so that a set-up practice does not count as a session's
    practice trial; a session moves each attempt to its own name, :func:`trial_name`).

    :param out: the study directory
    :param participant: participant id
    :param condition: the trial's condition (not part of a practice trial's folder)
    :param practice: a practice trial
    :return: the trial's folder
    """
    return Path(out) / "trials" / (f"{participant}-practice" if practice else trial_name(participant, condition, False))


def check_free(directory: Path) -> None:
    """Refuse a trial folder that holds a trial already (``--force`` replaces it).

    :param directory: the trial's folder (missing or empty: free)
    :raises ConfigError: one line naming the folder, what it holds and the ways out
    """
    if not directory.is_dir() or not any(directory.iterdir()):
        return
    try:
        status = json.loads((directory / "meta.json").read_text(encoding="utf-8")).get("status", "?")
    except (OSError, ValueError, AttributeError):
        status = "unreadable"
    raise ConfigError(f"{directory} holds a trial already (status {status}): pass --force to replace it, or use "
                      "another --participant or --out")


class _ClockedWriter(TrialWriter):
    """The trial writer with the wall clock on every event (``wall_time``, ISO 8601 UTC; when the
    event does not bring its own, the moment it is written)."""

    def event(self, kind: str, t_s: float, **fields: Any) -> None:
        fields.setdefault("wall_time", wall_time())
        super().event(kind, t_s, **fields)


def held_at_start(events: Iterable[KeyEvent]) -> dict[str, float]:
    """The driving keys down at t = 0 after the key events before it (the countdown).

    :param events: events at negative trial times [s]
    :return: each key held at t = 0 and when it was pressed [s, <= 0]
    """
    held: dict[str, float] = {}
    for ev in sorted(events, key=lambda e: e.t_s):
        if ev.key not in DRIVING_KEYS:
            continue
        if ev.down:
            held.setdefault(ev.key, ev.t_s)
        else:
            held.pop(ev.key, None)
    return held


def wheel_text(steer: float, throttle: float, brake: float) -> str:
    """How a step's wheel values are logged in the ``keys`` column of ``steps.csv`` (beside the keys held).

    :param steer: wheel command in ``[-1, 1]`` (positive to the right)
    :param throttle: throttle travel in ``[0, 1]``
    :param brake: brake travel in ``[0, 1]``
    :return: e.g. ``wheel:steer=+0.500,throttle=1.000,brake=0.000``
    """
    return f"wheel:steer={steer:+.3f},throttle={throttle:.3f},brake={brake:.3f}"


@dataclass
class _Snapshot:
    """What the window shows of one simulation step (made by the simulation thread)."""

    rgb: np.ndarray
    marks: list[dict[str, Any]] | None
    hud: Hud
    minimap: np.ndarray | None
    n_steps: int
    mirror: np.ndarray | None = None
    crashes: int = 0
    crash_mono: float | None = None


class _Trial:
    """The simulation side of a keyboard trial: runs in its own thread, locked to the wall
    clock, and hands the window a snapshot after every simulation step.

    Every write to the trial log happens on this thread; the window only reads snapshots and
    posts inputs (``(kind, key, monotonic time)``: ``down``, ``up``, ``other`` (a key that is not a trial key),
    ``closed``, ``signal``).
    """

    def __init__(self, env: gym.Env, log: TrialWriter, opts: DriveOptions, info: dict[str, Any],
                 shots_dir: Path, pre_start: Iterable[KeyEvent] = (), joystick: JoystickInput | None = None) -> None:
        u = env.unwrapped
        if not isinstance(u, DTHighwayEnv):
            raise TypeError(f"a keyboard trial drives a dt-highway-v0 env (got {type(u).__name__})")
        self.env, self.u, self.log, self.opts = env, u, log, opts
        self.cfg_fusion = self.u.dt_config.fusion.enabled
        self.duration = self.u.dt_config.highway.duration
        self.dt = 1.0 / self.u.dt_config.highway.simulation_frequency
        self.rec = TrialRecorder(log)
        self.pedals, self.wheel = Pedals(), Steering()
        self.joystick = joystick
        self.held: set[str] = set()
        self.lane_tap = 0
        self.n_steps = 0
        self.info = info
        self.paused = self.confirm_quit = False
        self.show_map = opts.minimap
        self.done = False
        self.end_reason, self.status = "time limit", "completed"
        self.error: BaseException | None = None
        self.inputs: queue.SimpleQueue[tuple[str, str, float]] = queue.SimpleQueue()
        self.lock = threading.Lock()
        self.snapshot: _Snapshot | None = None
        self.shots_dir = shots_dir
        self.next_shot = 0.0 if opts.screenshot_every_s else math.inf
        self.shots = 0
        self.wall0 = time.monotonic()
        self._paused_s = 0.0
        self._pause_start = 0.0
        self._pause_t = 0.0
        self._pause_why = ""
        self.pauses: list[dict[str, Any]] = []
        self.crashes: list[dict[str, Any]] = []
        self.crash_mono: float | None = None
        self.mirror_fn = render_mirrors if opts.mirrors else None
        self.rec.record(info, np.array([self.pedals.accel_mps2, 0.0]), "")
        for key, t_press in held_at_start(pre_start).items():  # held through the countdown: pressed at t = 0
            self.key_event(KeyEvent(0.0, True, key), pressed_at_s=round(t_press, 4))
        self._publish()

    @property
    def t_sim(self) -> float:
        """Trial time [s]."""
        return self.n_steps * self.dt

    def trial_time(self, t_mono: float) -> float:
        """The trial time of a moment of the wall clock, within the simulation step it fell in.

        :param t_mono: a moment of :func:`time.monotonic` [s]
        :return: trial time [s] (while paused: the time of the pause)
        """
        if self.paused:
            return self._pause_t
        t = t_mono - self.wall0 - self._paused_s
        return round(min(max(t, self.t_sim), self.t_sim + self.dt), 4)

    # ---------------------------------------------------------------- keys
    def _set_pause(self, on: bool, why: str, t_mono: float | None = None, t_s: float | None = None) -> None:
        """Pause or go on, logged.

        :param on: pause (``True``) or go on
        :param why: what asked for it (``P``, ``Esc``, ``end``)
        :param t_mono: when (:func:`time.monotonic`; ``None``: now)
        :param t_s: the trial time of a pause's start [s] (``None``: from ``t_mono``)
        """
        t_mono = time.monotonic() if t_mono is None else t_mono
        if on and not self.paused:
            self._pause_t = self.trial_time(t_mono) if t_s is None else t_s
            self.paused, self._pause_start, self._pause_why = True, t_mono, why
            self.log.event("pause_start", self._pause_t, wall_time=wall_time(t_mono), reason=why)
        elif not on and self.paused:
            self.paused = False
            d = max(t_mono - self._pause_start, 0.0)
            self._paused_s += d
            self.pauses.append({"t_s": self._pause_t, "duration_s": round(d, 3), "reason": self._pause_why})
            self.log.event("pause_end", self._pause_t, wall_time=wall_time(t_mono), duration_s=round(d, 3))

    def key_event(self, ev: KeyEvent, t_mono: float | None = None, **extra: Any) -> None:
        """Log a key press or release and act on it.

        :param ev: the event
        :param t_mono: when the window received it (:func:`time.monotonic`), for its wall time
        :param extra: more fields for the log
        """
        when = {} if t_mono is None else {"wall_time": wall_time(t_mono)}
        self.log.event("key_down" if ev.down else "key_up", ev.t_s, key=ev.key, **when, **extra)
        if not ev.down:
            self.held.discard(ev.key)
            return
        self.held.add(ev.key)
        scripted = self.opts.keys_from is not None
        if ev.key == "ESC":
            if self.confirm_quit or scripted:
                self.stop("quit by the participant")
            else:
                self.confirm_quit = True
                self._set_pause(True, "Esc", t_mono, ev.t_s)
        elif self.confirm_quit:  # any other key: go on
            self._go_on(t_mono)
        elif ev.key in ("LEFT", "RIGHT") and not self.opts.steering:
            self.lane_tap = -1 if ev.key == "LEFT" else 1
        elif ev.key == "P":
            self._set_pause(not self.paused, "P", t_mono, ev.t_s)
        elif ev.key == "M":
            self.show_map = not self.show_map

    def _go_on(self, t_mono: float | None) -> None:
        """The quit question answered "go on" (any key but Esc): the trial goes on."""
        self.confirm_quit = False
        self._set_pause(False, "Esc", t_mono)

    def take_input(self, kind: str, key: str, t_mono: float) -> None:
        """One input from the window thread (module docstring of the class)."""
        if kind in ("down", "up"):
            self.key_event(KeyEvent(self.trial_time(t_mono), kind == "down", key), t_mono)
        elif kind == "other":  # a key that is not a trial key (Enter, Space...): it answers the quit question only
            if self.confirm_quit:  # not logged as a key: the logs' keys are the trial's (the pause's end is logged)
                self._go_on(t_mono)
        elif kind == "closed":
            self.log.event("window_closed", self.trial_time(t_mono), wall_time=wall_time(t_mono))
            self.stop("window closed")
        elif kind == "signal":
            self.log.event("signal", self.trial_time(t_mono), wall_time=wall_time(t_mono), signal=key)
            self.stop(key)

    def stop(self, reason: str, status: str = "aborted") -> None:
        """End the trial."""
        if not self.done:
            if self.paused:
                self._set_pause(False, "end")
            self.done, self.end_reason, self.status = True, reason, status

    # ---------------------------------------------------------------- simulation
    def _publish(self) -> None:
        u = self.u
        ego = u.vehicle
        hud = Hud(float(ego.speed) * 3.6, int(ego.lane_index[2]) + 1,
                  len(u.road.network.graph[ego.lane_index[0]][ego.lane_index[1]]), self.duration - self.t_sim,
                  self.opts.label, self.paused)
        marks = (self.info.get("adas") or {}).get("overlay") if self.cfg_fusion else None
        minimap = self.env.render() if self.show_map else None  # rgb_array mode: an image
        assert minimap is None or isinstance(minimap, np.ndarray)
        rgb = u.camera_image().rgb
        mirror = None
        if self.mirror_fn is not None:
            h, w = rgb.shape[:2]
            mirror = self.mirror_fn(self.u, (round(w * MIRROR_FRACTION[0]), round(h * MIRROR_FRACTION[1])))
        snap = _Snapshot(rgb, marks, hud, minimap, self.n_steps, mirror, len(self.crashes), self.crash_mono)
        with self.lock:
            self.snapshot = snap
        if self.t_sim + 1e-9 >= self.next_shot:  # what the window shows of this step, saved
            self.shots_dir.mkdir(parents=True, exist_ok=True)
            img = compose_frame(snap.rgb, snap.marks, snap.hud, snap.minimap, snap.mirror)
            if self.crashes:
                img = crash_layer(img, self.t_sim - self.crashes[-1]["t_s"])
            cv2.imwrite(str(self.shots_dir / f"t{self.t_sim:07.2f}s.png"), img[..., ::-1])
            self.shots += 1
            self.next_shot += self.opts.screenshot_every_s or math.inf

    def _on_crash(self) -> None:
        """A crash: counted, then the trial ends or the ego is put back on the road (``on_crash``)."""
        self.crashes.append({"t_s": round(self.t_sim, 9), "wall_time": wall_time()})
        self.crash_mono = time.monotonic()
        if self.opts.on_crash == "end":
            self.stop("collision", "ended_by_collision")
            return
        placed = place_ego_after_crash(self.u)
        self.pedals.reset()
        self.wheel.reset()
        self.log.event("ego_reset", round(self.t_sim, 9), **placed)

    def _action(self) -> tuple[np.ndarray, str]:
        """This step's action and what the ``keys`` column logs of it: the keys held and, with a wheel,
        its values read now (:func:`wheel_text`)."""
        held = self.held
        keys = ";".join(sorted(held))
        if self.joystick is not None:  # the window's thread pumps the events that move the axes
            cmd = self.joystick.read()
            lane = cmd.steer if self.opts.steering else float(cmd.lane_tap or self.lane_tap)
            return np.array([cmd.accel_mps2, lane]), ";".join(filter(None, (keys, wheel_text(cmd.steer, cmd.throttle,
                                                                                             cmd.brake))))
        accel = self.pedals.update("UP" in held, "DOWN" in held, self.dt)
        if self.opts.steering:
            return np.array([accel, self.wheel.update("LEFT" in held, "RIGHT" in held, self.dt)]), keys
        return np.array([accel, float(self.lane_tap)]), keys

    def _step(self) -> None:
        action, keys = self._action()
        self.lane_tap = 0
        _, _, terminated, truncated, self.info = self.env.step(action)
        self.n_steps += 1
        self.rec.record(self.info, action, keys)
        crashed = bool(self.u.vehicle.crashed)
        if crashed:
            self._on_crash()
        if truncated:
            self.stop("time limit", "completed")
        elif terminated and not crashed:
            self.stop("the env ended the episode", "completed")
        self._publish()

    def _drain_inputs(self) -> None:
        while True:
            try:
                kind, key, t_mono = self.inputs.get_nowait()
            except queue.Empty:
                return
            self.take_input(kind, key, t_mono)

    def run(self) -> None:
        """The simulation loop (thread body): inputs, then the steps the wall clock asks for."""
        script = self.opts.keys_from
        self.wall0 = time.monotonic()
        try:
            while not self.done:
                self._drain_inputs()
                if script is not None and self.paused:  # a script's pause lasts in wall time
                    for ev in script.due(self.t_sim + time.monotonic() - self._pause_start):
                        self.key_event(ev)
                    if self.paused and script.finished:  # no key left to end it (a script built in code)
                        self.stop("the key script ended with the trial paused")
                if self.done:
                    break
                now = time.monotonic() - self.wall0 - self._paused_s
                if self.paused or self.t_sim + self.dt > now + 1e-9:
                    wait = 0.01 if self.paused else self.t_sim + self.dt - now
                    time.sleep(min(max(wait, 0.0), 0.005))
                    continue
                if script is not None:
                    for ev in script.due(self.t_sim):
                        self.key_event(ev)
                    if self.done or self.paused:
                        continue
                self._step()
        except BaseException as err:  # noqa: BLE001 - handed to the window's thread, which re-raises it
            self.error = err
            self.done = True


def _trial_overrides(opts: DriveOptions) -> list[str]:
    """The trial's ``--set`` strings: its simulation frequency, window size, the caller's and ``--duration``."""
    overrides = [] if opts.simulation_hz is None else [f"highway.simulation_frequency={opts.simulation_hz}"]
    if opts.size is not None:
        overrides += [f"camera.width_px={opts.size[0]}", f"camera.height_px={opts.size[1]}"]
    overrides += list(opts.overrides)
    if opts.duration_s is not None:
        overrides.append(f"highway.duration={opts.duration_s}")
    return overrides


WINDOW_KEYS = ("camera.width_px=", "camera.height_px=")
"""``--set`` strings that only size the window: two attempts of a trial may differ in them (another monitor)"""


def trial_settings(opts: DriveOptions | None = None, meta: dict[str, Any] | None = None) -> dict[str, Any]:
    """What makes two attempts the same trial: condition, seed, scenario (file name) and the ``--set`` strings
    (length and simulation frequency among them; the window's size left out), of a planned trial or of a log's
    ``meta.json``.

    :param opts: the planned trial's options
    :param meta: a trial log's metadata (:func:`_trial_meta`), when ``opts`` is ``None``
    :return: ``condition``, ``seed``, ``scenario`` and ``--set``, by name
    """
    m: dict[str, Any] = meta or {}
    if opts is not None:
        m = {"condition": opts.condition, "seed": opts.seed, "scenario": opts.scenario, "overrides": _trial_overrides(opts)}
    scenario = m.get("scenario")
    return {"condition": m.get("condition"), "seed": m.get("seed"), "scenario": Path(scenario).name if scenario else None,
            "--set": [o for o in m.get("overrides") or [] if not str(o).startswith(WINDOW_KEYS)]}


def _trial_config(opts: DriveOptions) -> tuple[DTConfig, list[str], float]:
    """The trial's configuration, with one decision per simulation step.

    :return: the configuration, the ``--set`` strings (the trial's simulation frequency, size and
        ``--duration`` among them; the caller's win) and the simulation frequency [Hz]
    :raises ConfigError: one line, on ``highway.offscreen_rendering = false``
    """
    overrides = _trial_overrides(opts)
    # first the simulation frequency alone (decisions at 1 Hz divide any), then decisions at that frequency
    cfg = load_config(opts.scenario, [*overrides, "highway.policy_frequency=1"], drive_config(opts.condition, opts.steering))
    f_sim = cfg.highway.simulation_frequency
    cfg = load_config(opts.scenario, [*overrides, f"highway.policy_frequency={f_sim}"],
                      drive_config(opts.condition, opts.steering))
    if cfg.highway.offscreen_rendering is False:  # highway-env's viewer would open its own window over the trial's
        raise ConfigError("highway.offscreen_rendering = false is not for keyboard trials: the mini-map is drawn into "
                          "the trial's window (leave it unset or true)")
    return cfg, overrides, f_sim


def _trial_meta(opts: DriveOptions, cfg: DTConfig, overrides: list[str], f_sim: float) -> dict[str, Any]:
    """The trial log's metadata (as a scripted trial's, the driver being the keyboard)."""
    return {"driver": "keyboard", "driver_file": None,
            "driver_params": {"keys_from": opts.keys_from is not None, "steering": opts.steering, "wheel": opts.wheel},
            "participant": opts.participant, "condition": opts.condition, "practice": opts.practice,
            "pair": None, "seed": opts.seed, "scenario": opts.scenario, "overrides": overrides,
            "config": cfg.to_dict(), "simulation_frequency_hz": f_sim, "display_label": opts.label,
            "on_crash": opts.on_crash, "window": {"size_px": [cfg.camera.width_px, cfg.camera.height_px],
                                                  "fullscreen": opts.fullscreen, "mirrors": opts.mirrors}}


def wheel_calibration_path(opts: DriveOptions) -> Path:
    """The wheel's calibration file: ``wheel_calibration``, else ``<out>/wheel-calibration.json``.

    :param opts: the trial's options
    :return: the file's path (it may not exist yet)
    """
    return Path(opts.wheel_calibration) if opts.wheel_calibration is not None else Path(opts.out) / "wheel-calibration.json"


def open_wheel(opts: DriveOptions) -> pygame.joystick.JoystickType | None:
    """The trial's wheel (``None``: the keyboard drives).

    :param opts: the trial's options (its ``wheel`` index)
    :return: the opened device, or ``None`` when no wheel is asked for
    :raises ConfigError: one line naming ``--wheel``, when there is no such device
    """
    if opts.wheel is None:
        return None
    try:
        return open_joystick(opts.wheel)
    except CalibrationError as err:
        raise ConfigError(f"--wheel {opts.wheel}: {err}") from None


def _wheel_input(opts: DriveOptions, device: pygame.joystick.JoystickType,
                 win: _Window) -> tuple[JoystickInput, Calibration] | None:
    """The wheel's reader, with its calibration loaded, or made on the calibration screen and saved
    (:func:`wheel_calibration_path`) when the file is missing.

    :return: the reader and the calibration; ``None`` when the calibration was cancelled
    :raises ConfigError: one line naming ``--wheel-calibration``, when the file is bad or does not fit the device
    """
    path = wheel_calibration_path(opts)
    try:
        if path.exists():
            cal: Calibration | None = Calibration.load(path)
        else:
            cal = calibration_screen(device, save_to=path, window=win.screen)
            pygame.display.set_caption(WINDOW_TITLE)
        if cal is None:
            return None
        return JoystickInput(device, cal), cal
    except (CalibrationError, ConfigError) as err:
        raise ConfigError(f"--wheel-calibration {path}: {err}") from None


MODIFIER_KEYS = frozenset(getattr(pygame, k) for k in (
    "K_LSHIFT", "K_RSHIFT", "K_LCTRL", "K_RCTRL", "K_LALT", "K_RALT", "K_LGUI", "K_RGUI", "K_MODE", "K_CAPSLOCK",
    "K_NUMLOCK", "K_SCROLLOCK"))
"""Keys that never answer the quit question: modifiers and locks (touched by accident, or sent by the system when
the window gets the focus back with Alt+Tab)"""


def _pass_events(win: _Window, trial: _Trial, names: dict[int, str], scripted: bool) -> None:
    """Hand the window's key presses and releases (not when a script drives) and its close to the simulation."""
    for ev in win.events():
        now = time.monotonic()
        if ev.type == pygame.QUIT:
            trial.inputs.put(("closed", "", now))
        elif not scripted and ev.type in (pygame.KEYDOWN, pygame.KEYUP) and ev.key in names:
            trial.inputs.put(("down" if ev.type == pygame.KEYDOWN else "up", names[ev.key], now))
        elif not scripted and ev.type == pygame.KEYDOWN and ev.key not in MODIFIER_KEYS:
            trial.inputs.put(("other", pygame.key.name(ev.key), now))  # not a trial key: it only answers the quit question


def _window_frame(trial: _Trial, snap: _Snapshot) -> np.ndarray:
    """The picture of a step, with the pause or (instead) the question whether to quit."""
    confirm = trial.confirm_quit
    img = compose_frame(snap.rgb, snap.marks, replace(snap.hud, paused=trial.paused and not confirm), snap.minimap,
                        snap.mirror)
    if confirm:
        dialog(img, QUIT_LINES)
    return img


def _with_crash(img: np.ndarray, snap: _Snapshot, view: CrashView) -> np.ndarray:
    return img if snap.crash_mono is None else view(img, time.monotonic() - snap.crash_mono)


def _window_loop(win: _Window, trial: _Trial, sim: threading.Thread, fps: int, scripted: bool,
                 beep: CrashBeep) -> tuple[list[float], np.ndarray | None]:
    """Read the window's events at up to ``fps`` frames per second and show the latest simulation
    step's picture when it changed, until the trial is over and its last step shown (or the
    simulation failed); beep on each new crash.

    :return: the work of each window frame that put a new picture on the window [ms] (frames that
        only read events are not counted), and the last picture (without the crash layer)
    """
    names = _key_names()
    frame_ms: list[float] = []
    shown_steps = -1
    heard = 0
    composed: tuple[tuple[Any, ...], np.ndarray] | None = None
    crash_view = CrashView()
    while True:
        t0 = time.perf_counter()
        _pass_events(win, trial, names, scripted)
        with trial.lock:
            snap = trial.snapshot
        if snap is not None:
            if snap.crashes > heard:
                heard = snap.crashes
                beep.play()
            key = (snap.n_steps, trial.paused, trial.confirm_quit)
            if composed is None or key != composed[0]:  # a step's picture is composed once, shown every frame
                composed = key, _window_frame(trial, snap)
            if win.show(_with_crash(composed[1], snap, crash_view)):
                frame_ms.append((time.perf_counter() - t0) * 1e3)
            shown_steps = snap.n_steps
        if trial.done and not sim.is_alive() and (shown_steps == trial.n_steps or trial.error is not None):
            return frame_ms, None if composed is None else composed[1]
        win.clock.tick(fps)


def _hold_crash_banner(win: _Window, trial: _Trial, last: np.ndarray | None, fps: int) -> None:
    """After a trial ended by a crash: the crash's feedback until its banner time is over (not
    when the window was closed or a signal came)."""
    if last is None or trial.crash_mono is None or trial.status != "ended_by_collision":
        return
    view = CrashView()
    while time.monotonic() - trial.crash_mono < CRASH_BANNER_S and not win.stopped:
        win.events()
        win.show(view(last, time.monotonic() - trial.crash_mono))
        win.clock.tick(fps)


def _drive(win: _Window, env: gym.Env, log: TrialWriter, opts: DriveOptions, info: dict[str, Any],
           shots_dir: Path, pre_start: list[KeyEvent],
           joystick: JoystickInput | None = None) -> tuple[_Trial, list[float], float]:
    """The trial itself: the simulation in its own thread, the window in this one.

    :return: the trial, each frame's work [ms] and the trial's wall time [s]
    :raises BaseException: what failed in the simulation (the log is then closed as aborted)
    """
    trial = _Trial(env, log, opts, info, shots_dir, pre_start, joystick)
    sim = threading.Thread(target=trial.run, name="dt-highway-sim", daemon=True)
    old_switch = sys.getswitchinterval()
    sys.setswitchinterval(0.0005)  # the window gets the interpreter back quickly from the simulation
    win.signals.trial = trial
    beep = CrashBeep(opts.sound)
    sim.start()
    loop_t0 = time.perf_counter()
    try:
        frame_ms, last = _window_loop(win, trial, sim, opts.fps, opts.keys_from is not None, beep)
        sim.join()
    finally:
        win.signals.trial = None
    loop_wall_s = time.perf_counter() - loop_t0
    sys.setswitchinterval(old_switch)
    if trial.error is not None:
        raise trial.error
    _hold_crash_banner(win, trial, last, opts.fps)
    paused_s = round(sum(p["duration_s"] for p in trial.pauses), 3)
    log.meta.update(end_reason=trial.end_reason, collision=_collision_meta(trial, opts),
                    cut_short=trial.status == "ended_by_collision" and trial.t_sim < trial.duration - 1e-6,
                    pauses=trial.pauses, paused_s=paused_s,
                    realtime_ratio=realtime_ratio(trial.t_sim, loop_wall_s, paused_s))
    if trial.status != "completed":
        log.close(trial.status, trial.end_reason)
    return trial, frame_ms, loop_wall_s


def realtime_ratio(sim_s: float, wall_s: float, paused_s: float = 0.0) -> float | None:
    """How much of real time a trial kept: simulated time over wall time, pauses left out (1.0: real time; less:
    the machine was too slow and the participant drove in slow motion, every step kept but stretched in time).

    :param sim_s: simulated time of the trial [s]
    :param wall_s: wall time of the trial [s]
    :param paused_s: wall time spent paused [s]
    :return: the ratio [-], rounded to 0.001; ``None`` when the trial ran for less than :data:`REALTIME_MIN_S` of
        wall time (too short to judge)
    """
    active = wall_s - paused_s
    if active < REALTIME_MIN_S:
        return None
    return round(sim_s / active, 3)


def is_slow(ratio: float | None) -> bool:
    """Whether a trial ran in slow motion: its :func:`realtime_ratio` below :data:`REALTIME_WARN_BELOW`.

    :param ratio: :func:`realtime_ratio` (``None``: too short to judge)
    :return: ``True`` when it was judged and is below the limit
    """
    return ratio is not None and ratio < REALTIME_WARN_BELOW


def slow_trial_line(ratio: float | None) -> str | None:
    """The experimenter's warning about a trial that did not keep real time.

    :param ratio: :func:`realtime_ratio`
    :return: the line, ``None`` when the trial kept real time or was too short (:func:`is_slow`)
    """
    if ratio is None or not is_slow(ratio):
        return None
    return (f"  warning: the simulation kept {ratio:.3f} of real time: the participant drove in slow motion (the "
            "machine was too slow; see 'Frame times' in the keyboard guide)")


def _collision_meta(trial: _Trial, opts: DriveOptions) -> dict[str, Any]:
    """The trial's ``collision`` entry: count, trial times [s], wall times and the policy."""
    return {"count": len(trial.crashes), "t_s": [c["t_s"] for c in trial.crashes],
            "wall_time": [c["wall_time"] for c in trial.crashes], "policy": opts.on_crash}


def _status_line(opts: DriveOptions, directory: Path, status: str, end_reason: str, t_sim: float,
                 duration: float, crashes: int, pauses: int) -> str:
    """The experimenter's one line about a trial (terminal only): where it was logged, or that nothing was
    (a trial that did not start writes no folder)."""
    name = f"{opts.participant} {opts.condition}{' (practice)' if opts.practice else ''}"
    where = "nothing saved" if status == "not started" else f"-> {directory}"
    return (f"{name}: {status} ({end_reason}), {t_sim:.1f} of {duration:g} s, {crashes} crash"
            f"{'' if crashes == 1 else 'es'}, {pauses} pause{'' if pauses == 1 else 's'} {where}")


def _stderr(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


def _made_env(config: dict[str, Any], seed: int) -> tuple[gym.Env, dict[str, Any]]:
    """The trial's env, reset: ``(env, info)``."""
    env = gym.make("dt-highway-v0", config=config, render_mode="rgb_array")
    try:
        _, info = env.reset(seed=seed)
    except BaseException:
        env.close()
        raise
    return env, info


def _prepare(win: _Window, img: np.ndarray | None,
             make: Callable[[], tuple[gym.Env, dict[str, Any]]]) -> tuple[gym.Env, dict[str, Any]]:
    """``make()`` in a worker thread while the window shows ``img`` (``None``: nothing new) and keeps reading its
    events, so that it answers the window manager for the seconds the env takes (a window that does not can be
    reported "not responding"); keys pressed meanwhile are dropped, a close or a signal is noted
    (:attr:`_Window.stopped`).

    :return: what ``make`` returned
    :raises Exception: what ``make`` raised
    """
    done: dict[str, Any] = {}

    def work() -> None:
        try:
            done["value"] = make()
        except BaseException as err:  # noqa: BLE001 (raised again on the window's thread)
            done["error"] = err

    worker = threading.Thread(target=work, name="dt-highway-prepare", daemon=True)
    worker.start()
    while worker.is_alive():
        win.events()
        if img is not None:
            win.show(img)  # drawn again only after a resize or an expose
        worker.join(timeout=1 / 30)
    if "error" in done:
        raise done["error"]
    return done["value"]


def _close_env(env: gym.Env, keep_window: bool) -> None:
    """Close the trial's env; with ``keep_window``, without its mini-map viewer's ``close``, which would call
    ``pygame.quit()`` and so close the window too (the viewer draws off screen: dropping it frees it)."""
    if keep_window:
        env.unwrapped.viewer = None  # type: ignore[attr-defined]  # highway-env's AbstractEnv
    env.close()


def run_drive(opts: DriveOptions, on_frame: Callable[[np.ndarray], None] | None = None,
              say: Callable[[str], object] | None = None, keep_window: bool = False) -> dict[str, Any]:
    """Run one keyboard trial in a pygame window and log it.

    The simulation runs in its own thread, locked to the wall clock; the window (this thread)
    reads key presses at up to ``opts.fps`` frames per second and passes them to the simulation,
    and puts the latest simulation step's picture on the window when it changed (a new step, the
    pause or quit question, the crash feedback, a resize), so that drawing never waits for a
    simulation step and an unchanged picture is not drawn again.

    :param opts: the trial
    :param on_frame: called with every picture put on the window (tests, recording), at the composed
        size: each distinct picture once (screens before and after the trial too), never a repeat
    :param say: where the experimenter's one-line status of the trial goes, and the slow-trial warning
        (:func:`slow_trial_line`) when there is one (default: stderr)
    :param keep_window: leave the window open at the end, for the next screen to draw on (a session: the
        participant never sees the desktop between screens and trials); the caller closes it (``pygame.quit()``).
        Otherwise the window closes with the trial
    :return: ``directory``, ``status`` (``completed``, ``ended_by_collision``, ``aborted`` or
        ``not started``), ``end_reason``, ``frames``: pictures put on the window during the trial (so
        ``frames / trial_wall_s`` is pictures shown per second, at most the simulation rate outside the
        crash flash), ``screenshots`` saved, ``frame_ms``: the work of each of those frames (window
        events, composing and showing the picture; not the wait for the next frame, and not the
        frames that only read events) [ms], ``size_px``, ``trial_wall_s`` and ``trial_sim_s`` (wall
        and simulated time of the trial [s]), ``realtime_ratio`` (:func:`realtime_ratio`; a trial below
        :data:`REALTIME_WARN_BELOW` is also said in a warning line), ``collisions`` (count), ``collision_t_s``, ``pauses``
    :raises ConfigError: on a bad option (one line)
    """
    if opts.on_crash not in CRASH_POLICIES:
        raise ConfigError(f"--on-crash must be one of {', '.join(CRASH_POLICIES)} (got {opts.on_crash!r})")
    say = say or _stderr
    cfg, overrides, f_sim = _trial_config(opts)
    directory = trial_dir(opts.out, opts.participant, opts.condition, opts.practice)
    if not opts.force:
        check_free(directory)
    shots_dir = opts.screenshots or directory / "screenshots"
    scripted = opts.keys_from is not None
    size = (cfg.camera.width_px, cfg.camera.height_px)
    meta = _trial_meta(opts, cfg, overrides, f_sim)
    old_switch = sys.getswitchinterval()
    env: gym.Env | None = None
    with _Signals() as signals:
        try:
            device = open_wheel(opts)
            win = _Window(size, opts.fullscreen, on_frame, signals)
            wheel = None if device is None else _wheel_input(opts, device, win)
            if wheel is not None:
                meta["wheel"] = {"index": opts.wheel, "device": device.get_name() if device else "",
                                 "calibration_file": str(wheel_calibration_path(opts)), "calibration": wheel[1].model_dump()}
            # the env (a few seconds: the twin's models) and the traffic are prepared with this on screen, not
            # the screen before it frozen; keys pressed meanwhile do not reach the keys screen
            prep = None if scripted else card(size, "Preparing the trial...", [])
            env, info = _prepare(win, prep, lambda: _made_env(cfg.to_dict(), opts.seed))
            env.render()  # highway-env's viewer (the mini-map) is made here, on the window's thread
            pygame.display.set_caption(WINDOW_TITLE)  # it renames the window
            win.screen = pygame.display.get_surface() or win.screen
            if device is not None and wheel is None:
                pre_start: list[KeyEvent] | None = None  # the wheel's set-up was cancelled
            elif scripted:
                assert opts.keys_from is not None
                # keys "held through the countdown"; a signal while the env was prepared: not started
                pre_start = None if win.stopped else opts.keys_from.due(-1e-6)
            else:
                pre_start = _start_screens(win, opts.label, opts.legend)
            if pre_start is None:
                reason = signals.received or ("window closed" if win.closed else
                                              "wheel set-up cancelled" if device is not None and wheel is None
                                              else "quit before the start")
                say(_status_line(opts, directory, "not started", reason, 0.0, cfg.highway.duration, 0, 0))
                return {"directory": str(directory), "status": "not started", "end_reason": reason,
                        "frames": 0, "screenshots": 0, "frame_ms": [], "size_px": list(size)}
            if opts.force and directory.exists():  # replaced whole (answers, screenshots...), once the trial starts
                shutil.rmtree(directory)
            with _ClockedWriter(directory, meta) as log:
                trial, frame_ms, loop_wall_s = _drive(win, env, log, opts, info, shots_dir, pre_start,
                                                      None if wheel is None else wheel[0])
            say(_status_line(opts, directory, trial.status, trial.end_reason, trial.t_sim, trial.duration,
                             len(trial.crashes), len(trial.pauses)))
            ratio = log.meta["realtime_ratio"]
            slow = slow_trial_line(ratio)
            if slow is not None:
                say(slow)
            unused = opts.keys_from.remaining if opts.keys_from is not None else []
            if unused:  # a script longer than the trial, or one it ended early: said, not dropped silently
                say(f"  the key script's last {len(unused)} event{'s' if len(unused) > 1 else ''} (from "
                    f"{unused[0].t_s:g} s) came after the trial's end: not used")
            if not scripted:
                _end_screen(win, trial.status, trial.end_reason, opts.practice)
        finally:
            sys.setswitchinterval(old_switch)
            if env is not None:
                _close_env(env, keep_window)
            if not keep_window:
                pygame.quit()
    return {"directory": str(directory), "status": trial.status, "end_reason": trial.end_reason,
            "frames": len(frame_ms), "screenshots": trial.shots, "frame_ms": frame_ms, "size_px": list(size),
            "trial_wall_s": loop_wall_s, "trial_sim_s": trial.t_sim, "realtime_ratio": ratio, "simulation_frequency_hz": f_sim,
            "collisions": len(trial.crashes), "collision_t_s": [c["t_s"] for c in trial.crashes], "pauses": trial.pauses}

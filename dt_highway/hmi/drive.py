"""The driving window: a participant drives the ego from the first-person camera view.

One trial: the scenario's highway with the ego under the keyboard (:mod:`dt_highway.hmi.keys`),
the synthetic camera as the main picture, in the overlay conditions the overlay's steady marks
drawn on it (:func:`dt_highway.overlay.draw_overlay`, from the fusion's output only), a HUD
(speed in km/h, lane, time left, a neutral label such as "Trial 2": never the condition's name),
highway-env's top-down view as a mini-map (M toggles it) and, with ``mirrors``, the rear-view
mirror image of :func:`dt_highway.camera.mirror.render_mirrors`. The
simulation is locked to the wall clock at its configured frequency (trials default to
:data:`TRIAL_SIMULATION_HZ`, one decision per simulation step); the window redraws at up to
``fps`` frames per second, the composed picture scaled to the window (resizable, or fullscreen).

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
never see a file path: paths and a one-line status per trial go to the terminal.
Headless: ``SDL_VIDEODRIVER=offscreen``.
"""

from __future__ import annotations

import contextlib
import math
import os
import queue
import re
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime
from pathlib import Path
from types import FrameType
from typing import Any, Self

import cv2
import gymnasium as gym
import numpy as np
import pygame  # loaded (without its banner) by highway-env already, which sets PYGAME_HIDE_SUPPORT_PROMPT

from dt_highway.camera.mirror import render_mirrors
from dt_highway.conditions import condition_config
from dt_highway.config import ConfigError, DTConfig, deep_merge, load_config
from dt_highway.env.core import DTHighwayEnv
from dt_highway.hmi.joystick import Calibration, CalibrationError, JoystickInput, calibration_screen, open_joystick
from dt_highway.hmi.keys import KeyEvent, KeyScript, Pedals, Steering
from dt_highway.metrics.trial_log import TrialRecorder, TrialWriter
from dt_highway.overlay import draw_overlay

LEGEND = (
    ("Up", "throttle (hold)"),
    ("Down", "brake (hold)"),
    ("Left / Right", "change lane"),
    ("M", "mini-map on / off"),
    ("P", "pause"),
    ("Esc", "quit (asks first)"),
)
"""The keys, as shown before a trial"""

WINDOW_TITLE = "dt-highway"
"""The window's title (never the condition)"""

TRIAL_SIMULATION_HZ = 30
"""Keyboard trials' simulation frequency unless told otherwise [Hz] (``highway.simulation_frequency``;
``highway.policy_frequency`` follows it). ``dt-highway bench drive`` here (2 cores, load ~0.5): 30 Hz kept real
time at 640x360 and 1280x720 (simulated / wall 0.999, 61 frames/s, frame p99 5.2 / 11.4 ms)"""

CRASH_POLICIES = ("end", "continue")
"""What a crash does to a keyboard trial: end it, or put the ego back on the road and go on"""

CRASH_BANNER_S = 1.5
"""How long the "COLLISION" banner stays up [s of wall time]"""

CRASH_FLASH_S = 0.5
"""How long the red flash takes to fade [s of wall time]"""

SIZE_LIMITS_PX = ((160, 4096), (90, 4096))
"""Allowed window sizes: (width min, max), (height min, max) [px]"""

MIRROR_FRACTION = (0.6, 0.17)
"""The mirror image's size asked for, as fractions of the frame's width and height"""

DRIVING_KEYS = ("UP", "DOWN", "LEFT", "RIGHT")
"""The keys that carry over from the countdown into the trial"""

END_SCREEN_S = 10.0
"""The "Trial saved" screen goes by itself after this long [s] (else only Enter dismisses it)"""

QUIT_LINES = ("Quit the trial?", "Esc: quit", "any other key: go on")
"""The question asked on the first Esc"""

PAUSE_LINES = ("PAUSED", "P: go on")
"""The pause screen's text"""

_ENTER = (pygame.K_RETURN, pygame.K_KP_ENTER)
_AMBER = (255, 230, 120)


def wall_time(t_mono: float | None = None) -> str:
    """The wall clock, ISO 8601 in UTC to the millisecond.

    :param t_mono: a moment of :func:`time.monotonic` [s] (``None``: now)
    :return: e.g. ``2026-11-24T01:02:03.456+00:00``
    """
    epoch = time.time() - (0.0 if t_mono is None else time.monotonic() - t_mono)
    return datetime.fromtimestamp(epoch, UTC).isoformat(timespec="milliseconds")


def parse_size(text: str) -> tuple[int, int]:
    """A window size from ``WIDTHxHEIGHT``.

    :param text: e.g. ``1280x720``
    :return: ``(width, height)`` [px]
    :raises ConfigError: one line naming the allowed form and range
    """
    (w_lo, w_hi), (h_lo, h_hi) = SIZE_LIMITS_PX
    m = re.fullmatch(r"\s*(\d{1,5})\s*[xX]\s*(\d{1,5})\s*", text or "")
    if m is not None:
        w, h = int(m.group(1)), int(m.group(2))
        if w_lo <= w <= w_hi and h_lo <= h <= h_hi:
            return w, h
    raise ConfigError(f"--size must be WIDTHxHEIGHT in pixels, width {w_lo}..{w_hi} and height {h_lo}..{h_hi}, "
                      f"e.g. 1280x720 (got {text!r})")


def drive_config(condition: str, steering: bool = False) -> dict[str, Any]:
    """What a keyboard trial changes in the configuration: the ``Driver`` action with one
    decision per simulation step (the keys act at once), the camera in every condition (it is
    the participant's view, and the observation), the fusion and its overlay as the condition says
    (:func:`~dt_highway.conditions.condition_config`: ``adas``, ``adas-threat``, ``sham``...).

    :raises ConfigError: on an unknown condition (one line naming the allowed ones)
    """
    cond = condition_config(condition)
    # the window shows the camera frame: as observation it costs nothing more (one rendering
    # per step), where highway-env's Kinematics table would cost ~10 ms a step with 50 vehicles
    action: dict[str, Any] = {"type": "Driver", "steering": True} if steering else {"type": "Driver"}
    return deep_merge(cond, {"highway": {"action": action, "observation": {"type": "Camera"}}, "camera": {"enabled": True}})


@dataclass
class Hud:
    """What the HUD shows.

    :param speed_kmh: ego speed [km/h]
    :param lane: lane number, 1 = leftmost
    :param n_lanes: lanes on the road
    :param time_left_s: trial time left [s]
    :param label: the neutral label of the trial (``Trial 2``, ``Practice``): never the condition's name
    :param paused: the trial is paused
    """

    speed_kmh: float
    lane: int
    n_lanes: int
    time_left_s: float
    label: str = "Trial"
    paused: bool = False


def _text(img: np.ndarray, text: str, org: tuple[int, int], scale: float, colour: tuple[int, int, int] = (255, 255, 255),
          thick: int = 1, shadow: bool = True) -> None:
    font = cv2.FONT_HERSHEY_DUPLEX
    if shadow:
        cv2.putText(img, text, (org[0] + 1, org[1] + 1), font, scale, (0, 0, 0), thick + 1, cv2.LINE_AA)
    cv2.putText(img, text, org, font, scale, colour, thick, cv2.LINE_AA)


def _scale(h: int) -> float:
    return max(h / 720.0, 0.35)


def dialog(img: np.ndarray, lines: Iterable[str], colour: tuple[int, int, int] = _AMBER) -> list[tuple[int, int, int, int]]:
    """Draw a box with centred lines of text in the middle of ``img`` (in place): the first line
    large, the others smaller, one below the other.

    :param img: ``uint8 (H, W, 3)`` RGB
    :param lines: the text
    :param colour: the first line's colour (RGB)
    :return: each line's box ``(x0, y0, x1, y1)`` [px] (they never overlap)
    """
    h, w = img.shape[:2]
    s = _scale(h)
    font = cv2.FONT_HERSHEY_DUPLEX
    styles = [(1.4 * s, max(1, round(3 * s))) if i == 0 else (0.95 * s, max(1, round(2 * s))) for i, _ in enumerate(lines)]
    texts = list(lines)
    sizes = [cv2.getTextSize(t, font, sc, th) for t, (sc, th) in zip(texts, styles, strict=True)]
    gap, pad = max(4, int(18 * s)), max(6, int(24 * s))
    heights = [ch + base + th for ((_, ch), base), (_, th) in zip(sizes, styles, strict=True)]
    box_w = max(cw for (cw, _), _ in sizes) + 2 * pad
    box_h = sum(heights) + gap * (len(texts) - 1) + 2 * pad
    x0, y0 = max((w - box_w) // 2, 0), max((h - box_h) // 2, 0)
    region = img[y0:y0 + box_h, x0:x0 + box_w]
    region[:] = (region * 0.2).astype(np.uint8)
    cv2.rectangle(img, (x0, y0), (x0 + box_w - 1, y0 + box_h - 1), colour, 1)
    rects = []
    y = y0 + pad
    for i, (text, ((cw, ch), _base), (sc, th), lh) in enumerate(zip(texts, sizes, styles, heights, strict=True)):
        x = (w - cw) // 2
        _text(img, text, (x, y + ch + th // 2), sc, colour if i == 0 else (255, 255, 255), thick=th, shadow=False)
        rects.append((x, y, x + cw, y + lh))
        y += lh + gap
    return rects


def crash_layer(img: np.ndarray, age_s: float) -> np.ndarray:
    """The crash feedback over a frame: a red flash fading over :data:`CRASH_FLASH_S` and a
    "COLLISION" banner for :data:`CRASH_BANNER_S` after the crash.

    :param img: the composed frame ``uint8 (H, W, 3)`` RGB (not changed)
    :param age_s: time since the crash [s]
    :return: the frame with the feedback (``img`` itself when the crash is older than the banner)
    """
    if not 0.0 <= age_s < CRASH_BANNER_S:
        return img
    out = img.copy()
    if age_s < CRASH_FLASH_S:
        alpha = 0.5 * (1.0 - age_s / CRASH_FLASH_S)
        red = np.zeros_like(out)
        red[..., 0] = 255
        out = cv2.addWeighted(out, 1.0 - alpha, red, alpha, 0.0)
    h, w = out.shape[:2]
    s = _scale(h)
    band_h = max(24, int(90 * s))
    y0 = int(h * 0.22)
    out[y0:y0 + band_h] = (200, 20, 20)
    th = max(1, round(4 * s))
    (cw, ch), _ = cv2.getTextSize("COLLISION", cv2.FONT_HERSHEY_DUPLEX, 2.0 * s, th)
    _text(out, "COLLISION", ((w - cw) // 2, y0 + (band_h + ch) // 2), 2.0 * s, thick=th, shadow=False)
    return out


def compose_frame(rgb: np.ndarray, marks: list[dict[str, Any]] | None, hud: Hud,
                  minimap: np.ndarray | None = None, mirror: np.ndarray | None = None) -> np.ndarray:
    """The picture the participant sees: the camera frame, the marks (overlay conditions), the
    HUD, the mini-map and the rear-view mirror. Used by the window and by the screenshots, so
    both show the same.

    :param rgb: camera frame ``uint8 (H, W, 3)``
    :param marks: the overlay's marks, or ``None`` (baseline: nothing drawn)
    :param hud: the HUD's values
    :param minimap: highway-env's top-down view, or ``None`` (hidden)
    :param mirror: the rear-view mirror image ``uint8 (h, w, 3)``, or ``None``; drawn at the top centre
    :return: ``uint8 (H, W, 3)`` RGB
    """
    out = draw_overlay(rgb, marks) if marks else np.ascontiguousarray(rgb).copy()
    h, w = out.shape[:2]
    s = _scale(h)
    pad = int(16 * s)
    t1, t2, t4 = max(1, round(1.5 * s)), max(1, round(2 * s)), max(1, round(4 * s))
    small = None
    if minimap is not None:  # bottom right, in the HUD's band: the sky stays free for the marks' labels
        small = cv2.resize(minimap, _minimap_size(w, minimap), interpolation=cv2.INTER_AREA)
    band_h = hud_band_height((w, h), minimap)
    band = out[h - band_h:, :]
    band[:] = (band * 0.45).astype(np.uint8)
    base = h - band_h // 2
    _text(out, f"{hud.speed_kmh:3.0f}", (pad, base + int(38 * s)), 2.6 * s, thick=t4, shadow=False)
    _text(out, "km/h", (pad + int(175 * s), base + int(38 * s)), 0.9 * s, thick=t2, shadow=False)
    _text(out, f"lane {hud.lane} of {hud.n_lanes}", (pad + int(300 * s), base - int(6 * s)), 1.0 * s, thick=t1, shadow=False)
    mins, secs = divmod(max(int(math.ceil(hud.time_left_s)), 0), 60)
    _text(out, f"time left {mins}:{secs:02d}", (pad + int(300 * s), base + int(34 * s)), 1.0 * s, thick=t1, shadow=False)
    if small is not None:
        th, tw = small.shape[:2]
        x0, y0 = w - tw - pad, h - band_h + (band_h - th) // 2
        out[y0:y0 + th, x0:x0 + tw] = small
        cv2.rectangle(out, (x0 - 1, y0 - 1), (x0 + tw, y0 + th), (200, 200, 200), 1)
    if mirror is not None:
        _draw_mirror(out, mirror, pad)
    (cw, ch), _ = cv2.getTextSize(hud.label, cv2.FONT_HERSHEY_DUPLEX, 0.9 * s, t1)
    cv2.rectangle(out, (pad // 2, pad // 2), (pad + cw + pad // 2, pad + ch + pad // 2), (0, 0, 0), -1)
    _text(out, hud.label, (pad, pad + ch), 0.9 * s, _AMBER, thick=t1, shadow=False)
    if hud.paused:
        dialog(out, PAUSE_LINES)
    return out


def _minimap_size(w: int, minimap: np.ndarray) -> tuple[int, int]:
    """The mini-map's size in a frame ``w`` pixels wide: ``(width, height)`` [px]."""
    mh, mw = minimap.shape[:2]
    tw = int(w * 0.36)
    return tw, max(1, int(mh * tw / mw))


def hud_band_height(size: tuple[int, int], minimap: np.ndarray | None = None) -> int:
    """The height of the HUD's band at the bottom of a frame of :func:`compose_frame`.

    :param size: the frame's ``(width, height)`` [px]
    :param minimap: the mini-map drawn in it, or ``None``
    :return: the band's height [px]
    """
    w, h = size
    s = _scale(h)
    if minimap is None:
        return int(110 * s)
    return max(int(110 * s), _minimap_size(w, minimap)[1] + 2 * int(16 * s))


def _draw_mirror(out: np.ndarray, mirror: np.ndarray, pad: int) -> None:
    """The rear-view mirror at the top centre of ``out`` (in place), framed, clipped to the frame."""
    h, w = out.shape[:2]
    img = np.asarray(mirror)[: h // 2, : w - 2 * pad, :3]
    mh, mw = img.shape[:2]
    if mh == 0 or mw == 0:
        return
    x0, y0 = (w - mw) // 2, max(pad // 2, 2)
    out[y0:y0 + mh, x0:x0 + mw] = img
    cv2.rectangle(out, (x0 - 2, y0 - 2), (x0 + mw + 1, y0 + mh + 1), (20, 20, 20), 2)


def card(size: tuple[int, int], title: str, lines: list[str]) -> np.ndarray:
    """A plain screen with a title and lines of text (start, break and end screens).

    :param size: ``(width, height)`` [px]
    :param title: the title
    :param lines: the text; a tab splits a line into two columns (the keys' legend)
    """
    w, h = size
    out = np.full((h, w, 3), 28, np.uint8)
    s = _scale(h)
    _text(out, title, (int(40 * s), int(90 * s)), 1.6 * s, _AMBER, thick=max(1, round(3 * s)), shadow=False)
    for i, line in enumerate(lines):
        y = int((160 + 48 * i) * s)
        for col, part in enumerate(line.split("\t", 1)):
            _text(out, part, (int((40 + 320 * col) * s), y), 0.95 * s, thick=max(1, round(2 * s)), shadow=False)
    return out


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
    :param fps: most window frames per second
    :param minimap: show the mini-map at the start
    :param steering: Left/Right steer (self-centring) instead of changing lanes
    :param display_label: what the participant is told the trial is (``Trial 2``...): never the condition's
        name; a practice trial with the default label shows ``Practice``
    :param on_crash: ``end`` the trial on a crash, or ``continue`` (the ego put back on the road, the crash counted)
    :param size: the window and camera size ``(width, height)`` [px] (``None``: the configuration's camera size)
    :param fullscreen: fill the screen (the picture scaled, its aspect kept)
    :param simulation_hz: simulation frequency [Hz] (``None``: the scenario's); decisions follow it
    :param mirrors: draw the rear-view mirror (needs :mod:`dt_highway.camera.mirror`; none without it)
    :param sound: beep on a crash when a sound device is there
    :param wheel: drive with this joystick or wheel (its index among those connected; ``None``: the keyboard):
        its pedals give the acceleration, its wheel the lane changes (or the steering with ``steering``),
        read once per simulation step (:class:`~dt_highway.hmi.joystick.JoystickInput`); P, M and Esc stay on the keyboard
    :param wheel_calibration: the wheel's calibration file (``None``: ``<out>/wheel-calibration.json``); when
        missing, the calibration screen runs first and saves it there
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

    @property
    def label(self) -> str:
        """The label shown to the participant."""
        return "Practice" if self.practice and self.display_label == "Trial" else self.display_label


PYGAME_KEYS = {"UP": "K_UP", "DOWN": "K_DOWN", "LEFT": "K_LEFT", "RIGHT": "K_RIGHT", "P": "K_p", "ESC": "K_ESCAPE",
               "M": "K_m"}


def _key_names() -> dict[int, str]:
    return {getattr(pygame, v): k for k, v in PYGAME_KEYS.items()}


def trial_dir(out: Path, participant: str, condition: str, practice: bool) -> Path:
    """Where a keyboard trial is logged."""
    return Path(out) / "trials" / f"{participant}-{'practice' if practice else condition}"


# ------------------------------------------------------------------------------------------ signals
class SignalScope:
    """SIGTERM and SIGINT go to :meth:`_handle` inside the ``with`` block (installed from the main
    thread only); the previous handlers come back after it. ``received`` is for the first signal's name."""

    def __init__(self) -> None:
        self.received: str | None = None
        self._old: dict[int, Any] = {}

    def __enter__(self) -> Self:
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGTERM, signal.SIGINT):
                self._old[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(self, *_: object) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old)
        self._old.clear()

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        raise NotImplementedError


class _Signals(SignalScope):
    """SIGTERM and SIGINT while the window is up: handed to the running trial as its end (logged
    as such), else noted so that the screens stop waiting. Installed before SDL starts, which
    would otherwise turn SIGTERM into a window close."""

    def __init__(self) -> None:
        super().__init__()
        self.trial: _Trial | None = None

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        name = signal.Signals(signum).name
        self.received = self.received or name
        trial = self.trial
        if trial is not None and not trial.done:
            trial.inputs.put(("signal", name, time.monotonic()))


# ------------------------------------------------------------------------------------------ the window
class _Window:
    """The trial's pygame window: frames are composed at the camera's size and shown scaled to
    the window (aspect kept, black bars); every frame shown also goes to ``on_frame``.

    :param size: the composed frames' size ``(width, height)`` [px]
    :param fullscreen: fill the screen
    :param on_frame: called with every frame shown (unscaled)
    :param signals: SIGTERM/SIGINT seen while the window is up
    """

    def __init__(self, size: tuple[int, int], fullscreen: bool = False,
                 on_frame: Callable[[np.ndarray], None] | None = None, signals: _Signals | None = None) -> None:
        pygame.display.init()
        self.size = size
        self.fullscreen = fullscreen
        self.screen = pygame.display.set_mode((0, 0), pygame.FULLSCREEN) if fullscreen \
            else pygame.display.set_mode(size, pygame.RESIZABLE)
        pygame.display.set_caption(WINDOW_TITLE)
        self.clock = pygame.time.Clock()
        self.on_frame = on_frame
        self.signals = signals or _Signals()
        self.closed = False
        self._cache: tuple[np.ndarray, tuple[int, int], pygame.Surface] | None = None

    @property
    def stopped(self) -> bool:
        """The window was closed or a signal came."""
        return self.closed or self.signals.received is not None

    def events(self) -> list[pygame.event.Event]:
        """The window's events (a close is noted in :attr:`closed`, a resize redraws)."""
        evs = pygame.event.get()
        for ev in evs:
            if ev.type == pygame.QUIT:
                self.closed = True
            elif ev.type in (pygame.VIDEORESIZE, pygame.WINDOWSIZECHANGED):
                self.screen = pygame.display.get_surface() or self.screen
        return evs

    def _surface(self, img: np.ndarray) -> tuple[pygame.Surface, tuple[int, int]]:
        """``img`` scaled to fit the window (cached for the same image and window size) and where it goes."""
        win = self.screen.get_size()
        if self._cache is None or self._cache[0] is not img or self._cache[1] != win:
            h, w = img.shape[:2]
            k = min(win[0] / w, win[1] / h)
            tw, th = max(1, round(w * k)), max(1, round(h * k))
            scaled = img if (tw, th) == (w, h) else cv2.resize(img, (tw, th), interpolation=cv2.INTER_LINEAR)
            surf = pygame.image.frombuffer(np.ascontiguousarray(scaled).tobytes(), (tw, th), "RGB")
            self._cache = (img, win, surf)
        surf = self._cache[2]
        return surf, ((win[0] - surf.get_width()) // 2, (win[1] - surf.get_height()) // 2)

    def show(self, img: np.ndarray) -> None:
        """Put ``img`` on the window, scaled."""
        surf, at = self._surface(img)
        if surf.get_size() != self.screen.get_size():
            self.screen.fill((0, 0, 0))
        self.screen.blit(surf, at)
        pygame.display.flip()
        if self.on_frame is not None:
            self.on_frame(img)

    def wait_key(self, img: np.ndarray, keys: tuple[int, ...], seconds: float | None = None) -> int | None:
        """Show ``img`` until one of ``keys`` (any key when empty) is pressed or ``seconds`` pass.

        :return: the key pressed; ``None`` after ``seconds`` or when the window was closed or a signal came
        """
        self.show(img)
        t_end = None if seconds is None else time.monotonic() + seconds
        while t_end is None or time.monotonic() < t_end:
            for ev in self.events():
                if ev.type in (pygame.VIDEORESIZE, pygame.WINDOWSIZECHANGED):
                    self.show(img)
                elif ev.type == pygame.KEYDOWN and (not keys or ev.key in keys):
                    return int(ev.key)
            if self.stopped:
                return None
            self.clock.tick(30)
        return None


def show_card(size: tuple[int, int], title: str, lines: list[str], timeout_s: float | None = None,
              fullscreen: bool = False) -> bool:
    """Show a screen (e.g. a break between trials) until Enter is pressed.

    :param size: window size ``(width, height)`` [px]
    :param timeout_s: give up waiting after this long (``None``: wait for Enter)
    :param fullscreen: fill the screen
    :return: ``False`` when the participant pressed Esc, closed the window or a signal came
    """
    with _Signals() as signals:
        try:
            win = _Window(size, fullscreen, signals=signals)
            key = win.wait_key(card(size, title, lines), (*_ENTER, pygame.K_ESCAPE), timeout_s)
            return key != pygame.K_ESCAPE and not win.stopped
        finally:
            pygame.quit()


# ------------------------------------------------------------------------------------------ sound
@contextlib.contextmanager
def _quiet_stderr() -> Iterator[None]:
    """Silence C libraries' messages on stderr (ALSA's when there is no sound card)."""
    try:
        saved = os.dup(2)
    except OSError:
        yield
        return
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 2)
            yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


class CrashBeep:
    """A short two-tone beep (numpy, through :mod:`pygame.sndarray`) for crashes; silent when
    there is no sound device or the mixer cannot start (never an error).

    :param enabled: try to make a sound at all
    :param freq_hz: the first tone [Hz] (the second is a fourth lower)
    :param duration_s: length [s]
    """

    def __init__(self, enabled: bool = True, freq_hz: float = 880.0, duration_s: float = 0.35) -> None:
        self.sound: pygame.mixer.Sound | None = None
        if not enabled:
            return
        try:
            with _quiet_stderr():
                if not pygame.mixer.get_init():
                    pygame.mixer.init()
            init = pygame.mixer.get_init()
            if init:
                self.sound = pygame.sndarray.make_sound(beep_samples(init[0], init[1], init[2], freq_hz, duration_s))
        except (pygame.error, ValueError, TypeError, NotImplementedError):
            self.sound = None

    def play(self) -> bool:
        """Play it.

        :return: whether a sound was started
        """
        if self.sound is None:
            return False
        try:
            self.sound.play()
        except pygame.error:
            return False
        return True


def beep_samples(rate_hz: int, size: int, channels: int, freq_hz: float = 880.0, duration_s: float = 0.35) -> np.ndarray:
    """The crash beep's samples in the mixer's format: two tones (``freq_hz``, then a fourth
    lower) with 10 ms fades, at 40 % of full scale.

    :param rate_hz: sample rate [Hz]
    :param size: pygame's sample format (``-16``: int16, ``32``: float32, ``8``/``-8``: 8 bit)
    :param channels: channels [-]
    :return: ``(n,)`` for one channel, else ``(n, channels)``
    :raises ValueError: on a sample format it does not write
    """
    n = max(1, round(rate_hz * duration_s))
    t = np.arange(n) / rate_hz
    f = np.where(t < duration_s / 2, freq_hz, freq_hz * 0.75)
    wave = np.sin(2 * np.pi * f * t)
    ramp = np.clip(np.minimum(t, duration_s - t) / 0.01, 0.0, 1.0)
    x = 0.4 * wave * ramp
    if size == -16:
        data = (x * 32767).astype(np.int16)
    elif size == 32:
        data = x.astype(np.float32)
    elif size == -8:
        data = (x * 127).astype(np.int8)
    elif size == 8:
        data = (x * 127 + 128).astype(np.uint8)
    else:
        raise ValueError(f"sample format {size} is not written")
    return data if channels == 1 else np.repeat(data[:, None], channels, axis=1)


# ------------------------------------------------------------------------------------------ crashes
def place_ego_after_crash(env: DTHighwayEnv, min_gap_m: float = 30.0, headway_s: float = 2.0,
                          step_m: float = 5.0, search_m: float = 500.0) -> dict[str, float]:
    """Put a crashed ego back on the road: in its lane, ahead of every crashed vehicle (they stop
    and are towed away by the traffic), with a clear gap to the vehicles in (or entering) the lane
    ahead and behind, at the speed of traffic around it, heading along the lane, not crashed.

    :param env: the env (its ego is moved)
    :param min_gap_m: smallest clear gap ahead and behind [m]
    :param headway_s: the gap is at least this headway at the new speed [s]
    :param step_m: search step along the lane [m]
    :param search_m: how far ahead to search for a clear place [m]
    :return: ``x_m`` (new position), ``moved_m`` (along the lane), ``lane`` (1 = leftmost), ``speed_mps``
    """
    road, ego = env.road, env.vehicle
    lane_index = ego.lane_index
    lane = road.network.get_lane(lane_index)
    s_ego = float(lane.local_coordinates(ego.position)[0])
    others = [v for v in road.vehicles if v is not ego]
    near = [float(v.speed) for v in others if not v.crashed and abs(float(v.position[0] - ego.position[0])) < 150.0]
    speed = float(np.median(near)) if near else max(float(ego.speed), 20.0)
    gap = max(min_gap_m, headway_s * speed)
    crashed = [float(lane.local_coordinates(v.position)[0]) for v in others if v.crashed]
    start = max([s_ego, *(s + gap for s in crashed)])
    in_lane = [float(lane.local_coordinates(v.position)[0]) for v in others
               if lane_index in (v.lane_index, getattr(v, "target_lane_index", None))]
    s = start
    while s < start + search_m and any(abs(x - s) < gap for x in in_lane):
        s += step_m
    ego.position = np.asarray(lane.position(s, 0.0), dtype=float)
    ego.heading = float(lane.heading_at(s))
    ego.speed = speed
    ego.crashed = False
    ego.impact = None
    ego.lane_index, ego.lane = lane_index, lane
    if hasattr(ego, "target_lane_index"):
        ego.target_lane_index = lane_index
    return {"x_m": float(ego.position[0]), "moved_m": s - s_ego, "lane": int(lane_index[2]) + 1, "speed_mps": speed}


# ------------------------------------------------------------------------------------------ the trial
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
    posts inputs (``(kind, key, monotonic time)``: ``down``, ``up``, ``closed``, ``signal``).
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
            self.confirm_quit = False
            self._set_pause(False, "Esc", t_mono)
        elif ev.key in ("LEFT", "RIGHT") and not self.opts.steering:
            self.lane_tap = -1 if ev.key == "LEFT" else 1
        elif ev.key == "P":
            self._set_pause(not self.paused, "P", t_mono, ev.t_s)
        elif ev.key == "M":
            self.show_map = not self.show_map

    def take_input(self, kind: str, key: str, t_mono: float) -> None:
        """One input from the window thread (module docstring of the class)."""
        if kind in ("down", "up"):
            self.key_event(KeyEvent(self.trial_time(t_mono), kind == "down", key), t_mono)
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


def _trial_config(opts: DriveOptions) -> tuple[DTConfig, list[str], float]:
    """The trial's configuration, with one decision per simulation step.

    :return: the configuration, the ``--set`` strings (the trial's simulation frequency, size and
        ``--duration`` among them; the caller's win) and the simulation frequency [Hz]
    """
    overrides = [] if opts.simulation_hz is None else [f"highway.simulation_frequency={opts.simulation_hz}"]
    if opts.size is not None:
        overrides += [f"camera.width_px={opts.size[0]}", f"camera.height_px={opts.size[1]}"]
    overrides += list(opts.overrides)
    if opts.duration_s is not None:
        overrides.append(f"highway.duration={opts.duration_s}")
    # first the simulation frequency alone (decisions at 1 Hz divide any), then decisions at that frequency
    cfg = load_config(opts.scenario, [*overrides, "highway.policy_frequency=1"], drive_config(opts.condition, opts.steering))
    f_sim = cfg.highway.simulation_frequency
    cfg = load_config(opts.scenario, [*overrides, f"highway.policy_frequency={f_sim}"],
                      drive_config(opts.condition, opts.steering))
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
    """The wheel's calibration file: ``wheel_calibration``, else ``<out>/wheel-calibration.json``."""
    return Path(opts.wheel_calibration) if opts.wheel_calibration is not None else Path(opts.out) / "wheel-calibration.json"


def open_wheel(opts: DriveOptions) -> pygame.joystick.JoystickType | None:
    """The trial's wheel (``None``: the keyboard drives).

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


def _countdown(win: _Window) -> list[KeyEvent] | None:
    """3-2-1, one second each, noting the driving keys pressed and released meanwhile.

    :return: those key events, at negative trial times [s] (t = 0 is the end of the countdown);
        ``None`` when the window was closed or a signal came
    """
    names = _key_names()
    t_end = time.monotonic() + 3.0
    events: list[KeyEvent] = []
    pressed = pygame.key.get_pressed()  # a key already held on the keys screen (a real keyboard)
    events += [KeyEvent(-3.0, True, k) for k, v in PYGAME_KEYS.items() if k in DRIVING_KEYS and pressed[getattr(pygame, v)]]
    for n in (3, 2, 1):
        img = card(win.size, str(n), ["get ready"])
        win.show(img)
        while time.monotonic() < t_end - (n - 1):
            for ev in win.events():
                if ev.type in (pygame.VIDEORESIZE, pygame.WINDOWSIZECHANGED):
                    win.show(img)
                elif ev.type in (pygame.KEYDOWN, pygame.KEYUP) and names.get(ev.key) in DRIVING_KEYS:
                    events.append(KeyEvent(round(time.monotonic() - t_end, 4), ev.type == pygame.KEYDOWN, names[ev.key]))
            if win.stopped:
                return None
            win.clock.tick(60)
    return events


def _start_screens(win: _Window, label: str) -> list[KeyEvent] | None:
    """The keys, until Enter, then a count-down.

    :return: the key events of the countdown (:func:`_countdown`); ``None`` when the participant
        pressed Esc, closed the window or a signal came instead
    """
    legend = [f"{k}\t{v}" for k, v in LEGEND]
    key = win.wait_key(card(win.size, f"{label}: the keys", [*legend, "", "Press Enter to start"]), (*_ENTER, pygame.K_ESCAPE))
    if key is None or key == pygame.K_ESCAPE:
        return None
    return _countdown(win)


def _pass_events(win: _Window, trial: _Trial, names: dict[int, str], scripted: bool) -> None:
    """Hand the window's key presses and releases (not when a script drives) and its close to the simulation."""
    for ev in win.events():
        now = time.monotonic()
        if ev.type == pygame.QUIT:
            trial.inputs.put(("closed", "", now))
        elif not scripted and ev.type in (pygame.KEYDOWN, pygame.KEYUP) and ev.key in names:
            trial.inputs.put(("down" if ev.type == pygame.KEYDOWN else "up", names[ev.key], now))


def _window_frame(trial: _Trial, snap: _Snapshot) -> np.ndarray:
    """The picture of a step, with the pause or (instead) the question whether to quit."""
    confirm = trial.confirm_quit
    img = compose_frame(snap.rgb, snap.marks, replace(snap.hud, paused=trial.paused and not confirm), snap.minimap,
                        snap.mirror)
    if confirm:
        dialog(img, QUIT_LINES)
    return img


def _with_crash(img: np.ndarray, snap: _Snapshot) -> np.ndarray:
    return img if snap.crash_mono is None else crash_layer(img, time.monotonic() - snap.crash_mono)


def _window_loop(win: _Window, trial: _Trial, sim: threading.Thread, fps: int, scripted: bool,
                 beep: CrashBeep) -> tuple[list[float], np.ndarray | None]:
    """Redraw the latest simulation step at up to ``fps`` frames per second until the trial is
    over and its last step shown (or the simulation failed); beep on each new crash.

    :return: each frame's work [ms], and the last picture (without the crash layer)
    """
    names = _key_names()
    frame_ms: list[float] = []
    shown_steps = -1
    heard = 0
    composed: tuple[tuple[Any, ...], np.ndarray] | None = None
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
            win.show(_with_crash(composed[1], snap))
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
    while time.monotonic() - trial.crash_mono < CRASH_BANNER_S and not win.stopped:
        win.events()
        win.show(crash_layer(last, time.monotonic() - trial.crash_mono))
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
    log.meta.update(end_reason=trial.end_reason, collision=_collision_meta(trial, opts),
                    cut_short=trial.status == "ended_by_collision" and trial.t_sim < trial.duration - 1e-6,
                    pauses=trial.pauses, paused_s=round(sum(p["duration_s"] for p in trial.pauses), 3))
    if trial.status != "completed":
        log.close(trial.status, trial.end_reason)
    return trial, frame_ms, loop_wall_s


def _collision_meta(trial: _Trial, opts: DriveOptions) -> dict[str, Any]:
    """The trial's ``collision`` entry: count, trial times [s], wall times and the policy."""
    return {"count": len(trial.crashes), "t_s": [c["t_s"] for c in trial.crashes],
            "wall_time": [c["wall_time"] for c in trial.crashes], "policy": opts.on_crash}


def _end_screen(win: _Window, trial: _Trial) -> None:
    """"Trial saved", until Enter (no other key) or :data:`END_SCREEN_S`; not when the window was closed or a signal came."""
    if win.stopped or trial.end_reason == "window closed":
        return
    early = ["The trial ended early: there was a collision.", ""] if trial.status == "ended_by_collision" else []
    win.wait_key(card(win.size, "Trial saved", [*early, "Thank you.", "", "Press Enter to go on"]), _ENTER, END_SCREEN_S)


def _status_line(opts: DriveOptions, directory: Path, status: str, end_reason: str, t_sim: float,
                 duration: float, crashes: int, pauses: int) -> str:
    """The experimenter's one line about a trial (terminal only)."""
    name = f"{opts.participant} {opts.condition}{' (practice)' if opts.practice else ''}"
    return (f"{name}: {status} ({end_reason}), {t_sim:.1f} of {duration:g} s, {crashes} crash"
            f"{'' if crashes == 1 else 'es'}, {pauses} pause{'' if pauses == 1 else 's'} -> {directory}")


def _stderr(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


def run_drive(opts: DriveOptions, on_frame: Callable[[np.ndarray], None] | None = None,
              say: Callable[[str], object] | None = None) -> dict[str, Any]:
    """Run one keyboard trial in a pygame window and log it.

    The simulation runs in its own thread, locked to the wall clock; the window (this thread)
    redraws the latest simulation step at up to ``opts.fps`` frames per second and passes key
    presses to the simulation, so that drawing never waits for a simulation step.

    :param opts: the trial
    :param on_frame: called with every frame shown (tests, recording), at the composed size
    :param say: where the experimenter's one-line status of the trial goes (default: stderr)
    :return: ``directory``, ``status`` (``completed``, ``ended_by_collision``, ``aborted`` or
        ``not started``), ``end_reason``, ``frames`` drawn, ``screenshots`` saved, ``frame_ms``: each
        frame's work (window events, composing and showing the picture; not the wait for the next
        frame) [ms], ``size_px``, ``trial_wall_s`` and ``trial_sim_s`` (wall and simulated time of
        the trial [s]), ``collisions`` (count), ``collision_t_s``, ``pauses``
    :raises ConfigError: on a bad option (one line)
    """
    if opts.on_crash not in CRASH_POLICIES:
        raise ConfigError(f"--on-crash must be one of {', '.join(CRASH_POLICIES)} (got {opts.on_crash!r})")
    say = say or _stderr
    cfg, overrides, f_sim = _trial_config(opts)
    directory = trial_dir(opts.out, opts.participant, opts.condition, opts.practice)
    shots_dir = opts.screenshots or directory / "screenshots"
    scripted = opts.keys_from is not None
    size = (cfg.camera.width_px, cfg.camera.height_px)
    env = gym.make("dt-highway-v0", config=cfg.to_dict(), render_mode="rgb_array")
    meta = _trial_meta(opts, cfg, overrides, f_sim)
    old_switch = sys.getswitchinterval()
    with _Signals() as signals:
        try:
            device = open_wheel(opts)
            win = _Window(size, opts.fullscreen, on_frame, signals)
            wheel = None if device is None else _wheel_input(opts, device, win)
            if wheel is not None:
                meta["wheel"] = {"index": opts.wheel, "device": device.get_name() if device else "",
                                 "calibration_file": str(wheel_calibration_path(opts)), "calibration": wheel[1].model_dump()}
            # the traffic and the twin's listening time are prepared while the participant reads the keys
            if not scripted:
                win.show(card(size, "Preparing the trial...", []))
            _, info = env.reset(seed=opts.seed)
            env.render()  # highway-env's viewer (the mini-map) is made here, on the window's thread
            pygame.display.set_caption(WINDOW_TITLE)  # it renames the window
            win.screen = pygame.display.get_surface() or win.screen
            if device is not None and wheel is None:
                pre_start: list[KeyEvent] | None = None  # the wheel's set-up was cancelled
            elif scripted:
                assert opts.keys_from is not None
                pre_start = opts.keys_from.due(-1e-6)  # keys "held through the countdown"
            else:
                pre_start = _start_screens(win, opts.label)
            if pre_start is None:
                reason = signals.received or ("window closed" if win.closed else
                                              "wheel set-up cancelled" if device is not None and wheel is None
                                              else "quit before the start")
                say(_status_line(opts, directory, "not started", reason, 0.0, cfg.highway.duration, 0, 0))
                return {"directory": str(directory), "status": "not started", "end_reason": reason,
                        "frames": 0, "screenshots": 0, "frame_ms": [], "size_px": list(size)}
            with _ClockedWriter(directory, meta) as log:
                trial, frame_ms, loop_wall_s = _drive(win, env, log, opts, info, shots_dir, pre_start,
                                                      None if wheel is None else wheel[0])
            say(_status_line(opts, directory, trial.status, trial.end_reason, trial.t_sim, trial.duration,
                             len(trial.crashes), len(trial.pauses)))
            if not scripted:
                _end_screen(win, trial)
        finally:
            sys.setswitchinterval(old_switch)
            env.close()
            pygame.quit()
    return {"directory": str(directory), "status": trial.status, "end_reason": trial.end_reason,
            "frames": len(frame_ms), "screenshots": trial.shots, "frame_ms": frame_ms, "size_px": list(size),
            "trial_wall_s": loop_wall_s, "trial_sim_s": trial.t_sim, "collisions": len(trial.crashes),
            "collision_t_s": [c["t_s"] for c in trial.crashes], "pauses": trial.pauses}

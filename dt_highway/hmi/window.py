"""The driving window: the pygame window a trial is shown in, its key names, and SIGTERM/SIGINT
while it is up.

:class:`_Window` shows pictures composed at the camera's size, scaled to the window (aspect kept,
black bars; resizable or fullscreen), and draws a picture only when it is a new one (another array
object, a new window size, or after the window was exposed again): an unchanged picture is not
drawn again while the window's events (the keys) are read at the window's rate. Its ``on_frame``
gets each picture put on the window once.
"""

from __future__ import annotations

import queue
import re
import signal
import threading
import time
from collections.abc import Callable
from types import FrameType
from typing import Any, Protocol, Self

import cv2
import numpy as np
import pygame  # without its banner: gymnasium, which dt_highway imports first, sets PYGAME_HIDE_SUPPORT_PROMPT

from dt_highway.errors import ConfigError

SIZE_LIMITS_PX = ((160, 4096), (90, 4096))
"""Allowed window sizes: (width min, max), (height min, max) [px]"""


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


WINDOW_TITLE = "dt-highway"
"""The window's title (never the condition)"""

DRIVING_KEYS = ("UP", "DOWN", "LEFT", "RIGHT")
"""The keys that carry over from the countdown into the trial"""

_EXPOSED = (pygame.VIDEOEXPOSE, pygame.WINDOWEXPOSED)
"""The events after which the window's content must be drawn again (uncovered)"""

PYGAME_KEYS = {"UP": "K_UP", "DOWN": "K_DOWN", "LEFT": "K_LEFT", "RIGHT": "K_RIGHT", "P": "K_p", "ESC": "K_ESCAPE",
               "M": "K_m"}
"""The trial's keys: their names in the logs and key scripts, and pygame's constants' names"""


def _key_names() -> dict[int, str]:
    return {getattr(pygame, v): k for k, v in PYGAME_KEYS.items()}


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


class TrialInbox(Protocol):
    """What a running trial offers the signal handler: whether it is over, and its inputs' queue
    (``(kind, key or signal name, monotonic time)``)."""

    done: bool
    inputs: queue.SimpleQueue[tuple[str, str, float]]


class _Signals(SignalScope):
    """SIGTERM and SIGINT while the window is up: handed to the running trial as its end (logged
    as such), else noted so that the screens stop waiting. Installed before SDL starts, which
    would otherwise turn SIGTERM into a window close."""

    def __init__(self) -> None:
        super().__init__()
        self.trial: TrialInbox | None = None

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        name = signal.Signals(signum).name
        self.received = self.received or name
        trial = self.trial
        if trial is not None and not trial.done:
            trial.inputs.put(("signal", name, time.monotonic()))


def open_display(size: tuple[int, int], fullscreen: bool = False) -> pygame.Surface:
    """The window to draw on: the one already open when there is one of the same kind (a session's, kept from its
    first screen to its last), else a new one. pygame-ce makes a new window at every ``set_mode``, so calling it
    again would show the participant the desktop (and move the window) at each trial's start.

    :param size: the window's size when one is made ``(width, height)`` [px] (a window already open keeps its own)
    :param fullscreen: fill the screen
    :return: the window's surface
    """
    pygame.display.init()
    pygame.display.set_caption(WINDOW_TITLE)  # before the window exists: it never shows pygame's own title
    current = pygame.display.get_surface()
    if current is not None and pygame.display.is_fullscreen() == fullscreen:
        return current
    if fullscreen:
        return pygame.display.set_mode((0, 0), pygame.FULLSCREEN)
    return pygame.display.set_mode(size, pygame.RESIZABLE)


class _Window:
    """The trial's pygame window: pictures are composed at the camera's size and shown scaled to
    the window (aspect kept, black bars). :meth:`show` puts a picture on the window (blit and flip)
    only when it is a new one: another array object than the last one shown, a new window size or
    surface, or after the window was exposed again; showing the same array object again costs
    nothing (in fullscreen under Xvfb a flip costs ~25-30 ms). Callers pass the same object for an
    unchanged picture and never draw into a picture after showing it. Events are read by
    :meth:`events` whether or not a picture is shown.

    :param size: the composed pictures' size ``(width, height)`` [px]
    :param fullscreen: fill the screen
    :param on_frame: called with every picture put on the window (unscaled), once per flip: every
        distinct picture once (again after a resize), never for a skipped repeat
    :param signals: SIGTERM/SIGINT seen while the window is up

    ``flips`` counts the pictures put on the window.
    """

    def __init__(self, size: tuple[int, int], fullscreen: bool = False,
                 on_frame: Callable[[np.ndarray], None] | None = None, signals: _Signals | None = None) -> None:
        self.size = size
        self.fullscreen = fullscreen
        self.screen = open_display(size, fullscreen)
        self.clock = pygame.time.Clock()
        self.on_frame = on_frame
        self.signals = signals or _Signals()
        self.closed = False
        self.flips = 0
        self._cache: tuple[np.ndarray, tuple[int, int], pygame.Surface] | None = None
        self._shown: tuple[np.ndarray, pygame.Surface, tuple[int, int]] | None = None

    @property
    def stopped(self) -> bool:
        """The window was closed or a signal came."""
        return self.closed or self.signals.received is not None

    def events(self) -> list[pygame.event.Event]:
        """The window's events (a close is noted in :attr:`closed`; after a resize or an expose the next
        :meth:`show` draws its picture even when it is unchanged)."""
        evs = pygame.event.get()
        for ev in evs:
            if ev.type == pygame.QUIT:
                self.closed = True
            elif ev.type in (pygame.VIDEORESIZE, pygame.WINDOWSIZECHANGED):
                self.screen = pygame.display.get_surface() or self.screen
                self._shown = None
            elif ev.type in _EXPOSED:
                self._shown = None  # uncovered: the next picture is put on the window even if unchanged
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

    def show(self, img: np.ndarray) -> bool:
        """Put ``img`` on the window, scaled, unless it is already there (the same array object,
        the same window surface and size, not exposed since): then nothing is drawn.

        :param img: ``uint8 (H, W, 3)`` RGB, not changed afterwards
        :return: whether it was put on the window (blit, flip and ``on_frame``)
        """
        win = self.screen.get_size()
        last = self._shown
        if last is not None and last[0] is img and last[1] is self.screen and last[2] == win:
            return False
        surf, at = self._surface(img)
        if surf.get_size() != win:
            self.screen.fill((0, 0, 0))
        self.screen.blit(surf, at)
        pygame.display.flip()
        self.flips += 1
        self._shown = (img, self.screen, win)
        if self.on_frame is not None:
            self.on_frame(img)
        return True

    def wait_key(self, img: np.ndarray, keys: tuple[int, ...], seconds: float | None = None) -> int | None:
        """Show ``img`` until one of ``keys`` (any key when empty) is pressed or ``seconds`` pass.

        :return: the key pressed; ``None`` after ``seconds`` or when the window was closed or a signal came
        """
        self.show(img)
        t_end = None if seconds is None else time.monotonic() + seconds
        while t_end is None or time.monotonic() < t_end:
            for ev in self.events():
                if ev.type == pygame.KEYDOWN and (not keys or ev.key in keys):
                    return int(ev.key)
            if self.stopped:
                return None
            self.show(img)  # drawn again only after a resize or an expose
            self.clock.tick(30)
        return None

"""Keyboard driving: pedals with smooth ramps, lane-change taps, and timed key scripts.

A participant drives with the arrow keys: Up is the throttle and Down the brake, both
continuous (held, the pedal travels towards full at a fixed rate; released, it returns),
not highway-env's five target speeds; Left/Right request a lane change. P pauses, Esc
quits (after a confirmation in the window).

:class:`Pedals` turns the keys held into the ``"Driver"`` action's acceleration command
[m/s^2]; :class:`KeyScript` reads a timed key script (``--keys-from FILE``) so that tests
and demos can drive a trial without a person::

    # time [s of trial time]  down|up  key
    0.5 down UP
    3.0 up   UP
    4.0 down LEFT
    4.1 up   LEFT

A script may start before 0 s, down to ``-COUNTDOWN_S``: driving keys pressed during the 3-2-1
countdown (``-1.5 down UP``); those still held at 0 s act from the first step and are logged as
pressed at 0 s, with when they were pressed (:func:`dt_highway.hmi.drive.held_at_start`).
"""

from __future__ import annotations

import codecs
import math
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

KEYS = ("UP", "DOWN", "LEFT", "RIGHT", "P", "ESC")
"""Key names of key scripts and logs"""
COUNTDOWN_KEYS = ("UP", "DOWN", "LEFT", "RIGHT")
"""The keys a script may press before 0 s (during the countdown)"""
COUNTDOWN_S = 3.0
"""The countdown before a trial (3-2-1) [s]: a key script's earliest time is ``-COUNTDOWN_S``"""


@dataclass(frozen=True)
class PedalSettings:
    """How the pedals respond.

    :param throttle_max_mps2: acceleration at full throttle [m/s^2]
    :param brake_max_mps2: deceleration at full brake [m/s^2]
    :param coast_mps2: acceleration with no pedal pressed (rolling resistance, drag) [m/s^2]
    :param throttle_rate_mps3: how fast the throttle command rises while Up is held [m/s^3]
    :param brake_rate_mps3: how fast the brake command rises while Down is held [m/s^3]
    :param release_rate_mps3: how fast a released pedal's command returns to coasting [m/s^3]
    """

    throttle_max_mps2: float = 2.5
    brake_max_mps2: float = 7.0
    coast_mps2: float = -0.3
    throttle_rate_mps3: float = 2.5
    brake_rate_mps3: float = 10.0
    release_rate_mps3: float = 10.0


class Pedals:
    """The acceleration command from the pedal keys held, ramped (Down wins over Up).

    :param settings: pedal response
    """

    def __init__(self, settings: PedalSettings = PedalSettings()) -> None:
        self.s = settings
        self.accel_mps2 = settings.coast_mps2

    def reset(self) -> None:
        """Pedals released, coasting."""
        self.accel_mps2 = self.s.coast_mps2

    def update(self, up: bool, down: bool, dt_s: float) -> float:
        """Advance the pedals by ``dt_s`` with these keys held.

        :param up: throttle key held
        :param down: brake key held
        :param dt_s: time step [s]
        :return: the acceleration command [m/s^2]
        """
        s = self.s
        a = self.accel_mps2
        if down:  # press the brake (or come off the throttle) at the brake's rate
            target, rate = -s.brake_max_mps2, s.brake_rate_mps3
        elif up:  # off the brake at the release rate, then the throttle rises at its own rate
            target, rate = s.throttle_max_mps2, s.throttle_rate_mps3
            if a < s.coast_mps2:
                t_off = (s.coast_mps2 - a) / s.release_rate_mps3
                if dt_s <= t_off:
                    self.accel_mps2 = a + s.release_rate_mps3 * max(dt_s, 0.0)
                    return self.accel_mps2
                a, dt_s = s.coast_mps2, dt_s - t_off
        else:  # released: back to coasting
            target, rate = s.coast_mps2, s.release_rate_mps3
        step = rate * max(dt_s, 0.0)
        self.accel_mps2 = min(a + step, target) if a < target else max(a - step, target)
        return self.accel_mps2


class Steering:
    """A self-centring steering command from the Left/Right keys held, in ``[-1, 1]``
    (positive to the right; the ``"Driver"`` action scales it to an angle).

    :param rate_per_s: how fast the command moves towards full lock while a key is held [1/s]
    :param centring_per_s: how fast it returns to 0 when no key is held [1/s]
    """

    def __init__(self, rate_per_s: float = 1.5, centring_per_s: float = 3.0) -> None:
        self.rate_per_s = rate_per_s
        self.centring_per_s = centring_per_s
        self.command = 0.0

    def reset(self) -> None:
        """Wheel centred."""
        self.command = 0.0

    def update(self, left: bool, right: bool, dt_s: float) -> float:
        """Advance by ``dt_s`` with these keys held (both or neither: back to the centre).

        :param left: the Left key is held
        :param right: the Right key is held
        :param dt_s: time since the last update [s]
        :return: the steering command in ``[-1, 1]``
        """
        target = (1.0 if right else 0.0) - (1.0 if left else 0.0)
        rate = self.rate_per_s if target != 0.0 and (target * self.command >= 0.0) else self.centring_per_s
        if target != 0.0 and target * self.command < 0.0:
            rate = self.centring_per_s + self.rate_per_s  # countersteering is quick
        step = rate * max(dt_s, 0.0)
        c = self.command
        self.command = min(c + step, target) if c < target else max(c - step, target)
        return self.command


@dataclass(frozen=True)
class KeyEvent:
    """One key press or release.

    :param t_s: trial time [s]
    :param down: pressed (``True``) or released
    :param key: one of :data:`KEYS`
    """

    t_s: float
    down: bool
    key: str


class KeyScriptError(ValueError):
    """A key script line that cannot be read (the message names the line)."""


class KeyScript:
    """A timed key script: the key events of a trial, in time order.

    Events at negative times (down to ``-COUNTDOWN_S``, in a file too) are keys pressed during the
    countdown: the driving keys still held at t = 0 are pressed then
    (:func:`dt_highway.hmi.drive.held_at_start`).

    :param events: the events (sorted by time; equal times keep their order)
    """

    def __init__(self, events: Iterable[KeyEvent]) -> None:
        self.events = sorted(events, key=lambda e: e.t_s)
        self._next = 0

    @classmethod
    def parse(cls, text: str, source: str = "<keys>") -> KeyScript:
        """Read ``time down|up KEY`` lines (``#`` starts a comment).

        :param text: the script's text
        :param source: where it comes from, for the error messages (a file name)
        :return: the script
        :raises KeyScriptError: naming the file and line of the first bad one, or a script that ends with
            the trial paused (``P`` pressed an odd number of times, and no ``ESC``, which ends a scripted
            trial, after the last)
        """
        events = []
        last = -math.inf
        for n, raw in enumerate(text.splitlines(), 1):
            line = raw.split("#", 1)[0].strip()
            if not line:
                continue
            parts = line.split()
            where = f"{source}:{n}"
            if len(parts) != 3:
                raise KeyScriptError(f"{where}: expected 'TIME down|up KEY' (got {raw.strip()!r})")
            t_text, action, key = parts[0], parts[1].lower(), parts[2].upper()
            try:
                t = float(t_text)
            except ValueError:
                raise KeyScriptError(f"{where}: time must be a number of seconds (got {t_text!r})") from None
            if not math.isfinite(t):
                raise KeyScriptError(f"{where}: time must be a finite number of seconds (got {t_text!r})")
            if t < -COUNTDOWN_S:
                raise KeyScriptError(f"{where}: time must be >= {-COUNTDOWN_S:g} s (before 0: the countdown) "
                                     f"(got {t_text})")
            if t < last:
                raise KeyScriptError(f"{where}: times must not go back ({t:g} s after {last:g} s)")
            if action not in ("down", "up"):
                raise KeyScriptError(f"{where}: action must be 'down' or 'up' (got {parts[1]!r})")
            if key not in KEYS:
                raise KeyScriptError(f"{where}: unknown key {parts[2]!r} (allowed: {', '.join(KEYS)})")
            if t < 0 and key not in COUNTDOWN_KEYS:
                raise KeyScriptError(f"{where}: only {', '.join(COUNTDOWN_KEYS)} can be pressed before 0 s "
                                     f"(the countdown; got {key} at {t:g} s)")
            events.append(KeyEvent(t, action == "down", key))
            last = t
        pauses = [e for e in events if e.down and e.key == "P"]
        quits = any(e.down and e.key == "ESC" and e.t_s >= pauses[-1].t_s for e in events) if pauses else False
        if len(pauses) % 2 and not quits:  # P toggles the pause: the trial would wait for a key never pressed
            times = f"{len(pauses)} time{'s' if len(pauses) > 1 else ''}"
            raise KeyScriptError(f"{source}: P is pressed {times}, the last at {pauses[-1].t_s:g} s: the script ends "
                                 "with the trial paused, which it would wait in for ever (press P again)")
        return cls(events)

    @classmethod
    def load(cls, path: str | Path) -> KeyScript:
        """Read a key script file: UTF-8 text (a byte-order mark is skipped), or UTF-16 with its
        byte-order mark (as some Windows editors save it).

        :param path: the key script file
        :return: the script
        :raises KeyScriptError: when it is missing, not text, or a line is bad
        """
        p = Path(path)
        try:
            data = p.read_bytes()
        except OSError as err:
            raise KeyScriptError(f"cannot read the key script {p}: {err.strerror or err}") from None
        utf16 = data.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE))
        try:
            text = data.decode("utf-16" if utf16 else "utf-8-sig")
            if "\x00" in text:  # UTF-16 without its byte-order mark, UTF-32: decodes, with NULs between the digits
                raise UnicodeDecodeError("utf-8", data, 0, 1, "NUL")
        except UnicodeDecodeError:
            raise KeyScriptError(f"the key script {p} is not text (UTF-8, or UTF-16 with a byte-order mark)") from None
        return cls.parse(text, str(p))

    def due(self, t_s: float) -> list[KeyEvent]:
        """The events up to trial time ``t_s`` not returned before.

        :param t_s: trial time [s]
        :return: those events, in time order
        """
        out = []
        while self._next < len(self.events) and self.events[self._next].t_s <= t_s + 1e-9:
            out.append(self.events[self._next])
            self._next += 1
        return out

    @property
    def finished(self) -> bool:
        """Every event has been returned."""
        return self._next >= len(self.events)

    @property
    def remaining(self) -> list[KeyEvent]:
        """The events not returned yet (after a trial: those it ended before)."""
        return self.events[self._next:]

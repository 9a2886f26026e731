"""A steering wheel with pedals, or a gamepad, through pygame's joystick API.

The device's axes become the ``"Driver"`` action's commands: the wheel a steering command in
``[-1, 1]`` (positive to the right) or, when the trial changes lanes instead of steering, a
lane-change request when the wheel is turned past a threshold; the pedals the acceleration
command [m/s^2], on the scale of the keyboard's :class:`~dt_highway.hmi.keys.PedalSettings`
(full throttle ``throttle_max_mps2``, full brake ``-brake_max_mps2``, neither ``coast_mps2``;
the brake wins over the throttle, as Down wins over Up on the keyboard).

Devices differ (a pedal may rest at -1 and go to +1, or rest at +1 and go to -1; a wheel's
centre is rarely exactly 0), so every axis goes through a :class:`Calibration`: per axis its
index, the value at rest (``centre``) and the extremes seen (``min``, ``max``), kept as a JSON
file per device. :func:`calibration_screen` makes one: it asks to let go of everything, turn
the wheel fully left and right, press each pedal fully, and finds from the recorded values
which axis is which and where its ends are.

Anything with pygame's ``Joystick`` methods (``get_name``, ``get_numaxes``, ``get_axis``) is a
device (:class:`AxisDevice`). The tests drive a real SDL device: pygame-ce 2.5 does not expose
SDL's virtual joystick, so :func:`attach_virtual_joystick` attaches one through ``ctypes`` on
the SDL library pygame itself loaded (``SDL_JoystickAttachVirtual``); pygame then sees it
as any other joystick (events, ``get_axis``).
"""

from __future__ import annotations

import ctypes
import glob
import json
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import cv2
import numpy as np
import pygame
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from dt_highway.config import config_error, read_user_file
from dt_highway.hmi.keys import PedalSettings

ROLES = ("steer", "throttle", "brake")
"""The axes a driving device has"""
DEFAULT_PEDALS = PedalSettings()
"""The keyboard's pedal scale, the default of the wheel's"""


class AxisDevice(Protocol):
    """What the input layer reads of a device: pygame's ``Joystick`` has these methods."""

    def get_name(self) -> str:
        """The device's name.

        :return: the name
        """
        ...

    def get_numaxes(self) -> int:
        """How many axes it has.

        :return: the number of axes
        """
        ...

    def get_axis(self, axis_number: int) -> float:
        """An axis's position, in ``[-1, 1]``.

        :param axis_number: the axis (0-based)
        :return: its position [-]
        """
        ...


class CalibrationError(ValueError):
    """A calibration that cannot be made or read (one line: what is missing or wrong)."""


# ----------------------------------------------------------------------------- calibration
class AxisCalibration(BaseModel):
    """One axis of a device.

    :param axis: the axis's index on the device
    :param min: the lowest value seen (wheel: turned fully left) [-]
    :param centre: the value at rest (wheel: straight; pedal: released) [-]
    :param max: the highest value seen (wheel: turned fully right) [-]
    :param deadzone: fraction of the travel around the centre read as the centre [-]
    :param inverted: the axis's values fall where the command rises (wheel: turning right lowers it)
    """

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    axis: int = Field(..., ge=0, le=63, description="the axis's index on the device")
    min: float = Field(..., ge=-1.0, le=1.0, description="lowest value seen [-]")
    centre: float = Field(..., ge=-1.0, le=1.0, description="value at rest [-]")
    max: float = Field(..., ge=-1.0, le=1.0, description="highest value seen [-]")
    deadzone: float = Field(0.03, ge=0.0, le=0.5, description="fraction of the travel read as the centre [-]")
    inverted: bool = Field(False, description="the command rises as the axis's value falls")

    @model_validator(mode="after")
    def _ordered(self) -> AxisCalibration:
        if not self.min <= self.centre <= self.max:
            raise ValueError(f"needs min <= centre <= max (got {self.min:g}, {self.centre:g}, {self.max:g})")
        if self.max - self.min < 0.05:
            raise ValueError(f"the axis moved over less than 0.05 of its range (min {self.min:g}, max {self.max:g})")
        return self

    def steer(self, value: float) -> float:
        """A wheel's command: -1 fully left, 0 at the centre, +1 fully right (piecewise linear on
        each side of the centre, so an off-centre rest still maps to 0 and both ends to +-1).

        :param value: the axis's raw value [-]
        :return: the command in ``[-1, 1]``
        """
        v = -value if self.inverted else value
        lo, c, hi = (-self.max, -self.centre, -self.min) if self.inverted else (self.min, self.centre, self.max)
        span = hi - c if v >= c else c - lo
        x = (v - c) / span if span > 0 else 0.0
        return _dead(max(-1.0, min(1.0, x)), self.deadzone)

    def pedal(self, value: float) -> float:
        """A pedal's travel: 0 released (at the centre), 1 fully pressed (at the extreme the
        calibration saw farther from the centre).

        :param value: the axis's raw value [-]
        :return: the travel in ``[0, 1]``
        """
        up, down = self.max - self.centre, self.centre - self.min
        full = self.max if up >= down else self.min
        x = (value - self.centre) / (full - self.centre)
        return max(0.0, _dead(min(1.0, x), self.deadzone))


def _dead(x: float, deadzone: float) -> float:
    """``x`` in ``[-1, 1]`` with ``|x| <= deadzone`` read as 0 and the rest stretched back to ``[-1, 1]``."""
    if abs(x) <= deadzone:
        return 0.0
    return math.copysign((abs(x) - deadzone) / (1.0 - deadzone), x)


class Calibration(BaseModel):
    """A device's calibration: which axis is the wheel and which the pedals, and their ranges.

    :param device: the device's name (as pygame gives it)
    :param steer: the wheel's axis
    :param throttle: the throttle pedal's axis
    :param brake: the brake pedal's axis
    """

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    device: str = Field("", description="the device's name")
    steer: AxisCalibration
    throttle: AxisCalibration
    brake: AxisCalibration

    @model_validator(mode="after")
    def _distinct(self) -> Calibration:
        axes = [self.steer.axis, self.throttle.axis, self.brake.axis]
        if len(set(axes)) != 3:
            raise ValueError(f"steer, throttle and brake need three different axes (got {axes})")
        return self

    def save(self, path: str | Path) -> Path:
        """Write the calibration as JSON.

        :param path: the file (its directory is made)
        :return: the file
        """
        p = Path(path)
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(json.dumps(self.model_dump(), indent=2) + "\n", encoding="utf-8")
        return p

    @classmethod
    def load(cls, path: str | Path) -> Calibration:
        """Read a calibration file.

        :param path: the calibration file (JSON, as :meth:`save` writes it)
        :return: the calibration
        :raises ConfigError: one line, when it is missing, not JSON, or a value is wrong (the
            dotted key and what is allowed)
        """
        p = Path(path)
        data = read_user_file(p, json.loads, json.JSONDecodeError,
                              missing="calibration file not found: {path} (make one with the calibration screen)",
                              unreadable="cannot read the calibration file {path}: {err}",
                              malformed="calibration file {path} is not valid JSON ({err.msg}, line {err.lineno})")
        try:
            return cls.model_validate(data)
        except ValidationError as err:
            raise config_error(err, cls, prefix=f"calibration file {p}: ") from None


def open_joystick(index: int = 0) -> pygame.joystick.JoystickType:
    """Open a connected joystick or wheel through pygame (its display and joystick modules are
    initialised here when they are not yet).

    :param index: the device's index among those connected
    :return: the device
    :raises CalibrationError: one line, when there is no such device (how many there are)
    """
    if not pygame.display.get_init():
        pygame.display.init()
    if not pygame.joystick.get_init():
        pygame.joystick.init()
    pygame.event.pump()
    n = pygame.joystick.get_count()
    if not 0 <= index < n:
        have = "no joystick or wheel is connected" if n == 0 else f"{n} connected (0..{n - 1})"
        raise CalibrationError(f"joystick {index} not found: {have}")
    return pygame.joystick.Joystick(index)  # opened when made (pygame-ce >= 2.4)


# ----------------------------------------------------------------------------- commands
@dataclass(frozen=True)
class WheelCommand:
    """What the device asks for at one instant.

    :param accel_mps2: acceleration command [m/s^2]
    :param steer: steering command in ``[-1, 1]`` (positive to the right)
    :param throttle: throttle travel in ``[0, 1]``
    :param brake: brake travel in ``[0, 1]``
    :param lane_tap: -1 / +1 when the wheel has just been turned past the lane-change threshold
        to the left / right, else 0
    """

    accel_mps2: float
    steer: float
    throttle: float
    brake: float
    lane_tap: int = 0


def pedal_accel(throttle: float, brake: float, settings: PedalSettings = DEFAULT_PEDALS) -> float:
    """The acceleration command of the pedals' travels (the brake wins, as on the keyboard).

    :param throttle: throttle travel in ``[0, 1]``
    :param brake: brake travel in ``[0, 1]``
    :param settings: the scale (the keyboard's pedal settings)
    :return: ``coast + throttle (throttle_max - coast)`` when the brake is released, else
        ``coast - brake (brake_max + coast)`` [m/s^2]
    """
    s = settings
    if brake > 0.0:
        return s.coast_mps2 - brake * (s.brake_max_mps2 + s.coast_mps2)
    return s.coast_mps2 + throttle * (s.throttle_max_mps2 - s.coast_mps2)


class JoystickInput:
    """Reads a calibrated device and gives the trial's commands.

    :param device: the device (a ``pygame.joystick.Joystick``, or anything with its methods)
    :param calibration: its calibration
    :param pedals: the acceleration scale
    :param lane_on: wheel command past which a lane change is asked for (lane-change trials) [-]
    :param lane_off: wheel command under which the next request is armed again [-]
    :raises CalibrationError: when the device lacks an axis the calibration uses
    """

    def __init__(self, device: AxisDevice, calibration: Calibration, pedals: PedalSettings = DEFAULT_PEDALS,
                 lane_on: float = 0.5, lane_off: float = 0.25) -> None:
        n = device.get_numaxes()
        used = max(calibration.steer.axis, calibration.throttle.axis, calibration.brake.axis)
        if used >= n:
            raise CalibrationError(f"the calibration uses axis {used}, the device {device.get_name()!r} has {n} axes "
                                   f"(0..{n - 1}): calibrate this device")
        self.device, self.cal, self.pedals = device, calibration, pedals
        self.lane_on, self.lane_off = lane_on, lane_off
        self._armed = True

    def read(self) -> WheelCommand:
        """The command now (call once per simulation step: a lane request is given once per turn).

        With pygame, events must be pumped (``pygame.event.get()`` or ``pump()``) for the axes
        to move.

        :return: the acceleration, steering, pedal travels and lane request now
        """
        c, d = self.cal, self.device
        steer = c.steer.steer(d.get_axis(c.steer.axis))
        throttle = c.throttle.pedal(d.get_axis(c.throttle.axis))
        brake = c.brake.pedal(d.get_axis(c.brake.axis))
        tap = 0
        if self._armed and abs(steer) >= self.lane_on:
            tap, self._armed = (1 if steer > 0 else -1), False
        elif abs(steer) <= self.lane_off:
            self._armed = True
        return WheelCommand(pedal_accel(throttle, brake, self.pedals), steer, throttle, brake, tap)


# ----------------------------------------------------------------------------- calibrating
CALIBRATION_STEPS: tuple[tuple[str, str], ...] = (
    ("rest", "Let go of the wheel and both pedals"),
    ("steer", "Turn the wheel fully left, then fully right, then let it go"),
    ("throttle", "Press the throttle (accelerator) fully down, then release it"),
    ("brake", "Press the brake fully down, then release it"),
)
"""The calibration's steps: name and what the screen asks"""
MIN_TRAVEL = 0.3
"""Least travel of an axis [-] (of its -1..1 range) for it to count as moved in a step"""


class CalibrationRecorder:
    """Finds the axes and their ranges from the values seen in each calibration step.

    ``rest`` gives every axis's centre (the mean of its values); each later step's axis is the
    one that moved farthest from its centre (among those not taken yet), with the extremes seen.
    The wheel is turned left first: if its highest value came before its lowest, turning right
    lowers it (``inverted``).

    :param n_axes: the device's number of axes
    """

    def __init__(self, n_axes: int) -> None:
        if n_axes < 3:
            raise CalibrationError(f"a driving device needs 3 axes (wheel, throttle, brake); this one has {n_axes}")
        self.n_axes = n_axes
        self.samples: dict[str, list[np.ndarray]] = {name: [] for name, _ in CALIBRATION_STEPS}

    def add(self, step: str, values: Sequence[float]) -> None:
        """Record the axes' values at one instant of a step.

        :param step: one of :data:`CALIBRATION_STEPS`' names
        :param values: every axis's value [-]
        """
        if step not in self.samples:
            raise ValueError(f"unknown calibration step {step!r} (allowed: {', '.join(self.samples)})")
        self.samples[step].append(np.asarray(values, dtype=float)[: self.n_axes])

    def result(self, device: str = "") -> Calibration:
        """The calibration.

        :param device: the device's name
        :return: the axes found, with their ranges
        :raises CalibrationError: when a step has no values or no axis moved enough in it
        """
        for step, rows in self.samples.items():
            if not rows:
                raise CalibrationError(f"calibration step {step!r} recorded nothing")
        centre = np.mean(self.samples["rest"], axis=0)
        taken: set[int] = set()
        axes: dict[str, AxisCalibration] = {}
        for role in ROLES:
            seen = np.array(self.samples[role])
            travel = np.abs(seen - centre).max(axis=0)
            travel[list(taken)] = -1.0
            axis = int(np.argmax(travel))
            if travel[axis] < MIN_TRAVEL:
                raise CalibrationError(f"no axis moved in step {role!r} (largest travel {max(travel[axis], 0.0):.2f}, "
                                       f"at least {MIN_TRAVEL} needed): do it again, fully")
            taken.add(axis)
            lo = min(float(seen[:, axis].min()), float(centre[axis]))
            hi = max(float(seen[:, axis].max()), float(centre[axis]))
            # the wheel is turned left first: when its highest value came first, right is down
            inverted = role == "steer" and int(np.argmax(seen[:, axis])) < int(np.argmin(seen[:, axis]))
            axes[role] = AxisCalibration(axis=axis, min=lo, centre=float(centre[axis]), max=hi, inverted=inverted)
        return Calibration(device=device, **axes)


def _bars(img: np.ndarray, values: Sequence[float], top: int, s: float) -> None:
    """Every axis's value as a horizontal bar (what the device reports, live)."""
    w = img.shape[1]
    x0, bw, bh = int(40 * s), int(w * 0.5), max(4, int(18 * s))
    for i, v in enumerate(values):
        y = top + i * int(bh * 1.8)
        cv2.rectangle(img, (x0, y), (x0 + bw, y + bh), (90, 90, 90), 1)
        mid = x0 + bw // 2
        end = mid + int(max(-1.0, min(1.0, v)) * bw / 2)
        cv2.rectangle(img, (min(mid, end), y + 2), (max(mid, end), y + bh - 2), (120, 200, 255), -1)
        cv2.putText(img, f"axis {i}: {v:+.2f}", (x0 + bw + int(16 * s), y + bh - 2), cv2.FONT_HERSHEY_DUPLEX,
                    0.6 * s, (220, 220, 220), 1, cv2.LINE_AA)


def calibration_frame(size: tuple[int, int], step: int, values: Sequence[float]) -> np.ndarray:
    """The calibration screen of one step: the request, the keys, and the axes live.

    :param size: ``(width, height)`` [px]
    :param step: index into :data:`CALIBRATION_STEPS`
    :param values: every axis's value now [-]
    :return: ``uint8 (height, width, 3)`` RGB
    """
    w, h = size
    s = max(h / 720.0, 0.35)
    img = np.full((h, w, 3), 28, np.uint8)
    font = cv2.FONT_HERSHEY_DUPLEX
    title = f"Wheel set-up {step + 1} of {len(CALIBRATION_STEPS)}"
    cv2.putText(img, title, (int(40 * s), int(80 * s)), font, 1.3 * s, (255, 230, 120), max(1, round(2 * s)), cv2.LINE_AA)
    cv2.putText(img, CALIBRATION_STEPS[step][1], (int(40 * s), int(150 * s)), font, 0.95 * s, (255, 255, 255),
                max(1, round(2 * s)), cv2.LINE_AA)
    cv2.putText(img, "then press Enter (Esc: cancel)", (int(40 * s), int(200 * s)), font, 0.8 * s, (200, 200, 200),
                1, cv2.LINE_AA)
    _bars(img, values, int(250 * s), s)
    return img


StepScript = Callable[[str, int], bool]
"""A scripted calibration: called at every sample with the step's name and the sample's index
in the step; may move the device; returns ``True`` when the step is done (instead of Enter)"""


def _step_done(script: StepScript | None, step: str, tick: int) -> bool | None:
    """Whether the step is done: by the script, or by Enter (``None``: cancelled with Esc or a close)."""
    done = script(step, tick) if script is not None else False
    for ev in pygame.event.get():
        if ev.type == pygame.QUIT or (ev.type == pygame.KEYDOWN and ev.key == pygame.K_ESCAPE):
            return None
        if ev.type == pygame.KEYDOWN and ev.key in (pygame.K_RETURN, pygame.K_KP_ENTER):
            done = True
    return done


def calibration_screen(device: AxisDevice, size: tuple[int, int] = (1280, 720), save_to: str | Path | None = None,
                       script: StepScript | None = None, sample_hz: float = 60.0, min_step_s: float = 0.3,
                       window: pygame.Surface | None = None) -> Calibration | None:
    """Calibrate a device in a window: each step of :data:`CALIBRATION_STEPS` is asked for on the
    screen (with the axes' values live) and recorded until Enter; the axes and their ranges are
    then found (:class:`CalibrationRecorder`).

    :param device: the device (pygame's joystick; pygame's display and joystick modules initialised)
    :param size: the window's ``(width, height)`` [px] (when ``window`` is not given)
    :param save_to: write the calibration there as JSON (``None``: not written)
    :param script: drives the steps instead of a person (tests); see :data:`StepScript`
    :param sample_hz: samples per second [Hz]
    :param min_step_s: a step records at least this long, so that a quick Enter cannot skip it [s]
    :param window: draw on this surface (``None``: open a window of ``size``)
    :return: the calibration, ``None`` when cancelled (Esc or the window closed)
    :raises CalibrationError: when a step saw no axis move (the message says which)
    """
    screen = window if window is not None else pygame.display.set_mode(size)
    if window is None:
        pygame.display.set_caption("dt-highway: wheel set-up")
    size = screen.get_size()
    n = device.get_numaxes()
    rec = CalibrationRecorder(n)
    dt = 1.0 / sample_hz
    for i, (step, _) in enumerate(CALIBRATION_STEPS):
        tick, t0 = 0, time.monotonic()
        while True:
            done = _step_done(script, step, tick)
            if done is None:
                return None
            values = [float(device.get_axis(a)) for a in range(n)]
            rec.add(step, values)
            img = calibration_frame(size, i, values)
            screen.blit(pygame.image.frombuffer(img.tobytes(), size, "RGB"), (0, 0))
            pygame.display.flip()
            tick += 1
            if done and (script is not None or time.monotonic() - t0 >= min_step_s):
                break
            if script is None:
                time.sleep(dt)
    cal = rec.result(device.get_name())
    if save_to is not None:
        cal.save(save_to)
    return cal


# ----------------------------------------------------------------------------- a simulated device
SDL_JOYSTICK_TYPE_WHEEL = 2
"""SDL's joystick type of a wheel (``SDL_JoystickType``)"""


class VirtualJoystick:
    """An SDL virtual joystick (SDL >= 2.0.14), attached through ``ctypes`` on the SDL library that
    pygame loaded, for tests and demos without hardware: pygame sees it as a real device.

    :param n_axes: its number of axes
    :param n_buttons: its number of buttons
    :raises RuntimeError: when pygame's SDL library cannot be found or refuses the device
    """

    def __init__(self, n_axes: int = 3, n_buttons: int = 4) -> None:
        self._sdl = _sdl_library()
        if not pygame.joystick.get_init():
            pygame.joystick.init()
        sdl = self._sdl
        sdl.SDL_JoystickAttachVirtual.restype = ctypes.c_int
        sdl.SDL_JoystickAttachVirtual.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_int, ctypes.c_int]
        sdl.SDL_JoystickOpen.restype = ctypes.c_void_p
        sdl.SDL_JoystickOpen.argtypes = [ctypes.c_int]
        sdl.SDL_JoystickSetVirtualAxis.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_int16]
        sdl.SDL_JoystickSetVirtualAxis.restype = ctypes.c_int
        sdl.SDL_JoystickDetachVirtual.argtypes = [ctypes.c_int]
        sdl.SDL_JoystickClose.argtypes = [ctypes.c_void_p]
        self.index = sdl.SDL_JoystickAttachVirtual(SDL_JOYSTICK_TYPE_WHEEL, n_axes, n_buttons, 0)
        if self.index < 0:
            raise RuntimeError("SDL refused the virtual joystick")
        self._handle = sdl.SDL_JoystickOpen(self.index)
        if not self._handle:
            raise RuntimeError("SDL could not open the virtual joystick")
        self.n_axes = n_axes

    def set_axis(self, axis: int, value: float) -> None:
        """Move an axis to ``value`` in ``[-1, 1]`` (SDL's -32768..32767), seen by pygame at its next event pump.

        :param axis: the axis (0-based)
        :param value: its position [-] (clipped to ``[-1, 1]``)
        :raises ValueError: on an axis the device does not have
        """
        raw = int(round(max(-1.0, min(1.0, value)) * 32767)) if value > -1.0 else -32768
        if self._sdl.SDL_JoystickSetVirtualAxis(self._handle, axis, raw) != 0:
            raise ValueError(f"axis must be 0..{self.n_axes - 1} (got {axis})")

    def close(self) -> None:
        """Detach the device."""
        if self._handle:
            self._sdl.SDL_JoystickClose(self._handle)
            self._sdl.SDL_JoystickDetachVirtual(self.index)
            self._handle = None


def _sdl_library() -> ctypes.CDLL:
    """The SDL2 library pygame uses (its wheel's bundled copy, else the system's)."""
    here = os.path.dirname(pygame.__file__)
    found = sorted(glob.glob(os.path.join(here, "..", "pygame_ce.libs", "libSDL2-*.so*")))
    found += sorted(glob.glob(os.path.join(here, "..", "pygame.libs", "libSDL2-*.so*")))
    for name in [*found, "libSDL2-2.0.so.0"]:
        try:
            return ctypes.CDLL(name)
        except OSError:
            continue
    raise RuntimeError("SDL2 library of pygame not found: the virtual joystick needs it")

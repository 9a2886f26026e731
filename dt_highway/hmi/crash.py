"""Crashes in a keyboard trial: the feedback over the picture (a red flash and a "COLLISION"
banner: :func:`crash_layer`, :class:`CrashView`), a beep (:class:`CrashBeep`, silent without a sound
device), the policies (:data:`CRASH_POLICIES`) and putting a crashed ego back on the road
(:func:`place_ego_after_crash`, policy ``continue``).
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator

import cv2
import numpy as np
import pygame  # without its banner: gymnasium, which dt_highway imports first, sets PYGAME_HIDE_SUPPORT_PROMPT

from dt_highway.choices import CRASH_POLICIES as CRASH_POLICIES  # re-exported: its home before dt_highway.choices
from dt_highway.env.core import DTHighwayEnv
from dt_highway.hmi.screens import _scale, _text

CRASH_BANNER_S = 1.5
"""How long the "COLLISION" banner stays up [s of wall time]"""

CRASH_FLASH_S = 0.5
"""How long the red flash takes to fade [s of wall time]"""


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
    :param freq_hz: the first tone's frequency [Hz]
    :param duration_s: the beep's length, both tones [s]
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
    :return: ``x_m`` (new position), ``moved_m`` (along the lane), ``lane`` (its id, 0 = leftmost, as the trial
        log's ``lane`` column and ``lane_change`` events), ``speed_mps``
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
    return {"x_m": float(ego.position[0]), "moved_m": s - s_ego, "lane": int(lane_index[2]), "speed_mps": speed}


class CrashView:
    """The crash feedback for a window: a fading picture during the flash, then one held picture.

    :func:`crash_layer` for a window: during the flash a new picture every call (it fades), after
    it the banner's picture made once per picture under it (the same object while that picture
    stays), so that the window does not redraw an unchanged picture (:meth:`_Window.show`).
    """

    def __init__(self) -> None:
        self._banner: tuple[np.ndarray, np.ndarray] | None = None

    def __call__(self, img: np.ndarray, age_s: float) -> np.ndarray:
        """``img`` with the crash's feedback ``age_s`` after it (:func:`crash_layer`).

        :param img: the composed picture (not changed)
        :param age_s: time since the crash [s]
        :return: the picture to show (``img`` itself once the banner's time is over)
        """
        if not 0.0 <= age_s < CRASH_BANNER_S or age_s < CRASH_FLASH_S:
            return crash_layer(img, age_s)
        if self._banner is None or self._banner[0] is not img:
            self._banner = img, crash_layer(img, age_s)
        return self._banner[1]

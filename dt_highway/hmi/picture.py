"""The picture a participant sees while driving (:func:`compose_frame`): the camera frame, the
overlay's marks (overlay conditions), the HUD (:class:`Hud`), the mini-map and the rear-view mirror.
Used by the driving window, its screenshots and the replay, so that all show the same.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from dt_highway.hmi.screens import _AMBER, PAUSE_LINES, _scale, _text, dialog
from dt_highway.overlay import Rect, draw_overlay

MIRROR_FRACTION = (0.6, 0.17)
"""The mirror image's size asked for, as fractions of the frame's width and height"""


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
    h, w = rgb.shape[:2]
    s = _scale(h)
    pad = int(16 * s)
    t1, t2, t4 = max(1, round(1.5 * s)), max(1, round(2 * s)), max(1, round(4 * s))
    band_h = hud_band_height((w, h), minimap)
    badge, mirror_at = _badge_rect(hud.label, h), _mirror_rect((w, h), mirror, pad)
    keep_out = [(0, h - band_h, w, band_h), *(_grown(r) for r in (badge, mirror_at) if r is not None)]
    out = draw_overlay(rgb, marks, keep_out=keep_out, bottom_px=h - band_h) if marks else np.ascontiguousarray(rgb).copy()
    small = None
    if minimap is not None:  # bottom right, in the HUD's band: the sky stays free for the marks' labels
        small = cv2.resize(minimap, _minimap_size(w, minimap), interpolation=cv2.INTER_AREA)
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
    if mirror is not None and mirror_at is not None:
        _draw_mirror(out, mirror, mirror_at)
    bx, by, bw, bh = badge
    cv2.rectangle(out, (bx, by), (bx + bw, by + bh), (0, 0, 0), -1)
    _text(out, hud.label, (pad, by + bh - pad // 2), 0.9 * s, _AMBER, thick=t1, shadow=False)
    if hud.paused:
        dialog(out, PAUSE_LINES)
    return out


def _grown(r: Rect) -> Rect:
    """``r`` one pixel larger on every side (``cv2.rectangle`` draws its end points, and a frame's line
    reaches one pixel past it)."""
    x, y, w, h = r
    return x - 1, y - 1, w + 3, h + 3


def _badge_rect(label: str, h: int) -> Rect:
    """Where the trial's label goes, top left of a frame ``h`` pixels high: ``(x, y, w, h)`` [px]."""
    s = _scale(h)
    pad = int(16 * s)
    (cw, ch), _ = cv2.getTextSize(label, cv2.FONT_HERSHEY_DUPLEX, 0.9 * s, max(1, round(1.5 * s)))
    return pad // 2, pad // 2, pad + cw, pad + ch


def _mirror_rect(size: tuple[int, int], mirror: np.ndarray | None, pad: int) -> Rect | None:
    """Where the rear-view mirror goes, frame included, at the top centre of a frame of ``size`` ``(w, h)``:
    ``(x, y, w, h)`` [px], ``None`` without a mirror (or an empty one)."""
    if mirror is None:
        return None
    w, h = size
    mh, mw = np.asarray(mirror)[: h // 2, : w - 2 * pad].shape[:2]
    if mh == 0 or mw == 0:
        return None
    x0, y0 = (w - mw) // 2, max(pad // 2, 2)
    return x0 - 2, y0 - 2, mw + 4, mh + 4


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


def _draw_mirror(out: np.ndarray, mirror: np.ndarray, at: Rect) -> None:
    """The rear-view mirror in ``out`` (in place), framed, at ``at`` (:func:`_mirror_rect`)."""
    x, y, rw, rh = at
    mh, mw = rh - 4, rw - 4
    out[y + 2:y + 2 + mh, x + 2:x + 2 + mw] = np.asarray(mirror)[:mh, :mw, :3]
    cv2.rectangle(out, (x, y), (x + rw - 1, y + rh - 1), (20, 20, 20), 2)

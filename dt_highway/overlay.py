"""The AR overlay: which marks a driver sees, kept steady, and how they are drawn.

The fusion places the twin's aggressive-tagged vehicles on camera boxes frame by frame; a far
or partly hidden car is placed in some frames and not in others. Shown as it is, its mark
blinks, and a blinking mark is both hard to read and a different warning from a steady one.
:class:`OverlayStabilizer` turns the fusion's per-frame items into the marks a driver sees:

* a vehicle's mark appears once the fusion has placed it in ``onset_frames`` consecutive
  frames (one stray frame does not flash a mark);
* it stays on its car while the fusion keeps placing it (the fusion's tracking keeps the
  vehicle on its track, so the box follows the car);
* when the fusion stops placing it, the mark is held for ``hold_s`` at the box predicted
  from its last movement (the box's velocity in the image), then removed.

Nothing here reads ground truth: input is the fusion's overlay items only.

:func:`draw_overlay` draws the marks on an RGB frame (a box and a label a driver reads at a
glance: "AGGRESSIVE DRIVER", the twin's confidence and the distance); the driving window and
the frame export both use it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from dt_highway.config import OverlayConfig, validate_section

MARK_RGB = (235, 40, 40)
"""Colour of an aggressive-driver mark (RGB)"""
_DEFAULTS = OverlayConfig()


@dataclass
class _Mark:
    item: dict[str, Any]
    box: np.ndarray
    velocity_px_s: np.ndarray = field(default_factory=lambda: np.zeros(4))
    streak: int = 1
    shown: bool = False
    last_seen_s: float = 0.0


class OverlayStabilizer:
    """Steady marks from the fusion's per-frame overlay items (module docstring).

    :param onset_frames: consecutive frames a vehicle must be placed in before its mark shows [-]
    :param hold_s: how long a shown mark stays after the fusion stops placing its vehicle [s]

    Defaults and ranges are the ``overlay`` section's (:class:`~dt_highway.config.OverlayConfig`).

    :raises ConfigError: on a value out of range
    """

    def __init__(self, onset_frames: int = _DEFAULTS.onset_frames, hold_s: float = _DEFAULTS.hold_s) -> None:
        settings = validate_section(OverlayConfig, "overlay", onset_frames=onset_frames, hold_s=hold_s)
        self.onset_frames = settings.onset_frames
        self.hold_s = settings.hold_s
        self._marks: dict[int, _Mark] = {}
        self._t_s: float | None = None

    def reset(self) -> None:
        """Forget every mark (a new episode)."""
        self._marks.clear()
        self._t_s = None

    def update(self, items: Sequence[dict[str, Any]], t_s: float) -> list[dict[str, Any]]:
        """One frame.

        :param items: the fusion's overlay items this frame (``vehicle_id``, ``box`` [px], ...)
        :param t_s: the frame's time [s]
        :return: the marks to show: the items, each with ``held`` (``True`` when its vehicle
            was not placed this frame and the box is predicted)
        """
        dt = 0.0 if self._t_s is None else max(t_s - self._t_s, 0.0)
        self._t_s = t_s
        now = {int(it["vehicle_id"]): it for it in items}
        for vid, it in now.items():
            box = np.asarray(it["box"], dtype=float)
            mark = self._marks.get(vid)
            if mark is None:
                self._marks[vid] = _Mark(dict(it), box, last_seen_s=t_s)
                continue
            gap = t_s - mark.last_seen_s
            fresh = gap > 0 and gap <= dt + 1e-9  # placed in the previous frame too
            if gap > 0:
                mark.velocity_px_s = (box - mark.box) / gap
            mark.streak = mark.streak + 1 if fresh else 1
            mark.item, mark.box, mark.last_seen_s = dict(it), box, t_s
        out = []
        for vid in list(self._marks):
            mark = self._marks[vid]
            if vid in now:
                mark.shown = mark.shown or mark.streak >= self.onset_frames
                if mark.shown:
                    out.append({**mark.item, "held": False})
                continue
            age = t_s - mark.last_seen_s
            if not mark.shown or age > self.hold_s:
                del self._marks[vid]
                continue
            box = mark.box + mark.velocity_px_s * age
            out.append({**mark.item, "box": [float(b) for b in box], "held": True})
        return out


def _label_lines(item: dict[str, Any]) -> tuple[str, str]:
    head = str(item.get("label", "aggressive driver")).upper()
    parts = []
    conf = item.get("confidence")
    if conf is not None and math.isfinite(float(conf)):
        parts.append(f"{100 * float(conf):.0f} %")
    dist = item.get("distance_m")
    if dist is not None and math.isfinite(float(dist)):
        parts.append(f"{float(dist):.0f} m")
    return head, "  ".join(parts)


def draw_overlay(rgb: np.ndarray, items: Sequence[dict[str, Any]], colour: tuple[int, int, int] = MARK_RGB,
                 full_labels: int = 2, label_range_m: float = 60.0) -> np.ndarray:
    """A copy of ``rgb`` with each mark drawn: a box on the vehicle and a label above it
    ("AGGRESSIVE DRIVER", confidence and distance) on a filled banner, sized to the image.
    The nearest vehicle's label sits just above its box; labels that would cover another
    one are moved up and joined to their box by a line. So that a glance is enough, only
    the ``full_labels`` nearest marks within ``label_range_m`` get the full label; the others
    get a small "!" tag.

    :param rgb: ``uint8 (H, W, 3)`` RGB frame
    :param items: marks (:meth:`OverlayStabilizer.update` or ``info["adas"]["overlay"]``)
    :param colour: the marks' colour (RGB)
    :param full_labels: most marks with the full label [-]
    :param label_range_m: farthest distance of a full label [m]
    :return: the annotated frame (same shape)
    """
    out = np.ascontiguousarray(rgb).copy()
    h, w = out.shape[:2]
    scale = max(h / 720.0, 0.3)  # text and lines grow with the picture
    thick = max(1, round(3 * scale))
    font = cv2.FONT_HERSHEY_DUPLEX
    placed: list[tuple[int, int, int, int]] = []
    banners = []
    n_full = 0
    for item in sorted(items, key=lambda it: float(it.get("distance_m") or 0.0)):  # nearest first
        x1, y1, x2, y2 = (float(v) for v in item["box"])
        if not all(map(math.isfinite, (x1, y1, x2, y2))) or x2 <= 0 or y2 <= 0 or x1 >= w or y1 >= h:
            continue
        p1 = (int(round(max(x1, 0))), int(round(max(y1, 0))))
        p2 = (int(round(min(x2, w - 1))), int(round(min(y2, h - 1))))
        cv2.rectangle(out, p1, p2, colour, thick, cv2.LINE_AA)
        dist = float(item.get("distance_m") or 0.0)
        if n_full < full_labels and (not math.isfinite(dist) or dist <= label_range_m):
            head, sub = _label_lines(item)
            n_full += 1
        else:
            head, sub = "!", ""
        fs_head, fs_sub = 0.9 * scale, 0.75 * scale
        (tw1, th1), _ = cv2.getTextSize(head, font, fs_head, thick)
        (tw2, th2), _ = cv2.getTextSize(sub, font, fs_sub, max(1, thick - 1)) if sub else ((0, 0), 0)
        pad = max(2, round(6 * scale))
        bw, bh = max(tw1, tw2) + 2 * pad, th1 + (th2 + pad if sub else 0) + 2 * pad
        bx = int(np.clip((p1[0] + p2[0]) / 2 - bw / 2, 0, max(w - bw, 0)))
        by = p1[1] - bh - thick
        if by < 0:  # no room above the box: below it
            by = min(p2[1] + thick, h - bh)
        while by > 0 and any(bx < ox2 and ox1 < bx + bw and by < oy2 and oy1 < by + bh
                             for ox1, oy1, ox2, oy2 in placed):
            by = max(by - bh - pad, 0)  # move up past the label in the way
        placed.append((bx, by, bx + bw, by + bh))
        banners.append((item, head, sub, bx, by, bw, bh, pad, th1, th2, p1, p2))
    for _item, head, sub, bx, by, bw, bh, pad, th1, th2, p1, p2 in reversed(banners):  # nearest drawn last, on top
        if by + bh < p1[1] - thick:  # moved away from its box: a leader line
            cx = (p1[0] + p2[0]) // 2
            cv2.line(out, (int(np.clip(cx, bx, bx + bw)), by + bh), (cx, p1[1]), colour, max(1, thick - 1), cv2.LINE_AA)
        cv2.rectangle(out, (bx, by), (bx + bw, by + bh), colour, -1)
        cv2.putText(out, head, (bx + pad, by + pad + th1), font, fs_head, (255, 255, 255), thick, cv2.LINE_AA)
        if sub:
            cv2.putText(out, sub, (bx + pad, by + 2 * pad + th1 + th2), font, fs_sub, (255, 255, 255),
                        max(1, thick - 1), cv2.LINE_AA)
    return out

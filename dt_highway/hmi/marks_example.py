"""What the warning marks look like, for the screen that explains them (the protocol's ``overlay``
screen, ``marks_example = true``).

A participant is shown the display before driving with it: a human-machine interface is introduced
with a picture of it, not only in words. The picture is drawn by the trial's own code: the ego
camera's renderer (:func:`~dt_highway.env.core.make_camera`, the ``camera`` section's defaults at
:data:`REFERENCE_SIZE_PX`) on a hand-built three-lane scene, and :func:`~dt_highway.overlay.draw_overlay`
for the marks, so it shows them in the colours and fonts of a trial, their size in proportion to the
picture's as in a 16:9 trial. It is rendered once (about 0.35 s) and scaled to the screen, whatever
the window's size. No simulation runs and no twin or detector is involved: the marks are placed on the
cars by projecting their outlines.

The scene: the ego in the middle lane; a car in the left lane 16 m ahead, already angled towards the
ego's lane, with the cut-in mark (">> CUTTING IN", amber; the twin also tags it aggressive); a car in the
right lane 34 m ahead with the driver-type mark ("AGGRESSIVE DRIVER", red); a car in the right lane 70 m
ahead with a driver-type mark beyond the two labelled ones (the small "!" tag of
:func:`~dt_highway.overlay.label_layout`); a car 80 m ahead without a mark. Every overlay condition (the
placebo's too) explains the display with this one picture, so it tells none of them
apart; in a given trial the display shows one or both kinds of mark.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from dt_highway.camera.pinhole import Pose
from dt_highway.camera.scene import LaneLine, RoadScene, VehicleSet
from dt_highway.config import CameraConfig
from dt_highway.env.core import make_camera
from dt_highway.overlay import THREAT_CUE, TYPE_CUE, TYPE_LABEL, draw_overlay, label_layout, threat_label

REFERENCE_SIZE_PX = (1280, 720)
"""The camera picture the example is cut from ``(width, height)`` [px] (16:9, as the default camera)"""


LANE_WIDTH_M = 4.0
"""The example road's lane width [m] (highway-env's)"""
EGO = Pose(0.0, LANE_WIDTH_M, 0.0)
"""The ego: the middle of three lanes [m], [rad]"""
CARS = ((7, 16.0, 1.6, 0.12, "threat"), (3, 34.0, 8.0, 0.0, "type"), (5, 70.0, 8.0, 0.0, "type"), (9, 80.0, 0.2, 0.0, ""))
"""The other cars: id, ``x`` [m], ``y`` [m], heading [rad], the mark it gets (``""``: none)"""
CAR_SIZE_M = (5.0, 2.0)
"""Length and width of the cars [m] (highway-env's)"""
CONFIDENCE = {"threat": 0.8, "type": 0.9}
"""The confidence each mark's label shows [-]"""


def _scene() -> RoadScene:
    edge = LANE_WIDTH_M / 2
    lines = (LaneLine(-edge, False), LaneLine(edge, True), LaneLine(edge + LANE_WIDTH_M, True),
             LaneLine(edge + 2 * LANE_WIDTH_M, False))
    return RoadScene(-edge, edge + 2 * LANE_WIDTH_M, -200.0, 2000.0, lines)


def _outline_box(points: np.ndarray, size: tuple[int, int]) -> list[float]:
    """The image box ``[x1, y1, x2, y2]`` [px] around projected points, clipped to the image."""
    x1, y1 = np.nanmin(points, axis=0)
    x2, y2 = np.nanmax(points, axis=0)
    return [max(float(x1), 0.0), max(float(y1), 0.0), min(float(x2), size[0] - 1.0), min(float(y2), size[1] - 1.0)]


def _corners(x_m: float, y_m: float, heading_rad: float, height_m: float) -> np.ndarray:
    """The 8 corners of a car's bounding cuboid, world frame, ``z`` up ``(8, 3)`` [m]."""
    length, width = CAR_SIZE_M
    c, s = math.cos(heading_rad), math.sin(heading_rad)
    return np.array([(x_m + c * dx - s * dy, y_m + s * dx + c * dy, z)
                     for dx in (-length / 2, length / 2) for dy in (-width / 2, width / 2) for z in (0.0, height_m)])


@functools.lru_cache(maxsize=1)
def marks_example() -> np.ndarray:
    """The example picture of the warning marks (module docstring): the band of a
    :data:`REFERENCE_SIZE_PX` camera picture from just above the marks' labels to just below the cars.

    :return: ``uint8 (h, 1280, 3)`` RGB, read-only (``h`` < 720)
    """
    size = REFERENCE_SIZE_PX
    cfg = CameraConfig(width_px=size[0], height_px=size[1])
    renderer = make_camera(cfg, _scene())
    image, _ = renderer.render(EGO, VehicleSet.of([c[:4] for c in CARS], *CAR_SIZE_M))
    items = []
    for vid, x_m, y_m, heading_rad, cue in CARS:
        if not cue:
            continue
        uv, _ = renderer.camera.pixels(_corners(x_m, y_m, heading_rad, cfg.vehicle_height_m), EGO)
        item = {"vehicle_id": vid, "box": _outline_box(uv, size), "confidence": CONFIDENCE[cue],
                "distance_m": round(x_m - EGO.x_m - CAR_SIZE_M[0] / 2 - cfg.mount.forward_m)}
        if cue == "threat":
            item |= {"cue": THREAT_CUE, "side": "left", "aggressive": True, "label": threat_label("left", True)}
        else:
            item |= {"cue": TYPE_CUE, "label": TYPE_LABEL}
        items.append(item)
    out = draw_overlay(image.rgb, items)
    tops, bottoms = [], []
    for b in label_layout(items, size[0], size[1]):
        tops += [b.box[1]] + ([b.label[1]] if b.label is not None else [])
        bottoms.append(b.box[3])
    pad = max(int(0.04 * size[1]), 2)
    band = out[max(min(tops) - pad, 0):min(max(bottoms) + 2 * pad, size[1])]
    band = np.ascontiguousarray(band)
    band.flags.writeable = False
    return band


__all__ = ["REFERENCE_SIZE_PX", "marks_example"]

"""Camera frames as pictures: colour-mapped depth and instance ids, boxes, PNG files.

Used by ``dt-highway camera`` (:mod:`dt_highway.evaluation.frames`) and by anything that wants to look at a frame.
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np

NEAR_COLOUR_M = 1.0
"""Depth shown in the warmest colour by :func:`colourise_depth` [m]"""


def colourise_depth(depth_m: np.ndarray, max_range_m: float) -> np.ndarray:
    """Depth as an RGB picture: turbo colour map on a log scale, red near (1 m), blue far.

    :param depth_m: depth image [m]
    :param max_range_m: the depth shown darkest blue [m]
    :return: ``uint8 (H, W, 3)`` RGB
    """
    z = np.clip(np.asarray(depth_m, dtype=np.float32), NEAR_COLOUR_M, max_range_m)
    t = np.log(z / NEAR_COLOUR_M) / math.log(max_range_m / NEAR_COLOUR_M)
    bgr = cv2.applyColorMap(np.rint(255.0 * (1.0 - t)).astype(np.uint8), cv2.COLORMAP_TURBO)
    return np.ascontiguousarray(bgr[..., ::-1])


def instance_colours(ids: np.ndarray) -> np.ndarray:
    """A distinct, stable colour ``(N, 3)`` per vehicle id (hue by the golden ratio), black for 0.

    :param ids: vehicle ids ``(N,)`` (0 = background)
    :return: ``uint8 (N, 3)`` RGB, one colour per id
    """
    ids = np.asarray(ids, dtype=np.int64)
    hue = ((ids * 0.6180339887) % 1.0 * 180).astype(np.uint8)
    hsv = np.stack([hue, np.full_like(hue, 200), np.full_like(hue, 255)], axis=-1)[None]
    rgb = cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)[0]
    rgb[ids == 0] = 0
    return rgb


def colourise_instance(instance: np.ndarray) -> np.ndarray:
    """The instance-id map as an RGB picture (one colour per vehicle, black background).

    :param instance: ``(H, W)`` vehicle id per pixel, 0 = background
    :return: ``uint8 (H, W, 3)`` RGB
    """
    ids, inverse = np.unique(instance, return_inverse=True)
    return instance_colours(ids)[inverse.reshape(instance.shape)]


def write_png(path: Path, rgb: np.ndarray) -> None:
    """Write an RGB image as PNG.

    :param path: the PNG file to write
    :param rgb: ``uint8 (H, W, 3)`` RGB image
    :raises OSError: if the file cannot be written
    """
    if not cv2.imwrite(str(path), np.ascontiguousarray(rgb[..., ::-1])):
        raise OSError(f"cannot write {path}")

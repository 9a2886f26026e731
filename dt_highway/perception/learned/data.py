"""Training and evaluation frames for the learned detector, made by the product's own camera.

Each frame is a random highway scene drawn by :class:`~dt_highway.camera.render.CameraRenderer`
(the renderer the env uses), with the renderer's ground truth as labels: the **visible box**
of every vehicle the camera shows. Scenes vary what a detector must not depend on:

* the road: 2 to 5 lanes, lane width 3.5 to 4.5 m, the ego in any lane, off its centre,
  slightly turned (lane changes);
* the traffic: 0 to 40 vehicles from 40 m behind to 200 m ahead, free flow and platoons with
  1 to 6 m gaps (occlusion), vehicles between lanes and turned (cut-ins), car sizes and
  heights, every paint of the renderer;
* the camera (training only): mount height 1.0 to 1.7 m, pitch 0 to 6 deg, field of view
  80 to 100 deg;
* colour and lighting (training only, :func:`~dt_highway.perception.learned.train.randomise_colours`):
  hue rotation, saturation, per-channel gains (white balance, coloured light), brightness,
  contrast, gamma, sensor noise, blur, so that the detector learns shapes, not the
  renderer's palette.

A frame is a pure function of its seed (:func:`make_frame`), so a held-out set is a range of
seeds that training never draws (training seeds start at :data:`TRAIN_SEED0`).

Which boxes are scored (:func:`scored`): vehicles at least :data:`MIN_HEIGHT_FRAC` of the
image height tall and at least :data:`MIN_VISIBILITY` visible, KITTI's "moderate"
difficulty (25 px of 375, partly occluded) scaled to the image. Smaller or more hidden
vehicles are labelled too, but evaluation ignores detections on them (COCO's crowd
regions) rather than counting them as hits or false alarms.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from dt_highway.camera.pinhole import Intrinsics, Mount, PinholeCamera, Pose
from dt_highway.camera.render import CameraImage, CameraRenderer, RenderSettings
from dt_highway.camera.scene import LaneLine, RoadScene, VehicleSet
from dt_highway.camera.truth import CameraTruth

MIN_HEIGHT_FRAC = 25.0 / 375.0
"""Least visible box height of a scored vehicle, as a fraction of the image height [-] (KITTI moderate)"""
MIN_VISIBILITY = 0.5
"""Least visibility of a scored vehicle [-] (KITTI moderate: partly occluded)"""
MIN_LABEL_PX = 6
"""Vehicles with fewer visible pixels are not labelled at all [px]"""
TRAIN_SEED0 = 1_000_000
"""Training frames use seeds from here on; evaluation sets use seeds below it"""
CLIP = 8
"""Consecutive seeds ``CLIP * k .. CLIP * k + CLIP - 1`` share a road and a camera (building a
renderer's road texture costs 20 ms, drawing a frame 2.5 ms); traffic and ego differ"""


@dataclass(frozen=True)
class SceneSettings:
    """What a synthetic frame may show.

    :param width_px: image width [px]
    :param height_px: image height [px]
    :param vary_camera: draw the camera's mount and field of view at random (training);
        otherwise the product's camera (1.3 m high, 3 deg down, 90 deg field of view)
    :param max_vehicles: most vehicles in a scene [-]
    """

    width_px: int = 320
    height_px: int = 180
    vary_camera: bool = True
    max_vehicles: int = 40


@dataclass
class LabelledFrame:
    """A frame and its labels.

    :param rgb: ``uint8 (H, W, 3)`` image
    :param depth_m: ``float32 (H, W)`` planar depth [m]
    :param boxes: ``(N, 4)`` visible boxes ``x1, y1, x2, y2`` [px]
    :param scored: ``(N,)`` whether each box counts in evaluation (else: ignored)
    :param image: the renderer's image (what a detector is given)
    :param truth: the renderer's ground truth (the labels' source, for evaluation tools)
    """

    rgb: np.ndarray
    depth_m: np.ndarray
    boxes: np.ndarray
    scored: np.ndarray
    image: CameraImage
    truth: CameraTruth


def scored(truth: CameraTruth) -> tuple[np.ndarray, np.ndarray]:
    """The labelled boxes of a rendered frame and which of them evaluation scores.

    :param truth: a rendered frame's ground truth
    :return: ``(boxes (N, 4), scored (N,) bool)``
    """
    h = truth.instance.shape[0]
    rows = [
        (t.visible_box, t.visibility)
        for t in truth.vehicles.values()
        if t.visible_box is not None and t.visible_px >= MIN_LABEL_PX
    ]
    if not rows:
        return np.zeros((0, 4)), np.zeros(0, dtype=bool)
    boxes = np.array([r[0] for r in rows], dtype=float)
    vis = np.array([r[1] for r in rows], dtype=float)
    tall = (boxes[:, 3] - boxes[:, 1]) >= MIN_HEIGHT_FRAC * h
    return boxes, tall & (vis >= MIN_VISIBILITY)


def _road(rng: np.random.Generator) -> tuple[RoadScene, np.ndarray]:
    n_lanes = int(rng.integers(2, 6))
    width = float(rng.uniform(3.5, 4.5))
    centres = width * np.arange(n_lanes)
    lines = [LaneLine(-width / 2, False)] + [LaneLine(c + width / 2, True) for c in centres[:-1]]
    lines.append(LaneLine(centres[-1] + width / 2, False))
    return RoadScene(-width / 2, centres[-1] + width / 2, -1e4, 1e4, tuple(lines)), centres


def _traffic(rng: np.random.Generator, centres: np.ndarray, ego: Pose, max_vehicles: int) -> VehicleSet:
    lane_w = float(centres[1] - centres[0])
    n_target = int(rng.integers(0, max_vehicles + 1))
    platoon = rng.random() < 0.5
    xs: list[float] = []  # centres [m]
    ys: list[float] = []
    hs: list[float] = []  # headings [rad]
    ls: list[float] = []  # lengths [m]
    ws: list[float] = []  # widths [m]

    def free(x: float, y: float, length: float, width: float) -> bool:
        # footprints must not overlap (the renderer's painting order needs disjoint cars)
        for x2, y2, l2, w2 in zip(xs, ys, ls, ws, strict=True):
            if abs(x - x2) < (length + l2) / 2 + 0.5 and abs(y - y2) < (width + w2) / 2 + 0.4:
                return False
        return abs(x - ego.x_m) > (length + 5.0) / 2 + 0.5 or abs(y - ego.y_m) > (width + 2.0) / 2 + 0.4

    for _ in range(4 * n_target):
        if len(xs) >= n_target:
            break
        length = float(rng.uniform(4.2, 5.6))
        width = float(rng.uniform(1.7, 2.2))
        lane = int(rng.integers(len(centres)))
        between = rng.random() < 0.12
        y = centres[lane] + (rng.uniform(-0.5, 0.5) * lane_w if between else rng.normal(0.0, 0.25))
        if platoon and xs and rng.random() < 0.6:
            # close behind or ahead of a car already placed in the same lane
            j = int(rng.integers(len(xs)))
            x = xs[j] + rng.choice([-1.0, 1.0]) * ((length + ls[j]) / 2 + rng.uniform(1.0, 6.0))
            y = ys[j] + rng.normal(0.0, 0.3)
        else:
            # more cars near the ego than far away (where they are tiny)
            x = ego.x_m + float(rng.choice([rng.uniform(-40.0, 200.0), rng.exponential(35.0) + 3.0]))
        heading = float(rng.normal(0.0, 0.08 if between else 0.015))
        if free(x, y, length, width):
            xs.append(x)
            ys.append(y)
            hs.append(heading)
            ls.append(length)
            ws.append(width)
    n = len(xs)
    if n == 0:
        return VehicleSet.empty()
    ids = rng.choice(np.arange(1, 100_000), size=n, replace=False).astype(np.int32)
    return VehicleSet(ids, np.array(xs), np.array(ys), np.array(hs), np.array(ls), np.array(ws))


@functools.lru_cache(maxsize=2)
def _renderer(clip: int, settings: SceneSettings) -> tuple[CameraRenderer, np.ndarray]:
    rng = np.random.default_rng([clip, 7])
    scene, centres = _road(rng)
    if settings.vary_camera:
        mount = Mount(0.5, 0.0, float(rng.uniform(1.0, 1.7)), math.radians(rng.uniform(0.0, 6.0)), 0.0)
        hfov = math.radians(rng.uniform(80.0, 100.0))
        height_m = float(rng.uniform(1.3, 1.8))
    else:
        mount, hfov, height_m = Mount(0.5, 0.0, 1.3, math.radians(3.0), 0.0), math.radians(90.0), 1.5
    camera = PinholeCamera(Intrinsics.from_fov(settings.width_px, settings.height_px, hfov), mount)
    return CameraRenderer(camera, scene, RenderSettings(vehicle_height_m=height_m)), centres


def make_frame(seed: int, settings: SceneSettings = SceneSettings()) -> LabelledFrame:
    """One synthetic frame and its labels, a pure function of ``seed`` and ``settings``.

    :param seed: the frame's seed (``seed // CLIP`` picks the road and the camera)
    :param settings: image size and what may vary
    :return: the frame (colours as rendered: training randomises them batch-wise)
    """
    if seed < 0:
        raise ValueError(f"seed must be >= 0 (got {seed})")
    renderer, centres = _renderer(seed // CLIP, settings)
    rng = np.random.default_rng(seed)
    lane = int(rng.integers(len(centres)))
    ego = Pose(float(rng.uniform(-1e3, 1e3)), float(centres[lane] + rng.normal(0.0, 0.3)), float(rng.normal(0.0, 0.02)))
    vehicles = _traffic(rng, centres, ego, settings.max_vehicles)
    image, truth = renderer.render(ego, vehicles)
    boxes, keep = scored(truth)
    return LabelledFrame(image.rgb, image.depth_m, boxes, keep, image, truth)

"""Detectors: a camera image in, boxes out (the paper's object detection, section III-B).

A detector (:class:`Detector`) has one method, ``detect(image)``, that takes a
:class:`~dt_highway.camera.render.CameraImage` and returns :class:`Detections`: boxes
``(x1, y1, x2, y2)`` [px] in the image frame of :mod:`dt_highway.camera.render`, a score
in ``[0, 1]`` and a class (0 = vehicle). A learned detector reads only ``image.rgb`` (and
``image.depth_m`` if it wants depth).

The default :class:`SimulatedDetector` stands in for a real one. It is a sensor model: it
starts from the renderer's ground truth (:class:`~dt_highway.camera.truth.CameraTruth`: each
vehicle's visible box and visibility), given to it beside the image, and adds the errors a
one-stage detector makes, seeded and configurable: box jitter, misses of small or mostly
hidden vehicles, **one merged box for vehicles that overlap strongly in the image** (the
failure the paper names), and false positives. Its boxes carry no vehicle ids: nothing
downstream can learn from it which box is which vehicle. :func:`run_detector` runs either
kind on a frame, giving the truth to the sensor model only.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from dt_highway.camera.render import CameraImage
from dt_highway.camera.truth import CameraTruth
from dt_highway.config import DetectorConfig, FrozenSettings, section_field

VEHICLE = 0
"""Class id of vehicles"""


@dataclass(frozen=True)
class Detections:
    """Boxes found in one frame.

    :param boxes: ``(N, 4)`` float ``x1, y1, x2, y2`` [px]
    :param scores: ``(N,)`` confidence in ``[0, 1]``
    :param classes: ``(N,)`` int class ids (0 = vehicle)
    """

    boxes: np.ndarray
    scores: np.ndarray
    classes: np.ndarray

    def __len__(self) -> int:
        return len(self.boxes)

    @classmethod
    def empty(cls) -> Detections:
        """No detections.

        :return: detections of zero rows
        """
        return cls(np.zeros((0, 4)), np.zeros(0), np.zeros(0, dtype=np.int64))

    @classmethod
    def of(cls, boxes: list[tuple[float, float, float, float]] | np.ndarray, score: float = 1.0) -> Detections:
        """Vehicle detections from a list of boxes (tests, examples).

        :param boxes: ``(N, 4)`` boxes ``x1, y1, x2, y2`` [px]
        :param score: every box's confidence in ``[0, 1]``
        :return: the detections, all of class vehicle
        """
        b = np.asarray(boxes, dtype=float).reshape(-1, 4)
        return cls(b, np.full(len(b), score), np.zeros(len(b), dtype=np.int64))


class Detector(Protocol):
    """Anything with ``detect(image) -> Detections``: a detector sees the image only."""

    def detect(self, image: CameraImage) -> Detections:
        """Find the vehicles in an image.

        :param image: the camera image
        :return: the detections
        """
        ...


class SimulatedDetectorSettings(FrozenSettings):
    """Error model of :class:`SimulatedDetector` (sizes in pixels of the frame at hand); the
    defaults and ranges are the ``detector`` section's (:class:`~dt_highway.config.DetectorConfig`).

    :param jitter: standard deviation of each box edge, as a fraction of the box's width
        (left/right edges) or height (top/bottom) [-]
    :param miss_height_px: visible height at which half of the vehicles are missed [px]
    :param miss_visibility: visibility at which half of the vehicles are missed [-]
    :param merge_overlap: two visible boxes whose intersection covers this share of the
        smaller one may come out as one box [-]
    :param merge_prob: probability that such a pair is merged in a frame [-]
    :param false_positives_per_frame: mean number of spurious boxes per frame [-]
    """

    jitter: float = section_field(DetectorConfig, "jitter")
    miss_height_px: float = section_field(DetectorConfig, "miss_height_px")
    miss_visibility: float = section_field(DetectorConfig, "miss_visibility")
    merge_overlap: float = section_field(DetectorConfig, "merge_overlap")
    merge_prob: float = section_field(DetectorConfig, "merge_prob")
    false_positives_per_frame: float = section_field(DetectorConfig, "false_positives_per_frame")


class SimulatedDetector:
    """A detector made from the renderer's ground truth plus realistic, seeded errors.

    :param settings: the error model (None: the ``detector`` section's defaults)
    :param rng: its random generator (seed it for reproducible detections)
    """

    def __init__(self, settings: SimulatedDetectorSettings | None = None,
                 rng: np.random.Generator | None = None) -> None:
        self.settings = settings if settings is not None else SimulatedDetectorSettings()
        self.rng = rng if rng is not None else np.random.default_rng()

    def detect(self, image: CameraImage, truth: CameraTruth) -> Detections:
        """Boxes for the vehicles of a frame (read from its ground truth), with errors.

        :param image: the rendered image (its size)
        :param truth: the frame's ground truth (its ``vehicles`` are used)
        :return: the detections (no vehicle ids)
        """
        s, rng = self.settings, self.rng
        seen = [t for t in truth.vehicles.values() if t.visible_box is not None]
        h_img, w_img = image.rgb.shape[:2]
        boxes = np.array([t.visible_box for t in seen], dtype=float).reshape(-1, 4)
        vis = np.array([t.visibility for t in seen], dtype=float)
        # misses: logistic in the visible height and in the visibility
        height = boxes[:, 3] - boxes[:, 1]
        p_size = 1.0 / (1.0 + np.exp(-(height - s.miss_height_px) / max(0.25 * s.miss_height_px, 1e-6)))
        p_vis = 1.0 / (1.0 + np.exp(-(vis - s.miss_visibility) / 0.06))
        detected = rng.random(len(boxes)) < p_size * p_vis
        boxes, vis = boxes[detected], vis[detected]
        # merges: strongly overlapping pairs come out as one box (union-find on the pairs)
        n = len(boxes)
        parent = list(range(n))

        def root(i: int) -> int:
            while parent[i] != i:
                parent[i] = parent[parent[i]]
                i = parent[i]
            return i

        if n > 1:
            ii, jj = np.triu_indices(n, 1)
            ix1 = np.maximum(boxes[ii, 0], boxes[jj, 0])
            iy1 = np.maximum(boxes[ii, 1], boxes[jj, 1])
            ix2 = np.minimum(boxes[ii, 2], boxes[jj, 2])
            iy2 = np.minimum(boxes[ii, 3], boxes[jj, 3])
            inter = np.clip(ix2 - ix1, 0, None) * np.clip(iy2 - iy1, 0, None)
            area = (boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1])
            cover = inter / np.maximum(np.minimum(area[ii], area[jj]), 1e-9)
            merge = (cover >= s.merge_overlap) & (rng.random(len(ii)) < s.merge_prob)
            for a, b in zip(ii[merge].tolist(), jj[merge].tolist(), strict=True):
                parent[root(a)] = root(b)
        groups: dict[int, list[int]] = {}
        for i in range(n):
            groups.setdefault(root(i), []).append(i)
        out_boxes, out_scores = [], []
        for members in groups.values():
            b = boxes[members]
            merged = np.array([b[:, 0].min(), b[:, 1].min(), b[:, 2].max(), b[:, 3].max()])
            out_boxes.append(merged)
            out_scores.append(0.55 + 0.4 * float(vis[members].max()) - 0.1 * (len(members) > 1))
        out = np.array(out_boxes, dtype=float).reshape(-1, 4)
        # jitter of each edge, relative to the box's size
        if len(out):
            w_box, h_box = out[:, 2] - out[:, 0], out[:, 3] - out[:, 1]
            size = np.stack([w_box, h_box, w_box, h_box], axis=1)
            out = out + rng.normal(0.0, s.jitter, out.shape) * size
        # false positives: boxes of vehicle-like size near the horizon band
        n_fp = rng.poisson(s.false_positives_per_frame)
        if n_fp:
            hgt = rng.uniform(0.03, 0.12, n_fp) * h_img
            wid = hgt * rng.uniform(1.0, 1.6, n_fp)
            cx = rng.uniform(0.05, 0.95, n_fp) * w_img
            cy = rng.uniform(0.45, 0.65, n_fp) * h_img
            fp = np.stack([cx - wid / 2, cy - hgt / 2, cx + wid / 2, cy + hgt / 2], axis=1)
            out = np.concatenate([out, fp])
            out_scores.extend(rng.uniform(0.3, 0.6, n_fp).tolist())
        scores = np.clip(np.array(out_scores, dtype=float) + rng.normal(0.0, 0.03, len(out_scores)), 0.0, 1.0)
        # keep boxes well formed and inside the image
        if len(out):
            out[:, [0, 2]] = np.clip(out[:, [0, 2]], -0.5, w_img - 0.5)
            out[:, [1, 3]] = np.clip(out[:, [1, 3]], -0.5, h_img - 0.5)
            ok = (out[:, 2] - out[:, 0] >= 1.0) & (out[:, 3] - out[:, 1] >= 1.0)
            out, scores = out[ok], scores[ok]
        return Detections(out, scores, np.full(len(out), VEHICLE, dtype=np.int64))


def run_detector(detector: Detector | SimulatedDetector, image: CameraImage, truth: CameraTruth) -> Detections:
    """One frame's detections: the :class:`SimulatedDetector` (a sensor model) reads the
    frame's ground truth, any other detector gets the image only.

    :param detector: the detector
    :param image: the camera image
    :param truth: the frame's ground truth (given to the sensor model only)
    :return: the detections
    """
    if isinstance(detector, SimulatedDetector):
        return detector.detect(image, truth)
    return detector.detect(image)


def iou(boxes_a: np.ndarray, boxes_b: np.ndarray) -> np.ndarray:
    """Intersection over union of every box of ``a`` with every box of ``b``.

    :param boxes_a: ``(N, 4)`` boxes ``x1, y1, x2, y2``
    :param boxes_b: ``(M, 4)`` boxes
    :return: ``(N, M)`` IoU in ``[0, 1]``
    """
    a = np.asarray(boxes_a, dtype=float).reshape(-1, 4)
    b = np.asarray(boxes_b, dtype=float).reshape(-1, 4)
    ix = np.maximum(np.minimum(a[:, None, 2], b[None, :, 2]) - np.maximum(a[:, None, 0], b[None, :, 0]), 0.0)
    iy = np.maximum(np.minimum(a[:, None, 3], b[None, :, 3]) - np.maximum(a[:, None, 1], b[None, :, 1]), 0.0)
    inter = ix * iy
    area_a = (a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1])
    area_b = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    union = area_a[:, None] + area_b[None, :] - inter
    return np.where(union > 0, inter / np.maximum(union, 1e-12), 0.0)

"""The learned detector behind the fusion's detector interface (``detector.kind = "learned"``)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import cast

import cv2
import numpy as np
import torch

from dt_highway.camera.render import CameraImage
from dt_highway.perception.detect import VEHICLE, Detections
from dt_highway.perception.learned.model import inverse_depth, peaks, to_input
from dt_highway.perception.learned.weights import load_weights

SCALES = ("resize", "native")
"""How frames of another size than the network's input are read"""


class LearnedDetector:
    """Finds vehicles in camera frames with a trained :class:`~dt_highway.perception.learned.model.PointDetector`.

    Frames of another size than the network's input are, with ``scale="resize"``, resized to
    it (``cv2.INTER_AREA``) and the boxes scaled back: the cost of a frame stays that of the
    network's size, but vehicles shrink with the frame. With ``scale="native"`` the (fully
    convolutional) network reads the frame as it is: a 640 x 360 frame costs four times a
    320 x 180 one, and far vehicles keep their pixels. It reads ``image.rgb`` (and
    ``image.depth_m`` for a depth model) only.

    :param weights: a weights file (``None``: the shipped weights)
    :param min_score: least score of a reported detection, in (0, 1] [-]
    :param threads: torch threads (``None``: leave torch's setting)
    :param scale: ``"resize"`` or ``"native"`` (see above)
    :raises FileNotFoundError: if the weights file does not exist
    :raises ValueError: if it is not a complete weights file
    """

    def __init__(self, weights: str | Path | None = None, min_score: float = 0.3, threads: int | None = None,
                 scale: str = "resize") -> None:
        if not 0.0 < min_score <= 1.0:
            raise ValueError(f"min_score must be in (0, 1] (got {min_score})")
        if scale not in SCALES:
            raise ValueError(f"scale must be one of {', '.join(SCALES)} (got '{scale}')")
        self.scale = scale
        self.model, self.meta = load_weights(weights)
        self.arch = self.model.arch
        self.min_score = min_score
        if threads is not None:
            torch.set_num_threads(threads)

    def detect(self, image: CameraImage) -> Detections:
        """Vehicles in one image.

        :param image: a camera image
        :return: boxes ``x1, y1, x2, y2`` [px] in the image's pixels, scores, classes (0)
        """
        return self.detect_batch([image.rgb], [image.depth_m] if self.arch.depth else None)[0]

    def detect_batch(self, rgbs: list[np.ndarray] | np.ndarray, depths: list[np.ndarray] | None = None,
                     min_score: float | None = None) -> list[Detections]:
        """Vehicles in a batch of images (one forward pass).

        :param rgbs: ``uint8 (H, W, 3)`` images, all of one size
        :param depths: ``(H, W)`` planar depth images [m] (depth models only)
        :param min_score: least score (default: the detector's)
        :return: one :class:`Detections` per image
        """
        arch = self.arch
        if len(rgbs) == 0:
            return []
        h, w = rgbs[0].shape[:2]
        size = (arch.width_px, arch.height_px)
        resize = (w, h) != size and self.scale == "resize"
        if resize:
            rgbs = [cv2.resize(im, size, interpolation=cv2.INTER_AREA) for im in rgbs]
        inv = None
        if arch.depth:
            if depths is None:
                raise ValueError("this detector reads depth: give the frames' depth images")
            ds = [cv2.resize(d, size, interpolation=cv2.INTER_NEAREST) if resize else d for d in depths]
            inv = torch.from_numpy(np.stack([inverse_depth(d) for d in ds]))
        images = cast("Sequence[np.ndarray]", rgbs)  # a list, or an (N, H, W, 3) array
        batch = torch.from_numpy(np.ascontiguousarray(np.stack(images)))
        with torch.inference_mode():
            heat, dist = self.model(to_input(batch, arch, inv))
            found = peaks(heat, dist, min_score=self.min_score if min_score is None else min_score)
        sx, sy = w / size[0], h / size[1]
        out = []
        for boxes, scores in found:
            if resize:
                # pixel centres are at integers: x_frame = (x_net + 0.5) * scale - 0.5
                boxes = (boxes + 0.5) * np.array([sx, sy, sx, sy]) - 0.5
            boxes[:, [0, 2]] = np.clip(boxes[:, [0, 2]], -0.5, w - 0.5)
            boxes[:, [1, 3]] = np.clip(boxes[:, [1, 3]], -0.5, h - 0.5)
            ok = (boxes[:, 2] - boxes[:, 0] >= 1.0) & (boxes[:, 3] - boxes[:, 1] >= 1.0)
            out.append(Detections(boxes[ok], scores[ok], np.full(int(ok.sum()), VEHICLE, dtype=np.int64)))
        return out

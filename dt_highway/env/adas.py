"""The ADAS pipeline of one simulation step: detector -> fusion -> overlay stabiliser.

The env calls :meth:`AdasPipeline.run` once per step (:meth:`~dt_highway.env.core.DTHighwayEnv.adas_output`
caches it for whoever asks first: the observation, ``info``, a driver's senses). It reads the
camera image and the twin view the ego received, never the simulator's truth; the frame's
ground truth reaches only the simulated detector, a sensor model
(:func:`~dt_highway.perception.detect.run_detector`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from dt_highway.camera.pinhole import PinholeCamera
from dt_highway.camera.render import CameraImage
from dt_highway.camera.truth import CameraTruth
from dt_highway.config import DTConfig
from dt_highway.labels import AGGRESSIVE
from dt_highway.overlay import OverlayStabilizer
from dt_highway.perception import (
    Detections,
    Detector,
    Fusion,
    SimulatedDetector,
    fusion_settings,
    make_detector,
    run_detector,
)
from dt_highway.twin.cloud import TwinVehicleView


class AdasPipeline:
    """Detector, fusion and overlay stabiliser of one episode.

    :param detector: the vehicle detector
    :param fusion: the camera/twin fusion (paper Algorithms 1 and 2)
    :param overlay: the overlay stabiliser
    """

    def __init__(self, detector: Detector | SimulatedDetector, fusion: Fusion, overlay: OverlayStabilizer) -> None:
        self.detector, self.fusion, self.overlay = detector, fusion, overlay

    @classmethod
    def from_config(cls, cfg: DTConfig, camera: PinholeCamera, detector_rng: np.random.Generator,
                    fusion_rng: np.random.Generator) -> AdasPipeline:
        """The pipeline a configuration describes, for a camera.

        :param cfg: the env's configuration (``detector``, ``fusion``, ``overlay``)
        :param camera: the ego camera's pinhole model
        :param detector_rng: the detector's random generator
        :param fusion_rng: the fusion's random generator
        """
        return cls(make_detector(cfg.detector, detector_rng), Fusion(camera, fusion_settings(cfg.fusion), fusion_rng),
                   OverlayStabilizer(cfg.overlay.onset_frames, cfg.overlay.hold_s))

    def run(self, image: CameraImage, truth: CameraTruth, view: Sequence[TwinVehicleView], twin_now_s: float,
            sim_time_s: float) -> dict[str, Any]:
        """Detector and fusion on this step's image: the ADAS output (never ground truth).

        :param image: this step's camera image
        :param truth: its ground truth, for the simulated detector's sensor model only
        :param view: the twin view the ego received
        :param twin_now_s: the twin clock now [s]
        :param sim_time_s: the episode clock now [s]
        :return: ``overlay``: the marks the driver sees: vehicles the twin tags aggressive
            and the fusion placed in the image, kept steady by the overlay stabilizer
            (``vehicle_id``, ``box`` [px], ``label``, ``confidence``, ``distance_m``, ``rule``,
            ``held``); ``fusion_items``: the same before stabilizing (this frame's placements
            only); ``placements``: every placed connected vehicle; ``n_boxes``; ``method``
        """
        detections: Detections = run_detector(self.detector, image, truth)
        placements = self.fusion.step(image, detections, view, twin_now_s)
        tags = {v.vehicle_id: v for v in view}
        items = []
        for vid, p in placements.items():
            if p.box is None:
                continue
            tv = tags[vid]
            if tv.tag == AGGRESSIVE:
                items.append({
                    "vehicle_id": vid, "box": list(p.box), "label": "aggressive driver",
                    "confidence": float(tv.confidence), "distance_m": p.distance_m, "rule": p.rule,
                })
        return {
            "overlay": self.overlay.update(items, sim_time_s),
            "fusion_items": items,
            "placements": {vid: list(p.box) for vid, p in placements.items() if p.box is not None},
            "n_boxes": len(detections),
            "method": self.fusion.settings.method,
        }

"""The ADAS pipeline of one simulation step: detector -> fusion -> mark selection -> overlay stabiliser.

The env calls :meth:`AdasPipeline.run` once per step (:meth:`~dt_highway.env.core.DTHighwayEnv.adas_output`
caches it for whoever asks first: the observation, ``info``, a driver's senses). It reads the
camera image, the twin view the ego received and the ego's own lane, never the simulator's truth;
the frame's ground truth reaches only the simulated detector, a sensor model
(:func:`~dt_highway.perception.detect.run_detector`).

Which cars are marked is ``overlay.mode`` (:func:`~dt_highway.overlay.select_items`); the marks are
kept steady (:class:`~dt_highway.overlay.OverlayStabilizer`) and bounded
(:func:`~dt_highway.overlay.bound_marks`). With ``overlay.sham`` (the placebo condition) that real
overlay is computed and hidden, and :class:`~dt_highway.overlay.ShamOverlay` shows as many marks,
alike, on cars drawn at random with the pipeline's own seeded generator.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from dt_highway.camera.pinhole import PinholeCamera
from dt_highway.camera.render import CameraImage
from dt_highway.camera.truth import CameraTruth
from dt_highway.config import DTConfig, OverlayConfig
from dt_highway.overlay import OverlayStabilizer, ShamOverlay, bound_marks, in_lane, select_items, side_of
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
from dt_highway.twin.tagger import HighwayMap

DEFAULT_LANE_WIDTH_M = 4.0
"""Lane width of the map used when none is given [m] (highway-env's ``StraightLane.DEFAULT_WIDTH``)"""


class AdasPipeline:
    """Detector, fusion, mark selection and overlay stabiliser of one episode.

    :param detector: the vehicle detector
    :param fusion: the camera/twin fusion (paper Algorithms 1 and 2)
    :param overlay: the overlay stabiliser
    :param settings: the ``overlay`` section (mode, threat horizon and threshold, clutter bound,
        sham); ``None``: the defaults with the stabiliser's onset and hold
    :param road_map: the lanes, for the side a threat comes from (``None``: 4 m lanes from ``y = 0``)
    :param rng: the sham overlay's random generator (used only with ``settings.sham``)
    """

    def __init__(self, detector: Detector | SimulatedDetector, fusion: Fusion, overlay: OverlayStabilizer,
                 settings: OverlayConfig | None = None, road_map: HighwayMap | None = None,
                 rng: np.random.Generator | None = None) -> None:
        self.detector, self.fusion, self.overlay = detector, fusion, overlay
        self.settings = settings if settings is not None else OverlayConfig(onset_frames=overlay.onset_frames,
                                                                           hold_s=overlay.hold_s)
        self.road_map = road_map if road_map is not None else HighwayMap(DEFAULT_LANE_WIDTH_M, 1000)
        self.sham = ShamOverlay(rng if rng is not None else np.random.default_rng(0), self.settings.hold_s) \
            if self.settings.sham else None

    @classmethod
    def from_config(cls, cfg: DTConfig, camera: PinholeCamera, detector_rng: np.random.Generator,
                    fusion_rng: np.random.Generator, overlay_rng: np.random.Generator | None = None,
                    road_map: HighwayMap | None = None) -> AdasPipeline:
        """The pipeline a configuration describes, for a camera.

        :param cfg: the env's configuration (``detector``, ``fusion``, ``overlay``; ``twin.intention``
            for the threat's horizon and threshold when ``overlay`` leaves them unset)
        :param camera: the ego camera's pinhole model
        :param detector_rng: the detector's random generator
        :param fusion_rng: the fusion's random generator
        :param overlay_rng: the sham overlay's random generator
        :param road_map: the lanes (for the side a threat comes from)
        :return: the pipeline
        """
        ov, twin = cfg.overlay, cfg.twin.intention
        settings = ov.model_copy(update={  # the threat's operating point: the twin's unless the overlay sets its own
            "horizon_s": ov.horizon_s if ov.horizon_s is not None else twin.operating_horizon_s,
            "threshold": ov.threshold if ov.threshold is not None else twin.threshold})
        return cls(make_detector(cfg.detector, detector_rng), Fusion(camera, fusion_settings(cfg.fusion), fusion_rng),
                   OverlayStabilizer(ov.onset_frames, ov.hold_s), settings, road_map, overlay_rng)

    def run(self, image: CameraImage, truth: CameraTruth, view: Sequence[TwinVehicleView], twin_now_s: float,
            sim_time_s: float, ego_lane: int = -1) -> dict[str, Any]:
        """Detector and fusion on this step's image: the ADAS output (never ground truth).

        :param image: this step's camera image
        :param truth: its ground truth, for the simulated detector's sensor model only
        :param view: the twin view the ego received
        :param twin_now_s: the twin clock now [s]
        :param sim_time_s: the episode clock now [s]
        :param ego_lane: the ego's lane id (the ego knows its own lane; negative: unknown, no threat marks)
        :return: ``overlay``: the marks the driver sees, kept steady and bounded (``vehicle_id``,
            ``box`` [px], ``label``, ``confidence``, ``distance_m``, ``rule``, ``cue``, ``held``;
            ``side`` and ``aggressive`` for a threat; with ``overlay.sham`` the sham marks);
            ``fusion_items``: the real marks' items before stabilizing (this frame's placements
            only); ``placements``: every placed connected vehicle; ``n_boxes``; ``method``;
            with ``overlay.sham`` also ``real_overlay`` (the hidden real marks) and ``sham_pairs``
            (each real mark's vehicle id and its sham mark's car)
        """
        detections: Detections = run_detector(self.detector, image, truth)
        placements = self.fusion.step(image, detections, view, twin_now_s)
        views = {v.vehicle_id: v for v in view}
        items = select_items(placements, views, self.settings, ego_lane, self.road_map)
        placed: dict[int, dict[str, Any]] = {vid: {"box": p.box, "distance_m": p.distance_m, "rule": p.rule}
                                             for vid, p in placements.items() if p.box is not None}
        marks = bound_marks(self.overlay.update(items, sim_time_s, placed), self.settings.max_marks)
        out: dict[str, Any] = {
            "overlay": marks,
            "fusion_items": items,
            "placements": {vid: list(car["box"]) for vid, car in placed.items()},
            "n_boxes": len(detections),
            "method": self.fusion.settings.method,
        }
        if self.sham is not None:
            cars = {vid: {"box": list(p.box), "distance_m": p.distance_m, "rule": p.rule,
                          "side": side_of(views[vid].y_m, ego_lane, self.road_map) if ego_lane >= 0 else None,
                          "in_ego_lane": ego_lane >= 0 and in_lane(views[vid].y_m, ego_lane, self.road_map)}
                    for vid, p in placements.items() if p.box is not None and p.distance_m <= self.settings.max_range_m}
            out["overlay"] = self.sham.update(marks, cars, sim_time_s)
            out["real_overlay"] = marks
            out["sham_pairs"] = self.sham.pairs
        return out

"""Perception and fusion: detectors, Algorithm 1 (depth), Algorithm 2 (matching), tracking."""

from __future__ import annotations

import numpy as np

from dt_highway.config import DetectorConfig, FusionConfig

from dt_highway.perception.depth import box_distances, sample_regions
from dt_highway.perception.detect import Detections, Detector, SimulatedDetector, SimulatedDetectorSettings, iou
from dt_highway.perception.fusion import METHODS, Fusion, FusionSettings, Placement
from dt_highway.perception.matching import JointCost, Match, match_baseline, match_distance, match_each, match_joint
from dt_highway.perception.tracking import BoxTracker



def make_detector(cfg: DetectorConfig, rng: np.random.Generator | None = None) -> SimulatedDetector:
    """The detector described by a ``detector`` config section.

    :param cfg: :class:`~dt_highway.config.DetectorConfig`
    :param rng: its random generator
    """
    return SimulatedDetector(SimulatedDetectorSettings(**cfg.model_dump(exclude={"kind"})), rng)


def fusion_settings(cfg: FusionConfig, method: str | None = None) -> FusionSettings:
    """Fusion settings from a ``fusion`` config section, optionally with another method.

    :param cfg: :class:`~dt_highway.config.FusionConfig`
    :param method: overrides ``cfg.method``
    """
    fields = cfg.model_dump(exclude={"enabled", "method"})
    return FusionSettings(method=method or cfg.method, **fields)


__all__ = [
    "fusion_settings",
    "make_detector",
    "METHODS",
    "BoxTracker",
    "Detections",
    "Detector",
    "Fusion",
    "FusionSettings",
    "JointCost",
    "Match",
    "Placement",
    "SimulatedDetector",
    "SimulatedDetectorSettings",
    "box_distances",
    "iou",
    "match_baseline",
    "match_distance",
    "match_each",
    "match_joint",
    "sample_regions",
]

"""Perception and fusion: detectors, Algorithm 1 (depth), Algorithm 2 (matching), tracking."""

from __future__ import annotations

from dt_highway.perception.depth import box_distances, sample_regions
from dt_highway.perception.detect import Detections, Detector, SimulatedDetector, SimulatedDetectorSettings, iou
from dt_highway.perception.fusion import METHODS, Fusion, FusionSettings, Placement
from dt_highway.perception.matching import JointCost, Match, match_baseline, match_distance, match_each, match_joint
from dt_highway.perception.tracking import BoxTracker



def make_detector(cfg, rng=None) -> SimulatedDetector:
    """The detector described by a ``detector`` config section.

    :param cfg: :class:`~dt_highway.config.DetectorConfig`
    :param rng: its random generator
    """
    settings = SimulatedDetectorSettings(
        jitter=cfg.jitter, miss_height_px=cfg.miss_height_px, miss_visibility=cfg.miss_visibility,
        merge_overlap=cfg.merge_overlap, merge_prob=cfg.merge_prob, false_positives_per_frame=cfg.false_positives_per_frame,
    )
    return SimulatedDetector(settings, rng)


def fusion_settings(cfg, method: str | None = None) -> FusionSettings:
    """Fusion settings from a ``fusion`` config section, optionally with another method.

    :param cfg: :class:`~dt_highway.config.FusionConfig`
    :param method: overrides ``cfg.method``
    """
    return FusionSettings(
        method=method or cfg.method, th=cfg.th, n_samples=cfg.n_samples, fallback=cfg.fallback,
        anchor_height_m=cfg.anchor_height_m, near_face_m=cfg.near_face_m, continuity_bonus=cfg.continuity_bonus,
    )


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

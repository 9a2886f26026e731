"""Perception and fusion: detectors, Algorithm 1 (depth), Algorithm 2 (matching), tracking."""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

from dt_highway.config import ConfigError, DetectorConfig, FusionConfig
from dt_highway.perception.depth import box_distances, sample_regions
from dt_highway.perception.detect import (
    Detections,
    Detector,
    SimulatedDetector,
    SimulatedDetectorSettings,
    iou,
    run_detector,
)
from dt_highway.perception.fusion import METHODS, Fusion, FusionSettings, Placement
from dt_highway.perception.matching import (
    JointCost,
    Match,
    match_baseline,
    match_distance,
    match_each,
    match_joint,
)
from dt_highway.perception.tracking import BoxTracker


def make_detector(cfg: DetectorConfig, rng: np.random.Generator | None = None) -> Detector | SimulatedDetector:
    """The detector described by a ``detector`` config section.

    :param cfg: :class:`~dt_highway.config.DetectorConfig`
    :param rng: its random generator (the simulated detector's errors)
    :return: a :class:`SimulatedDetector` or a
        :class:`~dt_highway.perception.learned.detector.LearnedDetector`
    :raises ConfigError: if the learned detector's weights file is missing or cannot be read
    """
    if cfg.kind == "learned":
        from dt_highway.perception.learned.weights import SHIPPED  # lazy: imports torch (~1 s), for the learned detector only

        path = Path(cfg.weights) if cfg.weights else SHIPPED
        stamp = path.stat().st_mtime_ns if path.is_file() else 0
        try:
            return _learned(str(path.resolve()), stamp, cfg.min_score, cfg.scale)
        except (FileNotFoundError, ValueError) as exc:
            raise ConfigError(f"detector.weights: {exc}") from None
    fields = cfg.model_dump(exclude={"kind", "weights", "min_score", "scale"})
    return SimulatedDetector(SimulatedDetectorSettings(**fields), rng)


@functools.lru_cache(maxsize=4)
def _learned(weights: str, stamp: int, min_score: float, scale: str) -> Detector:
    # one network per weights file (and version of it) and process: episodes and envs
    # share it (it has no state)
    from dt_highway.perception.learned.detector import LearnedDetector  # lazy: imports torch (~1 s)

    return LearnedDetector(weights, min_score, scale=scale)


def fusion_settings(cfg: FusionConfig, method: str | None = None) -> FusionSettings:
    """Fusion settings from a ``fusion`` config section, optionally with another method.

    :param cfg: :class:`~dt_highway.config.FusionConfig`
    :param method: overrides ``cfg.method``
    :return: the settings for :class:`~dt_highway.perception.fusion.Fusion`
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
    "run_detector",
    "sample_regions",
]

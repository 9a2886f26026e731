"""``dt-highway-v0``: the env (core loop), its ADAS pipeline, observations and actions."""

from dt_highway.env.core import ENV_ID, DTHighwayEnv, make_camera
from dt_highway.env.observations import (
    CameraObservation,
    OverlayKinematics,
    TwinTaggedKinematics,
)

__all__ = ["ENV_ID", "CameraObservation", "DTHighwayEnv", "OverlayKinematics", "TwinTaggedKinematics", "make_camera"]

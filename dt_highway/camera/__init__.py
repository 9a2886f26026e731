"""The ego's synthetic camera: the pinhole model (paper Eq. 1-3) and the RGB + depth renderer."""

from dt_highway.camera.pinhole import Intrinsics, Mount, PinholeCamera, Pose, Projection
from dt_highway.camera.render import (
    CameraFrame,
    CameraRenderer,
    RenderSettings,
    VehicleTruth,
    depth_to_uint8,
)
from dt_highway.camera.scene import LaneLine, RoadScene, VehicleSet

__all__ = [
    "CameraFrame",
    "CameraRenderer",
    "Intrinsics",
    "LaneLine",
    "Mount",
    "PinholeCamera",
    "Pose",
    "Projection",
    "RenderSettings",
    "RoadScene",
    "VehicleSet",
    "VehicleTruth",
    "depth_to_uint8",
]

"""The ego's synthetic camera: the pinhole model (paper Eq. 1-3), the RGB + depth renderer, and
its ground truth, kept apart in :mod:`~dt_highway.camera.truth` (evaluation and sensor models
only: import it from there)."""

from dt_highway.camera.pinhole import Intrinsics, Mount, PinholeCamera, Pose, Projection
from dt_highway.camera.render import CameraImage, CameraRenderer, RenderSettings, depth_to_uint8
from dt_highway.camera.scene import LaneLine, RoadScene, VehicleSet

__all__ = [
    "CameraImage",
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
    "depth_to_uint8",
]

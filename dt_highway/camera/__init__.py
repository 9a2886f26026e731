"""The ego's synthetic camera: the pinhole model (paper Eq. 1-3); the renderer follows."""

from dt_highway.camera.pinhole import Intrinsics, Mount, PinholeCamera, Pose, Projection

__all__ = ["Intrinsics", "Mount", "PinholeCamera", "Pose", "Projection"]

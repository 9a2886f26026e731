"""``dt-highway-v0``: the env (core loop), its ADAS pipeline, observations and actions, and the
driver's seat (what a driver is given: :mod:`~dt_highway.env.senses`, :class:`DriverSeat`)."""

from dt_highway import ENV_ID
from dt_highway.env.core import DTHighwayEnv, make_camera
from dt_highway.env.observations import (
    CameraObservation,
    OverlayKinematics,
    ResizedCamera,
    TwinTaggedKinematics,
)
from dt_highway.env.seat import DriverSeat

__all__ = ["ENV_ID", "CameraObservation", "DTHighwayEnv", "DriverSeat", "OverlayKinematics", "ResizedCamera",
           "TwinTaggedKinematics", "make_camera"]

"""The camera's ground truth: which vehicle each pixel shows, and each drawn vehicle's boxes.

The renderer (:class:`~dt_highway.camera.render.CameraRenderer`) makes it beside the image,
from the simulator's state. It is for evaluation (target identification, detector AP, frame
export), training labels and the simulated detector's sensor model only: never for the
fusion, the overlay, or what a driver is given (``tests/test_wall.py`` checks that the
drivers and the keyboard window do not import it).

Boxes are ``(x1, y1, x2, y2)`` [px] in the image frame of :mod:`dt_highway.camera.render`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class VehicleTruth:
    """Ground truth of one vehicle the camera draws.

    :param vehicle_id: the vehicle's stable id (its value in the instance map)
    :param visible_box: tight ``(x1, y1, x2, y2)`` box of its visible pixels [px], ``None``
        when it is fully hidden
    :param amodal_box: box of its whole projected shape, occluders ignored, not clipped to
        the image [px]
    :param visibility: visible pixels / pixels of its unoccluded shape inside the image [-]
    :param visible_px: number of visible pixels [px]
    :param amodal_px: number of pixels of its unoccluded shape inside the image [px]
    :param depth_m: planar depth of its centre (at half height) [m]
    :param range_m: Euclidean distance of its centre from the camera centre [m]
    :param truncated: its shape crosses the image border
    """

    vehicle_id: int
    visible_box: tuple[float, float, float, float] | None
    amodal_box: tuple[float, float, float, float]
    visibility: float
    visible_px: int
    amodal_px: int
    depth_m: float
    range_m: float
    truncated: bool

    def to_dict(self) -> dict:
        """A JSON-ready dict.

        :return: the fields by name
        """
        return dict(self.__dict__)


@dataclass(frozen=True)
class CameraTruth:
    """The ground truth of one rendered frame.

    :param instance: ``int32 (H, W)`` vehicle id per pixel, 0 = background (road, sky)
    :param vehicles: ground truth per drawn vehicle, keyed by vehicle id
    """

    instance: np.ndarray
    vehicles: dict[int, VehicleTruth]

"""The cloud digital twin: uplink (GNSS fixes), store, tagger, cloud and downlink."""

from dt_highway.twin.cloud import CloudTwin, Downlink, TwinVehicleView, TwinView
from dt_highway.twin.store import FixStore
from dt_highway.twin.tagger import (
    DriverRecord,
    HighwayMap,
    LaneChange,
    Tagger,
    posterior_aggressive,
)
from dt_highway.twin.uplink import GnssFix, Uplink, VehicleState

__all__ = [
    "CloudTwin", "Downlink", "TwinVehicleView", "TwinView", "FixStore", "DriverRecord", "HighwayMap",
    "LaneChange", "Tagger", "posterior_aggressive", "GnssFix", "Uplink", "VehicleState",
]

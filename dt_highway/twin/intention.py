"""Lane-change intention in the cloud twin: P(a vehicle changes lane within H s, and into which lane).

The twin estimates, for every connected vehicle, from what the cloud has received only (GNSS
fix histories, its picture of the neighbours built from their fixes, the driver-type
posterior), the probability that the vehicle changes lane within each horizon ``H`` and the
lane it moves to. The downlink carries the estimates beside the tag
(:attr:`~dt_highway.twin.cloud.TwinVehicleView.intents`); the threat overlay reads them.

This module holds the message type (the contract between twin, downlink, overlay and
evaluation). The model that fills it is built in this module too (issue 19, in progress).
"""

from __future__ import annotations

from dataclasses import dataclass

NO_LANE = -1
"""``target_lane`` when no lane change is predicted"""


@dataclass(frozen=True)
class LaneChangeIntent:
    """The twin's estimate that a vehicle changes lane within a horizon.

    :param horizon_s: the horizon ``H`` [s]
    :param p_change: probability that the vehicle's lane changes within ``H`` [-]
    :param target_lane: the most likely lane it moves to (the lane id, ``lane_index[2]`` of the
        twin's map), :data:`NO_LANE` when neither neighbouring lane is more likely than staying
    :param p_target: probability that it is in ``target_lane`` within ``H`` [-] (0 with :data:`NO_LANE`)
    """

    horizon_s: float
    p_change: float
    target_lane: int = NO_LANE
    p_target: float = 0.0

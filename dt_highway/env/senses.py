"""What a person at the wheel perceives: the one sanctioned read of the simulator's geometry.

A driver sees the cars around it (where they are, how fast they go; never who drives them),
a car drifting into its lane, and, in the ADAS condition, the overlay's markers on the camera
image, on whichever car the marker's box sits. These are read here from the simulator, the
way eyes would read them, and nowhere else; :func:`perceive` puts what a driver asked for
(its :class:`~dt_highway.drivers.perception.SenseRequest`) into the typed
:class:`~dt_highway.drivers.perception.Perception` it acts on. Drivers get what this module
gives them, never the env, its ``info`` or a truth object, and no array of the env's: the
camera image and a policy's observation are handed out as read-only copies (a driver that
writes into them gets ``ValueError``, and could not reach the env's frame even by making
them writeable again).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from dt_highway.drivers.perception import Mark, OwnState, Perception, Seen, SenseRequest, Surroundings
from dt_highway.perception.detect import iou

if TYPE_CHECKING:
    from dt_highway.env.core import DTHighwayEnv

ENTERING_RANGE_M = 80.0
"""How far ahead a car entering the ego's lane is looked for [m]"""


def look_around(env: DTHighwayEnv, range_m: float = 150.0) -> Surroundings:
    """The nearest vehicles ahead and behind in the ego's lane and the lanes beside it.

    :param env: the dt-highway env (unwrapped)
    :param range_m: how far the driver looks [m]
    :return: the nearest car ahead and behind per lane (-1 left, 0 own, +1 right), and where each car in range is
    """
    ego = env.vehicle
    ex = float(ego.position[0])
    lane = int(ego.lane_index[2])
    n_lanes = len(env.road.network.graph[ego.lane_index[0]][ego.lane_index[1]])
    ahead = {k: Seen() for k in (-1, 0, 1)}
    behind = {k: Seen() for k in (-1, 0, 1)}
    x_of: dict[int, tuple[float, int]] = {}
    for v in env.road.vehicles:
        if v is ego or not v.lane_index:
            continue
        dx = float(v.position[0]) - ex
        if abs(dx) > range_m:
            continue
        off = int(v.lane_index[2]) - lane
        vid = int(getattr(v, "dt_id", -1))
        x_of[vid] = (dx, off)
        if off not in ahead:
            continue
        gap = abs(dx) - (v.LENGTH + ego.LENGTH) / 2
        if dx > 0 and gap < ahead[off].gap_m:
            ahead[off] = Seen(vid, gap, float(v.speed))
        elif dx <= 0 and gap < behind[off].gap_m:
            behind[off] = Seen(vid, gap, float(v.speed))
    return Surroundings(float(env.sim_time_s), float(ego.speed), lane, n_lanes, ahead, behind, x_of)


def marked_vehicles(env: DTHighwayEnv, info: dict[str, Any], min_iou: float = 0.3) -> set[int]:
    """The cars the overlay marks, as a person looking at the screen sees them: for each
    overlay box, the vehicle whose visible outline in the camera image fits it best.

    :param env: the env (unwrapped), for the camera frame the overlay was drawn on
    :param info: the step's info (``info["adas"]["overlay"]``)
    :param min_iou: least overlap between marker and outline to see the marker on that car
    :return: ids of the vehicles the driver takes for marked
    """
    adas = info.get("adas")
    return cars_under_marks(env, adas.get("overlay") if adas else None, min_iou)


def cars_under_marks(env: DTHighwayEnv, overlay: Sequence[Mapping[str, Any]] | None, min_iou: float = 0.3) -> set[int]:
    """For each overlay item, the vehicle whose visible outline in this step's camera image
    fits the item's box best (IoU >= ``min_iou``): which car a person sees the marker on,
    right or wrong.

    :param env: the env (unwrapped), for the camera image the overlay was drawn on (its
        outlines are read from the image's ground truth, as eyes read a picture)
    :param overlay: the overlay items (``box`` [px]); ``None`` or empty: nothing marked
    :param min_iou: least overlap between marker and outline [-]
    :return: ids of the vehicles under a marker
    """
    if not overlay:
        return set()
    seen = [(vid, t.visible_box) for vid, t in env.camera_truth().vehicles.items() if t.visible_box is not None]
    if not seen:
        return set()
    outlines = np.array([b for _, b in seen], dtype=float)
    marked = set()
    for item in overlay:
        fit = iou(np.asarray(item["box"], dtype=float)[None], outlines)[0]
        j = int(np.argmax(fit))
        if fit[j] >= min_iou:
            marked.add(int(seen[j][0]))
    return marked


def cars_entering(env: DTHighwayEnv, range_m: float = ENTERING_RANGE_M) -> Seen | None:
    """The nearest car ahead whose body already reaches into the ego's lane, its centre in
    that lane or still in the next one (a car changing into the lane, as a driver sees it
    drift in).

    :param env: the dt-highway env (unwrapped)
    :param range_m: how far ahead the driver looks for it [m]
    :return: the car (bumper gap [m], speed [m/s]), or ``None``
    """
    ego = env.vehicle
    lane = env.road.network.get_lane(ego.lane_index)
    ex = float(ego.position[0])
    centre_y = float(lane.position(ex, 0.0)[1])
    best: Seen | None = None
    for v in env.road.vehicles:
        if v is ego:
            continue
        dx = float(v.position[0]) - ex
        if not 0.0 < dx < range_m:
            continue
        if abs(float(v.position[1]) - centre_y) >= lane.width_at(0.0) / 2 + v.WIDTH / 2:
            continue  # not in the lane, not even in part
        gap = dx - (v.LENGTH + ego.LENGTH) / 2
        if best is None or gap < best.gap_m:
            best = Seen(int(getattr(v, "dt_id", -1)), gap, float(v.speed))
    return best


def own_state(env: DTHighwayEnv) -> OwnState:
    """The ego's own state, as its driver knows it (speedometer, lane, a crash).

    :param env: the dt-highway env (unwrapped)
    :return: speed [m/s], heading [rad], lane (-1 off the road), lane count and whether it crashed
    """
    ego = env.vehicle
    lane_index = ego.lane_index
    n_lanes = len(env.road.network.graph[lane_index[0]][lane_index[1]]) if lane_index else 0
    return OwnState(float(ego.speed), float(ego.heading), int(lane_index[2]) if lane_index else -1, n_lanes,
                    bool(ego.crashed))


def _mark(item: Mapping[str, Any]) -> Mark:
    """An overlay item as it is drawn: its box and label, and the numbers printed beside it."""
    x1, y1, x2, y2 = (float(v) for v in item["box"])
    conf, dist = item.get("confidence"), item.get("distance_m")
    return Mark((x1, y1, x2, y2), str(item.get("label", "")), None if conf is None else float(conf),
                None if dist is None else float(dist))


def _read_only(a: np.ndarray) -> np.ndarray:
    """A copy of ``a`` that cannot be written (a driver's copy: it shares no memory with the env)."""
    out = np.array(a, copy=True)
    out.flags.writeable = False
    return out


def _driver_observation(observation: np.ndarray | Mapping[str, np.ndarray] | None
                        ) -> np.ndarray | dict[str, np.ndarray] | None:
    """A policy's observation as its driver is given it: read-only copies of its arrays."""
    if observation is None:
        return None
    if isinstance(observation, Mapping):
        return {str(k): _read_only(np.asarray(v)) for k, v in observation.items()}
    return _read_only(np.asarray(observation))


def perceive(env: DTHighwayEnv, request: SenseRequest, observation: np.ndarray | Mapping[str, np.ndarray] | None = None,
             overlay: Sequence[Mapping[str, Any]] | None = None) -> Perception:
    """What a driver perceives now, for what it asked: the one place a
    :class:`~dt_highway.drivers.perception.Perception` is made from the env.

    :param env: the dt-highway env (unwrapped)
    :param request: what the driver looks at
    :param observation: a policy's observation of this step (made by its
        :class:`~dt_highway.env.seat.DriverSeat`), passed on as read-only copies
    :param overlay: the overlay items to see instead of this step's ADAS output (tests,
        replays); ``None``: the env's own (none in the baseline condition)
    :return: the perception (only the requested parts filled; its arrays are read-only copies)
    """
    marks: tuple[Mark, ...] = ()
    under: frozenset[int] = frozenset()
    if request.marks:
        if overlay is None:
            adas = env.adas_output()
            overlay = adas.get("overlay") if adas else None
        marks = tuple(_mark(item) for item in overlay or ())
        under = frozenset(cars_under_marks(env, overlay))
    return Perception(
        time_s=float(env.sim_time_s),
        own=own_state(env),
        surroundings=look_around(env) if request.surroundings else None,
        entering=cars_entering(env) if request.entering else None,
        marks=marks,
        cars_under_marks=under,
        image=env.camera_image().read_only_copy() if request.image and env.camera is not None else None,
        observation=_driver_observation(observation),
    )

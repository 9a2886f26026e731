"""What a person at the wheel perceives: the one sanctioned read of the simulator's geometry.

A driver sees the cars around it (where they are, how fast they go; never who drives them)
and, in the ADAS condition, the overlay's markers on the camera image, on whichever car the
marker's box sits. Both are read here from the simulator, the way eyes would read them, and
nowhere else: drivers get what this module gives them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from dt_highway.perception.detect import iou


@dataclass(frozen=True)
class Seen:
    """A neighbour as the driver sees it: ``gap_m`` bumper to bumper (inf: nobody), its speed."""

    vehicle_id: int = -1
    gap_m: float = math.inf
    speed_mps: float = 0.0


@dataclass(frozen=True)
class Surroundings:
    """What the driver sees around it at one moment.

    :param t_s: time [s]
    :param speed_mps: own speed [m/s]
    :param lane: own lane index
    :param n_lanes: lanes on the road
    :param ahead: nearest vehicle ahead per lane offset (-1 left, 0 own, +1 right)
    :param behind: nearest vehicle behind per lane offset
    :param x_of: longitudinal offset of every vehicle nearby [m] and its lane offset, by id
    """

    t_s: float
    speed_mps: float
    lane: int
    n_lanes: int
    ahead: dict[int, Seen]
    behind: dict[int, Seen]
    x_of: dict[int, tuple[float, int]]


def look_around(env: Any, range_m: float = 150.0) -> Surroundings:
    """The nearest vehicles ahead and behind in the ego's lane and the lanes beside it.

    :param env: the dt-highway env (unwrapped)
    :param range_m: how far the driver looks [m]
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


def marked_vehicles(env: Any, info: dict[str, Any], min_iou: float = 0.3) -> set[int]:
    """The cars the overlay marks, as a person looking at the screen sees them: for each
    overlay box, the vehicle whose visible outline in the camera image fits it best.

    :param env: the env (unwrapped), for the camera frame the overlay was drawn on
    :param info: the step's info (``info["adas"]["overlay"]``)
    :param min_iou: least overlap between marker and outline to see the marker on that car
    :return: ids of the vehicles the driver takes for marked
    """
    adas = info.get("adas")
    return cars_under_marks(env, adas.get("overlay") if adas else None, min_iou)


def cars_under_marks(env: Any, overlay: list[dict[str, Any]] | None, min_iou: float = 0.3) -> set[int]:
    """For each overlay item, the vehicle whose visible outline in this step's camera image
    fits the item's box best (IoU >= ``min_iou``): which car a person sees the marker on,
    right or wrong.

    :param env: the env (unwrapped), for the camera frame the overlay was drawn on
    :param overlay: the overlay items (``box`` [px]); ``None`` or empty: nothing marked
    :param min_iou: least overlap between marker and outline [-]
    :return: ids of the vehicles under a marker
    """
    if not overlay:
        return set()
    seen = [(vid, t.visible_box) for vid, t in env.camera_frame().vehicles.items() if t.visible_box is not None]
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

"""What the camera looks at: the highway's lanes and the vehicles on it, as plain arrays.

The renderer does not read highway-env objects while it draws; these two small types are
the hand-over. :meth:`RoadScene.from_road` reads a highway-env road made of straight lanes
along ``+x`` (the highway of ``dt-highway-v0``), :meth:`VehicleSet.from_road` the vehicles.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from highway_env.road.lane import LineType, StraightLane
from highway_env.road.road import Road

from dt_highway.world.traffic import vehicle_id


@dataclass(frozen=True)
class LaneLine:
    """A painted line along the road.

    :param y_m: lateral position of the line's centre [m]
    :param dashed: dashed (lane divider) or solid (road edge)
    """

    y_m: float
    dashed: bool


@dataclass(frozen=True)
class RoadScene:
    """A straight multi-lane road along ``+x``.

    :param y_min_m: lateral position of the road's left edge (lowest ``y``) [m]
    :param y_max_m: lateral position of the road's right edge [m]
    :param x_start_m: where the road starts [m]
    :param x_end_m: where the road ends [m]
    :param lines: painted lines (dashed dividers, solid edges)
    """

    y_min_m: float
    y_max_m: float
    x_start_m: float
    x_end_m: float
    lines: tuple[LaneLine, ...]

    @classmethod
    def from_road(cls, road: Road) -> RoadScene:
        """Read the lanes of a highway-env road.

        :param road: a highway-env road of straight lanes along ``+x``
        :return: its extent and painted lines
        :raises ValueError: if a lane is not a straight lane along ``+x`` (the camera draws
            straight highways only)
        """
        lanes = road.network.lanes_list()
        if not lanes:
            raise ValueError("the road has no lanes to draw")
        lines: dict[float, bool] = {}
        y_lo, y_hi, x_lo, x_hi = [], [], [], []
        for lane in lanes:
            if (not isinstance(lane, StraightLane) or abs(lane.start[1] - lane.end[1]) > 1e-9
                    or lane.end[0] <= lane.start[0]):
                raise ValueError(
                    f"the camera draws straight lanes along +x only (got {type(lane).__name__} "
                    f"from {tuple(lane.start) if hasattr(lane, 'start') else '?'})"
                )
            y, half = float(lane.start[1]), float(lane.width) / 2.0
            y_lo.append(y - half)
            y_hi.append(y + half)
            x_lo.append(float(lane.start[0]))
            x_hi.append(float(lane.end[0]))
            for side, kind in zip((-1.0, 1.0), lane.line_types, strict=False):  # highway-env: two line types
                if kind == LineType.NONE:
                    continue
                key = round(y + side * half, 6)
                dashed = kind == LineType.STRIPED
                # a solid line wins where two lanes disagree about a shared edge
                lines[key] = lines.get(key, True) and dashed
        return cls(
            y_min_m=min(y_lo),
            y_max_m=max(y_hi),
            x_start_m=min(x_lo),
            x_end_m=max(x_hi),
            lines=tuple(LaneLine(y, d) for y, d in sorted(lines.items())),
        )


@dataclass(frozen=True)
class VehicleSet:
    """Vehicles to draw, one row each.

    :param ids: stable vehicle ids (never 0, the background of the instance map) ``(N,)``
    :param x_m: centre position along the road ``(N,)`` [m]
    :param y_m: centre lateral position ``(N,)`` [m]
    :param heading_rad: heading ``(N,)`` [rad]
    :param length_m: length ``(N,)`` [m]
    :param width_m: width ``(N,)`` [m]
    """

    ids: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    heading_rad: np.ndarray
    length_m: np.ndarray
    width_m: np.ndarray

    def __len__(self) -> int:
        return len(self.ids)

    @classmethod
    def from_road(cls, road: Road, exclude: object | None = None) -> VehicleSet:
        """The vehicles of a road, without ``exclude`` (the ego carrying the camera).

        :param road: the highway-env road
        :param exclude: a vehicle to leave out (the ego), or ``None``
        :return: one row per remaining vehicle, with its highway-env ``LENGTH`` and ``WIDTH``
        """
        vs = [v for v in road.vehicles if v is not exclude]
        if not vs:
            return cls.empty()
        return cls(
            ids=np.array([vehicle_id(v) for v in vs], dtype=np.int32),
            x_m=np.array([v.position[0] for v in vs], dtype=float),
            y_m=np.array([v.position[1] for v in vs], dtype=float),
            heading_rad=np.array([v.heading for v in vs], dtype=float),
            length_m=np.array([v.LENGTH for v in vs], dtype=float),
            width_m=np.array([v.WIDTH for v in vs], dtype=float),
        )

    @classmethod
    def empty(cls) -> VehicleSet:
        """No vehicles.

        :return: a set of zero rows
        """
        z = np.zeros(0)
        return cls(np.zeros(0, dtype=np.int32), z, z, z, z, z)

    @classmethod
    def of(
        cls,
        rows: list[tuple[int, float, float]] | list[tuple[int, float, float, float]],
        length_m: float = 5.0,
        width_m: float = 2.0,
    ) -> VehicleSet:
        """Build a set from ``(id, x, y[, heading])`` rows with one size (tests, examples).

        :param rows: ``(id, x [m], y [m])`` or ``(id, x [m], y [m], heading [rad])`` per vehicle (heading 0 if left out)
        :param length_m: every vehicle's length [m]
        :param width_m: every vehicle's width [m]
        :return: one row per vehicle
        """
        if not rows:
            return cls.empty()
        arr = np.array([list(r) + [0.0] * (4 - len(r)) for r in rows], dtype=float)
        n = len(arr)
        return cls(
            arr[:, 0].astype(np.int32), arr[:, 1], arr[:, 2], arr[:, 3], np.full(n, length_m), np.full(n, width_m)
        )

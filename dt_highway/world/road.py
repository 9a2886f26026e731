"""A faster highway-env road for our env: the same results, without the all-pairs loops.

highway-env's :class:`~highway_env.road.road.Road` finds a vehicle's leader and follower by
computing every other vehicle's lane coordinates in Python (``neighbour_vehicles``, called
several times per vehicle and step by IDM and MOBIL), and checks collisions for every pair
of vehicles (``step``). With 50 vehicles those two loops are most of a simulation step.
:class:`FastRoad` keeps highway-env's rules and replaces the loops:

* ``neighbour_vehicles`` on a straight lane computes all vehicles' lane coordinates at once
  (numpy; the positions are gathered once per ``act`` phase, in which nobody moves) and
  picks the same leader and follower, ties included (highway-env keeps the last
  of equal fronts and the first of equal rears in ``vehicles + objects`` order). On our
  straight road the lane directions are axis-aligned, so the coordinates are the very same
  floats as highway-env's. Curved lanes and connected-lane searches use highway-env's code.
* the closest lane of each vehicle after each step (:class:`FastRoadNetwork`) is found for
  all straight lanes at once, with highway-env's distance and tie rule.
* ``step`` moves the vehicles as highway-env does, then runs highway-env's own collision
  check only for the pairs two cheap tests cannot rule out, in highway-env's pair order. The
  broad phase is highway-env's own early exit (distance between centres against the half
  diagonals plus the caller's travel in the step), computed for all pairs at once; the
  narrow phase is the separating-axis test of the two rectangles on floats
  (:func:`~dt_highway.world.vehicle.surely_apart`). Both keep a 1e-6 m margin: a pair they
  skip is one whose check would return "no contact" with no side effect.

Only our env uses it (highway-env's classes are not patched).
"""

from __future__ import annotations

import bisect
import math
from typing import TYPE_CHECKING, Any

import numpy as np
from highway_env.road.lane import AbstractLane, StraightLane
from highway_env.road.road import LaneIndex, Road, RoadNetwork
from highway_env.vehicle.objects import Landmark

from dt_highway.world.vehicle import longitudinal, surely_apart

if TYPE_CHECKING:
    from highway_env.vehicle.kinematics import Vehicle
    from highway_env.vehicle.objects import RoadObject

_LaneRow = tuple[LaneIndex, float, float, float, float, float, float, float, float]
"""A straight lane's index, start x, y, direction x, y, lateral direction x, y, length [m] and heading [rad]"""
_LaneOrder = tuple[list[float], list[int]]
"""Items on a lane: their longitudinal positions [m], sorted, and their indexes"""
_SearchIndex = tuple[list["RoadObject"], np.ndarray, dict[int, int], dict[LaneIndex, _LaneOrder]]
"""Searchable objects, their positions ``(N, 2)`` [m], index by ``id``, per-lane orders"""

BROAD_PHASE_MARGIN_M = 1e-6
"""Extra distance the collision broad phase keeps pairs for [m]: our distances may differ from
``np.linalg.norm``'s in the last bits, so pairs within this of the threshold get the full check"""


_SEARCHABLE: dict[type, bool] = {}


def _searchable(cls: type) -> bool:
    """Whether objects of this class take part in neighbour searches (not landmarks), per
    class once: ``isinstance`` on highway-env's abstract classes is slow in a hot loop."""
    ok = _SEARCHABLE.get(cls)
    if ok is None:
        ok = _SEARCHABLE[cls] = not issubclass(cls, Landmark)
    return ok


class FastRoadNetwork(RoadNetwork):
    """highway-env's road network with a faster ``get_closest_lane_index`` for axis-aligned straight lanes.

    highway-env calls it for every vehicle after every step (``Vehicle.on_state_update``),
    and each lane's ``distance_with_heading`` goes through numpy on two-element arrays. Here
    each lane's start, direction, length and heading are read once, and the same weighted
    distance (``abs(lateral) + beyond either end + abs(wrapped heading difference)``, summed
    in highway-env's order) is computed with plain floats; the first smallest wins, as with
    ``np.argmin`` over highway-env's list. With axis-aligned lanes the lane coordinates are
    exact (products with 0 and 1), so every value is highway-env's, bit for bit. Networks
    with other lanes use highway-env's loop. Lanes must be added with ``add_lane``.
    """

    _lanes: list[_LaneRow] | None = None

    @classmethod
    def of(cls, network: RoadNetwork) -> FastRoadNetwork:
        """The same network (the same graph object) with the fast lookup.

        :param network: a highway-env road network
        :return: a network sharing ``network``'s graph
        """
        fast = cls()
        fast.graph = network.graph
        return fast

    def add_lane(self, _from: str, _to: str, lane: AbstractLane) -> None:
        """Add a lane (highway-env's), and forget the lane table.

        :param _from: the node where the lane starts
        :param _to: the node where the lane ends
        :param lane: the lane geometry
        """
        super().add_lane(_from, _to, lane)
        self._lanes = None

    def _lane_table(self) -> list[_LaneRow]:
        rows: list[_LaneRow] = []
        for _from, to_dict in self.graph.items():
            for _to, lanes in to_dict.items():
                for _id, lane in enumerate(lanes):
                    axis_aligned = (
                        all(float(c) in (-1.0, 0.0, 1.0) for c in (*lane.direction, *lane.direction_lateral))
                        if type(lane) is StraightLane else False
                    )
                    if not axis_aligned:
                        return []
                    rows.append(((_from, _to, _id), float(lane.start[0]), float(lane.start[1]),
                                 float(lane.direction[0]), float(lane.direction[1]), float(lane.direction_lateral[0]),
                                 float(lane.direction_lateral[1]), float(lane.length), float(lane.heading)))
        return rows

    def get_closest_lane_index(self, position: np.ndarray, heading: float | None = None) -> LaneIndex:
        """The lane closest to a position (and heading), as highway-env finds it.

        :param position: the position ``(x, y)`` [m]
        :param heading: the heading [rad] (``None``: by distance alone)
        :return: the closest lane's index ``(from, to, id)``
        """
        if self._lanes is None:
            self._lanes = self._lane_table()
        if not self._lanes:
            return super().get_closest_lane_index(position, heading)
        px, py = position.tolist() if type(position) is np.ndarray else (float(position[0]), float(position[1]))
        best, best_index = math.inf, None
        pi, two_pi = math.pi, 2 * math.pi
        for index, sx, sy, dx, dy, lx, ly, length, lane_heading in self._lanes:
            d0, d1 = px - sx, py - sy
            s = d0 * dx + d1 * dy
            r = d0 * lx + d1 * ly
            beyond, before = s - length, 0 - s
            # highway-env's abs(r) + max(s - length, 0) + max(0 - s, 0) [+ 1.0 * angle with a heading]
            # (``0 if x < 0 else x`` is max(x, 0), NaN and -0.0 included)
            dist = abs(r) + (0 if beyond < 0 else beyond) + (0 if before < 0 else before)
            if heading is not None:
                dist = dist + 1.0 * abs(((heading - lane_heading + pi) % two_pi) - pi)
            if dist < best or best_index is None:  # the first smallest, as np.argmin
                best, best_index = dist, index
        return best_index


class FastRoad(Road):
    """highway-env's road with vectorised neighbour search and a collision broad phase.

    :param args: highway-env's ``Road`` arguments, by position (``network, vehicles, road_objects, np_random,
        record_history``)
    :param kwargs: the same by name (and ``neighbour_vehicles_connected_lanes``)
    """

    _in_act = False
    _index: _SearchIndex | None = None
    network: RoadNetwork

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        """highway-env's ``Road(network, vehicles, road_objects, np_random, record_history)``; a plain
        :class:`RoadNetwork` is given the fast lane lookup (:class:`FastRoadNetwork`)."""
        super().__init__(*args, **kwargs)
        if type(self.network) is RoadNetwork:
            self.network = FastRoadNetwork.of(self.network)

    def act(self) -> None:
        """Decide every vehicle's action (highway-env's loop). Deciding moves nobody, so the
        searchable vehicles and their positions are gathered once for all the searches of
        this phase, not once per search."""
        self._in_act, self._index = True, None
        try:
            super().act()
        finally:
            self._in_act, self._index = False, None

    def _searchables(self) -> _SearchIndex:
        """The vehicles and objects searches consider, their positions ``(N, 2)`` [m], index by
        ``id``, and the per-lane sorted indexes (filled lazily by :meth:`_lane_order`)."""
        if self._index is not None:
            return self._index
        items = [v for v in self.vehicles + self.objects if _searchable(type(v))]
        pos = np.array([v.position for v in items], dtype=float).reshape(-1, 2)
        index: _SearchIndex = (items, pos, {id(v): i for i, v in enumerate(items)}, {})
        if self._in_act:
            self._index = index
        return index

    @staticmethod
    def _lane_order(lane: StraightLane, pos: np.ndarray) -> _LaneOrder:
        """The items on a lane (highway-env's ``on_lane`` with a 1 m margin), sorted by
        longitudinal position, ties by their order in ``vehicles + objects``."""
        d = pos - lane.start
        long = d[:, 0] * lane.direction[0] + d[:, 1] * lane.direction[1]
        lat = d[:, 0] * lane.direction_lateral[0] + d[:, 1] * lane.direction_lateral[1]
        on = (
            (np.abs(lat) <= lane.width / 2 + 1)
            & (-lane.VEHICLE_LENGTH <= long)
            & (long < lane.length + lane.VEHICLE_LENGTH)
        )
        idx = np.flatnonzero(on)
        order = idx[np.lexsort((idx, long[idx]))]
        return long[order].tolist(), order.tolist()

    def neighbour_vehicles(
        self, vehicle: Vehicle, lane_index: LaneIndex | None = None
    ) -> tuple[RoadObject | None, RoadObject | None]:
        """The preceding and following vehicles of ``vehicle`` on a lane, as highway-env finds them.

        A per-lane index sorted by longitudinal position answers it by bisection: the
        leader is the nearest item at or ahead of the vehicle (the last of equals, as
        highway-env's ``<=`` keeps it), the follower the nearest behind (the first of equals).

        :param vehicle: the vehicle whose neighbours are searched
        :param lane_index: the lane searched (``None``: the vehicle's own)
        :return: ``(leader, follower)``, each ``None`` when there is none
        """
        lane_index = lane_index or vehicle.lane_index
        if not lane_index:
            return None, None
        lane = self.network.get_lane(lane_index)
        if self.neighbour_vehicles_connected_lanes or type(lane) is not StraightLane:
            return super().neighbour_vehicles(vehicle, lane_index)
        items, pos, index, lanes = self._searchables()
        if not items:
            return None, None
        table = lanes.get(lane_index)
        if table is None:
            table = lanes[lane_index] = self._lane_order(lane, pos)
        longs, order = table
        s = longitudinal(lane, *vehicle.position.tolist())  # the arithmetic of the table above
        if s != s:  # NaN: highway-env's comparisons all fail, so it finds nobody
            return None, None
        me = index.get(id(vehicle), -1)
        n = len(longs)
        k = bisect.bisect_left(longs, s)
        v_front = v_rear = None
        i = k
        while i < n and order[i] == me:
            i += 1
        if i < n:
            best, last = longs[i], order[i]
            i += 1
            while i < n and longs[i] == best:
                if order[i] != me:
                    last = order[i]  # sorted by index within equals: the last is the largest
                i += 1
            v_front = items[last]
        i = k - 1
        while i >= 0 and order[i] == me:
            i -= 1
        if i >= 0:
            best, first = longs[i], order[i]
            i -= 1
            while i >= 0 and longs[i] == best:
                if order[i] != me:
                    first = order[i]
                i -= 1
            v_rear = items[first]
        return v_front, v_rear

    @staticmethod
    def close_pairs(items: list[RoadObject], dt: float) -> np.ndarray:
        """Which pairs may touch in a step: ``(N, N)`` bool, row = the vehicle that checks.

        highway-env's own early exit (``RoadObject._is_colliding``), for all pairs at once:
        no contact when the centres are farther apart than the half diagonals plus the
        checking vehicle's travel in the step [m], plus :data:`BROAD_PHASE_MARGIN_M`.

        :param items: the vehicles and objects (``vehicles + objects``)
        :param dt: the simulation step [s]
        :return: ``(N, N)`` bool, ``True`` where the pair may touch
        """
        pos = np.array([o.position for o in items], dtype=float).reshape(-1, 2)
        half_diag = np.array([o.diagonal / 2 for o in items])
        travel = np.array([float(getattr(o, "speed", 0.0)) * dt for o in items])
        dist = np.hypot(pos[:, None, 0] - pos[None, :, 0], pos[:, None, 1] - pos[None, :, 1])
        return dist <= half_diag[:, None] + half_diag[None, :] + travel[:, None] + BROAD_PHASE_MARGIN_M

    def step(self, dt: float) -> None:
        """Move every vehicle, then handle the collisions of the pairs that may touch.

        :param dt: the simulation step [s]
        """
        for vehicle in self.vehicles:
            vehicle.step(dt)
        items = self.vehicles + self.objects
        n_veh = len(self.vehicles)
        if len(items) < 2 or n_veh == 0:
            return
        close = np.triu(self.close_pairs(items, dt)[:n_veh], 1)
        # highway-env's order: each vehicle with the vehicles after it, then with the objects
        # (row-major order of the pairs i < j)
        rows, cols = close.nonzero()
        for i, j in zip(rows.tolist(), cols.tolist(), strict=True):
            vehicle, other = items[i], items[j]
            if not surely_apart(vehicle, other, dt, BROAD_PHASE_MARGIN_M):
                vehicle.handle_collisions(other, dt)

"""The cloud's per-vehicle GNSS history, bounded by a time window.

Fixes may arrive out of order (latency jitter); each history is kept sorted by the time
the fix was taken. Only the last ``window_s`` seconds (relative to the newest fix of that
vehicle) are kept, so memory stays flat however long the twin runs.
"""

from __future__ import annotations

import bisect
from collections.abc import Iterable

import numpy as np

from dt_highway.twin.uplink import GnssFix


class FixStore:
    """Per-vehicle fix histories.

    :param window_s: history kept per vehicle [s]
    """

    def __init__(self, window_s: float) -> None:
        if window_s <= 0:
            raise ValueError(f"window_s must be > 0 (got {window_s})")
        self.window_s = window_s
        self._times: dict[int, list[float]] = {}
        self._fixes: dict[int, list[GnssFix]] = {}
        self._rows: dict[int, list[tuple[float, float, float, float, float]]] = {}
        self._arrays: dict[int, np.ndarray] = {}  # history() per vehicle until its next change

    def add(self, fixes: Iterable[GnssFix]) -> set[int]:
        """Insert fixes; :return: the ids of the vehicles that got new data."""
        touched: set[int] = set()
        for f in fixes:
            times = self._times.setdefault(f.vehicle_id, [])
            items = self._fixes.setdefault(f.vehicle_id, [])
            rows = self._rows.setdefault(f.vehicle_id, [])
            i = bisect.bisect_right(times, f.t_s)
            times.insert(i, f.t_s)
            items.insert(i, f)
            rows.insert(i, (f.t_s, f.x_m, f.y_m, f.speed_mps, f.heading_rad))
            touched.add(f.vehicle_id)
        for vid in touched:
            self._arrays.pop(vid, None)
            self._prune(vid)
        return touched

    def _prune(self, vid: int) -> None:
        times = self._times[vid]
        cut = bisect.bisect_left(times, times[-1] - self.window_s)
        if cut:
            del times[:cut]
            del self._fixes[vid][:cut]
            del self._rows[vid][:cut]

    def drop_older_than(self, t_s: float) -> None:
        """Forget vehicles whose newest fix is older than ``t_s`` [s] (they left)."""
        for vid in [v for v, t in self._times.items() if t[-1] < t_s]:
            del self._times[vid]
            del self._fixes[vid]
            del self._rows[vid]
            self._arrays.pop(vid, None)

    def clear(self) -> None:
        """Forget every history."""
        self._times.clear()
        self._fixes.clear()
        self._rows.clear()
        self._arrays.clear()

    def __contains__(self, vehicle_id: int) -> bool:
        return vehicle_id in self._times

    def __len__(self) -> int:
        return len(self._times)

    def vehicle_ids(self) -> list[int]:
        """:return: ids with a history, sorted."""
        return sorted(self._times)

    def n_fixes(self) -> int:
        """:return: the number of fixes held in all (for memory checks)."""
        return sum(len(t) for t in self._times.values())

    def latest(self, vehicle_id: int) -> GnssFix | None:
        """:return: the newest fix of a vehicle, or ``None``."""
        items = self._fixes.get(vehicle_id)
        return items[-1] if items else None

    def history(self, vehicle_id: int) -> np.ndarray:
        """The history as an array of rows ``(t_s, x_m, y_m, speed_mps, heading_rad)``, oldest first.

        :return: a read-only array (kept until the vehicle's next fix: copy it to change it)
        """
        arr = self._arrays.get(vehicle_id)
        if arr is None:
            rows = self._rows.get(vehicle_id)
            if not rows:
                return np.empty((0, 5))
            arr = np.array(rows, dtype=float)
            arr.setflags(write=False)
            self._arrays[vehicle_id] = arr
        return arr

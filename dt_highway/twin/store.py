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


class _Track:
    """One vehicle's fixes: the fix objects, and their rows in a growable array.

    Rows live in ``buf[lo:hi]``. An in-order fix is written after the last row; anything
    else (an out-of-order fix, a full buffer) builds a new buffer. Rows once written are
    never changed in place, so an array handed out by :meth:`FixStore.history` (a view)
    keeps its values whatever arrives later.
    """

    __slots__ = ("times", "fixes", "buf", "lo", "hi")

    def __init__(self) -> None:
        self.times: list[float] = []
        self.fixes: list[GnssFix] = []
        self.buf = np.empty((64, 5))
        self.lo = self.hi = 0

    def insert(self, f: GnssFix) -> None:
        row = (f.t_s, f.x_m, f.y_m, f.speed_mps, f.heading_rad)
        i = bisect.bisect_right(self.times, f.t_s)
        self.times.insert(i, f.t_s)
        self.fixes.insert(i, f)
        if i == len(self.times) - 1 and self.hi < len(self.buf):
            self.buf[self.hi] = row
            self.hi += 1
            return
        rows = self.buf[self.lo:self.hi]
        new = np.empty((max(64, 2 * (len(rows) + 1)), 5))
        new[:i] = rows[:i]
        new[i] = row
        new[i + 1:len(rows) + 1] = rows[i:]
        self.buf, self.lo, self.hi = new, 0, len(rows) + 1

    def drop_first(self, n: int) -> None:
        del self.times[:n]
        del self.fixes[:n]
        self.lo += n


class FixStore:
    """Per-vehicle fix histories.

    :param window_s: history kept per vehicle [s]
    """

    def __init__(self, window_s: float) -> None:
        if window_s <= 0:
            raise ValueError(f"window_s must be > 0 (got {window_s})")
        self.window_s = window_s
        self._tracks: dict[int, _Track] = {}

    def add(self, fixes: Iterable[GnssFix]) -> set[int]:
        """Insert fixes; :return: the ids of the vehicles that got new data.

        :param fixes: the fixes that arrived (in any order)
        """
        touched: set[int] = set()
        for f in fixes:
            track = self._tracks.get(f.vehicle_id)
            if track is None:
                track = self._tracks[f.vehicle_id] = _Track()
            track.insert(f)
            touched.add(f.vehicle_id)
        for vid in touched:
            self._prune(vid)
        return touched

    def _prune(self, vid: int) -> None:
        track = self._tracks[vid]
        times = track.times
        cut = bisect.bisect_left(times, times[-1] - self.window_s)
        if cut:
            track.drop_first(cut)

    def drop_older_than(self, t_s: float) -> None:
        """Forget vehicles whose newest fix is older than ``t_s`` [s] (they left).

        :param t_s: the cut-off time [s]
        """
        for vid in [v for v, tr in self._tracks.items() if tr.times[-1] < t_s]:
            del self._tracks[vid]

    def clear(self) -> None:
        """Forget every history."""
        self._tracks.clear()

    def __contains__(self, vehicle_id: int) -> bool:
        return vehicle_id in self._tracks

    def __len__(self) -> int:
        return len(self._tracks)

    def vehicle_ids(self) -> list[int]:
        """The vehicles with a history.

        :return: ids with a history, sorted.
        """
        return sorted(self._tracks)

    def n_fixes(self) -> int:
        """The number of fixes held.

        :return: the number of fixes held in all (for memory checks).
        """
        return sum(len(tr.times) for tr in self._tracks.values())

    def latest(self, vehicle_id: int) -> GnssFix | None:
        """A vehicle's newest fix.

        :param vehicle_id: the vehicle
        :return: the newest fix of a vehicle, or ``None``.
        """
        track = self._tracks.get(vehicle_id)
        return track.fixes[-1] if track is not None and track.fixes else None

    def history(self, vehicle_id: int) -> np.ndarray:
        """The history as an array of rows ``(t_s, x_m, y_m, speed_mps, heading_rad)``, oldest first.

        :param vehicle_id: the vehicle (one without a history gets an empty ``(0, 5)`` array)
        :return: a read-only array; its values never change (later fixes go elsewhere)
        """
        track = self._tracks.get(vehicle_id)
        if track is None or track.hi == track.lo:
            return np.empty((0, 5))
        view = track.buf[track.lo:track.hi]
        view.flags.writeable = False
        return view

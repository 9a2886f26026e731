"""The cloud digital twin: receives fixes, keeps histories, tags drivers, serves views.

All times here are on the **twin clock** [s], which runs on across the episodes of one env
(the env adds an offset to its episode clock), so that a driver's evidence and tag can
outlive an episode when ``store.persist_across_episodes`` is on.
"""

from __future__ import annotations

import gc
import heapq
import itertools
import json
import math
import os
import sqlite3
import warnings
import weakref
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import IO, Any

try:
    import fcntl
except ImportError:  # not POSIX: a store file is not locked against a second env
    fcntl = None  # type: ignore[assignment]

import numpy as np

from dt_highway.config import ConfigError, DownlinkConfig, TwinConfig
from dt_highway.twin.intention import IntentionEstimator, IntentTable, LaneChangeIntent
from dt_highway.twin.store import FixStore
from dt_highway.twin.tagger import DriverRecord, HighwayMap, LaneChange, Tagger
from dt_highway.twin.uplink import GnssFix


@dataclass(frozen=True)
class TwinVehicleView:
    """The twin's view of one vehicle, as sent to the ego.

    :param vehicle_id: stable id
    :param t_fix_s: twin time the newest fix was taken [s]
    :param x_m: last known position along the road [m]
    :param y_m: last known lateral position [m]
    :param speed_mps: last known speed [m/s]
    :param heading_rad: last known heading [rad]
    :param tag: ``"aggressive"`` or ``"normal"``
    :param confidence: probability of ``tag`` under the twin's model [-]
    :param n_sudden: sudden lane changes seen
    :param observed_s: time the twin has observed this driver [s]
    :param intents: the twin's lane-change intention, one per configured horizon (shortest
        first); empty when the intention model is off or the twin has too few recent fixes of
        the vehicle (fewer than :data:`~dt_highway.twin.intention.MIN_FIXES`, or the newest over
        :data:`~dt_highway.twin.intention.MAX_AGE_S` old)
    """

    vehicle_id: int
    t_fix_s: float
    x_m: float
    y_m: float
    speed_mps: float
    heading_rad: float
    tag: str
    confidence: float
    n_sudden: int
    observed_s: float
    intents: tuple[LaneChangeIntent, ...] = ()

    def intent(self, horizon_s: float) -> LaneChangeIntent | None:
        """The vehicle's lane-change intention for a horizon.

        :param horizon_s: the horizon asked for [s]
        :return: the intention for the horizon closest to ``horizon_s``, ``None`` without any.
        """
        if not self.intents:
            return None
        return min(self.intents, key=lambda i: abs(i.horizon_s - horizon_s))


@dataclass(frozen=True)
class TwinView:
    """One downlink message: what the twin knew of the ego's neighbourhood.

    :param t_sent_s: twin time it left the cloud [s]
    :param t_received_s: twin time the ego received it [s]
    :param vehicles: one entry per nearby connected vehicle (the ego excluded)
    """

    t_sent_s: float
    t_received_s: float
    vehicles: tuple[TwinVehicleView, ...]

    def by_id(self) -> dict[int, TwinVehicleView]:
        """The view's vehicles by id.

        :return: the entries keyed by vehicle id.
        """
        return {v.vehicle_id: v for v in self.vehicles}


class CloudTwin:
    """Fix store + tagger + lane-change intention, fed by the uplink.

    :param config: twin configuration
    :param road: the map (lane geometry)
    :param ego_id: the vehicle the twin serves (its position is context for the others' intention)
    :raises ConfigError: when the intention model cannot be made (weights unreadable, horizons not covered)
    """

    def __init__(self, config: TwinConfig, road: HighwayMap, ego_id: int = 0) -> None:
        self.config = config
        self.road = road
        self.ego_id = ego_id
        self.store = FixStore(config.store.window_s)
        self.tagger = Tagger(config.tagger, road)
        self.now_s = 0.0
        self._pending: list[tuple[float, int, GnssFix]] = []
        self._seq = itertools.count()
        self._dirty: set[int] = set()
        self._next_update_s = -math.inf
        self._intention: IntentionEstimator | None = None
        self._intention_for: object = None
        self.intent_table: IntentTable | None = None
        """The newest intention estimate of every vehicle (``None`` before the first, or with the model off)"""
        self._next_intent_s = -math.inf
        self._intention_estimator()
        self._lock: IO[bytes] | None = None
        self.reopen()

    def reopen(self) -> None:
        """Take the store file (``store.path``) for this twin and read what it holds (at the start, and after a
        :meth:`close`: another twin may have written it since). Nothing to do without a file, or while it holds it.

        :raises ConfigError: one line, when the file cannot be opened, read or locked (another env holds it)
        """
        path = self.config.store.path
        if not path or self._lock is not None:
            return
        self._lock = lock_store(path)
        _HELD.add(self)
        try:
            load_records(path, self)
        except ConfigError:
            self._unlock()
            raise

    def __getstate__(self) -> dict[str, Any]:
        """A copy (``copy.deepcopy``, a pickle) holds no store file: it neither writes nor releases it."""
        state = self.__dict__.copy()
        state["_lock"] = None
        return state

    def _intention_estimator(self) -> IntentionEstimator | None:
        """The estimator of the configured ``twin.intention`` (remade when that section changes)."""
        cfg = self.config.intention
        if cfg is not self._intention_for:
            same = cfg == self._intention_for
            self._intention_for = cfg
            if same:
                return self._intention
            self._intention = None
            self.intent_table = None
            if cfg.enabled:
                try:
                    self._intention = IntentionEstimator(cfg, self.road, self.config.tagger.prior_aggressive)
                except ValueError as exc:
                    raise ConfigError(f"twin.intention: {exc}") from None
        return self._intention

    def start_episode(self) -> None:
        """Forget raw histories and in-flight fixes (positions of another episode); keep or
        drop the drivers' records according to ``store.persist_across_episodes``."""
        self.store.clear()
        self._pending.clear()
        self._dirty.clear()
        self.intent_table = None
        self._next_intent_s = -math.inf
        if not self.config.store.persist_across_episodes:
            self.tagger.records.clear()

    def receive(self, fixes: list[GnssFix]) -> None:
        """Queue fixes; each enters the store at its arrival time.

        :param fixes: fixes from the uplink, each with its arrival time
        """
        for f in fixes:
            heapq.heappush(self._pending, (f.arrival_s, next(self._seq), f))

    def advance(self, now_s: float) -> None:
        """Move the twin clock to ``now_s``: store arrived fixes, re-tag at ``tagger.update_hz``,
        estimate the intentions at ``intention.update_hz``.

        :param now_s: twin time [s]
        """
        self.now_s = now_s
        arrived = []
        while self._pending and self._pending[0][0] <= now_s:
            arrived.append(heapq.heappop(self._pending)[2])
        if arrived:
            self._dirty |= self.store.add(arrived)
        if now_s >= self._next_update_s:
            self._next_update_s = now_s + 1.0 / self.config.tagger.update_hz
            if self.tagger.tracks_traffic:
                self.tagger.observe_traffic(self.store, now_s)
            for vid in sorted(self._dirty):
                self.tagger.update(self.store, vid, now_s)
            self._dirty.clear()
            self.store.drop_older_than(now_s - self.config.store.window_s)
        estimator = self._intention_estimator()
        if estimator is not None and now_s >= self._next_intent_s:
            self._next_intent_s = now_s + 1.0 / self.config.intention.update_hz
            self.intent_table = estimator.estimate(self.store, self.tagger.records, now_s, self.ego_id)

    def n_pending(self) -> int:
        """The number of fixes in flight.

        :return: fixes sent but not yet arrived.
        """
        return len(self._pending)

    def view_around(self, ego_id: int) -> tuple[TwinVehicleView, ...]:
        """The twin's view of the vehicles within the downlink radius of the ego's last fix.

        :param ego_id: the vehicle the view is for (left out of it)
        :return: one entry per other vehicle within ``downlink.radius_m`` (none without a fix of the ego)
        """
        ego = self.store.latest(ego_id)
        if ego is None:
            return ()
        r2 = self.config.downlink.radius_m ** 2
        table = self.intent_table
        out = []
        for vid in self.store.vehicle_ids():
            if vid == ego_id:
                continue
            f = self.store.latest(vid)
            if f is None or (f.x_m - ego.x_m) ** 2 + (f.y_m - ego.y_m) ** 2 > r2:
                continue
            rec = self.tagger.record(vid, self.now_s)
            out.append(
                TwinVehicleView(
                    vid, f.t_s, f.x_m, f.y_m, f.speed_mps, f.heading_rad,
                    rec.tag, float(rec.confidence), rec.n_sudden, float(rec.observed_s),
                    table.intents(vid) if table is not None else (),
                )
            )
        return tuple(out)

    def close(self) -> None:
        """Write the drivers' records to the SQLite file, if one is configured, and let another twin open it."""
        if self.config.store.path and self._lock is not None:
            try:
                save_records(self.config.store.path, self)
            finally:
                self._unlock()

    def _unlock(self) -> None:
        if self._lock is not None:
            self._lock.close()  # the lock goes with the file's descriptor
            self._lock = None
        _HELD.discard(self)


_HELD: weakref.WeakSet[CloudTwin] = weakref.WeakSet()
"""The twins that hold their store file (in this process)"""


def _forget_files_in_child() -> None:
    """In a forked child: close the store files the parent's twins hold (the child shares them, and while it
    held them the parent could not let another env have them); the child's copies write nothing."""
    for twin in list(_HELD):
        if twin._lock is not None:
            twin._lock.close()
            twin._lock = None
    _HELD.clear()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_files_in_child)


class Downlink:
    """Cloud -> ego messages at a fixed rate, with latency and loss.

    :param config: downlink configuration
    :param rng: this component's random generator
    """

    def __init__(self, config: DownlinkConfig, rng: np.random.Generator) -> None:
        self.config = config
        self.rng = rng
        self.latest: TwinView | None = None
        self._queue: list[tuple[float, int, TwinView]] = []
        self._seq = itertools.count()
        self._next_send_s = -math.inf

    def reset(self) -> None:
        """Forget messages in flight and the last one received."""
        self.latest = None
        self._queue.clear()
        self._next_send_s = -math.inf

    def step(self, twin: CloudTwin, ego_id: int, now_s: float) -> TwinView | None:
        """Send a view when one is due, deliver those that arrived by ``now_s``.

        :param twin: the twin whose view is sent
        :param ego_id: the vehicle the views are for
        :param now_s: twin time [s]
        :return: the newest view received so far (``None`` before the first)
        """
        cfg = self.config
        if now_s >= self._next_send_s:
            last = now_s if not math.isfinite(self._next_send_s) else self._next_send_s
            self._next_send_s = last + 1.0 / cfg.rate_hz
            lost = self.rng.random() < cfg.loss_prob
            latency = max(0.0, cfg.latency_mean_s + cfg.latency_jitter_s * float(self.rng.normal()))
            if not lost:
                view = TwinView(now_s, now_s + latency, twin.view_around(ego_id))
                heapq.heappush(self._queue, (view.t_received_s, next(self._seq), view))
        while self._queue and self._queue[0][0] <= now_s:
            view = heapq.heappop(self._queue)[2]
            if self.latest is None or view.t_sent_s > self.latest.t_sent_s:
                self.latest = view
        return self.latest


def check_models(config: TwinConfig, road: HighwayMap) -> None:
    """Load the twin's models as a :class:`CloudTwin` does (the tagger's evidence weights, the intention
    model and its weights), without its store: a bad file is one line before any episode, not a failure
    of each.

    :param config: the twin's configuration (nothing to check when it is off)
    :param road: the map
    :raises ConfigError: one line, on a file that cannot be read or a model that cannot be made
    """
    if not config.enabled:
        return
    Tagger(config.tagger, road)
    if config.intention.enabled:
        try:
            IntentionEstimator(config.intention, road, config.tagger.prior_aggressive)
        except ValueError as exc:
            raise ConfigError(f"twin.intention: {exc}") from None


# ----------------------------------------------------------------------------- SQLite persistence
def lock_store(path: str | Path) -> IO[bytes]:
    """Open (or create) a store file and hold it for one twin: a second twin on the same file, in this process or
    another, would replace what the first writes at its close.

    :param path: the store file (``twin.store.path``)
    :return: the open file, whose closing releases it (on a file system without locks, unlocked, with a warning;
        without ``fcntl``, not POSIX, unlocked)
    :raises ConfigError: one line, when the file cannot be opened or another twin holds it
    """
    try:
        fh = open(path, "a+b")  # held until the twin closes
    except OSError as exc:
        raise ConfigError(f"twin.store.path '{path}' cannot be opened: {exc.strerror or exc}") from None
    if fcntl is None:
        return fh
    for attempt in range(2):
        try:
            fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
            return fh
        except BlockingIOError:
            if attempt == 0:  # an env dropped without close() holds it until the cycle collector frees it (and
                gc.collect()  # its finalizer writes and releases the file): free it now
        except OSError as exc:  # a file system without locks (some network mounts)
            warnings.warn(f"twin.store.path '{path}' cannot be locked ({exc.strerror or exc}): a second env on it "
                          "would not be refused", stacklevel=3)
            return fh
    fh.close()
    raise ConfigError(f"twin.store.path '{path}' is in use by another env (in this process or another): close that "
                      "env first (env.close()), or give each env its own file (the last to close would replace what "
                      "the others wrote)")


def save_records(path: str | Path, twin: CloudTwin) -> None:
    """Write every driver record and the twin clock to a SQLite file (replacing its content).

    :param path: the SQLite file
    :param twin: the twin whose records and clock are written
    :raises ConfigError: when the file cannot be written
    """
    try:
        con = sqlite3.connect(str(path))
    except sqlite3.Error as exc:
        raise ConfigError(f"twin.store.path '{path}' cannot be opened: {exc}") from None
    try:
        with con:
            con.execute("CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT)")
            con.execute("CREATE TABLE IF NOT EXISTS drivers (vehicle_id INTEGER PRIMARY KEY, record TEXT)")
            con.execute("DELETE FROM drivers")
            con.execute("INSERT OR REPLACE INTO meta VALUES ('now_s', ?)", (repr(twin.now_s),))
            con.executemany(
                "INSERT OR REPLACE INTO drivers VALUES (?, ?)",
                [(vid, json.dumps(asdict(rec))) for vid, rec in twin.tagger.records.items()],
            )
    except sqlite3.Error as exc:
        raise ConfigError(f"twin.store.path '{path}' cannot be written: {exc}") from None
    finally:
        con.close()


def load_records(path: str | Path, twin: CloudTwin) -> None:
    """Read driver records written by :func:`save_records` (a missing or empty file is an empty memory).

    :param path: the SQLite file
    :param twin: the twin that takes the records (into its tagger) and the clock
    """
    if not Path(path).exists():
        return
    try:
        con = sqlite3.connect(str(path))
    except sqlite3.Error as exc:
        raise ConfigError(f"twin.store.path '{path}' cannot be opened: {exc}") from None
    try:
        if not con.execute("SELECT name FROM sqlite_master").fetchall():
            return  # an empty file (as a new store, or a made temporary file, starts): an empty memory
        row = con.execute("SELECT value FROM meta WHERE key = 'now_s'").fetchone()
        if row:
            twin.now_s = float(row[0])
        for vid, text in con.execute("SELECT vehicle_id, record FROM drivers"):
            d = json.loads(text)
            d["evidence"] = [LaneChange(**e) for e in d["evidence"]]
            twin.tagger.records[int(vid)] = DriverRecord(**d)
    except (sqlite3.Error, KeyError, TypeError, ValueError) as exc:
        raise ConfigError(f"twin.store.path '{path}' is not a dt-highway twin store: {exc}") from None
    finally:
        con.close()

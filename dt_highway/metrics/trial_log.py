"""Crash-safe trial logs: one directory per trial.

* ``meta.json``: driver, participant, condition, seed, resolved config, package version,
  start and end time, end reason, and ``status`` (``running`` while the trial runs, then
  ``completed`` or ``aborted``). Written at the start and replaced atomically at the end.
* ``steps.csv``: one row per simulation step (the ego's state, leader gap, closing speed,
  TTC..., the driver's action or keys held, what the overlay showed), appended and flushed
  as the trial runs: a process killed outright loses at most the rows since the last flush
  (:attr:`TrialWriter.flush_every_s` of simulated time, 1 s by default).
* ``events.jsonl``: one JSON object per line (cut-ins with the vehicle's id and true type,
  overlay shown/hidden, collisions, lane changes, key presses), flushed as they come.

:func:`load_trial` reads a trial back: steps as a pandas DataFrame (a torn last line, left
by a killed process, is dropped), events and metadata; a trial whose process died while
``running`` reads as ``aborted``. Parquet is written on request after the trial completes
(never during it: a Parquet file is unreadable until closed).
"""

from __future__ import annotations

import csv
import io
import json
import os
import socket
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
import pandas as pd

from dt_highway._version import __version__
from dt_highway.jsonio import json_safe
from dt_highway.metrics.safety import trial_metrics

META, STEPS, EVENTS = "meta.json", "steps.csv", "events.jsonl"
STEP_COLUMNS = (
    "t_s", "x_m", "y_m", "lane", "speed_mps", "accel_mps2", "leader_id", "gap_m", "closing_mps", "ttc_s",
    "drac_mps2", "headway_s", "crashed", "action_accel_mps2", "action_lane", "keys", "overlay_ids",
    "overlay_labels",
)
"""Columns of ``steps.csv`` (units in the names; see :mod:`dt_highway.metrics.safety`)"""


def _write_json_atomic(path: Path, data: dict[str, Any]) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(json_safe(data), indent=2, allow_nan=False) + "\n", encoding="utf-8")
    os.replace(tmp, path)


def _version() -> str:
    return __version__


class TrialWriter:
    """Writes one trial's directory as the trial runs (use as a context manager).

    :param directory: the trial's directory (created; an existing trial there is replaced)
    :param meta: metadata (driver, participant, condition, seed, config...)
    :param flush_every_s: flush the step rows at least this often, in simulated time [s]
    """

    def __init__(self, directory: str | Path, meta: dict[str, Any], flush_every_s: float = 1.0) -> None:
        self.dir = Path(directory)
        self.dir.mkdir(parents=True, exist_ok=True)
        for name in (STEPS, EVENTS, "steps.parquet"):
            (self.dir / name).unlink(missing_ok=True)
        self.meta = {
            **meta, "status": "running", "package_version": _version(), "pid": os.getpid(),
            "host": socket.gethostname(), "start_time": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            "end_time": None, "end_reason": None, "n_steps": 0,
        }
        _write_json_atomic(self.dir / META, self.meta)
        self._steps = open(self.dir / STEPS, "w", newline="", encoding="utf-8")
        self._csv = csv.DictWriter(self._steps, fieldnames=STEP_COLUMNS, extrasaction="ignore")
        self._csv.writeheader()
        self._steps.flush()
        self._events = open(self.dir / EVENTS, "w", encoding="utf-8")
        self.flush_every_s = flush_every_s
        self._last_flush_t: float | None = None
        self.n_steps = 0

    def step(self, row: dict[str, Any]) -> None:
        """Append one simulation step's row (keys of :data:`STEP_COLUMNS`)."""
        self._csv.writerow(row)
        self.n_steps += 1
        t = float(row.get("t_s", 0.0))
        if self._last_flush_t is None or t - self._last_flush_t >= self.flush_every_s:
            self._steps.flush()
            self._last_flush_t = t

    def event(self, kind: str, t_s: float, **fields: Any) -> None:
        """Append one event, flushed at once.

        :param kind: e.g. ``cut_in``, ``overlay_shown``, ``overlay_hidden``, ``collision``,
            ``lane_change``, ``key_down``, ``key_up``
        :param t_s: simulation time [s]
        """
        self._events.write(json.dumps(json_safe({"kind": kind, "t_s": t_s, **fields}), allow_nan=False) + "\n")
        self._events.flush()

    def flush(self) -> None:
        """Flush the step rows now."""
        self._steps.flush()

    def close(self, status: str = "completed", end_reason: str = "") -> None:
        """Finish the trial: flush, and mark it ``completed`` or ``aborted``."""
        if self._steps.closed:
            return
        self._steps.close()
        self._events.close()
        self.meta.update(status=status, end_reason=end_reason, end_time=time.strftime("%Y-%m-%dT%H:%M:%S%z"),
                         n_steps=self.n_steps)
        _write_json_atomic(self.dir / META, self.meta)

    def __enter__(self) -> TrialWriter:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        if exc_type is not None and issubclass(exc_type, KeyboardInterrupt):
            self.close("aborted", "interrupted by the user")  # Ctrl-C
        elif exc_type is not None:
            self.close("aborted", f"{exc_type.__name__}: {exc}")
        else:
            self.close("completed", self.meta.get("end_reason") or "")


def write_parquet(directory: str | Path, trial: Trial | None = None) -> Path:
    """Write a completed trial's steps as ``steps.parquet`` beside ``steps.csv`` (needs pyarrow).

    The CSV stays the log of record; the Parquet copy is for fast loading of large studies.

    :param directory: the trial's directory
    :param trial: the trial already read from it (read here when ``None``)
    :return: the Parquet file
    :raises ImportError: if pyarrow is not installed
    :raises ValueError: if the trial is not completed
    """
    try:
        import pyarrow  # lazy: optional extra (pip install dt-highway[parquet]) # noqa: F401
    except ImportError:
        raise ImportError("Parquet output needs pyarrow: pip install 'dt-highway[parquet]'") from None
    trial = trial if trial is not None else load_trial(directory)
    if trial.meta.get("status") != "completed":
        raise ValueError(
            f"trial {trial.path} is {trial.meta.get('status')}: Parquet is written only for completed trials"
        )
    out = Path(directory) / "steps.parquet"
    tmp = out.with_name(out.name + ".tmp")
    trial.steps.to_parquet(tmp, index=False)
    os.replace(tmp, out)
    return out


@dataclass
class Trial:
    """A trial read back.

    :param steps: one row per simulation step
    :param events: the events, in order
    :param meta: the metadata; ``status`` is ``aborted`` for a trial whose process died
    :param path: its directory
    """

    steps: pd.DataFrame
    events: list[dict[str, Any]]
    meta: dict[str, Any]
    path: Path

    @property
    def dt_s(self) -> float:
        """The simulation step [s] (one row of ``steps``)."""
        return 1.0 / float(self.meta.get("simulation_frequency_hz", 15))

    @property
    def cut_ins(self) -> list[dict[str, Any]]:
        """The cut-in events."""
        return [e for e in self.events if e.get("kind") == "cut_in"]

    def metrics(self) -> dict[str, Any]:
        """Every safety metric of the trial (:func:`dt_highway.metrics.safety.trial_metrics`)."""
        return trial_metrics(self.steps, self.dt_s, self.cut_ins)


def _complete_lines(path: Path) -> str:
    """The file's text up to its last newline (a torn last line is dropped)."""
    if not path.exists():
        return ""
    data = path.read_bytes()
    cut = data.rfind(b"\n")
    return data[: cut + 1].decode("utf-8", errors="replace") if cut >= 0 else ""


def _alive(pid: object, host: object) -> bool:
    if host != socket.gethostname() or not isinstance(pid, int):
        return False
    try:
        os.kill(pid, 0)
    except (ProcessLookupError, PermissionError):
        return False
    return True


def load_trial(directory: str | Path) -> Trial:
    """Read a trial directory.

    :param directory: the trial's directory
    :return: steps (DataFrame), events and metadata
    :raises FileNotFoundError: if it holds no trial (no ``meta.json``)
    """
    d = Path(directory)
    meta_path = d / META
    if not meta_path.exists():
        raise FileNotFoundError(f"not a trial directory (no {META}): {d}")
    meta = json.loads(meta_path.read_text(encoding="utf-8"))
    if meta.get("status") == "running" and not _alive(meta.get("pid"), meta.get("host")):
        meta["status"] = "aborted"
        meta["end_reason"] = meta.get("end_reason") or "the process ended while the trial was running"
    text = _complete_lines(d / STEPS)
    if text.strip():
        steps = pd.read_csv(io.StringIO(text), keep_default_na=False, na_values=["", "nan", "NaN"],
                            dtype={"keys": str, "overlay_ids": str, "overlay_labels": str})
    else:
        steps = pd.DataFrame(columns=list(STEP_COLUMNS))
    events = []
    for line in _complete_lines(d / EVENTS).splitlines():
        if line.strip():
            try:
                events.append(json.loads(line))
            except json.JSONDecodeError:
                continue
    return Trial(steps, events, meta, d)


class TrialRecorder:
    """Writes what each env step reports into a trial log: one row per simulation step
    (safety samples, the driver's action or keys, the marks shown) and the events (cut-ins,
    marks shown and hidden, lane changes, collisions). Shared by scripted and keyboard trials.

    :param log: the trial's writer
    """

    def __init__(self, log: TrialWriter) -> None:
        self.log = log
        self.shown: dict[int, str] = {}
        self._lane: int | None = None
        self._crashed = False

    def record(self, info: dict[str, Any], action: Sequence[float] | np.ndarray, keys: str = "") -> None:
        """Log the samples and events of one env step.

        :param info: the step's info (``safety``, ``adas``, ``time_s``)
        :param action: the ``[acceleration, lane]`` action that led to it
        :param keys: keys held (keyboard trials), ``;``-separated
        """
        log = self.log
        overlay = (info.get("adas") or {}).get("overlay", [])
        now = {int(o["vehicle_id"]): o["label"] for o in overlay}
        t = float(info["time_s"])
        for vid in now.keys() - self.shown.keys():
            log.event("overlay_shown", t, vehicle_id=vid, label=now[vid])
        for vid in self.shown.keys() - now.keys():
            log.event("overlay_hidden", t, vehicle_id=vid)
        self.shown = now
        for c in info["safety"]["cut_ins"]:
            log.event("cut_in", c["t_s"], vehicle_id=c["vehicle_id"], driver_type=c["driver_type"],
                      gap_m=c["gap_m"], marked=c["vehicle_id"] in now)
        ids = sorted(now)
        for s in info["safety"]["samples"]:
            if self._lane is not None and s["lane"] != self._lane:
                log.event("lane_change", s["t_s"], from_lane=self._lane, to_lane=s["lane"])
            if s["crashed"] and not self._crashed:
                log.event("collision", s["t_s"], leader_id=s["leader_id"])
            self._lane, self._crashed = s["lane"], bool(s["crashed"])
            log.step({**s, "action_accel_mps2": float(action[0]), "action_lane": float(action[1]), "keys": keys,
                      "overlay_ids": ";".join(str(v) for v in ids), "overlay_labels": ";".join(now[v] for v in ids)})

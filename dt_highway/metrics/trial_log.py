"""Crash-safe trial logs: one directory per trial.

* ``meta.json``: driver, participant, condition, seed, resolved config, package version,
  start and end time, end reason, and ``status`` (``running`` while the trial runs, then
  ``completed`` or ``aborted``). Written at the start and replaced atomically at the end.
* ``steps.csv``: one row per simulation step, the state after it (the ego's state, leader gap,
  closing speed, TTC, 2-D TTC..., the driver's action or keys held, what the overlay showed;
  a trial of ``T`` s at ``f`` Hz has ``T f`` rows, ``t = 1/f ... T``, or one decision's steps more when
  highway-env's float clock falls just short of ``T``: :func:`expected_rows`), appended and flushed
  as the trial runs: a process killed outright loses at most the rows since the last flush
  (:attr:`TrialWriter.flush_every_s` of simulated time, 1 s by default).
* ``events.jsonl``: one JSON object per line (cut-ins with the vehicle's id and true type,
  overlay shown/hidden, collisions with the partner's id, true type and the kind, lane
  changes, key presses), flushed as they come.

:func:`load_trial` reads a trial back: steps as a pandas DataFrame (a torn last line, left
by a killed process, is dropped), events and metadata; a trial whose process died while
``running`` reads as ``aborted``; an unreadable ``meta.json`` or ``steps.csv`` is a
:class:`TrialLogError` naming the file. :func:`check_trial` says why a trial read back cannot
enter a study's statistics (not completed, rows missing, columns missing or not numbers...).
Parquet is written on request after the trial completes (never during it: a Parquet file is
unreadable until closed).
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import socket
import subprocess
import time
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
import pandas as pd

from dt_highway._version import __version__
from dt_highway.interrupts import interrupted_by_user, signals_deferred
from dt_highway.jsonio import finite_number, json_safe, positive_number, replace_text
from dt_highway.metrics.overlay_metrics import overlay_metrics
from dt_highway.metrics.safety import trial_metrics

META, STEPS, EVENTS = "meta.json", "steps.csv", "events.jsonl"
STEP_COLUMNS = (
    "t_s", "x_m", "y_m", "lane", "speed_mps", "accel_mps2", "leader_id", "gap_m", "closing_mps", "ttc_s",
    "drac_mps2", "headway_s", "crashed", "ttc_contact", "ttc2d_s", "ttc2d_id", "ttc2d_contact", "action_accel_mps2",
    "action_lane", "keys", "overlay_ids", "overlay_labels",
)
"""Columns of ``steps.csv`` (units in the names; see :mod:`dt_highway.metrics.safety`)"""
TEXT_COLUMNS = ("keys", "overlay_ids", "overlay_labels")
"""The columns of ``steps.csv`` that hold text (may be empty)"""
BOOL_COLUMNS = ("crashed", "ttc_contact", "ttc2d_contact")
"""The columns of ``steps.csv`` that hold ``True``/``False``"""
FILLED_COLUMNS = ("t_s", "x_m", "y_m", "lane", "speed_mps", "accel_mps2")
"""The columns of ``steps.csv`` that every row fills (never empty or NaN)"""
PACKAGE_DIR = Path(__file__).resolve().parents[2]
"""The directory that holds the ``dt_highway`` package (a git checkout's top, when run from one)"""


class TrialLogError(ValueError):
    """A trial's ``meta.json`` or ``steps.csv`` that cannot be read.

    :param file: the file
    :param reason: what is wrong with it, in a few words
    """

    def __init__(self, file: Path, reason: str) -> None:
        super().__init__(f"{file}: {reason}")
        self.file = file
        self.reason = f"{file.name} {reason}"



FINISHED_STATUSES = ("completed", "ended_by_collision")
"""A trial's ``status`` when it is data: run to its end, or ended by a collision (a keyboard trial under
``--on-crash end``; its rows stop at the crash, ``cut_short`` in its metrics)"""


def _write_json_atomic(path: Path, data: dict[str, Any]) -> None:
    replace_text(path, json.dumps(json_safe(data), indent=2, allow_nan=False) + "\n")


def _version() -> str:
    return __version__


@cache
def git_commit(directory: Path = PACKAGE_DIR) -> str | None:
    """The git commit the package runs from (``git rev-parse HEAD`` in its checkout), with
    ``-dirty`` when tracked files differ from it; ``None`` for an installed package (no ``.git``)
    or without git.

    :param directory: the checkout's top directory
    :return: the commit, or ``None``
    """
    if not (directory / ".git").exists():
        return None
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=directory, capture_output=True, text=True, timeout=10)
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=directory,
                               capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return None
    if head.returncode != 0 or not head.stdout.strip():
        return None
    return head.stdout.strip() + ("-dirty" if dirty.returncode == 0 and dirty.stdout.strip() else "")


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
            **meta, "status": "running", "package_version": _version(), "git_commit": git_commit(), "pid": os.getpid(),
            "host": socket.gethostname(), "start_time": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            "end_time": None, "end_reason": None, "n_steps": 0,
        }
        self.flush_every_s = flush_every_s
        self._last_flush_t: float | None = None
        self.n_steps = 0
        self._steps = open(self.dir / STEPS, "w", newline="", encoding="utf-8")
        self._events = open(self.dir / EVENTS, "w", encoding="utf-8")
        try:
            self._csv = csv.DictWriter(self._steps, fieldnames=STEP_COLUMNS, extrasaction="ignore")
            self._csv.writeheader()
            self._steps.flush()
            _write_json_atomic(self.dir / META, self.meta)
        except BaseException as exc:  # a Ctrl-C here, before the ``with`` is entered, must not leave it "running"
            self.close("aborted", _abort_reason(exc))
            raise

    def step(self, row: dict[str, Any]) -> None:
        """Append one simulation step's row (keys of :data:`STEP_COLUMNS`).

        :param row: column -> value (other keys are ignored)
        """
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
        :param fields: the event's other fields (``vehicle_id``, ``label``...), JSON-serialisable
        """
        self._events.write(json.dumps(json_safe({"kind": kind, "t_s": t_s, **fields}), allow_nan=False) + "\n")
        self._events.flush()

    def flush(self) -> None:
        """Flush the step rows now."""
        self._steps.flush()

    def close(self, status: str = "completed", end_reason: str = "") -> None:
        """Finish the trial: flush, and mark it ``completed`` or ``aborted``.

        :param status: the trial's final ``status`` (``completed``, ``ended_by_collision``, ``aborted``)
        :param end_reason: why it ended, in a few words
        """
        if self._steps.closed:
            return
        with signals_deferred():  # a second Ctrl-C here would leave the log "running"
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
        if exc is not None:
            self.close("aborted", _abort_reason(exc))
        else:
            self.close("completed", self.meta.get("end_reason") or "")


def _abort_reason(exc: BaseException) -> str:
    """A trial's ``end_reason`` when ``exc`` stopped it."""
    if interrupted_by_user(exc):  # Ctrl-C (also inside a numba-compiled function)
        return "interrupted by the user"
    return f"{type(exc).__name__}: {exc}"


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
    if trial.meta.get("status") not in FINISHED_STATUSES:
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

    @property
    def collisions(self) -> list[dict[str, Any]]:
        """The collision events."""
        return [e for e in self.events if e.get("kind") == "collision"]

    @property
    def planned_duration_s(self) -> float | None:
        """The trial's configured duration [s] (``None`` when the metadata has none, or not a
        positive finite number)."""
        return positive_number(_highway_setting(self.meta, "duration"))

    def metrics(self) -> dict[str, Any]:
        """Every safety metric of the trial (:func:`dt_highway.metrics.safety.trial_metrics`), and the
        overlay's (:func:`dt_highway.metrics.overlay_metrics.overlay_metrics`) when the log has its columns.

        :return: metric name -> value
        """
        m = trial_metrics(self.steps, self.dt_s, self.cut_ins, collisions=self.collisions,
                          planned_duration_s=self.planned_duration_s)
        if "overlay_ids" in self.steps and len(self.steps):
            m.update(overlay_metrics(self.steps, self.dt_s, self.cut_ins))
        return m


def _highway_setting(meta: dict[str, Any], key: str) -> Any:
    """``meta["config"]["highway"][key]``, or ``None`` where a level is missing or not a table."""
    config = meta.get("config")
    highway = config.get("highway") if isinstance(config, dict) else None
    return highway.get(key) if isinstance(highway, dict) else None


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
    :raises TrialLogError: if its ``meta.json`` or ``steps.csv`` cannot be read
    :raises TypeError: when ``directory`` is not a path
    """
    if not isinstance(directory, (str, Path)):
        raise TypeError(f"load_trial reads a trial's directory: a path (got {type(directory).__name__})")
    d = Path(directory)
    meta_path = d / META
    if not meta_path.exists():
        raise FileNotFoundError(f"not a trial directory (no {META}): {d}")
    try:
        meta = json.loads(meta_path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise TrialLogError(meta_path, f"is not valid JSON ({exc.msg.removesuffix(' at')}, line {exc.lineno} "
                                       f"column {exc.colno})") from None
    except UnicodeDecodeError:
        raise TrialLogError(meta_path, "is not UTF-8 text") from None
    except OSError as exc:
        raise TrialLogError(meta_path, f"cannot be read ({exc.strerror or exc})") from None
    if not isinstance(meta, dict):
        raise TrialLogError(meta_path, f"holds a JSON {type(meta).__name__}, not an object")
    if meta.get("status") == "running" and not _alive(meta.get("pid"), meta.get("host")):
        meta["status"] = "aborted"
        meta["end_reason"] = meta.get("end_reason") or "the process ended while the trial was running"
    try:
        text = _complete_lines(d / STEPS)
    except OSError as exc:
        raise TrialLogError(d / STEPS, f"cannot be read ({exc.strerror or exc})") from None
    if text.strip():
        _check_fields(d / STEPS, text)
        try:
            steps = pd.read_csv(io.StringIO(text), keep_default_na=False, na_values=["", "nan", "NaN"],
                                dtype=dict.fromkeys(TEXT_COLUMNS, str), index_col=False)
        except (ValueError, pd.errors.ParserError) as exc:  # ParserError, EmptyDataError, a bad dtype
            raise TrialLogError(d / STEPS, f"is not a readable CSV ({str(exc).strip().splitlines()[-1]})") from None
    else:
        steps = pd.DataFrame(columns=list(STEP_COLUMNS))
    try:
        lines = _complete_lines(d / EVENTS).splitlines()
    except OSError as exc:
        raise TrialLogError(d / EVENTS, f"cannot be read ({exc.strerror or exc})") from None
    events = []
    for line in lines:
        if line.strip():
            try:
                event = json.loads(line)
            except json.JSONDecodeError:
                continue  # a torn line (a crash while writing): the events before and after stand
            events.append(event if isinstance(event, dict) else {"kind": "not an object", "value": event})
    return Trial(steps, events, meta, d)


def _check_fields(path: Path, text: str) -> None:
    """Check that every line of a trial log's CSV has as many fields as its header.

    :raises TrialLogError: when a line of the CSV ``text`` has another number of fields than its header
    """
    width = None
    try:
        for lineno, fields in enumerate(csv.reader(io.StringIO(text)), start=1):
            if not fields:
                continue  # a blank line: skipped by the reader too
            if width is None:
                width = len(fields)
            elif len(fields) != width:
                raise TrialLogError(path, f"is not a readable CSV (line {lineno} has {len(fields)} fields, "
                                          f"the header {width})")
    except csv.Error as exc:
        raise TrialLogError(path, f"is not a readable CSV ({exc})") from None


MAX_DECISIONS = 10_000_000
"""Above this many policy steps :func:`expected_rows` counts instead of summing (a week at 15 Hz is 9 million)"""


def expected_rows(duration_s: float, simulation_hz: float, policy_hz: float | None = None) -> int:
    """Rows of ``steps.csv`` of a trial that ran its whole duration: one per simulation step.

    highway-env ends an episode at the first policy step at which its clock, advanced by
    ``1 / policy_hz`` per step, reaches ``duration_s``; each policy step is
    ``simulation_hz / policy_hz`` simulation steps (120 s at 15 Hz: 1800 rows).

    :param duration_s: the configured duration [s]
    :param simulation_hz: simulation frequency [Hz]
    :param policy_hz: policy frequency [Hz] (``None``: one decision per simulation step)
    :return: the number of rows
    :raises ValueError: on a duration or frequency that is not a positive finite number
    """
    policy_hz = policy_hz or simulation_hz
    if not all(math.isfinite(v) and v > 0 for v in (duration_s, simulation_hz, policy_hz)):
        raise ValueError(f"expected_rows needs positive finite numbers (got duration_s={duration_s}, "
                         f"simulation_hz={simulation_hz}, policy_hz={policy_hz})")
    if duration_s * policy_hz > MAX_DECISIONS:  # beyond any trial: the count, not the float sums of a long loop
        return math.ceil(duration_s * policy_hz) * int(simulation_hz // policy_hz)
    clock, steps = 0.0, 0
    while clock < duration_s:  # the same float sums as highway-env's clock
        clock += 1 / policy_hz
        steps += 1
    return steps * int(simulation_hz // policy_hz)


def _not_numbers(steps: pd.DataFrame) -> str | None:
    """Why the step columns do not hold what they should (numbers, True/False, filled), or ``None``."""
    for c in STEP_COLUMNS:
        if c in TEXT_COLUMNS:
            continue
        col = steps[c]
        if c in FILLED_COLUMNS + BOOL_COLUMNS and col.isna().any():
            return f"steps.csv column {c} is empty at line {int(np.flatnonzero(col.isna().to_numpy())[0]) + 2}"
        ok = pd.api.types.is_bool_dtype(col) if c in BOOL_COLUMNS else pd.api.types.is_numeric_dtype(col)
        if ok and c in FILLED_COLUMNS and np.isinf(col.to_numpy(float)).any():
            return f"steps.csv column {c} holds an infinite number at line {int(np.flatnonzero(np.isinf(col))[0]) + 2}"
        if not ok:
            good = (col.astype(str).isin(["True", "False"]) if c in BOOL_COLUMNS
                    else pd.to_numeric(col, errors="coerce").notna())
            bad = np.flatnonzero((~good & col.notna()).to_numpy())
            where = f": line {int(bad[0]) + 2} holds {str(col.iloc[bad[0]])[:20]!r}" if len(bad) else ""
            return f"steps.csv column {c} is not {'True/False' if c in BOOL_COLUMNS else 'numbers'}{where}"
    return None


def _bad_event(events: list[dict[str, Any]]) -> str | None:
    """Why the events the metrics read (cut-ins, collisions) are not as the recorder writes them, or ``None``."""
    for k, e in enumerate(events):
        if e.get("kind") == "not an object":
            return f"events.jsonl event {k + 1} is not a JSON object"
        if e.get("kind") not in ("cut_in", "collision"):
            continue
        if finite_number(e.get("t_s")) is None:
            return f"events.jsonl {e['kind']} event {k + 1} has no time (t_s: {e.get('t_s')!r})"
        vid = e.get("vehicle_id")
        if e["kind"] == "cut_in" and (not isinstance(vid, int) or isinstance(vid, bool)):
            return f"events.jsonl cut_in event {k + 1} names no vehicle (vehicle_id: {vid!r})"
    return None


def check_trial(trial: Trial) -> str | None:
    """Why a trial read back cannot enter a study's statistics, or ``None`` when it can.

    It can when it is finished (:data:`FINISHED_STATUSES`), its ``steps.csv`` has every column of :data:`STEP_COLUMNS`
    with numbers (``True``/``False`` in :data:`BOOL_COLUMNS`), as many rows as the
    configured duration makes (:func:`expected_rows`; fewer only when a collision ended it, the
    last row crashed: a trial *cut short*), as many as ``meta.json`` counts written, and its
    times are one row per simulation step (``t = k / f``).

    :param trial: the trial (:func:`load_trial`)
    :return: the reason, in a few words (``"steps.csv has 450 rows, 900 expected (60 s at 15 Hz)..."``)
    """
    meta, steps = trial.meta, trial.steps
    if meta.get("status") not in FINISHED_STATUSES:
        why = meta.get("end_reason")
        return f"status {meta.get('status') or 'missing'}" + (f" ({why})" if why else "")
    if not (trial.path / STEPS).exists():
        return "steps.csv missing"
    missing = [c for c in STEP_COLUMNS if c not in steps.columns]
    if missing:
        return f"steps.csv lacks column{'s' if len(missing) > 1 else ''} {', '.join(missing)}"
    if not len(steps):
        return "steps.csv has no rows"
    bad = _not_numbers(steps)
    if bad:
        return bad
    n = len(steps)
    written = meta.get("n_steps")
    if isinstance(written, int) and written != n:
        return f"steps.csv has {n} rows, meta.json counts {written} written"
    if not isinstance(meta.get("condition"), str) or not meta["condition"]:
        return f"meta.json names no condition (condition: {meta.get('condition')!r})"
    duration, hz = trial.planned_duration_s, positive_number(meta.get("simulation_frequency_hz"))
    policy = _highway_setting(meta, "policy_frequency")
    policy_hz = positive_number(policy)
    if duration is None or hz is None or (policy is not None and policy_hz is None):
        return ("meta.json lacks the configured duration or a frequency, as positive numbers (config.highway.duration "
                f"{_highway_setting(meta, 'duration')!r}, simulation_frequency_hz {meta.get('simulation_frequency_hz')!r}, "
                f"config.highway.policy_frequency {policy!r})")
    bad_event = _bad_event(trial.events)
    if bad_event:
        return bad_event
    want = expected_rows(duration, hz, policy_hz)
    crashed_at_end = bool(steps["crashed"].iloc[-1])
    if n > want or (n < want and not crashed_at_end):
        return (f"steps.csv has {n} rows, {want} expected ({duration:g} s at {float(hz):g} Hz)"
                + (": truncated" if n < want else ""))
    t = steps["t_s"].to_numpy(float)
    off = np.abs(t - np.arange(1, n + 1) / float(hz))
    if np.nanmax(off) > 0.5 / float(hz) or np.isnan(off).any():
        k = int(np.argmax(np.where(np.isnan(off), np.inf, off)))
        return f"steps.csv times are not one row per step: line {k + 2} has t = {t[k]:g} s, {(k + 1) / float(hz):g} expected"
    return None


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
        for c in info["safety"]["cut_ins"]:  # vehicle_id, gap_m, t_lane_s, driver_type, maneuver...
            fields = {"maneuver": "", **{k: v for k, v in c.items() if k != "t_s"}}
            log.event("cut_in", c["t_s"], **fields, marked=c["vehicle_id"] in now)
        ids = sorted(now)
        for s in info["safety"]["samples"]:
            if self._lane is not None and s["lane"] != self._lane:
                log.event("lane_change", s["t_s"], from_lane=self._lane, to_lane=s["lane"])
            if s["crashed"] and not self._crashed:
                col = s.get("collision") or {}
                log.event("collision", s["t_s"], leader_id=s["leader_id"], partner_id=col.get("partner_id", -1),
                          partner_type=col.get("partner_type"), collision_kind=col.get("kind", "unknown"),
                          lane_changer=col.get("lane_changer"), striker=col.get("striker"))
            self._lane, self._crashed = s["lane"], bool(s["crashed"])
            log.step({**s, "action_accel_mps2": float(action[0]), "action_lane": float(action[1]), "keys": keys,
                      "overlay_ids": ";".join(str(v) for v in ids), "overlay_labels": ";".join(now[v] for v in ids)})

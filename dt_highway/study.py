"""The study runner: a driver in the baseline and ADAS conditions, paired trial by trial.

Paired design: trial ``i`` of every condition starts from the same traffic seed (``seed + i``)
and the driver's own randomness from the same seed, so the conditions differ only in what
the driver is shown. In the ``baseline`` condition the camera and fusion are off (nothing
is shown); in ``adas`` they run and the driver sees the overlay; ``adas-type``/``adas-threat`` fix
the overlay's mode, and ``sham`` is the placebo (:mod:`dt_highway.conditions`). Any number of
conditions can be paired this way (``--conditions baseline,adas-threat,sham``): every condition's
trial ``i`` has the same seed.

Trials run in a process pool (``workers``), each writing its own crash-safe log directory
(:mod:`dt_highway.metrics.trial_log`) under ``<out>/trials/<condition>-<i>``; a finished trial is
skipped when the study is run again (resume), and a trial that fails is reported and marked
aborted without stopping the others. Ctrl-C (SIGINT to the process group, as a terminal sends it)
starts no further trial, interrupts the running ones (their logs are closed as aborted,
"interrupted by the user") and raises :class:`KeyboardInterrupt` once they have stopped. With the
Ray backend, SIGTERM does the same, and so does SIGINT when the study was started with it ignored
(a background job).
"""

from __future__ import annotations

import json
import os
import signal
import socket
import threading
import time
import traceback
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import Future, ProcessPoolExecutor, as_completed
from contextlib import contextmanager, suppress
from dataclasses import asdict, dataclass, field
from multiprocessing import get_context, parent_process
from multiprocessing.process import BaseProcess
from pathlib import Path
from typing import Any, cast

import gymnasium as gym
import numpy as np

from dt_highway.conditions import check_mode_override, condition_config, driver_config
from dt_highway.config import ConfigError, check_overrides, find_file
from dt_highway.drivers import load_driver
from dt_highway.env.core import DTHighwayEnv
from dt_highway.env.seat import DriverSeat
from dt_highway.interrupts import SignalsSeen, interrupted_by_user, signals_held
from dt_highway.jsonio import dump_json, replace_text, whole_number
from dt_highway.metrics.trial_log import (
    TrialRecorder,
    TrialWriter,
    load_trial,
    write_parquet,
)


def freeze_inputs(out: str | Path, driver: str, scenario: str | None) -> tuple[str, str | None]:
    """Copy the driver and scenario files into ``<out>/inputs/`` and return the copies' paths
    (a policy's ``.zip`` goes with the ``.json`` beside it).

    The trials read the copies, so that editing a file while a study runs cannot change it
    half-way, and the study directory keeps a record of what it ran. Resuming a study with a
    file that differs from its copy is refused.

    :param out: the study directory
    :param driver: driver file (``agents/<name>.toml``, or a policy's ``.zip``)
    :param scenario: scenario file or ``None``
    :return: the paths of the driver's copy and of the scenario's (``None`` when no scenario)
    :raises ConfigError: when a file is missing or differs from the study's copy
    """
    inputs = Path(out) / "inputs"
    frozen: list[str | None] = []
    driver = find_file(driver, "agents")  # agents/human.toml from any folder, as load_driver reads it
    paths: list[str | None] = [driver, None if scenario is None else find_file(scenario, "envs")]
    if Path(driver).suffix == ".zip":  # a trained policy: its metadata goes with it
        paths.append(str(Path(driver).with_suffix(".json")))
    for path in paths:
        if path is None:
            frozen.append(None)
            continue
        src = Path(path)
        if not src.is_file():
            raise ConfigError(f"file not found: {src}")
        copy = inputs / src.name
        data = src.read_bytes()
        if copy.exists() and copy.resolve() != src.resolve() and copy.read_bytes() != data:
            raise ConfigError(f"{src} differs from the copy the study in {out} was started with ({copy}): "
                              "use another --out, or restore the file")
        if not copy.exists():
            inputs.mkdir(parents=True, exist_ok=True)
            copy.write_bytes(data)
        frozen.append(str(copy))
    return str(frozen[0]), frozen[1]


def check_resume(out: str | Path, specs: Sequence[TrialSpec]) -> dict[str, dict[str, Any]]:
    """Refuse to resume a study with trials planned differently (seed, ``--set`` values, driver
    or scenario) from those it was started with (its ``study.json``).

    :param out: the study directory
    :param specs: the trials planned now (:func:`plan`)
    :return: the trials on record, by directory (empty when there is no ``study.json``)
    :raises ConfigError: naming the first trial that differs, or a ``study.json`` that cannot be read
    """
    record = Path(out) / "study.json"
    if not record.exists():
        return {}
    try:
        before = {t["directory"]: t for t in json.loads(record.read_text())["trials"]}
        if not all(isinstance(t, dict) and {"seed", "overrides", "driver", "scenario"} <= t.keys() for t in before.values()):
            raise ValueError("a trial without its settings")
    except (OSError, ValueError, KeyError, TypeError) as err:  # resumed, it would be written anew without its trials
        why = (err.strerror or str(err)) if isinstance(err, OSError) else "not the record of a study's trials"
        raise ConfigError(f"{record} cannot be read ({why}): it records the trials the study was started with, so "
                          "mend or move it to go on (the trials' own meta.json files hold their settings)") from None

    def key(t: dict[str, Any]) -> dict[str, Any]:
        name = lambda p: Path(p).name if p else None  # noqa: E731
        return {"seed": t["seed"], "--set": list(t["overrides"]), "driver": name(t["driver"]),
                "scenario": name(t["scenario"])}

    for spec in specs:
        old = before.get(spec.directory)
        if old is None:
            continue
        was, now = key(old), key(asdict(spec))
        differ = [f"{k} {was[k]!r}, now {now[k]!r}" for k in was if was[k] != now[k]]
        if differ:
            raise ConfigError(f"the study in {out} was started with other settings for {Path(spec.directory).name} "
                              f"({'; '.join(differ)}): use another --out, or the same settings")
    return before


@dataclass(frozen=True)
class TrialSpec:
    """One trial of a study.

    :param directory: where its log goes
    :param driver: driver file (``agents/<name>.toml``)
    :param condition: one of :data:`~dt_highway.conditions.CONDITIONS`
    :param index: trial number within the condition (the pair it belongs to)
    :param seed: traffic and driver seed
    :param scenario: scenario file or ``None``
    :param overrides: ``--set`` strings
    :param participant: participant id (keyboard trials)
    :param parquet: also write ``steps.parquet`` once the trial has completed
    """

    directory: str
    driver: str
    condition: str
    index: int
    seed: int
    scenario: str | None = None
    overrides: tuple[str, ...] = ()
    participant: str | None = None
    parquet: bool = False


def is_completed(directory: str | Path) -> bool:
    """Whether a trial directory holds a completed trial (its ``meta.json`` says so).

    :param directory: the trial's directory
    :return: ``True`` when its ``meta.json`` has ``"status": "completed"`` (``False`` when it cannot be read)
    """
    try:
        return json.loads((Path(directory) / "meta.json").read_text()).get("status") == "completed"
    except (OSError, ValueError, AttributeError):
        return False


def _done_result(spec: TrialSpec) -> dict[str, Any] | None:
    """The result of a trial completed by an earlier run (resume): ``skipped``, with its metrics from its log.

    :param spec: the trial
    :return: ``None`` when the trial must run (no log, an unreadable one, or one that did not complete);
        ``failed`` when its Parquet copy was asked for and cannot be written
    """
    out = Path(spec.directory)
    if not is_completed(out):  # its meta.json alone: a log that did not complete is not read
        return None
    try:
        done = load_trial(out)
    except (OSError, ValueError):  # an unreadable log: run the trial again
        return None
    if spec.parquet and not (out / "steps.parquet").exists():
        try:
            write_parquet(out, done)
        except (ImportError, ValueError) as err:
            return {"status": "failed", "directory": str(out), "error": str(err)}
    return {"status": "skipped", "directory": str(out), "metrics": done.metrics()}


def run_trial(spec: TrialSpec) -> dict[str, Any]:
    """Run one trial and write its log.

    :param spec: the trial
    :return: ``status`` (``completed``, ``skipped`` or ``failed``), the directory, the
        error (when failed) and the trial's metrics (when it has a log)
    """
    out = Path(spec.directory)
    done = _done_result(spec)
    if done is not None:
        return done
    try:
        driver = load_driver(spec.driver)
        cfg = driver_config(spec.scenario, spec.overrides, spec.condition, driver.config_overrides())
    except ConfigError as err:
        return {"status": "failed", "directory": str(out), "error": str(err)}
    meta = {"driver": driver.name, "driver_file": spec.driver, "driver_params": driver.params(),
            "participant": spec.participant, "condition": spec.condition, "pair": spec.index, "seed": spec.seed,
            "scenario": spec.scenario, "overrides": list(spec.overrides), "config": cfg.to_dict(),
            "simulation_frequency_hz": cfg.highway.simulation_frequency}
    try:
        env = gym.make("dt-highway-v0", config=cfg.to_dict())
        u = cast(DTHighwayEnv, env.unwrapped)
        with TrialWriter(out, meta) as log:
            _, info = env.reset(seed=spec.seed)
            seat = DriverSeat(u, driver.senses)  # what the driver perceives: never the env or info
            driver.reset(spec.seed)
            action = np.zeros(2)
            rec = TrialRecorder(log)
            end: str | None = None  # set when the episode ends; its last info is logged first
            while True:
                rec.record(info, action)
                if end is not None:
                    break
                action = np.asarray(driver.act(seat.perceive()), dtype=float)
                _, _, terminated, truncated, info = env.step(action)
                if terminated or truncated:
                    end = "collision" if u.vehicle.crashed else ("time limit" if truncated else "terminated")
            log.meta["end_reason"] = end
        env.close()
    except Exception as err:  # one failed trial must not sink the study
        if interrupted_by_user(err):  # Ctrl-C inside a numba-compiled function: a SystemError caused by it
            raise KeyboardInterrupt from err
        return {"status": "failed", "directory": str(out), "error": f"{type(err).__name__}: {err}",
                "traceback": traceback.format_exc()}
    trial = load_trial(out)
    if spec.parquet:
        try:
            write_parquet(out, trial)
        except (ImportError, ValueError) as err:  # the CSV log is complete: report, keep it
            return {"status": "failed", "directory": str(out), "error": str(err)}
    return {"status": "completed", "directory": str(out), "metrics": trial.metrics()}


@dataclass
class StudyResult:
    """What a study run did.

    :param directory: the study directory
    :param completed: trials run now
    :param skipped: trials already done before (resume)
    :param failed: trials that failed, with their errors
    """

    directory: str
    completed: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    failed: list[dict[str, str]] = field(default_factory=list)


def plan(out: str | Path, driver: str, conditions: Sequence[str], trials: int, seed: int,
         scenario: str | None = None, overrides: Sequence[str] = (), parquet: bool = False) -> list[TrialSpec]:
    """The trials of a paired study, pair by pair (trial ``i`` of every condition gets seed ``seed + i``).

    :param out: the study directory (the trials go to ``<out>/trials/<condition>-<NNN>``)
    :param driver: driver file (``agents/<name>.toml``)
    :param conditions: any of :data:`~dt_highway.conditions.CONDITIONS` (``baseline``, ``adas``,
        ``adas-type``, ``adas-threat``, ``sham``...), each once
    :param trials: trials per condition (pairs) [-]
    :param seed: seed of the first pair, an integer >= 0
    :param scenario: scenario file or ``None``
    :param overrides: ``--set`` strings
    :param parquet: also write each trial's ``steps.parquet`` once it has completed
    :return: one :class:`TrialSpec` per trial
    :raises ConfigError: on an unknown or repeated condition, ``trials < 1``, a seed that is not an integer >= 0, or
        an ``overlay.mode`` override beside a condition that names its mode
    """
    if isinstance(conditions, str):
        raise ConfigError(f"conditions must be a list of names, e.g. ['baseline', 'adas'] (got the string {conditions!r})")
    if not isinstance(conditions, (list, tuple)):
        raise ConfigError(f"conditions must be a list of names, e.g. ['baseline', 'adas'] (got {type(conditions).__name__})")
    overrides = check_overrides(overrides)
    if whole_number(trials) is None:
        raise ConfigError(f"--trials must be a whole number >= 1 (got {trials!r})")
    if whole_number(seed) is None or seed < 0:
        raise ConfigError(f"--seed must be a whole number >= 0 (got {seed!r})")
    trials, seed = int(trials), int(seed)  # numpy integers too
    for c in conditions:
        condition_config(c)
    check_mode_override(conditions, overrides)
    if len(set(conditions)) != len(conditions) or not conditions:
        raise ConfigError(f"--conditions must name each condition once (got {','.join(conditions) or 'none'})")
    if trials < 1:
        raise ConfigError(f"--trials must be >= 1 (got {trials})")
    return [TrialSpec(str(Path(out) / "trials" / f"{c}-{i:03d}"), driver, c, i, seed + i, scenario, tuple(overrides),
                      parquet=parquet) for i in range(trials) for c in conditions]


def run_study(specs: Sequence[TrialSpec], out: str | Path, workers: int = 2,
              progress: Callable[[dict[str, Any]], None] | None = None, backend: str = "process",
              ray_address: str | None = None) -> StudyResult:
    """Run the trials (in a process pool, or as Ray tasks), skipping those already completed.

    :param specs: the trials (:func:`plan`)
    :param out: the study directory (``study.json`` is written there)
    :param workers: parallel trials [-]
    :param progress: called with each trial's result as it finishes
    :param backend: ``process`` (default) or ``ray``
    :param ray_address: an existing Ray cluster's address (``ray`` backend)
    :return: the trials completed, skipped and failed
    :raises ConfigError: on a backend that cannot run (:func:`check_backend`) or a resumed study's other settings
    """
    check_backend(backend, ray_address)
    if whole_number(workers) is None or workers < 1:
        raise ConfigError(f"--workers must be a whole number >= 1 (got {workers!r})")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    recorded = check_resume(out, specs)
    trials = {**recorded, **{s.directory: asdict(s) for s in specs}}  # trials of earlier runs stay on record
    replace_text(out / "study.json", dump_json({"trials": list(trials.values())}) + "\n")  # never half written
    result = StudyResult(str(out))

    def record(r: dict[str, Any]) -> None:
        if r["status"] == "completed":
            result.completed.append(r["directory"])
        elif r["status"] == "skipped":
            result.skipped.append(r["directory"])
        else:
            result.failed.append({"directory": r["directory"], "error": r.get("error", "?")})
        if progress is not None:
            progress(r)

    todo = []
    with _sigterm_as_ctrl_c(None):  # a job scheduler's stop meanwhile: the study stops as on Ctrl-C
        for s in specs:  # trials done by an earlier run are read here: no worker (nor Ray) is started for them
            try:
                done = _done_result(s)
            except Exception as err:  # noqa: BLE001 - a damaged log (an older version's): reported, as a worker would
                done = {"status": "failed", "directory": s.directory, "error": f"{type(err).__name__}: {err}"}
            if done is None:
                todo.append(s)
            else:
                record(done)
        if todo and backend != "ray":  # Ray takes the signals its own way (_run_ray)
            if workers <= 1:  # in this process: SIGTERM closes the running trial's log as Ctrl-C does
                for s in todo:
                    record(run_trial(s))
            else:
                _run_pool(todo, workers, record)  # its own handler, inside this one, also stops the workers
    if todo and backend == "ray":
        _run_ray(todo, ray_address, workers, record)
    return result


_stop_event: Any = None  # in a study's worker process: the study's stop flag (a multiprocessing Event)
_stopped = False  # in a study's worker process: set by Ctrl-C, after which it starts no trial
_idle = threading.Event()  # in a study's worker process: set while no trial runs
_idle.set()
ORPHAN_GRACE_S = 30.0
"""A worker whose study process died (SIGKILL, a crash) gives its trial this long to close its log [s]"""


def _sigint_seen(signum: int, frame: Any) -> None:
    global _stopped
    _stopped = True


def _worker_init(stop: Any) -> None:
    """Start a study's worker process: Ctrl-C between trials is remembered (during one, it interrupts it),
    and the worker ends when the study's process does (:func:`_exit_with_parent`)."""
    global _stop_event
    _stop_event = stop
    signal.signal(signal.SIGINT, _sigint_seen)
    parent = parent_process()
    if parent is not None:
        threading.Thread(target=_exit_with_parent, args=(parent,), name="dt-highway-orphan-watch", daemon=True).start()


def _exit_with_parent(parent: BaseProcess, grace_s: float = ORPHAN_GRACE_S) -> None:
    """In a worker: wait for the study's process to end. A study that stops normally ends its workers first;
    one that was killed (SIGKILL, out of memory, a crash) cannot, and its workers would run on as orphans,
    finishing trials nobody collects and waiting for work forever. Stop the trial under way as Ctrl-C does
    (its log is closed as aborted, "interrupted by the user", so that resuming runs it again), then exit."""
    parent.join()
    if not _idle.is_set():
        os.kill(os.getpid(), signal.SIGINT)
        _idle.wait(grace_s)
    os._exit(1)


def _pool_trial(spec: TrialSpec) -> dict[str, Any]:
    """Run one trial in a worker process of the pool.

    :func:`run_trial` in a worker process: not started after Ctrl-C, interrupted by it.

    :return: run_trial's result, or status ``cancelled`` (not started) or ``interrupted``
    """
    global _stopped
    _idle.clear()
    try:
        signal.signal(signal.SIGINT, signal.default_int_handler)
        # asked after the handler is swapped: a Ctrl-C just before the swap went to _sigint_seen (and the trial
        # would have run to its end), one after it raises
        if _stopped or (_stop_event is not None and _stop_event.is_set()):
            return {"status": "cancelled", "directory": spec.directory}
        return run_trial(spec)
    except KeyboardInterrupt:  # its log is closed as aborted, "interrupted by the user"
        _stopped = True
        return {"status": "interrupted", "directory": spec.directory}
    finally:
        signal.signal(signal.SIGINT, _sigint_seen)
        _idle.set()


@contextmanager
def _sigint_ignored() -> Iterator[None]:
    """Ignore Ctrl-C while worker processes start: they inherit it, so that a half-started
    worker cannot die of it (with a traceback); :func:`_worker_init` then takes it over."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)


def _run_pool(specs: Sequence[TrialSpec], workers: int, record: Callable[[dict[str, Any]], None]) -> None:
    """Run the trials in a process pool, passing each result to ``record`` as it finishes.

    On Ctrl-C no queued trial starts; the running ones (whose processes got the SIGINT too)
    stop, and :class:`KeyboardInterrupt` is raised once they have. A SIGTERM to the study's
    process (``kill PID``, a job scheduler) does the same: it is passed on to the workers as a
    SIGINT (they would not get it: before, they ran on as orphans) and then taken as a Ctrl-C.
    """
    ctx = get_context("spawn")
    stop = ctx.Event()
    with ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_worker_init, initargs=(stop,)) as pool, \
            _sigterm_as_ctrl_c(pool):
        try:
            with _sigint_ignored():  # the workers start at submit
                futures: dict[Future, TrialSpec] = {pool.submit(_pool_trial, s): s for s in specs}
            for fut in as_completed(futures):
                try:
                    r = fut.result()
                except KeyboardInterrupt:
                    r = {"status": "interrupted"}
                except Exception as err:  # noqa: BLE001 - a worker that died
                    r = {"status": "failed", "directory": futures[fut].directory, "error": f"{type(err).__name__}: {err}"}
                if r["status"] in ("interrupted", "cancelled"):  # a worker got Ctrl-C: so did we, or will
                    raise KeyboardInterrupt
                record(r)
        except KeyboardInterrupt:
            stop.set()  # trials already handed to a worker's queue do not start either
            pool.shutdown(wait=True, cancel_futures=True)
            raise


@contextmanager
def _sigterm_as_ctrl_c(pool: ProcessPoolExecutor | None) -> Iterator[None]:
    """While the pool runs (main thread only): SIGTERM sends SIGINT to the pool's workers (``None``: no pool yet),
    then raises :class:`KeyboardInterrupt` here; the previous handler comes back afterwards."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def on_term(signum: int, frame: Any) -> None:
        stop_workers = list(getattr(pool, "_processes", None) or {})  # the executor's worker pids (no public API)
        for pid in stop_workers:
            with suppress(OSError):
                os.kill(pid, signal.SIGINT)
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, on_term)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def check_backend(backend: str, ray_address: str | None = None) -> None:
    """Check that a study's backend can run, before any trial: a known backend, Ray installed
    for ``ray``, and a cluster's address that answers.

    :param backend: ``process`` or ``ray``
    :param ray_address: an existing Ray cluster's address (``ray`` backend; ``None``: a local Ray)
    :raises ConfigError: one line naming what is missing
    """
    if backend not in ("process", "ray"):
        raise ConfigError(f"unknown backend {backend!r} (allowed: process, ray)")
    if ray_address is not None and backend != "ray":
        raise ConfigError("--ray-address needs --backend ray (the default process backend runs on this machine)")
    if backend == "ray":
        try:
            import ray  # lazy: optional extra (pip install dt-highway[ray]) # noqa: F401
        except ImportError:
            raise ConfigError("--backend ray needs Ray: pip install 'dt-highway[ray]'") from None
        if ray_address is not None and ray_address != "auto":
            _check_reachable(ray_address)


def _check_reachable(address: str, timeout_s: float = 5.0) -> None:
    """Fail fast with one line when a Ray address (``host:port`` or ``ray://host:port``)
    does not answer (Ray itself retries for minutes)."""
    host, _, port = address.removeprefix("ray://").rpartition(":")
    if not host or not port.isdigit():
        raise ConfigError(f"--ray-address must be host:port, ray://host:port or auto (got {address!r})")
    try:
        socket.create_connection((host, int(port)), timeout=timeout_s).close()
    except OSError as err:
        raise ConfigError(f"cannot reach Ray at {address}: {err}") from None


def _open_log(directory: str | Path) -> tuple[dict[str, Any], int | None] | None:
    """A trial log that says ``running``: its metadata, and its writer's process id when that ran on this host.

    :return: ``None`` when the trial has no such log (not started, finished, or unreadable)
    """
    try:
        meta = json.loads((Path(directory) / "meta.json").read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(meta, dict) or meta.get("status") != "running":
        return None
    pid = meta.get("pid")
    return meta, (pid if isinstance(pid, int) and meta.get("host") == socket.gethostname() else None)


def _alive(pid: int) -> bool:
    """Whether process ``pid`` runs on this host (a zombie counts as gone)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return True


def _being_written(directory: str | Path) -> bool:
    """Whether a trial's log is open in a live process on this host."""
    log = _open_log(directory)
    return log is not None and log[1] is not None and _alive(log[1])


def _mark_abandoned(directory: str | Path, wait_s: float = 2.0) -> bool:
    """Mark a trial log left ``running`` by a process that was killed (a Ray task that did not stop
    when cancelled) as aborted, "interrupted by the user", once that process (on this host) is gone.

    :param wait_s: how long to wait for the process to end [s]
    :return: whether the log was marked
    """
    deadline = time.monotonic() + wait_s
    while _being_written(directory):
        if time.monotonic() > deadline:
            return False
        time.sleep(0.05)
    log = _open_log(directory)
    if log is None or log[1] is None:  # finished, or written on another host: left to that host
        return False
    meta = {**log[0], "status": "aborted", "end_reason": "interrupted by the user",
            "end_time": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
    path = Path(directory) / "meta.json"
    tmp = path.with_name("meta.json.tmp")
    tmp.write_text(dump_json(meta) + "\n")
    os.replace(tmp, path)
    return True


def _ray_trial(spec: TrialSpec) -> dict[str, Any]:
    """Run one trial in a Ray worker.

    :func:`run_trial` as a Ray task. Ray cancels a running task by a simulated SIGINT in its worker,
    which Python drops when SIGINT is ignored there (inherited from a study started as a background
    job): the task then ran on. Its worker's Python takes SIGINT for the task (the OS signal stays
    blocked in Ray's workers).
    """
    main = threading.current_thread() is threading.main_thread()
    if main and signal.getsignal(signal.SIGINT) in (signal.SIG_IGN, signal.SIG_DFL):
        signal.signal(signal.SIGINT, signal.default_int_handler)
    return run_trial(spec)


def _run_ray(specs: Sequence[TrialSpec], address: str | None, workers: int,
             record: Callable[[dict[str, Any]], None]) -> None:
    """Run the trials as Ray tasks (one CPU each), passing each result to ``record`` as it finishes.

    Without ``address`` a local Ray is started with ``workers`` CPUs and shut down after;
    with one, the tasks go to that cluster (whose workers must have ``dt-highway``
    installed and see the study directory, e.g. on a shared file system).

    Ctrl-C or SIGTERM: no queued trial starts, the running ones are cancelled (their logs are
    closed as aborted, "interrupted by the user"), and :class:`KeyboardInterrupt` is raised once
    they have stopped. Ray starts its workers with SIGINT blocked, so a terminal's Ctrl-C reaches
    only this process: the signal is recorded (:func:`~dt_highway.interrupts.signals_held`) and acted on here.
    """
    import ray  # lazy: optional extra (pip install dt-highway[ray]); check_backend found it

    started = not ray.is_initialized()
    try:
        if started:
            try:
                if address is None:
                    ray.init(num_cpus=max(1, workers), include_dashboard=False, log_to_driver=False)
                else:
                    ray.init(address=address, log_to_driver=False)
            except (ConnectionError, RuntimeError, ValueError) as err:
                raise ConfigError(f"cannot start or reach Ray at {address or 'a local instance'}: {err}") from None
        # recorded, not raised, whatever the handlers were: a study started as a background job (``cmd &`` in a
        # script) inherits SIGINT ignored and never saw Ctrl-C; after ray.init SIGTERM went to Ray's handler in C (the
        # process aborted with a C++ stack dump, its running trial's log left open), so this comes after ray.init
        with signals_held() as stop:
            try:
                cancelled = _ray_tasks(ray, specs, record, stop)
            finally:
                if started:
                    ray.shutdown()  # still under the counting handlers: a second Ctrl-C cannot break it
    finally:
        if started:  # after a Ctrl-C during ray.init (a no-op when shut down already)
            ray.shutdown()
    if stop.count:
        for directory in cancelled:  # a trial killed at the end of the grace period left its log open
            _mark_abandoned(directory)
        raise KeyboardInterrupt


def _ray_tasks(ray: Any, specs: Sequence[TrialSpec], record: Callable[[dict[str, Any]], None], stop: SignalsSeen,
               poll_s: float = 0.2, grace_s: float = 5.0, missed_s: float = 2.0) -> list[str]:
    """Submit the trials to Ray and pass their results to ``record`` until all are done or ``stop`` counts a signal;
    then cancel the rest, give the running ones ``grace_s`` to close their logs, and kill those that missed the cancel.

    :param ray: the ``ray`` module (initialised)
    :param poll_s: how often ``stop`` is read [s]
    :param grace_s: how long cancelled trials may take to stop [s]; a second signal ends it
    :param missed_s: a task whose reference is not ready this long after its cancel missed it [s]
    :return: the directories of the trials that were cancelled (empty unless stopped)
    """
    task = ray.remote(num_cpus=1, max_retries=0)(_ray_trial)
    pending = {task.remote(s): s for s in specs}
    while pending and not stop.count:
        done, _ = ray.wait(list(pending), num_returns=1, timeout=poll_s)
        for ref in done:
            spec = pending.pop(ref)
            try:
                r = ray.get(ref)
            except Exception as err:  # noqa: BLE001 - a task whose worker died
                r = {"status": "failed", "directory": spec.directory, "error": f"{type(err).__name__}: {err}"}
            record(r)
    if not stop.count:
        return []
    for ref in pending:  # the queued tasks do not start, the running ones get KeyboardInterrupt
        ray.cancel(ref)
    left = list(pending)
    t0 = time.monotonic()
    # a cancelled task's reference is ready at once and its log is closed a moment later; a task handed to a
    # worker at the moment of the cancel can miss it (and later ones): its reference stays pending, it runs on
    while stop.count < 2 and time.monotonic() < t0 + grace_s:
        _, left = ray.wait(left, num_returns=len(left), timeout=0) if left else ([], [])
        if left and time.monotonic() >= t0 + missed_s:
            _kill(ray, left)
            left = []
        if not left and not any(_being_written(s.directory) for s in pending.values()):
            break
        time.sleep(poll_s)
    _kill(ray, left)
    return [spec.directory for spec in pending.values()]


def _kill(ray: Any, refs: Sequence[Any]) -> None:
    """Kill the workers of Ray tasks that missed their cancel (their trial logs are marked aborted after)."""
    for ref in refs:
        ray.cancel(ref, force=True)

"""Ctrl-C during a study stops it within seconds, keeps what is done, and the same command resumes it."""

import json
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
import types
from contextlib import suppress
from pathlib import Path

import pytest

from dt_highway import study
from dt_highway.bench import _children
from dt_highway.cli import main
from dt_highway.interrupts import SignalsSeen, signals_held
from dt_highway.study import is_completed

REPO = Path(__file__).resolve().parents[1]
EXE = shutil.which("dt-highway") or str(Path(sys.executable).with_name("dt-highway"))
INTERRUPTED = ("aborted", "interrupted by the user")


PAIRS = 3
TRIALS = 2 * PAIRS  # baseline and ADAS


def _command(out: Path, *extra: str) -> list[str]:
    """A study of :data:`TRIALS` short trials on 2 workers (a short pre-roll too: the twin's history does not matter
    here): Ctrl-C comes when the first one has completed, while the other worker's trial runs."""
    return [EXE, "study", "--driver", "agents/idm.toml", "--scenario", "envs/highway-trial.toml", "--trials", str(PAIRS),
            "--workers", "2", "--set", "highway.duration=15", "--set", "twin.preroll_s=10", "--out", str(out), *extra]


def _metas(out: Path) -> dict[str, tuple[str, str] | None]:
    found: dict[str, tuple[str, str] | None] = {}
    for path in (out / "trials").glob("*/meta.json"):
        try:
            meta = json.loads(path.read_text())
            found[path.parent.name] = (meta["status"], meta["end_reason"])
        except (OSError, ValueError):  # being written
            found[path.parent.name] = None
    return found


def _interrupt_after_first_trial(cmd: list[str], out: Path, timeout_s: float = 60.0, stop_within_s: float = 10.0,
                                 sig: int = signal.SIGINT, sigint_ignored: bool = False,
                                 to_group: bool = True) -> tuple[dict, dict, str, float]:
    """Run the study in its own process group, send ``sig`` to the group (or to the study's process alone:
    ``kill PID``, ``timeout``) once a trial has completed while another one runs.

    :param sigint_ignored: start the study with SIGINT ignored, as a shell starts a background job
        (``cmd &`` in a script): Python then keeps it ignored
    :return: trial states just before the signal, after the exit, the output, seconds from signal to exit
    """
    env = {**os.environ, "SDL_VIDEODRIVER": "offscreen", "MPLBACKEND": "Agg"}
    disposition = signal.SIG_IGN if sigint_ignored else signal.SIG_DFL  # not inherited from whatever runs the tests
    proc = subprocess.Popen(cmd, cwd=REPO, env=env, start_new_session=True, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, preexec_fn=lambda: signal.signal(signal.SIGINT, disposition))
    try:
        deadline = time.monotonic() + timeout_s
        while True:  # a trial completed and another one running (its log open): the signal comes then
            before = _metas(out)
            states = {m[0] for m in before.values() if m}
            if {"completed", "running"} <= states:
                break
            assert proc.poll() is None and time.monotonic() < deadline, "the study ended or stalled before a trial"
            time.sleep(0.05)
        t0 = time.monotonic()
        if to_group:
            os.killpg(proc.pid, sig)  # as a terminal's Ctrl-C: the workers get it too
        else:
            os.kill(proc.pid, sig)
        output, _ = proc.communicate(timeout=stop_within_s + 10)
        took = time.monotonic() - t0
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
    assert proc.returncode == 130, output
    return before, _metas(out), output, took


def _check_interrupted(cmd: list[str], before: dict, after: dict, output: str, took: float,
                       stop_within_s: float = 10.0) -> list[str]:
    """Stopped in time with one line, finished trials kept, the others aborted "interrupted by the user"
    (on Ray too: a trial handed to a worker at the moment of the signal is cancelled again, or killed and marked)."""
    assert took < stop_within_s, f"took {took:.1f} s to stop"
    assert "Traceback" not in output, output
    assert f"resume with: dt-highway {' '.join(cmd[1:])}" in output, output
    done = [name for name, m in before.items() if m and m[0] == "completed"]
    for name in done:  # finished trials are kept
        assert after[name] == before[name]
    for name, m in after.items():  # the others were stopped, and none ran to its end after the signal
        assert m is not None and (m[0] == "completed" or m == INTERRUPTED), (name, m)
        assert name in before or m == INTERRUPTED, f"{name} started after the signal and ran to its end"
    assert len(after) < TRIALS and sum(m[0] == "completed" for m in after.values() if m) < TRIALS
    return [name for name, m in after.items() if m and m[0] == "completed"]


def test_ctrl_c_stops_a_study_in_seconds_and_the_same_command_resumes_it(tmp_path):
    out = tmp_path / "study"
    cmd = _command(out)
    before, after, output, took = _interrupt_after_first_trial(cmd, out)
    assert any(m == INTERRUPTED for m in after.values()), after  # a running trial was interrupted, its log closed
    done = _check_interrupted(cmd, before, after, output, took)
    kept = {name: (out / "trials" / name / "steps.csv").read_bytes() for name in done}

    env = {**os.environ, "SDL_VIDEODRIVER": "offscreen", "MPLBACKEND": "Agg"}
    # the resumed run takes ~15 s on a quiet machine, minutes on a loaded one
    again = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr
    assert f"{TRIALS - len(done)} trials run, {len(done)} already done, 0 failed" in again.stdout
    first_bar = re.search(rf"study:\s+\d+%\|[^|]*\|\s*(\d+)/{TRIALS}", again.stderr)
    assert first_bar and int(first_bar.group(1)) == len(done), again.stderr  # the skipped trials count as done
    assert all(m == ("completed", "time limit") for m in _metas(out).values()) and len(_metas(out)) == TRIALS
    for name, data in kept.items():  # skipped, not run again
        assert (out / "trials" / name / "steps.csv").read_bytes() == data


def test_sigterm_to_a_process_pool_study_stops_it_as_ctrl_c_does(tmp_path):
    """``kill PID`` (a job scheduler's stop): before, the study died at once (exit -15, no message) and its
    workers ran on as orphans, one starting and finishing a trial afterwards."""
    out = tmp_path / "study"
    cmd = _command(out)
    before, after, output, took = _interrupt_after_first_trial(cmd, out, sig=signal.SIGTERM, to_group=False)
    _check_interrupted(cmd, before, after, output, took)
    time.sleep(1.0)  # no orphan goes on writing
    assert _metas(out) == after


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads the process table from /proc")
def test_a_killed_study_leaves_no_worker_behind_and_their_trials_marked_to_run_again(tmp_path):
    """SIGKILL (or the OOM killer) gives the study no chance to stop its process pool: before, its workers ran on
    as orphans, finishing trials nobody collected, then waiting for work forever."""
    out = tmp_path / "study"
    env = {**os.environ, "SDL_VIDEODRIVER": "offscreen", "MPLBACKEND": "Agg"}
    proc = subprocess.Popen(_command(out), cwd=REPO, env=env, start_new_session=True, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120.0
        while not any(m and m[0] == "running" for m in _metas(out).values()):
            assert proc.poll() is None and time.monotonic() < deadline, "the study ended or stalled before a trial"
            time.sleep(0.05)
        workers = [c for c in _children([proc.pid]) if b"spawn_main" in Path(f"/proc/{c}/cmdline").read_bytes()]
        assert len(workers) == 2, workers  # the pool's workers (not multiprocessing's resource tracker)
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
        deadline = time.monotonic() + 60.0
        while any(study._alive(w) for w in workers) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not [w for w in workers if study._alive(w)], "orphaned workers still running"
    finally:
        with suppress(ProcessLookupError):  # whatever is left of the study's process group
            os.killpg(proc.pid, signal.SIGKILL)
    metas = _metas(out)
    assert metas and all(m is not None and (m[0] == "completed" or m == INTERRUPTED) for m in metas.values()), metas


@pytest.mark.parametrize("sig, sigint_ignored", [(signal.SIGINT, False), (signal.SIGINT, True), (signal.SIGTERM, False)],
                         ids=["ctrl-c", "ctrl-c-to-a-background-job", "sigterm-to-the-process"])
def test_ctrl_c_stops_a_study_on_a_local_ray(tmp_path, sig, sigint_ignored):
    """Ray starts its workers with SIGINT blocked: only the study's own process sees a Ctrl-C, and it must act
    on it even when started with SIGINT ignored (a background job: before, the study then ran all its trials
    and exited 0), or when Ray's handlers would take the signal (SIGTERM: Ray aborted with a C++ stack dump)."""
    pytest.importorskip("ray", reason="the test extras install ray; without it this backend cannot run")
    out = tmp_path / "study"
    cmd = _command(out, "--backend", "ray")
    before, after, output, took = _interrupt_after_first_trial(cmd, out, timeout_s=120, sig=sig, sigint_ignored=sigint_ignored,
                                                               to_group=sig == signal.SIGINT)
    print(f"stopped {took:.2f} s after the signal; before: {before}; after: {after}")  # shown by pytest -rP
    _check_interrupted(cmd, before, after, output, took)


def test_study_refuses_an_out_directory_that_is_not_a_study(tmp_path, capsys):
    other = tmp_path / "mine"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    assert main(["study", "--driver", "agents/idm.toml", "--out", str(other), "--trials", "1"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "exists and is not a study" in err
    assert sorted(p.name for p in other.iterdir()) == ["notes.txt"]  # nothing written there
    (tmp_path / "file").write_text("x")
    assert main(["study", "--driver", "agents/idm.toml", "--out", str(tmp_path / "file")]) == 2
    assert f"{tmp_path / 'file'} is a file, not a folder" in capsys.readouterr().err


def test_signals_are_counted_not_raised_while_ray_runs_and_the_handlers_come_back():
    outside: list[int] = []  # a SIGTERM that the block did not take lands here, not in the end of the test run
    guard = signal.signal(signal.SIGTERM, lambda signum, frame: outside.append(signum))
    try:
        before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
        with signals_held() as stop:
            os.kill(os.getpid(), signal.SIGINT)  # no KeyboardInterrupt here
            os.kill(os.getpid(), signal.SIGTERM)
            for _ in range(100):
                if stop.count == 2:
                    break
                time.sleep(0.01)
            assert (stop.count, stop.first, outside) == (2, signal.SIGINT, [])
        assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == before
    finally:
        signal.signal(signal.SIGTERM, guard)


class _FakeRay:
    """Ray's calls as _ray_tasks makes them: ``a`` finishes, then Ctrl-C; ``b`` stops when cancelled, ``c`` misses it."""

    def __init__(self, stop):
        self.stop, self.ready, self.cancels = stop, {"a"}, []

    def remote(self, **_):
        return lambda fn: type("Task", (), {"remote": staticmethod(lambda spec: Path(spec.directory).name)})

    def wait(self, refs, num_returns, timeout):
        ready = [r for r in refs if r in self.ready][:num_returns]
        if "a" in ready:
            self.stop(signal.SIGINT, None)
        return ready, [r for r in refs if r not in ready]

    def get(self, ref):
        return {"status": "completed", "directory": ref}

    def cancel(self, ref, force=False):
        self.cancels.append((ref, force))
        if ref == "b" or force:
            self.ready.add(ref)


def test_ray_trials_stop_on_a_signal_and_a_task_that_misses_its_cancel_is_killed(tmp_path):
    stop = SignalsSeen()
    ray = _FakeRay(stop)
    specs = [study.TrialSpec(str(tmp_path / n), "agents/idm.toml", "baseline", i, i) for i, n in enumerate("abc")]
    recorded = []
    t0 = time.monotonic()
    cancelled = study._ray_tasks(ray, specs, recorded.append, stop, poll_s=0.01, missed_s=0.1)
    assert recorded == [{"status": "completed", "directory": "a"}]  # finished before the signal: kept
    assert ray.cancels == [("b", False), ("c", False), ("c", True)]  # c missed its cancel: killed after missed_s
    assert cancelled == [str(tmp_path / "b"), str(tmp_path / "c")] and time.monotonic() - t0 < 1.0


def test_a_log_left_running_by_a_killed_worker_is_marked_aborted(tmp_path):
    dead = subprocess.Popen(["true"])
    dead.wait()  # reaped: its pid is free
    meta = {"status": "running", "end_reason": None, "host": socket.gethostname(), "pid": dead.pid, "seed": 7}
    for name, changes in {"killed": {}, "alive": {"pid": os.getpid()}, "done": {"status": "completed"},
                          "elsewhere": {"host": "another-host"}}.items():
        (tmp_path / name).mkdir()
        (tmp_path / name / "meta.json").write_text(json.dumps({**meta, **changes}))
    assert study._mark_abandoned(tmp_path / "killed")
    marked = json.loads((tmp_path / "killed" / "meta.json").read_text())
    assert (marked["status"], marked["end_reason"], marked["seed"]) == ("aborted", "interrupted by the user", 7)
    assert not is_completed(tmp_path / "killed")  # resume runs it again
    for name, status in (("alive", "running"), ("done", "completed"), ("elsewhere", "running")):  # untouched
        assert not study._mark_abandoned(tmp_path / name, wait_s=0.1)
        assert json.loads((tmp_path / name / "meta.json").read_text())["status"] == status


def test_a_ctrl_c_as_a_worker_takes_its_next_trial_cancels_it(monkeypatch):
    """The flake of test_sigterm_to_a_process_pool_study_stops_it_as_ctrl_c_does: a SIGINT that reached a worker
    after it asked whether to stop and before it swapped in the handler that interrupts a trial went to the
    between-trials handler, and the trial then ran to its end."""
    import dt_highway.study as study

    ran: list[str] = []
    monkeypatch.setattr(study, "run_trial", lambda spec: ran.append(spec.directory) or {"status": "completed"})
    monkeypatch.setattr(study, "_stopped", False)
    real = signal.signal

    def swap(signum, handler):
        if signum == signal.SIGINT and handler is signal.default_int_handler:
            study._sigint_seen(signum, None)  # the SIGINT lands just as the handler is swapped in
        return real(signum, handler)

    monkeypatch.setattr(study.signal, "signal", swap)
    spec = types.SimpleNamespace(directory="trials/baseline-001")
    try:
        assert study._pool_trial(spec) == {"status": "cancelled", "directory": "trials/baseline-001"}
        assert ran == []
    finally:
        real(signal.SIGINT, signal.default_int_handler)

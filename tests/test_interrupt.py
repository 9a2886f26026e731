"""Ctrl-C during a study stops it within seconds, keeps what is done, and the same command resumes it."""

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from dt_highway.cli import main

REPO = Path(__file__).resolve().parents[1]
EXE = shutil.which("dt-highway") or str(Path(sys.executable).with_name("dt-highway"))
INTERRUPTED = ("aborted", "interrupted by the user")


def _command(out: Path, *extra: str) -> list[str]:
    return [EXE, "study", "--driver", "agents/idm.toml", "--scenario", "envs/highway-trial.toml", "--trials", "4",
            "--workers", "2", "--set", "highway.duration=30", "--out", str(out), *extra]


def _metas(out: Path) -> dict[str, tuple[str, str] | None]:
    found: dict[str, tuple[str, str] | None] = {}
    for path in (out / "trials").glob("*/meta.json"):
        try:
            meta = json.loads(path.read_text())
            found[path.parent.name] = (meta["status"], meta["end_reason"])
        except (OSError, ValueError):  # being written
            found[path.parent.name] = None
    return found


def _interrupt_after_first_trial(cmd: list[str], out: Path, timeout_s: float = 60.0,
                                 stop_within_s: float = 10.0) -> tuple[dict, dict, str, float]:
    """Run the study in its own process group, SIGINT the group once a trial has completed.

    :return: trial states just before the signal, after the exit, the output, seconds from signal to exit
    """
    env = {**os.environ, "SDL_VIDEODRIVER": "offscreen", "MPLBACKEND": "Agg"}
    proc = subprocess.Popen(cmd, cwd=REPO, env=env, start_new_session=True, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.monotonic() + timeout_s
        while not any(m and m[0] == "completed" for m in _metas(out).values()):
            assert proc.poll() is None and time.monotonic() < deadline, "the study ended or stalled before a trial"
            time.sleep(0.05)
        before = _metas(out)
        t0 = time.monotonic()
        os.killpg(proc.pid, signal.SIGINT)  # as a terminal's Ctrl-C: the workers get it too
        output, _ = proc.communicate(timeout=stop_within_s + 10)
        took = time.monotonic() - t0
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
    assert proc.returncode == 130, output
    return before, _metas(out), output, took


def _check_interrupted(cmd: list[str], before: dict, after: dict, output: str, took: float,
                       strict: bool = True, stop_within_s: float = 10.0) -> list[str]:
    """``strict``: no trial may run to its end after the signal (the process pool); on Ray a trial
    handed to a worker at the moment of the signal may still finish (seen once in two runs)."""
    assert took < stop_within_s, f"took {took:.1f} s to stop"
    assert "Traceback" not in output, output
    assert f"resume with: dt-highway {' '.join(cmd[1:])}" in output, output
    done = [name for name, m in before.items() if m and m[0] == "completed"]
    for name in done:  # finished trials are kept
        assert after[name] == before[name]
    for name, m in after.items():  # the others were stopped, and none ran to its end after the signal
        assert m is not None and (m[0] == "completed" or m == INTERRUPTED), (name, m)
        assert not strict or name in before or m == INTERRUPTED, f"{name} started after the signal"
    assert len(after) < 8 and sum(m[0] == "completed" for m in after.values() if m) < 8
    return [name for name, m in after.items() if m and m[0] == "completed"]


def test_ctrl_c_stops_a_study_in_seconds_and_the_same_command_resumes_it(tmp_path):
    out = tmp_path / "study"
    cmd = _command(out)
    before, after, output, took = _interrupt_after_first_trial(cmd, out)
    assert any(m == INTERRUPTED for m in after.values()), after  # a running trial was interrupted, its log closed
    done = _check_interrupted(cmd, before, after, output, took)
    kept = {name: (out / "trials" / name / "steps.csv").read_bytes() for name in done}

    env = {**os.environ, "SDL_VIDEODRIVER": "offscreen", "MPLBACKEND": "Agg"}
    again = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=60)
    assert again.returncode == 0, again.stderr
    assert f"{8 - len(done)} trials run, {len(done)} already done, 0 failed" in again.stdout
    first_bar = re.search(r"study:\s+\d+%\|[^|]*\|\s*(\d+)/8", again.stderr)
    assert first_bar and int(first_bar.group(1)) == len(done), again.stderr  # the skipped trials count as done
    assert all(m == ("completed", "time limit") for m in _metas(out).values()) and len(_metas(out)) == 8
    for name, data in kept.items():  # skipped, not run again
        assert (out / "trials" / name / "steps.csv").read_bytes() == data


@pytest.mark.xfail(strict=False, reason="known limit (issue 21): on a loaded machine a local Ray study has been seen to "
                   "take over 10 s to stop, and once to run all its trials to the end after Ctrl-C (exit 0)")
def test_ctrl_c_stops_a_study_on_a_local_ray(tmp_path):
    pytest.importorskip("ray", reason="the test extras install ray; without it this backend cannot run")
    out = tmp_path / "study"
    cmd = _command(out, "--backend", "ray")
    # Ray waits up to 10 s for the cancelled tasks to close their logs, then shuts down: under load (a
    # fresh-check with other jobs on the 2 cores) that took over 10 s once; alone it stops in ~3 s
    before, after, output, took = _interrupt_after_first_trial(cmd, out, timeout_s=90, stop_within_s=20.0)
    _check_interrupted(cmd, before, after, output, took, strict=False, stop_within_s=20.0)


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
    assert "is not a directory" in capsys.readouterr().err

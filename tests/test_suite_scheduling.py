"""How the suite's tests are shared out between its 2 pytest-xdist workers (``tests/conftest.py``)."""

import re
from pathlib import Path

from conftest import WALL_CLOCK, WHOLE_FILE, pytest_xdist_make_scheduler

ROOT = Path(__file__).resolve().parents[1]


class _Config:
    """The two options the scheduler reads from pytest's configuration."""

    def __init__(self, dist: str) -> None:
        self.values = {"dist": dist, "tx": ["2*popen"]}

    def getvalue(self, name: str) -> object:
        return self.values[name]


def test_every_test_the_scheduling_names_exists():
    """A renamed file or test would silently leave the unit it was put in."""
    for entry in (*WALL_CLOCK, *WHOLE_FILE):
        path, _, test = entry.partition("::")
        assert (ROOT / path).is_file(), entry
        if test:
            assert re.search(rf"^def {re.escape(test)}\(", (ROOT / path).read_text(), re.MULTILINE), entry


def test_wall_clock_tests_form_one_unit_and_whole_files_another_the_rest_one_each():
    units = pytest_xdist_make_scheduler(_Config("load"), None)
    split = units._split_scope  # type: ignore[attr-defined]
    assert split("tests/test_interrupt.py::test_sigterm_to_a_process_pool_study_stops_it_as_ctrl_c_does") == "wall_clock"
    assert split("tests/test_drive.py::test_a_replayed_trial_is_logged_completely_with_the_scripted_keys") == "wall_clock"
    assert split("tests/test_study.py::test_the_ray_backend_runs_the_same_trials_on_a_local_ray") == "wall_clock"
    # the rest of test_study.py, and a file whose name only begins like a named one, are shared out test by test
    other = "tests/test_study.py::test_study_and_report_commands"
    assert split(other) == other
    assert split("tests/test_drivers.py::test_x") == "tests/test_drivers.py::test_x"
    assert split("tests/test_calibration.py::test_a_bad_knob_is_one_line_before_any_trial[a]") == "tests/test_calibration.py::"
    assert split("tests/test_replay.py::test_y") == "tests/test_replay.py::"


def test_another_dist_mode_is_left_to_pytest_xdist():
    assert pytest_xdist_make_scheduler(_Config("loadfile"), None) is None
    assert pytest_xdist_make_scheduler(_Config("no"), None) is None


def test_a_test_that_leaves_sigint_changed_is_named_and_the_next_sees_the_handler_back(tmp_path):
    """One fresh-check saw a test fail because an earlier one on its worker had left SIGINT ignored."""
    import shutil
    import signal
    import subprocess
    import sys

    shutil.copy(ROOT / "tests" / "conftest.py", tmp_path / "conftest.py")
    (tmp_path / "test_leak.py").write_text(
        "import signal\n\n\ndef test_leaks():\n    signal.signal(signal.SIGINT, signal.SIG_IGN)\n\n\n"
        "def test_after():\n    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler\n")
    # the child's SIGINT as a terminal's, not inherited from whatever runs the tests (a suite started as a background
    # job, `cmd &` in a script, runs with SIGINT ignored, and a Python started so keeps it ignored)
    run = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:randomly", "-p", "no:cacheprovider",
                          str(tmp_path / "test_leak.py")], cwd=tmp_path, capture_output=True, text=True, timeout=120,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    assert "2 passed" in run.stdout, run.stdout + run.stderr
    assert "test_leak.py::test_leaks left the SIGINT handler <Handlers.SIG_IGN: 1>" in run.stdout, run.stdout

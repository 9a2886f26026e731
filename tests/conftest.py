"""Shared settings of the test suite.

The suite runs on 2 pytest-xdist workers (``addopts`` in ``pyproject.toml``); ``python -m pytest -n 0`` runs it in
one process. How the tests are shared out is :func:`pytest_xdist_make_scheduler` below.
"""

import os

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
os.environ.setdefault("MPLBACKEND", "Agg")

import pytest

#: a small, fast scenario for tests (few vehicles, short episode and pre-roll)
SMALL = {
    "highway": {"vehicles_count": 12, "duration": 6.0, "lanes_count": 3},
    "traffic": {"population_size": 60},
    "twin": {"preroll_s": 5.0},
}


@pytest.fixture
def small_config() -> dict:
    import copy

    return copy.deepcopy(SMALL)


@pytest.fixture(autouse=True)
def _sigint_handler_kept(request: pytest.FixtureRequest):
    """A test that leaves SIGINT handled otherwise (ignored, say) changes every later test on its worker (the
    twenty-third session saw one such failure, its cause unfound): put the handler back after each test, and name
    the test in a warning (in the run's warnings summary, from every worker)."""
    import signal
    import threading
    import warnings

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    before = signal.getsignal(signal.SIGINT)
    yield
    after = signal.getsignal(signal.SIGINT)
    if after is not before:
        signal.signal(signal.SIGINT, before)
        warnings.warn(f"{request.node.nodeid} left the SIGINT handler {after!r} (was {before!r}; put back)",
                      UserWarning, stacklevel=1)


def numba_interrupt() -> SystemError:
    """What Ctrl-C during a numba-compiled call raises: a SystemError whose cause is the KeyboardInterrupt
    (``tests/test_interrupts.py`` checks it on the real thing)."""
    try:
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as ki:
            raise SystemError("CPUDispatcher(<function _perspective>) returned a result with an exception set") from ki
    except SystemError as err:
        return err


#: tests that measure wall time (a pause, a window close, Ctrl-C answered within seconds) or run studies and keyboard
#: sessions in other processes (process pools, a local Ray): one worker runs them one after another, so two of them
#: never share the 2 cores (the other worker runs the rest meanwhile)
WALL_CLOCK = ("tests/test_interrupt.py::", "tests/test_drive_trial.py::", "tests/test_drive.py::",
              "tests/test_session_flow.py::", "tests/test_study.py::test_the_ray_backend_runs_the_same_trials_on_a_local_ray")
#: files whose tests share one costly module fixture (a calibration run, a keyboard trial): one worker runs each whole
WHOLE_FILE = ("tests/test_calibration.py::", "tests/test_replay.py::")


@pytest.hookimpl(optionalhook=True)  # pytest-xdist's hook: without pytest-xdist, unused
def pytest_xdist_make_scheduler(config: pytest.Config, log: object) -> object | None:
    """Under ``--dist load`` (``-n 2``'s default), the tests are shared out one by one as there, except that the tests of
    :data:`WALL_CLOCK` form one unit of work, and each file of :data:`WHOLE_FILE` another; any other ``--dist`` is left
    to pytest-xdist.

    Not ``xdist_group`` marks with ``--dist loadgroup``: pytest-xdist 3.8 puts the group into ``item._nodeid``, which
    pytest 9.2 no longer reads, so the marks are silently ignored there (checked on 2026-11-28).
    """
    if config.getvalue("dist") != "load":
        return None
    from xdist.scheduler import LoadScopeScheduling

    class _Units(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            if nodeid.startswith(WALL_CLOCK):
                return "wall_clock"
            return next((f for f in WHOLE_FILE if nodeid.startswith(f)), nodeid)

    return _Units(config, log)

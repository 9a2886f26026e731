"""Ctrl-C inside numba code: what Python receives, and how the CLI answers it."""

import signal

import numpy as np
import pytest
from conftest import numba_interrupt

from dt_highway.camera.pinhole import _perspective
from dt_highway.cli import main
from dt_highway.interrupts import interrupted_by_user


def test_every_interrupt_fired_into_numba_code_is_recognised_as_the_users():
    """The real thing: a SIGALRM handler raises KeyboardInterrupt while the camera's compiled projection
    runs in a loop; what comes out is the interrupt or a SystemError caused by it (often: numba's
    dispatcher returns a result with the error set), and each is the user's interrupt."""
    points = np.random.default_rng(0).normal(size=(20, 3)) + [0.0, 0.0, 5.0]
    _perspective(points, 1.0, 1.0, 0.0, 0.0, 0.1)  # compiled before the timer runs

    def handler(signum, frame):
        raise KeyboardInterrupt

    old = signal.signal(signal.SIGALRM, handler)
    kinds = []
    try:
        for _ in range(40):
            try:  # the timer starts inside the try: however late the signal is handled, it is caught here
                signal.setitimer(signal.ITIMER_REAL, 0.0003)
                while True:
                    _perspective(points, 1.0, 1.0, 0.0, 0.0, 0.1)
            except (KeyboardInterrupt, SystemError) as err:
                kinds.append((type(err).__name__, interrupted_by_user(err)))
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)
    assert len(kinds) == 40 and all(ok for _, ok in kinds), kinds
    print("exceptions seen:", {k: sum(1 for name, _ in kinds if name == k) for k in {n for n, _ in kinds}})
    assert not interrupted_by_user(SystemError("not an interrupt")) and not interrupted_by_user(None)


@pytest.mark.parametrize("raised, code", [(numba_interrupt, 130), (lambda: SystemError("a real bug"), None)])
def test_the_cli_exits_130_on_ctrl_c_inside_numba_code_and_lets_a_real_system_error_through(monkeypatch, capsys,
                                                                                             raised, code):
    def boom(*args, **kwargs):
        raise raised()

    monkeypatch.setattr("dt_highway.evaluation.twin.evaluate_twin", boom)  # what twin-eval runs (imports when run)
    if code is None:
        with pytest.raises(SystemError, match="a real bug"):
            main(["twin-eval", "--quiet"])
    else:
        assert main(["twin-eval", "--quiet"]) == code
        assert capsys.readouterr().err.strip() == "dt-highway twin-eval: interrupted"

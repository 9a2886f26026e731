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

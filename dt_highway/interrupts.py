"""Ctrl-C, also when it arrives inside compiled code.

A :class:`KeyboardInterrupt` that a signal handler raises while a numba-compiled function runs
reaches Python as ``SystemError: CPUDispatcher(...) returned a result with an exception set``
(CPython's check of a C call that returned a value with an error set), whose ``__cause__`` is the
interrupt. The camera, the traffic core and the safety metrics run numba code at every step, so a
Ctrl-C, a SIGTERM turned into one, or Ray cancelling a task can land there (measured: about 1 in
300 interrupts of an ADAS env step, 2 in 3 of a loop of camera projections). The places that handle
Ctrl-C while simulating (a study's trials, RL training, the pre-roll helper, the command line) ask
:func:`interrupted_by_user` instead of catching ``KeyboardInterrupt`` alone; the keyboard trials
simulate in a thread that never receives signals.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from typing import Any


def interrupted_by_user(exc: BaseException | None) -> bool:
    """Whether an exception is Ctrl-C (a :class:`KeyboardInterrupt`) or was raised because of one.

    :param exc: the exception (``None``: no exception)
    :return: whether it or an exception in its chain of causes and contexts is a KeyboardInterrupt
    """
    seen: set[int] = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


class SignalsSeen:
    """A signal handler that records the signals instead of acting on them (:func:`signals_held`).

    It never raises: a :class:`KeyboardInterrupt` inside Ray's client code can leave Ray half-way through a call,
    and one inside a trial log's last write leaves the log "running"; the caller reads what came instead.
    """

    def __init__(self) -> None:
        self.signums: list[int] = []

    def __call__(self, signum: int, frame: Any) -> None:
        """Record the signal (a signal handler)."""
        self.signums.append(signum)

    @property
    def count(self) -> int:
        """How many signals came."""
        return len(self.signums)

    @property
    def first(self) -> int | None:
        """The first signal that came (``None``: none)."""
        return self.signums[0] if self.signums else None


@contextmanager
def signals_held(signums: Sequence[int] = (signal.SIGINT, signal.SIGTERM), *,
                 over_foreign: bool = True) -> Iterator[SignalsSeen]:
    """Record the signals ``signums`` instead of acting on them until the block is left; then the previous handlers
    are back. Off the main thread, where Python cannot catch signals, nothing is recorded.

    :param signums: the signals to hold
    :param over_foreign: also take a signal whose handler was not set from Python (Ray's, in C), which cannot be put
        back: the default handler follows the block. ``False`` leaves such a signal alone.
    :return: a context manager that yields the :class:`SignalsSeen` that records them
    """
    seen = SignalsSeen()
    if threading.current_thread() is not threading.main_thread():
        yield seen
        return
    old = {s: signal.signal(s, seen) for s in signums if over_foreign or signal.getsignal(s) is not None}
    try:
        yield seen
    finally:
        for s, handler in old.items():
            signal.signal(s, handler if handler is not None else signal.SIG_DFL)


@contextmanager
def signals_deferred(signums: Sequence[int] = (signal.SIGINT, signal.SIGTERM)) -> Iterator[None]:
    """Hold the signals ``signums`` while the block runs, then hand each one that came to the handler it was meant
    for (a handler not set from Python is left alone: it could not be put back).

    :param signums: the signals to defer
    :return: a context manager (it yields nothing)
    """
    seen = SignalsSeen()
    try:
        with signals_held(signums, over_foreign=False) as seen:
            yield
    finally:
        for signum in seen.signums:
            signal.raise_signal(signum)

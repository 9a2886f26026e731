"""The next episode's start, computed ahead in a helper process (``dt-highway train``'s fast path).

Every training episode starts with a reset: a new driver population and 60 s of traffic before
t = 0 (the pre-roll, 900 simulation steps: about a fifth of a kinematic episode's work). In
``SubprocVecEnv`` the workers step in lockstep, so a worker in its pre-roll holds the others up.
:class:`PrerollAhead` plays the same seeds as :class:`Reseed` (``first,
first + stride, ...``), but each reset takes an env that a helper process (``python -m
dt_highway.rl.preroll``, at a lower CPU priority: it runs on what the workers leave idle) has
already reset with that seed, pickled whole: the same object state, so the same episode, byte
for byte (``tests/test_preroll.py``). While the episode runs, the helper resets the next seed.

Only for configurations without a camera, fusion or twin (``kinematics`` training, see
:func:`ahead_ok`): their envs pickle as plain Python state. A reset the helper cannot serve (a
seed out of turn, ``options``, a helper that stopped) is done in this process, as without it.

The pipe carries pickles between this package's own processes, never from outside.
"""

from __future__ import annotations

import os
import pickle
import select
import struct
import subprocess
import sys
from typing import IO, Any

import gymnasium as gym

from dt_highway.config import DTConfig
from dt_highway.env import DTHighwayEnv
from dt_highway.interrupts import interrupted_by_user

HELPER_NICE = 10
"""How much lower the helper's CPU priority is than the worker's (``os.nice`` increment)"""
_HEADER = struct.Struct("<Q")


def ahead_ok(env_config: DTConfig) -> bool:
    """Whether an env of this configuration can be reset ahead in a helper: no camera, no
    fusion, no twin (what is left pickles as plain state), traffic with a pre-roll to save.

    :param env_config: the env configuration the training runs
    :return: whether it can
    """
    return (not env_config.camera.enabled and not env_config.fusion.enabled and not env_config.twin.enabled
            and env_config.twin.preroll_s > 0 and env_config.traffic.driver_types)


def _send(stream: IO[bytes], obj: Any) -> None:
    blob = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    stream.write(_HEADER.pack(len(blob)))
    stream.write(blob)
    stream.flush()


def _receive(stream: IO[bytes]) -> Any:
    head = stream.read(_HEADER.size)
    if len(head) < _HEADER.size:
        raise EOFError("the other end closed the pipe")
    (n,) = _HEADER.unpack(head)
    blob = stream.read(n)
    if len(blob) < n:
        raise EOFError("the other end closed the pipe mid-message")
    return pickle.loads(blob)  # our own helper's pickles, over a private pipe


class Reseed(gym.Wrapper):
    """Give every episode its own seed: ``first, first + stride, first + 2 stride, ...``
    (vectorised envs pass a seed to the first reset only).

    :param env: the env to wrap
    :param first: the first episode's seed
    :param stride: seed increment between episodes
    """

    def __init__(self, env: gym.Env, first: int, stride: int = 1) -> None:
        super().__init__(env)
        self.next_seed, self.stride = first, stride

    def _seed_for(self, seed: int | None) -> int:
        """The seed of the episode starting now: ``seed`` when given, else the next of the sequence."""
        if seed is None:
            seed = self.next_seed
            self.next_seed += self.stride
        return seed

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[Any, dict]:
        """Reset with the next seed of the sequence (or ``seed``, when given).

        :param seed: the episode's seed (``None``: the next of the sequence)
        :param options: passed to the env's reset
        :return: the env's ``(observation, info)``
        """
        return self.env.reset(seed=self._seed_for(seed), options=options)


class PrerollAhead(Reseed):
    """A ``dt-highway-v0`` env whose seeded resets are computed ahead by a helper process.

    :param env_config: the env configuration (a dict, as ``gym.make`` takes it; :func:`ahead_ok`)
    :param first: the first episode's seed
    :param stride: seed increment between episodes
    """

    def __init__(self, env_config: dict[str, Any], first: int, stride: int = 1) -> None:
        super().__init__(DTHighwayEnv(config=env_config), first, stride)  # what gym.make(...).unwrapped is
        self.served = self.missed = 0
        self._pending: int | None = None
        env = {**os.environ, "OMP_NUM_THREADS": "1"}
        self._helper: subprocess.Popen[bytes] | None = subprocess.Popen(
            [sys.executable, "-m", "dt_highway.rl.preroll"], stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env)
        try:
            assert self._helper.stdin is not None
            _send(self._helper.stdin, env_config)
        except OSError:
            self._stop_helper()

    def _ask(self, seed: int) -> None:
        """Ask the helper for the env reset with ``seed``."""
        if self._helper is None:
            return
        try:
            assert self._helper.stdin is not None
            _send(self._helper.stdin, seed)
            self._pending = seed
        except OSError:
            self._stop_helper()

    def _take(self) -> tuple[Any, ...] | None:
        """The helper's answer to the last request, ``(env, obs, info, seed)`` (``None``: it stopped)."""
        if self._helper is None:
            return None
        try:
            assert self._helper.stdout is not None
            answer = _receive(self._helper.stdout)
        except (OSError, EOFError, pickle.UnpicklingError):
            self._stop_helper()
            return None
        finally:
            self._pending = None
        return answer if isinstance(answer, tuple) else None

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[Any, dict]:
        """Reset, from the helper's computed pre-roll when it matches the seed (else computed here), and ask for the next.

        :param seed: the episode's seed (``None``: the next of the sequence)
        :param options: passed to the env's reset (given: the reset is computed here)
        :return: the env's ``(observation, info)``
        """
        seed = self._seed_for(seed)
        ready = None
        if self._pending is not None:
            answer = self._take()
            if answer is not None and self._pending_matches(answer, seed) and options is None:
                ready = answer
        if ready is not None:
            env, obs, info, _ = ready
            self.env.close()
            self.env = env
            self.served += 1
        else:
            obs, info = self.env.reset(seed=seed, options=options)
            self.missed += 1
        self._ask(self.next_seed)
        return obs, info

    def wait_ready(self, timeout_s: float = 60.0) -> bool:
        """Wait until the helper's next start is ready (a benchmark's warm-up; training never waits here).

        :param timeout_s: longest wait [s]
        :return: whether a start is ready to be taken
        """
        if self._helper is None or self._pending is None or self._helper.stdout is None:
            return False
        ready, _, _ = select.select([self._helper.stdout], [], [], timeout_s)
        return bool(ready)

    @staticmethod
    def _pending_matches(answer: tuple[Any, ...], seed: int) -> bool:
        return len(answer) == 4 and answer[3] == seed

    def _stop_helper(self) -> None:
        helper, self._helper, self._pending = self._helper, None, None
        if helper is None:
            return
        for stream in (helper.stdin, helper.stdout):
            try:
                if stream is not None:
                    stream.close()
            except OSError:
                pass
        try:
            helper.wait(timeout=5)
        except subprocess.TimeoutExpired:
            helper.kill()
            helper.wait()

    def close(self) -> None:
        """Stop the helper process, then close the env."""
        self._stop_helper()
        super().close()


def _serve(stdin: IO[bytes], stdout: IO[bytes]) -> None:
    """The helper's loop: the configuration, then one seed at a time -> ``(env, obs, info, seed)``."""
    env = DTHighwayEnv(config=_receive(stdin))
    while True:
        try:
            seed = _receive(stdin)
        except EOFError:  # the worker is gone or done
            return
        obs, info = env.reset(seed=int(seed))
        _send(stdout, (env, obs, info, int(seed)))


def _main() -> None:
    try:
        os.nice(HELPER_NICE)
    except OSError:
        pass
    answers = os.fdopen(os.dup(sys.stdout.fileno()), "wb")  # the pipe to the worker: for answers only
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())  # anything printed goes to stderr, not into the pipe
    try:
        _serve(sys.stdin.buffer, answers)
    except (KeyboardInterrupt, BrokenPipeError):  # Ctrl-C reaches the whole process group; the worker left
        pass
    except SystemError as err:  # Ctrl-C inside numba code (dt_highway.interrupts)
        if not interrupted_by_user(err):
            raise


if __name__ == "__main__":
    _main()

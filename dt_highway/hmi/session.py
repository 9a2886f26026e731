"""The session protocol of a participant: a practice trial, then the session's conditions
(``baseline`` and ``adas`` unless told otherwise; any of :data:`~dt_highway.conditions.CONDITIONS`,
``sham`` among them) in counterbalanced order, with a break screen between trials.

Order: a balanced Latin square (Williams 1949, Aust. J. Sci. Res. A 2, 149): with ``k`` conditions
its rows are the orders, ``k`` of them for even ``k`` and ``2k`` for odd ``k`` (the square and its
mirror image); over a full set of rows every condition is driven equally often in every position
and follows every other condition equally often (first-order carry-over balanced). Participant
``n`` (the number its id ends in: P01, P02...) drives row ``(n - 1) mod rows``; an id without a
trailing number gets ``n`` from a stable checksum of the id. With ``baseline`` and ``adas`` that is
the old rule: odd participants AB, even ones BA. Recruit participants in multiples of the number of
rows for full balance. The practice trial is driven in the participant's first condition.

Every condition uses the same traffic seed (the paired design of the scripted studies; the practice
trial uses another). Every trial is logged in ``<out>/trials/<participant>-<practice|condition>``
(the participant is told ``adas`` for every overlay condition, ``sham`` too:
:func:`~dt_highway.conditions.display_name`); running the session again skips the trials already
completed and runs the rest (an aborted one again).
"""

from __future__ import annotations

import re
import zlib
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any

from dt_highway.conditions import check_condition
from dt_highway.config import ConfigError
from dt_highway.hmi.drive import DriveOptions, run_drive, show_card, trial_dir
from dt_highway.hmi.keys import KeyScript
from dt_highway.metrics.trial_log import load_trial

PRACTICE_SEED_OFFSET = 1000
"""The practice trial's traffic seed is the session's seed plus this"""


DEFAULT_CONDITIONS = ("baseline", "adas")
"""A session's conditions unless told otherwise"""


def balanced_latin_square(k: int) -> list[list[int]]:
    """The rows of a balanced Latin square (Williams design) of ``k`` treatments ``0..k-1``.

    The first row is ``0, 1, k-1, 2, k-2, ...``; row ``r`` adds ``r`` mod ``k``; for odd ``k`` the
    mirror images of those rows follow (``2k`` rows).

    :param k: number of treatments, >= 1
    :return: the rows (each a permutation of ``range(k)``)
    """
    first, lo, hi = [0], 1, k - 1
    while len(first) < k:
        first.append(lo)
        lo += 1
        if len(first) < k:
            first.append(hi)
            hi -= 1
    rows = [[(c + r) % k for c in first] for r in range(k)]
    return rows + [row[::-1] for row in rows] if k % 2 else rows


def check_conditions(conditions: Sequence[str]) -> tuple[str, ...]:
    """A session's conditions, checked: known, no repeats, at least two.

    :raises ConfigError: one line naming the problem
    """
    out = tuple(check_condition(c) for c in conditions)
    if len(set(out)) != len(out):
        raise ConfigError(f"--conditions names a condition twice (got {','.join(out)})")
    if len(out) < 2:
        raise ConfigError(f"a session needs at least two conditions (got {','.join(out) or 'none'})")
    return out


def condition_order(participant: str, conditions: Sequence[str] = DEFAULT_CONDITIONS) -> tuple[str, ...]:
    """The counterbalanced order of a participant's conditions (module docstring).

    :param participant: participant id (its trailing number picks the row)
    :param conditions: the session's conditions
    :raises ConfigError: on unknown or repeated conditions
    """
    conds = check_conditions(conditions)
    m = re.search(r"(\d+)$", participant)
    n = int(m.group(1)) if m else zlib.crc32(participant.encode("utf-8"))
    rows = balanced_latin_square(len(conds))
    return tuple(conds[i] for i in rows[(n - 1) % len(rows)])


def session_plan(base: DriveOptions, practice_duration_s: float | None = None,
                 conditions: Sequence[str] = DEFAULT_CONDITIONS) -> list[DriveOptions]:
    """The trials of a session: practice, then the conditions in the participant's order.

    :param base: options shared by the trials (participant, out, scenario, seed...)
    :param practice_duration_s: the practice trial's length [s] (``None``: as the others)
    :param conditions: the session's conditions
    :raises ConfigError: on unknown or repeated conditions
    """
    order = condition_order(base.participant, conditions)
    practice = replace(base, condition=order[0], practice=True, seed=base.seed + PRACTICE_SEED_OFFSET,
                       duration_s=practice_duration_s if practice_duration_s is not None else base.duration_s)
    trials = [practice, *(replace(base, condition=c, practice=False) for c in order)]
    if base.screenshots is not None:  # one folder per trial, or their screenshots would overwrite each other
        trials = [
            replace(t, screenshots=base.screenshots / trial_dir(t.out, t.participant, t.condition, t.practice).name)
            for t in trials
        ]
    return trials


def _completed(opts: DriveOptions) -> bool:
    d = trial_dir(opts.out, opts.participant, opts.condition, opts.practice)
    try:
        return load_trial(d).meta.get("status") == "completed"
    except (FileNotFoundError, ValueError):
        return False


def run_session(base: DriveOptions, practice_duration_s: float | None = None,
                say: Callable[[str], object] = print,
                conditions: Sequence[str] = DEFAULT_CONDITIONS) -> list[dict[str, Any]]:
    """Run the session's missing trials, with a break screen before each but the first.

    :param base: shared options (``condition`` is ignored: the plan sets it)
    :param practice_duration_s: the practice trial's length [s]
    :param say: where progress lines go
    :param conditions: the session's conditions
    :return: one result per trial (``status`` ``skipped`` for those already completed)
    """
    results = []
    size = None
    ran = 0
    for opts in session_plan(base, practice_duration_s, conditions):
        name = trial_dir(opts.out, opts.participant, opts.condition, opts.practice).name
        if _completed(opts):
            say(f"{name}: already completed, skipped")
            results.append({"directory": str(trial_dir(opts.out, opts.participant, opts.condition, opts.practice)),
                            "status": "skipped"})
            continue
        if ran and base.keys_from is None and size is not None:
            what = "the practice trial" if opts.practice else f"trial {ran}"
            if not show_card(size, "Break", [f"Next: {what}.", "", "Take a rest.", "Press Enter when you are ready."]):
                say("session stopped at the break")
                break
        if opts.keys_from is not None:  # each trial replays the script from its start
            opts = replace(opts, keys_from=KeyScript(opts.keys_from.events))
        result = run_drive(opts)
        size = tuple(result.get("size_px", (640, 360)))
        ran += 1
        say(f"{name}: {result['status']} ({result['end_reason']})")
        results.append(result)
        if result["status"] != "completed":
            say("session stopped: run the same command again to go on")
            break
    return results


__all__ = ["balanced_latin_square", "check_conditions", "condition_order", "run_session", "session_plan",
           "DEFAULT_CONDITIONS", "PRACTICE_SEED_OFFSET"]

"""The session protocol of a participant: a practice trial, then both conditions in
counterbalanced order, with a break screen between trials.

Order: participants whose id ends in an odd number (P01, P03...) drive ``baseline`` then
``adas`` (AB), even ones ``adas`` then ``baseline`` (BA); an id without a trailing number
gets its order from a stable checksum of the id. Both conditions use the same traffic seed
(the paired design of the scripted studies; the practice trial uses another). Every trial is
logged in ``<out>/trials/<participant>-<practice|baseline|adas>``; running the session again
skips the trials already completed and runs the rest (an aborted one again).
"""

from __future__ import annotations

import re
import zlib
from collections.abc import Callable
from dataclasses import replace
from typing import Any

from dt_highway.hmi.drive import DriveOptions, run_drive, show_card, trial_dir
from dt_highway.hmi.keys import KeyScript
from dt_highway.metrics.trial_log import load_trial

PRACTICE_SEED_OFFSET = 1000
"""The practice trial's traffic seed is the session's seed plus this"""


def condition_order(participant: str) -> tuple[str, str]:
    """The counterbalanced order of a participant's conditions (module docstring)."""
    m = re.search(r"(\d+)$", participant)
    n = int(m.group(1)) if m else zlib.crc32(participant.encode("utf-8"))
    return ("baseline", "adas") if n % 2 == 1 else ("adas", "baseline")


def session_plan(base: DriveOptions, practice_duration_s: float | None = None) -> list[DriveOptions]:
    """The trials of a session: practice, then the two conditions in the participant's order.

    :param base: options shared by the trials (participant, out, scenario, seed...)
    :param practice_duration_s: the practice trial's length [s] (``None``: as the others)
    """
    first, second = condition_order(base.participant)
    practice = replace(base, condition=first, practice=True, seed=base.seed + PRACTICE_SEED_OFFSET,
                       duration_s=practice_duration_s if practice_duration_s is not None else base.duration_s)
    trials = [practice, replace(base, condition=first, practice=False), replace(base, condition=second, practice=False)]
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
                say: Callable[[str], object] = print) -> list[dict[str, Any]]:
    """Run the session's missing trials, with a break screen before each but the first.

    :param base: shared options (``condition`` is ignored: the plan sets it)
    :param practice_duration_s: the practice trial's length [s]
    :param say: where progress lines go
    :return: one result per trial (``status`` ``skipped`` for those already completed)
    """
    results = []
    size = None
    ran = 0
    for opts in session_plan(base, practice_duration_s):
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


__all__ = ["condition_order", "run_session", "session_plan", "PRACTICE_SEED_OFFSET"]

"""Calibrating a trial scenario on the **baseline** condition only (``dt-highway calibrate``).

For every value of one scenario knob (a configuration key, e.g. ``traffic.dangerous.brake_mps2``)
and every driver, the harness runs ``trials`` paired-seed baseline trials (camera, fusion and
overlay off: nothing is shown to the driver) through the study runner, and reads back from the
trial logs:

* ``cut_ins_per_h``: the cut-in manoeuvres aimed at the ego that became its leader, per hour
  (the cut-in events of the logs whose ``maneuver`` is ``gentle`` or ``dangerous``, i.e. the
  traffic's own cut-ins on the ego; other lane entries in front of the ego are counted apart);
* ``cut_in_ttc_median_s``: the median over those cut-ins of the ego's minimum TTC to the
  cutting car (1-D leader TTC while it leads, within 10 s; capped at 10 s as in the metrics);
  ``cut_in_ttc_below_1s``: the share of them below 1 s; the same for the dangerous ones alone
  (``dangerous_*``) and for every lane entry (``entries_*``);
* ``collisions_per_h`` and ``trials_with_collision``: the ego's collisions, and the trials one cut short;
* ``conflicts_2d_per_h``: onsets of 2-D TTC below 1.5 s per hour, when the logs have it.

It never runs the ADAS or sham conditions: a scenario is chosen by what its baseline looks like,
never by the effect a study is meant to measure. Each (driver, value) cell keeps its study
directory under ``out`` (resumable: a rerun skips the trials already done).
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from dt_highway.conditions import driver_config
from dt_highway.config import ConfigError, override_value
from dt_highway.metrics.safety import TTC_CAP_S, cut_in_outcomes
from dt_highway.metrics.trial_log import Trial, load_trial
from dt_highway.study import plan, run_study

MANEUVERS = ("gentle", "dangerous")
"""The ``maneuver`` of a logged cut-in event that the traffic aimed at the ego"""


@dataclass(frozen=True)
class CalibrationCell:
    """One row of the calibration table: a driver at one value of the knob.

    :param driver: the driver file's stem
    :param value: the knob's value, as given
    :param figures: the baseline figures (module docstring)
    """

    driver: str
    value: str
    figures: dict[str, float]


def _safe_name(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.=-]+", "_", text)


def _cut_in_rows(trial: Trial) -> list[dict[str, Any]]:
    """Every logged cut-in of a trial with its outcome and manoeuvre."""
    events = trial.cut_ins
    outcomes = cut_in_outcomes(trial.steps, events)
    return [{**o, "maneuver": str(e.get("maneuver") or "")} for o, e in zip(outcomes, events, strict=True)]


def _ttc_figures(prefix: str, ttc: list[float]) -> dict[str, float]:
    capped = np.minimum(np.asarray(ttc, dtype=float), TTC_CAP_S)
    if not len(capped):
        return {f"{prefix}n": 0.0, f"{prefix}ttc_median_s": math.nan, f"{prefix}ttc_below_1s": math.nan}
    return {f"{prefix}n": float(len(capped)), f"{prefix}ttc_median_s": float(np.median(capped)),
            f"{prefix}ttc_below_1s": float(np.mean(capped < 1.0))}


def baseline_figures(trials: Sequence[Trial]) -> dict[str, float]:
    """The calibration figures of a set of baseline trials (module docstring).

    :param trials: the trials, read back
    :return: figures by name (units in the names; shares in [0, 1])
    """
    hours = sum(len(t.steps) * t.dt_s for t in trials) / 3600.0
    rows = [r for t in trials for r in _cut_in_rows(t)]
    aimed = [r["min_ttc_s"] for r in rows if r["maneuver"] in MANEUVERS]
    dangerous = [r["min_ttc_s"] for r in rows if r["maneuver"] == "dangerous"]
    metrics = [t.metrics() for t in trials]
    collisions = sum(int(m["collisions"]) for m in metrics)
    out = {"trials": float(len(trials)), "hours": hours,
           "cut_ins_per_h": len(aimed) / hours if hours else math.nan,
           "dangerous_per_h": len(dangerous) / hours if hours else math.nan}
    out |= _ttc_figures("cut_in_", aimed)
    out |= _ttc_figures("dangerous_", dangerous)
    out |= _ttc_figures("entries_", [r["min_ttc_s"] for r in rows])
    out["collisions_per_h"] = collisions / hours if hours else math.nan
    out["trials_with_collision"] = float(sum(int(m["collisions"]) > 0 for m in metrics))
    conflicts = [m.get("conflicts_2d") for m in metrics]
    if all(c is not None for c in conflicts) and hours:
        out["conflicts_2d_per_h"] = float(sum(conflicts)) / hours  # type: ignore[arg-type]
    return out


def split_values(text: str) -> list[str]:
    """The values of ``--knob KEY=V1,V2,...``: split at the commas outside brackets and quotes, so a list
    or a quoted string is one value (``[1.0,2.0],[1.0,3.0]`` is two); empty ones are left out.

    :param text: the part after ``KEY=``
    :return: the values, stripped, in order
    :raises ConfigError: on unbalanced brackets or an unclosed quote
    """
    values, depth, quote, start = [], 0, "", 0
    for i, ch in enumerate(text + ","):
        if quote:
            quote = "" if ch == quote else quote
        elif ch in "\"'":
            quote = ch
        elif ch in "[{":
            depth += 1
        elif ch in "]}":
            depth -= 1
        elif ch == "," and depth == 0:
            values.append(text[start:i].strip())
            start = i + 1
    if quote or depth:
        raise ConfigError(f"--knob values {text!r}: {'an unclosed quote' if quote else 'unbalanced brackets'}")
    return [v for v in values if v]  # "2,3," is 2 and 3, as in the other comma-separated options


UNREAD_IN_BASELINE = ("detector", "fusion", "overlay")
"""Sections the baseline condition never reads (no camera, fusion or overlay): a knob there changes nothing"""


def check_values(knob: str, values: Sequence[str], scenario: str | None, overrides: Sequence[str]) -> None:
    """Refuse, before any trial runs, a knob the baseline trials never read (:data:`UNREAD_IN_BASELINE`), a
    knob or value the configuration refuses, a ``--set`` of the knob
    (or of a table that sets it), or a configuration no driver can drive
    (:func:`~dt_highway.conditions.check_driver_action`).

    :param knob: the configuration key varied
    :param values: its values, as ``--set`` would take them
    :param scenario: scenario file
    :param overrides: further ``--set`` strings, for every cell
    :raises ConfigError: one line
    """
    if not values:
        raise ConfigError("calibrate needs at least one value")
    section = knob.split(".", 1)[0]
    if section in UNREAD_IN_BASELINE:  # every cell would be the same trials
        raise ConfigError(f"--knob {knob}: calibrate runs baseline trials, which have no detector, fusion or overlay, "
                          f"so {section}.* changes nothing there (calibrate a world's knob: traffic.*, highway.*, ego.*, "
                          "twin.*)")
    for text in overrides:  # the knob's value would replace it in every cell, without a word
        if override_value(text, knob) is not None:
            raise ConfigError(f"--set {text.strip()} sets the key --knob varies ({knob}): drop it, or give the value "
                              "in --knob")
    for v in values:  # as driver_config checks each trial's: the ego's action, the twin's model files
        driver_config(scenario, [*overrides, f"{knob}={v}"], "baseline", {})


def calibrate(
    knob: str,
    values: Sequence[str],
    drivers: Sequence[str],
    out: str | Path,
    trials: int = 10,
    seed: int = 1000,
    scenario: str | None = None,
    overrides: Sequence[str] = (),
    workers: int = 2,
    progress: Callable[[dict[str, Any]], None] | None = None,
) -> list[CalibrationCell]:
    """Run the baseline trials of every (driver, knob value) and compute their figures.

    :param knob: a configuration key, e.g. ``traffic.dangerous.brake_mps2``
    :param values: its values, as ``--set`` would take them
    :param drivers: driver files (``agents/human.toml``, ``agents/idm.toml``)
    :param out: the calibration directory (one study directory per cell)
    :param trials: baseline trials per cell [-]
    :param seed: seed of the first trial (trial ``i`` uses ``seed + i``; keep these seeds apart from
        the studies that will be run on the scenario)
    :param scenario: scenario file
    :param overrides: further ``--set`` strings, for every cell
    :param workers: parallel trials [-]
    :param progress: called with each trial's result as it finishes
    :return: one cell per (driver, value), drivers outermost
    :raises ConfigError: on a knob or value the configuration refuses (before any trial runs)
    """
    check_values(knob, values, scenario, overrides)
    cells = []
    for driver in drivers:
        for v in values:
            directory = Path(out) / f"{_safe_name(Path(driver).stem)}-{_safe_name(knob)}={_safe_name(v)}"
            specs = plan(directory, driver, ["baseline"], trials, seed, scenario, [*overrides, f"{knob}={v}"])
            result = run_study(specs, directory, workers=workers, progress=progress)
            if result.failed:
                raise ConfigError(f"{len(result.failed)} calibration trial(s) failed, e.g. {result.failed[0]['error']}")
            figures = baseline_figures([load_trial(s.directory) for s in specs])
            cells.append(CalibrationCell(Path(driver).stem, v, figures))
    return cells


def check_table_kept(out: Path, knob: str, drivers: Sequence[str], values: Sequence[str], force: bool) -> None:
    """Refuse to replace a calibration table of other cells (another knob, or a driver or value the new run
    leaves out) unless ``force``: the same cells again (a resumed or repeated run), or more, keep its rows.

    :param out: the calibration directory (``calibration.csv`` in it)
    :param knob: the configuration key varied
    :param drivers: the drivers' names (their files' stems), as the table's rows
    :param values: the knob's values, as typed
    :param force: replace any table
    :raises ConfigError: one line naming what the table there holds
    """
    path = out / "calibration.csv"
    if force or not path.is_file():
        return
    try:
        held = pd.read_csv(path, dtype=str, keep_default_na=False)
    except (ValueError, OSError):  # not a table: nothing to keep
        return
    if len(held.columns) < 2 or held.columns[0] != "driver":
        return  # no calibration table
    if held.columns[1] == knob:
        try:
            cells = {(d, knob_value(knob, v)) for d, v in zip(held["driver"], held[knob], strict=True)}
        except ConfigError:  # a value edited into something --set cannot read: another table
            cells = set()
        if cells and cells <= {(d, knob_value(knob, v)) for d in drivers for v in values}:
            return  # the same cells again, or more: the new table keeps every row of the one there
    column = held.columns[1]
    there = f"{column} = {', '.join(dict.fromkeys(held[column]))} for {', '.join(dict.fromkeys(held['driver']))}"
    raise ConfigError(f"{path} holds the table of another calibration ({there}): pass --force to replace it, "
                      "or another --out")


def knob_value(knob: str, text: str) -> str:
    """A ``--knob`` value as the configuration reads it, to compare (``2`` and ``2.0`` the same number).

    :param knob: the configuration key varied
    :param text: the value, as typed
    :return: the ``repr`` of the value read (a number as a float)
    :raises ConfigError: on a value ``--set`` cannot parse
    """
    value = override_value(f"{knob}={text}", knob, "--knob")
    number = isinstance(value, int | float) and not isinstance(value, bool)
    return repr(float(value)) if number else repr(value)


TABLE_COLUMNS = {
    "cut_ins_per_h": "cut-ins on the ego [1/h]",
    "cut_in_ttc_median_s": "median min TTC [s]",
    "cut_in_ttc_below_1s": "share < 1 s",
    "dangerous_ttc_median_s": "dangerous: median min TTC [s]",
    "entries_ttc_median_s": "all lane entries: median min TTC [s]",
    "collisions_per_h": "collisions [1/h]",
    "trials_with_collision": "trials with a collision",
    "conflicts_2d_per_h": "2-D conflicts [1/h]",
}
"""The calibration table's columns: figure -> heading"""


def calibration_table(cells: Sequence[CalibrationCell], knob: str) -> pd.DataFrame:
    """The cells as a table: one row per (driver, value), the figures of :data:`TABLE_COLUMNS`.

    :param cells: the cells (:func:`calibrate`)
    :param knob: the configuration key varied (a column's name)
    :return: columns ``driver``, the knob, the headings of the figures there, ``trials``
    """
    rows = []
    for c in cells:
        row: dict[str, Any] = {"driver": c.driver, knob: c.value}
        for key, heading in TABLE_COLUMNS.items():
            if key in c.figures:
                row[heading] = c.figures[key]
        row["trials"] = int(c.figures["trials"])
        rows.append(row)
    return pd.DataFrame(rows)


def markdown(table: pd.DataFrame) -> str:
    """A table as GitHub markdown, numbers to two decimals (pandas' ``to_markdown`` needs tabulate,
    not a dependency: six lines here do it).

    :param table: the table (e.g. :func:`calibration_table`)
    :return: the markdown: a heading line, a rule, one line per row
    """

    def cell(v: Any) -> str:
        if isinstance(v, float | np.floating):
            return "n/a" if math.isnan(v) else f"{v:.2f}"
        return str(v)

    lines = ["| " + " | ".join(str(c) for c in table.columns) + " |", "|" + "---|" * len(table.columns)]
    lines += ["| " + " | ".join(cell(v) for v in row) + " |" for row in table.itertuples(index=False)]
    return "\n".join(lines) + "\n"

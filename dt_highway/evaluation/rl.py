"""Evaluate any driver on the same seeds (``dt-highway evaluate``): policies and scripted drivers.

Each episode is one trial of the scenario in one condition, the driver acting through the
``Driver`` action as in a study. Return is the env's reward summed over the decisions
(highway-env's reward: speed in ``reward_speed_range``, right lane, collision); the safety
metrics are :func:`~dt_highway.metrics.safety.trial_metrics` of the episode's per-step samples.

``dt-highway rl-compare`` (:func:`rl_compare`, issue 22's table) runs rows of driver file x condition
(x ablation) on the same held-out seeds and pairs them by seed. It is a command of its own rather than
an ``evaluate --compare`` mode: its input is a list of rows, not one driver and one condition, and
its output is a folder (JSON, Markdown table, episodes CSV) with paired tests, not one driver's means.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from multiprocessing import get_context
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pandas as pd

from dt_highway.choices import COMPARE_SCENARIO, COMPARE_SEED
from dt_highway.conditions import CONDITIONS, driver_config
from dt_highway.config import ConfigError
from dt_highway.drivers import Driver, load_driver
from dt_highway.drivers.policy import PolicyDriver
from dt_highway.env.seat import DriverSeat
from dt_highway.jsonio import dump_json, whole_number
from dt_highway.metrics.safety import TTC_CAP_S, collision_label, cut_in_outcomes, trial_metrics
from dt_highway.metrics.stats import MIN_PAIRS, describe, paired_tests


def run_episode(driver: Driver, env: gym.Env, seed: int) -> dict[str, Any]:
    """One episode of ``driver`` in ``env`` from ``reset(seed)``; the driver acts on what its
    seat perceives (:class:`~dt_highway.env.seat.DriverSeat`), ``info`` is for the metrics.

    :param driver: the driver
    :param env: a ``dt-highway-v0`` env, wrapped (``gym.make``) or not
    :param seed: the seed of the env's reset and of the driver's
    :return: ``return``, ``steps``, ``collision``, the trial metrics (units in the names),
        ``collision_label`` (the first collision's kind, empty without a crash), ``cut_in_ttcs_s`` (each
        cut-in's minimum TTC, capped at ``safety.TTC_CAP_S``) and ``cut_in_ttc_median_s``, their median (NaN without any)
    :raises TypeError: if ``env`` is not a ``dt-highway-v0`` env
    """
    _, info = env.reset(seed=seed)
    seat = DriverSeat(env, driver.senses)
    u = seat.env
    driver.reset(seed)
    samples, cut_ins = list(info["safety"]["samples"]), list(info["safety"]["cut_ins"])
    total, steps = 0.0, 0
    while True:
        action = np.asarray(driver.act(seat.perceive()), dtype=float)
        _, reward, terminated, truncated, info = env.step(action)
        total += float(reward)
        steps += 1
        samples += info["safety"]["samples"]
        cut_ins += info["safety"]["cut_ins"]
        if terminated or truncated:
            break
    frame = pd.DataFrame(samples)
    metrics = trial_metrics(frame, 1.0 / u.config["simulation_frequency"], cut_ins)
    cut_ttc = [min(o["min_ttc_s"], TTC_CAP_S) for o in cut_in_outcomes(frame, cut_ins)] if len(frame) else []
    crashed = bool(u.vehicle.crashed)
    return {"seed": seed, "return": total, "steps": steps, "collision": crashed, **metrics,
            "collision_label": collision_label(metrics["collision_kind"] or None, metrics["collision_striker"] or None,
                                               metrics["collision_lane_changer"] or None) if crashed else "",
            "cut_in_ttc_median_s": float(np.median(cut_ttc)) if cut_ttc else math.nan,
            "cut_in_ttcs_s": [float(v) for v in cut_ttc]}


def _mean(values: list[float]) -> float:
    finite = [v for v in values if isinstance(v, (int, float)) and math.isfinite(v)]
    return float(np.mean(finite)) if finite else math.nan


def evaluate(driver_path: str, episodes: int, seed: int, scenario: str | None = "envs/highway-trial.toml",
             condition: str = "adas", overrides: tuple[str, ...] = (),
             progress: Callable[[int], None] | None = None, driver: Driver | None = None) -> dict[str, Any]:
    """Run ``episodes`` episodes (seeds ``seed .. seed + episodes - 1``) of a driver.

    :param driver_path: ``agents/<name>.zip`` or ``agents/<driver>.toml``
    :param driver: the driver already loaded from ``driver_path`` (else it is loaded here)
    :param episodes: number of episodes
    :param seed: first seed
    :param scenario: scenario file
    :param condition: ``baseline`` (no overlay) or ``adas``
    :param overrides: ``dotted.key=value`` overrides
    :param progress: called with 0 when the checks are done and the episodes start, then with 1 after each
    :return: the means over episodes and the episodes themselves
    :raises ConfigError: on a bad driver, scenario, condition or count
    """
    if whole_number(episodes) is None or episodes < 1:
        raise ConfigError(f"--episodes must be a whole number >= 1 (got {episodes!r})")
    if whole_number(seed) is None or seed < 0:
        raise ConfigError(f"--seed must be a whole number >= 0 (got {seed!r})")
    if driver is None and not isinstance(driver_path, (str, Path)):
        raise ConfigError(f"the driver must be a file's path, agents/<name>.zip or .toml (got {type(driver_path).__name__})")
    driver = driver if driver is not None else load_driver(driver_path)
    cfg = driver_config(scenario, overrides, condition, driver.config_overrides())
    env = gym.make("dt-highway-v0", config=cfg.to_dict())
    rows = []
    try:
        if hasattr(driver, "model"):  # a policy that cannot drive this env says so before any episode
            DriverSeat(env.unwrapped, driver.senses)
            driver.reset(seed)
        if progress is not None:
            progress(0)  # checks done: the episodes start
        for k in range(episodes):
            rows.append(run_episode(driver, env, seed + k))
            if progress is not None:
                progress(1)
    finally:
        env.close()
    cut_in_ttc = [r["cut_in_ttc_min_s"] for r in rows]
    return {
        "driver": driver_path,
        "condition": condition,
        "scenario": scenario,
        "overrides": list(overrides),
        "episodes": episodes,
        "seeds": [seed, seed + episodes - 1],
        "mean_return": _mean([r["return"] for r in rows]),
        "collision_rate": float(np.mean([r["collision"] for r in rows])),
        "mean_speed_kmh": _mean([r["speed_mean_kmh"] for r in rows]),
        "mean_ttc_s": _mean([r["ttc_mean_s"] for r in rows]),
        "cut_in_ttc_min_s": _mean(cut_in_ttc),
        "cut_ins": int(sum(r["cut_ins"] for r in rows)),
        "episodes_with_cut_ins": int(sum(1 for v in cut_in_ttc if math.isfinite(v))),
        "mean_steps": _mean([r["steps"] for r in rows]),
        "definitions": {
            "mean_return": "env reward summed over an episode's decisions, mean over episodes",
            "collision_rate": "share of episodes that end with the ego crashed",
            "mean_speed_kmh": "ego speed, mean over each episode's simulation steps, mean over episodes",
            "mean_ttc_s": "per episode: mean TTC over closing samples below the cap (safety.TTC_CAP_S); "
                          "mean over episodes that have any",
            "cut_in_ttc_min_s": "per episode: smallest TTC to a vehicle that cut in ahead (capped); "
                                "mean over episodes with a cut-in",
        },
        "per_episode": rows,
    }


# --- dt-highway rl-compare: rows of driver x condition (x ablation) on the same held-out seeds -------------------

ABLATIONS = ("zero-marks",)
"""What a row can take away from its driver: ``zero-marks`` zeroes the policy's overlay columns
(:attr:`~dt_highway.drivers.policy.PolicyDriver.overlay_features`) while the env runs the same condition"""
SHAM_OF = {"adas": "sham", "adas-type": "sham-type", "adas-threat": "sham-threat"}
"""Each ADAS condition's placebo"""
COMPARE_METRICS = ("return", "collision", "conflicts_2d_per_h", "cut_in_ttc_median_s", "speed_mean_kmh")
"""The per-episode values the rows are summarised and compared on (units in the names)"""
COMPARE_DEFINITIONS = {
    "return": "env reward summed over an episode's decisions (run_episode; the reward of the scenario's env)",
    "collision": "1 when the episode ends with the ego crashed (its kind: the first collision's, safety.collision_label)",
    "conflicts_2d_per_h": "onsets of 2-D TTC < 1.5 s (safety.CONFLICT_TTC_S) per hour of the episode",
    "cut_in_ttc_median_s": "per episode: the median over its cut-ins on the ego of each cut-in's minimum TTC "
                           "(capped at safety.TTC_CAP_S); episodes without a cut-in have none",
    "speed_mean_kmh": "ego speed, mean over the episode's simulation steps",
}


@dataclass(frozen=True)
class Row:
    """One row of the comparison: a driver file in a condition, with an optional ablation.

    :param driver: the driver file (``agents/<name>.zip`` or ``.toml``)
    :param condition: one of :data:`~dt_highway.conditions.CONDITIONS`
    :param ablation: one of :data:`ABLATIONS`, or empty
    """

    driver: str
    condition: str
    ablation: str = ""

    @property
    def label(self) -> str:
        """``<file name>@<condition>[:<ablation>]``, the row's name in the outputs"""
        return f"{Path(self.driver).name}@{self.condition}" + (f":{self.ablation}" if self.ablation else "")


ROW_SYNTAX = "DRIVER@CONDITION[:ABLATION], e.g. ppo-safe-adas.zip@adas-threat:zero-marks"


def parse_rows(text: str, driver_dir: str | Path = "agents") -> list[Row]:
    """Parse ``--rows``: comma-separated ``DRIVER@CONDITION[:ABLATION]``.

    A driver without a folder that is not a file here is looked for in ``driver_dir``.

    :param text: the rows
    :param driver_dir: where bare driver names are looked for
    :return: the rows, in order
    :raises ConfigError: one line naming the bad row and the allowed conditions or ablations
    """
    rows: list[Row] = []
    for part in (p.strip() for p in text.split(",")):
        if not part:
            continue
        driver, at, rest = part.rpartition("@")  # the last @: a folder may hold one, a condition never does
        condition, colon, ablation = rest.partition(":")
        if not at or not driver or not condition:
            raise ConfigError(f"--rows: bad row {part!r} (expected {ROW_SYNTAX})")
        if condition not in CONDITIONS:
            raise ConfigError(f"--rows: row {part!r}: unknown condition {condition!r} (allowed: {', '.join(CONDITIONS)})")
        if colon and ablation not in ABLATIONS:
            raise ConfigError(f"--rows: row {part!r}: unknown ablation {ablation!r} (allowed: {', '.join(ABLATIONS)})")
        if ablation == "zero-marks" and condition == "baseline":
            raise ConfigError(f"--rows: row {part!r}: zero-marks needs a condition with marks "
                              f"(allowed: {', '.join(c for c in CONDITIONS if c != 'baseline')})")
        path = Path(driver)
        if not path.exists() and path.parent == Path(".") and (Path(driver_dir) / driver).exists():
            path = Path(driver_dir) / driver
        row = Row(str(path), condition, ablation)
        twin = next((r for r in rows if r.label == row.label), None)
        if twin is not None and Path(twin.driver).resolve() != path.resolve():  # the label names the file only
            raise ConfigError(f"--rows: {twin.driver} and {path} are both called {path.name!r}: the comparison's rows "
                              "are named after the file, so rename one")
        if twin is not None:
            raise ConfigError(f"--rows: row {row.label!r} is named twice")
        rows.append(row)
    if not rows:
        raise ConfigError(f"--rows: no row (expected {ROW_SYNTAX}, comma-separated)")
    return rows


def row_driver(row: Row) -> Driver:
    """Load a row's driver and apply its ablation.

    :param row: the row
    :return: the driver, with the ablation applied
    :raises ConfigError: one line, on a bad driver file or an ablation the driver cannot take
    """
    driver = load_driver(row.driver)
    if row.ablation == "zero-marks":
        if not isinstance(driver, PolicyDriver) or not driver.overlay_features:
            raise ConfigError(f"--rows: row {row.label!r}: zero-marks needs a policy that sees the overlay's marks "
                              f"({row.driver} has no overlay columns)")
        driver.zero_columns(driver.overlay_features)
    return driver


class _RowRunner:
    """A row's driver and env, made once and reused for its episodes."""

    def __init__(self, row: Row, scenario: str | None, overrides: tuple[str, ...]) -> None:
        self.row, self.driver = row, row_driver(row)
        cfg = driver_config(scenario, overrides, row.condition, self.driver.config_overrides())
        self.env = gym.make("dt-highway-v0", config=cfg.to_dict())
        if hasattr(self.driver, "model"):  # a policy that cannot drive this env says so before any episode
            DriverSeat(self.env.unwrapped, self.driver.senses)
            self.driver.reset(0)

    def episode(self, seed: int) -> dict[str, Any]:
        out = run_episode(self.driver, self.env, seed)
        return {"row": self.row.label, "driver": self.row.driver, "condition": self.row.condition,
                "ablation": self.row.ablation, **out}

    def close(self) -> None:
        self.env.close()


_RUNNERS: dict[tuple[Row, str | None, tuple[str, ...]], _RowRunner] = {}
"""A worker process's runners (one per row)"""


def _pool_episode(row: Row, scenario: str | None, overrides: tuple[str, ...], seed: int) -> dict[str, Any]:
    key = (row, scenario, overrides)
    if key not in _RUNNERS:
        _RUNNERS[key] = _RowRunner(row, scenario, overrides)
    return _RUNNERS[key].episode(seed)


def _is_aware(driver: Driver) -> bool:
    return bool(getattr(driver, "overlay_features", ()))


def comparisons(rows: list[Row], aware: dict[str, bool], policy: dict[str, bool]) -> list[dict[str, str]]:
    """The paired comparisons the rows allow, each ``b - a`` with ``b`` an ADAS-aware policy's row
    (no ablation, an ADAS condition) and ``a``: the same policy in that condition's sham, the same
    policy with zeroed marks, and every row of a policy without marks (the baseline policy).

    :param rows: the rows (:func:`parse_rows`)
    :param aware: per row label: its driver is a policy that sees the overlay's marks
    :param policy: per row label: its driver is a trained policy
    :return: ``kind``, ``a``, ``b`` per comparison
    """
    out: list[dict[str, str]] = []
    for b in rows:
        if b.ablation or not aware[b.label] or b.condition not in SHAM_OF:
            continue
        for a in rows:
            if a.driver == b.driver and a.condition == SHAM_OF[b.condition] and not a.ablation:
                out.append({"kind": "vs sham marks", "a": a.label, "b": b.label})
            elif a.driver == b.driver and a.condition == b.condition and a.ablation == "zero-marks":
                out.append({"kind": "vs zeroed marks", "a": a.label, "b": b.label})
            elif policy[a.label] and not aware[a.label] and not a.ablation:
                out.append({"kind": "vs baseline policy", "a": a.label, "b": b.label})
    return out


def paired_by_seed(episodes: pd.DataFrame, a: str, b: str) -> dict[str, Any]:
    """Paired tests of row ``b`` minus row ``a``, episodes paired by seed
    (:func:`dt_highway.metrics.stats.paired_tests`: Wilcoxon signed-rank, paired t, Cohen's d_z), and the collisions.

    :param episodes: one row per episode with ``row``, ``seed`` and :data:`COMPARE_METRICS`
    :param a: the reference row's label
    :param b: the label of the row tested against it
    :return: ``a``, ``b``, ``tests`` per metric, ``collisions`` (``a``, ``b``, ``only_a``, ``only_b``, ``both``)
    """
    frame = episodes[episodes["row"].isin([a, b])].copy()
    frame["condition"] = frame["row"]
    frame["status"] = "completed"
    frame["collision"] = frame["collision"].astype(float)
    tests = paired_tests(frame, a, b, names=COMPARE_METRICS)
    wide = frame.pivot_table(index="seed", columns="row", values="collision", aggfunc="first").dropna()
    ca = wide[a].astype(bool) if a in wide else pd.Series(dtype=bool)
    cb = wide[b].astype(bool) if b in wide else pd.Series(dtype=bool)
    collisions = {"a": int(ca.sum()), "b": int(cb.sum()), "only_a": int((ca & ~cb).sum()),
                  "only_b": int((cb & ~ca).sum()), "both": int((ca & cb).sum())}
    return {"a": a, "b": b, "tests": tests, "collisions": collisions}


def summarise_row(frame: pd.DataFrame) -> dict[str, Any]:
    """One row's figures: per metric n, mean, SD and 95 % CI (:func:`dt_highway.metrics.stats.describe`),
    the collisions and their kinds, and the median over all its cut-ins of their minimum TTC.

    :param frame: the row's episodes, one per line (the dicts of :func:`run_episode`)
    :return: ``episodes``, ``collisions``, ``collision_kinds``, ``cut_ins``, ``cut_in_ttc_pooled_median_s`` and,
        per metric of :data:`COMPARE_METRICS`, its :func:`~dt_highway.metrics.stats.describe`
    """
    crashed = frame[frame["collision"].astype(bool)]
    kinds = Counter(str(k) or "unknown" for k in crashed["collision_label"])
    pooled = [v for vs in frame["cut_in_ttcs_s"] for v in vs]
    return {
        "episodes": len(frame),
        "collisions": len(crashed),
        "collision_kinds": dict(sorted(kinds.items())),
        "cut_ins": len(pooled),
        "cut_in_ttc_pooled_median_s": float(np.median(pooled)) if pooled else None,
        **{m: describe(frame[m].to_numpy(float), lo=0.0 if m != "return" else -math.inf,
                       hi=1.0 if m == "collision" else math.inf) for m in COMPARE_METRICS},
    }


def _check_rows(rows: list[Row], scenario: str | None, overrides: tuple[str, ...],
                keep: bool) -> tuple[dict[str, bool], dict[str, bool], dict[Row, _RowRunner]]:
    """Load every row's driver and make its env (a bad row fails here, before any episode)."""
    aware, policy, runners = {}, {}, {}
    for row in rows:
        runner = _RowRunner(row, scenario, overrides)
        aware[row.label], policy[row.label] = _is_aware(runner.driver), hasattr(runner.driver, "model")
        if keep:
            runners[row] = runner
        else:
            runner.close()
    return aware, policy, runners


def rl_compare(rows: list[Row], episodes: int, seed: int = COMPARE_SEED, scenario: str | None = COMPARE_SCENARIO,
               overrides: tuple[str, ...] = (), workers: int = 1,
               progress: Callable[[int], None] | None = None) -> dict[str, Any]:
    """Run every row on the same seeds ``seed .. seed + episodes - 1`` and compare them.

    :param rows: the rows (:func:`parse_rows`)
    :param episodes: episodes per row
    :param seed: first seed
    :param scenario: scenario file
    :param overrides: ``dotted.key=value`` overrides (every row)
    :param workers: processes running episodes (1: here)
    :param progress: called with 0 when the checks are done, then with 1 after each episode
    :return: ``rows`` (per row label: :func:`summarise_row`), ``comparisons`` (:func:`paired_by_seed`
        with ``kind``), ``episodes`` (one dict per episode), the settings and definitions
    :raises ConfigError: on a bad row, driver, scenario or count
    """
    if episodes < 1:
        raise ConfigError(f"--episodes must be >= 1 (got {episodes})")
    if workers < 1:
        raise ConfigError(f"--workers must be >= 1 (got {workers})")
    aware, policy, runners = _check_rows(rows, scenario, overrides, keep=workers == 1)
    if progress is not None:
        progress(0)
    tasks = [(row, seed + k) for k in range(episodes) for row in rows]
    results: list[dict[str, Any]] = []
    try:
        if workers == 1:
            for row, s in tasks:
                results.append(runners[row].episode(s))
                if progress is not None:
                    progress(1)
        else:
            with ProcessPoolExecutor(max_workers=workers, mp_context=get_context("spawn")) as pool:
                futures = [pool.submit(_pool_episode, row, scenario, overrides, s) for row, s in tasks]
                try:
                    for fut in as_completed(futures):
                        results.append(fut.result())
                        if progress is not None:
                            progress(1)
                except BaseException:
                    pool.shutdown(wait=False, cancel_futures=True)
                    raise
    finally:
        for runner in runners.values():
            runner.close()
    order = {row.label: i for i, row in enumerate(rows)}
    results.sort(key=lambda r: (order[r["row"]], r["seed"]))
    frame = pd.DataFrame(results)
    comps = [{"kind": c["kind"], **paired_by_seed(frame, c["a"], c["b"])} for c in comparisons(rows, aware, policy)]
    return {
        "scenario": scenario,
        "overrides": list(overrides),
        "episodes": episodes,
        "seeds": [seed, seed + episodes - 1],
        "rows": {row.label: {"driver": row.driver, "condition": row.condition, "ablation": row.ablation,
                             "adas_aware": aware[row.label], **summarise_row(frame[frame["row"] == row.label])}
                 for row in rows},
        "comparisons": comps,
        "definitions": {**COMPARE_DEFINITIONS,
                        "ci95": "Student t interval of the mean over episodes (dt_highway.metrics.stats.describe)",
                        "tests": "b - a paired by seed: Wilcoxon signed-rank and paired t p-values, Cohen's d_z "
                                 "(dt_highway.metrics.stats.paired_tests); pairs with a NaN (no cut-in) are left out",
                        "collisions": "episodes ending crashed in a, in b, only in a, only in b, in both"},
        "episodes_table": results,
    }


def _num(x: float | None, digits: int = 2) -> str:
    return "–" if x is None or not math.isfinite(x) else f"{x:.{digits}f}"


def _mean_ci(d: dict[str, Any], digits: int = 2) -> str:
    lo, hi = d["ci95"]
    ci = f" [{_num(lo, digits)}, {_num(hi, digits)}]" if lo is not None else ""
    return f"{_num(d['mean'], digits)}{ci}"


def _p(x: float | None) -> str:
    return "–" if x is None else (f"{x:.3f}" if x >= 0.001 else "<0.001")


def markdown_table(result: dict[str, Any]) -> str:
    """The rows and the paired comparisons as Markdown (for ``docs/results/rl/``).

    :param result: :func:`rl_compare`'s result
    :return: the tables, with a line on the seeds and the definitions
    """
    lines = [f"{result['episodes']} episodes per row of {result['scenario']}, seeds "
             f"{result['seeds'][0]}..{result['seeds'][1]} (the same in every row)"
             + (f", with {' '.join('--set ' + o for o in result['overrides'])}" if result["overrides"] else "") + ".",
             "",
             ("| Row | Collisions (kinds) | Conflicts / h (2-D TTC < 1.5 s) | Cut-in min TTC [s]: median of all cut-ins (n); "
             "mean of episode medians | Mean speed [km/h] | Return |"),
             "|---|---|---|---|---|---|"]
    for label, r in result["rows"].items():
        kinds = ", ".join(f"{k} {n}" for k, n in r["collision_kinds"].items())
        lines.append(
            f"| {label} | {r['collisions']}/{r['episodes']}{f' ({kinds})' if kinds else ''} "
            f"| {_mean_ci(r['conflicts_2d_per_h'], 1)} "
            f"| {_num(r['cut_in_ttc_pooled_median_s'])} ({r['cut_ins']}); {_mean_ci(r['cut_in_ttc_median_s'])} "
            f"| {_mean_ci(r['speed_mean_kmh'], 1)} | {_mean_ci(r['return'], 1)} |")
    lines += ["", "Means with 95 % confidence intervals (Student t over episodes).", ""]
    if result["comparisons"]:
        lines += [("| Comparison (b − a, paired by seed) | Pairs | Δ conflicts / h (p Wilcoxon, p t) "
                  "| Δ cut-in min TTC [s] (p W, p t) | Δ mean speed [km/h] (p W, p t) | Δ return (p W, p t) "
                  "| Collisions a / b (only a, only b) |"),
                  "|---|---|---|---|---|---|---|"]
        for c in result["comparisons"]:
            cells = []
            for m in ("conflicts_2d_per_h", "cut_in_ttc_median_s", "speed_mean_kmh", "return"):
                t = c["tests"].get(m)
                cells.append("–" if t is None else
                             f"{_num(t['mean_diff'])} ({_p(t['wilcoxon_p'])}, {_p(t['ttest_p'])}; n {t['n_pairs']})")
            k = c["collisions"]
            n = c["tests"].get("return", {}).get("n_pairs", 0)
            lines.append(f"| {c['b']} − {c['a']} ({c['kind']}) | {n} | " + " | ".join(cells)
                         + f" | {k['a']} / {k['b']} ({k['only_a']}, {k['only_b']}) |")
        lines += ["", ("Δ is b − a (negative conflicts and positive TTC favour b); cut-in TTC pairs need a cut-in "
                  "in both episodes of the seed.")]
        if result["episodes"] < MIN_PAIRS:
            lines.append(f"Small sample: {result['episodes']} pairs per comparison; below {MIN_PAIRS} the p-values "
                         f"and intervals say little.")
    return "\n".join(lines) + "\n"


EPISODE_COLUMNS = ("row", "driver", "condition", "ablation", "seed", "return", "steps", "collision", "collision_label",
                   "conflicts_2d", "conflicts_2d_per_h", "cut_ins", "cut_in_ttc_median_s", "cut_in_ttc_min_s",
                   "speed_mean_kmh", "ttc2d_min_s", "duration_s")
"""The episodes CSV's first columns (every other metric of the episode follows)"""


def compare_paths(out: str | Path) -> list[Path]:
    """The files :func:`write_compare` writes into the folder ``out``.

    :param out: the folder
    :return: ``compare.json``, ``compare.md`` and ``episodes.csv`` in it
    """
    return [Path(out) / name for name in ("compare.json", "compare.md", "episodes.csv")]


def write_compare(result: dict[str, Any], out: str | Path) -> list[Path]:
    """Write ``compare.json`` (everything), ``compare.md`` (:func:`markdown_table`) and ``episodes.csv``
    (one line per episode; ``cut_in_ttcs_s`` joined by ``;``) into the folder ``out``.

    :param result: a result of :func:`rl_compare`
    :param out: the folder (created)
    :return: the files written
    """
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    frame = pd.DataFrame(result["episodes_table"])
    frame["cut_in_ttcs_s"] = frame["cut_in_ttcs_s"].map(lambda vs: ";".join(f"{v:.3f}" for v in vs))
    first = [c for c in EPISODE_COLUMNS if c in frame]
    frame = frame[first + [c for c in frame.columns if c not in first]]
    paths = compare_paths(folder)
    paths[0].write_text(dump_json(result) + "\n", encoding="utf-8")
    paths[1].write_text(markdown_table(result), encoding="utf-8")
    frame.to_csv(paths[2], index=False)
    return paths

"""The safety-metrics report of a study directory (paper Fig. 7): tables, paired tests, plots.

``write_report(study_dir)`` reads every trial log under ``<study>/trials`` and writes
``metrics.csv`` (one row per trial), ``summary.json`` (per condition: n, mean, SD and 95 %
CI of each metric; paired tests between conditions) and a self-contained ``report.html``
(plots embedded as PNG). Only completed trials enter the statistics; aborted ones are
listed; practice trials are left out. Pairs are trials with the same pair number (scripted
drivers) or participant (keyboard trials).
"""

from __future__ import annotations

import base64
import io
import math
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any

import jinja2
import matplotlib
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
from scipy import stats

from dt_highway.jsonio import dump_json
from dt_highway.metrics.safety import CUT_IN_WINDOW_S, MS_TO_KMH, TTC_CAP_S, TTC_STAR_S
from dt_highway.metrics.trial_log import load_trial

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

SUMMARY_METRICS = ("speed_variance_kmh2", "ttc_mean_s", "ttc_min_s", "tet_s", "tit_s2", "speed_mean_kmh",
                   "headway_mean_s", "drac_max_mps2", "hard_brakes", "cut_in_ttc_min_s", "reaction_mean_s")
"""Metrics summarised per condition and tested between conditions"""
PAPER = {"speed_variance_kmh2": (16.6, 14.2), "ttc_mean_s": (1.2, 3.2)}
"""The paper's values, baseline -> ADAS (units not stated there)"""
DEFINITIONS = {
    "speed_variance_kmh2": (
        "sample variance (N-1) of the ego's speed in km/h over the trial's simulation steps [(km/h)^2]"
    ),
    "ttc_mean_s": f"mean TTC over closing samples with TTC below {TTC_CAP_S:g} s [s]",
    "ttc_min_s": f"minimum TTC over the trial, capped at {TTC_CAP_S:g} s (never closer: {TTC_CAP_S:g}) [s]",
    "tet_s": f"time exposed TTC: time with 0 <= TTC <= {TTC_STAR_S:g} s [s] (Minderhoud & Bovy 2001)",
    "tit_s2": f"time integrated TTC: integral of ({TTC_STAR_S:g} s - TTC) over that time [s^2]",
    "speed_mean_kmh": "mean ego speed [km/h]",
    "headway_mean_s": "mean time headway gap / ego speed, with a leader [s]",
    "drac_max_mps2": "maximum deceleration rate to avoid the crash dv^2 / (2 gap) [m/s^2]",
    "hard_brakes": "onsets of ego deceleration >= 3 m/s^2 [-]",
    "cut_in_ttc_min_s": f"smallest of the cut-ins' minimum TTC to the cutting vehicle, capped at {TTC_CAP_S:g} s [s]",
    "reaction_mean_s": "mean time from a cut-in to the ego's first deceleration >= 1 m/s^2 [s]",
    "ttc": (
        "gap / closing speed, bumper to bumper to the vehicle ahead overlapping the ego's lane; "
        "infinite when not closing"
    ),
    "collisions": "onsets of the ego's crash [-]",
}


def collect(study_dir: str | Path) -> tuple[pd.DataFrame, dict[str, Any]]:
    """Every trial's metrics (one row each) and the data the plots need.

    :raises FileNotFoundError: when the directory holds no trials
    """
    root = Path(study_dir)
    dirs = sorted(p.parent for p in root.glob("trials/*/meta.json"))
    if not dirs:
        raise FileNotFoundError(f"no trials under {root / 'trials'} (run dt-highway study first)")
    rows: list[dict[str, Any]] = []
    traces: list[dict[str, Any]] = []
    ttc_samples: dict[str | None, list[np.ndarray]] = {}
    cut_ins: list[dict[str, Any]] = []
    for d in dirs:
        trial = load_trial(d)
        meta = trial.meta
        if meta.get("practice"):
            continue  # practice trials are not data
        cuts = trial.cut_ins
        row = {"trial": d.name, "condition": meta.get("condition"), "pair": meta.get("pair"),
               "participant": meta.get("participant"), "driver": meta.get("driver"), "seed": meta.get("seed"),
               "status": meta.get("status"), "end_reason": meta.get("end_reason")}
        if len(trial.steps):
            row.update(trial.metrics())
        rows.append(row)
        if meta.get("status") != "completed" or not len(trial.steps):
            continue
        s = trial.steps
        cond = meta.get("condition")
        ttc = s["ttc_s"].to_numpy(float)
        ttc_samples.setdefault(cond, []).append(ttc[(s["closing_mps"].to_numpy(float) > 0) & (ttc < TTC_CAP_S)])
        t = s["t_s"].to_numpy(float)
        v = s["speed_mps"].to_numpy(float) * MS_TO_KMH
        overlay = s["overlay_ids"].fillna("").astype(str).to_numpy()
        for c in cuts:
            t0 = float(c["t_s"])
            grid = np.arange(-2.0, CUT_IN_WINDOW_S + 1e-9, 0.5)
            trace = np.interp(t0 + grid, t, v, left=np.nan, right=np.nan)
            traces.append({"condition": cond, "grid": grid, "speed_kmh": trace - np.interp(t0, t, v)})
            # marked in time: on the overlay at some step of the window before the cut-in
            before = overlay[(t >= t0 - CUT_IN_WINDOW_S) & (t <= t0)]
            vid = str(int(c["vehicle_id"]))
            marked_before = any(vid in ids.split(";") for ids in before if ids)
            cut_ins.append({"condition": cond, "driver_type": c.get("driver_type"), "marked_in_time": marked_before})
    return pd.DataFrame(rows), {"traces": traces, "ttc": ttc_samples, "cut_ins": cut_ins}


def _describe(x: np.ndarray) -> dict[str, Any]:
    x = x[np.isfinite(x)]
    n = len(x)
    if not n:
        return {"n": 0, "mean": None, "sd": None, "ci95": [None, None]}
    mean = float(x.mean())
    sd = float(x.std(ddof=1)) if n > 1 else None
    ci: list[float | None]
    if n > 1 and sd is not None:
        half = float(stats.t.ppf(0.975, n - 1) * sd / math.sqrt(n))
        ci = [mean - half, mean + half]
    else:
        ci = [None, None]
    return {"n": n, "mean": mean, "sd": sd, "ci95": ci}


def paired_tests(metrics: pd.DataFrame, a: str = "baseline", b: str = "adas") -> dict[str, Any]:
    """Wilcoxon signed-rank and paired t-test of ``b - a`` per metric, with Cohen's ``d_z``.

    Pairs: same participant when the trials have one, else the same pair number.
    """
    done = metrics[metrics["status"] == "completed"].copy()
    done["key"] = done["participant"].where(done["participant"].notna(), done["pair"].astype(str))
    out: dict[str, Any] = {}
    for m in SUMMARY_METRICS:
        if m not in done:
            continue
        wide = done.pivot_table(index="key", columns="condition", values=m, aggfunc="first")
        if a not in wide or b not in wide:
            continue
        pair = wide[[a, b]].replace([np.inf, -np.inf], np.nan).dropna()
        diff = (pair[b] - pair[a]).to_numpy(float)
        res: dict[str, Any] = {"n_pairs": len(diff), "mean_diff": float(diff.mean()) if len(diff) else None,
                               "wilcoxon_p": None, "ttest_p": None, "effect_size_dz": None}
        if len(diff) >= 2 and np.any(diff != 0):
            res["wilcoxon_p"] = float(stats.wilcoxon(diff).pvalue)
            sd = diff.std(ddof=1)
            if sd > 0:
                res["ttest_p"] = float(stats.ttest_rel(pair[b], pair[a]).pvalue)
                res["effect_size_dz"] = float(diff.mean() / sd)
        out[m] = res
    return out


def summarise(metrics: pd.DataFrame, extra: dict[str, Any]) -> dict[str, Any]:
    """``summary.json``'s contents."""
    done = metrics[metrics["status"] == "completed"]
    conditions = {}
    order = {"baseline": 0, "adas": 1}
    for cond, g in sorted(done.groupby("condition"), key=lambda cg: (order.get(cg[0], 2), str(cg[0]))):
        entry: dict[str, Any] = {"n": int(len(g))}
        for m in SUMMARY_METRICS:
            if m in g:
                entry[m] = _describe(g[m].to_numpy(float))
        entry["collisions"] = int(g["collisions"].sum()) if "collisions" in g else 0
        cuts = [c for c in extra["cut_ins"] if c["condition"] == cond]
        entry["cut_ins"] = len(cuts)
        entry["cut_ins_marked_in_time"] = sum(c["marked_in_time"] for c in cuts)
        rough = [c for c in cuts if c["driver_type"] == "aggressive"]
        entry["cut_ins_by_aggressive"] = len(rough)
        entry["cut_ins_by_aggressive_marked_in_time"] = sum(c["marked_in_time"] for c in rough)
        conditions[str(cond)] = entry
    return {"conditions": conditions, "paired_tests": paired_tests(metrics),
            "aborted_trials": metrics.loc[metrics["status"] != "completed", "trial"].tolist(),
            "paper": {k: {"baseline": v[0], "adas": v[1]} for k, v in PAPER.items()},
            "definitions": DEFINITIONS}


def _png(fig: Figure) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _legend(ax: Axes) -> None:
    if ax.get_legend_handles_labels()[1]:
        ax.legend(fontsize=8)
    else:
        ax.text(0.5, 0.5, "no data", transform=ax.transAxes, ha="center", va="center", color="0.5")


def _plots(metrics: pd.DataFrame, extra: dict[str, Any]) -> dict[str, str]:
    matplotlib.use("Agg")
    colours = {"baseline": "tab:grey", "adas": "tab:red"}
    out = {}
    fig, ax = plt.subplots(figsize=(6, 3.2))
    for cond, chunks in extra["ttc"].items():
        x = np.concatenate(chunks) if chunks else np.zeros(0)
        if len(x):
            ax.hist(x, bins=np.linspace(0, TTC_CAP_S, 41).tolist(), alpha=0.55, density=True,
                    label=f"{cond} ({len(x)} samples)", color=colours.get(cond))
    ax.axvline(TTC_STAR_S, color="k", lw=0.8, ls="--")
    ax.set_xlabel("TTC while closing [s]")
    ax.set_ylabel("density")
    _legend(ax)
    out["ttc"] = _png(fig)

    fig, ax = plt.subplots(figsize=(4.5, 3.4))
    done = metrics[metrics["status"] == "completed"]
    wide = done.pivot_table(index="pair", columns="condition", values="speed_variance_kmh2", aggfunc="first")
    if {"baseline", "adas"} <= set(wide.columns):
        for _, r in wide.iterrows():
            ax.plot([0, 1], [r["baseline"], r["adas"]], color="0.6", marker="o", ms=3, lw=0.8)
        ax.plot([0, 1], [wide["baseline"].mean(), wide["adas"].mean()], color="tab:red", marker="o", lw=2.5,
                label="mean")
    _legend(ax)
    ax.set_xticks([0, 1], ["baseline", "ADAS"])
    ax.set_ylabel("speed variance [(km/h)$^2$]")
    out["variance"] = _png(fig)

    fig, ax = plt.subplots(figsize=(6, 3.2))
    for cond in ("baseline", "adas"):
        tr = [t for t in extra["traces"] if t["condition"] == cond]
        if tr:
            arr = np.array([t["speed_kmh"] for t in tr])
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # instants no trace reaches
                ax.plot(tr[0]["grid"], np.nanmean(arr, axis=0), color=colours[cond], lw=2,
                        label=f"{cond} ({len(tr)} cut-ins)")
    ax.axvline(0, color="k", lw=0.8, ls="--")
    ax.set_xlabel("time from the cut-in [s]")
    ax.set_ylabel("ego speed change [km/h]")
    _legend(ax)
    out["cut_in_speed"] = _png(fig)
    return out


_TEMPLATE = """<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>dt-highway safety report: {{ name }}</title>
<style>body{font-family:system-ui,sans-serif;max-width:60em;margin:2em auto;padding:0 1em;color:#222}
table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #ccc;padding:.3em .6em;text-align:right}
th{background:#f3f3f3}td:first-child,th:first-child{text-align:left}img{max-width:100%}
.small{color:#666;font-size:.9em}</style></head><body>
<h1>Safety metrics: {{ name }}</h1>
<p>Drivers: {{ drivers }}. Trials: {{ n_completed }} completed{% if aborted %}, {{ aborted|length }} aborted ({{ aborted|join(", ") }}){% endif %}.</p>
<h2>Per condition</h2>
<table><tr><th>metric</th>{% for c in conds %}<th>{{ c }}: mean &plusmn; SD [95% CI] (n)</th>{% endfor %}<th>paper (baseline &rarr; ADAS)</th></tr>
{% for m in metrics %}<tr><td title="{{ definitions[m] }}">{{ m }}</td>
{% for c in conds %}{% set d = summary.conditions[c][m] %}<td>{{ fmt(d.mean) }} &plusmn; {{ fmt(d.sd) }} [{{ fmt(d.ci95[0]) }}, {{ fmt(d.ci95[1]) }}] ({{ d.n }})</td>{% endfor %}
<td>{% if m in paper %}{{ paper[m].baseline }} &rarr; {{ paper[m].adas }}{% endif %}</td></tr>{% endfor %}
<tr><td>collisions</td>{% for c in conds %}<td>{{ summary.conditions[c].collisions }}</td>{% endfor %}<td></td></tr>
</table>
<h2>Paired tests (ADAS &minus; baseline)</h2>
<table><tr><th>metric</th><th>pairs</th><th>mean difference</th><th>Wilcoxon p</th><th>paired t p</th><th>d<sub>z</sub></th></tr>
{% for m, t in summary.paired_tests.items() %}<tr><td>{{ m }}</td><td>{{ t.n_pairs }}</td><td>{{ fmt(t.mean_diff) }}</td><td>{{ fmt(t.wilcoxon_p) }}</td><td>{{ fmt(t.ttest_p) }}</td><td>{{ fmt(t.effect_size_dz) }}</td></tr>{% endfor %}
</table>
<h2>Plots</h2>
<h3>TTC distribution</h3><img alt="TTC distribution per condition" src="data:image/png;base64,{{ plots.ttc }}">
<h3>Speed variance, paired by trial</h3><img alt="paired speed variance" src="data:image/png;base64,{{ plots.variance }}">
<h3>Speed around cut-ins</h3><img alt="speed traces around cut-ins" src="data:image/png;base64,{{ plots.cut_in_speed }}">
<h2>How the overlay performed</h2>
<p>A cut-in's vehicle counts as marked in time when the overlay showed it at some moment of the {{ window }} s before it cut in.</p>
<table><tr><th>condition</th><th>cut-ins</th><th>marked in time</th><th>cut-ins by aggressive drivers (true type)</th><th>of those, marked in time</th></tr>
{% for c in conds %}{% set e = summary.conditions[c] %}<tr><td>{{ c }}</td><td>{{ e.cut_ins }}</td><td>{{ e.cut_ins_marked_in_time }}{{ pct(e.cut_ins_marked_in_time, e.cut_ins) }}</td>
<td>{{ e.cut_ins_by_aggressive }}</td><td>{{ e.cut_ins_by_aggressive_marked_in_time }}{{ pct(e.cut_ins_by_aggressive_marked_in_time, e.cut_ins_by_aggressive) }}</td></tr>{% endfor %}
</table>
<h2>Definitions</h2><ul>{% for k, v in definitions.items() %}<li><b>{{ k }}</b>: {{ v }}</li>{% endfor %}</ul>
<p class="small">The paper does not state its units or how it aggregates TTC; the values above follow the definitions listed here.</p>
</body></html>
"""  # noqa: E501 - the HTML template's lines are as long as its rows


def _fmt(x: Any) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "–"
    if isinstance(x, float):
        return f"{x:.3g}" if abs(x) < 0.01 else f"{x:.2f}"
    return str(x)


def write_report(study_dir: str | Path) -> dict[str, Path]:
    """Write ``metrics.csv``, ``summary.json`` and ``report.html`` into the study directory.

    :return: the files written
    :raises FileNotFoundError: when the directory holds no trials
    """
    root = Path(study_dir)
    metrics, extra = collect(root)
    summary = summarise(metrics, extra)
    files = {"metrics": root / "metrics.csv", "summary": root / "summary.json", "html": root / "report.html"}
    metrics.to_csv(files["metrics"], index=False)
    files["summary"].write_text(dump_json(summary) + "\n")
    env = jinja2.Environment(autoescape=True, undefined=jinja2.StrictUndefined)
    conds = [c for c in ("baseline", "adas") if c in summary["conditions"]] + sorted(
        c for c in summary["conditions"] if c not in ("baseline", "adas"))
    html = env.from_string(_TEMPLATE).render(
        name=root.name, drivers=", ".join(sorted(str(d) for d in metrics["driver"].dropna().unique())),
        n_completed=int((metrics["status"] == "completed").sum()), aborted=summary["aborted_trials"], conds=conds,
        metrics=[m for m in SUMMARY_METRICS if all(m in summary["conditions"][c] for c in conds)], summary=summary,
        paper=summary["paper"], definitions=DEFINITIONS, plots=_plots(metrics, extra), fmt=_fmt,
        window=f"{CUT_IN_WINDOW_S:g}",
        pct=lambda k, n: f" ({100 * k / n:.0f} %)" if n else "")
    files["html"].write_text(html, encoding="utf-8")
    return files

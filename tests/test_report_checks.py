"""The report checks every trial it reads (a bad one is excluded, named, with its reason), says
where it came from, and labels its numbers: hand-made studies, hand-computed values."""

import json
import math
import shutil
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

from dt_highway.cli import main
from dt_highway.config import ConfigError
from dt_highway.metrics.trial_log import (
    PACKAGE_DIR,
    TrialLogError,
    TrialWriter,
    check_trial,
    expected_rows,
    git_commit,
    load_trial,
)
from dt_highway.report import METRIC_INFO, _pfmt, describe, metric_label, write_report

HZ = 2  # samples every 0.5 s; planned 10 s: 20 rows


def write_trial(root, cond, pair, speed_mps, n=20, crash=False, duration=10.0):
    """A trial of ``n`` rows at 2 Hz, constant speed; a crash at the last row when ``crash``."""
    meta = {"driver": "idm", "condition": cond, "pair": pair, "seed": 10 + pair, "participant": None,
            "scenario": "/x/inputs/highway-trial.toml", "overrides": ["highway.duration=10"],
            "simulation_frequency_hz": HZ, "config": {"highway": {"duration": duration, "policy_frequency": HZ}}}
    d = root / "trials" / f"{cond}-{pair:03d}"
    with TrialWriter(d, meta) as log:
        for k in range(n):
            hit = crash and k == n - 1
            log.step({"t_s": (k + 1) / HZ, "x_m": speed_mps * (k + 1) / HZ, "y_m": 4.0, "lane": 1,
                      "speed_mps": speed_mps + (k % 2), "accel_mps2": 0.0, "leader_id": -1, "gap_m": math.inf,
                      "closing_mps": 0.0, "ttc_s": math.inf, "drac_mps2": 0.0, "headway_s": math.inf, "crashed": hit,
                      "ttc_contact": False, "ttc2d_s": math.inf, "ttc2d_id": -1, "ttc2d_contact": False,
                      "action_accel_mps2": 0.0, "action_lane": 0.0, "keys": "", "overlay_ids": "", "overlay_labels": ""})
        if crash:
            log.meta["end_reason"] = "collision"
    return d


def make_study(root, pairs=6):
    """``pairs`` pairs of baseline (20 m/s) and adas (20 + pair m/s) trials, with a study.json."""
    dirs = {}
    for pair in range(pairs):
        dirs[("baseline", pair)] = write_trial(root, "baseline", pair, 20.0)
        dirs[("adas", pair)] = write_trial(root, "adas", pair, 20.0 + pair)
    (root / "study.json").write_text(json.dumps({"trials": [{"directory": str(d)} for d in dirs.values()]}))
    return dirs


def test_expected_rows_follow_highway_envs_clock():
    assert expected_rows(120, 15, 5) == 1800  # the paper's trial: one row per simulation step
    assert expected_rows(60, 15, 5) == 900 and expected_rows(4, 15, 5) == 60
    assert expected_rows(1.5, 15, 15) == 23  # the clock passes 1.5 s at the 23rd step
    assert expected_rows(1.5, 15, 5) == 24  # 8 decisions of 3 steps
    assert expected_rows(10, 2) == 20


def test_check_trial_names_what_is_wrong(tmp_path):
    good = write_trial(tmp_path, "baseline", 0, 20.0)
    assert check_trial(load_trial(good)) is None
    short = write_trial(tmp_path, "baseline", 1, 20.0, n=12, crash=True)  # a collision ended it: legitimate
    assert check_trial(load_trial(short)) is None
    stopped = write_trial(tmp_path, "baseline", 2, 20.0, n=12)  # no collision: rows are missing
    assert check_trial(load_trial(stopped)) == "steps.csv has 12 rows, 20 expected (10 s at 2 Hz): truncated"
    longer = write_trial(tmp_path, "baseline", 3, 20.0, n=22)
    assert check_trial(load_trial(longer)) == "steps.csv has 22 rows, 20 expected (10 s at 2 Hz)"
    text = write_trial(tmp_path, "baseline", 4, 20.0)
    csv = (text / "steps.csv").read_text().splitlines()
    cells = csv[5].split(",")
    cells[4] = "fast"  # speed_mps of the 5th row (line 6 of the file)
    (text / "steps.csv").write_text("\n".join([*csv[:5], ",".join(cells), *csv[6:]]) + "\n")
    assert check_trial(load_trial(text)) == "steps.csv column speed_mps is not numbers: line 6 holds 'fast'"
    gap = write_trial(tmp_path, "baseline", 5, 20.0)
    csv = (gap / "steps.csv").read_text().splitlines()
    (gap / "steps.csv").write_text("\n".join([*csv[:3], csv[4], csv[4], *csv[5:]]) + "\n")  # row 3 lost, row 4 twice
    meta = json.loads((gap / "meta.json").read_text())
    assert check_trial(load_trial(gap)) == "steps.csv times are not one row per step: line 4 has t = 2 s, 1.5 expected"
    (gap / "meta.json").write_text(json.dumps({**meta, "status": "aborted", "end_reason": "interrupted by the user"}))
    assert check_trial(load_trial(gap)) == "status aborted (interrupted by the user)"


def _meta(d, **changes):
    meta = json.loads((d / "meta.json").read_text())
    (d / "meta.json").write_text(json.dumps({**meta, **changes}))


def _config(d, **highway):
    meta = json.loads((d / "meta.json").read_text())
    _meta(d, config={**meta["config"], "highway": {**meta["config"]["highway"], **highway}})


@pytest.mark.parametrize(("damage", "reason"), [
    (lambda d: _config(d, duration=1e12), None),  # counted, not summed for ever: 2e12 rows expected
    (lambda d: _config(d, duration="long"), ("meta.json lacks the configured duration or a frequency, as positive numbers "
                                             "(config.highway.duration 'long', simulation_frequency_hz 2, "
                                             "config.highway.policy_frequency 2)")),
    (lambda d: _config(d, policy_frequency=-1), "config.highway.policy_frequency -1)"),
    (lambda d: _config(d, duration=float("inf")), "config.highway.duration inf,"),
    (lambda d: _meta(d, config=[1]), "config.highway.duration None,"),
    (lambda d: _meta(d, condition=None), "meta.json names no condition (condition: None)"),
    (lambda d: (d / "steps.csv").write_text((d / "steps.csv").read_text().replace(",20.0,", ",1e400,", 1)),
     "steps.csv column speed_mps holds an infinite number at line 2"),
    (lambda d: (d / "events.jsonl").write_text('{"kind": "cut_in", "t_s": 1.0}\n'),
     "events.jsonl cut_in event 1 names no vehicle (vehicle_id: None)"),
    (lambda d: (d / "events.jsonl").write_text('{"kind": "collision", "t_s": "x"}\n'),
     "events.jsonl collision event 1 has no time (t_s: 'x')"),
    (lambda d: (d / "events.jsonl").write_text("[1]\n"), "events.jsonl event 1 is not a JSON object"),
])
def test_damaged_metadata_and_events_are_a_reason_not_a_hang_or_a_crash(tmp_path, damage, reason):
    d = write_trial(tmp_path, "baseline", 0, 20.0)
    damage(d)
    why = check_trial(load_trial(d))
    if reason is None:
        assert why == "steps.csv has 20 rows, 2000000000000 expected (1e+12 s at 2 Hz): truncated"
    else:
        assert why is not None and reason in why, why


def test_expected_rows_refuses_what_is_not_a_duration():
    for bad in ((math.inf, 15), (3, -15), (math.nan, 15), (0, 15)):
        with pytest.raises(ValueError, match="positive finite numbers"):
            expected_rows(*bad)
    assert expected_rows(1e300, 15, 5) > 0  # at once


def test_a_study_with_damaged_trials_still_reports_on_the_others(tmp_path):
    dirs = make_study(tmp_path, pairs=3)
    _config(dirs[("adas", 0)], duration="long")
    _meta(dirs[("adas", 1)], config=[1])
    (dirs[("adas", 2)] / "events.jsonl").write_text('{"kind": "cut_in", "t_s": 1.0}\n')
    warnings: list[str] = []
    write_report(tmp_path, warn=warnings.append)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert sorted(e["trial"] for e in summary["excluded"]) == ["adas-000", "adas-001", "adas-002"]
    assert summary["conditions"]["baseline"]["n"] == 3 and len(warnings) == 3


def test_unreadable_logs_raise_one_error_naming_the_file(tmp_path):
    d = write_trial(tmp_path, "baseline", 0, 20.0)
    (d / "meta.json").write_text('{"status": "completed",')
    with pytest.raises(TrialLogError, match=r"meta.json: is not valid JSON \(Expecting property name"):
        load_trial(d)
    (d / "meta.json").write_text("[1, 2]")
    with pytest.raises(TrialLogError, match="holds a JSON list, not an object"):
        load_trial(d)


@pytest.fixture(scope="module")
def broken(tmp_path_factory):
    """A study of 6 pairs, four of whose trials are broken in four ways, one missing its meta.json."""
    root = tmp_path_factory.mktemp("broken")
    dirs = make_study(root)
    steps = dirs[("adas", 0)] / "steps.csv"
    lines = steps.read_text().splitlines()
    steps.write_text("\n".join(lines[: 1 + 10]) + "\n")  # half-length: the header and 10 of 20 rows
    (dirs[("adas", 1)] / "steps.csv").write_text(lines[0] + "\n")  # empty: the header only
    (dirs[("adas", 2)] / "meta.json").unlink()  # missing meta.json
    (dirs[("adas", 3)] / "meta.json").write_text("{not json")  # corrupt meta.json
    (dirs[("adas", 4)] / "steps.csv").write_text(lines[0] + "\n" + lines[1] + ",1,2,3\n\x00\x01garbage\n")  # corrupt
    shutil.rmtree(dirs[("baseline", 5)])  # planned in study.json, never run
    warnings: list[str] = []
    write_report(root, warn=warnings.append)
    return root, json.loads((root / "summary.json").read_text()), warnings


REASONS = {
    "adas-000": "steps.csv has 10 rows, meta.json counts 20 written",
    "adas-001": "steps.csv has no rows",
    "adas-002": "meta.json missing",
    "adas-003": "meta.json is not valid JSON (Expecting property name enclosed in double quotes, line 1 column 2)",
    "adas-004": "steps.csv is not a readable CSV (line 2 has 25 fields, the header 22)",
    "baseline-005": "not run (planned in study.json, no trial directory)",
}


def test_bad_trials_are_excluded_each_with_its_reason(broken):
    root, summary, warnings = broken
    assert {e["trial"]: e["reason"] for e in summary["excluded"]} == REASONS
    assert warnings == [f"trial {t} excluded: {r}" for t, r in REASONS.items()]  # one line each, naming the trial
    html = (root / "report.html").read_text()
    assert "6 trials excluded" in html
    for t, r in REASONS.items():
        assert f"<li>{t}: {r.replace('(', '(')}" in html.replace("&#34;", '"').replace("&#39;", "'")
    metrics = pd.read_csv(root / "metrics.csv").set_index("trial")
    assert metrics.loc["adas-000", "excluded"] == REASONS["adas-000"]
    assert pd.isna(metrics.loc["adas-005", "excluded"])  # kept


def test_the_others_are_kept_and_their_numbers_unchanged(broken):
    _, summary, _ = broken
    conds = summary["conditions"]
    assert conds["baseline"]["n"] == 5 and conds["adas"]["n"] == 1  # adas-005 alone; baseline-005 never ran
    assert summary["comparisons"][0]["n_pairs"] == 0  # adas-005's partner is missing
    # the mean speed of baseline: 20 and 21 m/s alternating, 20.5 m/s = 73.8 km/h, in each of the 5 trials
    assert conds["baseline"]["speed_mean_kmh"]["mean"] == pytest.approx(73.8)
    assert conds["adas"]["speed_mean_kmh"]["mean"] == pytest.approx(25.5 * 3.6)


def test_a_whole_study_that_cannot_be_read_is_one_error(tmp_path, capsys):
    assert main(["report", str(tmp_path / "nope")]) == 2
    assert capsys.readouterr().err.strip() == f"dt-highway report: error: study directory {tmp_path / 'nope'} does not exist"
    (tmp_path / "file").write_text("x")
    assert main(["report", str(tmp_path / "file")]) == 2
    assert "is not a study directory (it is a file)" in capsys.readouterr().err
    root = tmp_path / "all-bad"
    d = write_trial(root, "baseline", 0, 20.0)
    (d / "meta.json").write_text("")
    assert main(["report", str(root)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["warning: trial baseline-000 excluded: meta.json is not valid JSON (Expecting value, line 1 column 1)",
                   f"dt-highway report: error: no usable trial under {root / 'trials'}: all 1 excluded (see the warnings)"]
    (tmp_path / "empty-study").mkdir()
    with pytest.raises(ConfigError, match="no trials under"):
        write_report(tmp_path / "empty-study")


def test_a_cut_short_trial_is_kept_not_excluded(tmp_path):
    make_study(tmp_path, pairs=2)
    write_trial(tmp_path, "adas", 1, 21.0, n=12, crash=True)
    warnings: list[str] = []
    write_report(tmp_path, warn=warnings.append)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert warnings == [] and summary["excluded"] == []
    assert [t["trial"] for t in summary["cut_short_trials"]] == ["adas-001"] and summary["conditions"]["adas"]["n"] == 2


def test_provenance_in_the_summary_and_the_html(tmp_path):
    make_study(tmp_path, pairs=3)
    files = write_report(tmp_path, warn=lambda m: None)
    prov = json.loads(files["summary"].read_text())["provenance"]
    assert prov["scenario"] == ["highway-trial.toml"] and prov["overrides"] == [["highway.duration=10"]]
    assert prov["trial_length_s"] == [10.0] and prov["simulation_frequency_hz"] == [HZ]
    assert prov["seeds"] == [10, 11, 12] and prov["seeds_text"] == "10-12" and prov["drivers"] == ["idm"]
    assert prov["trials"] == 6 and prov["hosts"]["trials"] == [prov["hosts"]["report"]]
    assert prov["git_commit"]["report"] == git_commit() and prov["package_version"]["report"]
    assert prov["trials_started"] <= prov["trials_ended"] <= prov["report_date"]
    html = files["html"].read_text()
    for text in ("Scenario</td><td>highway-trial.toml (--set highway.duration=10)", "Trial length</td><td>10 s at 2 Hz",
                 "Seeds</td><td>10-12", "Drivers</td><td>idm", "Git commit</td>", "Report written</td>"):
        assert text in html


def test_git_commit_of_a_checkout_and_of_none(tmp_path):
    assert git_commit(tmp_path) is None  # not a git checkout (an installed package)
    if (PACKAGE_DIR / ".git").exists():
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=PACKAGE_DIR, capture_output=True, text=True).stdout
        assert git_commit().split("-")[0] == head.strip()


def test_labels_units_p_values_and_small_samples(tmp_path):
    assert metric_label("speed_variance_kmh2") == "Speed variance [(km/h)^2]"
    assert metric_label("speed_variance_kmh2", tex=True) == "Speed variance [(km/h)$^2$]"
    assert metric_label("tit_s2") == "Time integrated TTC (TIT) [s^2]" and metric_label("other") == "other"
    assert (_pfmt(0.0004), _pfmt(0.04567), _pfmt(None), _pfmt(1.0)) == ("< 0.001", "0.046", "–", "1.000")
    make_study(tmp_path, pairs=3)
    files = write_report(tmp_path, warn=lambda m: None)
    summary = json.loads(files["summary"].read_text())
    assert summary["comparisons"][0]["small_sample"] and summary["labels"]["ttc_min_s"] == {
        "label": "Minimum TTC", "unit": "s", "range": [0.0, 10.0]}
    html = files["html"].read_text()
    assert "Small sample:</b> adas &minus; baseline has 3 pairs; below 10 pairs" in html
    assert ">Speed variance [(km/h)^2]</td>" in html and ">speed_variance_kmh2<" not in html
    assert "d<sub>z</sub> = mean of the paired differences / their SD" in html
    # adas - baseline mean speed: 0, 3.6, 7.2 km/h: Wilcoxon on 2 non-zero differences
    t = summary["comparisons"][0]["tests"]["speed_mean_kmh"]
    assert t["mean_diff"] == pytest.approx(3.6) and t["effect_size_dz"] == pytest.approx(3.6 / 3.6)
    p_t = t["ttest_p"]
    assert f"<td>{_pfmt(t['wilcoxon_p'])}</td><td>{_pfmt(p_t)}</td>" in html


def test_confidence_intervals_stay_in_the_metrics_range():
    d = describe(np.array([0.0, 0.0, 3.0]), 0.0, math.inf)  # mean 1, SD sqrt(3): t(0.975, 2) = 4.303
    half = 4.302652729911275
    assert d["mean"] == 1.0 and d["ci95"] == pytest.approx([0.0, 1.0 + half]) and d["ci95_clipped"]
    assert describe(np.array([0.0, 0.0, 3.0]), 0.0, 3.0)["ci95"] == pytest.approx([0.0, 3.0])
    free = describe(np.array([0.0, 0.0, 3.0]))
    assert free["ci95"] == pytest.approx([1.0 - half, 1.0 + half]) and not free["ci95_clipped"]
    assert all(lo <= hi for *_, lo, hi in METRIC_INFO.values())


def test_report_command_keeps_warnings_on_stderr(tmp_path):
    make_study(tmp_path, pairs=2)
    (tmp_path / "trials" / "adas-001" / "meta.json").unlink()
    proc = subprocess.run([sys.executable, "-m", "dt_highway.cli", "report", str(tmp_path)], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr.strip().splitlines() == ["warning: trial adas-001 excluded: meta.json missing"]

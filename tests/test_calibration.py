"""The baseline calibration harness (dt-highway calibrate) and the cut-in manoeuvre in the logs."""

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from dt_highway.metrics.safety import TTC_CAP_S
from dt_highway.metrics.trial_log import load_trial

ROOT = Path(__file__).resolve().parents[1]


def _cli(*args: str, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "dt_highway.cli", *args], cwd=cwd, capture_output=True, text=True,
                          timeout=600)


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("cal")
    r = _cli("calibrate", "--knob", "traffic.dangerous.brake_mps2=2,4", "--drivers", "agents/idm.toml",
             "--trials", "2", "--set", "traffic.dangerous.share=1.0", "--set", "highway.duration=40",
             "--workers", "2", "--out", str(out), "--quiet")
    assert r.returncode == 0, r.stderr
    assert "| idm | 2 |" in r.stdout and "| idm | 4 |" in r.stdout
    return out


def test_the_table_counts_the_cut_ins_aimed_at_the_ego_from_the_logs(calibrated: Path):
    table = pd.read_csv(calibrated / "calibration.csv")
    assert list(table["traffic.dangerous.brake_mps2"]) == [2, 4] and list(table["trials"]) == [2, 2]
    assert table["cut-ins on the ego [1/h]"].sum() > 0  # the checks below compare something
    for _, row in table.iterrows():
        cell = calibrated / f"idm-traffic.dangerous.brake_mps2={row['traffic.dangerous.brake_mps2']}"
        trials = [load_trial(d) for d in sorted((cell / "trials").iterdir())]
        assert all(t.meta["condition"] == "baseline" for t in trials)  # never the ADAS condition
        events = [e for t in trials for e in t.events if e["kind"] == "cut_in"]
        aimed = [e for e in events if e["maneuver"] in ("gentle", "dangerous")]
        assert all(e["maneuver"] == "dangerous" for e in aimed)  # share = 1
        hours = sum(len(t.steps) for t in trials) / 15 / 3600
        assert row["cut-ins on the ego [1/h]"] == pytest.approx(len(aimed) / hours)
        # the median of the minimum TTC while the cutting car leads, from the steps by hand
        mins = []
        for t in trials:
            s = t.steps
            for e in (e for e in t.events if e["kind"] == "cut_in" and e["maneuver"]):
                after = s[s["t_s"] >= e["t_s"] - 1e-9]
                lead = after["leader_id"].to_numpy() == e["vehicle_id"]
                run = after[: int(np.argmin(lead)) if not lead.all() else len(lead)]
                run = run[run["t_s"] <= e["t_s"] + 10.0]
                mins.append(min(float(run["ttc_s"].min()) if len(run) else math.inf, TTC_CAP_S))
        expected = float(np.median(mins)) if mins else math.nan
        got = row["median min TTC [s]"]
        assert (math.isnan(got) and math.isnan(expected)) or got == pytest.approx(expected)
    assert (calibrated / "calibration.md").read_text().startswith("| driver | traffic.dangerous.brake_mps2 |")


def test_a_bad_knob_is_one_line_before_any_trial(tmp_path: Path):
    r = _cli("calibrate", "--knob", "traffic.dangerous.brake_mps2=-1", "--drivers", "agents/idm.toml",
             "--out", str(tmp_path / "c"), "--quiet")
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1
    assert "traffic.dangerous.brake_mps2" in r.stderr and not (tmp_path / "c").exists()
    r = _cli("calibrate", "--knob", "traffic.dangerous.brake_mps2", "--out", str(tmp_path / "c"), "--quiet")
    assert r.returncode == 2 and "--knob must be KEY=V1,V2" in r.stderr


def test_the_log_says_which_lane_entries_were_cut_ins_aimed_at_the_ego(calibrated: Path):
    cell = calibrated / "idm-traffic.dangerous.brake_mps2=4"
    events = [e for d in sorted((cell / "trials").iterdir()) for e in load_trial(d).events if e["kind"] == "cut_in"]
    assert events and all("maneuver" in e for e in events)
    assert {e["maneuver"] for e in events} <= {"", "gentle", "dangerous"}
    assert json.dumps(events)  # plain JSON values


def test_a_table_of_other_cells_is_replaced_only_with_force(calibrated: Path):
    """A second calibrate into the same --out (by default always runs/calibration) replaced the table with its
    own cells; the same cells again (a resumed run) still write it."""
    common = ["--drivers", "agents/idm.toml", "--trials", "2", "--set", "traffic.dangerous.share=1.0",
              "--set", "highway.duration=40", "--out", str(calibrated), "--quiet"]
    table = (calibrated / "calibration.csv").read_bytes()
    r = _cli("calibrate", "--knob", "traffic.dangerous.brake_mps2=4,2", *common)  # the same cells: resumed
    assert r.returncode == 0, r.stderr
    assert pd.read_csv(calibrated / "calibration.csv")["traffic.dangerous.brake_mps2"].tolist() == [4, 2]
    for knob in ("traffic.dangerous.brake_mps2=2", "traffic.aggressive_fraction=0.3"):
        r = _cli("calibrate", "--knob", knob, *common)
        assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
        assert ("calibration.csv holds the table of another calibration (traffic.dangerous.brake_mps2 = 4, 2 for "
                "idm): pass --force") in r.stderr, r.stderr
    from dt_highway.evaluation.calibration import check_table_kept

    knob = "traffic.dangerous.brake_mps2"
    check_table_kept(calibrated, knob, ["idm"], ["2", "4", "3"], force=False)  # more cells: the rows are kept
    check_table_kept(calibrated, knob, ["idm", "human"], ["2", "4"], force=False)
    r = _cli("calibrate", "--knob", "traffic.dangerous.brake_mps2=2,4", *common, "--force")
    assert r.returncode == 0, r.stderr
    assert (calibrated / "calibration.csv").read_bytes() == table  # the cells resumed: the first table again


def test_knob_values_split_outside_brackets_and_a_set_of_the_knob_is_refused():
    from dt_highway.config import ConfigError
    from dt_highway.evaluation.calibration import check_values, split_values

    assert split_values(" 2, 3,4 ") == ["2", "3", "4"]
    assert split_values("[1.0,2.0],[1.0,3.0]") == ["[1.0,2.0]", "[1.0,3.0]"]  # was four values, none a list
    assert split_values("'a,b',c") == ["'a,b'", "c"]
    assert split_values("2,,3,") == ["2", "3"]  # as the other comma-separated options
    for bad, words in (("[1,2", "unbalanced brackets"), ("2],3", "unbalanced brackets"), ("'a", "an unclosed quote")):
        with pytest.raises(ConfigError, match=words):
            split_values(bad)
    knob = "traffic.dangerous.brake_mps2"
    for override in (f"{knob}=5", "traffic.dangerous={brake_mps2=5}"):  # the knob replaced it in every cell
        with pytest.raises(ConfigError, match=r"sets the key --knob varies \(traffic.dangerous.brake_mps2\)"):
            check_values(knob, ["2", "3"], None, [override])
    check_values(knob, ["2", "3"], None, ["traffic.dangerous={share=1.0}", "traffic.dangerous.share=0.5"])
    for unread in ("overlay.max_marks", "fusion.method", "detector.kind"):  # every cell the same baseline trials
        with pytest.raises(ConfigError, match=rf"--knob {unread}: calibrate runs baseline trials, which have no "):
            check_values(unread, ["1", "2"], None, [])
    check_values("twin.intention.horizons_s", ["[1.0,2.0]", "[1.0,3.0]"], None, ["twin.intention.operating_horizon_s=1"])

"""The report on a hand-made study: comparisons for any number of conditions, paired by seed,
conflicts per hour, collision kinds and trials cut short by a collision."""

import json
import math

import pandas as pd
import pytest

from dt_highway.metrics.trial_log import TrialWriter
from dt_highway.report import compare, comparisons, condition_order, paired_tests, write_report

HZ = 2  # samples every 0.5 s
COLLISION = {"partner_id": 9, "partner_type": "aggressive", "collision_kind": "side_swipe", "lane_changer": "partner",
             "striker": None}


def write_trial(root, cond, pair, speed_mps, dip_at=None, n=20, crash=False):
    """A trial of n samples at 2 Hz (planned 10 s); 2-D TTC 1 s at sample ``dip_at``; a crash at the last."""
    meta = {"driver": "idm", "condition": cond, "pair": pair, "seed": 1 + pair, "participant": None,
            "simulation_frequency_hz": HZ, "config": {"highway": {"duration": 10.0}}}
    with TrialWriter(root / "trials" / f"{cond}-{pair:03d}", meta) as log:
        for k in range(n):
            hit = crash and k == n - 1
            log.step({"t_s": (k + 1) / HZ, "x_m": speed_mps * (k + 1) / HZ, "y_m": 4.0, "lane": 1, "speed_mps": speed_mps,
                      "accel_mps2": 0.0, "leader_id": -1, "gap_m": math.inf, "closing_mps": 0.0, "ttc_s": math.inf,
                      "drac_mps2": 0.0, "headway_s": math.inf, "crashed": hit, "ttc_contact": False,
                      "ttc2d_s": math.nan if hit else (1.0 if k == dip_at else math.inf), "ttc2d_id": 9 if hit else -1,
                      "ttc2d_contact": hit, "action_accel_mps2": 0.0, "action_lane": 0.0, "keys": "",
                      "overlay_ids": "", "overlay_labels": ""})
        if crash:
            log.event("collision", n / HZ, leader_id=-1, **COLLISION)
            log.meta["end_reason"] = "collision"


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    root = tmp_path_factory.mktemp("study")
    for pair in (0, 1):
        write_trial(root, "baseline", pair, 20.0, dip_at=5 if pair == 0 else None)
        write_trial(root, "adas", pair, 25.0 + pair)
        write_trial(root, "sham", pair, 22.0 + pair / 2)
        write_trial(root, "adas-threat", pair, 24.0 - pair, n=12 if pair == 1 else 20, crash=pair == 1)
    write_report(root)
    return root, json.loads((root / "summary.json").read_text())


def test_order_and_comparisons_of_any_conditions():
    assert condition_order(["sham", "adas-type", "baseline", "zzz", "adas"]) == ["baseline", "adas", "adas-type", "sham",
                                                                                 "zzz"]
    assert comparisons(["adas-type", "sham-type", "adas", "baseline"]) == [
        ("baseline", "adas"), ("baseline", "adas-type"), ("baseline", "sham-type"), ("sham-type", "adas-type")]
    assert comparisons(["adas", "adas-threat", "sham"]) == [("sham", "adas"), ("sham", "adas-threat")]  # no baseline


def test_every_condition_against_baseline_and_adas_against_sham(study):
    _, summary = study
    comps = summary["comparisons"]
    assert [(c["a"], c["b"]) for c in comps] == [("baseline", "adas"), ("baseline", "adas-threat"),
                                                 ("baseline", "sham"), ("sham", "adas"), ("sham", "adas-threat")]
    by = {(c["a"], c["b"]): c for c in comps}
    # km/h: adas 90 and 93.6 - baseline 72; adas-threat 86.4 and 82.8 - sham 79.2 and 81
    assert by[("baseline", "adas")]["tests"]["speed_mean_kmh"]["mean_diff"] == pytest.approx((18.0 + 21.6) / 2)
    assert by[("sham", "adas-threat")]["tests"]["speed_mean_kmh"]["mean_diff"] == pytest.approx((7.2 + 1.8) / 2)
    assert all(c["n_pairs"] == 2 for c in comps)
    assert summary["paired_tests"] == by[("baseline", "adas")]["tests"]  # kept: the adas - baseline tests


def test_cut_short_trials_are_flagged_and_counted_in_their_pairs(study):
    root, summary = study
    comps = {(c["a"], c["b"]): c for c in summary["comparisons"]}
    assert comps[("baseline", "adas-threat")]["cut_short_pairs"] == ["/seed 2"]
    assert comps[("baseline", "adas")]["cut_short_pairs"] == []
    assert summary["conditions"]["adas-threat"]["cut_short_trials"] == ["adas-threat-001"]
    (short,) = summary["cut_short_trials"]
    assert (short["trial"], short["duration_s"], short["planned_duration_s"]) == ("adas-threat-001", 6.0, 10.0)
    metrics = pd.read_csv(root / "metrics.csv").set_index("trial")
    assert bool(metrics.loc["adas-threat-001", "cut_short"]) and not bool(metrics.loc["adas-threat-000", "cut_short"])
    assert metrics.loc["adas-threat-001", "collision_partner_id"] == 9
    html = (root / "report.html").read_text()
    assert "cut short by a collision" in html and "adas-threat &minus; sham" in html and "16.6" in html


def test_conflicts_per_hour_and_collision_kinds_per_condition(study):
    _, summary = study
    conds = summary["conditions"]
    assert list(conds) == ["baseline", "adas", "adas-threat", "sham"]
    assert conds["baseline"]["conflicts_2d"] == 1
    assert conds["baseline"]["conflicts_2d_per_h_pooled"] == pytest.approx(180.0)  # 1 in 20 s
    assert conds["adas-threat"]["conflicts_2d_per_h_pooled"] == pytest.approx(1 / 16.0 * 3600)  # the contact, 10 + 6 s
    assert conds["adas"]["conflicts_2d_per_h_pooled"] == 0.0
    assert conds["adas-threat"]["collision_kinds"] == {"side_swipe: partner's lane change": 1}
    assert conds["baseline"]["collision_kinds"] == {} and conds["adas-threat"]["collisions"] == 1
    assert conds["baseline"]["conflicts_2d_per_h"]["mean"] == pytest.approx((360.0 + 0.0) / 2)  # per trial, then mean


def test_a_condition_no_trial_ran_in_is_one_line(tmp_path):
    metrics = pd.DataFrame({"condition": ["baseline", "adas"], "key": ["0", "0"], "status": ["completed"] * 2,
                            "speed_mean_kmh": [80.0, 81.0]})
    for call in (lambda: paired_tests(metrics, "baseline", "ADAS"), lambda: compare(metrics, "nope", "adas")):
        with pytest.raises(ValueError, match=r"^no trial of condition '(ADAS|nope)' in these metrics \(conditions: "
                                             r"adas, baseline\)$"):
            call()


def test_describe_takes_a_plain_list():
    from dt_highway.report import describe
    assert describe([1, 2, 3, float("nan")]) | {"ci95": None} == {"n": 3, "mean": 2.0, "sd": 1.0, "ci95": None,
                                                                    "ci95_clipped": False}

"""The study's conditions (baseline, adas and its modes, sham), their pairing by seed, and the
keyboard session's counterbalanced order of any number of them."""

from collections import Counter
from itertools import pairwise
from pathlib import Path

import pytest

from dt_highway.conditions import CONDITIONS, condition_config, display_name, is_sham
from dt_highway.config import ConfigError, load_config
from dt_highway.hmi.drive import DriveOptions, drive_config
from dt_highway.hmi.session import balanced_latin_square, condition_order, session_plan
from dt_highway.study import plan


def _resolved(condition, overrides=()):
    return load_config(None, list(overrides), condition_config(condition))


def test_each_condition_sets_camera_fusion_and_the_overlay():
    want = {  # condition: (fusion on, overlay.mode, overlay.sham) with the defaults
        "baseline": (False, "type", False), "adas": (True, "type", False), "adas-type": (True, "type", False),
        "adas-threat": (True, "threat", False), "sham": (True, "type", True), "sham-type": (True, "type", True),
        "sham-threat": (True, "threat", True),
    }
    assert set(want) == set(CONDITIONS)
    for cond, (on, mode, sham) in want.items():
        cfg = _resolved(cond)
        assert (cfg.fusion.enabled, cfg.camera.enabled, cfg.overlay.mode, cfg.overlay.sham) == (on, on, mode, sham), cond
        assert cfg.highway.action["type"] == "Driver"
    # adas and sham follow the configured mode; the named modes do not need it
    assert _resolved("adas", ["overlay.mode=threat"]).overlay.mode == "threat"
    assert _resolved("sham", ["overlay.mode=both"]).overlay.mode == "both"
    assert condition_config("adas") == {"highway": {"action": {"type": "Driver"}}, "camera": {"enabled": True},
                                        "fusion": {"enabled": True}}  # as before: no overlay keys
    assert [display_name(c) for c in CONDITIONS] == ["baseline"] + ["adas"] * 6  # the placebo is blind
    assert is_sham("sham-threat") and not is_sham("adas-threat")
    with pytest.raises(ConfigError, match=r"^unknown condition 'placebo' \(allowed: baseline, adas, .*sham"):
        condition_config("placebo")


def test_a_study_pairs_every_condition_by_seed():
    specs = plan("o", "agents/human.toml", ["baseline", "adas-threat", "sham"], 3, 10)
    assert [(s.condition, s.index, s.seed) for s in specs[:3]] == [("baseline", 0, 10), ("adas-threat", 0, 10),
                                                                   ("sham", 0, 10)]
    assert {s.seed for s in specs if s.index == 2} == {12} and len(specs) == 9
    assert Path(specs[2].directory).name == "sham-000"
    with pytest.raises(ConfigError, match="each condition once"):
        plan("o", "agents/human.toml", ["baseline", "sham", "sham"], 1, 0)
    with pytest.raises(ConfigError, match="unknown condition 'shame'"):
        plan("o", "agents/human.toml", ["baseline", "shame"], 1, 0)


@pytest.mark.parametrize("k", [2, 3, 4, 5])
def test_the_balanced_latin_square_balances_positions_and_carry_over(k):
    rows = balanced_latin_square(k)
    assert len(rows) == (k if k % 2 == 0 else 2 * k)
    assert all(sorted(r) == list(range(k)) for r in rows)
    reps = len(rows) // k
    for pos in range(k):  # every treatment in every position equally often
        assert Counter(r[pos] for r in rows) == dict.fromkeys(range(k), reps)
    follows = Counter(p for r in rows for p in pairwise(r))  # every ordered pair equally often
    assert set(follows) == {(a, b) for a in range(k) for b in range(k) if a != b}
    assert set(follows.values()) == {reps}


def test_a_session_orders_its_conditions_by_participant_and_can_include_the_sham():
    assert condition_order("P01") == ("baseline", "adas") and condition_order("P02") == ("adas", "baseline")  # as before
    three = ["baseline", "adas-threat", "sham"]
    orders = [condition_order(f"P{n:02d}", three) for n in range(1, 7)]
    assert len(set(orders)) == 6  # six participants: all six orders of three conditions
    assert orders[0] == ("baseline", "adas-threat", "sham") and orders[6 % 6] == condition_order("P07", three)
    trials = session_plan(DriveOptions("P02", "baseline", Path("o"), seed=5), 30.0, three)
    assert [(t.condition, t.practice, t.opts.seed) for t in trials] == [  # a practice trial per condition, in order
        *((c, True, 1005 + i) for i, c in enumerate(orders[1])), *((c, False, 5) for c in orders[1])]
    with pytest.raises(ConfigError, match="at least two"):
        condition_order("P01", ["sham"])
    with pytest.raises(ConfigError, match="twice"):
        condition_order("P01", ["sham", "sham"])
    # the keyboard trial of a sham: the fusion runs, the overlay is the placebo
    cfg = load_config(None, [], drive_config("sham"))
    assert cfg.overlay.sham and cfg.fusion.enabled and cfg.highway.observation["type"] == "Camera"
    assert not load_config(None, [], drive_config("baseline")).fusion.enabled


def test_the_cli_runs_a_three_condition_study_paired_by_seed(tmp_path, capsys):
    from dt_highway.cli import main
    from dt_highway.metrics.trial_log import load_trial

    out = tmp_path / "s"
    # the world of the earlier studies: seed 4 has an aggressive car in view in the first 3 s
    args = ["study", "--driver", "agents/human.toml", "--scenario", "envs/highway-trial-v1.toml", "--conditions",
            "baseline,adas-threat,sham", "--trials", "1", "--seed", "4", "--workers", "1", "--out", str(out), "--quiet",
            "--set", "highway.duration=3", "--set", "twin.preroll_s=20"]
    assert main(args) == 0
    trials = {c: load_trial(out / "trials" / f"{c}-000") for c in ("baseline", "adas-threat", "sham")}
    assert {t.meta["seed"] for t in trials.values()} == {4}
    assert trials["sham"].meta["config"]["overlay"]["sham"] is True
    assert trials["adas-threat"].meta["config"]["overlay"]["mode"] == "threat"
    assert trials["sham"].steps["overlay_ids"].fillna("").astype(str).str.len().sum() > 0  # the placebo shows marks
    capsys.readouterr()
    assert main([*args[:6], "baseline,placebo", *args[7:]]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unknown condition 'placebo'" in err[0]


def test_a_keyboard_session_can_include_the_sham(tmp_path, capsys):
    from dt_highway.cli import main
    from dt_highway.metrics.trial_log import load_trial

    keys = tmp_path / "keys.txt"
    keys.write_text("0.1 down UP\n0.5 up UP\n")
    out = tmp_path / "k"
    assert main(["session", "--participant", "P02", "--conditions", "baseline,sham", "--duration", "1",
                 "--practice-duration", "0.5", "--out", str(out), "--keys-from", str(keys), "--no-minimap",
                 "--set", "highway.vehicles_count=12", "--set", "twin.preroll_s=5",
                 "--set", "camera.width_px=320", "--set", "camera.height_px=180"]) == 0
    said = capsys.readouterr().out
    assert "practice sham, baseline, then sham, baseline" in said and "4 of 4 trials done" in said  # P02: the second row
    sham = load_trial(out / "trials" / "P02-sham")
    assert sham.meta["condition"] == "sham" and sham.meta["config"]["overlay"]["sham"] is True
    assert load_trial(out / "trials" / "P02-practice-sham").meta["condition"] == "sham"


def test_a_set_mode_beside_a_condition_that_names_its_mode_is_refused(tmp_path, capsys):
    """``--set overlay.mode=threat`` beside ``adas-type`` ran adas-type in threat mode, labelled adas-type."""
    from dt_highway.cli import main

    mode = ["overlay.mode=threat"]
    with pytest.raises(ConfigError, match=r"^--set overlay.mode would override the mode adas-type names: drop it"):
        plan(tmp_path, "agents/idm.toml", ["adas-type", "adas-threat"], 1, 0, overrides=mode)
    with pytest.raises(ConfigError, match=r"^--set overlay.mode would override"):  # set inside its table too
        plan(tmp_path, "agents/idm.toml", ["adas-type"], 1, 0, overrides=['overlay={mode="threat", max_marks=2}'])
    assert len(plan(tmp_path, "agents/idm.toml", ["baseline", "adas", "sham"], 1, 0, overrides=mode)) == 3  # they take it
    assert len(plan(tmp_path, "agents/idm.toml", ["adas-type"], 1, 0, overrides=["overlay.max_marks=2"])) == 1
    for command in (["study", "--driver", "agents/idm.toml", "--conditions", "baseline,sham-threat"],
                    ["session", "--participant", "P01", "--conditions", "baseline,sham-threat"]):
        assert main([*command, "--set", " overlay.mode = type", "--out", str(tmp_path / "o")]) == 2
        said = capsys.readouterr()
        err = said.err
        assert err.count("\n") == 1 and "--set overlay.mode would override the mode sham-threat names" in err, err
        assert said.out == ""  # the session announced its plan before refusing it
        assert not (tmp_path / "o").exists()


def test_a_session_goes_on_only_in_the_conditions_and_order_it_started_with(tmp_path, capsys):
    """Resumed with other ``--conditions`` (or the same typed in another order), a session added trials out of the
    participant's counterbalanced order."""
    from dt_highway.cli import main

    keys = tmp_path / "keys.txt"
    keys.write_text("0.1 down UP\n0.3 up UP\n")
    out = tmp_path / "k"
    args = ["session", "--participant", "P01", "--duration", "0.6", "--practice-duration", "0.3", "--out", str(out),
            "--keys-from", str(keys), "--no-minimap", "--set", "highway.vehicles_count=12", "--set", "twin.preroll_s=5",
            "--set", "camera.width_px=320", "--set", "camera.height_px=180"]
    assert main([*args, "--conditions", "baseline,sham"]) == 0
    trials = sorted(p.name for p in (out / "trials").iterdir())
    capsys.readouterr()
    for other, gives in (("baseline,adas", "baseline, adas"), ("sham,baseline", "sham, baseline")):
        assert main([*args, "--conditions", other]) == 2
        printed = capsys.readouterr()
        err = printed.err
        said = f"P01's session started with the conditions baseline, sham (in that order); --conditions gives {gives}"
        assert err.count("\n") == 1 and said in err, err
        assert "session of P01" not in printed.out  # the plan is said once every check has passed
        assert sorted(p.name for p in (out / "trials").iterdir()) == trials  # nothing driven
    assert main([*args, "--conditions", "baseline,sham"]) == 0  # the same: goes on (all done, skipped)
    assert "4 of 4 trials done" in capsys.readouterr().out

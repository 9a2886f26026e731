"""dt-highway rl-compare (issue 22's table): rows, the zero-marks ablation, pairing by seed, outputs."""

import csv
import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from gymnasium import spaces

from dt_highway.cli import main
from dt_highway.config import ConfigError
from dt_highway.drivers.perception import OwnState, Perception
from dt_highway.drivers.policy import OVERLAY_FEATURES, THREAT_FEATURES, PolicyDriver, load_policy
from dt_highway.env import OverlayKinematics
from dt_highway.evaluation.rl import Row, comparisons, paired_by_seed, parse_rows, row_driver
from dt_highway.rl.config import load_train_config

ROOT = Path(__file__).resolve().parents[1]
SHORT = ["--set", "highway.duration=5", "--set", "twin.preroll_s=5"]


class _Recorder:
    """A stand-in model: keeps the observation it is given, then stops the decision."""

    def __init__(self, shape: tuple[int, int], n_actions: int) -> None:
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=shape, dtype=np.float32)
        self.action_space = spaces.Discrete(n_actions)
        self.seen: np.ndarray | None = None

    def predict(self, observation, deterministic=True):
        self.seen = np.array(observation, copy=True)
        raise StopIteration


def _threat_policy() -> PolicyDriver:
    config = load_train_config(ROOT / "agents/ppo-safe-adas.toml")  # observation = "adas-threat"
    meta = {"env_config": {"highway": {"observation": config.observation_config(), "action": config.action_config()}}}
    return PolicyDriver("threat", _Recorder((7, 8), len(config.speeds_mps) + 2), config, meta)


def _decide(driver: PolicyDriver, observation: np.ndarray) -> np.ndarray:
    own = OwnState(speed_mps=25.0, heading_rad=0.0, lane=1, n_lanes=3, crashed=False)
    with pytest.raises(StopIteration):
        driver.act(Perception(time_s=0.0, own=own, observation=observation))
    assert driver.model.seen is not None
    return driver.model.seen


def test_the_overlay_columns_are_the_envs():
    assert list(OVERLAY_FEATURES) == OverlayKinematics.EXTRA_FEATURES
    assert list(THREAT_FEATURES) == OverlayKinematics.THREAT_FEATURES


def test_zero_marks_zeroes_exactly_the_overlay_columns_of_a_threat_policy():
    driver = _threat_policy()
    assert driver.features == ("presence", "x", "y", "vx", "vy", "marked", "cut_in_warned", "side")
    assert driver.overlay_features == ("marked", "cut_in_warned", "side")
    obs = np.arange(1, 57, dtype=np.float32).reshape(7, 8)  # every cell nonzero and distinct
    assert np.array_equal(_decide(driver, obs), obs)  # no ablation: the observation as it is
    driver.zero_columns(driver.overlay_features)
    seen = _decide(driver, obs)
    assert np.all(seen[:, 5:] == 0)
    assert np.array_equal(seen[:, :5], obs[:, :5])
    assert obs[0, 5] == 6.0  # the seat's observation itself is left alone


def test_the_zero_marks_row_zeroes_only_marked_on_the_shipped_adas_policy():
    driver = row_driver(Row(str(ROOT / "agents/ppo-adas.zip"), "adas", "zero-marks"))
    assert isinstance(driver, PolicyDriver) and driver.zeroed == (5,)
    recorder = _Recorder((7, 6), driver.model.action_space.n)
    driver.model = recorder
    obs = np.ones((7, 6), dtype=np.float32)
    seen = _decide(driver, obs)
    assert seen[:, 5].tolist() == [0.0] * 7 and np.all(seen[:, :5] == 1.0)


def test_zero_columns_refuses_a_column_the_policy_does_not_have():
    driver = load_policy(ROOT / "agents/ppo-baseline.zip")
    assert driver.overlay_features == ()
    with pytest.raises(ConfigError, match="no observation column marked"):
        driver.zero_columns(["marked"])


def test_rows_parse_and_bad_rows_fail_in_one_line():
    rows = parse_rows("ppo-adas.zip@adas-threat, ppo-adas.zip@adas-threat:zero-marks,agents/idm.toml@baseline",
                      ROOT / "agents")
    assert [r.label for r in rows] == ["ppo-adas.zip@adas-threat", "ppo-adas.zip@adas-threat:zero-marks",
                                       "idm.toml@baseline"]
    assert rows[0].driver == str(ROOT / "agents/ppo-adas.zip") and rows[1].ablation == "zero-marks"
    bad = {"idm.toml": "expected DRIVER@CONDITION", "idm.toml@adas-thret": "allowed: baseline, adas, adas-type",
           "ppo-adas.zip@adas:zero": "allowed: zero-marks", "idm.toml@baseline,idm.toml@baseline": "named twice",
           "ppo-adas.zip@baseline:zero-marks": "needs a condition with marks", ",": "no row"}
    for text, message in bad.items():
        with pytest.raises(ConfigError, match=message) as err:
            parse_rows(text, ROOT / "agents")
        assert "\n" not in str(err.value)


def test_rows_take_a_folder_with_an_at_and_tell_two_files_of_one_name_apart(tmp_path):
    odd = tmp_path / "runs@night"
    odd.mkdir()
    (odd / "idm.toml").write_text((ROOT / "agents" / "idm.toml").read_text())
    rows = parse_rows(f"{odd}/idm.toml@adas:zero-marks,idm.toml@adas", ROOT / "agents")  # was "unknown condition"
    assert rows[0].driver == str(odd / "idm.toml") and rows[0].condition == "adas" and rows[0].ablation == "zero-marks"
    with pytest.raises(ConfigError, match=r"are both called 'idm.toml': .* rename one$"):  # was "named twice"
        parse_rows(f"idm.toml@adas,{odd}/idm.toml@adas", ROOT / "agents")


def test_a_bad_row_is_one_line_on_the_command_line(capsys):
    assert main(["rl-compare", "--rows", "idm.toml@adas-thret", "--episodes", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "unknown condition 'adas-thret'" in err and "sham-threat" in err
    assert main(["rl-compare", "--rows", f"{ROOT}/agents/idm.toml@adas:zero-marks", "--episodes", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "needs a policy that sees the overlay's marks" in err


def test_comparisons_pair_the_aware_row_with_its_sham_its_zeroed_marks_and_the_baseline_policy():
    rows = parse_rows("a.zip@adas-threat,a.zip@sham-threat,a.zip@adas-threat:zero-marks,a.zip@sham,b.zip@baseline,"
                      "idm.toml@baseline")
    aware = {r.label: r.driver == "a.zip" for r in rows}
    policy = {r.label: r.driver.endswith(".zip") for r in rows}
    got = {(c["kind"], c["a"]) for c in comparisons(rows, aware, policy)}
    assert got == {("vs sham marks", "a.zip@sham-threat"), ("vs zeroed marks", "a.zip@adas-threat:zero-marks"),
                   ("vs baseline policy", "b.zip@baseline")}  # a.zip@sham is another mode's sham: not paired
    assert all(c["b"] == "a.zip@adas-threat" for c in comparisons(rows, aware, policy))


def test_pairing_is_by_seed_not_by_position():
    seeds = [1, 2, 3, 4, 5]
    a = pd.DataFrame({"row": "A", "seed": seeds, "conflicts_2d_per_h": [0.0, 1.0, 2.0, 3.0, 4.0],
                      "collision": [True, True, False, False, False]})
    # B's episodes come in another order, plus a seed A does not have; per seed B - A = 1, 2, 3, 4, 5
    b = pd.DataFrame({"row": "B", "seed": [6, 5, 4, 3, 2, 1], "conflicts_2d_per_h": [100.0, 9.0, 7.0, 5.0, 3.0, 1.0],
                      "collision": [True, False, False, True, True, False]})
    frame = pd.concat([a, b], ignore_index=True)
    for m in ("return", "cut_in_ttc_median_s", "speed_mean_kmh"):
        frame[m] = 1.0  # no difference: no test
    res = paired_by_seed(frame, "A", "B")
    t = res["tests"]["conflicts_2d_per_h"]
    assert t["n_pairs"] == 5 and t["mean_diff"] == pytest.approx(3.0)
    assert t["wilcoxon_p"] == pytest.approx(2 / 32)  # exact: all 5 differences positive, 2 of 2^5 sign patterns
    # paired t: mean 3, SD sqrt(2.5), t = 3 / (sqrt(2.5) / sqrt(5)) = 4.243 on 4 df
    assert t["ttest_p"] == pytest.approx(0.013236, abs=1e-5)
    assert t["effect_size_dz"] == pytest.approx(3 / math.sqrt(2.5))
    assert res["tests"]["return"]["mean_diff"] == 0.0 and res["tests"]["return"]["wilcoxon_p"] is None
    # collisions over the paired seeds 1..5: A on 1, 2; B on 2, 3
    assert res["collisions"] == {"a": 2, "b": 2, "only_a": 1, "only_b": 1, "both": 1}


def test_a_tiny_run_prints_the_table_and_writes_the_files(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(ROOT)
    out = tmp_path / "cmp"
    code = main(["rl-compare", "--rows", "ppo-adas.zip@adas,ppo-adas.zip@adas:zero-marks", "--episodes", "2",
                 *SHORT, "--out", str(out), "--quiet"])
    assert code == 0
    printed = capsys.readouterr().out
    assert "| Row | Collisions (kinds) | Conflicts / h (2-D TTC < 1.5 s) | Cut-in min TTC [s]" in printed
    assert "| Mean speed [km/h] | Return |" in printed
    assert "| ppo-adas.zip@adas | " in printed and "| ppo-adas.zip@adas:zero-marks | " in printed
    assert "ppo-adas.zip@adas − ppo-adas.zip@adas:zero-marks (vs zeroed marks) | 2 |" in printed
    result = json.loads((out / "compare.json").read_text())
    assert result["seeds"] == [10000, 10001] and list(result["rows"]) == ["ppo-adas.zip@adas",
                                                                           "ppo-adas.zip@adas:zero-marks"]
    assert result["rows"]["ppo-adas.zip@adas"]["adas_aware"] and result["rows"]["ppo-adas.zip@adas"]["episodes"] == 2
    with (out / "episodes.csv").open() as f:
        episodes = list(csv.DictReader(f))
    assert [(e["row"], e["seed"]) for e in episodes] == [
        ("ppo-adas.zip@adas", "10000"), ("ppo-adas.zip@adas", "10001"),
        ("ppo-adas.zip@adas:zero-marks", "10000"), ("ppo-adas.zip@adas:zero-marks", "10001")]
    assert (out / "compare.md").read_text() in printed
    # a second comparison into the same folder is refused before any episode, the first kept; --force replaces it
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    again = ["rl-compare", "--rows", "idm.toml@baseline", "--episodes", "1", *SHORT, "--out", str(out), "--quiet"]
    assert main(again) == 2
    err = capsys.readouterr().err
    said = f"{out} holds an earlier comparison (compare.json, compare.md, episodes.csv): pass --force to replace it"
    assert err.count("\n") == 1 and said in err, err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert main([*again, "--force"]) == 0
    assert list(json.loads((out / "compare.json").read_text())["rows"]) == ["idm.toml@baseline"]

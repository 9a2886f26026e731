"""The configuration tree: layers, deep merge, and one-line errors for every mistake."""

import subprocess
import sys

import gymnasium as gym
import pytest

import dt_highway  # noqa: F401  (registers the env)
from dt_highway.config import ConfigError, DTConfig, load_config, merge, parse_override, validate


def test_defaults_are_valid():
    cfg = DTConfig()
    assert cfg.twin.uplink.noise_sigma_m == 1.0
    assert cfg.twin.uplink.rate_hz == 10.0
    assert cfg.twin.uplink.latency_mean_s == 0.1
    assert cfg.twin.connected_fraction == 1.0


def test_deep_merge_keeps_siblings():
    cfg = merge(DTConfig(), {"twin": {"uplink": {"rate_hz": 5}}})
    assert cfg.twin.uplink.rate_hz == 5
    assert cfg.twin.uplink.noise_sigma_m == 1.0  # sibling kept
    assert cfg.twin.downlink.rate_hz == 10.0


def test_highway_env_keys_at_top_level_are_accepted():
    cfg = validate({"lanes_count": 3, "twin": {"preroll_s": 0}})
    assert cfg.highway.lanes_count == 3


def test_layers_scenario_then_set(tmp_path):
    f = tmp_path / "s.toml"
    f.write_text("[twin.uplink]\nrate_hz = 2.0\nnoise_sigma_m = 2.0\n")
    cfg = load_config(f, ["twin.uplink.rate_hz=4"])
    assert cfg.twin.uplink.rate_hz == 4  # --set wins over the file
    assert cfg.twin.uplink.noise_sigma_m == 2.0  # the file wins over the default


@pytest.mark.parametrize(
    "text, expected",
    [("a.b=3", {"a": {"b": 3}}), ("a=0.5", {"a": 0.5}), ("a=true", {"a": True}),
     ("a=[1, 2]", {"a": [1, 2]}), ("a.b=hello", {"a": {"b": "hello"}})],
)
def test_parse_override(text, expected):
    assert parse_override(text) == expected


@pytest.mark.parametrize(
    "tree, must_contain",
    [
        ({"twin": {"uplnk": {}}}, ["unknown key 'twin.uplnk'", "uplink"]),
        ({"twin": {"uplink": {"noise_sigma_m": -1}}}, ["twin.uplink.noise_sigma_m", ">= 0"]),
        ({"twin": {"uplink": {"rate_hz": 0}}}, ["twin.uplink.rate_hz", "> 0"]),
        ({"twin": {"uplink": {"loss_prob": 1.5}}}, ["twin.uplink.loss_prob", "< 1"]),
        ({"traffic": {"aggressive_fraction": 2}}, ["traffic.aggressive_fraction", "<= 1"]),
        ({"highway": {"lanes_count": "four"}}, ["highway.lanes_count", "integer"]),
        ({"twin": 3}, ["twin must be a table"]),
        ({"highway": {"simulation_frequency": 15, "policy_frequency": 2}}, ["multiple of policy_frequency"]),
        ({"highway": {"duration": float("inf")}}, ["highway.duration", "finite"]),
        ({"highway": {"lanes_count": 3, "initial_lane_id": 3}}, ["initial_lane_id must be < lanes_count"]),
        ({"traffic": {"spawn_ahead_m": 500}}, ["spawn_ahead_m", "recycle_distance_m"]),
        ({"traffic": {"normal": {"target_speed_mps": [30, 20]}}}, ["target_speed_mps"]),
    ],
)
def test_bad_values_give_one_line_naming_the_key(tree, must_contain):
    with pytest.raises(ConfigError) as info:
        validate(tree)
    msg = str(info.value)
    assert "\n" not in msg
    for part in must_contain:
        assert part in msg


def test_unreadable_toml(tmp_path):
    f = tmp_path / "bad.toml"
    f.write_text("[twin\nrate = ")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(f)


def test_missing_scenario_file(tmp_path):
    with pytest.raises(ConfigError, match="does not exist"):
        load_config(tmp_path / "nope.toml")


def test_bad_set_syntax():
    with pytest.raises(ConfigError, match="dotted.key=value"):
        load_config(overrides=["twin.uplink.rate_hz"])


def test_gym_make_rejects_bad_config_clearly():
    with pytest.raises(ConfigError, match="twin.uplink.noise_sigma_m"):
        gym.make("dt-highway-v0", config={"twin": {"uplink": {"noise_sigma_m": -1}}})


def test_shipped_scenarios_are_valid():
    from pathlib import Path

    root = Path(__file__).resolve().parents[1] / "envs"
    files = sorted(root.glob("*.toml"))
    assert files, "no scenario files shipped"
    for f in files:
        load_config(f)


def test_cli_bad_input_is_one_line_without_traceback():
    proc = subprocess.run(
        [sys.executable, "-m", "dt_highway.cli", "twin-eval", "--set", "twin.uplink.rate_hz=0", "--quiet"],
        capture_output=True, text=True,
    )
    assert proc.returncode == 2
    lines = [ln for ln in proc.stderr.strip().splitlines() if ln]
    assert len(lines) == 1, proc.stderr
    assert "twin.uplink.rate_hz" in lines[0]
    assert "Traceback" not in proc.stderr


def test_default_scenario_file_is_the_defaults():
    from pathlib import Path

    from dt_highway.config import DTConfig, load_config

    path = Path(__file__).resolve().parent.parent / "envs" / "default.toml"
    assert load_config(path) == DTConfig()


def test_a_partial_downlink_table_keeps_the_downlink_defaults():
    from dt_highway.config import load_config

    down = load_config(overrides=["twin.downlink.rate_hz=5"]).twin.downlink
    assert (down.rate_hz, down.latency_mean_s, down.latency_jitter_s, down.loss_prob) == (5.0, 0.05, 0.01, 0.0)

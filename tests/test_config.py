"""The configuration tree: layers, deep merge, and one-line errors for every mistake."""

import math
import re
import subprocess
import sys

import gymnasium as gym
import pytest

import dt_highway  # noqa: F401  (registers the env)
from dt_highway.config import CHECKOUT, ConfigError, DTConfig, load_config, merge, parse_override, validate


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
        ({"highway": {"lanes_count": "four"}}, ["highway.lanes_count", "must be a whole number, not text"]),
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


def test_the_documented_relative_paths_work_from_any_folder(tmp_path, monkeypatch):
    from dt_highway.agent_config import load_train_config
    from dt_highway.drivers import load_driver

    monkeypatch.chdir(tmp_path)  # not the checkout: envs/ and agents/ are not here
    assert load_config("envs/highway-trial.toml") == load_config(CHECKOUT / "envs" / "highway-trial.toml")
    assert load_driver("agents/human.toml").name == "human" and load_driver("idm.toml").name == "idm"
    train = load_train_config("agents/ppo-baseline.toml")
    load_config(train.scenario)  # the scenario it names (envs/highway-trial-v1.toml) is found too
    with pytest.raises(ConfigError, match=r"scenario file 'envs/nope.toml' does not exist"):
        load_config("envs/nope.toml")  # a name the checkout has not either: the message names what was typed
    for typo in ("emvs/highway-trial.toml", "../envs/highway-trial.toml"):  # another folder: no silent stand-in
        with pytest.raises(ConfigError, match=f"scenario file '{re.escape(typo)}' does not exist"):
            load_config(typo)
    with pytest.raises(ConfigError, match="driver file not found: agnets/idm.toml"):
        load_driver("agnets/idm.toml")
    # a file of that name here is the one read
    (tmp_path / "envs").mkdir()
    (tmp_path / "envs" / "highway-trial.toml").write_text("[highway]\nlanes_count = 2\n")
    assert load_config("envs/highway-trial.toml").highway.lanes_count == 2


def test_nonsense_that_highway_env_or_the_idm_would_take_silently_is_refused(tmp_path):
    for low_high in ("[30, 20]", "[20, 20]"):  # the speed reward divides by high - low
        with pytest.raises(ConfigError, match=r"reward_speed_range must be \[low, high\] m/s with low < high"):
            load_config(overrides=[f"highway.reward_speed_range={low_high}"])
    from dt_highway.drivers import load_driver

    idm = (CHECKOUT / "agents" / "idm.toml").read_text()
    for key in ("delta", "time_headway_s", "max_accel_mps2", "comfort_decel_mps2"):  # 0: no acceleration, or / 0
        f = tmp_path / f"{key}.toml"
        f.write_text(re.sub(rf"^{key} = [0-9.]+", f"{key} = 0", idm, flags=re.M))
        with pytest.raises(ConfigError, match=rf"idm.{key} = 0.0 is out of range: must be > 0"):
            load_driver(f)


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


# ----------------------------------------------------------------------------- observation and action types
@pytest.mark.parametrize("section, ours", [("observation", ["Camera", "OverlayKinematics"]),
                                           ("action", ["Driver", "DiscreteDriver"])])
def test_an_unknown_observation_or_action_type_is_refused_when_configured(section, ours):
    with pytest.raises(ConfigError) as info:
        load_config(overrides=[f"highway.{section}.type=Nope"])
    msg = str(info.value)
    assert "\n" not in msg and f"highway.{section}.type = 'Nope'" in msg
    assert all(name in msg for name in ours)
    assert ("Kinematics" if section == "observation" else "DiscreteMetaAction") in msg  # highway-env's own
    with pytest.raises(ConfigError, match=f"highway.{section}.type"):
        gym.make("dt-highway-v0", config={section: {"type": "Nope"}})  # before highway-env's factory runs


def test_the_known_types_are_highway_envs_factories_names_and_ours():
    import inspect
    import re

    from highway_env.envs.common.action import action_factory
    from highway_env.envs.common.observation import observation_factory

    from dt_highway.config import (
        ACTION_TYPES,
        HIGHWAY_ENV_ACTION_TYPES,
        HIGHWAY_ENV_OBSERVATION_TYPES,
        OBSERVATION_TYPES,
    )

    def names(factory):
        return set(re.findall(r'config\["type"\] == "(\w+)"', inspect.getsource(factory)))

    assert names(observation_factory) == set(HIGHWAY_ENV_OBSERVATION_TYPES)  # highway-env 1.12's, exactly
    assert names(action_factory) == set(HIGHWAY_ENV_ACTION_TYPES)
    assert set(OBSERVATION_TYPES) - set(HIGHWAY_ENV_OBSERVATION_TYPES) == {"Camera", "OverlayKinematics"}
    assert set(ACTION_TYPES) - set(HIGHWAY_ENV_ACTION_TYPES) == {"Driver", "DiscreteDriver"}
    validate({"highway": {"observation": {"type": "OccupancyGrid"}, "action": {"type": "ContinuousAction"}}})


# ----------------------------------------------------------------------------- settings derived from sections
def test_component_settings_take_defaults_and_ranges_from_their_config_section():
    from dt_highway.camera.render import RenderSettings
    from dt_highway.config import CameraConfig, DetectorConfig, FusionConfig, OverlayConfig
    from dt_highway.overlay import OverlayStabilizer
    from dt_highway.perception import FusionSettings, SimulatedDetectorSettings

    for settings, section in ((SimulatedDetectorSettings(), DetectorConfig()), (FusionSettings(), FusionConfig()),
                              (RenderSettings(), CameraConfig())):
        shared = set(type(settings).model_fields) & set(type(section).model_fields)
        assert shared and all(getattr(settings, k) == getattr(section, k) for k in shared)
    overlay = OverlayStabilizer()
    assert (overlay.onset_frames, overlay.hold_s) == (OverlayConfig().onset_frames, OverlayConfig().hold_s)
    # the ranges are the sections' too
    for make, key in ((lambda: SimulatedDetectorSettings(jitter=0.9), "jitter"),
                      (lambda: FusionSettings(th=1.0), "th"),
                      (lambda: RenderSettings(vehicle_height_m=0.1), "vehicle_height_m")):
        with pytest.raises(ValueError, match=key):
            make()
    with pytest.raises(ConfigError, match=r"^invalid configuration: overlay\.hold_s = -1 is out of range"):
        OverlayStabilizer(hold_s=-1)
    with pytest.raises(ValueError, match="method must be one of baseline, fusion, joint, tracked"):
        FusionSettings(method="magic")
    with pytest.raises(ValueError, match="frozen"):
        FusionSettings().th = 0.5  # type: ignore[misc]


# ----------------------------------------------------------------------------- training files
@pytest.mark.parametrize("tree, must_contain", [
    ({"kind": "rl", "bogus": 1}, ["training config: unknown key 'bogus' (allowed here: kind, algorithm"]),
    ({"kind": "rl", "n_envs": 0}, ["training config: n_envs = 0 is out of range: must be >= 1"]),
    ({"kind": "rl", "algorithm": "A2C"}, ["training config: algorithm = 'A2C'", "'PPO' or 'DQN'"]),
    ({"kind": "rl", "accels_mps2": [-20.0]},
     ["training config: accels_mps2 must be a non-empty list within [-8.0, 3.0]"]),
    ({"kind": "rl", "timesteps": 0, "seed": -1}, ["timesteps = 0", "; seed = -1"]),  # every mistake, one line
])
def test_training_files_are_refused_through_the_config_error_path(tree, must_contain):
    from dt_highway.rl.config import parse_train_config

    with pytest.raises(ConfigError) as info:
        parse_train_config(tree)
    assert "\n" not in str(info.value)
    for part in must_contain:
        assert part in str(info.value)


def test_settings_take_positional_values_as_the_dataclasses_did():
    from dt_highway.camera.render import RenderSettings

    s = RenderSettings(200.0, 1.5)
    assert (s.max_range_m, s.vehicle_height_m) == (200.0, 1.5)
    with pytest.raises(TypeError, match="at most"):
        RenderSettings(1.0, 2.0, 0.5, 4.0, 5.0)
    with pytest.raises(TypeError, match="both by position and by keyword"):
        RenderSettings(200.0, max_range_m=100.0)


@pytest.mark.parametrize("observation, must_contain", [
    ({"type": "Kinematics", "vehicles_count": -1}, "highway.observation.vehicles_count = -1: must be a whole number from 1"),
    ({"type": "Kinematics", "vehicles_count": 10**7}, "vehicles_count = 10000000: must be a whole number from 1 to 1000"),
    ({"type": "OverlayKinematics", "vehicles_count": 2.5}, "highway.observation.vehicles_count = 2.5"),
    ({"type": "Kinematics", "bogus": 1}, "highway.observation.bogus = 1: not a Kinematics option (allowed: type, features"),
    ({"vehicles_count": 3, "order": "random"}, "highway.observation.order = 'random': must be 'sorted' or 'shuffled'"),
    ({"type": "Kinematics", "features": []}, "highway.observation.features = []: must be a non-empty list of feature names"),
    ({"type": "Kinematics", "features": "xy"}, "highway.observation.features = 'xy': must be a non-empty list"),
    ({"type": "Kinematics", "normalize": "yes"}, "highway.observation.normalize = 'yes': must be true or false"),
    ({"type": "Kinematics", "features_range": {"x": [5, 5]}}, "features_range = {'x': [5, 5]}: must be {feature: [low, high]"),
    ({"type": "Kinematics", "features_range": "x"}, "highway.observation.features_range = 'x': must be"),
])
def test_kinematics_options_are_checked_when_configured(observation, must_contain):
    with pytest.raises(ConfigError) as info:
        validate({"highway": {"observation": observation}})
    assert "\n" not in str(info.value) and must_contain in str(info.value), str(info.value)
    fine = {"type": "Kinematics", "vehicles_count": 7, "see_behind": True, "order": "shuffled", "features": ["presence", "x"],
            "features_range": {"x": [-100, 100]}, "normalize": False}
    validate({"highway": {"observation": fine}})
    validate({"highway": {"observation": {**fine, "vehicles_count": 1000}}})  # the most rows taken


def test_a_number_read_back_from_json_or_toml_is_checked_once_for_every_reader():
    from dt_highway.jsonio import finite_number, positive_number

    assert finite_number(3) == 3.0 and finite_number(-2.5) == -2.5
    for odd in (True, False, "3", None, [1], math.nan, math.inf, -math.inf):
        assert finite_number(odd) is None, odd
    assert positive_number(15) == 15.0 and positive_number(0) is None and positive_number(-1) is None


def test_values_that_were_silently_ignored_or_meaningless_are_refused():
    """Each was accepted and did something else than it says: the overlay read the twin's nearest horizon for
    any horizon_s, a threshold of 0 marked every car, the intention columns stayed 0 or were not added."""
    cases = {
        ("overlay.horizon_s=2.5",): "overlay.horizon_s must be one of twin.intention.horizons_s [1.0, 2.0, 3.0] (got 2.5)",
        ("overlay.threshold=0",): "overlay.threshold = 0 is out of range: must be > 0",
        ("twin.in_observation_intent=true",): "in_observation_intent = true needs in_observation = true",
        ("twin.in_observation=true", "twin.in_observation_intent=true", "twin.intention.enabled=false"):
            "in_observation_intent = true needs intention.enabled = true",
        ("twin.tagger.evidence_weights=/no/such.json",): "evidence_weights file not found: /no/such.json",
    }
    for overrides, words in cases.items():
        with pytest.raises(ConfigError) as err:
            load_config(None, list(overrides))
        assert words in str(err.value) and "\n" not in str(err.value), err.value
    # what stays allowed: one of the twin's horizons, a threshold up to 1, the columns with the tag's
    cfg = load_config(None, ["overlay.horizon_s=1", "overlay.threshold=1", "twin.intention.horizons_s=[1.0,2.5,3.0]",
                             "twin.in_observation=true", "twin.in_observation_intent=true"])
    assert cfg.overlay.horizon_s == 1.0 and cfg.twin.in_observation_intent
    assert load_config(None, ["twin.intention.horizons_s=[1.0,2.5,3.0]", "overlay.horizon_s=2.5"]).overlay.horizon_s == 2.5


def test_override_value_finds_a_key_set_by_name_or_in_a_table():
    from dt_highway.config import override_value

    assert override_value("overlay.mode=threat", "overlay.mode") == "threat"
    assert override_value('overlay={mode="both", max_marks=2}', "overlay.mode") == "both"
    assert override_value("overlay.max_marks=2", "overlay.mode") is None
    assert override_value("overlay=1", "overlay.mode") is None  # no table: the configuration says what is wrong
    assert override_value("traffic.dangerous.brake_mps2 = 2.0", "traffic.dangerous.brake_mps2") == 2.0
    with pytest.raises(ConfigError, match="--knob expects dotted.key=value"):
        override_value("nope", "a.b", "--knob")


def test_a_highway_key_given_at_the_top_level_and_in_its_section_is_given_once():
    """The top-level value won without a word."""
    with pytest.raises(ConfigError, match=r"^vehicles_count is given at the top level \(5\) and as "
                       r"highway.vehicles_count \(30\): give it once$"):
        validate({"vehicles_count": 5, "highway": {"vehicles_count": 30}})
    assert validate({"vehicles_count": 5, "highway": {"vehicles_count": 5, "lanes_count": 3}}).highway.vehicles_count == 5
    with pytest.raises(ConfigError, match="give it once"):
        gym.make("dt-highway-v0", config={"highway": {"lanes_count": 3}, "lanes_count": 2})
    # a later layer's top-level key beats an earlier layer's section: --set duration=60 on a scenario's [highway]
    assert load_config("envs/highway-trial.toml", ["duration=60"]).highway.duration == 60
    assert load_config("envs/highway-trial.toml", ["lanes_count=4"], {"highway": {"lanes_count": 2}}).highway.lanes_count == 4
    with pytest.raises(ConfigError, match="give it once"):  # both spellings in the one --set layer
        load_config(None, ["lanes_count=4", "highway.lanes_count=2"])


@pytest.mark.parametrize("override, words", [
    # each was accepted and then a traceback, a crash, a hang or nan (a sweep of every key's edge values)
    ("highway.collision_reward=0.5", "normalize_reward needs collision_reward < high_speed_reward + right_lane_reward"),
    ("highway.collision_reward=1e308", "normalize_reward needs"),  # the reward was -inf or nan at every step
    ("highway.road_length=1e300", "highway.road_length = 1e+300 is out of range: must be <= 100000000.0"),
    ("highway.scaling=5000", "highway.scaling = 5000 is out of range: must be <= 100"),  # pygame segfault
    ("highway.scaling=1e-9", "must be >= 0.02"),  # a 2.5 TiB surface
    ("highway.centering_position=[0.5,1e18]", "each a share of the screen in [0, 1]"),
    ("twin.downlink.radius_m=1e300", "twin.downlink.radius_m = 1e+300 is out of range"),  # OverflowError
    ("traffic.population_seed=-1", "traffic.population_seed = -1 is out of range: must be >= 0"),
    ("traffic.population_size=1000000000", "must be <= 100000"),  # memory climbed for minutes
    ("twin.tagger.rate_normal_per_min=1e-320", "must be >= 1e-06"),  # nan confidences
    ("twin.uplink.speed_noise_sigma_mps=1e300", "must be <= 20"),
    ("highway.observation.type=[1]", "highway.observation.type = [1]: not a highway-env or dt-highway observation type"),
])
def test_values_that_broke_the_env_later_are_refused(override, words):
    with pytest.raises(ConfigError) as err:
        load_config(None, [override])
    assert words in str(err.value) and "\n" not in str(err.value), err.value


def test_the_reward_and_screen_checks_keep_every_sensible_setting():
    assert load_config(None, ["highway.normalize_reward=false", "highway.collision_reward=0.5"])
    assert load_config(None, ["highway.centering_position=[0,1]", "highway.scaling=0.05", "twin.downlink.radius_m=1e9"])
    assert load_config(None, ["highway.scaling=100", "traffic.population_seed=0"])


def test_a_validated_configuration_cannot_be_changed_in_place():
    """A section set on its own would skip the rules across sections (fusion needs the camera): one line,
    which says how to change it; the configuration is as it was."""
    cfg = load_config(None, [])
    for section, key, value in [(cfg.fusion, "enabled", True), (cfg.highway, "lanes_count", 2), (cfg, "seed", 3)]:
        old = getattr(section, key, None)
        with pytest.raises(ConfigError, match=r"^the configuration cannot be changed in place .*configure") as err:
            setattr(section, key, value)
        assert "\n" not in str(err.value)
        assert getattr(section, key, None) == old


def test_gym_make_takes_the_configuration_load_config_gives():
    cfg = load_config("envs/highway-trial.toml", ["highway.duration=3"])
    env = gym.make("dt-highway-v0", config=cfg)
    assert env.unwrapped.dt_config == cfg and env.unwrapped.config["duration"] == 3.0
    env.close()


@pytest.mark.parametrize(("tree", "words"), [
    ({"highway": {"lanes_count": True}}, "highway.lanes_count = True: must be a whole number, not true/false"),
    ({"twin": {"uplink": {"rate_hz": True}}}, "twin.uplink.rate_hz = True: must be a number, not true/false"),
    ({"highway": {"lanes_count": "3"}}, "highway.lanes_count = '3': must be a whole number, not text"),
    ({"traffic": {"population_seed": False}}, "traffic.population_seed = False: must be a whole number"),
    ({"overlay": {"sham": "yes"}}, "overlay.sham = 'yes': must be true or false"),
    ({"ego": {"autopilot": 1}}, "ego.autopilot = 1: must be true or false"),
    ({"highway": {"reward_speed_range": [True, 30]}},
     "reward_speed_range = [True, 30]: must be a list of numbers, without true/false"),
    ({"twin": {"intention": {"horizons_s": ["1", 2.0]}}}, "must be a list of numbers, without text"),
    ({"highway": {"offscreen_rendering": "off"}}, "highway.offscreen_rendering = 'off': must be true or false"),
])
def test_numbers_and_switches_are_not_read_from_other_types(tree, words):
    """pydantic's lax reading made lanes_count = true one lane, "off" false and "3" 3."""
    with pytest.raises(ConfigError, match=re.escape(words)):
        validate(tree)


def test_numbers_and_switches_of_numpy_and_python_types_are_taken():
    import numpy as np
    cfg = validate({"highway": {"lanes_count": np.int64(3), "duration": 4}, "ego": {"autopilot": np.True_},
                    "traffic": {"population_seed": None}})
    assert cfg.highway.lanes_count == 3 and cfg.highway.duration == 4.0 and cfg.ego.autopilot is True


def test_a_training_file_takes_numbers_as_numbers():
    import tomllib

    from dt_highway.agent_config import parse_train_config
    tree = tomllib.loads((CHECKOUT / "agents" / "ppo-adas.toml").read_text())
    for key, value, words in [("timesteps", True, "timesteps = True: must be a whole number, not true/false"),
                              ("n_envs", "3", "n_envs = '3': must be a whole number, not text")]:
        with pytest.raises(ConfigError, match=re.escape(words)):
            parse_train_config({**tree, key: value}, "x.toml")


def test_a_configuration_cannot_lose_a_key_in_place_either():
    cfg = load_config(None, [])
    with pytest.raises(ConfigError, match=r"^the configuration cannot be changed in place \(del HighwayConfig"):
        del cfg.highway.lanes_count
    assert cfg.highway.lanes_count == 4
    import numpy as np
    with pytest.raises(ConfigError) as err:
        cfg.highway.lanes_count = np.arange(100)  # a long value: shortened, on one line
    assert "\n" not in str(err.value) and "...)" in str(err.value)

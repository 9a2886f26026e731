"""RL drivers: training configs, training smoke runs, policies as drivers, evaluation."""

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from dt_highway.cli import main
from dt_highway.conditions import CONDITIONS
from dt_highway.config import ConfigError, load_config
from dt_highway.drivers import load_driver
from dt_highway.drivers.policy import PolicyDriver, load_policy
from dt_highway.env import DriverSeat, DTHighwayEnv, OverlayKinematics
from dt_highway.env.senses import cars_under_marks
from dt_highway.evaluation.rl import evaluate
from dt_highway.rl.config import load_train_config, parse_train_config
from dt_highway.rl.train import train

ROOT = Path(__file__).resolve().parents[1]
SHORT = ["highway.duration=8", "twin.preroll_s=5", "highway.vehicles_count=12"]


def _tiny(tmp_path: Path, observation: str, algorithm: str, n_envs: int = 1, steps: int = 200) -> Path:
    hyper = {"PPO": {"n_steps": 64, "batch_size": 32, "n_epochs": 2},
             "DQN": {"learning_starts": 50, "buffer_size": 1000, "train_freq": 4}}[algorithm]
    cfg = parse_train_config({"kind": "rl", "algorithm": algorithm, "observation": observation, "scenario":
                              str(ROOT / "envs/highway-trial.toml"), "set": SHORT, "timesteps": steps,
                              "n_envs": n_envs, "eval_every_steps": 100, "eval_episodes": 1,
                              "checkpoint_every_steps": 100, "hyperparameters": hyper})
    out = tmp_path / f"{algorithm.lower()}-{observation}.zip"
    meta = train(cfg, out, progress=False)
    assert out.is_file() and out.with_suffix(".json").is_file()
    assert meta["timesteps_done"] >= steps and meta["evaluations"] and meta["versions"]["stable-baselines3"]
    assert meta["env_config"]["highway"]["observation"]["type"] == {"kinematics": "Kinematics",
                                                                     "adas": "OverlayKinematics"}[observation]
    assert any(out.with_suffix(".d").glob("checkpoint_*.zip"))
    curve = pd.read_csv(out.with_suffix(".curve.csv"))  # the training curve, written by train()
    evals = curve.dropna(subset=["eval_mean_return"])
    assert evals["eval_mean_return"].tolist() == pytest.approx([e["mean_return"] for e in meta["evaluations"]], rel=1e-5)
    assert curve["train_length_mean"].notna().any() and out.with_suffix(".curve.png").stat().st_size > 10_000
    return out


def test_training_smoke_runs_on_both_observation_settings(tmp_path):
    base = _tiny(tmp_path, "kinematics", "PPO", n_envs=2)  # SubprocVecEnv, "dt_highway:dt-highway-v0" in the children
    adas = _tiny(tmp_path, "adas", "DQN")
    for path, observation, width in ((base, "kinematics", 5), (adas, "adas", 6)):
        driver = load_driver(path)
        assert isinstance(driver, PolicyDriver) and driver.config.observation == observation
        assert driver.model.observation_space.shape == (7, width)
        result = evaluate(str(path), 1, 3, str(ROOT / "envs/highway-trial.toml"), "adas", tuple(SHORT))
        assert result["episodes"] == 1 and result["mean_steps"] > 0 and np.isfinite(result["mean_return"])


def test_the_shipped_policies_load_and_drive():
    for name, width in (("ppo-baseline", 5), ("ppo-adas", 6)):
        path = ROOT / "agents" / f"{name}.zip"
        driver = load_policy(path)
        meta = json.loads(path.with_suffix(".json").read_text())
        assert meta["evaluations"] and meta["timesteps_done"] >= 60_000 and not meta["interrupted"]
        assert driver.model.observation_space.shape == (7, width)
        for condition in ("baseline", "adas"):
            result = evaluate(str(path), 1, 0, str(ROOT / "envs/highway-trial.toml"), condition, tuple(SHORT))
            assert result["mean_steps"] > 0


@pytest.mark.parametrize("name", ["ppo-safe-baseline", "ppo-safe-adas"])
def test_the_safe_policies_load_and_drive_in_every_condition(name):
    """The round-2 policies (safety-aware reward, delayed assisted menu): 500k+ steps, a curve, and a
    short episode in each condition a study can run (an ADAS-aware policy in baseline sees no marks)."""
    path = ROOT / "agents" / f"{name}.zip"
    driver = load_policy(path)
    meta = json.loads(path.with_suffix(".json").read_text())
    assert meta["timesteps_done"] >= 500_000 and not meta["interrupted"] and meta["action"] == "assisted-delayed"
    assert meta["train_config"]["reward"]["collision"]["cut_in"] > 0  # the safety-aware reward, not highway-env's
    curve = pd.read_csv(path.with_suffix(".curve.csv"))
    assert curve["timesteps"].max() >= 500_000 and path.with_suffix(".curve.png").is_file()
    steps = {}
    for condition in CONDITIONS:
        result = evaluate(str(path), 1, 0, str(ROOT / "envs/highway-trial.toml"), condition, tuple(SHORT), driver=driver)
        steps[condition] = result["mean_steps"]
    assert all(n > 0 for n in steps.values()), steps


def test_a_policy_from_another_observation_space_is_refused(tmp_path, capsys):
    src = ROOT / "agents" / "ppo-adas.zip"  # its network takes 7 x 6 (the marks' column)
    wrong = tmp_path / "wrong.zip"
    shutil.copy(src, wrong)
    meta = json.loads(src.with_suffix(".json").read_text())
    meta["train_config"]["observation"] = "kinematics"  # metadata of a 7 x 5 observation
    meta["env_config"]["highway"]["observation"]["type"] = "Kinematics"
    wrong.with_suffix(".json").write_text(json.dumps(meta))
    env = DTHighwayEnv(config=load_config(str(ROOT / "envs/highway-trial.toml"), SHORT).to_dict())
    env.reset(seed=0)
    with pytest.raises(ConfigError, match="trained on observations"):
        DriverSeat(env, load_policy(wrong).senses)
    code = main(["evaluate", "--driver", str(wrong), "--episodes", "1", "--scenario",
                 str(ROOT / "envs/highway-trial.toml"), *sum((["--set", s] for s in SHORT), [])])
    err = capsys.readouterr().err
    assert code == 2 and "trained on observations" in err and len(err.strip().splitlines()) == 1


def test_policy_and_training_file_mistakes_are_one_line(tmp_path, capsys):
    good = ROOT / "agents" / "ppo-baseline.zip"
    (tmp_path / "no-meta.zip").write_bytes(good.read_bytes())
    (tmp_path / "foreign.zip").write_bytes(good.read_bytes())
    (tmp_path / "foreign.json").write_text('{"hello": 1}')
    (tmp_path / "broken.zip").write_bytes(b"not a zip")
    meta = json.loads(good.with_suffix(".json").read_text())
    (tmp_path / "other.zip").write_bytes(b"not a zip")
    (tmp_path / "other.json").write_text(json.dumps(meta))  # names the shipped model's hash
    meta.pop("model_sha256")
    (tmp_path / "broken.json").write_text(json.dumps(meta))
    for name, words in (("missing.zip", "not found"), ("no-meta.zip", "not a dt-highway policy"),
                        ("foreign.zip", "not the metadata"), ("other.zip", "another model file"),
                        ("broken.zip", "cannot load")):
        with pytest.raises(ConfigError, match=words):
            load_driver(tmp_path / name)
    with pytest.raises(ConfigError, match="training config"):
        load_driver(ROOT / "agents" / "ppo-baseline.toml")  # a training config is not a driver
    with pytest.raises(ConfigError, match="kind"):
        load_train_config(ROOT / "agents" / "idm.toml")
    for tree, words in (({"kind": "rl", "algorithm": "A2C"}, "algorithm"), ({"kind": "rl", "bogus": 1}, "bogus"),
                        ({"kind": "rl", "observation": "radar"}, "observation"), ({"kind": "rl", "n_envs": 0}, "n_envs")):
        with pytest.raises(ConfigError, match=words):
            parse_train_config(tree)
    with pytest.raises(ConfigError, match="accels_mps2"):
        parse_train_config({"kind": "rl", "accels_mps2": [-20.0, 0.0]})  # refused here, not in a worker process
    cfg = tmp_path / "bad-hyper.toml"
    cfg.write_text('kind = "rl"\ntimesteps = 10\nset = ["highway.duration=4", "twin.preroll_s=1"]\n'
                   '[hyperparameters]\nnot_a_parameter = 1\n')
    for argv, words in ((["train", "--config", str(cfg), "--out", str(tmp_path / "x.pt")], ".zip"),
                        (["train", "--config", str(cfg), "--out", str(good)], "exists"),
                        (["train", "--config", str(cfg), "--out", str(tmp_path / "x.zip")], "not_a_parameter"),
                        (["evaluate", "--driver", str(tmp_path / "missing.zip")], "not found")):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert words in err and len(err.strip().splitlines()) == 1, err
    kept = tmp_path / "moved.d" / "notes.txt"  # an earlier run's checkpoints, its policy moved away
    kept.parent.mkdir()
    kept.write_text("mine")
    assert main(["train", "--config", str(cfg), "--out", str(tmp_path / "moved.zip")]) == 2
    err = capsys.readouterr().err
    assert "moved.d exists: pass --force" in err and len(err.strip().splitlines()) == 1 and kept.read_text() == "mine"



@pytest.mark.parametrize("algorithm, hyper, words", [
    ("PPO", {"gamma": 2}, "hyperparameters.gamma = 2: must be a number >= 0 and <= 1"),
    ("PPO", {"gamma": "0.9"}, "hyperparameters.gamma = '0.9'"),
    ("PPO", {"gamma": True}, "hyperparameters.gamma = True"),
    ("PPO", {"learning_rate": 0}, "learning_rate = 0: must be a number > 0"),
    ("PPO", {"n_epochs": 0}, "n_epochs = 0: must be a whole number >= 1"),
    ("PPO", {"n_steps": 64.5}, "n_steps = 64.5"),
    ("PPO", {"clip_range": -0.2, "ent_coef": -1},
     "clip_range = -0.2: must be a number > 0 (or a schedule, from Python); hyperparameters.ent_coef"),
    ("PPO", {"gae_lambda": float("nan")}, "gae_lambda"),
    ("PPO", {"seed": 3}, "hyperparameters.seed cannot be set here: use the training file's seed"),
    ("PPO", {"policy_kwargs": {"net_arch": [8]}}, "use the [policy_kwargs] table"),
    ("DQN", {"tau": 0}, "tau = 0: must be a number > 0 and <= 1"),
    ("DQN", {"exploration_final_eps": 1.5}, "exploration_final_eps"),
    ("DQN", {"train_freq": [4, "epoch"]}, 'train_freq = [4, \'epoch\']: must be a whole number >= 1 or [N, "step"]'),
    ("DQN", {"gradient_steps": 1.5}, "-1: as many as the env steps of the rollout; 0: no training"),
    ("PPO", {"batch_size": 1}, "batch_size = 1 needs normalize_advantage = false"),
    ("PPO", {"n_steps": 1, "batch_size": 2}, "n_steps = 1 with n_envs = 1 gives rollouts of one step"),
    ("DQN", {"optimize_memory_usage": True}, "needs replay_buffer_kwargs = {handle_timeout_termination = false}"),
    ("DQN", {"optimize_memory_usage": True, "replay_buffer_kwargs": {"handle_timeout_termination": False},
             "n_steps": 2}, "optimize_memory_usage = true needs n_steps = 1 (got 2)"),
    ("PPO", {"max_grad_norm": float("-inf")}, "max_grad_norm = -inf: must be a number > 0"),
    ("DQN", {"train_freq": [1, "episode"]}, "counts episodes, which stable-baselines3 does in one env only: set n_envs = 1"),
    ("DQN", {"buffer_size": 0}, "buffer_size = 0"),
])
def test_hyperparameters_the_algorithm_would_take_silently_are_refused(algorithm, hyper, words):
    # stable-baselines3 trains with gamma = 2, or fails after the first rollout with gamma = "0.9"
    with pytest.raises(ConfigError) as err:
        parse_train_config({"kind": "rl", "algorithm": algorithm, "hyperparameters": hyper,
                            "n_envs": 1 if "n_steps" in hyper else 2}, "agents/x.toml")
    assert str(err.value).startswith("agents/x.toml: hyperparameters.") and words in str(err.value), err.value
    assert "\n" not in str(err.value)


def test_the_hyperparameter_checks_take_what_stable_baselines3_takes(tmp_path):
    import inspect

    import stable_baselines3 as sb3
    from stable_baselines3.common.type_aliases import TrainFreq, TrainFrequencyUnit
    from stable_baselines3.common.utils import LinearSchedule

    from dt_highway.agent_config import HYPERPARAMETERS, check_hyperparameters

    for algorithm, model in HYPERPARAMETERS.items():  # the defaults the API pages show are SB3's own
        signature = inspect.signature(getattr(sb3, algorithm)).parameters
        assert {name: field.default for name, field in model.model_fields.items()} == {
            name: signature[name].default for name in model.model_fields}
    for algorithm, hyper in (("PPO", {"clip_range": lambda progress: 0.2 * progress, "learning_rate": LinearSchedule(
                                 1e-3, 1e-4, 1.0), "clip_range_vf": LinearSchedule(0.2, 0.1, 1.0)}),
                             ("PPO", {"n_steps": np.int64(128), "gamma": np.float32(0.99), "max_grad_norm": float("inf")}),
                             ("PPO", {"batch_size": 1, "normalize_advantage": False}),
                             ("DQN", {"train_freq": (np.int64(4), "step"), "gradient_steps": 0}),
                             ("DQN", {"optimize_memory_usage": True,
                                      "replay_buffer_kwargs": {"handle_timeout_termination": np.False_}}),
                             ("DQN", {"train_freq": TrainFreq(2, TrainFrequencyUnit.EPISODE), "gradient_steps": -3})):
        assert check_hyperparameters(algorithm, hyper) is None, hyper
    one = parse_train_config({"kind": "rl", "algorithm": "DQN", "n_envs": 1, "hyperparameters": {
        "train_freq": [1, "episode"]}})
    with pytest.raises(ConfigError, match=r"with n_envs = 2: hyperparameters.train_freq = \[1, 'episode'\] counts"):
        train(one, tmp_path / "unused.zip", n_envs=2)  # --n-envs 2 is checked as the file's own n_envs


def test_hyperparameters_in_range_reach_the_algorithm():
    from stable_baselines3.common.env_util import make_vec_env

    from dt_highway.rl.train import build_model

    env = make_vec_env("CartPole-v1", n_envs=1)
    dqn = build_model(parse_train_config({"kind": "rl", "algorithm": "DQN", "n_envs": 1, "hyperparameters": {
        "train_freq": [1, "episode"], "gradient_steps": -1, "tau": 0.005, "exploration_fraction": 1.0}}), env)
    assert (dqn.train_freq.frequency, dqn.train_freq.unit.value) == (1, "episode")  # a TOML list, a tuple to SB3
    assert (dqn.gradient_steps, dqn.tau, dqn.exploration_fraction) == (-1, 0.005, 1.0)
    ppo = build_model(parse_train_config({"kind": "rl", "hyperparameters": {
        "gamma": 1, "n_steps": 16, "batch_size": 16, "learning_rate": 1e-3, "target_kl": 0.02}}), env)
    assert (ppo.gamma, ppo.n_steps, ppo.batch_size, ppo.target_kl) == (1, 16, 16, 0.02)
    for name in ("ppo-baseline", "ppo-adas", "ppo-safe-baseline", "ppo-safe-adas"):  # the shipped files still load
        assert load_train_config(ROOT / "agents" / f"{name}.toml").hyperparameters["gamma"] == 0.97

def test_discrete_driver_menu_and_the_overlay_column():
    # a minute of pre-roll: the twin has tagged drivers by t = 0, so markers show up
    cfg = load_config(str(ROOT / "envs/highway-trial.toml"), ["highway.duration=8", "highway.vehicles_count=16",
                                                              "camera.enabled=true", "fusion.enabled=true"],
                      {"highway": {"observation": {"type": "OverlayKinematics"}, "action": {"type": "DiscreteDriver"}}})
    env = DTHighwayEnv(config=cfg.to_dict())
    assert env.action_space.n == 8
    assert list(env.action_type.driver_action(6)) == [0.0, -1.0] and list(env.action_type.driver_action(0)) == [-6.0, 0.0]
    with pytest.raises(ValueError, match="0..7"):
        env.action_type.driver_action(8)
    obs, info = env.reset(seed=3)  # a seed with tagged drivers in view in the first 3 s (seeds 0-2 have none)
    assert isinstance(env.observation_type, OverlayKinematics)
    marked_seen = 0
    for _ in range(15):
        obs, _, term, trunc, info = env.step(3)
        rows = env.observation_type.observed()
        under = cars_under_marks(env, info["adas"]["overlay"])  # the cars a person sees the markers on
        for r, v in enumerate(rows[1:], start=1):
            assert obs[r, -1] == float(v.dt_id in under)
        assert obs[0, -1] == 0.0  # the ego's own row
        marked_seen += int(obs[:, -1].sum())
        if term or trunc:
            break
    assert marked_seen > 0
    # the baseline condition: no overlay, the column stays 0
    cfg = load_config(str(ROOT / "envs/highway-trial.toml"), SHORT,
                      {"highway": {"observation": {"type": "OverlayKinematics"}, "action": {"type": "Driver"}}})
    env = DTHighwayEnv(config=cfg.to_dict())
    obs, _ = env.reset(seed=0)
    for _ in range(5):
        obs, *_ = env.step(np.zeros(2))
        assert not obs[:, -1].any()


def test_a_policy_runs_a_study_in_both_conditions_and_the_report_covers_it(tmp_path):
    out = tmp_path / "study"
    args = ["study", "--driver", str(ROOT / "agents" / "ppo-adas.zip"), "--trials", "1", "--workers", "1", "--out",
            str(out), "--quiet", "--report", "--scenario", str(ROOT / "envs/highway-trial.toml"),
            *sum((["--set", s] for s in SHORT), [])]
    assert main(args) == 0
    assert (out / "inputs" / "ppo-adas.zip").is_file() and (out / "inputs" / "ppo-adas.json").is_file()
    meta = json.loads((out / "trials" / "adas-000" / "meta.json").read_text())
    assert meta["status"] == "completed" and meta["driver"] == "ppo-adas"
    assert meta["driver_params"]["observation"] == "adas"
    summary = json.loads((out / "summary.json").read_text())
    assert summary["conditions"]["baseline"]["n"] == 1 and summary["conditions"]["adas"]["n"] == 1
    assert "ppo-adas" in (out / "report.html").read_text()


def test_the_policy_sees_what_the_training_env_showed(tmp_path):
    """PolicyDriver's observation of an env equals the training env's own observation, step by step."""
    path = ROOT / "agents" / "ppo-adas.zip"
    driver = load_policy(path)
    tree = driver.config.env_config().to_dict()  # the training env: ADAS condition, OverlayKinematics, assisted menu
    tree["highway"]["duration"] = 6
    env = DTHighwayEnv(config=tree)
    obs, info = env.reset(seed=5)
    seat = DriverSeat(env, driver.senses)
    driver.reset(5)
    for _ in range(20):
        perception = seat.perceive()
        assert np.array_equal(perception.observation, obs)
        k = int(driver.model.predict(obs, deterministic=True)[0])
        assert np.array_equal(driver.menu.action(k, perception), env.action_type.driver_action(k))
        obs, _, term, trunc, info = env.step(k)
        if term or trunc:
            break


def test_the_overlay_column_follows_the_marker_on_screen_not_the_id(monkeypatch):
    """A marker whose box sits on car B but whose item names car A marks B's row: the column
    is what a driver sees on the screen, never the id (or the true type) behind it."""
    cfg = load_config(str(ROOT / "envs/highway-trial.toml"), [*SHORT, "camera.enabled=true", "fusion.enabled=true"],
                      {"highway": {"observation": {"type": "OverlayKinematics", "vehicles_count": 7,
                                                   "see_behind": True}, "action": {"type": "Driver"}}})
    env = DTHighwayEnv(config=cfg.to_dict())
    env.reset(seed=0)
    env.step(np.zeros(2))
    rows = env.observation_type.observed()
    frame = env.camera_truth()
    seen = [v for v in rows[1:] if v.dt_id in frame.vehicles and frame.vehicles[v.dt_id].visible_box is not None]
    assert len(seen) >= 2
    a, b = seen[0], seen[1]
    fake = {"overlay": [{"vehicle_id": a.dt_id, "box": list(frame.vehicles[b.dt_id].visible_box),
                         "label": "aggressive driver", "confidence": 0.9}]}
    monkeypatch.setattr(env, "adas_output", lambda: fake)
    obs = env.observation_type.observe()
    marked = {rows[r].dt_id for r in range(1, len(rows)) if obs[r, -1] == 1.0}
    assert marked == {b.dt_id}
    monkeypatch.setattr(env, "adas_output", lambda: {"overlay": []})
    assert not env.observation_type.observe()[:, -1].any()


def test_vision_setting_trains_and_drives_in_both_conditions(tmp_path):
    cfg = parse_train_config({"kind": "rl", "observation": "vision", "depth": True, "timesteps": 32, "n_envs": 1,
                              "scenario": str(ROOT / "envs/highway-trial.toml"), "set": SHORT,
                              "eval_every_steps": 32, "eval_episodes": 1,
                              "hyperparameters": {"n_steps": 16, "batch_size": 16, "n_epochs": 1}})
    out = tmp_path / "vision.zip"
    meta = train(cfg, out, progress=False)
    assert meta["env_config"]["camera"]["width_px"] == 128 and meta["evaluations"]
    for condition in ("baseline", "adas"):  # the study's camera size: frames are resized for the policy
        result = evaluate(str(out), 1, 0, str(ROOT / "envs/highway-trial.toml"), condition, tuple(SHORT))
        assert result["mean_steps"] > 0


@pytest.mark.parametrize("inside_numba", [False, True])
def test_an_interrupted_training_keeps_what_it_learned(tmp_path, monkeypatch, capsys, inside_numba):
    """Ctrl-C, also when it lands in numba code (a SystemError caused by it), keeps what was learned."""
    from conftest import numba_interrupt
    from stable_baselines3 import PPO

    def stop(self, *args, **kwargs):
        self.num_timesteps = 64
        raise numba_interrupt() if inside_numba else KeyboardInterrupt

    monkeypatch.setattr(PPO, "learn", stop)
    cfg = tmp_path / "tiny.toml"
    cfg.write_text(f'kind = "rl"\nscenario = "{ROOT / "envs/highway-trial.toml"}"\nset = {json.dumps(SHORT)}\n'
                   'timesteps = 1000\nn_envs = 1\n')
    out = tmp_path / "tiny.zip"
    assert main(["train", "--config", str(cfg), "--out", str(out), "--quiet"]) == 130
    meta = json.loads(out.with_suffix(".json").read_text())
    assert meta["interrupted"] is True and out.is_file()
    assert "no training curve" in capsys.readouterr().err and not out.with_suffix(".curve.png").exists()
    assert isinstance(load_policy(out), PolicyDriver)  # the pair is consistent (hash checked)


def test_the_assisted_menu_brakes_for_a_car_coming_into_the_lane():
    from dt_highway.drivers.menus import AssistedMenu
    from dt_highway.env.senses import perceive

    cfg = load_config(str(ROOT / "envs/highway-trial.toml"), SHORT, {"highway": {"action": {"type": "Driver"}}})
    env = DTHighwayEnv(config=cfg.to_dict())
    env.reset(seed=0)
    ego = env.vehicle
    lane = env.road.network.get_lane(ego.lane_index)
    centre = float(lane.position(float(ego.position[0]), 0.0)[1])
    others = [v for v in env.road.vehicles if v is not ego]
    for v in others:  # clear the road ahead but for one car, 15 m ahead and 10 m/s slower
        v.position[0] = float(ego.position[0]) - 200.0
    car = others[0]
    car.position[0], car.speed = float(ego.position[0]) + 15.0 + car.LENGTH, float(ego.speed) - 10.0
    menu = AssistedMenu()
    accel = {}
    for offset in (4.0, 2.5, 0.0):  # in the next lane, half into the ego's lane, in it
        car.position[1] = centre + offset
        accel[offset] = menu.action(perceive(env, AssistedMenu.SENSES), 3)[0]
    assert accel[4.0] > 0 > accel[2.5] and accel[2.5] == accel[0.0]
    assert menu.action(perceive(env, AssistedMenu.SENSES), 3)[1] == 0.0


def test_dqn_on_images_gets_a_replay_buffer_that_fits_in_memory():
    from stable_baselines3.common.vec_env import DummyVecEnv

    from dt_highway.rl.train import VISION_DQN_BUFFER, _make_env, build_model

    for hyper, size in (({}, VISION_DQN_BUFFER), ({"buffer_size": 500}, 500)):
        cfg = parse_train_config({"kind": "rl", "algorithm": "DQN", "observation": "vision", "set": SHORT,
                                  "scenario": str(ROOT / "envs/highway-trial.toml"), "hyperparameters": hyper})
        env = DummyVecEnv([_make_env(cfg.env_config().to_dict(), 0, 1)])
        try:
            assert build_model(cfg, env).buffer_size == size
        finally:
            env.close()

"""The camera inside the env: observation, one rendering per step, ground truth in info, errors."""

import copy

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import dt_highway  # noqa: F401  (registers the env)
from dt_highway.config import ConfigError
from dt_highway.env import DTHighwayEnv

CAMERA = {"camera": {"enabled": True, "width_px": 160, "height_px": 90}}


@pytest.fixture
def cfg(small_config):
    """Build small camera configs: ``cfg(highway={...})``."""

    def make(**extra) -> dict:
        return _config(small_config, **extra)

    return make


def _config(base: dict, **extra) -> dict:
    cfg = copy.deepcopy(base)
    cfg.update(copy.deepcopy(CAMERA))
    for key, value in extra.items():
        cfg.setdefault(key, {}).update(value)
    return cfg


def test_camera_observation_passes_check_env(cfg):
    env = gym.make("dt-highway-v0", config=cfg(highway={"observation": {"type": "Camera"}}))
    check_env(env.unwrapped, skip_render_check=True)
    obs, _ = env.reset(seed=1)
    assert set(obs) == {"rgb", "depth"}
    assert obs["rgb"].shape == (90, 160, 3) and obs["rgb"].dtype == np.uint8
    assert obs["depth"].shape == (90, 160, 1) and obs["depth"].dtype == np.uint8
    assert env.observation_space.contains(obs)
    env.close()


def test_rgb_only_observation_and_sb3_checker(cfg):
    from stable_baselines3.common.env_checker import check_env as sb3_check_env

    env = DTHighwayEnv(config=cfg(highway={"observation": {"type": "Camera", "depth": False}}))
    obs, _ = env.reset(seed=0)
    assert set(obs) == {"rgb"}
    sb3_check_env(env, warn=False)
    env.close()


def test_one_rendering_per_step_shared_by_observation_info_and_callers(monkeypatch, cfg):
    env = DTHighwayEnv(config=cfg(highway={"observation": {"type": "Camera"}}))
    env.reset(seed=2)
    calls = []
    original = env.camera.render
    monkeypatch.setattr(env.camera, "render", lambda *a, **k: calls.append(1) or original(*a, **k))
    obs, _, _, _, info = env.step(1)
    assert len(calls) == 1
    frame = env.camera_image()
    assert len(calls) == 1 and frame.rgb is obs["rgb"]
    assert frame.time_s == pytest.approx(info["time_s"])
    truth = {t["vehicle_id"]: t for t in info["ground_truth"]["camera"]}
    assert truth.keys() == env.camera_truth().vehicles.keys()
    env.step(1)
    env.camera_image()
    assert len(calls) == 2
    env.close()


def test_same_seed_same_frames(cfg):
    frames = []
    for _ in range(2):
        env = DTHighwayEnv(config=cfg())
        env.reset(seed=4)
        env.step(1)
        f, t = env.camera_image(), env.camera_truth()
        frames.append((f.rgb.tobytes(), f.depth_m.tobytes(), t.instance.tobytes()))
        env.close()
    assert frames[0] == frames[1]


def test_frames_show_the_traffic_and_never_the_ego(cfg):
    env = DTHighwayEnv(config=cfg(highway={"vehicles_count": 30}))
    env.reset(seed=0)
    seen = set()
    for _ in range(4):
        env.step(1)
        f = env.camera_truth()
        seen |= {v for v, t in f.vehicles.items() if t.visible_px > 0}
        assert 0 not in f.vehicles
    assert len(seen) >= 3
    env.close()


def test_camera_off_by_default_and_errors(cfg, small_config):
    env = DTHighwayEnv(config=copy.deepcopy(small_config))
    env.reset(seed=0)
    with pytest.raises(RuntimeError, match="camera is off"):
        env.camera_image()
    with pytest.raises(RuntimeError, match="camera is off"):
        env.camera_truth()
    env.close()
    with pytest.raises(ConfigError, match="needs camera.enabled"):
        DTHighwayEnv(config={"highway": {"observation": {"type": "Camera"}}})
    with pytest.raises(ConfigError, match="takes only 'depth'"):
        DTHighwayEnv(config=cfg(highway={"observation": {"type": "Camera", "grey": True}}))
    with pytest.raises(ConfigError, match="max_range_m"):
        DTHighwayEnv(config={"camera": {"near_m": 5.0, "max_range_m": 2.0}})
    with pytest.raises(ConfigError, match="camera.width_px"):
        DTHighwayEnv(config={"camera": {"width_px": 0}})
    with pytest.raises(ConfigError, match="cx_px must lie in the image"):
        DTHighwayEnv(config={"camera": {"cx_px": 700.0}})


def test_principal_point_moves_the_image(cfg):
    frames = []
    for cx in (None, 60.0):
        env = DTHighwayEnv(config=cfg(camera={"cx_px": cx}))
        env.reset(seed=1)
        assert env.camera.camera.intrinsics.cx_px == (79.5 if cx is None else cx)
        frames.append(env.camera_image().rgb)
        env.close()
    assert frames[0].tobytes() != frames[1].tobytes()


def test_adas_overlay_items_come_from_the_twin_and_the_fusion(cfg):
    env = DTHighwayEnv(config=cfg(fusion={"enabled": True}, ego={"autopilot": True},
                                  highway={"vehicles_count": 30}, traffic={"aggressive_fraction": 0.5}))
    _, info = env.reset(seed=3)
    shown = 0
    for _ in range(6):
        _, _, _, _, info = env.step(1)
        adas = info["adas"]
        aggressive = {v["vehicle_id"] for v in info["twin"] or [] if v["tag"] == "aggressive"}
        for item in adas["overlay"]:
            assert item["vehicle_id"] in aggressive  # only what the twin tags, never ground truth
            assert item["label"] == "aggressive driver" and 0.0 <= item["confidence"] <= 1.0
            x1, y1, x2, y2 = item["box"]
            assert x2 > x1 and y2 > y1
            shown += 1
        assert set(adas["placements"]) <= {v["vehicle_id"] for v in info["twin"] or []}
    assert adas["method"] == "tracked"
    env.close()
    with pytest.raises(ConfigError, match="fusion.enabled = true needs camera.enabled"):
        DTHighwayEnv(config={"fusion": {"enabled": True}})

"""The threat cue in the ADAS-aware observation (``observation = "adas-threat"``:
OverlayKinematics with ``threat = true``): ``cut_in_warned`` and ``side`` from the marks as drawn,
the sham's marks through the same columns, and the old observation settings unchanged."""

from pathlib import Path

import numpy as np
import pytest

from dt_highway.config import ConfigError, load_config
from dt_highway.env import DTHighwayEnv, OverlayKinematics
from dt_highway.env.senses import cars_under_marks
from dt_highway.rl.config import parse_train_config
from dt_highway.world.traffic import vehicle_id

ROOT = Path(__file__).resolve().parents[1]
SHORT = ["highway.duration=8", "twin.preroll_s=5", "highway.vehicles_count=12"]


def _env(observation: str, condition: str | None = None) -> DTHighwayEnv:
    cfg = parse_train_config({"kind": "rl", "observation": observation, "action": "assisted", "set": SHORT})
    return DTHighwayEnv(config=cfg.env_config(condition).to_dict())


def _visible_rows(env: DTHighwayEnv, observer: OverlayKinematics) -> list[tuple[int, tuple[float, ...]]]:
    """(row, the car's visible outline in the camera image) of the observed cars the camera sees."""
    boxes = {vid: t.visible_box for vid, t in env.camera_truth().vehicles.items() if t.visible_box is not None}
    return [(r, tuple(boxes[vehicle_id(v)])) for r, v in enumerate(observer.observed()[1:], start=1)
            if vehicle_id(v) in boxes]


def test_a_marked_cutting_in_car_has_the_cue_and_its_side():
    env = _env("adas-threat")
    env.reset(seed=2)
    obs_type = env.observation_type
    assert isinstance(obs_type, OverlayKinematics) and obs_type.threat
    assert obs_type.features[-3:] == ["marked", "cut_in_warned", "side"] and env.observation_space.shape == (7, 8)
    seen = _visible_rows(env, obs_type)
    assert len(seen) >= 2, "the scene should show two observed cars"
    (r1, box1), (r2, box2) = seen[:2]
    overlay = [{"box": box1, "label": "cutting in from left"}, {"box": box2, "label": "aggressive driver"}]
    env.adas_output = lambda: {"overlay": overlay}  # what is on the screen, by hand
    obs = obs_type.observe()
    assert obs[r1, -3:].tolist() == [1.0, 1.0, -1.0]  # marked, warned, from the left
    assert obs[r2, -3:].tolist() == [1.0, 0.0, 0.0]  # a driver-type mark: marked, no cut-in cue
    others = [r for r in range(1, 7) if r not in (r1, r2)]
    assert not obs[others, -3:].any() and not obs[0, -3:].any()
    overlay[0]["label"] = "cutting in from right + aggressive driver"
    assert obs_type.observe()[r1, -3:].tolist() == [1.0, 1.0, 1.0]
    # the old ADAS observation of the same screen: its columns, the same values, one column fewer
    old = OverlayKinematics(env, vehicles_count=7, see_behind=True)
    assert old.space().shape == (7, 6) and np.array_equal(old.observe(), obs_type.observe()[:, :6])
    env.close()


def test_the_old_observation_settings_are_unchanged():
    for observation, kind, width in (("kinematics", "Kinematics", 5), ("adas", "OverlayKinematics", 6)):
        cfg = parse_train_config({"kind": "rl", "observation": observation})
        table = cfg.observation_config()
        assert table == {"type": kind, "vehicles_count": 7, "see_behind": True}  # no "threat" key
        env = _env(observation)
        assert env.observation_space.shape == (7, width)
        env.close()
    assert parse_train_config({"kind": "rl", "observation": "adas-threat"}).env_config().overlay.mode == "threat"


def test_the_sham_marks_flow_through_the_same_columns():
    """In the sham-threat condition the marks on screen are on cars drawn at random; the columns are
    those marks, read the same way (each mark's car, and whether its label says cutting in)."""
    cfg = parse_train_config({"kind": "rl", "observation": "adas-threat", "action": "assisted",
                              "set": [*SHORT, "highway.duration=12"]})
    env = DTHighwayEnv(config=cfg.env_config("sham-threat").to_dict())
    obs, _ = env.reset(seed=4)  # a sham cut-in mark from about 8.6 s on
    shown = 0
    for _ in range(60):
        overlay = env.adas_output()["overlay"]
        rows = env.observation_type.observed()[1:]
        for r, v in enumerate(rows, start=1):
            under = [item for item in overlay if vehicle_id(v) in cars_under_marks(env, [item])]
            warned = any(str(item["label"]).startswith("cutting in") for item in under)
            assert obs[r, -3:-1].tolist() == [float(bool(under)), float(warned)]
            shown += warned
        obs, _, done, trunc, _ = env.step(2)
        if done or trunc:
            break
    env.close()
    assert shown > 0, "no sham cut-in mark on an observed car in these steps"


def test_threat_is_an_option_of_the_overlay_observation_only():
    for table in ({"type": "Kinematics", "threat": True}, {"type": "OverlayKinematics", "threat": 1}):
        with pytest.raises(ConfigError, match="threat"):
            load_config(None, [], {"highway": {"observation": table}})

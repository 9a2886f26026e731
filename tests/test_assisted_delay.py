"""The delayed assisted menu (``action = "assisted-delayed"``): its gap keeping reacts to a car newly
in the lane ahead only a reaction time after it appeared, and brakes no harder than its limit; with
no delay it is today's menu exactly. Hand-built perceptions, IDM values by hand."""

import math
from pathlib import Path

import numpy as np
import pytest

from dt_highway.config import ConfigError, load_config
from dt_highway.drivers.menus import AssistedMenu, DiscreteMenu
from dt_highway.drivers.perception import OwnState, Perception, Seen, Surroundings
from dt_highway.env import DTHighwayEnv
from dt_highway.rl.config import parse_train_config

ROOT = Path(__file__).resolve().parents[1]
DT = 0.2  # decisions at 5 Hz
V = 25.0
LEADER, CUTTER, OTHER = 3, 7, 9
KEEP_27 = 2  # choice: desired speed 27 m/s, keep the lane


def _perception(t, leader_gap_m=math.inf, cutter=None, lane=1):
    """The ego in lane ``lane`` of 3 at 25 m/s; its leader ``leader_gap_m`` ahead at 25 m/s (inf: none);
    ``cutter``: ``(gap [m], speed [m/s], state)``, state ``"entering"`` (its body reaches into the
    lane) or ``"in"`` (in the lane: the nearest ahead, the leader hidden behind it)."""
    ahead = {-1: Seen(), 0: Seen(LEADER, leader_gap_m, V) if math.isfinite(leader_gap_m) else Seen(), 1: Seen()}
    x_of = {LEADER: (leader_gap_m + 5.0, 0)} if math.isfinite(leader_gap_m) else {}
    entering = None
    if cutter is not None:
        gap, speed, state = cutter
        x_of[CUTTER] = (gap + 5.0, 0 if state == "in" else -1)
        entering = Seen(CUTTER, gap, speed)
        if state == "in":
            ahead[0] = entering
    s = Surroundings(t, V, lane, 3, ahead, {-1: Seen(), 0: Seen(), 1: Seen()}, x_of)
    return Perception(t, OwnState(V, 0.0, lane, 3, False), s, entering)


def _idm(gap_m, closing_mps, v0=27.0):
    """The assisted menu's IDM by hand: a = 1.5, b = 2, T = 1.2 s, s0 = 2 m, delta = 4."""
    free = 1 - (V / v0) ** 4
    if not math.isfinite(gap_m):
        return 1.5 * free
    s_star = 2.0 + V * 1.2 + V * closing_mps / (2 * math.sqrt(1.5 * 2.0))
    return 1.5 * (free - (s_star / gap_m) ** 2)


def _run(menu, cutter_from_s=1.0, n=20, leader_gap_m=math.inf, cutter=(10.0, 20.0), in_lane_from_s=math.inf):
    """The menu's accelerations at decisions ``k DT``; a car cuts in at ``cutter_from_s`` (gap, speed),
    entering first, in the lane from ``in_lane_from_s``."""
    menu.reset()
    out = []
    for k in range(n):
        t = k * DT
        c = None
        if t >= cutter_from_s - 1e-9:
            c = (*cutter, "in" if t >= in_lane_from_s - 1e-9 else "entering")
        out.append(float(menu.action(_perception(t, leader_gap_m, c), KEEP_27)[0]))
    return np.array(out)


def test_free_road_then_a_cut_in_the_delayed_menu_keeps_going_for_the_reaction_time():
    """Free road, then at t = 1 s a car cuts in 10 m ahead at 20 m/s: the undelayed menu brakes at
    once (IDM asks for ~ -69 m/s^2: the -8 m/s^2 floor); the delayed one keeps its free-road
    acceleration (+0.40 m/s^2) until t = 1 + 1.2 s, then brakes at its 6 m/s^2 limit."""
    free, hard = _idm(math.inf, 0.0), _idm(10.0, 5.0)
    assert free == pytest.approx(0.3975, abs=1e-3) and hard < -60
    now = _run(AssistedMenu())
    delayed = _run(AssistedMenu(reaction_time_s=1.2, brake_limit_mps2=6.0))
    t = np.arange(20) * DT
    before, during, after = t < 1.0 - 1e-9, (t >= 1.0 - 1e-9) & (t < 2.2 - 1e-9), t >= 2.2 - 1e-9
    assert np.allclose(now[before], free) and np.allclose(delayed[before], free)
    assert np.all(now[during | after] == -8.0)
    assert np.allclose(delayed[during], free) and np.all(delayed[during] > 0)  # no braking during the delay
    assert np.all(delayed[after] == -6.0)  # after it, braking at the limit
    assert during.sum() == 6  # 1.2 s at 5 Hz


def test_during_the_delay_it_follows_the_car_it_followed_even_once_the_new_one_hides_it():
    """A leader 40 m ahead at the ego's speed; a car cuts in 12 m ahead at 22 m/s at t = 1 s and is
    in the lane (the nearest ahead, the leader no longer seen as such) from t = 1.4 s: until
    t = 2.2 s the delayed menu follows the leader (its gap from where it is seen, 40 m), then the new car."""
    follow, cut = _idm(40.0, 0.0), _idm(12.0, 3.0)
    delayed = _run(AssistedMenu(reaction_time_s=1.2, brake_limit_mps2=6.0), leader_gap_m=40.0, cutter=(12.0, 22.0),
                   in_lane_from_s=1.4)
    t = np.arange(20) * DT
    assert np.allclose(delayed[t < 2.2 - 1e-9], follow)  # -0.5625 m/s^2: the leader's gap, as without the cut-in
    assert follow == pytest.approx(1.5 * (1 - (25 / 27) ** 4 - (32 / 40) ** 2))
    assert np.allclose(delayed[t >= 2.2 - 1e-9], max(cut, -6.0))
    assert _run(AssistedMenu(), leader_gap_m=40.0, cutter=(12.0, 22.0), in_lane_from_s=1.4)[5] == max(cut, -8.0)


def test_expected_cars_are_followed_at_once():
    menu = AssistedMenu(reaction_time_s=1.2, brake_limit_mps2=6.0)
    # the first decision of an episode: the car ahead is already there
    assert menu.action(_perception(0.0, 30.0), KEEP_27)[0] == pytest.approx(_idm(30.0, 0.0))
    # a car appearing farther than the one followed (say the leader's leader, once the leader left): at once
    menu.reset()
    menu.action(_perception(0.0, 30.0), KEEP_27)
    far = Perception(0.2, OwnState(V, 0.0, 1, 3, False),
                     Surroundings(0.2, V, 1, 3, {-1: Seen(), 0: Seen(OTHER, 50.0, V), 1: Seen()},
                                  {-1: Seen(), 0: Seen(), 1: Seen()}, {OTHER: (55.0, 0), LEADER: (35.0, -1)}))
    assert menu.action(far, KEEP_27)[0] == pytest.approx(_idm(50.0, 0.0))
    # the lane the ego moved into: its leader at once
    menu.reset()
    menu.action(_perception(0.0, math.inf, lane=1), KEEP_27)
    assert menu.action(_perception(0.2, 20.0, lane=0), KEEP_27)[0] == pytest.approx(max(_idm(20.0, 0.0), -6.0))


def test_without_a_delay_it_is_today_s_menu_exactly():
    rng = np.random.default_rng(1)
    a, b = AssistedMenu(), AssistedMenu(reaction_time_s=0.0)
    for k in range(50):
        gap = float(rng.uniform(3, 60))
        c = (float(rng.uniform(2, gap)), float(rng.uniform(15, 30)), "entering") if rng.random() < 0.5 else None
        choice = int(rng.integers(4))
        p = _perception(k * DT, gap, c)
        assert np.array_equal(a.action(p, choice), b.action(p, choice))


def test_the_settings_are_checked_and_reach_the_env():
    cfg = parse_train_config({"kind": "rl", "action": "assisted-delayed", "reaction_time_s": 1.4, "brake_limit_mps2": 5,
                              "set": ["highway.duration=8", "twin.preroll_s=5", "highway.vehicles_count=12"]})
    table = cfg.action_config()
    assert table["reaction_time_s"] == 1.4 and table["brake_limit_mps2"] == 5.0
    assert "reaction_time_s" not in parse_train_config({"kind": "rl", "action": "assisted"}).action_config()
    env = DTHighwayEnv(config=cfg.env_config().to_dict())
    menu = env.action_type.choices.assisted
    assert menu is not None and menu.reaction_time_s == 1.4 and menu.brake_limit_mps2 == 5.0
    env.close()
    with pytest.raises(ConfigError, match="brake_limit_mps2"):
        parse_train_config({"kind": "rl", "action": "assisted-delayed", "brake_limit_mps2": 9})
    with pytest.raises(ValueError, match="assisted menu"):
        DiscreteMenu(reaction_time_s=1.0)
    tree = load_config(str(ROOT / "envs/highway-trial.toml"), [],
                       {"highway": {"action": {"type": "DiscreteDriver", "assist": True, "reaction_time_s": -1}}})
    with pytest.raises(ConfigError, match="reaction_time_s"):
        DTHighwayEnv(config=tree.to_dict())

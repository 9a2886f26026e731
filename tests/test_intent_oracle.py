"""The oracle of ``twin-eval --intent --oracle``: futures simulated from the whole state, with what is not yet
decided drawn afresh."""

import math

import numpy as np
import pytest
from highway_env.road.road import Road, RoadNetwork
from highway_env.vehicle.kinematics import Vehicle

from dt_highway.config import TrafficConfig
from dt_highway.evaluation.intent_oracle import (
    Oracle,
    OracleSettings,
    copy_road,
    intents_from_futures,
    rollout_changes,
)
from dt_highway.labels import AGGRESSIVE
from dt_highway.world.traffic import DriverPopulation, TrafficManager, cut_in_policy

DT = 1.0 / 15
HORIZONS = (1.0, 2.0, 3.0)


def _scene(next_attempt_s: float):
    """An ego at constant speed in lane 1 and an aggressive driver 6 m ahead of it in lane 0 whose next cut-in attempt
    opens at ``next_attempt_s`` (0: open now, the ego in its gap window)."""
    cfg = TrafficConfig(cut_in_ego_preference=1.0)
    road = Road(network=RoadNetwork.straight_road_network(3, speed_limit=30), np_random=np.random.default_rng(0))
    manager = TrafficManager(cfg, DriverPopulation(cfg, 1.0, np.random.default_rng(0)), np.random.default_rng(5))
    ego = Vehicle(road, road.network.get_lane(("0", "1", 1)).position(200.0, 0), 0.0, 25.0)
    ego.dt_id = 0
    ego.lane_index = ("0", "1", 1)
    driver = next(d for d in manager.population.drivers.values() if d.driver_type == AGGRESSIVE)
    cutter = manager.make_vehicle(road, driver, ("0", "1", 0), 200.0 + 6.0 + ego.LENGTH, 25.0)
    cutter.target_speed = 25.0
    road.vehicles += [ego, cutter]
    cutter.cut_in.next_attempt_s = next_attempt_s
    return road, manager, ego, cutter


def _p_into_ego_lane(road: Road, cutter, rollouts: int, seed: int = 0, settings: OracleSettings | None = None) -> np.ndarray:
    """P(the cutter moves right, into the ego's lane) within 1, 2, 3 s."""
    ids = np.array([cutter.dt_id])
    futures = rollout_changes(road, ids, max(HORIZONS), DT, rollouts, np.random.default_rng(seed), settings)
    p = intents_from_futures(futures, rollouts, ids, np.array([0]), HORIZONS)
    assert p.shape == (1, 3, 3) and np.allclose(p.sum(axis=2), 1.0)
    return p[0, :, 2]


def test_an_open_cut_in_attempt_is_foreseen_and_the_road_is_left_untouched():
    road, manager, ego, cutter = _scene(next_attempt_s=0.0)
    state = [(v.position.copy(), v.speed, v.lane_index) for v in road.vehicles] + [(cutter.target_lane_index, cutter.timer)]
    p = _p_into_ego_lane(road, cutter, rollouts=8)
    # decided in the driver's mind: every future has its centre in the ego's lane within 1 s (3 m/s sideways)
    assert np.all(p == 1.0)
    for (x0, s0, l0), v in zip(state, road.vehicles, strict=False):
        assert np.array_equal(x0, v.position) and (s0, l0) == (v.speed, v.lane_index)
    assert state[-1] == (cutter.target_lane_index, cutter.timer)
    assert manager.events == [] and cutter.cut_in.next_attempt_s == 0.0


@pytest.mark.parametrize("next_attempt_s", [1.0, 100.0])
def test_the_oracle_does_not_know_when_the_next_attempt_comes(next_attempt_s):
    # whether the attempt is drawn to open in 1 s or in 100 s, the oracle sees a driver with no open attempt, whose
    # next one comes at its rate: P(within 3 s) = 1 - exp(-rate 3 s), the aggressive driver's 4/min -> 0.18
    road, _, _, cutter = _scene(next_attempt_s=next_attempt_s)
    rate = cutter.cut_in.rate_per_min
    expected = 1.0 - math.exp(-rate * 3.0 / 60.0)
    p = _p_into_ego_lane(road, cutter, rollouts=300)
    assert 0.10 < expected < 0.30
    assert p[-1] == pytest.approx(expected, abs=0.09)  # ~4 standard errors of 300 futures; less: 3 s is a cut-in's onset
    assert cutter.cut_in.next_attempt_s == next_attempt_s


@pytest.mark.parametrize(("hide", "chasing"), [("attempts", False), ("attempts", True), ("unseen_attempts", False)])
def test_an_oracle_denied_the_attempts_does_not_know_that_one_is_open(hide, chasing):
    # the same open attempt that every future above carries out: hidden, it is a fresh Poisson wait like any other
    road, _, _, cutter = _scene(next_attempt_s=0.0)
    if chasing:
        cutter.cut_in.desired_speed_mps = 30.0  # its own speed, kept while it matches the ego's
    expected = 1.0 - math.exp(-cutter.cut_in.rate_per_min * 3.0 / 60.0)
    p = _p_into_ego_lane(road, cutter, rollouts=300, settings=OracleSettings(hide=frozenset({hide})))
    assert p[-1] == pytest.approx(expected, abs=0.09)
    assert cutter.cut_in.next_attempt_s == 0.0  # the simulator's driver still has it open


def test_an_attempt_seen_in_the_chase_stays_known_with_only_the_unseen_ones_hidden():
    road, _, _, cutter = _scene(next_attempt_s=0.0)
    cutter.cut_in.desired_speed_mps = 30.0
    p = _p_into_ego_lane(road, cutter, rollouts=8, settings=OracleSettings(hide=frozenset({"unseen_attempts"})))
    assert np.all(p == 1.0)


def test_what_the_oracle_hides_is_replaced_in_the_copies_only():
    road, _, ego, cutter = _scene(next_attempt_s=50.0)
    cutter.target_speed, cutter.timer = 31.0, 0.0
    x0, y0, v0 = float(cutter.position[0]), float(cutter.position[1]), float(cutter.speed)
    settings = OracleSettings(hide=frozenset({"positions", "speeds", "timers"}), sigma_position_m=1.0, sigma_speed_mps=0.2)
    copies = [next(v for v in copy_road(road, np.random.default_rng(k), settings).vehicles if v.dt_id == cutter.dt_id)
              for k in range(200)]
    dx = np.array([c.position[0] - x0 for c in copies])
    dv = np.array([c.speed - v0 for c in copies])
    assert 0.8 < dx.std() < 1.2 and 0.15 < dv.std() < 0.25 and abs(dx.mean()) < 0.2
    assert all(c.position[1] == y0 for c in copies)  # lanes stay as they are
    assert all(c.target_speed == c.speed for c in copies)  # the desired speed is taken to be the present one
    timers = np.array([c.timer for c in copies])
    assert timers.min() >= 0.0 and timers.max() < cutter.LANE_CHANGE_DELAY and timers.std() > 0.05
    ego_copy = next(v for v in copy_road(road, np.random.default_rng(0), settings).vehicles if v.dt_id == 0)
    assert np.array_equal(ego_copy.position, ego.position) and ego_copy.speed == ego.speed  # the ego is known
    assert (float(cutter.position[0]), cutter.speed, cutter.target_speed, cutter.timer) == (x0, v0, 31.0, 0.0)
    hideable = r"positions, speeds, timers, attempts, unseen_attempts"
    with pytest.raises(ValueError, match=rf"cannot hide minds \(it can hide: {hideable}\)"):
        OracleSettings(hide=frozenset({"minds"}))


def test_sides_are_counted_from_the_estimates_lane():
    futures = {7: [(0.5, 2), (2.5, 0)], 8: []}  # of 4 copies: one moved right at 0.5 s, one left at 2.5 s
    ids = np.array([7, 8, 9])
    p = intents_from_futures(futures, 4, ids, np.array([1, 1, 1]), HORIZONS)
    assert p[0].tolist() == [[0.75, 0.0, 0.25], [0.75, 0.0, 0.25], [0.5, 0.25, 0.25]]
    assert p[1].tolist() == p[2].tolist() == [[1.0, 0.0, 0.0]] * 3  # no change in any copy; no futures at all
    # the estimate already puts vehicle 7 in lane 2: the move there is no change, the one to lane 0 is two lanes away
    assert intents_from_futures(futures, 4, ids[:1], np.array([2]), HORIZONS)[0].tolist() == [[1.0, 0.0, 0.0]] * 3
    # 0.6 s after the futures were simulated: the move at 0.5 s is imminent, the one at 2.5 s comes within 2 s
    late = intents_from_futures(futures, 4, ids[:1], np.array([1]), HORIZONS, elapsed_s=0.6)[0]
    assert late.tolist() == [[0.75, 0.0, 0.25], [0.5, 0.25, 0.25], [0.5, 0.25, 0.25]]


def test_copies_draw_from_their_own_generator_and_report_nothing():
    road, manager, _, cutter = _scene(next_attempt_s=50.0)
    rng = np.random.default_rng(1)
    sim = copy_road(road, rng)
    twin = next(v for v in sim.vehicles if getattr(v, "dt_id", -1) == cutter.dt_id)
    assert twin is not cutter and twin.cut_in.rng is rng and cutter.cut_in.rng is not rng
    assert twin.cut_in.on_cut_in is None and twin.cut_in.on_lane_hop is None
    assert twin.cut_in.next_attempt_s != 50.0
    assert cutter.cut_in.on_cut_in is not None  # the simulator's own still reports to its traffic manager


def test_the_oracle_reuses_its_last_run_within_its_period_and_settings_are_checked():
    road, _, _, cutter = _scene(next_attempt_s=0.0)
    oracle = Oracle(OracleSettings(rollouts=2, period_s=0.2), HORIZONS)
    ids, lanes = np.array([cutter.dt_id]), np.array([0])
    first = oracle.estimate(road, 0.0, DT, ids, lanes)
    cutter.cut_in.next_attempt_s = math.inf  # would change the oracle's answer, were it run again
    assert np.array_equal(oracle.estimate(road, 0.1, DT, ids, lanes), first)
    assert oracle.estimate(road, 0.0, DT, np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)).shape == (0, 3, 3)
    with pytest.raises(ValueError, match="at least 1 rollout"):
        OracleSettings(rollouts=0)


TINY = ["--set", "highway.vehicles_count=10", "--set", "highway.duration=4", "--set", "twin.preroll_s=6",
        "--set", "highway.lanes_count=3", "--set", "traffic.population_size=40"]


def test_twin_eval_scores_the_oracle_on_the_same_estimates_and_its_mistakes_are_one_line_errors(capsys):
    import json

    from dt_highway.cli import main

    assert main(["twin-eval", "--intent", "--episodes", "1", "--oracle", "2", "--json", "--quiet", *TINY]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["oracle"] == {"rollouts": 2, "period_s": 0.2}
    models = result["models"]
    assert list(models) == ["learned", "physics", "oracle"]
    for a, b in zip(models["oracle"]["per_horizon"], models["learned"]["per_horizon"], strict=True):
        assert (a["n_samples"], a["n_positive"]) == (b["n_samples"], b["n_positive"]) and a["n_samples"] > 0
    assert main(["twin-eval", "--intent", "--episodes", "1", "--oracle", "2", "--quiet", *TINY]) == 0
    assert "oracle (the simulator's whole state" in capsys.readouterr().out
    assert main(["twin-eval", "--oracle", "4", "--quiet", *TINY]) == 2
    assert "--oracle goes with --intent" in capsys.readouterr().err
    assert main(["twin-eval", "--intent", "--sweep", "--oracle", "4", "--quiet", *TINY]) == 2
    assert "leave out --sweep" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["twin-eval", "--intent", "--oracle", "0", "--quiet", *TINY])
    assert "--oracle must be a finite number > 0 (got 0)" in capsys.readouterr().err
    assert main(["twin-eval", "--intent", "--oracle-hide", "timers", "--quiet", *TINY]) == 2
    assert "--oracle-hide goes with --oracle N" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["twin-eval", "--intent", "--oracle", "2", "--oracle-hide", "timers,minds", "--quiet", *TINY])
    err = capsys.readouterr().err
    assert "--oracle-hide takes a comma-separated list of positions, speeds, timers, attempts, unseen_attempts" in err


def test_twin_eval_names_what_the_oracle_was_denied(capsys, monkeypatch):
    import json

    from dt_highway.cli import main

    args = ["twin-eval", "--intent", "--episodes", "1", "--oracle", "2", "--oracle-hide", "timers, attempts", "--quiet", *TINY]
    assert main([*args, "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["oracle"] == {"rollouts": 2, "period_s": 0.2, "hide": ["attempts", "timers"]}
    assert main(args) == 0
    assert "oracle (the simulator's whole state but attempts, timers, 2 simulated futures" in capsys.readouterr().out
    # a hidden position is off by one fix of the uplink evaluated
    seen = []
    monkeypatch.setattr("dt_highway.evaluation.intent.evaluate_intent", lambda *a, oracle, **k: seen.append(oracle) or {})
    monkeypatch.setattr("dt_highway.evaluation.intent.format_intent", lambda result: [])
    noisy = ["--set", "twin.uplink.noise_sigma_m=3", "--set", "twin.uplink.speed_noise_sigma_mps=0.5"]
    assert main([*args, "--oracle-hide", "positions", *noisy]) == 0
    assert (seen[0].hide, seen[0].sigma_position_m, seen[0].sigma_speed_mps) == (frozenset({"positions"}), 3.0, 0.5)


# ----------------------------------------------------------------------------- from the twin's picture
def _picture(cars):
    """A twin picture of the ego (id 0, lane 1 at x = 200 m, 25 m/s) and ``cars``: ``(id, x, y, speed, lateral speed,
    p_aggressive)``."""
    from dt_highway.twin.intention import TwinPicture

    rows = [(0, 200.0, 4.0, 25.0, 0.0, 0.1), *cars]
    ids, x, y, v, vlat, pa = (np.array(c) for c in zip(*rows, strict=True))
    return TwinPicture(ids.astype(np.int64), 10.0, x, y, v, vlat, pa)


def _picture_oracle(rollouts=4):
    from dt_highway.twin.tagger import HighwayMap

    return Oracle(OracleSettings(rollouts=rollouts, start="picture"), HORIZONS, TrafficConfig(), HighwayMap(4.0, 3))


def test_a_picture_copy_puts_each_car_where_the_twin_sees_it_with_a_drawn_type():
    from dt_highway.evaluation.intent_oracle import picture_road
    from dt_highway.twin.tagger import HighwayMap

    network = RoadNetwork.straight_road_network(3, speed_limit=30)
    # car 7 moves toward lane 2 (1.2 m off lane 1's centre at 1 m/s); car 8 keeps lane 0; car 9 is surely aggressive
    picture = _picture([(7, 230.0, 5.2, 26.0, 1.0, 0.0), (8, 180.0, 0.1, 24.0, 0.05, 0.0), (9, 150.0, 8.0, 28.0, 0.0, 1.0)])
    road = picture_road(network, picture, HighwayMap(4.0, 3), TrafficConfig(), np.random.default_rng(0))
    by_id = {v.dt_id: v for v in road.vehicles}
    assert sorted(by_id) == [0, 7, 8, 9]
    for i, vid in enumerate(picture.vehicle_ids.tolist()):
        v = by_id[vid]
        assert v.position[0] == pytest.approx(picture.x_m[i]) and v.position[1] == pytest.approx(picture.y_m[i])
        assert v.speed == picture.speed_mps[i] and v.target_speed == picture.speed_mps[i]
    assert by_id[7].target_lane_index[2] == 2 and by_id[8].target_lane_index[2] == 0
    assert by_id[0].enable_lane_change is False and by_id[0].cut_in is None
    assert by_id[9].cut_in is not None and by_id[7].cut_in is None  # types drawn from the tagger's posterior
    assert by_id[9].LANE_CHANGE_DELAY == TrafficConfig().aggressive.lane_change_delay_s


def test_an_oracle_from_the_picture_foresees_a_move_under_way_and_not_a_car_keeping_its_lane():
    picture = _picture([(7, 230.0, 5.2, 25.0, 1.0, 0.0), (8, 120.0, 0.0, 25.0, 0.0, 0.0)])
    road = Road(network=RoadNetwork.straight_road_network(3, speed_limit=30), np_random=np.random.default_rng(0))
    oracle = _picture_oracle()
    ids, lanes = np.array([7, 8]), np.array([1, 0])
    p = oracle.estimate(road, 0.0, DT, ids, lanes, picture)
    assert np.all(p[0, :, 2] == 1.0)  # car 7 into lane 2 within 1 s, in every future
    assert np.all(p[1, :, 0] == 1.0)  # car 8 stays
    # within the period the last run is reused; without the ego's fixes the copies are not simulated
    assert np.array_equal(oracle.estimate(road, 0.1, DT, ids, lanes, picture), p)
    no_ego = _picture([(7, 230.0, 5.2, 25.0, 1.0, 0.0)])
    no_ego = type(no_ego)(*(a[1:] if isinstance(a, np.ndarray) else a for a in vars(no_ego).values()))
    assert np.all(_picture_oracle().estimate(road, 0.0, DT, ids, lanes, no_ego)[:, :, 0] == 1.0)
    with pytest.raises(ValueError, match="pass it"):
        _picture_oracle().estimate(road, 0.0, DT, ids, lanes)


def test_with_the_twins_estimate_a_picture_copy_draws_the_moves_under_way_from_it():
    from dataclasses import replace

    picture = _picture([(7, 330.0, 4.6, 25.0, 0.5, 0.0), (8, 120.0, 0.0, 25.0, 0.0, 0.0)])
    road = Road(network=RoadNetwork.straight_road_network(3, speed_limit=30), np_random=np.random.default_rng(0))
    ids, lanes = np.array([7, 8]), np.array([1, 0])
    assert np.all(_picture_oracle().estimate(road, 0.0, DT, ids, lanes, picture)[0, 2, 2] == 1.0)  # by the fixes: moving
    # the twin says car 7 (drifting right by its fixes) stays and car 8 moves right: the copies follow the twin
    moves = np.array([[0.0, 0.0], [0.0, 0.0], [0.0, 1.0]])
    p = _picture_oracle().estimate(road, 0.0, DT, ids, lanes, replace(picture, p_move=moves))
    assert np.all(p[0, :, 0] == 1.0) and np.all(p[1, 2, 2] == 1.0)
    half = np.array([[0.0, 0.0], [0.0, 0.0], [0.5, 0.0]])
    p = _picture_oracle(rollouts=40).estimate(road, 0.0, DT, ids, lanes, replace(picture, p_move=half))
    assert p[1, 2, 0] == 1.0  # lane 0 has no left neighbour: no move
    p = _picture_oracle(rollouts=40).estimate(road, 0.0, DT, ids, np.array([1, 1]),
                                              replace(picture, p_move=np.array([[0, 0], [0.5, 0], [0, 0]])))
    assert 0.25 < p[0, 2, 1] < 0.75  # car 7 moves left in about half of the copies


def test_a_driver_the_twin_judges_chasing_the_ego_has_its_attempt_open_in_the_copies():
    from dataclasses import replace

    from dt_highway.evaluation.intent_oracle import picture_road
    from dt_highway.twin.tagger import HighwayMap

    network = RoadNetwork.straight_road_network(3, speed_limit=30)
    # car 9 tagged normal but judged chasing; car 7 tagged aggressive, not chasing; car 8 neither
    picture = _picture([(7, 230.0, 0.0, 26.0, 0.0, 1.0), (8, 180.0, 0.0, 24.0, 0.0, 0.0), (9, 150.0, 8.0, 28.0, 0.0, 0.0)])
    chased = picture.with_chases(np.array([9, 7]), np.array([1.0, 0.0]))
    assert chased.p_chase is not None and chased.p_chase.tolist() == [0.0, 0.0, 0.0, 1.0]  # the ego: 0
    for seed in range(5):
        by_id = {v.dt_id: v for v in picture_road(network, chased, HighwayMap(4.0, 3), TrafficConfig(),
                                                 np.random.default_rng(seed)).vehicles}
        assert by_id[9].cut_in is not None and by_id[9].cut_in.next_attempt_s == 0.0  # aggressive, attempt open
        assert by_id[7].cut_in is not None and by_id[7].cut_in.next_attempt_s > 0.0  # a fresh wait
        assert by_id[8].cut_in is None
    # p_chase 0 everywhere draws exactly what a picture without it draws
    def state(p):
        road = picture_road(network, p, HighwayMap(4.0, 3), TrafficConfig(), np.random.default_rng(3))
        return [(v.dt_id, v.timer, v.cut_in.next_attempt_s if v.cut_in else None) for v in road.vehicles]
    assert state(picture) == state(replace(picture, p_chase=np.zeros(4)))
    half = picture.with_chases(np.array([8]), np.array([0.5]))
    opened = [next(v for v in picture_road(network, half, HighwayMap(4.0, 3), TrafficConfig(),
                                           np.random.default_rng(s)).vehicles if v.dt_id == 8).cut_in for s in range(200)]
    share = np.mean([c is not None and c.next_attempt_s == 0.0 for c in opened])
    assert 0.4 < share < 0.6 and all(c is None or c.next_attempt_s == 0.0 for c in opened)  # chasing = aggressive here


def test_the_simulators_open_attempt_goes_into_a_picture_copy_as_it_is():
    """``reveal`` ``attempts``: a driver with an open attempt is aggressive in every copy, its attempt open for as long
    as it has been (so it weaves when its patience runs out) and of its style; a near miss's brake under way and the
    lane kept after it carry over, in times from now; a driver without one draws as before."""
    from dt_highway.evaluation.intent_oracle import OpenAttempt, RevealedPicture, picture_road
    from dt_highway.twin.tagger import HighwayMap
    from dt_highway.world.traffic import BrakePlan

    policy = cut_in_policy(TrafficConfig(), 4.0, np.random.default_rng(0))
    policy.next_attempt_s = 12.0
    assert OpenAttempt.of(policy, clock_s=10.0) is None  # not open yet: a fresh draw gives the same
    policy.dangerous = True
    attempt = OpenAttempt.of(policy, clock_s=14.5)
    assert attempt == OpenAttempt(True, 2.5)
    policy.next_attempt_s, policy.committed_until_s = 30.0, 16.0
    policy.brake = BrakePlan(("0", "1", 1), 13.0, 20.0)
    braking = OpenAttempt.of(policy, clock_s=14.5)
    assert braking == OpenAttempt(True, None, BrakePlan(("0", "1", 1), -1.5, 20.0), 1.5)

    network = RoadNetwork.straight_road_network(3, speed_limit=30)
    picture = _picture([(7, 230.0, 0.0, 26.0, 0.0, 0.0), (8, 180.0, 0.0, 24.0, 0.0, 0.0), (9, 150.0, 8.0, 28.0, 0.0, 0.0)])
    given = RevealedPicture.of(picture, {7: attempt, 9: braking})
    for seed in range(5):
        by_id = {v.dt_id: v for v in picture_road(network, given, HighwayMap(4.0, 3), TrafficConfig(),
                                                 np.random.default_rng(seed)).vehicles}
        open_7, braking_9 = by_id[7].cut_in, by_id[9].cut_in
        assert open_7 is not None and open_7.next_attempt_s == -2.5 and open_7.dangerous  # tagged normal: 0
        assert open_7.brake is None and open_7.committed_until_s == 0.0
        assert braking_9 is not None and braking_9.brake == BrakePlan(("0", "1", 1), -1.5, 20.0)
        assert braking_9.committed_until_s == 1.5 and braking_9.next_attempt_s > 0.0  # the next one: a fresh draw,
        assert not braking_9.dangerous  # its style too (no near misses in these settings)
        assert by_id[8].cut_in is None
    # the near miss under way steers to its victim's lane (lane 1; the twin sees car 9 in lane 2, keeping it) and
    # keeps its brake plan, which starts once it is there
    by_id[9].act()
    assert by_id[9].target_lane_index[2] == 1 and by_id[9].cut_in.brake is not None
    # a driver chasing for longer than its patience gives up at once and weaves (here: into the empty lane 1)
    weaver = picture_road(network, RevealedPicture.of(picture, {8: OpenAttempt(False, 60.0)}), HighwayMap(4.0, 3),
                          TrafficConfig(), np.random.default_rng(0))
    car = next(v for v in weaver.vehicles if v.dt_id == 8)
    car.act()
    assert car.target_lane_index[2] == 1 and car.cut_in is not None and car.cut_in.next_attempt_s > 0.0


def test_the_picture_oracle_carries_the_twins_chase_detector_unless_hidden():
    from dt_highway.twin.tagger import HighwayMap

    assert _picture_oracle().chase is not None
    hidden = Oracle(OracleSettings(start="picture", hide=frozenset({"chases"})), HORIZONS, TrafficConfig(),
                    HighwayMap(4.0, 3))
    assert hidden.chase is None and Oracle(OracleSettings(), HORIZONS).chase is None


def test_the_twins_moves_come_from_its_intention_estimate():
    from dt_highway.config import IntentionConfig
    from dt_highway.twin.intention import IntentionEstimator, twin_picture
    from dt_highway.twin.store import FixStore
    from dt_highway.twin.tagger import HighwayMap
    from dt_highway.twin.uplink import GnssFix

    store = FixStore(30.0)
    store.add([GnssFix(vid, t / 10, 25.0 * t / 10 + 10 * vid, 4.0 * vid, 25.0, 0.0, t / 10 + 0.1)
               for vid in (0, 1) for t in range(80, 101)])
    table = IntentionEstimator(IntentionConfig(), HighwayMap(4.0, 3)).estimate(store, {}, 10.0)
    picture = twin_picture(store, {}, 10.0).with_moves(table)
    assert picture.p_move is not None and picture.p_move.shape == (2, 2)
    assert np.array_equal(picture.p_move[0], [0.0, 0.0])  # the ego is not judged
    assert np.allclose(picture.p_move[1], table.probs[0, 0, 1:])


def test_picture_settings_are_checked():
    with pytest.raises(ValueError, match="cannot start from 'minds'"):
        OracleSettings(start="minds")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"starting from the twin's picture cannot hide speeds \(it can hide: chases\)"):
        OracleSettings(start="picture", hide=frozenset({"speeds"}))
    with pytest.raises(ValueError, match=r"starting from the simulator's state cannot hide chases"):
        OracleSettings(hide=frozenset({"chases"}))
    with pytest.raises(ValueError, match="needs the traffic settings and the map"):
        Oracle(OracleSettings(start="picture"), HORIZONS)
    with pytest.raises(ValueError, match="only the oracle starting from the twin's picture can be given"):
        OracleSettings(reveal=frozenset({"chases"}))
    with pytest.raises(ValueError, match=r"cannot be given the simulator's minds \(it can be given: chases, lateral, types, "
                                         r"positions, attempts\)"):
        OracleSettings(start="picture", reveal=frozenset({"minds"}))
    with pytest.raises(ValueError, match="chases cannot be both hidden and given"):
        OracleSettings(start="picture", hide=frozenset({"chases"}), reveal=frozenset({"chases"}))
    with pytest.raises(ValueError, match="attempts cannot be given with chases hidden"):
        OracleSettings(start="picture", hide=frozenset({"chases"}), reveal=frozenset({"attempts"}))


def test_a_picture_given_parts_of_the_simulators_state_has_them():
    """``--oracle-reveal``: the picture's chases are the simulator's chase state (no detector is loaded), its lateral
    positions, lateral speeds and moves the simulator's; so are the types, the positions along the road and speeds,
    and the open attempts when given; the rest stays the twin's."""
    from dt_highway.config import load_config
    from dt_highway.env import DTHighwayEnv
    from dt_highway.evaluation.intent import _picture
    from dt_highway.evaluation.intent_oracle import OpenAttempt
    from dt_highway.twin.chase import ChaseDetector
    from dt_highway.twin.tagger import HighwayMap
    from dt_highway.world.traffic import driver_type, vehicle_id

    for given in ("chases", "attempts"):
        assert Oracle(OracleSettings(start="picture", reveal=frozenset({given})), HORIZONS, TrafficConfig(),
                      HighwayMap(4.0, 3)).chase is None
    cfg = load_config(None, ["highway.vehicles_count=10", "highway.duration=3", "twin.preroll_s=8",
                             "traffic.population_size=40"])
    env = DTHighwayEnv(config=cfg.to_dict())
    env.reset(seed=3)
    env.step(1)
    twin = env.twin
    assert twin is not None and twin.intent_table is not None
    plain = _picture(env, twin.intent_table, None)
    on_road = {vehicle_id(v): v for v in env.road.vehicles}
    ids = [i for i in plain.vehicle_ids.tolist() if i in on_road and i != 0]
    chaser, mover = on_road[ids[0]], on_road[ids[1]]
    if chaser.cut_in is None:  # a normal driver here: give it an aggressive driver's cut-in policy
        chaser.cut_in = cut_in_policy(TrafficConfig(), 4.0, np.random.default_rng(0))
    chaser.cut_in.desired_speed_mps = 20.0  # an open attempt chasing the ego, as the world sets it
    mover.target_lane_index = ("0", "1", int(mover.lane_index[2]) + (1 if mover.lane_index[2] == 0 else -1))
    given = _picture(env, twin.intent_table, None, frozenset({"chases", "lateral"}))
    everything = _picture(env, twin.intent_table, None, frozenset({"attempts", "types", "positions"}))
    detected = _picture(env, twin.intent_table, ChaseDetector.load(), frozenset({"types"}))
    chaser.cut_in.next_attempt_s = chaser.clock_s - 1.0  # open for 1 s
    attempts = _picture(env, twin.intent_table, None, frozenset({"attempts"})).attempts
    env.close()
    assert given.p_chase is not None and given.p_move is not None and plain.p_move is not None
    k = {vid: i for i, vid in enumerate(given.vehicle_ids.tolist())}
    assert given.p_chase[k[ids[0]]] == 1.0 and given.p_chase.sum() >= 1.0
    assert all(given.p_chase[k[vid]] == float(getattr(on_road[vid], "cut_in", None) is not None
                                              and on_road[vid].cut_in.desired_speed_mps is not None) for vid in ids)
    side = int(mover.target_lane_index[2]) - int(mover.lane_index[2])
    assert list(given.p_move[k[ids[1]]]) == [float(side < 0), float(side > 0)]
    for vid in ids:
        v = on_road[vid]
        assert given.y_m[k[vid]] == float(v.position[1])
        assert given.lateral_speed_mps[k[vid]] == pytest.approx(float(v.speed) * math.sin(float(v.heading)))
    assert not np.array_equal(given.y_m, plain.y_m)  # the fixes' lateral positions carry their noise
    assert np.array_equal(given.x_m, plain.x_m) and np.array_equal(given.p_aggressive, plain.p_aggressive)
    # types, positions and open attempts (which give the chases too); the lateral states stay the twin's
    assert everything.p_chase is not None and np.array_equal(everything.p_chase, given.p_chase)
    assert np.array_equal(everything.y_m, plain.y_m)
    for vid in ids:
        v = on_road[vid]
        assert everything.p_aggressive[k[vid]] == float(driver_type(v) == AGGRESSIVE)
        assert (everything.x_m[k[vid]], everything.speed_mps[k[vid]]) == (float(v.position[0]), float(v.speed))
    # with only the types given, the detector's verdicts stay
    assert detected.p_chase is not None and np.array_equal(detected.p_aggressive, everything.p_aggressive)
    assert detected.p_chase.max() > 0 and not np.array_equal(detected.p_chase, given.p_chase)
    assert not np.array_equal(everything.x_m, plain.x_m) and not np.array_equal(everything.p_aggressive,
                                                                                plain.p_aggressive)
    assert attempts[ids[0]] == OpenAttempt(chaser.cut_in.dangerous, pytest.approx(1.0))
    in_play = {vid for vid, v in on_road.items() if getattr(v, "cut_in", None) is not None
               and (v.clock_s >= v.cut_in.next_attempt_s or v.cut_in.brake is not None
                    or v.cut_in.committed_until_s > v.clock_s)}
    assert set(attempts) == in_play and len(in_play) < sum(getattr(v, "cut_in", None) is not None
                                                           for v in on_road.values())  # the others: fresh draws


def test_twin_eval_scores_the_oracle_from_the_picture_and_its_mean_with_the_model(capsys):
    import json

    from dt_highway.cli import main

    args = ["twin-eval", "--intent", "--episodes", "1", "--oracle", "2", "--oracle-from", "picture", "--quiet", *TINY]
    assert main([*args, "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["oracle"] == {"rollouts": 2, "period_s": 0.2, "start": "picture"}
    assert list(result["models"]) == ["learned", "physics", "oracle", "learned+oracle"]
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "oracle (the twin's picture and its chase detector's verdicts simulated with the simulator's driver models" in out
    assert "learned+oracle (the mean of the two estimates)" in out
    assert main(["twin-eval", "--intent", "--oracle-from", "picture", "--quiet", *TINY]) == 2
    assert "--oracle-from goes with --oracle N" in capsys.readouterr().err
    assert main([*args, "--oracle-hide", "timers"]) == 2
    assert "--oracle-hide timers goes with --oracle-from state" in capsys.readouterr().err
    assert main([*args, "--oracle-hide", "chases", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["oracle"]["hide"] == ["chases"]
    assert main([*args[:6], "--oracle-hide", "chases", "--quiet", *TINY]) == 2
    assert "--oracle-hide chases goes with --oracle-from picture" in capsys.readouterr().err
    assert main(["twin-eval", "--oracle-from", "picture", "--quiet", *TINY]) == 2
    assert "--oracle-from goes with --intent" in capsys.readouterr().err
    assert main([*args, "--oracle-reveal", "chases,lateral", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["oracle"]["reveal"] == ["chases", "lateral"]
    assert main([*args, "--oracle-reveal", "chases"]) == 0
    assert "the twin's picture with the simulator's chases of the ego simulated" in capsys.readouterr().out
    assert main([*args, "--oracle-reveal", "attempts,types"]) == 0
    assert ("the twin's picture with the simulator's open cut-in attempts and driver types simulated"
            in capsys.readouterr().out)
    assert main([*args[:6], "--oracle-reveal", "chases", "--quiet", *TINY]) == 2
    assert "--oracle-reveal goes with --oracle-from picture" in capsys.readouterr().err
    assert main([*args, "--oracle-reveal", "chases", "--oracle-hide", "chases"]) == 2
    assert "--oracle-hide and --oracle-reveal both name chases: choose one" in capsys.readouterr().err
    assert main([*args, "--oracle-reveal", "attempts", "--oracle-hide", "chases"]) == 2
    assert "--oracle-reveal attempts gives the chases too" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main([*args, "--oracle-reveal", "minds"])
    assert ("--oracle-reveal takes a comma-separated list of chases, lateral, types, positions, attempts (got 'minds')"
            in capsys.readouterr().err)
    assert main(["twin-eval", "--oracle-reveal", "chases", "--quiet", *TINY]) == 2
    assert "--oracle-reveal goes with --intent" in capsys.readouterr().err

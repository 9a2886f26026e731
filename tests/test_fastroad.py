"""FastRoad gives highway-env's Road results: the same neighbours, collisions and trajectories."""

import gymnasium as gym
import numpy as np
from highway_env.road.road import Road, RoadNetwork
from highway_env.vehicle.kinematics import Vehicle

import dt_highway  # noqa: F401  (registers the env)
from dt_highway.config import load_config
from dt_highway.world.road import FastRoad


def _roads(seed):
    rng = np.random.default_rng(seed)
    net = RoadNetwork.straight_road_network(3, length=1000.0)
    fast, stock = FastRoad(network=net), Road(network=net)
    vehicles = []
    for k in range(40):
        lane = int(rng.integers(3))
        x = float(rng.choice([100.0, 130.0])) if k < 6 else float(rng.uniform(0, 400))  # ties at 100 and 130 m
        y = lane * 4.0 + float(rng.normal(0, 0.8))  # some between lanes
        vehicles.append(Vehicle(fast, [x, y], 0.0, 25.0))
    fast.vehicles = vehicles
    stock.vehicles = vehicles
    return fast, stock, vehicles


def test_neighbours_are_highway_envs_ties_included():
    for seed in range(5):
        fast, stock, vehicles = _roads(seed)
        for in_act in (False, True):  # built per search, and the per-lane index shared by an act phase
            fast._in_act, fast._index = in_act, None
            for v in vehicles:
                for lane in range(3):
                    idx = ("0", "1", lane)
                    assert fast.neighbour_vehicles(v, idx) == stock.neighbour_vehicles(v, idx)
                assert fast.neighbour_vehicles(v) == stock.neighbour_vehicles(v)
            # a vehicle that is not on the road (a probe) finds the same neighbours too
            probe = Vehicle(fast, [130.0, 4.0], 0.0, 20.0)
            assert fast.neighbour_vehicles(probe, ("0", "1", 1)) == stock.neighbour_vehicles(probe, ("0", "1", 1))
        fast._in_act, fast._index = False, None


def _run(fast: bool, extra=(), seconds=10.0):
    cfg = load_config("envs/highway-trial.toml", [f"traffic.fast_road={str(fast).lower()}", "highway.vehicles_count=30",
                                                   "twin.preroll_s=5", f"highway.duration={seconds}", *extra],
                      {"highway": {"action": {"type": "Driver"}}})
    env = gym.make("dt-highway-v0", config=cfg.to_dict())
    u = env.unwrapped
    env.reset(seed=2)
    crashed_at = None
    for k in range(int(seconds * cfg.highway.policy_frequency)):
        _, _, term, trunc, _ = env.step(np.array([3.0, 0.0]))  # full throttle: the ego runs into its leader
        if u.vehicle.crashed and crashed_at is None:
            crashed_at = k
        if term or trunc:
            break
    return {getattr(v, "dt_id", i): (v.position.copy(), v.speed, v.crashed) for i, v in enumerate(u.road.vehicles)}, crashed_at


def test_trajectories_and_collisions_are_the_same_as_with_highway_envs_road():
    """The fast core against highway-env's Road (and, for plain traffic, its IDMVehicle):
    typed drivers use the same vehicle code either way, so their runs are bit-identical;
    plain IDM traffic is highway-env's arithmetic against our float version: within 1e-6 m."""
    for extra, tolerance in (((), 0.0), (("traffic.driver_types=false",), 1e-6)):
        fast, crash_fast = _run(True, extra)
        stock, crash_stock = _run(False, extra)
        assert crash_fast == crash_stock and crash_fast is not None  # the collision happens, at the same step
        assert fast.keys() == stock.keys()
        for vid in fast:
            assert np.abs(fast[vid][0] - stock[vid][0]).max() <= tolerance
            assert abs(fast[vid][1] - stock[vid][1]) <= tolerance and fast[vid][2] == stock[vid][2]


def test_plain_idm_traffic_follows_stock_highway_v0_exactly():
    """Driver types off: the same seed gives stock highway-v0's vehicles and trajectories (twin on, FastRoad)."""
    settings = {"vehicles_count": 50, "lanes_count": 4, "simulation_frequency": 15, "policy_frequency": 1, "duration": 40}
    stock = gym.make("highway-v0", config=settings).unwrapped
    ours = gym.make("dt-highway-v0", config={"highway": {**settings, "road_length": 10000.0},
                                             "traffic": {"driver_types": False}}).unwrapped
    stock.reset(seed=1)
    ours.reset(seed=1)
    assert ours.twin is not None and isinstance(ours.road, FastRoad)
    for _ in range(8):
        stock.step(1)
        ours.step(1)
        a = np.array([v.position for v in stock.road.vehicles])
        b = np.array([v.position for v in ours.road.vehicles])
        assert a.shape == b.shape and np.abs(a - b).max() <= 1e-6
    assert ours.twin_view is not None  # the twin ran all along


def test_the_broad_phase_skips_only_pairs_highway_env_rules_out():
    rng = np.random.default_rng(0)
    net = RoadNetwork.straight_road_network(3, length=1000.0)
    road = FastRoad(network=net)
    kept = 0
    for _ in range(20):
        vs = [Vehicle(road, [float(rng.uniform(0, 60)), float(rng.uniform(-2, 10))], float(rng.normal(0, 0.2)),
                      float(rng.uniform(-5, 40))) for _ in range(30)]
        close = FastRoad.close_pairs(vs, 1 / 15)
        for i, a in enumerate(vs):
            for j, b in enumerate(vs):
                if i != j and not close[i, j]:
                    inter, will, transition = a._is_colliding(b, 1 / 15)
                    assert not inter and not will and not transition.any()
        kept += int(close.sum()) - len(vs)
    assert kept > 0  # some pairs do get highway-env's full check

"""The fast core's pieces against highway-env's own: vehicles, collisions, observation, twin store."""

import math

import numpy as np
from highway_env.envs.common.observation import KinematicObservation
from highway_env.road.road import Road, RoadNetwork
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.kinematics import Vehicle

import dt_highway  # noqa: F401  (registers the env)
from dt_highway.env import DTHighwayEnv
from dt_highway.twin import FixStore, GnssFix, HighwayMap
from dt_highway.twin.tagger import median
from dt_highway.world.observation import FastKinematicObservation
from dt_highway.world.road import BROAD_PHASE_MARGIN_M, FastRoadNetwork
from dt_highway.world.vehicle import FastIDMVehicle, surely_apart

DT = 1 / 15


def test_surely_apart_only_skips_pairs_highway_env_finds_apart():
    rng = np.random.default_rng(0)
    road = Road(network=RoadNetwork.straight_road_network(3, length=1000.0))
    skipped = 0
    for _ in range(20000):
        a = Vehicle(road, [500.0, float(rng.uniform(0, 8))], float(rng.normal(0, 0.4)), float(rng.uniform(-5, 40)))
        b = Vehicle(road, [500.0 + float(rng.uniform(-9, 9)), float(rng.uniform(0, 8))],
                    float(rng.choice([rng.normal(0, 0.4), rng.uniform(-math.pi, math.pi)])), float(rng.uniform(-5, 40)))
        if surely_apart(a, b, DT, BROAD_PHASE_MARGIN_M):
            skipped += 1
            intersecting, will_intersect, _ = a._is_colliding(b, DT)
            assert not intersecting and not will_intersect
    assert skipped > 8000  # it does rule out most near pairs (the rest get highway-env's full check)


def _twin_roads(seed: int, n: int = 30):
    """The same random traffic twice: highway-env's IDMVehicle and our FastIDMVehicle."""
    rng = np.random.default_rng(seed)
    net = RoadNetwork.straight_road_network(4, length=2000.0)
    stock, fast = Road(network=net), Road(network=FastRoadNetwork.of(net))
    for k in range(n):
        lane, x = int(rng.integers(4)), float(rng.uniform(0, 400))
        y = lane * 4.0 + float(rng.normal(0, 0.5))
        h, v, target = float(rng.normal(0, 0.03)), float(rng.uniform(15, 32)), float(rng.uniform(20, 32))
        timer, delta = float(rng.uniform(0, 1.2)), float(rng.uniform(3.5, 4.5)) if k % 2 else 4.0
        for road, cls in ((stock, IDMVehicle), (fast, FastIDMVehicle)):
            veh = cls(road, [x, y], h, v, target_speed=target, timer=timer)
            veh.DELTA = delta
            road.vehicles.append(veh)
    return stock, fast


def test_fast_idm_decides_and_moves_as_highway_env():
    lane_changes = 0
    for seed in range(4):
        stock, fast = _twin_roads(seed)
        for _ in range(45):  # 3 s: MOBIL fires, lane changes start
            for road in (stock, fast):
                road.act()
            for a, b in zip(stock.vehicles, fast.vehicles, strict=True):
                assert a.target_lane_index == b.target_lane_index
                assert abs(a.action["steering"] - b.action["steering"]) <= 1e-9
                assert abs(a.action["acceleration"] - b.action["acceleration"]) <= 1e-9
            lane_changes += sum(v.lane_index != v.target_lane_index for v in fast.vehicles)
            for road in (stock, fast):
                road.step(DT)
            for a, b in zip(stock.vehicles, fast.vehicles, strict=True):
                assert np.abs(a.position - b.position).max() <= 1e-9 and abs(a.speed - b.speed) <= 1e-9
                assert a.lane_index == b.lane_index and a.crashed == b.crashed
    assert lane_changes > 0  # MOBIL's decisions were compared, not only car following


def test_fast_kinematics_observation_is_highway_envs_bit_for_bit():
    options = [{}, {"absolute": True}, {"see_behind": True, "vehicles_count": 10}, {"normalize": False},
               {"clip": False}, {"features": ["presence", "x", "y", "vx", "vy", "heading", "cos_h", "sin_h", "cos_d",
                                              "sin_d", "long_off", "lat_off", "ang_off"]},
               {"features_range": {"x": [-100, 100], "y": [-12, 12], "vx": [-20, 20], "vy": [-20, 20]}}]
    env = DTHighwayEnv(config={"highway": {"duration": 100}})
    env.reset(seed=3)
    assert isinstance(env.observation_type, FastKinematicObservation)
    for step in range(12):
        env.step(step % 5)
        for opt in options:
            want, got = KinematicObservation(env, **opt).observe(), FastKinematicObservation(env, **opt).observe()
            assert got.dtype == want.dtype and got.shape == want.shape and np.array_equal(got, want)
    env.close()


def test_store_keeps_sorted_bounded_histories_that_never_change_once_handed_out():
    rng = np.random.default_rng(2)
    store = FixStore(window_s=5.0)
    reference: list[tuple] = []
    handed_out = []
    for k in range(600):
        t = k * 0.1 + float(rng.choice([0.0, -0.35, -0.05]))  # some arrive out of order
        fix = GnssFix(1, t, 10.0 * t, float(rng.normal()), 25.0, 0.0, t)
        store.add([fix])
        reference.append((fix.t_s, fix.x_m, fix.y_m, fix.speed_mps, fix.heading_rad))
        reference.sort(key=lambda r: r[0])  # stable, as the store's bisect_right insertion
        newest = reference[-1][0]
        reference = [r for r in reference if r[0] >= newest - 5.0]
        h = store.history(1)
        assert np.array_equal(h, np.array(reference)) and not h.flags.writeable
        if k % 50 == 0:
            handed_out.append((h, h.copy()))
    for h, copy in handed_out:
        assert np.array_equal(h, copy)
    assert store.n_fixes() == len(reference)


def test_median_and_lane_of_one_are_numpys():
    rng = np.random.default_rng(4)
    for n in list(range(1, 30)) * 30:
        a = np.round(rng.normal(size=n), int(rng.integers(0, 3)))
        if rng.random() < 0.05:
            a[rng.integers(n)] = np.nan
        want = float(np.median(a))
        assert median(a) == want or (math.isnan(median(a)) and math.isnan(want))
    road = HighwayMap(4.0, 4, first_lane_y_m=0.0)
    for y in [*rng.uniform(-10, 30, 2000), 2.0, 6.0, -2.0, 10.0, 14.0, 18.0, -6.0]:
        assert road.lane_of_one(float(y)) == int(road.lane_of(float(y)))


class _WideBerth(Vehicle):
    """A vehicle with its own collision check: contact within its length plus 0.5 m."""

    def _is_colliding(self, other, dt):
        close = bool(np.linalg.norm(other.position - self.position) < self.LENGTH + 0.5)
        return close, False, np.zeros(2)


def test_a_vehicle_with_its_own_collision_check_gets_it():
    from dt_highway.world.road import FastRoad

    crashed = {}
    for name, cls in (("stock", Road), ("fast", FastRoad)):
        road = cls(network=RoadNetwork.straight_road_network(2, length=1000.0))
        a, b = _WideBerth(road, [100.0, 0.0], 0.0, 20.0), Vehicle(road, [105.3, 0.0], 0.0, 20.0)
        road.vehicles = [a, b]
        road.step(DT)
        crashed[name] = (a.crashed, b.crashed)
    assert crashed["fast"] == crashed["stock"] == (True, True)

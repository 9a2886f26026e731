"""The paper's near-miss cut-in (Fig. 5): from just ahead in the next lane into the ego's lane, then a brake."""

import math

import numpy as np
import pytest
from highway_env.road.road import Road, RoadNetwork
from highway_env.vehicle.kinematics import Vehicle

from dt_highway.config import TrafficConfig
from dt_highway.labels import AGGRESSIVE
from dt_highway.world.traffic import DriverPopulation, TrafficManager

DT = 1.0 / 15


def _scene(share: float, gap_m: float = 4.0, cutter_speed: float = 25.0, ego_speed: float = 25.0,
           brake_onset: str = "in_lane"):
    """An ego at constant speed in lane 1 and one aggressive driver just ahead of it in lane 0, whose cut-in attempt
    is due now."""
    cfg = TrafficConfig(dangerous={"share": share, "brake_onset": brake_onset}, cut_in_ego_preference=1.0)
    road = Road(network=RoadNetwork.straight_road_network(3, speed_limit=30), np_random=np.random.default_rng(0))
    manager = TrafficManager(cfg, DriverPopulation(cfg, 1.0, np.random.default_rng(0)), np.random.default_rng(5))
    ego = Vehicle(road, road.network.get_lane(("0", "1", 1)).position(200.0, 0), 0.0, ego_speed)
    ego.dt_id = 0
    ego.lane_index = ("0", "1", 1)
    driver = next(d for d in manager.population.drivers.values() if d.driver_type == AGGRESSIVE)
    x = 200.0 + gap_m + ego.LENGTH
    cutter = manager.make_vehicle(road, driver, ("0", "1", 0), x, cutter_speed)
    cutter.target_speed = cutter_speed
    road.vehicles += [ego, cutter]
    assert cutter.cut_in is not None
    cutter.cut_in.schedule(0.0)  # draws the style with the policy's rng
    cutter.cut_in.next_attempt_s = 0.0
    return road, manager, ego, cutter


def _run(road: Road, manager: TrafficManager, ego: Vehicle, cutter: Vehicle, seconds: float) -> list[dict[str, float]]:
    rows = []
    for k in range(int(round(seconds / DT))):
        ego.action = {"steering": 0.0, "acceleration": 0.0}  # the ego does not react: what a surprised driver does first
        road.act()
        ego.action = {"steering": 0.0, "acceleration": 0.0}
        road.step(DT)
        manager.time_s = (k + 1) * DT
        gap = cutter.position[0] - ego.position[0] - (cutter.LENGTH + ego.LENGTH) / 2
        closing = ego.speed - cutter.speed
        rows.append({"t": (k + 1) * DT, "lane": cutter.lane_index[2], "target": cutter.target_lane_index[2],
                     "speed": cutter.speed, "accel": cutter.action["acceleration"], "gap": gap,
                     "ttc": gap / closing if closing > 0 and cutter.lane_index == ego.lane_index else math.inf})
    return rows


def test_a_dangerous_cut_in_enters_the_ego_lane_then_brakes_so_that_the_ego_closes():
    road, manager, ego, cutter = _scene(share=1.0)
    assert cutter.cut_in.dangerous
    rows = _run(road, manager, ego, cutter, 3.0)
    events = [e for e in manager.events if e.kind == "cut_in"]
    assert [(e.vehicle_id, e.other_id, e.style) for e in events] == [(cutter.dt_id, 0, "dangerous")]
    entered = next(r for r in rows if r["lane"] == 1)
    assert entered["t"] < 1.5  # at the aggressive driver's 3 m/s lateral speed
    # from the step after its centre crossed into the ego's lane (the command is taken before the move)
    braking = [r for r in rows if r["lane"] == 1 and entered["t"] < r["t"] <= entered["t"] + 1.0]
    assert len(braking) == 15 and all(r["accel"] == pytest.approx(-3.0) for r in braking)  # traffic.dangerous.brake_mps2
    # the ego (25 m/s, no reaction) closes on it: TTC drops below 2 s within 2 s of the lane change
    assert min(r["ttc"] for r in rows) < 2.0


def test_with_the_brake_at_the_lane_change_the_cutter_enters_the_lane_already_slower():
    road, manager, ego, cutter = _scene(share=1.0, gap_m=6.0, brake_onset="lane_change")
    rows = _run(road, manager, ego, cutter, 3.0)
    started = next(r for r in rows if r["target"] == 1)
    entered = next(r for r in rows if r["lane"] == 1)
    before = [r for r in rows if started["t"] <= r["t"] < entered["t"]]
    assert len(before) >= 5 and all(r["accel"] == pytest.approx(-3.0) for r in before)  # braking while still beside
    # in the ego's lane it is already 3 m/s^2 x DT x (steps before + the step that took it across) slower than the ego
    assert 25.0 - entered["speed"] == pytest.approx(3.0 * DT * (len(before) + 1), abs=0.01)
    assert entered["ttc"] < 10.0  # the ego closes from the first moment
    road, manager, ego, cutter = _scene(share=1.0, gap_m=30.0, brake_onset="lane_change")
    cutter.cut_in.dangerous_gap_m = (20.0, 40.0)  # room enough for the whole brake without a crash
    rows = _run(road, manager, ego, cutter, 6.0)
    lowest = min(r["speed"] for r in rows)
    assert lowest == pytest.approx(25.0 - 4.0, abs=0.25)  # and the brake still ends at the victim's speed minus the drop
    assert cutter.cut_in.brake is None and all(r["target"] == 1 for r in rows if r["t"] > 1.0)
    in_lane = TrafficConfig(dangerous={"share": 1.0})
    assert in_lane.dangerous.brake_onset == "in_lane"
    assert in_lane.model_dump()["dangerous"].get("brake_onset", "in_lane") == "in_lane"
    with pytest.raises(ValueError, match="brake_onset"):
        TrafficConfig(dangerous={"brake_onset": "early"})


def test_the_brake_ends_at_the_victims_speed_minus_the_drop_and_the_driver_keeps_the_lane():
    road, manager, ego, cutter = _scene(share=1.0, gap_m=30.0)
    cutter.cut_in.dangerous_gap_m = (20.0, 40.0)  # room enough for the whole brake without a crash
    rows = _run(road, manager, ego, cutter, 6.0)
    lowest = min(r["speed"] for r in rows)
    assert lowest == pytest.approx(25.0 - 4.0, abs=0.25)  # traffic.dangerous.speed_drop_mps below the victim
    assert all(r["target"] == 1 for r in rows if r["t"] > 1.0)  # no abort, no weaving on
    braked = [r["t"] for r in rows if r["accel"] == pytest.approx(-3.0)]
    assert cutter.cut_in.brake is None  # done: the lane is kept KEEP_LANE_S after the brake's end
    assert cutter.cut_in.committed_until_s == pytest.approx(braked[-1] + cutter.cut_in.KEEP_LANE_S, abs=2 * DT)


def test_a_victim_much_faster_or_slower_is_not_a_dangerous_candidate():
    road, manager, ego, cutter = _scene(share=1.0, ego_speed=22.0, cutter_speed=25.0)
    _run(road, manager, ego, cutter, 0.5)
    assert not [e for e in manager.events if e.kind == "cut_in"]  # 3 m/s apart > MATCHED_SPEED_MPS


def test_share_zero_is_todays_gentle_cut_in():
    road, manager, ego, cutter = _scene(share=0.0, gap_m=6.0)
    assert not cutter.cut_in.dangerous
    rows = _run(road, manager, ego, cutter, 3.0)
    assert [e.style for e in manager.events if e.kind == "cut_in"] == ["gentle"]
    assert all(r["accel"] > -3.0 for r in rows)  # no imposed brake
    assert TrafficConfig().model_dump().get("dangerous") is None  # not in dumped configs at its default
    assert TrafficConfig(dangerous={"share": 0.5}).model_dump()["dangerous"]["share"] == 0.5

"""2-D TTC and PET: hand-computed cases, and a randomized cross-check of the separating-axis
TTC against two independent oracles (Jiao's corner-to-edge ray casting, and brute-force time
stepping with a polygon test that does not use separating axes)."""

import math
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
from highway_env.vehicle.kinematics import Vehicle

from dt_highway.metrics.ttc2d import Footprint, min_ttc_2d, overlapping, post_encroachment_time, ttc_2d


def car(x, y, vx=0.0, vy=0.0, heading=0.0, length=5.0, width=2.0):
    return Footprint(x, y, length, width, heading, vx, vy)


# ----------------------------------------------------------------------- independent oracles
def corners(fp, t=0.0):
    """CCW corners of a footprint at time t (rotation matrix times the local corners)."""
    c, s = math.cos(fp.heading_rad), math.sin(fp.heading_rad)
    rot = np.array([[c, -s], [s, c]])
    local = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * [fp.length_m / 2, fp.width_m / 2]
    centre = np.array([fp.x_m + fp.vx_mps * t, fp.y_m + fp.vy_mps * t])
    return local @ rot.T + centre


def cross(u, v):
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]


def inside(points, poly):
    """Points (..., P, 2) inside or on the CCW convex polygon (..., 4, 2): (..., P) bool."""
    edges = np.roll(poly, -1, axis=-2) - poly
    rel = points[..., :, None, :] - poly[..., None, :, :]
    return np.all(cross(edges[..., None, :, :], rel) >= 0, axis=-1)


def edges_cross(pa, pb):
    """Whether some edge of polygon pa properly crosses some edge of pb: (...,) bool."""
    a0, a1 = pa[..., :, None, :], np.roll(pa, -1, axis=-2)[..., :, None, :]
    b0, b1 = pb[..., None, :, :], np.roll(pb, -1, axis=-2)[..., None, :, :]
    d1, d2 = cross(a1 - a0, b0 - a0), cross(a1 - a0, b1 - a0)
    d3, d4 = cross(b1 - b0, a0 - b0), cross(b1 - b0, a1 - b0)
    return np.any((d1 * d2 < 0) & (d3 * d4 < 0), axis=(-2, -1))


def intersect(pa, pb):
    """Convex polygons intersect iff a corner of one is in the other or two edges cross."""
    return np.any(inside(pa, pb), axis=-1) | np.any(inside(pb, pa), axis=-1) | edges_cross(pa, pb)


def point_segment_distance(p, q0, q1):
    e = q1 - q0
    s = np.clip(np.dot(p - q0, e) / np.dot(e, e), 0.0, 1.0)
    return float(np.linalg.norm(p - (q0 + s * e)))


def distance(pa, pb):
    """Distance between two disjoint convex polygons (0 when they intersect)."""
    if intersect(pa, pb):
        return 0.0
    return min(
        point_segment_distance(p, q[i], q[(i + 1) % 4]) for p_set, q in ((pa, pb), (pb, pa)) for p in p_set for i in range(4)
    )


def ray_hits_segment(p, v, q0, q1):
    """Smallest t >= 0 with p + v t on the segment [q0, q1] (inf if none or parallel)."""
    e = q1 - q0
    denom = cross(v, e)
    if abs(denom) < 1e-12:
        return math.inf
    t = cross(q0 - p, e) / denom
    s = cross(q0 - p, v) / denom
    return t if t >= 0.0 and -1e-12 <= s <= 1 + 1e-12 else math.inf


def jiao_ttc(a, b):
    """Jiao (2023): in B's frame A moves with v = v_a - v_b; first contact is a corner of A
    reaching an edge of B along v, or a corner of B reaching an edge of A along -v."""
    ca, cb = corners(a), corners(b)
    if intersect(ca, cb):
        return 0.0
    v = np.array([a.vx_mps - b.vx_mps, a.vy_mps - b.vy_mps])
    hits = [ray_hits_segment(p, v, q[i], q[(i + 1) % 4]) for p in ca for q in (cb,) for i in range(4)]
    hits += [ray_hits_segment(p, -v, q[i], q[(i + 1) % 4]) for p in cb for q in (ca,) for i in range(4)]
    return min(hits)


def random_footprint(rng, general, x_m):
    """General: any heading and velocity; else highway-like: near-parallel, same direction."""
    length_m, width_m = rng.uniform(3.0, 6.0), rng.uniform(1.5, 2.5)
    if general:
        y_m, heading_rad, (vx_mps, vy_mps) = rng.uniform(-25, 25), rng.uniform(-np.pi, np.pi), rng.uniform(-20, 20, 2)
    else:
        y_m, heading_rad, vx_mps, vy_mps = rng.uniform(-6, 6), rng.normal(0, 0.1), rng.uniform(15, 35), rng.normal(0, 1)
    return Footprint(*(float(v) for v in (x_m, y_m, length_m, width_m, heading_rad, vx_mps, vy_mps)))


def random_pair(rng):
    """A pair of footprints, half of them general (B heading roughly towards A), half highway-like."""
    general = bool(rng.random() < 0.5)
    a = random_footprint(rng, general, 0.0)
    b = random_footprint(rng, general, rng.uniform(-25, 25) if general else rng.uniform(-60, 60))
    if general:
        bearing_rad = math.atan2(a.y_m - b.y_m, a.x_m - b.x_m) + rng.normal(0.0, 0.3)
        closing_mps = rng.uniform(2.0, 20.0)
        closing = closing_mps * math.cos(bearing_rad), closing_mps * math.sin(bearing_rad)
        b = replace(b, vx_mps=a.vx_mps + closing[0], vy_mps=a.vy_mps + closing[1])
    return a, b


# ------------------------------------------------------------------------------- 2-D TTC by hand
def test_head_on_with_lateral_offset():
    a = car(0.0, 0.0, vx=20.0, length=5.0, width=2.0)
    b = car(50.0, 1.0, vx=-15.0, heading=math.pi, length=4.5, width=1.8)  # offset 1.0 < (2 + 1.8) / 2: overlaps
    gap_m = 50.0 - 5.0 / 2 - 4.5 / 2  # facing bumpers
    assert ttc_2d(a, b) == pytest.approx(gap_m / (20.0 + 15.0), abs=1e-12)
    assert not overlapping(a, b)
    # with a lateral offset wider than the half widths they pass each other
    assert ttc_2d(a, car(50.0, 1.95, vx=-15.0, heading=math.pi, length=4.5, width=1.8)) == math.inf


def test_lane_change_into_slower_car_lateral_overlap_first():
    a = car(0.0, 0.0, vx=25.0, vy=1.0)  # drifting left at 1 m/s into the next lane
    b = car(20.0, 4.0, vx=20.0)  # slower, ahead in the next lane
    # lateral: |4 - 1 t| <= 2 from t = 2 s; longitudinal: 20 - 5 = 15 m gap at 5 m/s -> 3 s
    assert ttc_2d(a, b) == pytest.approx(3.0, abs=1e-12)


def test_lane_change_into_slower_car_longitudinal_overlap_first():
    a = car(0.0, 0.0, vx=25.0, vy=0.5)
    b = car(20.0, 4.0, vx=20.0)
    # longitudinal overlap during [3, 5] s; lateral gap 4 - 2 = 2 m at 0.5 m/s -> 4 s (side swipe)
    assert ttc_2d(a, b) == pytest.approx(4.0, abs=1e-12)
    # drifting slower still, the lateral contact (from 10 s) comes after A has passed B (5 s)
    assert ttc_2d(car(0.0, 0.0, vx=25.0, vy=0.2), b) == math.inf


def test_parallel_side_by_side_at_the_same_speed_never_touch():
    assert ttc_2d(car(0.0, 0.0, vx=25.0), car(0.0, 3.5, vx=25.0)) == math.inf
    assert ttc_2d(car(0.0, 0.0), car(0.0, 3.5)) == math.inf  # both standing


def test_parallel_with_a_lateral_gap_and_relative_speed_never_touch():
    assert ttc_2d(car(0.0, 0.0, vx=30.0), car(10.0, 3.5, vx=20.0)) == math.inf  # overtaking
    assert ttc_2d(car(0.0, 0.0, vx=20.0), car(-40.0, -3.5, vx=35.0)) == math.inf  # overtaken
    assert ttc_2d(car(0.0, 0.0, vx=30.0), car(50.0, 0.0, vx=35.0)) == math.inf  # same lane, diverging


def test_already_overlapping_is_zero_and_flagged():
    a, b = car(0.0, 0.0, vx=20.0), car(3.0, 0.5, vx=25.0)
    assert overlapping(a, b) and overlapping(b, a)
    assert ttc_2d(a, b) == 0.0 and math.copysign(1.0, ttc_2d(a, b)) == 1.0  # +0.0
    assert overlapping(car(0.0, 0.0), car(5.0, 0.0))  # bumpers touching: closed rectangles
    assert not overlapping(car(0.0, 0.0), car(5.001, 0.0))
    touching = car(0.0, 0.0, vx=20.0), car(5.0, 0.0, vx=20.0)  # bumpers touching, no relative motion
    assert overlapping(*touching) and ttc_2d(*touching) == 0.0


def test_rotated_rectangles_crossing():
    a = car(-20.0, 0.0, vx=10.0, length=5.0, width=2.0)  # eastbound
    b = car(0.0, -12.0, vy=5.0, heading=math.pi / 2, length=4.0, width=2.0)  # northbound: x in [-1, 1], y +- 2
    # x overlap: -20 + 10 t + 2.5 >= -1 -> t >= 1.65 s, until -20 + 10 t - 2.5 <= 1 -> 2.35 s
    # y overlap: -12 + 5 t + 2 >= -1 -> t >= 1.8 s (B's front reaches A's side), until 3.0 s
    assert ttc_2d(a, b) == pytest.approx(1.8, abs=1e-12)
    # 2 s later, B arrives after A has gone
    assert ttc_2d(a, car(0.0, -15.0, vy=5.0, heading=math.pi / 2, length=4.0, width=2.0)) == math.inf


def test_rotated_rectangles_following():
    a = car(0.0, 0.0, vy=10.0, heading=math.pi / 2, length=5.0, width=2.0)  # northbound
    b = car(0.5, 30.0, vy=4.0, heading=math.pi / 2, length=4.0, width=2.0)
    assert ttc_2d(a, b) == pytest.approx((30.0 - 2.5 - 2.0) / (10.0 - 4.0), abs=1e-12)


def test_corner_first_contact():
    b = car(0.0, 0.0, length=4.0, width=2.0)  # standing: x in [-2, 2], y in [-1, 1]
    diamond = {"length": 2 * math.sqrt(2), "width": 2 * math.sqrt(2), "heading": math.pi / 4}  # corners 2 m from centre
    # A's left corner (x - 2, 0) reaches B's right edge x = 2: (10 - 2 - 2) / 5
    assert ttc_2d(car(10.0, 0.0, vx=-5.0, **diamond), b) == pytest.approx(1.2, abs=1e-12)
    # 1.5 m up, A's left corner passes above B; B's corner (2, 1) reaches A's lower-left edge
    # x + y = x_c - 2 + 1.5 when x_c = 3.5, i.e. t = (10 - 3.5) / 5
    assert ttc_2d(car(10.0, 1.5, vx=-5.0, **diamond), b) == pytest.approx(1.3, abs=1e-12)


def test_horizon():
    a, b = car(0.0, 0.0, vx=30.0), car(30.0, 0.0, vx=20.0)  # 25 m gap at 10 m/s
    assert ttc_2d(a, b) == pytest.approx(2.5)
    assert ttc_2d(a, b, horizon_s=2.0) == math.inf
    assert ttc_2d(a, b, horizon_s=3.0) == pytest.approx(2.5)
    with pytest.raises(ValueError, match="horizon_s"):
        ttc_2d(a, b, horizon_s=-1.0)


def test_min_ttc_2d_picks_the_nearest_conflict():
    ego = car(0.0, 0.0, vx=30.0)
    others = [car(60.0, 0.0, vx=20.0), car(10.0, 3.5, vx=20.0), car(30.0, 0.0, vx=20.0), car(-30.0, 0.0, vx=20.0)]
    assert min_ttc_2d(ego, others) == (pytest.approx(2.5), 2)
    assert min_ttc_2d(ego, others, horizon_s=2.0) == (math.inf, -1)
    assert min_ttc_2d(ego, []) == (math.inf, -1)
    assert min_ttc_2d(ego, [others[1], others[2], others[2]]) == (pytest.approx(2.5), 1)  # the first on ties
    assert min_ttc_2d(ego, [others[1], others[3]]) == (math.inf, -1)
    ttc_s, i = min_ttc_2d(ego, [*others, car(2.0, 1.0)])
    assert (ttc_s, i) == (0.0, 4) and overlapping(ego, [*others, car(2.0, 1.0)][i])


def test_from_vehicle():
    duck = SimpleNamespace(position=np.array([1.0, 2.0]), LENGTH=5.0, WIDTH=2.0, heading=0.1, velocity=np.array([3.0, 0.3]))
    assert Footprint.from_vehicle(duck) == Footprint(1.0, 2.0, 5.0, 2.0, 0.1, 3.0, 0.3)
    fp = Footprint.from_vehicle(Vehicle(None, [10.0, 4.0], heading=0.2, speed=20.0))
    assert (fp.x_m, fp.y_m, fp.length_m, fp.width_m, fp.heading_rad) == (10.0, 4.0, Vehicle.LENGTH, Vehicle.WIDTH, 0.2)
    assert (fp.vx_mps, fp.vy_mps) == pytest.approx((20.0 * math.cos(0.2), 20.0 * math.sin(0.2)))
    assert all(type(v) is float for v in vars(fp).values())


# ----------------------------------------------------------------------- 2-D TTC, randomized
def test_matches_jiao_oracle_and_is_symmetric_on_random_pairs():
    rng = np.random.default_rng(20230301)
    pairs = [random_pair(rng) for _ in range(2000)]
    ttc = np.array([ttc_2d(a, b) for a, b in pairs])
    oracle = np.array([jiao_ttc(a, b) for a, b in pairs])
    finite = np.isfinite(ttc)
    assert 0.2 < finite.mean() < 0.8 and (ttc == 0.0).sum() >= 20  # the sample exercises every outcome
    np.testing.assert_array_equal(finite, np.isfinite(oracle))
    np.testing.assert_allclose(ttc[finite], oracle[finite], rtol=0.0, atol=1e-6)
    assert [ttc_2d(b, a) for a, b in pairs] == ttc.tolist()  # symmetric, to the last bit
    assert [overlapping(a, b) for a, b in pairs] == (ttc == 0.0).tolist()
    vectorised = [min_ttc_2d(a, [b]) for a, b in pairs]
    assert [t for t, _ in vectorised] == ttc.tolist()


def test_matches_brute_force_time_stepping():
    """No contact on a 2 ms time grid before the TTC, and the rectangles touch at the TTC."""
    rng = np.random.default_rng(7)
    horizon_s, step_s = 8.0, 0.002
    times = np.arange(0.0, horizon_s + step_s, step_s)
    for _ in range(300):
        a, b = random_pair(rng)
        ttc = ttc_2d(a, b)
        ca = corners(a)[None] + times[:, None, None] * [a.vx_mps, a.vy_mps]
        cb = corners(b)[None] + times[:, None, None] * [b.vx_mps, b.vy_mps]
        hit = intersect(ca, cb)
        before = times < ttc - 1e-9
        assert not hit[before].any(), (a, b, ttc, times[hit][0])
        if ttc <= horizon_s:
            assert distance(corners(a, ttc), corners(b, ttc)) < 1e-6, (a, b, ttc)


# ------------------------------------------------------------------------------------------- PET
def straight(t_s, x0, y0, vx, vy, heading=0.0, length=4.0, width=2.0):
    return [Footprint(x0 + vx * t, y0 + vy * t, length, width, heading, vx, vy) for t in t_s]


def test_pet_crossing_by_hand():
    t_s = np.arange(0.0, 6.0, 1 / 15)  # the env's 15 Hz
    other = straight(t_s, 50.0, -10.0, 0.0, 10.0, heading=math.pi / 2)  # northbound at x = 50, 4 m x 2 m
    ego = straight(t_s, 19.0, 0.0, 10.0, 0.0)  # eastbound at y = 0, 4 m x 2 m
    # conflict area [49, 51] x [-1, 1]; the other's rear leaves y = 1 when -10 + 10 t - 2 = 1: t = 1.3 s;
    # the ego's front reaches x = 49 when 19 + 10 t + 2 = 49: t = 2.8 s
    for cell_m in (0.5, 0.1):
        tol_s = cell_m * (1 / 10 + 1 / 10)  # the docstring's bound
        assert post_encroachment_time(t_s, ego, other, cell_m=cell_m) == pytest.approx(1.5, abs=tol_s)
        assert post_encroachment_time(t_s, other, ego, cell_m=cell_m) == post_encroachment_time(t_s, ego, other, cell_m)


@pytest.mark.parametrize(
    ("x_ego0", "v_ego", "y_other0", "v_other"),
    [(19.0, 10.0, -10.0, 10.0), (0.0, 25.0, -20.0, 8.0), (30.0, 12.0, -30.0, 15.0), (10.0, 20.0, -6.0, 3.0)],
)
def test_pet_crossing_matches_the_analytic_minimum(x_ego0, v_ego, y_other0, v_other):
    """Perpendicular crossings (either one first): PET at every point of the conflict square, minimised."""
    t_s = np.arange(0.0, 8.0, 0.05)
    ego = straight(t_s, x_ego0, 0.0, v_ego, 0.0, length=4.5, width=1.8)
    other = straight(t_s, 50.0, y_other0, 0.0, v_other, heading=math.pi / 2, length=4.0, width=2.0)
    x, y = np.meshgrid(np.linspace(49.0, 51.0, 401), np.linspace(-0.9, 0.9, 401))
    ego_in, ego_out = (x - 2.25 - x_ego0) / v_ego, (x + 2.25 - x_ego0) / v_ego
    other_in, other_out = (y - 2.0 - y_other0) / v_other, (y + 2.0 - y_other0) / v_other
    exact = np.maximum(np.maximum(other_in - ego_out, ego_in - other_out), 0.0).min()
    cell_m = 0.25
    pet = post_encroachment_time(t_s, ego, other, cell_m=cell_m)
    assert pet == pytest.approx(exact, abs=cell_m * (1 / v_ego + 1 / v_other))


def test_pet_cut_in_is_the_time_gap():
    t_s = np.arange(0.0, 8.0, 1 / 15)
    ego = straight(t_s, 0.0, 0.0, 20.0, 0.0, length=5.0, width=2.0)
    # the other starts 30 m ahead bumper to bumper in the next lane (y = 4), at the ego's speed,
    # moves into the ego's lane at 1 m/s and stays there: the ego reaches each spot its rear left
    # 30 m / 20 m/s later
    other = [Footprint(35.0 + 20.0 * t, max(4.0 - t, 0.0), 5.0, 2.0, 0.0, 20.0, -1.0 if t < 4 else 0.0) for t in t_s]
    assert post_encroachment_time(t_s, ego, other) == pytest.approx(1.5, abs=1e-6)  # exact: constant velocity


def test_pet_collision_is_zero():
    t_s = np.arange(0.0, 5.0, 0.1)
    ego = straight(t_s, 0.0, 0.0, 10.0, 0.0)
    other = straight(t_s, 30.0, -20.0, 0.0, 6.667, heading=math.pi / 2)  # both at (30, 0) at t = 3 s
    assert ttc_2d(ego[0], other[0]) < 5.0
    assert post_encroachment_time(t_s, ego, other) == 0.0


def test_pet_never_sharing_space_is_inf():
    t_s = np.arange(0.0, 4.0, 0.1)
    ego = straight(t_s, 0.0, 0.0, 10.0, 0.0)
    assert post_encroachment_time(t_s, ego, straight(t_s, 0.0, 3.5, 12.0, 0.0)) == math.inf  # parallel lanes
    # the paths' boxes overlap at x in [38, 42], y in [-1, 1], but the other is at y > 10 there
    diagonal = straight(t_s, 40.0, 20.0, 7.5, -10.0, heading=-math.atan2(4, 3))
    assert post_encroachment_time(t_s, ego, diagonal) == math.inf


def test_pet_rejects_bad_input():
    t_s = np.arange(0.0, 1.0, 0.1)
    ego = straight(t_s, 0.0, 0.0, 10.0, 0.0)
    with pytest.raises(ValueError, match="one footprint per time"):
        post_encroachment_time(t_s, ego, ego[:-1])
    with pytest.raises(ValueError, match="increasing"):
        post_encroachment_time(t_s[::-1], ego, ego)
    with pytest.raises(ValueError, match="cell_m"):
        post_encroachment_time(t_s, ego, ego, cell_m=0.0)

"""The camera renderer: exact occlusion and depth (against a ray caster), boxes, determinism."""

import math

import numpy as np
import pytest
from highway_env.road.road import Road, RoadNetwork

from dt_highway.camera import (
    CameraRenderer,
    Intrinsics,
    Mount,
    PinholeCamera,
    Pose,
    RenderSettings,
    RoadScene,
    VehicleSet,
    depth_to_uint8,
)
from dt_highway.camera.render import CAR

W, H = 320, 180
MOUNT = Mount(forward_m=0.5, height_m=1.3, pitch_rad=math.radians(3))


def _scene(lanes: int = 4) -> RoadScene:
    return RoadScene.from_road(Road(RoadNetwork.straight_road_network(lanes, length=10000)))


def _renderer(w: int = W, h: int = H, mount: Mount = MOUNT, **settings) -> CameraRenderer:
    cam = PinholeCamera(Intrinsics.from_fov(w, h, math.radians(90)), mount)
    return CameraRenderer(cam, _scene(), RenderSettings(**settings))


def _random_traffic(seed: int, n: int = 30, ego=(100.0, 4.0)) -> VehicleSet:
    """Cars ahead of and beside the ego, in lanes, some changing lanes, none overlapping."""
    rng = np.random.default_rng(seed)
    rows, taken = [], []
    vid = 1
    while len(rows) < n:
        x = ego[0] + rng.uniform(-10, 120)
        y = 4.0 * rng.integers(0, 4) + rng.normal(0, 0.4)
        if abs(x - ego[0]) < 6 and abs(y - ego[1]) < 3:
            continue  # that would be inside the ego
        if any(abs(x - a) < 6.5 and abs(y - b) < 2.6 for a, b in taken):
            continue
        taken.append((x, y))
        rows.append((vid, x, y, rng.normal(0, 0.06)))
        vid += 1
    return VehicleSet.of(rows)


def _ray_cast(renderer: CameraRenderer, pose: Pose, vs: VehicleSet) -> tuple[np.ndarray, np.ndarray]:
    """Reference: per pixel centre, the nearest vehicle part hit by the ray (Cyrus-Beck on half-spaces)."""
    cam, k = renderer.camera, renderer.camera.intrinsics
    u, v = np.meshgrid(np.arange(k.width_px, dtype=float), np.arange(k.height_px, dtype=float))
    rays = np.stack([(u - k.cx_px) / k.fx_px, (v - k.cy_px) / k.fy_px, np.ones_like(u)], axis=-1)  # Z = 1
    best_z = np.full(u.shape, np.inf)
    best_id = np.zeros(u.shape, dtype=np.int32)
    height = renderer.settings.vehicle_height_m
    for i in range(len(vs)):
        c, s = math.cos(vs.heading_rad[i]), math.sin(vs.heading_rad[i])
        for part in CAR.part_vertices:
            unit = CAR.vertices[part]
            lx, ly, lz = unit[:, 0] * vs.length_m[i], unit[:, 1] * vs.width_m[i], unit[:, 2] * height
            world = np.stack([vs.x_m[i] + c * lx - s * ly, vs.y_m[i] + s * lx + c * ly, lz], axis=1)
            pc = cam.to_camera(world, pose)
            centre = pc.mean(axis=0)
            # faces of the frustum, bottom included: (rear, front, left, right, top, bottom)
            quads = [(0, 3, 7, 4), (1, 2, 6, 5), (0, 1, 5, 4), (3, 2, 6, 7), (4, 5, 6, 7), (0, 1, 2, 3)]
            z_in = np.zeros(u.shape)
            z_out = np.full(u.shape, np.inf)
            for q in quads:
                p = pc[list(q)]
                n = np.cross(p[1] - p[0], p[2] - p[0])
                if n @ (p.mean(axis=0) - centre) < 0:
                    n = -n
                d = n @ p[0]  # inside: n . X <= d; on the ray X = Z * r
                nr = rays @ n
                with np.errstate(divide="ignore", invalid="ignore"):
                    zz = d / nr
                z_in = np.where(nr < 0, np.maximum(z_in, zz), z_in)
                z_out = np.where(nr > 0, np.minimum(z_out, zz), z_out)
                z_out = np.where((nr == 0) & (d < 0), -np.inf, z_out)
            hit = (z_in <= z_out) & (z_out > cam.near_m) & (z_in < best_z)
            best_z = np.where(hit, z_in, best_z)
            best_id = np.where(hit, vs.ids[i], best_id)
    return best_id, best_z


def _near_edge(instance: np.ndarray) -> np.ndarray:
    """Pixels within one pixel of a change of instance id."""
    edge = np.zeros(instance.shape, dtype=bool)
    dv = instance[1:] != instance[:-1]
    dh = instance[:, 1:] != instance[:, :-1]
    edge[1:] |= dv
    edge[:-1] |= dv
    edge[:, 1:] |= dh
    edge[:, :-1] |= dh
    grown = edge.copy()
    grown[1:] |= edge[:-1]
    grown[:-1] |= edge[1:]
    grown[:, 1:] |= edge[:, :-1]
    grown[:, :-1] |= edge[:, 1:]
    return grown


def test_frame_types_and_shapes():
    r = _renderer()
    f, t = r.render(Pose(100, 4, 0), _random_traffic(0))
    assert f.rgb.dtype == np.uint8 and f.rgb.shape == (H, W, 3)
    assert f.depth_m.dtype == np.float32 and f.depth_m.shape == (H, W)
    assert t.instance.dtype == np.int32 and t.instance.shape == (H, W)
    assert f.range_m().shape == (H, W)
    assert set(np.unique(t.instance)) - {0} <= set(t.vehicles)


def test_road_depth_is_analytic_for_a_level_camera():
    level = Mount(forward_m=0.0, height_m=1.4, pitch_rad=0.0)
    r = _renderer(mount=level, max_range_m=150.0)
    f, t = r.render(Pose(50, 0, 0), VehicleSet.empty())
    k = r.camera.intrinsics
    rows = np.arange(H)
    expected = k.fy_px * 1.4 / (rows - k.cy_px)
    ground = (rows > k.cy_px) & (expected <= 150.0)
    assert ground.sum() > 50
    for u in (0, W // 3, W - 1):
        np.testing.assert_allclose(f.depth_m[ground, u], expected[ground], rtol=1e-5)
    # sky and ground beyond max range saturate at max range
    assert np.all(f.depth_m[~ground] == pytest.approx(150.0))
    assert not t.instance.any() and not t.vehicles


@pytest.mark.parametrize("seed", range(4))
def test_occlusion_and_depth_match_a_ray_caster(seed):
    r = _renderer()
    pose = Pose(100, 4, float(np.random.default_rng(seed).normal(0, 0.03)))
    vs = _random_traffic(seed)
    f, t = r.render(pose, vs)
    ref_id, ref_z = _ray_cast(r, pose, vs)
    near_edge = _near_edge(t.instance) | _near_edge(ref_id)
    disagree = t.instance != ref_id
    assert (ref_id > 0).sum() > 500, "the scene should show some vehicles"
    # every pixel away from an outline shows the vehicle the ray meets first
    assert not (disagree & ~near_edge).any()
    assert disagree.mean() < 0.02
    # and its exact planar depth (away from the outlines of faces, where a pixel may show the
    # neighbouring face of the same car)
    face_edge = _near_edge(r._face_map)
    both = (t.instance == ref_id) & (ref_id > 0) & ~near_edge & ~face_edge
    assert both.sum() > 0.25 * (ref_id > 0).sum()
    np.testing.assert_allclose(f.depth_m[both], ref_z[both], rtol=1e-4)


def test_hidden_vehicle_has_visibility_zero_and_no_box():
    r = _renderer()
    vs = VehicleSet.of([(1, 112.0, 4.0), (2, 150.0, 4.0)])  # 2 right behind 1, in the ego's lane
    f, t = r.render(Pose(100, 4, 0), vs)
    assert 2 in t.vehicles, "a hidden vehicle in the view is still reported"
    hidden = t.vehicles[2]
    assert hidden.visibility == 0.0 and hidden.visible_box is None and hidden.visible_px == 0
    assert hidden.amodal_px > 0
    assert not (t.instance == 2).any()
    assert t.vehicles[1].visibility == pytest.approx(1.0)
    # move it one lane over: now seen, partly
    f2, t2 = r.render(Pose(100, 4, 0), VehicleSet.of([(1, 112.0, 4.0), (2, 150.0, 8.0)]))
    assert 0.0 < t2.vehicles[2].visibility < 1.0


@pytest.mark.parametrize("seed", range(3))
def test_visible_boxes_are_the_instance_extents(seed):
    r = _renderer()
    f, t = r.render(Pose(100, 4, 0), _random_traffic(seed))
    seen = 0
    for vid, truth in t.vehicles.items():
        ys, xs = np.nonzero(t.instance == vid)
        assert truth.visible_px == len(xs)
        if not len(xs):
            assert truth.visible_box is None and truth.visibility == 0.0
            continue
        seen += 1
        assert truth.visible_box == (xs.min() - 0.5, ys.min() - 0.5, xs.max() + 0.5, ys.max() + 0.5)
        assert 0.0 < truth.visibility <= 1.0
        ax1, ay1, ax2, ay2 = truth.amodal_box
        bx1, by1, bx2, by2 = truth.visible_box
        # the visible part lies inside the whole shape, up to OpenCV's inclusive polygon fill
        # (a silhouette may grow by up to one pixel)
        assert bx1 >= ax1 - 1.5 and by1 >= ay1 - 1.5 and bx2 <= ax2 + 1.5 and by2 <= ay2 + 1.5
    assert seen >= 5


def test_rear_face_depth_is_the_gap_to_the_camera():
    r = _renderer(mount=Mount(forward_m=0.5, height_m=1.3, pitch_rad=0.0))
    f, t = r.render(Pose(100, 4, 0), VehicleSet.of([(7, 130.0, 4.0)]))
    k = r.camera.intrinsics
    # the pixel straight ahead at 0.5 m above the road hits the rear face: Z = 130 - 2.5 - 100.5
    v = int(round(k.cy_px + k.fy_px * (1.3 - 0.5) / 27.0))
    u = int(round(k.cx_px))
    assert t.instance[v, u] == 7
    assert f.depth_m[v, u] == pytest.approx(27.0, abs=1e-4)
    assert t.vehicles[7].depth_m == pytest.approx(130.0 - 100.5, abs=1e-9)
    norm = math.sqrt(1.0 + ((u - k.cx_px) / k.fx_px) ** 2 + ((v - k.cy_px) / k.fy_px) ** 2)
    assert f.range_m()[v, u] == pytest.approx(27.0 * norm, rel=1e-6)


def test_vehicles_behind_or_beside_the_camera():
    r = _renderer()
    # behind; alongside on both sides, crossing the camera's plane (x = 100.5)
    vs = VehicleSet.of([(1, 80.0, 4.0), (2, 102.5, 8.0), (3, 102.5, 0.0)])
    f, t = r.render(Pose(100, 4, 0), vs)
    assert 1 not in t.vehicles
    for vid in (2, 3):  # crossing the image plane: clipped at the near plane, seen at the image's side
        truth = t.vehicles[vid]
        assert truth.truncated and truth.visible_px > 0
        cols = np.nonzero(t.instance == vid)[1]
        assert (cols.min() == 0) if vid == 3 else (cols.max() == W - 1)
        assert truth.visible_px > 1000
        assert (f.depth_m[t.instance == vid] >= r.camera.near_m).all()


def test_output_is_deterministic():
    vs = _random_traffic(5)
    a = _renderer().render(Pose(100, 4, 0.02), vs)
    b = _renderer().render(Pose(100, 4, 0.02), vs)
    c = _renderer().render(Pose(100, 4, 0.02), vs)
    for (x, xt), (y, yt) in ((a, b), (a, c)):
        assert x.rgb.tobytes() == y.rgb.tobytes()
        assert x.depth_m.tobytes() == y.depth_m.tobytes()
        assert xt.instance.tobytes() == yt.instance.tobytes()
        assert xt.vehicles == yt.vehicles


def test_colours_follow_ids_not_driver_types():
    r = _renderer()
    f1, t1 = r.render(Pose(100, 4, 0), VehicleSet.of([(3, 120.0, 4.0)]))
    f2, _ = r.render(Pose(100, 4, 0), VehicleSet.of([(3, 120.0, 4.0)]))
    assert f1.rgb.tobytes() == f2.rgb.tobytes()
    assert len(np.unique(f1.rgb[t1.instance == 3].reshape(-1, 3), axis=0)) >= 4  # shaded faces, glass, lights


def test_bad_input_is_refused():
    with pytest.raises(ValueError, match="max_range_m"):
        _renderer(max_range_m=0.05)
    with pytest.raises(ValueError, match="vehicle ids"):
        _renderer().render(Pose(100, 4, 0), VehicleSet.of([(0, 120.0, 4.0)]))
    with pytest.raises(ValueError, match="straight lanes"):
        from highway_env.road.lane import CircularLane

        net = RoadNetwork()
        net.add_lane("a", "b", CircularLane([0, 0], 20, 0, 1))
        RoadScene.from_road(Road(net))


def test_depth_to_uint8():
    d = np.array([0.0, 100.0, 200.0, 500.0], dtype=np.float32)
    assert depth_to_uint8(d, 200.0).tolist() == [255, 128, 0, 0]

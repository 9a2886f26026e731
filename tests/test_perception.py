"""Perception and fusion: Algorithm 1, every branch of Algorithm 2, the baseline, the joint
assignment, tracking, the simulated detector, and the fusion's handling of bad inputs."""

import math

import numpy as np
import pytest

from dt_highway.camera import Intrinsics, Mount, PinholeCamera, Pose
from dt_highway.camera.render import CameraImage
from dt_highway.camera.truth import CameraTruth, VehicleTruth
from dt_highway.perception import (
    BoxTracker,
    Detections,
    Fusion,
    FusionSettings,
    SimulatedDetector,
    SimulatedDetectorSettings,
    box_distances,
    iou,
    match_baseline,
    match_distance,
    match_joint,
    sample_regions,
)
from dt_highway.twin.cloud import TwinVehicleView


# ----------------------------------------------------------------------------- Algorithm 1
def test_sample_region_is_the_lower_quarter_of_the_shrunk_box():
    area = sample_regions(np.array([[0.0, 0.0, 100.0, 80.0]]), th=0.2, shape=(200, 200))[0]
    # shrunk by 20 %: x 10..90, y 8..72; its lower quarter: y 56..72
    np.testing.assert_allclose(area, [10.0, 56.0, 90.0, 72.0])


@pytest.mark.parametrize("seed", range(5))
def test_samples_stay_inside_the_lower_quarter(seed):
    rng = np.random.default_rng(seed)
    h, w = 120, 200
    for _ in range(20):
        x1, y1 = rng.uniform(0, 150), rng.uniform(0, 80)
        box = np.array([[x1, y1, x1 + rng.uniform(8, 50), y1 + rng.uniform(8, 40)]])
        a = sample_regions(box, 0.2, (h, w))[0]
        depth = np.full((h, w), 99.0, dtype=np.float32)
        cols = np.arange(w)
        rows = np.arange(h)
        inside = np.outer((rows >= a[1]) & (rows <= a[3]), (cols >= a[0]) & (cols <= a[2]))
        depth[inside] = 10.0
        d = box_distances(depth, box, th=0.2, n=50, rng=rng)
        assert d[0] == pytest.approx(10.0), "a sample fell outside the sampling area"


def test_mean_and_median_and_range_reference():
    depth = np.full((50, 50), 20.0, dtype=np.float32)
    depth[40:45, 10:12] = 200.0  # a few far pixels (road, sky) inside the area
    box = np.array([[0.0, 0.0, 49.0, 49.0]])
    rng = np.random.default_rng(0)
    mean = box_distances(depth, box, 0.2, 400, rng, reducer="mean")[0]
    median = box_distances(depth, box, 0.2, 400, rng, reducer="median")[0]
    assert mean > 21.0 and median == pytest.approx(20.0)
    norm = np.full((50, 50), 1.5, dtype=np.float32)
    rng_d = box_distances(np.full((50, 50), 20.0, np.float32), box, 0.2, 10, rng, reference="range", ray_norm=norm)[0]
    assert rng_d == pytest.approx(30.0)


def test_degenerate_boxes_and_bad_parameters():
    depth = np.full((40, 60), 7.0, dtype=np.float32)
    out = box_distances(depth, np.array([[10.0, 10.0, 10.2, 10.2], [500.0, 500.0, 520.0, 520.0]]), n=5)
    assert out[0] == pytest.approx(7.0)  # thinner than a pixel: the pixel at its centre
    assert len(out) == 2
    assert box_distances(depth, np.zeros((0, 4))).shape == (0,)
    with pytest.raises(ValueError, match="resize threshold"):
        box_distances(depth, np.array([[0, 0, 10, 10]]), th=1.0)
    with pytest.raises(ValueError, match="n \\(sample points"):
        box_distances(depth, np.array([[0, 0, 10, 10]]), n=0)
    with pytest.raises(ValueError, match="ray_norm"):
        box_distances(depth, np.array([[0, 0, 10, 10]]), reference="range")


# ----------------------------------------------------------------------------- Algorithm 2
BOXES = np.array([[100.0, 100.0, 200.0, 180.0], [150.0, 90.0, 260.0, 170.0], [400.0, 100.0, 450.0, 140.0]])


def test_one_box_contains_the_anchor():
    m = match_distance((420.0, 120.0), BOXES, np.array([10.0, 20.0, 30.0]), 5.0)
    assert (m.index, m.rule) == (2, "single")


def test_several_boxes_resolved_by_depth_with_the_absolute_difference():
    # the anchor is in boxes 0 and 1; D_g = 50: box 1 (48 m) is the right one. The signed
    # difference of the paper's text (d_j - D_g) would pick box 0 (30 - 50 = -20).
    m = match_distance((170.0, 150.0), BOXES, np.array([30.0, 48.0, 99.0]), 50.0)
    assert (m.index, m.rule, m.candidates) == (1, "depth", (0, 1))
    m = match_distance((170.0, 150.0), BOXES, np.array([49.0, 80.0, 99.0]), 50.0)
    assert m.index == 0


def test_no_box_contains_the_anchor():
    d = np.array([10.0, 20.0, 30.0])
    assert match_distance((300.0, 300.0), BOXES, d, 10.0).index is None
    near = match_distance((205.0, 178.0), BOXES, d, 10.0, fallback="nearest", max_fallback_px=20.0)
    assert (near.index, near.rule) == (0, "fallback")
    assert match_distance((600.0, 300.0), BOXES, d, 10.0, fallback="nearest").index is None


def test_anchor_behind_the_camera_empty_detections_and_missing_gnss_distance():
    d = np.array([10.0, 20.0, 30.0])
    assert match_distance((math.nan, math.nan), BOXES, d, 10.0).rule == "none"
    assert match_distance(None, BOXES, d, 10.0).index is None
    assert match_distance((170.0, 150.0), np.zeros((0, 4)), np.zeros(0), 10.0).index is None
    assert match_baseline((170.0, 150.0), np.zeros((0, 4))).index is None
    # no GNSS distance: the nearest-centre rule decides between the candidates
    m = match_distance((160.0, 140.0), BOXES, d, math.nan)
    assert (m.index, m.rule) == (0, "centre")
    with pytest.raises(ValueError, match="one distance per box"):
        match_distance((170.0, 150.0), BOXES, np.array([1.0]), 5.0)


def test_baseline_picks_the_nearest_centre():
    assert match_baseline((160.0, 140.0), BOXES).index == 0
    assert match_baseline((195.0, 130.0), BOXES).index == 1
    assert match_baseline((195.0, 130.0), BOXES).rule == "centre"


def test_joint_assignment_gives_each_vehicle_its_own_box():
    boxes = np.array([[100.0, 100.0, 140.0, 130.0], [130.0, 100.0, 170.0, 130.0], [300.0, 100.0, 340.0, 130.0]])
    dist = np.array([20.0, 40.0, 30.0])
    # both anchors sit in the overlap of boxes 0 and 1; depth tells them apart
    anchors = np.array([[135.0, 115.0], [135.0, 115.0]])
    out = match_joint(anchors, np.array([40.0, 20.0]), boxes, dist)
    assert out == [1, 0]
    # a vehicle far from every box gets none; box 2 (an unconnected car) stays unassigned
    out = match_joint(np.array([[135.0, 115.0], [600.0, 400.0]]), np.array([20.0, 30.0]), boxes, dist)
    assert out == [0, None]
    assert match_joint(np.array([[math.nan, math.nan]]), np.array([math.nan]), boxes, dist) == [None]
    assert match_joint(np.zeros((0, 2)), np.zeros(0), boxes, dist) == []


# ----------------------------------------------------------------------------- tracking
def test_tracks_keep_their_identity_through_a_missed_detection():
    tracker = BoxTracker()
    ids = []
    for k in range(8):
        box = np.array([[100.0 + 3 * k, 100.0, 140.0 + 3 * k, 130.0]])
        tracker.update(box if k != 4 else np.zeros((0, 4)))  # frame 4: missed
        ids.append({t.track_id for t in tracker.tracks})
        if k == 4:  # coasting on its prediction, which moved on with the box
            coast_ids, coast_boxes = tracker.coasting()
            assert coast_ids.tolist() == [1]
            np.testing.assert_allclose(coast_boxes[0], [112.0, 100.0, 152.0, 130.0], atol=1.5)
    assert all(i == {1} for i in ids)
    track = tracker.tracks[0]
    assert track.misses == 0 and track.hits == 7


def test_a_merged_detection_does_not_capture_two_tracks():
    tracker = BoxTracker()
    a = np.array([100.0, 100.0, 140.0, 130.0])
    b = np.array([136.0, 100.0, 176.0, 130.0])
    for _ in range(3):
        tracker.update(np.array([a, b]))
    tracker.update(np.array([[100.0, 100.0, 176.0, 130.0]]))  # one box over both
    assert tracker.detection_tracks == [None]
    assert set(tracker.coasting()[0].tolist()) == {1, 2}



class _FullSortFilter:
    """SORT's 7-state Kalman filter written out with full matrices (Bewley et al. 2016), the
    reference for :class:`BoxTracker`'s decoupled filters (same noise: SORT's, with the aspect
    ratio's process noise 1e-2)."""

    F = np.eye(7) + np.eye(7, k=4)
    H = np.eye(4, 7)
    Q = np.diag([1.0, 1.0, 1.0, 1e-2, 1e-2, 1e-2, 1e-4])
    R = np.diag([1.0, 1.0, 10.0, 10.0])

    def __init__(self, box):
        self.x = np.concatenate([self._z(box), np.zeros(3)])
        self.P = np.diag([10.0, 10.0, 10.0, 10.0, 1e4, 1e4, 1e4])

    @staticmethod
    def _z(b):
        w, h = b[2] - b[0], b[3] - b[1]
        return np.array([b[0] + w / 2, b[1] + h / 2, w * h, w / h])

    def predict(self):
        if self.x[2] + self.x[6] <= 0:
            self.x[6] = 0.0
        self.x = self.F @ self.x
        self.P = self.F @ self.P @ self.F.T + self.Q

    def update(self, box):
        s = self.H @ self.P @ self.H.T + self.R
        k = self.P @ self.H.T @ np.linalg.inv(s)
        self.x = self.x + k @ (self._z(box) - self.H @ self.x)
        self.P = (np.eye(7) - k @ self.H) @ self.P

    def box(self):
        w = np.sqrt(self.x[2] * self.x[3])
        h = self.x[2] / w
        return np.array([self.x[0] - w / 2, self.x[1] - h / 2, self.x[0] + w / 2, self.x[1] + h / 2])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_decoupled_filters_equal_sorts_full_kalman_filter(seed):
    """Tracks far apart (association is unambiguous) with noisy, growing boxes and missed
    frames: every coasting track's predicted box equals the full 7-state filter's."""
    rng = np.random.default_rng(seed)
    n = 6
    start = np.stack([np.arange(n) * 100.0 + 20, rng.uniform(100, 200, n)], axis=1)
    size = rng.uniform(20, 40, (n, 2))
    vel = rng.normal(0, 2, (n, 2))
    tracker, ref = BoxTracker(max_misses=50), []
    compared = 0
    for f in range(30):
        centre, wh = start + f * vel, size * (1 + 0.02 * f)
        boxes = np.concatenate([centre - wh / 2, centre + wh / 2], axis=1) + rng.normal(0, 1.0, (n, 4))
        seen = rng.random(n) > 0.25 if f else np.ones(n, dtype=bool)
        tracker.update(boxes[seen])
        if not f:  # all seen in the first frame: vehicle i starts track i + 1
            ref = [_FullSortFilter(b) for b in boxes]
            continue
        for i in range(n):
            ref[i].predict()
            if seen[i]:
                ref[i].update(boxes[i])
        assert sorted(t.track_id for t in tracker.tracks) == list(range(1, n + 1))
        coast_ids, coast_boxes = tracker.coasting(min_hits=1)
        assert sorted(coast_ids.tolist()) == [i + 1 for i in range(n) if not seen[i]]
        for tid, box in zip(coast_ids.tolist(), coast_boxes, strict=True):
            np.testing.assert_allclose(box, ref[tid - 1].box(), rtol=1e-9, atol=1e-9)
            compared += 1
    assert compared > 20

# ----------------------------------------------------------------------------- simulated detector
def _image(depth_m: float = 28.0) -> CameraImage:
    h, w = 180, 320
    return CameraImage(np.zeros((h, w, 3), np.uint8), np.full((h, w), depth_m, np.float32), Pose(0, 0, 0))


def _frame(truths: list[VehicleTruth], depth_m: float = 28.0) -> tuple[CameraImage, CameraTruth]:
    image = _image(depth_m)
    return image, CameraTruth(np.zeros(image.depth_m.shape, np.int32), {t.vehicle_id: t for t in truths})


def _truth(vid, box, vis=1.0):
    return VehicleTruth(vid, box, box, vis, 100, 100, 20.0, 20.0, False)


def test_simulated_detector_without_errors_returns_the_visible_boxes():
    perfect = SimulatedDetectorSettings(jitter=0.0, miss_height_px=0.0, miss_visibility=0.0, merge_prob=0.0,
                                        false_positives_per_frame=0.0)
    frame = _frame([_truth(1, (10.5, 20.5, 50.5, 50.5)), _truth(2, (100.5, 60.5, 130.5, 80.5)),
                    VehicleTruth(3, None, (0, 0, 5, 5), 0.0, 0, 30, 60.0, 60.0, False)])
    det = SimulatedDetector(perfect, np.random.default_rng(0)).detect(*frame)
    np.testing.assert_allclose(np.sort(det.boxes, axis=0),
                               np.sort(np.array([[10.5, 20.5, 50.5, 50.5], [100.5, 60.5, 130.5, 80.5]]), axis=0))


def test_simulated_detector_merges_overlapping_vehicles_and_is_seeded():
    merging = SimulatedDetectorSettings(jitter=0.0, miss_height_px=0.0, miss_visibility=0.0, merge_prob=1.0,
                                        false_positives_per_frame=0.0)
    frame = _frame([_truth(1, (10.5, 20.5, 50.5, 50.5)), _truth(2, (20.5, 25.5, 45.5, 45.5))])
    det = SimulatedDetector(merging, np.random.default_rng(0)).detect(*frame)
    np.testing.assert_allclose(det.boxes, [[10.5, 20.5, 50.5, 50.5]])
    noisy = SimulatedDetectorSettings(false_positives_per_frame=1.0)
    one = SimulatedDetector(noisy, np.random.default_rng(3)).detect(*frame)
    two = SimulatedDetector(noisy, np.random.default_rng(3)).detect(*frame)
    np.testing.assert_array_equal(one.boxes, two.boxes)


# ----------------------------------------------------------------------------- fusion
CAMERA = PinholeCamera(Intrinsics.from_fov(320, 180, math.radians(90)), Mount(forward_m=0.0, height_m=1.3))


def _twin(vid, x, y, t_fix=0.0, speed=0.0):
    return TwinVehicleView(vid, t_fix, x, y, speed, 0.0, "aggressive", 0.9, 2, 60.0)


def test_anchor_projection_and_latency_compensation():
    fusion = Fusion(CAMERA, FusionSettings(method="fusion"), np.random.default_rng(0))
    frame = _image()
    uv, depth = fusion.anchors(frame, [_twin(1, 30.0, 0.0), _twin(2, -10.0, 0.0)], now_s=0.0, compensate=False)
    assert uv[0, 0] == pytest.approx(CAMERA.intrinsics.cx_px) and depth[0] == pytest.approx(30.0)
    assert np.isnan(uv[1]).all() and np.isnan(depth[1])  # behind the camera
    # 1 s old at 10 m/s: compensation moves it 10 m ahead
    _, d_comp = fusion.anchors(frame, [_twin(1, 30.0, 0.0, t_fix=-1.0, speed=10.0)], now_s=0.0, compensate=True)
    assert d_comp[0] == pytest.approx(40.0)


@pytest.mark.parametrize("method", ["baseline", "fusion", "joint", "tracked"])
def test_fusion_handles_empty_and_bad_inputs(method):
    fusion = Fusion(CAMERA, FusionSettings(method=method), np.random.default_rng(0))
    frame = _image()
    assert fusion.step(frame, Detections.empty(), [], 0.0) == {}
    out = fusion.step(frame, Detections.empty(), [_twin(1, 30.0, 0.0)], 0.0)
    assert out[1].box is None and out[1].rule == "none"
    bad = [_twin(2, math.nan, 0.0), _twin(3, 30.0, 0.0, t_fix=math.nan, speed=math.nan)]
    out = fusion.step(frame, Detections.of([(150.0, 80.0, 170.0, 100.0)]), bad, 0.0)
    assert 2 not in out  # no position: not placed, no crash
    assert set(out) <= {3}


@pytest.mark.parametrize("method", ["baseline", "fusion", "joint", "tracked"])
def test_fusion_places_a_vehicle_on_its_box(method):
    fusion = Fusion(CAMERA, FusionSettings(method=method), np.random.default_rng(0))
    twin = [_twin(7, 30.0, 0.0)]
    uv, _ = fusion.anchors(_image(), twin, 0.0, compensate=False)
    u, v = uv[0]
    target = (u - 10, v - 8, u + 10, v + 6)
    dets = Detections.of([target, (u + 60, v - 8, u + 80, v + 6)])
    for _ in range(3):
        out = fusion.step(_image(), dets, twin, 0.0)
    assert out[7].box is not None and iou([out[7].box], [target])[0, 0] == pytest.approx(1.0)


def test_bad_method_is_refused():
    with pytest.raises(ValueError, match="method must be one of"):
        FusionSettings(method="magic")


@pytest.mark.parametrize("seed", range(5))
def test_batch_matching_equals_one_target_at_a_time(seed):
    from dt_highway.perception import match_each

    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, 300, (12, 2))
    boxes = np.concatenate([xy, xy + rng.uniform(10, 80, (12, 2))], axis=1)
    dist = rng.uniform(5, 80, 12)
    dist[3] = np.nan
    anchors = rng.uniform(0, 350, (30, 2))
    anchors[4] = np.nan
    gnss = rng.uniform(5, 80, 30)
    gnss[5] = np.nan
    for fallback in ("none", "nearest"):
        idx, rules = match_each(anchors, boxes, fallback=fallback)
        for k in range(30):
            m = match_baseline(anchors[k], boxes, fallback)
            assert (m.index if m.index is not None else -1, m.rule) == (idx[k], rules[k])
        idx, rules = match_each(anchors, boxes, dist, gnss, fallback=fallback)
        for k in range(30):
            m = match_distance(anchors[k], boxes, dist, gnss[k], fallback)
            assert (m.index if m.index is not None else -1, m.rule) == (idx[k], rules[k])


@pytest.mark.parametrize("n", [1, 2, 5, 20, 21])
def test_row_median_is_numpy_median(n):
    from dt_highway.perception.depth import row_median

    values = np.random.default_rng(n).normal(30, 10, (7, n))
    np.testing.assert_array_equal(row_median(values), np.median(values, axis=1))


def test_config_sections_and_settings_share_their_defaults():
    from dt_highway.config import DetectorConfig, FusionConfig
    from dt_highway.perception import fusion_settings, make_detector

    assert make_detector(DetectorConfig()).settings == SimulatedDetectorSettings()
    assert fusion_settings(FusionConfig()) == FusionSettings()
    assert fusion_settings(FusionConfig(), "baseline").method == "baseline"

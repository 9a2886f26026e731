"""The pinhole model: parity with OpenCV, analytic road depth, flags, round trips."""

import math

import cv2
import numpy as np
import pytest

from dt_highway.camera import Intrinsics, Mount, PinholeCamera, Pose


def _random_setup(rng):
    intr = Intrinsics.from_fov(640, 360, math.radians(rng.uniform(50, 110)),
                               cx_px=rng.uniform(300, 340), cy_px=rng.uniform(160, 200))
    mount = Mount(forward_m=rng.uniform(-1, 2), lateral_m=rng.uniform(-0.5, 0.5), height_m=rng.uniform(1.0, 2.0),
                  pitch_rad=rng.uniform(-0.1, 0.2), yaw_rad=rng.uniform(-0.3, 0.3))
    pose = Pose(rng.uniform(0, 1000), rng.uniform(0, 12), rng.uniform(-0.5, 0.5))
    return PinholeCamera(intr, mount), pose


def test_intrinsics_from_fov():
    k = Intrinsics.from_fov(640, 360, math.radians(90))
    assert k.fx_px == pytest.approx(320.0)
    assert (k.cx_px, k.cy_px) == (319.5, 179.5)


@pytest.mark.parametrize("seed", range(10))
def test_projection_matches_cv2_project_points(seed):
    rng = np.random.default_rng(seed)
    cam, pose = _random_setup(rng)
    rot, t = cam.extrinsics(pose)
    assert np.allclose(rot @ rot.T, np.eye(3)) and np.linalg.det(rot) == pytest.approx(1.0)
    # points ahead of the camera, on and above the road (z up)
    fwd = np.array([math.cos(pose.heading_rad), math.sin(pose.heading_rad)])
    d = rng.uniform(5, 150, 200)
    lat = rng.uniform(-12, 12, 200)
    xy = np.array([pose.x_m, pose.y_m]) + d[:, None] * fwd + lat[:, None] * np.array([-fwd[1], fwd[0]])
    pts = np.column_stack([xy, rng.uniform(0, 3, 200)])
    proj = cam.project(pts, pose)
    assert proj.in_front.all()
    rvec, _ = cv2.Rodrigues(rot)
    pts_rh = pts * np.array([1.0, 1.0, -1.0])  # OpenCV needs the right-handed (z down) world
    uv_cv, _ = cv2.projectPoints(pts_rh.reshape(-1, 1, 3), rvec, t, cam.intrinsics.matrix, None)
    assert np.max(np.abs(proj.uv_px - uv_cv.reshape(-1, 2))) < 1e-6


def test_level_camera_road_depth_is_f_h_over_v_minus_cy():
    intr = Intrinsics.from_fov(640, 360, math.radians(90))
    h = 1.4
    cam = PinholeCamera(intr, Mount(forward_m=0.0, height_m=h))
    pose = Pose(100.0, 4.0, 0.0)
    d = np.array([5.0, 10.0, 20.0, 40.0, 80.0])
    road = np.column_stack([100.0 + d, np.full_like(d, 4.0), np.zeros_like(d)])
    proj = cam.project(road, pose)
    v = proj.uv_px[:, 1]
    assert np.allclose(proj.depth_m, intr.fy_px * h / (v - intr.cy_px))
    assert np.allclose(proj.depth_m, d)


def test_points_behind_the_camera_are_flagged():
    cam = PinholeCamera(Intrinsics.from_fov(640, 360, math.radians(90)), Mount(forward_m=0.0))
    pose = Pose(0.0, 0.0, 0.0)
    proj = cam.project(np.array([[-10.0, 0.0, 1.0], [10.0, 0.0, 1.0], [0.05, 0.0, 1.3], [10.0, 50.0, 1.0]]), pose)
    assert list(proj.in_front) == [False, True, False, True]
    assert np.isnan(proj.uv_px[0]).all() and np.isnan(proj.uv_px[2]).all()
    assert list(proj.in_image) == [False, True, False, False]  # the last one is far off to the side


def test_a_point_to_the_right_appears_right_of_centre():
    cam = PinholeCamera(Intrinsics.from_fov(640, 360, math.radians(90)), Mount(forward_m=0.0, height_m=1.3))
    proj = cam.project(np.array([[20.0, 3.0, 1.3], [20.0, -3.0, 1.3], [20.0, 0.0, 3.0]]), Pose(0.0, 0.0, 0.0))
    assert proj.uv_px[0, 0] > cam.intrinsics.cx_px > proj.uv_px[1, 0]  # +y is the driver's right
    assert proj.uv_px[2, 1] < cam.intrinsics.cy_px  # higher up is higher in the image


@pytest.mark.parametrize("seed", range(5))
def test_unproject_inverts_project(seed):
    rng = np.random.default_rng(100 + seed)
    cam, pose = _random_setup(rng)
    fwd = np.array([math.cos(pose.heading_rad), math.sin(pose.heading_rad), 0.0])
    pts = np.array([pose.x_m, pose.y_m, 0.0]) + rng.uniform(10, 80, (50, 1)) * fwd + rng.uniform(-2, 2, (50, 3))
    proj = cam.project(pts, pose)
    back = cam.unproject(proj.uv_px, proj.depth_m, pose)
    assert np.allclose(back, pts, atol=1e-9)
    assert np.allclose(cam.range_from_depth(proj.uv_px, proj.depth_m), proj.range_m)


@pytest.mark.parametrize("args", [(0, 360, 1.0), (640, 360, 0.0), (640, 360, math.pi)])
def test_bad_intrinsics(args):
    with pytest.raises(ValueError):
        Intrinsics.from_fov(*args)

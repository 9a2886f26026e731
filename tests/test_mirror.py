"""Mirrors: the ego camera's renderer looking back, flipped like a mirror (hmi/mirror.py)."""

import math

import numpy as np
import pytest

import dt_highway  # noqa: F401  (registers the env)
from dt_highway.camera.pinhole import Mount
from dt_highway.env.core import DTHighwayEnv
from dt_highway.hmi.mirror import (
    BEZEL,
    MIRRORS,
    MirrorSettings,
    draw_mirrors,
    mirror_layout,
    mirror_mounts,
    mirrors_for,
    render_mirrors,
)

SIZE = (800, 140)


def test_layout_centres_the_rear_mirror_and_puts_the_side_mirrors_at_the_ends():
    lay = mirror_layout(SIZE)
    assert set(lay) == set(MIRRORS)
    x, y, w, h = lay["rear"]
    # 0.42 of 800 = 336 px with a 2 px frame on each side; the full height less the frame
    assert (w, h) == (332, 136) and x + w / 2 == SIZE[0] / 2 and y == 2
    assert lay["left"] == (2, 2, 156, 108)  # 0.2 of 800 less the frame; 0.8 of 140 = 112 less the frame
    assert lay["right"] == (800 - 2 - 156, 2, 156, 108)
    with pytest.raises(ValueError, match="at least 8x8 px"):
        mirror_layout((40, 10))


def test_mounts_look_back_and_the_side_mirrors_outwards():
    cam = Mount(0.5, 0.0, 1.3, math.radians(3.0), 0.0)
    m = mirror_mounts(cam, MirrorSettings(side_outward_deg=10.0))
    assert m["rear"].yaw_rad == pytest.approx(math.pi) and m["rear"].forward_m == 0.5 and m["rear"].height_m == 1.3
    # the optical axis in the ego frame (x forward, y right): straight back, back-left, back-right
    for name, (ax, ay) in {"rear": (-1.0, 0.0), "left": (-math.cos(0.1745), -math.sin(0.1745)),
                           "right": (-math.cos(0.1745), math.sin(0.1745))}.items():
        yaw = m[name].yaw_rad
        assert (math.cos(yaw), math.sin(yaw)) == pytest.approx((ax, ay), abs=1e-3), name
    assert m["left"].lateral_m < 0 < m["right"].lateral_m


@pytest.fixture
def env(small_config):
    cfg = {**small_config, "camera": {"enabled": True, "width_px": 160, "height_px": 90}}
    e = DTHighwayEnv(config=cfg)
    e.reset(seed=0)
    yield e
    e.close()


def _only(env: DTHighwayEnv, offsets: list[tuple[float, float]]) -> None:
    """Keep the ego and place other vehicles at ``(dx, dy)`` from it, parallel to it [m]."""
    ego = env.vehicle
    pool = env.__dict__.setdefault("_test_pool", [v for v in env.road.vehicles if v is not ego])
    others = pool[: len(offsets)]
    for v, (dx, dy) in zip(others, offsets, strict=True):
        v.position = ego.position + np.array([dx, dy])
        v.heading = ego.heading
    env.road.vehicles = [ego, *others]


def _changed(env: DTHighwayEnv, strip: np.ndarray, empty: np.ndarray, name: str) -> tuple[np.ndarray, np.ndarray]:
    x, y, w, h = mirror_layout(SIZE)[name]
    diff = np.any(strip[y:y + h, x:x + w] != empty[y:y + h, x:x + w], axis=2)
    rows, cols = np.nonzero(diff)
    return rows, cols


def test_a_car_behind_is_in_the_rear_mirror_and_a_car_ahead_is_not(env):
    ego = env.vehicle
    env.vehicle.heading = 0.0
    _only(env, [])
    empty = render_mirrors(env, SIZE)
    assert empty.shape == (SIZE[1], SIZE[0], 3) and empty.dtype == np.uint8
    assert (empty[0, 0] == BEZEL).all() and (empty[-1, SIZE[0] // 2 - 170] == BEZEL).all()  # the strip's background

    _only(env, [(40.0, 0.0)])  # ahead: none of the mirrors sees it
    ahead = render_mirrors(env, SIZE)
    assert np.array_equal(ahead, empty)

    _only(env, [(-10.0, 0.0)])  # right behind, same lane
    behind = render_mirrors(env, SIZE)
    rows, cols = _changed(env, behind, empty, "rear")
    x, y, w, h = mirror_layout(SIZE)["rear"]
    assert len(cols) > 1500
    # centred; its rear face (2 m wide, 10 + 0.5 - 2.5 = 8 m from the eye) is f 2 / 8 px wide,
    # f = 332 / (2 tan 25 deg) = 356 px: 89 px
    f = w / (2 * math.tan(math.radians(25.0)))
    assert (cols.min() + cols.max()) / 2 == pytest.approx((w - 1) / 2, abs=2)
    assert cols.max() - cols.min() + 1 == pytest.approx(f * ego.WIDTH / 8.0, abs=4)
    # the car's roof is above the horizon (40 % from the top): the eye at 1.3 m, the roof at 1.5 m
    assert rows.min() < 0.4 * h < rows.max()


def test_the_mirror_is_flipped_a_car_behind_left_shows_on_the_left(env):
    env.vehicle.heading = 0.0
    _only(env, [])
    empty = render_mirrors(env, SIZE)
    w = mirror_layout(SIZE)["rear"][2]
    for dy, side in ((-4.0, "left"), (4.0, "right")):  # y grows to the ego's right
        _only(env, [(-15.0, dy)])
        strip = render_mirrors(env, SIZE)
        _, cols = _changed(env, strip, empty, "rear")
        assert len(cols) > 300
        centre = (cols.min() + cols.max()) / 2
        assert (centre < w / 2) if side == "left" else (centre > w / 2), (side, centre)
        # and it is in that side's mirror, not in the other one
        other = "right" if side == "left" else "left"
        assert len(_changed(env, strip, empty, side)[1]) > 100
        assert len(_changed(env, strip, empty, other)[1]) == 0


def test_draw_mirrors_paints_only_the_mirrors_over_the_frame(env):
    frame = np.full((360, 640, 3), 7, np.uint8)
    out = draw_mirrors(frame, env)
    assert out is frame
    # strip 0.6 x 640 = 384 px wide, centred: outside it and below it the frame is untouched
    assert (frame[:, : (640 - 384) // 2 - 1] == 7).all() and (frame[100:] == 7).all()
    assert (frame[30, 320] != 7).any()  # the rear-view mirror, top centre
    # the same renderers are kept for the same size (made once per env and size)
    assert mirrors_for(env, (384, 61)) is mirrors_for(env, (384, 61))


def test_renderers_are_kept_per_size_and_remade_when_the_camera_changes(env):
    a, b = mirrors_for(env, (400, 100)), mirrors_for(env, (500, 120))
    assert mirrors_for(env, (400, 100)) is a and mirrors_for(env, (500, 120)) is b  # both sizes kept
    assert a.renderers["rear"].camera.intrinsics.width_px == round(400 * 0.42) - 4
    env.configure({"camera": {"mount": {"height_m": 1.6}}})  # the driver's eye higher: the rear-view mirror follows
    c = mirrors_for(env, (400, 100))
    assert c is not a and c.renderers["rear"].camera.mount.height_m == 1.6


def test_far_cars_are_left_out_beyond_each_mirrors_range(env):
    env.vehicle.heading = 0.0
    _only(env, [])
    empty = render_mirrors(env, SIZE)
    _only(env, [(-80.0, 4.0)])  # 80 m back, a lane to the right: beyond the side mirrors' 60 m, within the rear's 100 m
    strip = render_mirrors(env, SIZE)
    assert len(_changed(env, strip, empty, "rear")[1]) > 0
    assert len(_changed(env, strip, empty, "right")[1]) == 0

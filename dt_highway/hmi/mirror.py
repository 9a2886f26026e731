"""The driving window's mirrors: a rear-view mirror and two side mirrors, drawn by the ego camera's
own renderer (for the person at the wheel and the replay; no driver policy sees them).

Each mirror is a :class:`~dt_highway.camera.render.CameraRenderer` looking back from the ego
(the optical axis turned by ``pi``), its picture flipped left-right as a mirror shows it: a car
behind in the lane to the ego's left appears on the mirror's left. The rear-view mirror sits at
the ego camera's mount (the driver's eye), the side mirrors at the ego's sides, turned outwards
so that they show the neighbouring lanes behind (the ego itself is never drawn, so nothing of
it hides the view).

The three pictures are laid out in a strip, the rear-view mirror in the centre and the side
mirrors at the ends (:func:`mirror_layout`); :func:`render_mirrors` returns the strip,
:func:`draw_mirrors` draws it over the top of a frame (the window's picture), leaving the
frame visible between the mirrors. The renderers are made once per env and strip size and
kept while the road and the camera settings stay the same.

The mirrors render the simulator's vehicles the way the ego camera does: what a driver sees,
no ground truth (the renderer's truth output is dropped here).
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import cv2
import numpy as np

from dt_highway.camera.pinhole import Intrinsics, Mount, PinholeCamera, Pose
from dt_highway.camera.render import CameraRenderer, RenderSettings
from dt_highway.camera.scene import RoadScene, VehicleSet

if TYPE_CHECKING:
    from highway_env.road.road import Road

    from dt_highway.config import CameraConfig
    from dt_highway.env.core import DTHighwayEnv

MIRRORS = ("left", "rear", "right")
"""The mirrors, left to right as they appear in the strip"""
BEZEL = (18, 18, 20)
"""Colour of the mirrors' frames and of the strip's background (RGB)"""


@dataclass(frozen=True)
class MirrorSettings:
    """Where the mirrors look from and how they are laid out.

    :param rear_hfov_deg: horizontal field of view of the rear-view mirror [deg]
    :param side_hfov_deg: horizontal field of view of each side mirror [deg]
    :param side_outward_deg: how far the side mirrors are turned outwards from straight back [deg]
    :param side_forward_m: the side mirrors' place ahead of the ego's centre [m]
    :param side_lateral_m: their distance from the ego's centre line [m]
    :param side_height_m: their height above the road [m]
    :param horizon_frac: where the horizon lies in a mirror, as a fraction of its height from the top
    :param rear_width_frac: the rear-view mirror's width, fraction of the strip's width
    :param side_width_frac: each side mirror's width, fraction of the strip's width
    :param side_height_frac: each side mirror's height, fraction of the strip's height
    :param rear_max_range_m: farthest distance the rear-view mirror draws [m] (at most the camera's
        ``max_range_m``; a car 2 m wide is 4 px wide there in a mirror 180 px wide)
    :param side_max_range_m: farthest distance a side mirror draws [m] (at most the camera's)
    :param bezel_px: width of a mirror's frame [px]
    """

    rear_hfov_deg: float = 50.0
    side_hfov_deg: float = 40.0
    side_outward_deg: float = 14.0
    side_forward_m: float = 1.0
    side_lateral_m: float = 1.05
    side_height_m: float = 1.1
    horizon_frac: float = 0.4
    rear_width_frac: float = 0.42
    side_width_frac: float = 0.2
    side_height_frac: float = 0.8
    rear_max_range_m: float = 100.0
    side_max_range_m: float = 60.0
    bezel_px: int = 2


def mirror_layout(size: tuple[int, int], settings: MirrorSettings = MirrorSettings()) -> dict[str, tuple[int, int, int, int]]:
    """Where each mirror's picture lies in a strip (inside its frame).

    :param size: the strip's ``(width, height)`` [px]
    :param settings: the layout's fractions
    :return: per mirror (:data:`MIRRORS`), ``(x, y, width, height)`` of its picture in the strip [px]
    :raises ValueError: when the strip is too small for three mirrors of at least 8x8 px
    """
    w, h = size
    b = settings.bezel_px
    rear_w = int(round(w * settings.rear_width_frac)) - 2 * b
    side_w = int(round(w * settings.side_width_frac)) - 2 * b
    rear_h = h - 2 * b
    side_h = int(round(h * settings.side_height_frac)) - 2 * b
    if min(rear_w, side_w, rear_h, side_h) < 8:
        raise ValueError(f"a mirror strip must leave every mirror at least 8x8 px (got a strip of {w}x{h} px)")
    return {
        "left": (b, b, side_w, side_h),
        "rear": ((w - rear_w) // 2, b, rear_w, rear_h),
        "right": (w - b - side_w, b, side_w, side_h),
    }


def mirror_mounts(camera_mount: Mount, settings: MirrorSettings = MirrorSettings()) -> dict[str, Mount]:
    """The mirrors' viewpoints on the ego, each looking back (yaw turned by ``pi``).

    :param camera_mount: the ego camera's mount: the rear-view mirror looks from there
    :param settings: the side mirrors' place and turn
    :return: per mirror, its mount (the picture is then flipped left-right)
    """
    out_rad = math.radians(settings.side_outward_deg)
    back = camera_mount.yaw_rad + math.pi
    side = {"left": (-1.0, back + out_rad), "right": (1.0, back - out_rad)}  # yaw > pi turns the axis to the left
    mounts = {"rear": Mount(camera_mount.forward_m, camera_mount.lateral_m, camera_mount.height_m,
                            camera_mount.pitch_rad, back)}
    for name, (sign, yaw) in side.items():
        mounts[name] = Mount(settings.side_forward_m, sign * settings.side_lateral_m, settings.side_height_m,
                             camera_mount.pitch_rad, yaw)
    return mounts


class Mirrors:
    """The three mirror renderers of one strip size.

    :param camera: the ego camera's configuration (mount, near plane, range, car height)
    :param scene: the road
    :param size: the strip's ``(width, height)`` [px]
    :param settings: the mirrors' viewpoints and layout
    """

    def __init__(self, camera: CameraConfig, scene: RoadScene, size: tuple[int, int],
                 settings: MirrorSettings = MirrorSettings()) -> None:
        self.size = (int(size[0]), int(size[1]))
        self.settings = settings
        self.layout = mirror_layout(self.size, settings)
        m = camera.mount
        base = Mount(m.forward_m, m.lateral_m, m.height_m, math.radians(m.pitch_deg), math.radians(m.yaw_deg))
        mounts = mirror_mounts(base, settings)
        self.renderers: dict[str, CameraRenderer] = {}
        for name in MIRRORS:
            _, _, w, h = self.layout[name]
            rear = name == "rear"
            max_range = min(settings.rear_max_range_m if rear else settings.side_max_range_m, camera.max_range_m)
            render = RenderSettings(max_range_m=max(max_range, camera.near_m * 2),
                                    vehicle_height_m=camera.vehicle_height_m, detail_min_px=camera.detail_min_px)
            hfov = settings.rear_hfov_deg if rear else settings.side_hfov_deg
            intr = Intrinsics.from_fov(w, h, math.radians(hfov), cy_px=settings.horizon_frac * (h - 1))
            self.renderers[name] = CameraRenderer(PinholeCamera(intr, mounts[name], camera.near_m), scene, render)

    def pictures(self, pose: Pose, vehicles: VehicleSet) -> dict[str, np.ndarray]:
        """Each mirror's picture, already flipped left-right.

        :param pose: the ego's pose
        :param vehicles: the vehicles around (not the ego)
        :return: per mirror, ``uint8 (h, w, 3)`` RGB
        """
        out = {}
        for name, renderer in self.renderers.items():
            image, _ = renderer.render(pose, vehicles)
            out[name] = image.rgb[:, ::-1]
        return out

    def strip(self, pose: Pose, vehicles: VehicleSet) -> np.ndarray:
        """The strip: the mirrors in their frames on the bezel colour.

        :param pose: the ego's pose
        :param vehicles: the vehicles around (not the ego)
        :return: ``uint8 (height, width, 3)`` RGB
        """
        w, h = self.size
        out = np.empty((h, w, 3), np.uint8)
        out[:] = BEZEL
        for name, pic in self.pictures(pose, vehicles).items():
            x, y, pw, ph = self.layout[name]
            out[y:y + ph, x:x + pw] = pic
        return out

    def draw(self, frame: np.ndarray, pose: Pose, vehicles: VehicleSet, top_px: int = 0) -> np.ndarray:
        """Draw the mirrors (with their frames) over a frame, in place; the frame shows between them.

        :param frame: ``uint8 (H, W, 3)`` RGB, at least as wide as the strip
        :param pose: the ego's pose
        :param vehicles: the vehicles around (not the ego)
        :param top_px: the strip's top row in the frame [px]
        :return: ``frame``
        """
        w, h = self.size
        x0 = (frame.shape[1] - w) // 2
        b = self.settings.bezel_px
        for name, pic in self.pictures(pose, vehicles).items():
            x, y, pw, ph = self.layout[name]
            fx, fy = x0 + x, top_px + y
            cv2.rectangle(frame, (fx - b, fy - b), (fx + pw + b - 1, fy + ph + b - 1), BEZEL, -1)
            frame[fy:fy + ph, fx:fx + pw] = pic
        return frame


@dataclass
class _Cached:
    road: Road
    scene: RoadScene
    camera_json: str
    mirrors: dict[tuple[object, ...], Mirrors] = field(default_factory=dict)


_CACHE: weakref.WeakKeyDictionary[DTHighwayEnv, _Cached] = weakref.WeakKeyDictionary()
CACHED_SIZES = 4
"""Strip sizes whose renderers are kept per env (a window resized back and forth)"""


def mirrors_for(env: DTHighwayEnv, size: tuple[int, int], settings: MirrorSettings = MirrorSettings()) -> Mirrors:
    """The env's mirrors for a strip size, made on the first call and kept while the road and the
    camera's configuration stay the same (the last :data:`CACHED_SIZES` sizes and settings).

    :param env: the dt-highway env (unwrapped), after ``reset``
    :param size: the strip's ``(width, height)`` [px]
    :param settings: the mirrors' viewpoints and layout
    :return: the mirrors' renderers
    """
    cached = _CACHE.get(env)
    road = env.road
    if cached is None or cached.road is not road:  # a new episode: same renderers if the road is the same
        scene = RoadScene.from_road(road)
        if cached is None or cached.scene != scene:
            cached = _Cached(road, scene, "")
        cached.road = road
        _CACHE[env] = cached
    camera_json = env.dt_config.camera.model_dump_json()
    if camera_json != cached.camera_json:
        cached.mirrors.clear()
        cached.camera_json = camera_json
    key = (int(size[0]), int(size[1]), settings)
    mirrors = cached.mirrors.pop(key, None)
    if mirrors is None:
        mirrors = Mirrors(env.dt_config.camera, cached.scene, size, settings)
        while len(cached.mirrors) >= CACHED_SIZES:
            cached.mirrors.pop(next(iter(cached.mirrors)))
    cached.mirrors[key] = mirrors  # most recent last
    return mirrors


def _ego_view(env: DTHighwayEnv) -> tuple[Pose, VehicleSet]:
    ego = env.vehicle
    pose = Pose(float(ego.position[0]), float(ego.position[1]), float(ego.heading))
    return pose, VehicleSet.from_road(env.road, exclude=ego)


def render_mirrors(env: DTHighwayEnv, size: tuple[int, int], settings: MirrorSettings = MirrorSettings()) -> np.ndarray:
    """The mirror strip of the env's current state: the rear-view mirror in the centre, the side
    mirrors at the ends, each rendered by the ego camera's renderer looking back and flipped
    left-right (see the module docstring).

    :param env: the dt-highway env (unwrapped), after ``reset``
    :param size: the strip's ``(width, height)`` [px]
    :param settings: the mirrors' viewpoints and layout
    :return: ``uint8 (height, width, 3)`` RGB; between the mirrors the colour :data:`BEZEL`
    :raises ValueError: when the strip is too small (:func:`mirror_layout`)
    """
    pose, vehicles = _ego_view(env)
    return mirrors_for(env, size, settings).strip(pose, vehicles)


def draw_mirrors(frame: np.ndarray, env: DTHighwayEnv, height_frac: float = 0.17, width_frac: float = 0.6,
                 top_px: int | None = None, settings: MirrorSettings = MirrorSettings()) -> np.ndarray:
    """Draw the env's mirrors over the top of a frame (the window's picture), in place.

    :param frame: ``uint8 (H, W, 3)`` RGB
    :param env: the dt-highway env (unwrapped), after ``reset``
    :param height_frac: the strip's height, fraction of the frame's height
    :param width_frac: the strip's width, fraction of the frame's width (centred)
    :param top_px: the strip's top row [px] (``None``: 1 % of the frame's height)
    :param settings: the mirrors' viewpoints and layout
    :return: ``frame``
    """
    fh, fw = frame.shape[:2]
    size = (int(round(fw * width_frac)), int(round(fh * height_frac)))
    top = int(round(0.01 * fh)) if top_px is None else top_px
    pose, vehicles = _ego_view(env)
    return mirrors_for(env, size, settings).draw(frame, pose, vehicles, top + settings.bezel_px)

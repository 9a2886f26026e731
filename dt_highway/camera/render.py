"""The ego's synthetic camera: an RGB + depth + instance renderer on the CPU.

The paper's ego carries an RGB camera and a depth camera (Unity). This module draws the
same two images, plus an instance-id map and the ground-truth boxes, from highway-env's
2-D world, fast enough for real-time trials (see ``dt-highway bench camera``).

How a frame is made
-------------------
1. **Ground and sky.** The road (asphalt, shoulders, solid edge lines, dashed lane lines,
   grass) is a top-down texture, periodic along the road. The ground plane maps to the
   image by a homography ``H = K [r1 r2 t]`` (the pinhole model of
   :mod:`dt_highway.camera.pinhole` restricted to ``z = 0``), so one
   ``cv2.warpPerspective`` draws it. Rows beyond ``max_range_m`` fade into the sky's haze.
2. **Vehicles.** Each vehicle is a car: a body box and a cabin (a frustum, glass on its
   sides), with tail lights, headlights, number plate, wheels and a dark lower band drawn on
   the body as decals. Faces are shaded by their direction to the sun.
3. **Exact occlusion.** Vehicles are painted far to near in an order that is exact, not a
   sort by distance: for two vehicles whose image boxes overlap, a line separating their
   footprints (separating-axis test) tells which one a ray from the camera meets first;
   a topological sort of those relations gives the painting order (for disjoint convex
   footprints seen from a point such an order always exists). Inside a car, back faces are
   culled and the cabin is painted after the body when the camera is above the body's top
   (before it otherwise), which is exact too. Each painted polygon writes its colour into
   the RGB image and its id into a face map, from which depth and instance ids are read.
4. **Depth.** On a planar face ``1 / Z`` is affine in the pixel coordinates, so each
   pixel's depth is exact for the face it shows (no interpolation error).

Outputs and conventions
-----------------------
:meth:`CameraRenderer.render` returns two objects: the :class:`CameraImage` (what the
camera delivers: ``rgb``, ``depth_m``, the pose and the time) and, apart, the
:class:`~dt_highway.camera.truth.CameraTruth` (``instance`` and ``vehicles``).

* ``rgb``: ``uint8 (H, W, 3)``.
* ``depth_m``: ``float32 (H, W)``, **planar depth** ``Z`` along the optical axis [m]
  (CARLA's convention), saturated at ``max_range_m`` (sky, and ground farther than it).
  :meth:`CameraImage.range_m` gives the Euclidean range from the camera centre instead.
* ``instance``: ``int32 (H, W)``, 0 = background (road, sky), else the vehicle id.
* ``vehicles``: per vehicle drawn, a :class:`~dt_highway.camera.truth.VehicleTruth` (visible
  box, amodal box, visibility). Boxes are ``(x1, y1, x2, y2)`` [px] in the image frame where pixel
  ``(col, row)`` covers ``[col - 0.5, col + 0.5] x [row - 0.5, row + 0.5]`` (pixel centres
  at integer coordinates, as in OpenCV and :mod:`~dt_highway.camera.pinhole`).
  Polygons are filled with OpenCV's inclusive rule (1/16 px vertex precision), so a
  silhouette can be up to one pixel wider than the exact projection; the visible box,
  pixel counts and visibility all use the same pixels.

``instance`` and ``vehicles`` are simulator ground truth: for evaluation, training labels and
the simulated detector, never for what a driver, the fusion or the twin sees.

Limits: straight highways along ``+x`` (the road of ``dt-highway-v0``), drawn endless;
the ego (the camera's carrier) is not drawn; vehicles whose centre is farther than
``max_range_m`` along the optical axis are not drawn.
"""

from __future__ import annotations

import heapq
import math
import numbers
from dataclasses import dataclass, field

import cv2
import numpy as np
from pydantic import Field

from dt_highway.camera.pinhole import PinholeCamera, Pose
from dt_highway.camera.scene import RoadScene, VehicleSet
from dt_highway.camera.truth import CameraTruth, VehicleTruth
from dt_highway.config import CameraConfig, FrozenSettings, section_field

_SHIFT = 4
"""Fixed-point bits of polygon vertices given to OpenCV (1/16 px precision)"""
_ONE = 1 << _SHIFT


# ----------------------------------------------------------------------------- settings and outputs
class RenderSettings(FrozenSettings):
    """Scene settings of the renderer; those a user sets take their defaults and ranges from
    the ``camera`` section (:class:`~dt_highway.config.CameraConfig`).

    :param max_range_m: farthest distance drawn (ground, vehicles); the depth image
        saturates there [m]
    :param vehicle_height_m: height of a car [m]
    :param fog_start: fraction of ``max_range_m`` where the ground starts to fade into haze
    :param detail_min_px: lights, plates and wheels are drawn on vehicles at least this wide
        in the image [px] (a level of detail: smaller ones would not show them)
    """

    max_range_m: float = section_field(CameraConfig, "max_range_m")
    vehicle_height_m: float = section_field(CameraConfig, "vehicle_height_m")
    fog_start: float = Field(default=0.45, ge=0, le=1)
    detail_min_px: float = section_field(CameraConfig, "detail_min_px")


@dataclass(frozen=True)
class CameraImage:
    """One rendered image, what the camera delivers (see the module docstring for conventions);
    its ground truth is a separate :class:`~dt_highway.camera.truth.CameraTruth`.

    :param rgb: ``uint8 (H, W, 3)`` colour image
    :param depth_m: ``float32 (H, W)`` planar depth [m]
    :param pose: the ego pose the image was rendered from
    :param time_s: simulation time of the image [s] (NaN when not given)
    """

    rgb: np.ndarray
    depth_m: np.ndarray
    pose: Pose
    time_s: float = math.nan
    _ray_norm: np.ndarray | None = field(default=None, repr=False)
    """The renderer's ray norms (one read-only array shared by all its images)"""

    def range_m(self) -> np.ndarray:
        """Euclidean range image ``float32 (H, W)`` [m]: distance from the camera centre.

        :return: ``float32 (H, W)`` distance of each pixel's point from the camera centre [m]
        :raises ValueError: if the image carries no ray norms (not made by the renderer)
        """
        if self._ray_norm is None:
            raise ValueError("this image has no ray norms (build it with CameraRenderer.render)")
        return self.depth_m * self._ray_norm

    def read_only_copy(self) -> CameraImage:
        """A copy of this image whose arrays are read-only and shared with nothing: what a
        driver is given (:func:`~dt_highway.env.senses.perceive`). Writing into it raises
        ``ValueError``; even with its flags set writeable again it cannot reach this image.

        :return: the read-only copy
        """
        ray = self._ray_norm
        return CameraImage(_read_only_copy(self.rgb), _read_only_copy(self.depth_m), self.pose, self.time_s,
                           None if ray is None else _read_only_copy(ray))


def _read_only_copy(a: np.ndarray) -> np.ndarray:
    out = np.array(a, copy=True)
    out.flags.writeable = False
    return out


# ----------------------------------------------------------------------------- the car model
_PAINTS = np.array(
    [
        (226, 226, 222), (172, 176, 180), (38, 38, 42), (88, 92, 96), (168, 28, 30), (32, 62, 142),
        (28, 38, 72), (42, 92, 62), (222, 182, 44), (208, 112, 34), (190, 170, 132), (122, 162, 202),
    ],
    dtype=float,
)
"""Car paints; a vehicle's paint follows from its id alone (never from its driver type)"""
_GLASS = (44, 54, 66)
_DECAL_COLOURS = {
    "tail": (196, 22, 28),
    "head": (236, 234, 210),
    "plate": (226, 226, 216),
    "wheel": (22, 22, 24),
    "band": (48, 48, 52),
}
_SUN = np.array([-0.45, 0.35, 0.82]) / np.linalg.norm([-0.45, 0.35, 0.82])
"""Direction towards the sun, world frame, z up"""


@dataclass(frozen=True)
class _Model:
    """A vehicle shape in units of (length, width, height) around the vehicle's centre."""

    vertices: np.ndarray  # (V, 3) in units of (L, W, H); z up from the road
    faces: np.ndarray  # (F, 4) vertex indices of the shape's faces
    face_part: np.ndarray  # (F,) which convex part a face belongs to
    face_glass: np.ndarray  # (F,) glass faces (not painted)
    part_vertices: tuple[np.ndarray, ...]  # vertex indices of each part
    decals: np.ndarray  # (D, 4) vertex indices of decals
    decal_face: np.ndarray  # (D,) the face a decal lies on
    decal_kind: tuple[str, ...]
    body_top: float  # height of the body's top in units of H
    normals: np.ndarray  # (F, 3) outward unit normals in the unit frame (x fwd, y right, z up)


def _frustum(x0: float, x1: float, y0: float, y1: float, z0: float, z1: float, inset_x: tuple[float, float] = (0.0, 0.0),
             inset_y: float = 0.0) -> tuple[list[tuple[float, float, float]], list[tuple[int, int, int, int]]]:
    bx = [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
    tx = [(x0 + inset_x[0], y0 + inset_y), (x1 - inset_x[1], y0 + inset_y), (x1 - inset_x[1], y1 - inset_y),
          (x0 + inset_x[0], y1 - inset_y)]
    verts = [(x, y, z0) for x, y in bx] + [(x, y, z1) for x, y in tx]
    # rear, front, left (low y), right, top; the bottom is never seen
    faces = [(0, 3, 7, 4), (1, 2, 6, 5), (0, 1, 5, 4), (3, 2, 6, 7), (4, 5, 6, 7)]
    return verts, faces


def _car_model(body_top: float = 0.55) -> _Model:
    body_v, body_f = _frustum(-0.5, 0.5, -0.5, 0.5, 0.0, body_top)
    cab_v, cab_f = _frustum(-0.36, 0.2, -0.46, 0.46, body_top, 1.0, inset_x=(0.08, 0.17), inset_y=0.07)
    verts = body_v + cab_v
    faces = body_f + [tuple(i + 8 for i in f) for f in cab_f]
    face_part = [0] * 5 + [1] * 5
    face_glass = [False] * 5 + [True, True, True, True, False]
    decal_rows: list[tuple[int, str, list[tuple[float, float, float]]]] = []

    def on_end(face: int, x: float, y0: float, y1: float, z0: float, z1: float, kind: str) -> None:
        decal_rows.append((face, kind, [(x, y0, z0), (x, y1, z0), (x, y1, z1), (x, y0, z1)]))

    def on_side(face: int, y: float, x0: float, x1: float, z0: float, z1: float, kind: str) -> None:
        decal_rows.append((face, kind, [(x0, y, z0), (x1, y, z0), (x1, y, z1), (x0, y, z1)]))

    h = body_top
    on_end(0, -0.5, -0.5, 0.5, 0.0, 0.3 * h, "band")
    on_end(0, -0.5, -0.47, -0.29, 0.62 * h, 0.86 * h, "tail")
    on_end(0, -0.5, 0.29, 0.47, 0.62 * h, 0.86 * h, "tail")
    on_end(0, -0.5, -0.13, 0.13, 0.36 * h, 0.52 * h, "plate")
    on_end(1, 0.5, -0.5, 0.5, 0.0, 0.3 * h, "band")
    on_end(1, 0.5, -0.46, -0.28, 0.6 * h, 0.8 * h, "head")
    on_end(1, 0.5, 0.28, 0.46, 0.6 * h, 0.8 * h, "head")
    for face, y in ((2, -0.5), (3, 0.5)):
        on_side(face, y, -0.5, 0.5, 0.0, 0.3 * h, "band")
        on_side(face, y, -0.39, -0.23, 0.0, 0.5 * h, "wheel")
        on_side(face, y, 0.23, 0.39, 0.0, 0.5 * h, "wheel")
    v = np.array(verts, dtype=float)
    normals = []
    for f, part in zip(faces, face_part, strict=True):
        q = v[list(f)]
        n = np.cross(q[1] - q[0], q[2] - q[0])
        part_centre = v[:8].mean(axis=0) if part == 0 else v[8:16].mean(axis=0)
        if n @ (q.mean(axis=0) - part_centre) < 0:
            n = -n
        normals.append(n / np.linalg.norm(n))
    decal_idx = []
    for _, _, quad in decal_rows:
        decal_idx.append(tuple(range(len(verts), len(verts) + 4)))
        verts.extend(quad)
    return _Model(
        vertices=np.array(verts, dtype=float),
        faces=np.array(faces, dtype=np.intp),
        face_part=np.array(face_part),
        face_glass=np.array(face_glass),
        part_vertices=(np.arange(8), np.arange(8, 16)),
        decals=np.array(decal_idx, dtype=np.intp),
        decal_face=np.array([r[0] for r in decal_rows]),
        decal_kind=tuple(r[1] for r in decal_rows),
        body_top=body_top,
        normals=np.array(normals),
    )


CAR = _car_model()


def paint_of(vehicle_ids: np.ndarray) -> np.ndarray:
    """Paint colours ``(N, 3)`` of vehicles, a hash of their ids (Knuth's multiplicative).

    :param vehicle_ids: vehicle ids ``(N,)``
    :return: ``float (N, 3)`` RGB paint per vehicle, in 0-255
    """
    h = (np.asarray(vehicle_ids, dtype=np.uint64) * np.uint64(2654435761)) % np.uint64(2**32)
    return _PAINTS[(h >> np.uint64(7)) % np.uint64(len(_PAINTS))]


# ----------------------------------------------------------------------------- ground
class _Ground:
    """The road texture and the parts of the frame that do not move (sky, ground depth).

    Seen from a driver's eye the road is squeezed along its length: a pixel row 30 m ahead
    covers metres of road. Sampling the full texture there would flicker (dashes alias) and
    read memory all over the texture, so each band of rows samples a copy of the texture
    averaged along the road by a power of two that matches its footprint (a one-axis
    mip-map, "rip-map"); across the road it keeps full resolution, so far lane lines stay.
    """

    PX_PER_M_ALONG = 8.0
    """Texture resolution along the road [px/m]"""
    PX_PER_M_ACROSS = 12.0
    """Texture resolution across the road [px/m]"""
    DASH_M = 3.0
    """Length of a lane-line dash [m]"""
    GAP_M = 9.0
    """Gap between dashes [m] (3 m + 9 m: the US interstate pattern)"""
    DIVIDER_WIDTH_M = 0.15
    """Width of dashed lane dividers [m]"""
    EDGE_WIDTH_M = 0.2
    """Width of solid edge lines [m]"""
    SHOULDER_M = 2.5
    """Paved shoulder beyond each edge line [m]"""
    GRASS_M = 6.0
    """Textured grass beyond the shoulders [m] (plain grass farther out)"""
    LEVELS = 7
    """Along-road averaging levels: 2, 4, ... 2^LEVELS texels per sample"""
    ASPHALT = (92, 94, 98)
    SHOULDER = (112, 112, 110)
    PAINT = (232, 232, 226)
    GRASS = (86, 122, 62)
    SKY_TOP = (92, 142, 210)
    HAZE = (200, 212, 222)

    def __init__(self, scene: RoadScene, camera: PinholeCamera, settings: RenderSettings) -> None:
        k = camera.intrinsics
        self.period_m = self.DASH_M + self.GAP_M
        # the texture is placed in whole multiples of this, so every level stays aligned
        self.align_m = self.period_m * 2**self.LEVELS / math.gcd(int(self.period_m * self.PX_PER_M_ALONG), 2**self.LEVELS)
        self.y0_m = scene.y_min_m - self.SHOULDER_M - self.GRASS_M
        tex = self._texture(scene, settings.max_range_m)
        ny, nx = tex.shape[:2]
        self.levels = [tex] + [
            cv2.resize(tex, (nx >> lv, ny), interpolation=cv2.INTER_AREA) for lv in range(1, self.LEVELS + 1)
        ]
        w, h = k.width_px, k.height_px
        # planar depth of the ground at each pixel: Z = height / (n . K^-1 [u, v, 1]),
        # n the world's down axis in the camera frame (independent of the ego's pose)
        rot, _ = camera.extrinsics(Pose(0.0, 0.0, 0.0))
        n_c = rot[:, 2]
        u = (np.arange(w) - k.cx_px) / k.fx_px
        v = (np.arange(h) - k.cy_px) / k.fy_px
        denom = n_c[0] * u[None, :] + n_c[1] * v[:, None] + n_c[2]
        with np.errstate(divide="ignore"):
            z = np.where(denom > 1e-12, camera.mount.height_m / np.maximum(denom, 1e-12), np.inf)
        far = settings.max_range_m
        # the camera has no roll, so the horizon is a row: the ground starts at the first
        # row whose every pixel is nearer than max_range
        ground_rows = np.flatnonzero(np.all(z <= far, axis=1))
        self.row0 = int(ground_rows[0]) if len(ground_rows) else h
        self.depth = np.minimum(z, far).astype(np.float32)
        sky = np.empty((h, w, 3), dtype=float)
        frac = np.clip(np.arange(h) / max(self.row0, 1), 0.0, 1.0)[:, None, None] ** 0.6
        sky[:] = np.array(self.SKY_TOP) * (1 - frac) + np.array(self.HAZE) * frac
        self.sky = sky.astype(np.uint8)
        # haze over far ground: a blend factor per ground row
        zr = z[self.row0 :, w // 2] if self.row0 < h else np.zeros(0)
        alpha = np.clip((zr - settings.fog_start * far) / max((1 - settings.fog_start) * far, 1e-9), 0.0, 1.0)
        fog_rows = np.flatnonzero(alpha > 0)
        self.fog_end = int(fog_rows[-1]) + 1 if len(fog_rows) else 0
        self.fog_alpha = alpha[: self.fog_end, None, None].astype(np.float32)
        # bands of rows by along-road footprint: texels of level 0 per pixel row (looking
        # along the road; the ego's heading is small on a highway)
        self.bands: list[tuple[int, int, int]] = []
        if len(zr):
            z_mid = np.minimum(zr, far)
            step_m = np.abs(np.gradient(z_mid)) if len(z_mid) > 1 else np.zeros(1)
            level = np.clip(np.floor(np.log2(np.maximum(step_m * self.PX_PER_M_ALONG, 1.0))), 0, self.LEVELS).astype(int)
            start = 0
            for i in range(1, len(level) + 1):
                if i == len(level) or level[i] != level[start]:
                    self.bands.append((self.row0 + start, self.row0 + i, int(level[start])))
                    start = i

    def _texture(self, scene: RoadScene, max_range_m: float) -> np.ndarray:
        sx, sy, p = self.PX_PER_M_ALONG, self.PX_PER_M_ACROSS, self.period_m
        y1 = scene.y_max_m + self.SHOULDER_M + self.GRASS_M
        ny = int(math.ceil((y1 - self.y0_m) * sy))
        nx_tile = int(round(p * sx))
        ys = self.y0_m + (np.arange(ny) + 0.5) / sy
        xs = (np.arange(nx_tile) + 0.5) / sx
        tile = np.empty((ny, nx_tile, 3), dtype=float)
        paved = (ys >= scene.y_min_m - self.SHOULDER_M) & (ys <= scene.y_max_m + self.SHOULDER_M)
        road = (ys >= scene.y_min_m) & (ys <= scene.y_max_m)
        tile[:] = np.array(self.GRASS)
        tile[paved] = np.array(self.SHOULDER)
        tile[road] = np.array(self.ASPHALT)
        rng = np.random.default_rng(7)  # fixed: the texture is part of the scene, not of an episode
        grain = rng.normal(0.0, 1.0, (ny, nx_tile, 1))
        tile += grain * np.where(paved, 2.5, 9.0)[:, None, None]
        for line in scene.lines:
            width = self.DIVIDER_WIDTH_M if line.dashed else self.EDGE_WIDTH_M
            # paint coverage of each texel row (anti-aliased edges)
            cover = np.clip((width / 2 - np.abs(ys - line.y_m)) * sy + 0.5, 0.0, 1.0)[:, None, None]
            cols = xs < self.DASH_M if line.dashed else np.ones(nx_tile, dtype=bool)
            tile[:, cols] = tile[:, cols] * (1 - cover) + np.array(self.PAINT) * cover
        n_aligned = int(math.ceil((2 * max_range_m + 2 * self.align_m) / self.align_m))
        reps = int(round(n_aligned * self.align_m / p))
        return np.ascontiguousarray(np.tile(np.clip(tile, 0, 255).astype(np.uint8), (1, reps, 1)))

    def _texture_origin(self, cam_x_m: float, max_range_m: float) -> float:
        return math.floor((cam_x_m - max_range_m - self.align_m) / self.align_m) * self.align_m

    def draw(self, rgb: np.ndarray, k_mat: np.ndarray, rot: np.ndarray, t: np.ndarray, cam_x_m: float, far: float) -> None:
        """Sky, ground and haze into ``rgb`` (in place)."""
        h, w = rgb.shape[:2]
        rgb[: self.row0] = self.sky[: self.row0]
        if self.row0 >= h:
            return
        img_from_ground = k_mat @ np.column_stack([rot[:, 0], rot[:, 1], t])
        x0 = self._texture_origin(cam_x_m, far)
        tex_from_ground = np.array(
            [[self.PX_PER_M_ALONG, 0.0, -self.PX_PER_M_ALONG * x0 - 0.5],
             [0.0, self.PX_PER_M_ACROSS, -self.PX_PER_M_ACROSS * self.y0_m - 0.5],
             [0.0, 0.0, 1.0]]
        )
        base = tex_from_ground @ np.linalg.inv(img_from_ground)
        for r0, r1, lv in self.bands:
            s = 1.0 / (1 << lv)
            to_level = np.array([[s, 0.0, 0.5 * s - 0.5], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
            shift = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, float(r0)], [0.0, 0.0, 1.0]])
            cv2.warpPerspective(
                self.levels[lv], to_level @ base @ shift, (w, r1 - r0), dst=rgb[r0:r1],
                flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_CONSTANT, borderValue=self.GRASS,
            )
        if self.fog_end:
            band = rgb[self.row0 : self.row0 + self.fog_end]
            band[:] = band * (1.0 - self.fog_alpha) + np.array(self.HAZE, dtype=np.float32) * self.fog_alpha


# ----------------------------------------------------------------------------- the renderer
class CameraRenderer:
    """Renders what the ego's camera sees.

    :param camera: the pinhole camera (intrinsics, mount, near plane)
    :param scene: the road
    :param settings: scene settings (None: the ``camera`` section's defaults)
    """

    def __init__(self, camera: PinholeCamera, scene: RoadScene, settings: RenderSettings | None = None) -> None:
        settings = settings if settings is not None else RenderSettings()
        if settings.max_range_m <= camera.near_m:
            raise ValueError(f"max_range_m must exceed the near plane {camera.near_m} m (got {settings.max_range_m})")
        self.camera = camera
        self.scene = scene
        self.settings = settings
        self.model = CAR
        k = camera.intrinsics
        self.shape = (k.height_px, k.width_px)
        self._k = k.matrix
        self._ground = _Ground(scene, camera, settings)
        self._face_map = np.zeros(self.shape, dtype=np.int32)
        cols, rows = np.meshgrid(np.arange(k.width_px, dtype=float), np.arange(k.height_px, dtype=float))
        xn = (cols - k.cx_px) / k.fx_px
        yn = (rows - k.cy_px) / k.fy_px
        self._ray_norm = np.sqrt(1.0 + xn * xn + yn * yn).astype(np.float32)
        self._ray_norm.flags.writeable = False  # every image of this renderer shares it
        self._kx = max(k.cx_px + 0.5, k.width_px - 0.5 - k.cx_px) / k.fx_px
        self._ky = max(k.cy_px + 0.5, k.height_px - 0.5 - k.cy_px) / k.fy_px
        m = self.model
        # the decals lying on each face, and every polygon's vertex indices
        self._face_decals = [
            [len(m.faces) + int(j) for j in np.flatnonzero(m.decal_face == f)] for f in range(len(m.faces))
        ]
        self._polys = np.concatenate([m.faces, m.decals])  # (F + D, 4) vertex indices
        decal_colour = np.array([_DECAL_COLOURS[kind] for kind in m.decal_kind], dtype=float)
        self._decal_colour = decal_colour
        self._hull_vertices = np.concatenate(m.part_vertices)
        # faces in painting order: the cabin after the body when the camera is above the
        # body's top, before it otherwise (fixed by the mount and the car's height)
        cam_above_body = camera.mount.height_m >= m.body_top * settings.vehicle_height_m
        self._face_seq = [int(f) for p in ((0, 1) if cam_above_body else (1, 0)) for f in np.flatnonzero(m.face_part == p)]

    # ------------------------------------------------------------------ public
    def render(self, pose: Pose, vehicles: VehicleSet, time_s: float = math.nan) -> tuple[CameraImage, CameraTruth]:
        """Render one frame.

        :param pose: the ego's pose (the camera rides on it)
        :param vehicles: the vehicles to draw (not the ego)
        :param time_s: simulation time stamped on the image [s]
        :return: the image (RGB, planar depth, pose) and, apart, its ground truth (instance
            ids, boxes per vehicle: for evaluation and sensor models only)
        """
        h, w = self.shape
        if len(vehicles) and int(vehicles.ids.min()) <= 0:
            raise ValueError(f"vehicle ids must be >= 1, 0 is the instance map's background (got {int(vehicles.ids.min())})")
        rot, t = self.camera.extrinsics(pose)
        cam_centre = -rot.T @ t  # z down
        rgb = np.empty((h, w, 3), dtype=np.uint8)
        self._ground.draw(rgb, self._k, rot, t, float(cam_centre[0]), self.settings.max_range_m)
        depth = self._ground.depth.copy()
        face_map = self._face_map
        face_map.fill(0)
        truths: dict[int, VehicleTruth] = {}
        instance = None
        if len(vehicles):
            instance = self._draw_vehicles(vehicles, rot, t, cam_centre, rgb, depth, truths)
        if instance is None:
            instance = np.zeros((h, w), dtype=np.int32)
        return CameraImage(rgb, depth, pose, time_s, self._ray_norm), CameraTruth(instance, truths)

    # ------------------------------------------------------------------ vehicles
    def _draw_vehicles(
        self,
        vs: VehicleSet,
        rot: np.ndarray,
        t: np.ndarray,
        cam_centre: np.ndarray,
        rgb: np.ndarray,
        depth: np.ndarray,
        truths: dict[int, VehicleTruth],
    ) -> np.ndarray | None:
        """Paint the vehicles into ``rgb`` and ``depth`` (in place), fill ``truths``.

        :return: the instance map, ``None`` when no vehicle is drawn
        """
        m, s, k = self.model, self.settings, self.camera.intrinsics
        near, far = self.camera.near_m, s.max_range_m
        height = s.vehicle_height_m
        # --- cull by bounding sphere against the view frustum
        centres = np.stack([vs.x_m, vs.y_m, np.full(len(vs), -height / 2)], axis=1) @ rot.T + t
        radius = 0.5 * np.sqrt(vs.length_m**2 + vs.width_m**2 + height**2)
        zc = centres[:, 2]
        keep = (zc + radius > near) & (zc < far)
        keep &= np.abs(centres[:, 0]) - radius * math.sqrt(1 + self._kx**2) <= zc * self._kx
        keep &= np.abs(centres[:, 1]) - radius * math.sqrt(1 + self._ky**2) <= zc * self._ky
        idx = np.flatnonzero(keep)
        if not len(idx):
            return None
        ids = vs.ids[idx]
        n_v = len(idx)
        length, width, heading = vs.length_m[idx], vs.width_m[idx], vs.heading_rad[idx]
        c, sn = np.cos(heading), np.sin(heading)
        # vehicle frame (x fwd, y right, z up) -> camera: rot @ [heading rotation, z mirrored]
        to_world = np.zeros((n_v, 3, 3))
        to_world[:, 0, 0], to_world[:, 0, 1], to_world[:, 1, 0], to_world[:, 1, 1] = c, -sn, sn, c
        to_world[:, 2, 2] = -1.0
        to_cam = rot @ to_world  # (n, 3, 3)
        origin = np.stack([vs.x_m[idx], vs.y_m[idx], np.zeros(n_v)], axis=1) @ rot.T + t  # (n, 3)
        scale = np.stack([length, width, np.full(n_v, height)], axis=1)  # (n, 3)
        pc = (m.vertices[None] * scale[:, None, :]) @ to_cam.transpose(0, 2, 1) + origin[:, None, :]  # (n, V, 3)
        # --- faces: outward normals (scaled template normals), back-face culling, shading
        ns = m.normals[None] / scale[:, None, :]
        ns /= np.linalg.norm(ns, axis=2, keepdims=True)
        sun_local = np.stack([c * _SUN[0] + sn * _SUN[1], -sn * _SUN[0] + c * _SUN[1], np.full(n_v, _SUN[2])], axis=1)
        shade = 0.42 + 0.58 * np.clip(np.einsum("nfk,nk->nf", ns, sun_local), 0.0, None)
        normal = ns @ to_cam.transpose(0, 2, 1)  # camera frame
        d = np.einsum("nfk,nfk->nf", normal, pc[:, m.faces[:, 0]])  # plane: normal . P = d
        front = d < -1e-9  # the camera is on the outer side of the face's plane
        paint = paint_of(ids)
        glass = np.array(_GLASS, dtype=float)[None, None] * (0.75 + 0.25 * shade[..., None])
        colour = np.where(m.face_glass[None, :, None], glass,
                          paint[:, None, :] * shade[..., None])
        colour = np.concatenate([colour, np.broadcast_to(self._decal_colour[None], (len(idx), len(m.decals), 3))
                                 * (0.8 + 0.2 * shade[:, m.decal_face, None])], axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            coef = np.stack(
                [normal[..., 0] / (k.fx_px * d), normal[..., 1] / (k.fy_px * d),
                 (normal[..., 2] - normal[..., 0] * k.cx_px / k.fx_px - normal[..., 1] * k.cy_px / k.fy_px) / d],
                axis=2,
            )
        coef = np.concatenate([coef, coef[:, m.decal_face]], axis=1)  # decals lie on their face's plane
        # --- project; vehicles crossing the near plane get their polygons clipped
        z = pc[..., 2]
        hull_z = z[:, self._hull_vertices]
        crossing = hull_z.min(axis=1) <= near
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = np.stack([k.fx_px * pc[..., 0] / z + k.cx_px, k.fy_px * pc[..., 1] / z + k.cy_px], axis=2)
        uv_hull = uv[:, self._hull_vertices]
        boxes = np.concatenate([uv_hull.min(axis=1), uv_hull.max(axis=1)], axis=1)  # (n, 4)
        fixed = np.round(np.where(crossing[:, None, None], 0.0, uv) * _ONE).astype(np.int32)
        clipped: dict[int, list[tuple[int, np.ndarray]]] = {}
        for i in np.flatnonzero(crossing).tolist():
            polys = self._clipped_polygons(pc[i], front[i], near)
            if not polys:
                boxes[i] = np.nan
                continue
            pts = np.concatenate([p for _, p in polys]) / _ONE
            boxes[i] = (pts[:, 0].min(), pts[:, 1].min(), pts[:, 0].max(), pts[:, 1].max())
            clipped[i] = polys
        on_image = (boxes[:, 2] >= -0.5) & (boxes[:, 0] <= k.width_px - 0.5) & (boxes[:, 3] >= -0.5) & (
            boxes[:, 1] <= k.height_px - 0.5
        )
        on_image &= np.isfinite(boxes).all(axis=1)
        order = self._paint_order(np.flatnonzero(on_image), vs, idx, boxes, cam_centre, zc[idx], hull_z)
        # --- paint colour and face id of each polygon, far to near
        face_map = self._face_map
        face_seq = self._face_seq
        with_decals_seq = [[f] + self._face_decals[f] for f in range(len(m.faces))]
        colour_list = np.clip(colour, 0, 255).astype(np.int64).tolist()
        front_list = front.tolist()
        poly_pts = np.ascontiguousarray(fixed[:, self._polys])  # (n, F + D, 4, 2)
        rec_v: list[int] = []  # per painted polygon: its vehicle and its face or decal code
        rec_code: list[int] = []
        amodal_px: dict[int, int] = {}
        detail = s.detail_min_px
        w_img, h_img = k.width_px, k.height_px
        fill, line, in_range, count = cv2.fillConvexPoly, cv2.LINE_8, cv2.inRange, cv2.countNonZero
        box_list = boxes.tolist()
        # each vehicle's window in the image: its amodal box, clipped, with a pixel to spare
        safe = np.nan_to_num(boxes)
        windows = np.stack([
            np.clip(np.floor(safe[:, 0]), 0, w_img), np.clip(np.floor(safe[:, 1]), 0, h_img),
            np.clip(np.ceil(safe[:, 2]) + 2, 0, w_img), np.clip(np.ceil(safe[:, 3]) + 2, 0, h_img),
        ], axis=1).astype(int).tolist()
        n_painted = 0
        for i in order:
            bx0, by0, bx1, by1 = box_list[i]
            x0, y0, x1, y1 = windows[i]
            col = colour_list[i]
            k0 = n_painted + 1
            if i in clipped:
                codes = [code for code, _ in clipped[i]]
                for code, pts in clipped[i]:
                    n_painted += 1
                    fill(face_map, pts, n_painted, line, _SHIFT)
                    fill(rgb, pts, col[code], line, _SHIFT)
            else:
                fr, pts_i = front_list[i], poly_pts[i]
                if bx1 - bx0 >= detail:
                    codes = [c for f in face_seq if fr[f] for c in with_decals_seq[f]]
                else:
                    codes = [f for f in face_seq if fr[f]]
                for code in codes:
                    n_painted += 1
                    pts = pts_i[code]
                    fill(face_map, pts, n_painted, line, _SHIFT)
                    fill(rgb, pts, col[code], line, _SHIFT)
            rec_v.extend([i] * len(codes))
            rec_code.extend(codes)
            # nothing nearer is painted yet: the vehicle's face ids in its window are its
            # whole (amodal) in-image shape
            inside = n_painted >= k0 and x1 > x0 and y1 > y0
            amodal_px[i] = count(in_range(face_map[y0:y1, x0:x1], k0, n_painted)) if inside else 0
        if not rec_v:
            return None
        rv, rc = np.array(rec_v), np.array(rec_code)
        # --- exact planar depth per pixel: 1 / Z = a u + b v + c on the face it shows
        lut = np.zeros((3, len(rv) + 1))
        lut[:, 1:] = coef[rv, rc].T
        fm = face_map.ravel()
        pix = np.flatnonzero(fm > 0)
        f = fm[pix]
        row, col = np.divmod(pix, w_img)
        inv_z = np.take(lut[0], f) * col + np.take(lut[1], f) * row + np.take(lut[2], f)
        depth.ravel()[pix] = 1.0 / inv_z
        lut_vid = np.zeros(len(rv) + 1, dtype=np.int32)
        lut_vid[1:] = ids[rv]
        instance = np.zeros((h_img, w_img), dtype=np.int32)
        instance.ravel()[pix] = np.take(lut_vid, f)
        # --- ground truth: visible boxes and visibility from the instance map
        rng_c = np.linalg.norm(centres[idx], axis=1).tolist()
        depth_c = zc[idx].tolist()
        id_list = ids.tolist()
        for i in order:
            vid = id_list[i]
            bx0, by0, bx1, by1 = box_list[i]
            x0, y0, x1, y1 = windows[i]
            n_amodal = amodal_px[i]
            n_vis, visible_box = 0, None
            if n_amodal:
                mask = in_range(instance[y0:y1, x0:x1], vid, vid)
                n_vis = count(mask)
                if n_vis:
                    rx, ry, rw, rh = cv2.boundingRect(mask)
                    visible_box = (x0 + rx - 0.5, y0 + ry - 0.5, x0 + rx + rw - 0.5, y0 + ry + rh - 0.5)
            truths[vid] = VehicleTruth(  # positional: this runs for every vehicle of every frame
                vid, visible_box, (bx0, by0, bx1, by1), min(1.0, n_vis / n_amodal) if n_amodal else 0.0, n_vis,
                n_amodal, depth_c[i], rng_c[i], bx0 < -0.5 or by0 < -0.5 or bx1 > w_img - 0.5 or by1 > h_img - 0.5,
            )
        return instance

    def _clipped_polygons(self, pc: np.ndarray, front: np.ndarray, near: float) -> list[tuple[int, np.ndarray]]:
        """Front faces (with decals) of a vehicle crossing the near plane, clipped to it, fixed point."""
        k = self.camera.intrinsics
        out: list[tuple[int, np.ndarray]] = []
        for f in self._face_seq:
            if front[f]:
                for code in [f] + self._face_decals[f]:
                    poly = pc[self._polys[code]]
                    if poly[:, 2].min() <= near:
                        poly = _clip_near(poly, near)
                        if len(poly) < 3:
                            continue
                    uv = np.stack([k.fx_px * poly[:, 0] / poly[:, 2] + k.cx_px,
                                   k.fy_px * poly[:, 1] / poly[:, 2] + k.cy_px], 1)
                    out.append((code, np.round(uv * _ONE).astype(np.int32)))
        return out

    @staticmethod
    def _paint_order(
        cand: np.ndarray,
        vs: VehicleSet,
        idx: np.ndarray,
        boxes: np.ndarray,
        cam_centre: np.ndarray,
        depth: np.ndarray,
        vertex_z: np.ndarray,
    ) -> list[int]:
        """Far-to-near painting order that is exact for disjoint footprints (see the module docstring).

        Two vehicles need an order only when their image boxes overlap. When their depth
        ranges do not overlap either, the nearer one is in front (depth grows along every
        ray); otherwise a line separating their footprints decides.
        """
        n = len(cand)
        if n <= 1:
            return [int(i) for i in cand]
        b = boxes[cand]
        ii, jj = _pairs(n)
        overlap = (b[ii, 0] <= b[jj, 2]) & (b[jj, 0] <= b[ii, 2]) & (b[ii, 1] <= b[jj, 3]) & (b[jj, 1] <= b[ii, 3])
        ii, jj = ii[overlap], jj[overlap]
        z_lo, z_hi = vertex_z[cand].min(axis=1), vertex_z[cand].max(axis=1)
        a_nearer = z_hi[ii] < z_lo[jj]
        b_nearer = z_hi[jj] < z_lo[ii]
        by_depth = a_nearer | b_nearer
        if by_depth.all():
            # every depth relation holds in the order of the nearest vertices' depth
            return [int(cand[q]) for q in np.argsort(-z_lo, kind="stable")]
        before: list[list[int]] = [[] for _ in range(n)]  # before[a]: those painted after a
        indeg = [0] * n
        for a, bb, af in zip(ii[by_depth].tolist(), jj[by_depth].tolist(), a_nearer[by_depth].tolist(), strict=True):
            back, fr = (bb, a) if af else (a, bb)
            before[back].append(fr)
            indeg[fr] += 1
        ii, jj = ii[~by_depth], jj[~by_depth]
        if len(ii):
            g = idx[cand]
            hd = vs.heading_rad[g]
            ax = np.stack([np.stack([np.cos(hd), np.sin(hd)], 1), np.stack([-np.sin(hd), np.cos(hd)], 1)], 1)  # (n, 2, 2)
            half = np.stack([vs.length_m[g], vs.width_m[g]], 1) / 2
            ctr = np.stack([vs.x_m[g], vs.y_m[g]], 1)
            signs = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]], dtype=float)
            corners = ctr[:, None] + np.einsum("ck,nk,nkd->ncd", signs, half, ax)  # (n, 4, 2)
            axes = np.concatenate([ax[ii], ax[jj]], axis=1)  # (P, 4, 2)
            pa = np.einsum("pcd,pad->pac", corners[ii], axes)
            pb = np.einsum("pcd,pad->pac", corners[jj], axes)
            cam = np.einsum("d,pad->pa", cam_centre[:2], axes)
            a_lo = pa.max(axis=2) < pb.min(axis=2)  # a entirely below b on this axis
            b_lo = pb.max(axis=2) < pa.min(axis=2)
            sep_a = np.where(a_lo, (pa.max(axis=2) + pb.min(axis=2)) / 2, np.nan)
            sep_b = np.where(b_lo, (pb.max(axis=2) + pa.min(axis=2)) / 2, np.nan)
            # a is in front when the camera is on a's side of a separating line
            a_front_axis = np.where(a_lo, cam < sep_a, np.where(b_lo, cam > sep_b, False))
            separated = a_lo | b_lo
            first = np.argmax(separated, axis=1)
            rows = np.arange(len(ii))
            has_sep = separated[rows, first]
            a_front = np.where(has_sep, a_front_axis[rows, first], depth[cand[ii]] < depth[cand[jj]])
            for a, bb, af in zip(ii.tolist(), jj.tolist(), a_front.tolist(), strict=True):
                back, fr = (bb, a) if af else (a, bb)
                before[back].append(fr)
                indeg[fr] += 1
        # Kahn's algorithm, farthest first among the ready ones
        dist = z_lo
        heap = [(-dist[q], q) for q in range(n) if indeg[q] == 0]
        heapq.heapify(heap)
        done = [False] * n
        order: list[int] = []
        while len(order) < n:
            if not heap:  # a cycle (only with overlapping footprints, i.e. crashes): farthest goes first
                q = max((q for q in range(n) if not done[q]), key=lambda q: dist[q])
                indeg[q] = 0
                heap.append((-dist[q], q))
            _, q = heapq.heappop(heap)
            if done[q]:
                continue
            done[q] = True
            order.append(int(cand[q]))
            for r in before[q]:
                indeg[r] -= 1
                if indeg[r] == 0 and not done[r]:
                    heapq.heappush(heap, (-dist[r], r))
        return order


_PAIRS: dict[int, tuple[np.ndarray, np.ndarray]] = {}


def _pairs(n: int) -> tuple[np.ndarray, np.ndarray]:
    """All index pairs ``i < j`` of ``n`` items (cached)."""
    pairs = _PAIRS.get(n)
    if pairs is None:
        pairs = _PAIRS[n] = np.triu_indices(n, 1)
    return pairs


def _clip_near(poly: np.ndarray, near: float) -> np.ndarray:
    """Sutherland-Hodgman clip of a polygon (camera frame) to ``Z >= near``."""
    out = []
    n = len(poly)
    for a in range(n):
        p, q = poly[a], poly[(a + 1) % n]
        pin, qin = p[2] >= near, q[2] >= near
        if pin:
            out.append(p)
        if pin != qin:
            s = (near - p[2]) / (q[2] - p[2])
            out.append(p + s * (q - p))
    return np.array(out) if out else np.zeros((0, 3))


def depth_to_uint8(depth_m: np.ndarray, max_range_m: float) -> np.ndarray:
    """Encode planar depth as ``uint8`` for image policies: ``round(255 (1 - Z / max_range))``.

    Linear in depth, 255 at the camera and 0 at ``max_range_m`` or beyond (one level is
    ``max_range_m / 255``, 0.78 m at 200 m).

    :param depth_m: depth image [m]
    :param max_range_m: the range mapped to 0 [m]
    :return: ``uint8`` image of the same shape
    :raises ValueError: on a range that is not a finite number > 0
    """
    if not (isinstance(max_range_m, numbers.Real) and math.isfinite(max_range_m) and max_range_m > 0):
        raise ValueError(f"max_range_m must be a finite number > 0 [m] (got {max_range_m!r})")
    scaled = 255.0 - np.asarray(depth_m, dtype=np.float32) * np.float32(255.0 / max_range_m)
    return np.clip(np.rint(scaled), 0, 255).astype(np.uint8)

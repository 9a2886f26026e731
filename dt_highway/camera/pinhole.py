"""The pinhole camera model of the paper's coordinate transform (section III-A, Eq. 1-3).

Frames
------
* **World**: highway-env's road frame, ``x`` along the road [m], ``y`` across it [m]
  (increasing towards higher lane indices, i.e. to the right of a vehicle heading along
  ``+x``), and ``z`` **up** [m] (0 on the road). With ``y`` to the right and ``z`` up this
  frame is left-handed, so internally points are mirrored to ``z_down = -z`` (a
  right-handed x-forward / y-right / z-down frame) before the rotation; every public
  function takes and returns ``z`` up.
* **Camera**: OpenCV's, ``X`` right, ``Y`` down, ``Z`` forward along the optical axis [m].
* **Image**: ``u`` to the right, ``v`` down [px], pixel centres at integer coordinates.

Eq. (1) of the paper writes ``P_w = [R|t] P_c`` (camera to world); here ``R`` and ``t``
are the inverse, world to camera: ``P_c = R P_w + t``, the convention of
``cv2.projectPoints``. Eq. (2)-(3) with ``f / d_x = f_x`` and ``f / d_y = f_y`` reduce to
``u = f_x X_c / Z_c + c_x`` and ``v = f_y Y_c / Z_c + c_y``.

Depth is **planar**: ``Z_c``, the distance along the optical axis (CARLA's convention);
:func:`PinholeCamera.project` also returns the Euclidean range ``|P_c|``.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np

from dt_highway._jit import kernel


def _check_pixels(**sizes: object) -> None:
    """Refuse an image size that is not a whole number of pixels > 0, in one line naming it."""
    for name, v in sizes.items():
        if isinstance(v, bool) or not isinstance(v, numbers.Integral) or v <= 0:
            raise ValueError(f"{name} must be a whole number of pixels > 0 (got {v!r})")


@dataclass(frozen=True)
class Intrinsics:
    """Image size and the pinhole's intrinsic parameters.

    :param width_px: image width [px]
    :param height_px: image height [px]
    :param fx_px: focal length along ``u`` [px]
    :param fy_px: focal length along ``v`` [px]
    :param cx_px: principal point ``u`` [px]
    :param cy_px: principal point ``v`` [px]
    """

    width_px: int
    height_px: int
    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float

    def __post_init__(self) -> None:
        """Refuse a size that is not a whole number of pixels > 0, and focal lengths or a principal point that are
        not finite (focal lengths > 0), in one line."""
        _check_pixels(width_px=self.width_px, height_px=self.height_px)
        for name in ("fx_px", "fy_px", "cx_px", "cy_px"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, numbers.Real) or not math.isfinite(v) \
                    or (name.startswith("f") and v <= 0):
                raise ValueError(f"{name} must be a finite number{' > 0' if name.startswith('f') else ''} (got {v!r})")

    @classmethod
    def from_fov(
        cls, width_px: int, height_px: int, hfov_rad: float, cx_px: float | None = None, cy_px: float | None = None
    ) -> Intrinsics:
        """Square pixels with ``f = W / (2 tan(hfov / 2))``, principal point at the centre by default.

        :param width_px: image width [px]
        :param height_px: image height [px]
        :param hfov_rad: horizontal field of view [rad]
        :param cx_px: principal point ``u`` [px] (default: the centre, ``(W - 1) / 2``)
        :param cy_px: principal point ``v`` [px] (default: the centre, ``(H - 1) / 2``)
        :return: the intrinsics
        :raises ValueError: on a non-positive size or a field of view outside (0, pi)
        """
        _check_pixels(width_px=width_px, height_px=height_px)
        if not 0.0 < hfov_rad < math.pi:
            raise ValueError(f"horizontal field of view must be in (0, pi) rad (got {hfov_rad})")
        f = width_px / (2.0 * math.tan(hfov_rad / 2.0))
        cx = (width_px - 1) / 2.0 if cx_px is None else cx_px
        cy = (height_px - 1) / 2.0 if cy_px is None else cy_px
        return cls(width_px, height_px, f, f, cx, cy)

    @property
    def matrix(self) -> np.ndarray:
        """The 3x3 intrinsic matrix ``K``."""
        return np.array([[self.fx_px, 0.0, self.cx_px], [0.0, self.fy_px, self.cy_px], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class Mount:
    """Where the camera sits on the ego, in the ego's frame (x forward, y right, z up).

    :param forward_m: ahead of the ego's centre [m]
    :param lateral_m: to the right of the ego's centre [m]
    :param height_m: above the road [m]
    :param pitch_rad: tilt of the optical axis below the horizon [rad] (positive looks down)
    :param yaw_rad: turn of the optical axis to the right of the ego's heading [rad]
    """

    forward_m: float = 0.5
    lateral_m: float = 0.0
    height_m: float = 1.3
    pitch_rad: float = 0.0
    yaw_rad: float = 0.0


@dataclass(frozen=True)
class Pose:
    """The ego's pose on the road (highway-env's ``position`` and ``heading``).

    :param x_m: position along the road [m]
    :param y_m: lateral position [m]
    :param heading_rad: heading, from ``+x`` towards ``+y`` [rad]
    """

    x_m: float
    y_m: float
    heading_rad: float


@dataclass(frozen=True)
class Projection:
    """Projected points.

    :param uv_px: ``(N, 2)`` pixel coordinates, NaN for points not in front of the camera
    :param depth_m: ``(N,)`` planar depth ``Z_c`` [m] (negative behind the camera)
    :param range_m: ``(N,)`` Euclidean distance to the camera centre [m]
    :param in_front: ``(N,)`` depth beyond the near plane
    :param in_image: ``(N,)`` in front and inside the image
    """

    uv_px: np.ndarray
    depth_m: np.ndarray
    range_m: np.ndarray
    in_front: np.ndarray
    in_image: np.ndarray


@kernel
def _perspective(
    pc: np.ndarray, fx: float, fy: float, cx: float, cy: float, near: float
) -> tuple[np.ndarray, np.ndarray]:
    """Eq. (2)-(3): camera-frame points ``(N, 3)`` to pixels ``(N, 2)`` (NaN when not beyond
    ``near``) and planar depth ``(N,)`` [m]."""
    n = pc.shape[0]
    uv = np.empty((n, 2))
    z = np.empty(n)
    for i in range(n):
        z[i] = pc[i, 2]
        if pc[i, 2] > near:
            uv[i, 0] = fx * pc[i, 0] / pc[i, 2] + cx
            uv[i, 1] = fy * pc[i, 1] / pc[i, 2] + cy
        else:
            uv[i, 0] = uv[i, 1] = np.nan
    return uv, z


def _z_down(points: np.ndarray) -> np.ndarray:
    out = np.array(points, dtype=float, copy=True)
    out[..., 2] = -out[..., 2]
    return out


class PinholeCamera:
    """A pinhole camera mounted on the ego.

    :param intrinsics: image size and intrinsic parameters
    :param mount: the camera's place on the ego
    :param near_m: points closer than this along the optical axis are not in front [m]
    """

    def __init__(self, intrinsics: Intrinsics, mount: Mount = Mount(), near_m: float = 0.1) -> None:
        if near_m <= 0:
            raise ValueError(f"near_m must be > 0 (got {near_m})")
        self.intrinsics = intrinsics
        self.mount = mount
        self.near_m = near_m

    def extrinsics(self, pose: Pose) -> tuple[np.ndarray, np.ndarray]:
        """World-to-camera rotation and translation for an ego pose (the inverse of Eq. 1).

        :param pose: the ego's pose
        :return: ``R`` (3x3, proper rotation) and ``t`` (3,) with ``P_c = R P + t`` for ``P``
            in the right-handed world frame (``z`` down); see the module docstring. The last
            pose's pair is kept (read-only): a frame's projections all share one pose
        """
        cached = self.__dict__.get("_extrinsics_cache")
        if cached is not None and cached[0] == pose and cached[1] is self.mount:
            return cached[2], cached[3]
        ch, sh = math.cos(pose.heading_rad), math.sin(pose.heading_rad)
        ego_to_world = np.array([[ch, -sh, 0.0], [sh, ch, 0.0], [0.0, 0.0, 1.0]])
        rot = self._axes_in_ego @ ego_to_world.T  # rows: the camera's right, down, forward axes
        centre = np.array([pose.x_m, pose.y_m, 0.0]) + ego_to_world @ self._offset_in_ego
        t = -rot @ centre
        rot.flags.writeable = t.flags.writeable = False  # shared by every caller of this pose
        self.__dict__["_extrinsics_cache"] = (pose, self.mount, rot, t)
        return rot, t

    @property
    def _axes_in_ego(self) -> np.ndarray:
        """The camera's right, down and forward axes (rows) in the ego frame (x fwd, y right, z down)."""
        cached = self.__dict__.get("_axes_cache")
        if cached is not None and cached[0] is self.mount:
            return cached[1]
        m = self.mount
        cp, sp = math.cos(m.pitch_rad), math.sin(m.pitch_rad)
        cy, sy = math.cos(m.yaw_rad), math.sin(m.yaw_rad)
        forward = np.array([cp * cy, cp * sy, sp])
        right = np.array([-sy, cy, 0.0])
        axes = np.stack([right, np.cross(forward, right), forward])
        self.__dict__["_axes_cache"] = (m, axes)
        return axes

    @property
    def _offset_in_ego(self) -> np.ndarray:
        m = self.mount
        return np.array([m.forward_m, m.lateral_m, -m.height_m])

    def to_camera(self, points_world: np.ndarray, pose: Pose) -> np.ndarray:
        """World points (``z`` up) in the camera frame, ``(N, 3)`` [m].

        :param points_world: ``(N, 3)`` or ``(3,)`` points, ``z`` up [m]
        :param pose: the ego's pose
        :return: ``(N, 3)`` points in the camera frame (``X`` right, ``Y`` down, ``Z`` forward) [m]
        """
        rot, t = self.extrinsics(pose)
        return _z_down(np.atleast_2d(points_world)) @ rot.T + t

    def project(self, points_world: np.ndarray, pose: Pose) -> Projection:
        """Project world points (e.g. a target's GNSS antenna) into the image (Eq. 2-3).

        :param points_world: ``(N, 3)`` or ``(3,)`` points, ``z`` up [m]
        :param pose: the ego's pose
        :return: pixels, planar depth, range, and flags; points behind the camera (or
            nearer than ``near_m``) get NaN pixels and ``in_front = False``
        """
        pc = self.to_camera(points_world, pose)
        uv, z = self._pixels(pc)
        in_front = z > self.near_m
        k = self.intrinsics
        with np.errstate(invalid="ignore"):
            in_image = in_front & (uv[:, 0] >= -0.5) & (uv[:, 0] < k.width_px - 0.5) & (uv[:, 1] >= -0.5) & (
                uv[:, 1] < k.height_px - 0.5
            )
        return Projection(uv, z, np.linalg.norm(pc, axis=1), in_front, in_image)

    def pixels(self, points_world: np.ndarray, pose: Pose) -> tuple[np.ndarray, np.ndarray]:
        """The lean part of :meth:`project`, for hot paths: pixels and planar depth only.

        :param points_world: ``(N, 3)`` points, ``z`` up [m]
        :param pose: the ego's pose
        :return: ``(N, 2)`` pixels (NaN when not in front of the near plane) and ``(N,)``
            planar depth [m]
        """
        return self._pixels(self.to_camera(points_world, pose))

    def _pixels(self, pc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        k = self.intrinsics
        return _perspective(np.ascontiguousarray(pc, dtype=float), k.fx_px, k.fy_px, k.cx_px, k.cy_px, self.near_m)

    def unproject(self, uv_px: np.ndarray, depth_m: np.ndarray, pose: Pose) -> np.ndarray:
        """Pixels with planar depth back to world points (``z`` up), ``(N, 3)`` [m].

        :param uv_px: ``(N, 2)`` or ``(2,)`` pixel coordinates [px]
        :param depth_m: ``(N,)`` planar depth ``Z_c`` per pixel [m]
        :param pose: the ego's pose
        :return: ``(N, 3)`` world points, ``z`` up [m]
        """
        uv = np.atleast_2d(np.asarray(uv_px, dtype=float))
        z = np.atleast_1d(np.asarray(depth_m, dtype=float))
        k = self.intrinsics
        pc = np.stack([(uv[:, 0] - k.cx_px) / k.fx_px * z, (uv[:, 1] - k.cy_px) / k.fy_px * z, z], axis=1)
        rot, t = self.extrinsics(pose)
        return _z_down((pc - t) @ rot)

    def range_from_depth(self, uv_px: np.ndarray, depth_m: np.ndarray) -> np.ndarray:
        """Euclidean range [m] of pixels with planar depth ``depth_m`` [m] (depth-image conversion).

        :param uv_px: pixel coordinates, ``(..., 2)`` [px]
        :param depth_m: planar depth ``Z_c`` per pixel, ``(...)`` [m]
        :return: Euclidean distance to the camera centre per pixel, ``(...)`` [m]
        """
        uv = np.asarray(uv_px, dtype=float)
        k = self.intrinsics
        xn = (uv[..., 0] - k.cx_px) / k.fx_px
        yn = (uv[..., 1] - k.cy_px) / k.fy_px
        return np.asarray(depth_m, dtype=float) * np.sqrt(1.0 + xn * xn + yn * yn)

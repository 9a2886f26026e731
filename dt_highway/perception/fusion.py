"""The fusion of camera and cloud twin: which box in the image is which connected vehicle.

One :class:`Fusion` per ego, fed frame by frame with the camera frame, the detector's boxes
and the twin view the ego has received. Methods (``FusionSettings.method``):

* ``baseline``: the paper's RGB-only approach: anchor (the twin's GNSS position projected,
  section III-A) inside a box; among several, the box whose centre is nearest the anchor.
* ``fusion``: the paper's method: Algorithm 1 (depth evaluation, mean) + Algorithm 2
  (distance matching), one target at a time, with the twin position as received.
* ``joint``: latency compensation (each twin position moved to the frame's time at its
  reported speed and heading), the vehicle's whole expected outline projected when its
  anchor is off the image (a vehicle beside the ego, whose centre is not in view), robust
  depth (median), GNSS distance moved to the vehicle's near face, and all connected
  vehicles in view assigned to boxes at once (Hungarian).
* ``tracked``: ``joint`` on SORT tracks instead of raw boxes, with each vehicle keeping its
  track from frame to frame: it survives missed and merged detections and stale GNSS.

Nothing here reads ground truth: inputs are the image-side detections and depth, the
twin's message, the camera model and the ego's pose.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from operator import attrgetter
from typing import Any, Literal, NamedTuple

import numpy as np
from pydantic import field_validator

from dt_highway._jit import kernel
from dt_highway.camera.pinhole import PinholeCamera
from dt_highway.camera.render import CameraImage
from dt_highway.config import FUSION_METHODS, FrozenSettings, FusionConfig, FusionMethod, section_field
from dt_highway.perception.depth import box_distances
from dt_highway.perception.detect import Detections
from dt_highway.perception.matching import JointCost, match_each, match_joint
from dt_highway.perception.tracking import BoxTracker
from dt_highway.twin.cloud import TwinVehicleView

_BOX_CORNERS = np.array([[sx, sy, sz] for sx in (-0.5, 0.5) for sy in (-0.5, 0.5) for sz in (0.0, 1.0)])
"""Corners of a unit box around a vehicle's centre on the road (x fwd, y right, z up)"""
_BOX_EDGES = np.array([[i, j] for i in range(8) for j in range(i + 1, 8)
                       if np.sum(_BOX_CORNERS[i] != _BOX_CORNERS[j]) == 1])
"""The 12 edges of that box"""

_STATE = attrgetter("x_m", "y_m", "speed_mps", "heading_rad", "t_fix_s")


def _twin_state(twin: Sequence[TwinVehicleView]) -> np.ndarray:
    """``(K, 5)`` position x, y [m], speed [m/s], heading [rad] and fix time [s] of twin vehicles."""
    return np.array(list(map(_STATE, twin)), dtype=float).reshape(-1, 5)


@kernel
def _positions(state: np.ndarray, now_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Latency compensation: each position moved to ``now_s`` at its speed and heading (an
    unknown or negative age counts as 0).

    :return: x and y [m]
    """
    n = state.shape[0]
    x, y = np.empty(n), np.empty(n)
    for i in range(n):
        age = now_s - state[i, 4]
        if not np.isfinite(age) or age < 0.0:
            age = 0.0
        x[i] = state[i, 0] + state[i, 2] * np.cos(state[i, 3]) * age
        y[i] = state[i, 1] + state[i, 2] * np.sin(state[i, 3]) * age
    return x, y


Method = FusionMethod
METHODS: tuple[str, ...] = FUSION_METHODS


class FusionSettings(FrozenSettings):
    """Settings of :class:`Fusion`; those a user sets take their defaults and ranges from the
    ``fusion`` section (:class:`~dt_highway.config.FusionConfig`), the others are the model's.

    :param method: ``baseline``, ``fusion`` (the paper), ``joint`` or ``tracked``
    :param th: Algorithm 1's box resize threshold [-]
    :param n_samples: Algorithm 1's sample points per box [-]
    :param fallback: Algorithm 2 (and baseline) when no box contains the anchor: ``none`` or ``nearest``
    :param anchor_height_m: height of the GNSS point above the road [m] (mid-height of a car)
    :param near_face_m: for ``joint``/``tracked``: the depth image sees a vehicle's near
        face, about half a length in front of its GNSS point; this much is taken off the
        GNSS distance before comparing [m]
    :param continuity_bonus: for ``tracked``: cost taken off keeping last frame's track [-]
    :param coast_penalty: for ``tracked``: cost added to a track without a detection this frame [-]
    :param position_sigma_m: for ``joint``/``tracked``: expected error of a twin position [m]
        (GNSS noise plus what latency compensation leaves); widens the anchor's tolerance
    :param assumed_length_m: for ``joint``/``tracked``: length of a vehicle's expected outline [m]
        (the twin does not send sizes; highway-env's cars are 5 m x 2 m)
    :param assumed_width_m: its width [m]
    :param assumed_height_m: its height [m]
    :param joint: the joint assignment's cost weights
    """

    method: Method = section_field(FusionConfig, "method")
    th: float = section_field(FusionConfig, "th")
    n_samples: int = section_field(FusionConfig, "n_samples")
    fallback: Literal["none", "nearest"] = section_field(FusionConfig, "fallback")
    anchor_height_m: float = section_field(FusionConfig, "anchor_height_m")
    near_face_m: float = section_field(FusionConfig, "near_face_m")
    continuity_bonus: float = section_field(FusionConfig, "continuity_bonus")
    coast_penalty: float = 0.3
    position_sigma_m: float = 1.0
    assumed_length_m: float = 5.0
    assumed_width_m: float = 2.0
    assumed_height_m: float = 1.5
    joint: JointCost = JointCost()

    @field_validator("method", mode="before")
    @classmethod
    def _known_method(cls, method: Any) -> Any:
        if method not in METHODS:
            raise ValueError(f"method must be one of {', '.join(METHODS)} (got {method!r})")
        return method


class Placement(NamedTuple):
    """Where the fusion put one connected vehicle in the image.

    :param vehicle_id: the twin's id of the vehicle
    :param box: its box ``x1, y1, x2, y2`` [px], ``None`` when it was not placed
    :param distance_m: the box's distance from Algorithm 1 [m] (NaN without a box)
    :param gnss_distance_m: planar depth of its (compensated) GNSS point [m]
    :param anchor_uv: the anchor pixel (NaN when behind the camera)
    :param rule: how the box was chosen (see :mod:`~dt_highway.perception.matching`),
        ``"joint"`` or ``"track"`` for the joint methods, ``"none"`` without a box

    A named tuple (immutable, and cheap to make: a frame makes one per connected vehicle).
    """

    vehicle_id: int
    box: tuple[float, float, float, float] | None
    distance_m: float
    gnss_distance_m: float
    anchor_uv: tuple[float, float]
    rule: str


class Fusion:
    """Places the twin's connected vehicles on the camera's boxes, frame after frame.

    :param camera: the ego's camera model (the renderer's ``camera``)
    :param settings: method and parameters (None: the ``fusion`` section's defaults)
    :param rng: random generator of Algorithm 1's sampling
    """

    def __init__(self, camera: PinholeCamera, settings: FusionSettings | None = None,
                 rng: np.random.Generator | None = None) -> None:
        self.camera = camera
        self.settings = settings if settings is not None else FusionSettings()
        self.rng = rng if rng is not None else np.random.default_rng()
        self.tracker = BoxTracker()
        self._track_of: dict[int, int] = {}

    def reset(self) -> None:
        """Forget the tracks (new episode)."""
        self.tracker.reset()
        self._track_of = {}

    def anchors(self, frame: CameraImage, twin: Sequence[TwinVehicleView], now_s: float,
                compensate: bool) -> tuple[np.ndarray, np.ndarray]:
        """Anchor pixels and GNSS planar depths of twin vehicles (coordinate transform, III-A).

        :param frame: the camera image (its pose is the ego's)
        :param twin: the twin's vehicles as received
        :param now_s: the frame's time on the twin's clock [s]
        :param compensate: move each position forward by its age at its speed and heading
        :return: ``(K, 2)`` pixels (NaN when behind the camera) and ``(K,)`` planar depths [m]
        """
        return self._anchors(_twin_state(twin), frame, now_s, compensate)

    def expected_boxes(self, frame: CameraImage, twin: Sequence[TwinVehicleView], now_s: float) -> np.ndarray:
        """Where each twin vehicle should appear: its 3-D outline (a car of the assumed size at
        its compensated position and heading) projected and clipped to the image.

        :param frame: the camera image (its pose is the ego's)
        :param twin: the twin's vehicles as received
        :param now_s: the frame's time on the twin's clock [s]
        :return: ``(K, 4)`` boxes [px], NaN rows for vehicles not in view
        """
        return self._expected_boxes(_twin_state(twin), frame, now_s)

    def _anchors(self, state: np.ndarray, frame: CameraImage, now_s: float,
                 compensate: bool) -> tuple[np.ndarray, np.ndarray]:
        if not len(state):
            return np.zeros((0, 2)), np.zeros(0)
        x, y = _positions(state, float(now_s)) if compensate else (state[:, 0], state[:, 1])
        world = np.empty((len(x), 3))
        world[:, 0], world[:, 1], world[:, 2] = x, y, self.settings.anchor_height_m
        uv, z = self.camera.pixels(world, frame.pose)  # the pinhole model (paper Eq. 1-3)
        z[~np.isfinite(uv[:, 0])] = np.nan
        return uv, z

    def _expected_boxes(self, state: np.ndarray, frame: CameraImage, now_s: float) -> np.ndarray:
        s, k = self.settings, self.camera.intrinsics
        if not len(state):
            return np.zeros((0, 4))
        x, y = _positions(state, float(now_s))
        c, sn = np.cos(state[:, 3]), np.sin(state[:, 3])
        lx = _BOX_CORNERS[:, 0] * s.assumed_length_m
        ly = _BOX_CORNERS[:, 1] * s.assumed_width_m
        world = np.stack([x[:, None] + c[:, None] * lx - sn[:, None] * ly,
                          y[:, None] + sn[:, None] * lx + c[:, None] * ly,
                          np.broadcast_to(_BOX_CORNERS[:, 2] * s.assumed_height_m, (len(x), 8))], axis=2)
        pc = self.camera.to_camera(world.reshape(-1, 3), frame.pose).reshape(-1, 8, 3)
        near = self.camera.near_m + 1e-3
        p, q = pc[:, _BOX_EDGES[:, 0]], pc[:, _BOX_EDGES[:, 1]]
        straddle = (p[..., 2] > near) != (q[..., 2] > near)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (near - p[..., 2]) / (q[..., 2] - p[..., 2])
            cut = p + t[..., None] * (q - p)
        cand = np.concatenate([pc, cut], axis=1)  # (K, 20, 3)
        ok = np.concatenate([pc[..., 2] > near, straddle], axis=1)
        z = np.where(ok, cand[..., 2], 1.0)
        u = k.fx_px * np.where(ok, cand[..., 0], 0.0) / z + k.cx_px
        v = k.fy_px * np.where(ok, cand[..., 1], 0.0) / z + k.cy_px
        box = np.stack([np.where(ok, u, np.inf).min(1), np.where(ok, v, np.inf).min(1),
                        np.where(ok, u, -np.inf).max(1), np.where(ok, v, -np.inf).max(1)], axis=1)
        box[:, [0, 2]] = np.clip(box[:, [0, 2]], -0.5, k.width_px - 0.5)
        box[:, [1, 3]] = np.clip(box[:, [1, 3]], -0.5, k.height_px - 0.5)
        empty = ~ok.any(axis=1) | (box[:, 2] - box[:, 0] < 0.5) | (box[:, 3] - box[:, 1] < 0.5)
        box[empty] = np.nan
        return box

    def _candidates(self, boxes: np.ndarray) -> tuple[np.ndarray, list[int | None]]:
        """The boxes to match: the detections, and with ``tracked`` also the predicted boxes of
        established tracks that got no detection (missed, merged or hidden).

        :param boxes: this frame's detections ``(N, 4)`` [px]
        :return: the candidate boxes and, with ``tracked``, the track each came from (``None``:
            a detection that fed no track); otherwise an empty list
        """
        if self.settings.method != "tracked":
            return boxes, []
        self.tracker.update(boxes)
        coast_ids, coast_boxes = self.tracker.coasting()
        track_ids = self.tracker.detection_tracks + coast_ids.tolist()
        return np.concatenate([boxes, coast_boxes]), track_ids

    def _continuity_cost(self, ids: list[int], n_boxes: int, n_det: int, track_ids: list[int | None]) -> np.ndarray:
        """Extra matching cost ``(vehicles, boxes)``: a coasting track (no detection this frame)
        is less sure than a detected box, and the track a vehicle was on last frame is cheaper."""
        s = self.settings
        extra = np.zeros((len(ids), n_boxes))
        extra[:, n_det:] = s.coast_penalty
        pos = {tid: j for j, tid in enumerate(track_ids) if tid is not None}
        for k, vid in enumerate(ids):
            j = pos.get(self._track_of.get(vid, -2))
            if j is not None:
                extra[k, j] -= s.continuity_bonus
        return extra

    def _outline_boxes(self, anchors: np.ndarray, state: np.ndarray, frame: CameraImage, now_s: float) -> np.ndarray | None:
        """The expected outline box of each vehicle whose anchor is off the image (beside the
        ego), which is matched by its outline instead; NaN rows for the others, ``None`` if none is off."""
        k_int = self.camera.intrinsics
        off = ~(np.isfinite(anchors).all(axis=1) & (anchors[:, 0] >= -0.5) & (anchors[:, 0] <= k_int.width_px - 0.5)
                & (anchors[:, 1] >= -0.5) & (anchors[:, 1] <= k_int.height_px - 0.5))
        if not off.any():
            return None
        return np.where(off[:, None], self._expected_boxes(state, frame, now_s), np.nan)

    def _remember_tracks(self, ids: list[int], chosen: list[int], track_ids: list[int | None]) -> None:
        """Keep the track each vehicle was placed on (for the next frame's continuity bonus)."""
        for vid, j in zip(ids, chosen, strict=True):
            tid = track_ids[j] if j >= 0 else None
            if tid is not None:
                self._track_of[vid] = tid
            else:
                self._track_of.pop(vid, None)

    def step(self, frame: CameraImage, detections: Detections, twin: Sequence[TwinVehicleView],
             now_s: float) -> dict[int, Placement]:
        """Place every connected vehicle of the twin view on a box of this frame.

        :param frame: the camera image (RGB, depth, pose; never its ground truth)
        :param detections: the detector's boxes for this frame
        :param twin: the twin's vehicles as received by the ego (may be empty)
        :param now_s: the frame's time on the twin's clock [s] (for latency compensation)
        :return: a placement per twin vehicle, keyed by its id
        """
        s = self.settings
        twin = [v for v in twin if v is not None]
        state = _twin_state(twin)
        finite = np.isfinite(state[:, 0]) & np.isfinite(state[:, 1])
        if not finite.all():  # a vehicle without a position cannot be placed
            twin = [v for v, ok in zip(twin, finite.tolist(), strict=True) if ok]
            state = state[finite]
        boxes = np.asarray(detections.boxes, dtype=float).reshape(-1, 4)
        n_det = len(boxes)
        boxes, track_ids = self._candidates(boxes)
        joint = s.method in ("joint", "tracked")
        if not twin:
            return {}
        anchors, gnss = self._anchors(state, frame, now_s, compensate=joint)
        if s.method == "baseline":
            dist = np.full(len(boxes), np.nan)  # RGB only: no depth
        else:
            dist = box_distances(frame.depth_m, boxes, s.th, s.n_samples, self.rng,
                                 reducer="median" if joint else "mean")
        ids = [v.vehicle_id for v in twin]
        box_list, dist_list = boxes.tolist(), dist.tolist()
        gnss_list, anchor_list = gnss.tolist(), list(map(tuple, anchors.tolist()))

        def placements(chosen: list[int], rules: list[str]) -> dict[int, Placement]:
            return {vid: Placement(vid, tuple(box_list[j]), dist_list[j], g, a, rule) if j >= 0
                    else Placement(vid, None, math.nan, g, a, "none")
                    for vid, j, g, a, rule in zip(ids, chosen, gnss_list, anchor_list, rules, strict=True)}

        if not joint:
            if s.method == "baseline":
                chosen_idx, rules = match_each(anchors, boxes, fallback=s.fallback)
            else:
                chosen_idx, rules = match_each(anchors, boxes, dist, gnss, fallback=s.fallback)
            return placements(chosen_idx.tolist(), rules)
        extra = self._continuity_cost(ids, len(boxes), n_det, track_ids) if s.method == "tracked" and len(boxes) else None
        expected = self._outline_boxes(anchors, state, frame, now_s)
        sigma_px = self.camera.intrinsics.fx_px * s.position_sigma_m / np.maximum(gnss, 1.0)
        chosen = [-1 if j is None else j for j in
                  match_joint(anchors, gnss - s.near_face_m, boxes, dist, s.joint, extra_cost=extra,
                              expected_boxes=expected, anchor_sigma_px=sigma_px)]
        if s.method == "tracked":
            self._remember_tracks(ids, chosen, track_ids)
        return placements(chosen, ["track" if s.method == "tracked" else "joint"] * len(ids))

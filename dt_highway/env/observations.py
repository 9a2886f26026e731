"""The env's own observation types, beside highway-env's.

* :class:`TwinTaggedKinematics`: Kinematics plus what the twin delivered about each observed car;
* :class:`OverlayKinematics`: Kinematics plus the overlay's marks as seen on the screen;
* :class:`CameraObservation`: the ego camera's images, for vision agents;
* :class:`ResizedCamera`: a vision policy's view of the screen (image and overlay, at the size
  it was trained on), for a policy driving through :class:`~dt_highway.env.seat.DriverSeat`.

None of them reads ground truth: the twin columns come from the delivered view, the marks
from the ADAS output through :func:`~dt_highway.env.senses.cars_under_marks`.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np
from gymnasium import spaces
from highway_env.envs.common.observation import ObservationType
from highway_env.vehicle.objects import RoadObject
from scipy.optimize import linear_sum_assignment

from dt_highway.camera.render import depth_to_uint8
from dt_highway.config import ConfigError
from dt_highway.drivers.perception import Mark
from dt_highway.env.senses import cars_under_marks
from dt_highway.labels import AGGRESSIVE
from dt_highway.overlay import draw_overlay
from dt_highway.twin.cloud import TwinView
from dt_highway.twin.intention import NO_LANE
from dt_highway.world.observation import FastKinematicObservation
from dt_highway.world.traffic import vehicle_id

if TYPE_CHECKING:
    from dt_highway.env.core import DTHighwayEnv


class _KinematicsPlus(FastKinematicObservation):
    """highway-env's Kinematics observation plus the columns ``EXTRA_FEATURES``, filled by
    :meth:`fill` from what the ego received. The extra columns are matched to the rows in
    sorted order; the rows are shuffled afterwards if the observation asks for it."""

    EXTRA_FEATURES: list[str] = []
    features: list[str]
    order: str

    def __init__(self, env: DTHighwayEnv, **kwargs: Any) -> None:
        super().__init__(env, **kwargs)
        self.base_features = list(self.features)
        self.features = self.base_features + self.EXTRA_FEATURES
        self._rows: list[RoadObject] | None = None

    def observed(self) -> list[RoadObject]:
        """The observer and the rows' objects; inside :meth:`observe`, the list it already found."""
        return self._rows if self._rows is not None else super().observed()

    def observe(self) -> np.ndarray:
        if not self.env.road:
            return np.zeros((self.vehicles_count, len(self.features)), dtype=np.float32)
        features, self.features = self.features, self.base_features
        order, self.order = self.order, "sorted"
        try:
            rows = self._rows = super().observed()  # once per step: the base rows and the extra columns share it
            base = super().observe()
        finally:
            self.features, self.order, self._rows = features, order, None
        out = np.zeros((base.shape[0], len(self.features)), dtype=base.dtype)
        out[:, : base.shape[1]] = base
        self.fill(out[:, base.shape[1]:], rows[: base.shape[0]])
        if self.order == "shuffled":
            self.env.np_random.shuffle(out[1:])
        return out

    def fill(self, extra: np.ndarray, rows: list[RoadObject]) -> None:
        """Write the extra columns (``extra``, one row per observed object, the ego first) in place."""
        raise NotImplementedError


class TwinTaggedKinematics(_KinematicsPlus):
    """highway-env's Kinematics observation plus two columns from the delivered twin view.

    ``twin_known`` is 1 when an observed vehicle was associated with a vehicle of the twin's
    view, and ``twin_aggressive`` is then the twin's probability that its driver is
    aggressive (0 otherwise). The association uses only what the ego received: each twin
    position is moved forward by its age at its reported speed and heading, and observed
    vehicles are matched to them by minimum total distance (Hungarian), gated at
    ``GATE_M``. Ground truth is never read.

    With ``twin.in_observation_intent`` two more columns carry the delivered lane-change intention
    at the operating horizon (``twin.intention.operating_horizon_s``) of an associated vehicle:
    ``twin_p_change``, the probability that it changes lane within that horizon, and
    ``twin_target_dlane``, the lane it would move to relative to its own lane in the twin's map
    (-1 left, +1 right, 0 none).

    :param env: the env
    :param kwargs: highway-env's Kinematics observation options (``vehicles_count``, ``features``, ``order``...)
    """

    EXTRA_FEATURES = ["twin_known", "twin_aggressive"]
    INTENT_FEATURES = ["twin_p_change", "twin_target_dlane"]
    """The intention columns (``twin.in_observation_intent``)"""
    OWN_COLUMNS = (*EXTRA_FEATURES, *INTENT_FEATURES)
    GATE_M = 6.0
    """Largest distance between an observed vehicle and a twin position to associate them [m]"""

    def __init__(self, env: DTHighwayEnv, **kwargs: Any) -> None:
        super().__init__(env, **kwargs)
        twin = env.dt_config.twin
        self.intent_horizon_s = twin.intention.operating_horizon_s if twin.in_observation_intent else None
        if self.intent_horizon_s is not None:
            self.features = self.features + self.INTENT_FEATURES

    def fill(self, extra: np.ndarray, rows: list[RoadObject]) -> None:
        """The twin's columns of each row's car, from the twin view the ego received (zeros: a car the twin lacks).

        :param extra: the twin's columns, one row per observed object (the ego first), written in place
        :param rows: the observed objects, the ego first
        """
        view: TwinView | None = self.env.twin_view
        if view is None or not view.vehicles or len(rows) < 2:
            return
        now = self.env.twin_now_s
        pred = np.array([
            [v.x_m + v.speed_mps * math.cos(v.heading_rad) * (now - v.t_fix_s),
             v.y_m + v.speed_mps * math.sin(v.heading_rad) * (now - v.t_fix_s)]
            for v in view.vehicles
        ])
        pos = np.array([o.position for o in rows[1:]])
        cost = np.linalg.norm(pos[:, None, :] - pred[None, :, :], axis=2)
        for r, c in zip(*linear_sum_assignment(cost), strict=True):
            if cost[r, c] <= self.GATE_M:
                tv = view.vehicles[c]
                extra[r + 1, 0] = 1.0
                extra[r + 1, 1] = tv.confidence if tv.tag == AGGRESSIVE else 1.0 - tv.confidence
                intent = tv.intent(self.intent_horizon_s) if self.intent_horizon_s is not None else None
                if intent is not None:
                    extra[r + 1, 2] = intent.p_change
                    if intent.target_lane != NO_LANE:
                        own_lane = int(self.env.road_map.lane_of_one(tv.y_m))
                        extra[r + 1, 3] = float(np.sign(intent.target_lane - own_lane))


class OverlayKinematics(_KinematicsPlus):
    """highway-env's Kinematics observation plus a column ``marked``: 1 when the ADAS overlay
    shows an "aggressive driver" marker on that vehicle, as the driver sees it on the screen.

    The marker is read the way :func:`~dt_highway.env.senses.cars_under_marks` reads it
    for scripted drivers: the car whose visible outline best fits the marker's box. When the
    fusion put the label on the wrong car, this column is on the wrong car too; without the
    ADAS (camera or fusion off, the baseline condition) it is all zeros. The twin's verdict
    reaches the observation only through the fusion and the overlay, never from ground truth.

    With ``threat = true`` (the ``adas-threat`` training setting) two more columns carry the threat
    cue, read from the label drawn on the car as a person reads it
    (:attr:`~dt_highway.drivers.perception.Mark.is_cut_in`, :attr:`~dt_highway.drivers.perception.Mark.side`):
    ``cut_in_warned``, 1 when a mark on that car says "cutting in"; ``side``, the side its label says
    the car comes from (-1 left, +1 right, 0 not said). The ``sham`` condition's marks, being what
    is on the screen, fill these columns the same way.

    :param env: the env
    :param threat: add the threat-cue columns
    :param kwargs: highway-env's Kinematics observation options (``vehicles_count``, ``features``, ``order``...)
    """

    EXTRA_FEATURES = ["marked"]
    THREAT_FEATURES = ["cut_in_warned", "side"]
    """The columns of the threat cue (``threat = true``)"""
    OWN_COLUMNS = (*EXTRA_FEATURES, *THREAT_FEATURES)
    TYPE_NAME = "OverlayKinematics"

    def __init__(self, env: DTHighwayEnv, threat: bool = False, **kwargs: Any) -> None:
        super().__init__(env, **kwargs)
        self.threat = bool(threat)
        if self.threat:
            self.features = self.features + self.THREAT_FEATURES

    def fill(self, extra: np.ndarray, rows: list[RoadObject]) -> None:
        """The overlay's columns: 1 for each row's car under a mark the driver sees (and its threat cue).

        :param extra: the overlay's columns, one row per observed object (the ego first), written in place
        :param rows: the observed objects, the ego first
        """
        adas = self.env.adas_output()
        if adas is None or not adas["overlay"]:
            return
        if not self.threat:
            marked = cars_under_marks(self.env, adas["overlay"])
            for r, v in enumerate(rows[1:], start=1):
                if vehicle_id(v) in marked:
                    extra[r, 0] = 1.0
            return
        row_of = {vehicle_id(v): r for r, v in enumerate(rows[1:], start=1)}
        for item in adas["overlay"]:  # each mark on the car a person sees it on (as cars_under_marks, one at a time)
            row = next((row_of[c] for c in cars_under_marks(self.env, [item]) if c in row_of), None)
            if row is None:
                continue
            x1, y1, x2, y2 = (float(b) for b in item["box"])
            mark = Mark((x1, y1, x2, y2), str(item.get("label", "")))
            extra[row, 0] = 1.0
            if mark.is_cut_in:
                extra[row, 1] = 1.0
                extra[row, 2] = float(mark.side)


class CameraObservation(ObservationType):
    """The ego camera's images, for vision agents: ``{"rgb": (H, W, 3), "depth": (H, W, 1)}``.

    Both are ``uint8`` images as stable-baselines3's ``MultiInputPolicy`` expects. Depth is
    encoded by :func:`~dt_highway.camera.render.depth_to_uint8` (linear, 255 at the camera,
    0 at ``camera.max_range_m`` and beyond); the float depth in metres is on
    ``env.unwrapped.camera_image().depth_m``. The image is the env's one rendering of the
    step, shared with ``info`` and the fusion (it is not rendered twice).

    :param env: the env (camera on)
    :param depth: also return the depth image
    """

    def __init__(self, env: DTHighwayEnv, depth: bool = True) -> None:
        super().__init__(env)
        self.depth = bool(depth)

    def space(self) -> spaces.Space:
        """The observation space of the camera's images.

        :return: the camera's RGB image (and its depth, with ``depth``), ``uint8``
        """
        cam = self.env.dt_config.camera
        parts: dict[str, spaces.Space] = {
            "rgb": spaces.Box(0, 255, shape=(cam.height_px, cam.width_px, 3), dtype=np.uint8)
        }
        if self.depth:
            parts["depth"] = spaces.Box(0, 255, shape=(cam.height_px, cam.width_px, 1), dtype=np.uint8)
        return spaces.Dict(parts)

    def observe(self) -> dict[str, np.ndarray]:
        """The camera's images now.

        :return: the camera's RGB image (and its depth scaled to ``uint8`` over the camera's range)
        """
        image = self.env.camera_image()
        out = {"rgb": image.rgb}
        if self.depth:
            out["depth"] = depth_to_uint8(image.depth_m, self.env.dt_config.camera.max_range_m)[..., None]
        return out


class ResizedCamera:
    """A vision policy's view: the ego camera's image at the size it was trained on, with the
    ADAS overlay drawn on it when there is one (what a driver sees on the screen).

    :param env: the env (camera on)
    :param size: ``(width, height)`` [px] the policy takes
    :param depth: also the depth image (``uint8``, as :class:`CameraObservation`)
    :raises ConfigError: if the camera is off
    """

    def __init__(self, env: DTHighwayEnv, size: tuple[int, int], depth: bool = False) -> None:
        if not env.dt_config.camera.enabled:
            raise ConfigError("a vision policy looks through the camera: run it with camera.enabled = true")
        self.env, self.size, self.depth = env, size, depth

    def space(self) -> spaces.Dict:
        """The observation space of the resized picture.

        :return: the resized picture (and its depth), ``uint8``
        """
        w, h = self.size
        parts: dict[str, spaces.Space] = {"rgb": spaces.Box(0, 255, shape=(h, w, 3), dtype=np.uint8)}
        if self.depth:
            parts["depth"] = spaces.Box(0, 255, shape=(h, w, 1), dtype=np.uint8)
        return spaces.Dict(parts)

    def observe(self) -> dict[str, np.ndarray]:
        """The picture the driver sees now, at the policy's size.

        :return: the picture the driver sees, overlay drawn, resized (and its depth)
        """
        image = self.env.camera_image()
        rgb = image.rgb
        adas = self.env.adas_output()
        if adas is not None and adas["overlay"]:
            rgb = draw_overlay(rgb, adas["overlay"])
        same = rgb.shape[1] == self.size[0] and rgb.shape[0] == self.size[1]
        out = {"rgb": rgb if same else cv2.resize(rgb, self.size, interpolation=cv2.INTER_AREA)}
        if self.depth:
            d = depth_to_uint8(image.depth_m, self.env.dt_config.camera.max_range_m)
            out["depth"] = (d if same else cv2.resize(d, self.size, interpolation=cv2.INTER_AREA))[..., None]
        return out

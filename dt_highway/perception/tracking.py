"""Box tracking across frames (SORT: a Kalman filter per box, Hungarian assignment on IoU).

The paper leaves tracking to future work ("GNSS transmission may have delays and limited
update frequency"). Tracks give boxes identities over time, so the fusion can keep a
target on its box when a frame is ambiguous: when the detector misses the target, when it
merges the target with a neighbour (a track coasts on its prediction instead of taking the
merged box), or when the twin's position is stale.

State per track (Bewley et al., 2016, "Simple Online and Realtime Tracking"): box centre
``(u, v)`` [px], area ``s`` [px^2] and aspect ratio ``r`` [-], and the velocities of
``u, v, s``; constant-velocity motion, one step per frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

from dt_highway.perception.detect import iou


def _to_z(box: np.ndarray) -> np.ndarray:
    w, h = box[2] - box[0], box[3] - box[1]
    return np.array([box[0] + w / 2, box[1] + h / 2, w * h, w / max(h, 1e-6)])


def _to_box(x: np.ndarray) -> np.ndarray:
    s, r = max(float(x[2]), 1e-6), max(float(x[3]), 1e-6)
    w = np.sqrt(s * r)
    h = s / max(w, 1e-6)
    return np.array([x[0] - w / 2, x[1] - h / 2, x[0] + w / 2, x[1] + h / 2])


_F = np.eye(7)
_F[0, 4] = _F[1, 5] = _F[2, 6] = 1.0
_H = np.eye(4, 7)
_R = np.diag([1.0, 1.0, 10.0, 10.0])
_Q = np.diag([1.0, 1.0, 1.0, 1e-2, 1e-2, 1e-2, 1e-4])
_P0 = np.diag([10.0, 10.0, 10.0, 10.0, 1e4, 1e4, 1e4])


@dataclass
class Track:
    """One tracked box.

    :param track_id: identity, stable while the track lives
    :param x: Kalman state ``(u, v, s, r, du, dv, ds)``
    :param p: its covariance
    :param hits: frames with a detection
    :param misses: frames since the last detection
    :param age: frames since birth
    """

    track_id: int
    x: np.ndarray
    p: np.ndarray = field(default_factory=lambda: _P0.copy())
    hits: int = 1
    misses: int = 0
    age: int = 0
    detected: np.ndarray | None = None

    @property
    def box(self) -> np.ndarray:
        """Current box ``x1, y1, x2, y2`` [px]: this frame's detection when there is one,
        else the filter's prediction (a coasting track)."""
        return self.detected if self.detected is not None else _to_box(self.x)

    @property
    def predicted_box(self) -> np.ndarray:
        """The filter's box ``x1, y1, x2, y2`` [px]."""
        return _to_box(self.x)

    def predict(self) -> None:
        if self.x[2] + self.x[6] <= 0:
            self.x[6] = 0.0
        self.x = _F @ self.x
        self.p = _F @ self.p @ _F.T + _Q
        self.age += 1
        self.misses += 1
        self.detected = None

    def update(self, box: np.ndarray) -> None:
        z = _to_z(box)
        y = z - _H @ self.x
        s = _H @ self.p @ _H.T + _R
        k = self.p @ _H.T @ np.linalg.inv(s)
        self.x = self.x + k @ y
        self.p = (np.eye(7) - k @ _H) @ self.p
        self.hits += 1
        self.misses = 0
        self.detected = np.asarray(box, dtype=float).copy()


class BoxTracker:
    """SORT with a guard against merged detections.

    :param iou_gate: least IoU between a detection and a track's prediction to associate them
    :param max_misses: frames a track survives without detections (it coasts on its prediction)
    :param merge_cover: a detection that covers this share of two or more established
        tracks' predicted boxes, ...
    :param merge_iou: ... and has an IoU below this with each of them, is taken for a merged
        box: those tracks coast rather than jump to it
    """

    def __init__(self, iou_gate: float = 0.3, max_misses: int = 5, merge_cover: float = 0.6,
                 merge_iou: float = 0.6) -> None:
        self.iou_gate = iou_gate
        self.max_misses = max_misses
        self.merge_cover = merge_cover
        self.merge_iou = merge_iou
        self.tracks: list[Track] = []
        self._next_id = 1
        self.detection_tracks: list[int | None] = []
        """Track id of each detection of the last update (``None`` for a merged box)"""

    def reset(self) -> None:
        """Forget every track."""
        self.tracks = []
        self._next_id = 1

    def update(self, boxes: np.ndarray) -> list[Track]:
        """Advance one frame with this frame's detections.

        :param boxes: ``(N, 4)`` detected boxes
        :return: the live tracks (updated, new, or coasting on their prediction)
        """
        b = np.asarray(boxes, dtype=float).reshape(-1, 4)
        for t in self.tracks:
            t.predict()
        merged = np.zeros(len(b), dtype=bool)
        if self.tracks and len(b):
            pred = np.array([t.predicted_box for t in self.tracks])
            established = np.array([t.hits >= 2 for t in self.tracks])
            ix = np.clip(np.minimum(b[:, None, 2], pred[None, :, 2]) - np.maximum(b[:, None, 0], pred[None, :, 0]), 0, None)
            iy = np.clip(np.minimum(b[:, None, 3], pred[None, :, 3]) - np.maximum(b[:, None, 1], pred[None, :, 1]), 0, None)
            area = np.maximum((pred[:, 2] - pred[:, 0]) * (pred[:, 3] - pred[:, 1]), 1e-6)
            cover = ix * iy / area[None, :]  # share of each track's box inside each detection
            overlap = iou(b, pred)
            # a merged box covers two or more established tracks and resembles none of them
            covers = (cover >= self.merge_cover) & established[None, :]
            merged = (covers.sum(axis=1) >= 2) & ((overlap * covers).max(axis=1) < self.merge_iou)
            overlap[merged] = 0.0
            rows, cols = linear_sum_assignment(-overlap)
            used_d: dict[int, int] = {}
            used_t: set[int] = set()
            for r, c in zip(rows, cols):
                if overlap[r, c] >= self.iou_gate:
                    self.tracks[c].update(b[r])
                    used_d[int(r)] = self.tracks[c].track_id
                    used_t.add(int(c))
            # second pass for what is left: a detection whose centre lies near a track's
            # predicted centre (within half the predicted box) continues it, even if the
            # box changed size too much for the IoU gate (small, jittery boxes)
            free_d = [i for i in range(len(b)) if i not in used_d and not merged[i]]
            free_t = [j for j in range(len(self.tracks)) if j not in used_t]
            if free_d and free_t:
                cd = (b[free_d, :2] + b[free_d, 2:]) / 2
                ct = (pred[free_t, :2] + pred[free_t, 2:]) / 2
                half = np.maximum((pred[free_t, 2:] - pred[free_t, :2]) / 2, 1.0)
                dist = np.abs(cd[:, None, :] - ct[None]) / half[None]  # in half-sizes of the track
                score = np.where((dist <= 1.0).all(axis=2), np.hypot(dist[..., 0], dist[..., 1]), np.inf)
                if np.isfinite(score).any():
                    rr, cc = linear_sum_assignment(np.where(np.isfinite(score), score, 1e6))
                    for r, c in zip(rr, cc):
                        if np.isfinite(score[r, c]):
                            track = self.tracks[free_t[c]]
                            track.update(b[free_d[r]])
                            used_d[free_d[r]] = track.track_id
        else:
            used_d = {}
        self.detection_tracks = []
        for i in range(len(b)):
            if i in used_d:
                self.detection_tracks.append(used_d[i])
            elif merged[i]:
                self.detection_tracks.append(None)
            else:
                self.tracks.append(Track(self._next_id, np.concatenate([_to_z(b[i]), np.zeros(3)]), detected=b[i].copy()))
                self.detection_tracks.append(self._next_id)
                self._next_id += 1
        self.tracks = [t for t in self.tracks if t.misses <= self.max_misses]
        return list(self.tracks)

    def coasting(self, min_hits: int = 3) -> list[Track]:
        """Tracks without a detection this frame that had at least ``min_hits`` before."""
        return [t for t in self.tracks if t.misses > 0 and t.hits >= min_hits]

"""Box tracking across frames (SORT: a Kalman filter per box, Hungarian assignment on IoU).

The paper leaves tracking to future work ("GNSS transmission may have delays and limited
update frequency"). Tracks give boxes identities over time, so the fusion can keep a
target on its box when a frame is ambiguous: when the detector misses the target, when it
merges the target with a neighbour (a track coasts on its prediction instead of taking the
merged box), or when the twin's position is stale.

State per track (Bewley et al., 2016, "Simple Online and Realtime Tracking"): box centre
``(u, v)`` [px], area ``s`` [px^2] and aspect ratio ``r`` [-], and the velocities of
``u, v, s``; constant-velocity motion, one step per frame. SORT's noise matrices are
diagonal, so the 7-state filter splits exactly into independent filters: (u, du), (v, dv)
and (s, ds) with a 2x2 covariance each (those of u and v are equal: same noise, same
measurements) and r with a variance. All tracks are filtered at once on these small
covariances, which gives SORT's numbers for a handful of array operations per frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment


# SORT's noise (Bewley et al.): process Q = diag(1, 1, 1, 1e-2, 1e-2, 1e-2, 1e-4) and
# measurement R = diag(1, 1, 10, 10) over (u, v, s, r, du, dv, ds); initial P = diag(10, 10,
# 10, 10, 1e4, 1e4, 1e4). Per decoupled filter: (Q of the value, Q of the rate, R, P0 value, P0 rate)
_UV = (1.0, 1e-2, 1.0, 10.0, 1e4)
_S = (1.0, 1e-4, 10.0, 10.0, 1e4)
_R_Q, _R_R, _R_P0 = 1e-2, 10.0, 10.0


def _predict_cov(p: np.ndarray, q: tuple[float, ...]) -> None:
    """Constant-velocity prediction of 2x2 covariances stored as ``(p00, p01, p11)`` rows, in place."""
    p00, p01, p11 = p[:, 0].copy(), p[:, 1].copy(), p[:, 2].copy()
    p[:, 0] = p00 + 2.0 * p01 + p11 + q[0]
    p[:, 1] = p01 + p11
    p[:, 2] = p11 + q[1]


def _update_cov(p: np.ndarray, r: float) -> tuple[np.ndarray, np.ndarray]:
    """Kalman update of 2x2 covariances from a measurement of the value; return the gains."""
    s = p[:, 0] + r
    k0, k1 = p[:, 0] / s, p[:, 1] / s
    p11 = p[:, 2] - k1 * p[:, 1]
    p[:, 0] = (1.0 - k0) * p[:, 0]
    p[:, 1] = (1.0 - k0) * p[:, 1]
    p[:, 2] = p11
    return k0, k1


def _to_z(boxes: np.ndarray) -> np.ndarray:
    """Boxes ``(N, 4)`` to measurements ``(N, 4)``: centre, area, aspect ratio."""
    w, h = boxes[:, 2] - boxes[:, 0], boxes[:, 3] - boxes[:, 1]
    return np.stack([boxes[:, 0] + w / 2, boxes[:, 1] + h / 2, w * h, w / np.maximum(h, 1e-6)], axis=1)


def _to_boxes(x: np.ndarray) -> np.ndarray:
    """States ``(N, 7)`` to boxes ``(N, 4)``."""
    s, r = np.maximum(x[:, 2], 1e-6), np.maximum(x[:, 3], 1e-6)
    w = np.sqrt(s * r)
    h = s / np.maximum(w, 1e-6)
    return np.stack([x[:, 0] - w / 2, x[:, 1] - h / 2, x[:, 0] + w / 2, x[:, 1] + h / 2], axis=1)


@dataclass(frozen=True)
class Track:
    """A snapshot of one track.

    :param track_id: identity, stable while the track lives
    :param box: its box this frame ``x1, y1, x2, y2`` [px]: the detection when it had one,
        else the filter's prediction (a coasting track)
    :param hits: frames with a detection
    :param misses: frames since the last detection
    """

    track_id: int
    box: np.ndarray
    hits: int
    misses: int


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
        self.reset()

    def reset(self) -> None:
        """Forget every track."""
        self._x = np.zeros((0, 7))
        self._p_uv = np.zeros((0, 3))
        self._p_s = np.zeros((0, 3))
        self._p_r = np.zeros(0)
        self._ids = np.zeros(0, dtype=np.int64)
        self._hits = np.zeros(0, dtype=np.int64)
        self._misses = np.zeros(0, dtype=np.int64)
        self._detected = np.zeros((0, 4))
        self._next_id = 1
        self.detection_tracks: list[int | None] = []
        """Track id of each detection of the last update (``None`` for a merged box)"""

    @property
    def tracks(self) -> list[Track]:
        """The live tracks."""
        boxes = self._boxes()
        return [Track(int(i), boxes[k], int(h), int(m))
                for k, (i, h, m) in enumerate(zip(self._ids, self._hits, self._misses))]

    def _boxes(self) -> np.ndarray:
        return np.where((self._misses == 0)[:, None], self._detected, _to_boxes(self._x))

    def update(self, boxes: np.ndarray) -> None:
        """Advance one frame with this frame's detections.

        :param boxes: ``(N, 4)`` detected boxes
        """
        b = np.asarray(boxes, dtype=float).reshape(-1, 4)
        # predict every track
        shrink = self._x[:, 2] + self._x[:, 6] <= 0
        self._x[shrink, 6] = 0.0
        self._x[:, :3] += self._x[:, 4:]
        _predict_cov(self._p_uv, _UV)
        _predict_cov(self._p_s, _S)
        self._p_r += _R_Q
        self._misses += 1
        n_t = len(self._ids)
        merged = np.zeros(len(b), dtype=bool)
        det_track = np.full(len(b), -1, dtype=np.int64)  # index of the track each detection feeds
        if n_t and len(b):
            pred = _to_boxes(self._x)
            established = self._hits >= 2
            ix = np.maximum(np.minimum(b[:, None, 2], pred[None, :, 2]) - np.maximum(b[:, None, 0], pred[None, :, 0]), 0.0)
            iy = np.maximum(np.minimum(b[:, None, 3], pred[None, :, 3]) - np.maximum(b[:, None, 1], pred[None, :, 1]), 0.0)
            area = np.maximum((pred[:, 2] - pred[:, 0]) * (pred[:, 3] - pred[:, 1]), 1e-6)
            inter = ix * iy
            cover = inter / area[None, :]  # share of each track's box inside each detection
            area_b = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
            union = area_b[:, None] + area[None, :] - inter
            overlap = np.where(union > 0, inter / np.maximum(union, 1e-12), 0.0)  # IoU
            # a merged box covers two or more established tracks and resembles none of them
            covers = (cover >= self.merge_cover) & established[None, :]
            merged = (covers.sum(axis=1) >= 2) & ((overlap * covers).max(axis=1) < self.merge_iou)
            overlap[merged] = 0.0
            rows, cols = linear_sum_assignment(-overlap)
            ok = overlap[rows, cols] >= self.iou_gate
            det_track[rows[ok]] = cols[ok]
            # second pass for what is left: a detection whose centre lies near a track's
            # predicted centre (within half the predicted box) continues it, even if the
            # box changed size too much for the IoU gate (small, jittery boxes)
            free_d = np.flatnonzero((det_track < 0) & ~merged)
            taken = np.zeros(n_t, dtype=bool)
            taken[det_track[det_track >= 0]] = True
            free_t = np.flatnonzero(~taken)
            if len(free_d) and len(free_t):
                cd = (b[free_d, :2] + b[free_d, 2:]) / 2
                ct = (pred[free_t, :2] + pred[free_t, 2:]) / 2
                half = np.maximum((pred[free_t, 2:] - pred[free_t, :2]) / 2, 1.0)
                dist = np.abs(cd[:, None, :] - ct[None]) / half[None]
                score = np.where((dist <= 1.0).all(axis=2), np.hypot(dist[..., 0], dist[..., 1]), np.inf)
                if np.isfinite(score).any():
                    rr, cc = linear_sum_assignment(np.where(np.isfinite(score), score, 1e6))
                    good = np.isfinite(score[rr, cc])
                    det_track[free_d[rr[good]]] = free_t[cc[good]]
        # Kalman update of the tracks that got a detection, all at once
        fed = np.flatnonzero(det_track >= 0)
        if len(fed):
            ti = det_track[fed]
            y = _to_z(b[fed]) - self._x[ti, :4]
            p_uv, p_s, p_r = self._p_uv[ti], self._p_s[ti], self._p_r[ti]
            k0, k1 = _update_cov(p_uv, _UV[2])
            ks0, ks1 = _update_cov(p_s, _S[2])
            kr = p_r / (p_r + _R_R)
            x = self._x[ti]
            x[:, 0] += k0 * y[:, 0]
            x[:, 4] += k1 * y[:, 0]
            x[:, 1] += k0 * y[:, 1]
            x[:, 5] += k1 * y[:, 1]
            x[:, 2] += ks0 * y[:, 2]
            x[:, 6] += ks1 * y[:, 2]
            x[:, 3] += kr * y[:, 3]
            self._x[ti] = x
            self._p_uv[ti], self._p_s[ti], self._p_r[ti] = p_uv, p_s, (1.0 - kr) * p_r
            self._hits[ti] += 1
            self._misses[ti] = 0
            self._detected[ti] = b[fed]
        # new tracks for the detections nobody claimed (merged boxes start none)
        new = np.flatnonzero((det_track < 0) & ~merged)
        if len(new):
            z = _to_z(b[new])
            self._x = np.concatenate([self._x, np.concatenate([z, np.zeros((len(new), 3))], axis=1)])
            self._p_uv = np.concatenate([self._p_uv, np.tile([_UV[3], 0.0, _UV[4]], (len(new), 1))])
            self._p_s = np.concatenate([self._p_s, np.tile([_S[3], 0.0, _S[4]], (len(new), 1))])
            self._p_r = np.concatenate([self._p_r, np.full(len(new), _R_P0)])
            new_ids = np.arange(self._next_id, self._next_id + len(new))
            self._next_id += len(new)
            self._ids = np.concatenate([self._ids, new_ids])
            self._hits = np.concatenate([self._hits, np.ones(len(new), dtype=np.int64)])
            self._misses = np.concatenate([self._misses, np.zeros(len(new), dtype=np.int64)])
            self._detected = np.concatenate([self._detected, b[new]])
        row_of = det_track.copy()
        row_of[new] = n_t + np.arange(len(new))
        ids = self._ids[np.maximum(row_of, 0)].tolist()
        self.detection_tracks = [None if row_of[i] < 0 else ids[i] for i in range(len(b))]
        # drop the tracks lost for too long
        alive = self._misses <= self.max_misses
        if not alive.all():
            self._x, self._ids = self._x[alive], self._ids[alive]
            self._p_uv, self._p_s, self._p_r = self._p_uv[alive], self._p_s[alive], self._p_r[alive]
            self._hits, self._misses, self._detected = self._hits[alive], self._misses[alive], self._detected[alive]

    def coasting(self, min_hits: int = 3) -> tuple[np.ndarray, np.ndarray]:
        """Tracks without a detection this frame that had at least ``min_hits`` before.

        :return: their ids ``(M,)`` and predicted boxes ``(M, 4)``
        """
        sel = (self._misses > 0) & (self._hits >= min_hits)
        return self._ids[sel], _to_boxes(self._x[sel])

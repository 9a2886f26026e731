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
measurements) and r with a variance. ``tests/test_perception.py`` checks them against the
full 7-state filter.

A frame is three compiled loops (:mod:`dt_highway._jit`) around scipy's Hungarian solver:
predict and score (IoU, merged-box guard), a second association by box centres, and the
Kalman update with the birth and death of tracks. The tracks live in one float array and
one integer array, one row per track.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from dt_highway._jit import fmax, fmin, kernel

# SORT's noise (Bewley et al.) over (u, v, s, r, du, dv, ds): measurement R = diag(1, 1, 10,
# 10), initial P = diag(10, 10, 10, 10, 1e4, 1e4, 1e4), process Q = diag(1, 1, 1, 1e-2, 1e-2,
# 1e-2, 1e-4): SORT's, except for the aspect ratio r, 1e-2 instead of 1 (a car's box changes
# shape slowly). Per decoupled filter: Q of the value, Q of the rate, R, P0 value, P0 rate
_UV_Q0, _UV_Q1, _UV_R, _UV_P0, _UV_P1 = 1.0, 1e-2, 1.0, 10.0, 1e4
_S_Q0, _S_Q1, _S_R, _S_P0, _S_P1 = 1.0, 1e-4, 10.0, 10.0, 1e4
_R_Q, _R_R, _R_P0 = 1e-2, 10.0, 10.0

# one row per track: the state (u, v, s, r, du, dv, ds), the covariances (p00, p01, p11) of
# (u, du) and (v, dv), of (s, ds), the variance of r, and the last detected box
_X, _P_UV, _P_S, _P_R, _DET, _NF = 0, 7, 10, 13, 14, 18
# and in the integer array: id, frames with a detection, frames since the last one
_ID, _HITS, _MISSES = 0, 1, 2


@kernel
def _state_box(f: np.ndarray, k: int, out: np.ndarray) -> None:
    """The box ``x1, y1, x2, y2`` of track row ``k``'s state (centre, area, aspect ratio)."""
    s, r = fmax(f[k, 2], 1e-6), fmax(f[k, 3], 1e-6)
    w = np.sqrt(s * r)
    h = s / fmax(w, 1e-6)
    out[0], out[1], out[2], out[3] = f[k, 0] - w / 2, f[k, 1] - h / 2, f[k, 0] + w / 2, f[k, 1] + h / 2


@kernel
def _state_boxes(f: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """Boxes of the states of the given track rows, ``(len(rows), 4)``."""
    out = np.empty((len(rows), 4))
    for i in range(len(rows)):
        _state_box(f, rows[i], out[i])
    return out


@kernel
def _coasting(f: np.ndarray, ints: np.ndarray, min_hits: int) -> tuple[np.ndarray, np.ndarray]:
    """Ids and predicted boxes of the tracks without a detection this frame that had ``min_hits``."""
    sel = np.flatnonzero((ints[:, _MISSES] > 0) & (ints[:, _HITS] >= min_hits))
    return ints[sel, _ID].copy(), _state_boxes(f, sel)


@kernel
def _predict_and_score(f: np.ndarray, ints: np.ndarray, b: np.ndarray, merge_cover: float,
                       merge_iou: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Predict every track one frame (in place); IoU of each detection with each prediction.

    :return: predicted boxes ``(T, 4)``, IoU ``(N, T)`` (zero rows for merged boxes), merged ``(N,)``
    """
    n_t, n_b = f.shape[0], b.shape[0]
    for k in range(n_t):
        if f[k, 2] + f[k, 6] <= 0:  # the area would go negative: stop shrinking
            f[k, 6] = 0.0
        f[k, 0] += f[k, 4]
        f[k, 1] += f[k, 5]
        f[k, 2] += f[k, 6]
        p00, p01, p11 = f[k, _P_UV], f[k, _P_UV + 1], f[k, _P_UV + 2]
        f[k, _P_UV], f[k, _P_UV + 1], f[k, _P_UV + 2] = p00 + 2.0 * p01 + p11 + _UV_Q0, p01 + p11, p11 + _UV_Q1
        p00, p01, p11 = f[k, _P_S], f[k, _P_S + 1], f[k, _P_S + 2]
        f[k, _P_S], f[k, _P_S + 1], f[k, _P_S + 2] = p00 + 2.0 * p01 + p11 + _S_Q0, p01 + p11, p11 + _S_Q1
        f[k, _P_R] += _R_Q
        ints[k, _MISSES] += 1
    pred = _state_boxes(f, np.arange(n_t))
    overlap = np.zeros((n_b, n_t))
    merged = np.zeros(n_b, dtype=np.bool_)
    for i in range(n_b):
        area_b = (b[i, 2] - b[i, 0]) * (b[i, 3] - b[i, 1])
        n_cover, best = 0, 0.0
        for k in range(n_t):
            ix = fmax(fmin(b[i, 2], pred[k, 2]) - fmax(b[i, 0], pred[k, 0]), 0.0)
            iy = fmax(fmin(b[i, 3], pred[k, 3]) - fmax(b[i, 1], pred[k, 1]), 0.0)
            area = fmax((pred[k, 2] - pred[k, 0]) * (pred[k, 3] - pred[k, 1]), 1e-6)
            inter = ix * iy
            union = area_b + area - inter
            iou = inter / fmax(union, 1e-12) if union > 0 else 0.0
            overlap[i, k] = iou
            # a merged box covers two or more established tracks and resembles none of them
            if inter / area >= merge_cover and ints[k, _HITS] >= 2:
                n_cover += 1
                best = fmax(best, iou)
        if n_cover >= 2 and best < merge_iou:
            merged[i] = True
            overlap[i, :] = 0.0
    return pred, overlap, merged


@kernel
def _centre_score(b: np.ndarray, pred: np.ndarray, det_track: np.ndarray, merged: np.ndarray,
                  n_t: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Second association: distance of each free detection's centre from each free track's
    predicted centre, per axis in half the predicted box; inf beyond the box.

    :return: free detections, free tracks, score ``(len(free_d), len(free_t))``
    """
    taken = np.zeros(n_t, dtype=np.bool_)
    n_fd = 0
    for i in range(len(det_track)):
        if det_track[i] >= 0:
            taken[det_track[i]] = True
        elif not merged[i]:
            n_fd += 1
    free_d = np.empty(n_fd, dtype=np.int64)
    n_fd = 0
    for i in range(len(det_track)):
        if det_track[i] < 0 and not merged[i]:
            free_d[n_fd] = i
            n_fd += 1
    free_t = np.flatnonzero(~taken)
    score = np.empty((len(free_d), len(free_t)))
    for a in range(len(free_d)):
        i = free_d[a]
        cdu, cdv = (b[i, 0] + b[i, 2]) / 2, (b[i, 1] + b[i, 3]) / 2
        for c in range(len(free_t)):
            k = free_t[c]
            du = np.abs(cdu - (pred[k, 0] + pred[k, 2]) / 2) / fmax((pred[k, 2] - pred[k, 0]) / 2, 1.0)
            dv = np.abs(cdv - (pred[k, 1] + pred[k, 3]) / 2) / fmax((pred[k, 3] - pred[k, 1]) / 2, 1.0)
            score[a, c] = np.hypot(du, dv) if (du <= 1.0 and dv <= 1.0) else np.inf
    return free_d, free_t, score


@kernel
def _update(f: np.ndarray, ints: np.ndarray, b: np.ndarray, det_track: np.ndarray, merged: np.ndarray,
            next_id: int, max_misses: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """Kalman update of the tracks that got a detection, new tracks for the detections nobody
    claimed (merged boxes start none), and the tracks lost for too long dropped.

    :return: the new track arrays, each detection's track id (-1: none, a merged box) and the next free id
    """
    n_t, n_b = f.shape[0], b.shape[0]
    n_new = 0
    for i in range(n_b):
        if det_track[i] < 0 and not merged[i]:
            n_new += 1
    g = np.empty((n_t + n_new, _NF))
    gi = np.empty((n_t + n_new, 3), dtype=np.int64)
    g[:n_t] = f
    gi[:n_t] = ints
    det_ids = np.full(n_b, -1, dtype=np.int64)
    row = n_t
    for i in range(n_b):
        w, h = b[i, 2] - b[i, 0], b[i, 3] - b[i, 1]
        z0, z1, z2, z3 = b[i, 0] + w / 2, b[i, 1] + h / 2, w * h, w / fmax(h, 1e-6)
        k = det_track[i]
        if k >= 0:
            y0, y1, y2, y3 = z0 - g[k, 0], z1 - g[k, 1], z2 - g[k, 2], z3 - g[k, 3]
            # (u, du) and (v, dv): one covariance, measured value
            s = g[k, _P_UV] + _UV_R
            k0, k1 = g[k, _P_UV] / s, g[k, _P_UV + 1] / s
            p11 = g[k, _P_UV + 2] - k1 * g[k, _P_UV + 1]
            g[k, _P_UV], g[k, _P_UV + 1], g[k, _P_UV + 2] = (1.0 - k0) * g[k, _P_UV], (1.0 - k0) * g[k, _P_UV + 1], p11
            s = g[k, _P_S] + _S_R
            ks0, ks1 = g[k, _P_S] / s, g[k, _P_S + 1] / s
            p11 = g[k, _P_S + 2] - ks1 * g[k, _P_S + 1]
            g[k, _P_S], g[k, _P_S + 1], g[k, _P_S + 2] = (1.0 - ks0) * g[k, _P_S], (1.0 - ks0) * g[k, _P_S + 1], p11
            kr = g[k, _P_R] / (g[k, _P_R] + _R_R)
            g[k, _P_R] = (1.0 - kr) * g[k, _P_R]
            g[k, 0] += k0 * y0
            g[k, 4] += k1 * y0
            g[k, 1] += k0 * y1
            g[k, 5] += k1 * y1
            g[k, 2] += ks0 * y2
            g[k, 6] += ks1 * y2
            g[k, 3] += kr * y3
            gi[k, _HITS] += 1
            gi[k, _MISSES] = 0
        elif not merged[i]:
            k = row
            row += 1
            g[k, 0], g[k, 1], g[k, 2], g[k, 3] = z0, z1, z2, z3
            g[k, 4] = g[k, 5] = g[k, 6] = 0.0
            g[k, _P_UV], g[k, _P_UV + 1], g[k, _P_UV + 2] = _UV_P0, 0.0, _UV_P1
            g[k, _P_S], g[k, _P_S + 1], g[k, _P_S + 2] = _S_P0, 0.0, _S_P1
            g[k, _P_R] = _R_P0
            gi[k, _ID], gi[k, _HITS], gi[k, _MISSES] = next_id, 1, 0
            next_id += 1
        else:
            continue
        g[k, _DET:_DET + 4] = b[i]
        det_ids[i] = gi[k, _ID]
    alive = gi[:, _MISSES] <= max_misses
    return g[alive], gi[alive], det_ids, next_id


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
        self._f = np.zeros((0, _NF))
        self._i = np.zeros((0, 3), dtype=np.int64)
        self._next_id = 1
        self.detection_tracks: list[int | None] = []
        """Track id of each detection of the last update (``None`` for a merged box)"""

    @property
    def tracks(self) -> list[Track]:
        """The live tracks."""
        pred = _state_boxes(self._f, np.arange(len(self._f)))
        return [Track(int(i), self._f[k, _DET:_DET + 4].copy() if m == 0 else pred[k], int(h), int(m))
                for k, (i, h, m) in enumerate(self._i.tolist())]

    def update(self, boxes: np.ndarray) -> None:
        """Advance one frame with this frame's detections.

        :param boxes: ``(N, 4)`` detected boxes ``x1, y1, x2, y2`` [px]
        """
        b = np.ascontiguousarray(boxes, dtype=float).reshape(-1, 4)
        pred, overlap, merged = _predict_and_score(self._f, self._i, b, float(self.merge_cover), float(self.merge_iou))
        n_t = len(self._f)
        det_track = np.full(len(b), -1, dtype=np.int64)  # row of the track each detection feeds
        if n_t and len(b):
            rows, cols = linear_sum_assignment(-overlap)
            ok = overlap[rows, cols] >= self.iou_gate
            det_track[rows[ok]] = cols[ok]
            # second pass for what is left: a detection whose centre lies near a track's
            # predicted centre (within half the predicted box) continues it, even if the
            # box changed size too much for the IoU gate (small, jittery boxes)
            if not ok.all() or len(b) > n_t:
                free_d, free_t, score = _centre_score(b, pred, det_track, merged, n_t)
                finite = np.isfinite(score)
                if finite.any():
                    rr, cc = linear_sum_assignment(np.where(finite, score, 1e6))
                    good = finite[rr, cc]
                    det_track[free_d[rr[good]]] = free_t[cc[good]]
        self._f, self._i, det_ids, self._next_id = _update(self._f, self._i, b, det_track, merged, self._next_id,
                                                           self.max_misses)
        self.detection_tracks = [None if t < 0 else t for t in det_ids.tolist()]

    def coasting(self, min_hits: int = 3) -> tuple[np.ndarray, np.ndarray]:
        """Tracks without a detection this frame that had at least ``min_hits`` before.

        :param min_hits: least number of detections a track must have had
        :return: their ids ``(M,)`` and predicted boxes ``(M, 4)``
        """
        return _coasting(self._f, self._i, min_hits)

"""Which detected box is the target: the paper's Algorithm 2, its RGB-only baseline, and a
joint assignment of all connected vehicles at once.

The anchor point is the target's GNSS position projected into the image (section III-A,
:meth:`~dt_highway.camera.pinhole.PinholeCamera.project`).

* :func:`match_baseline` (RGB only): the boxes that contain the anchor; one -> that box;
  several -> the one whose centre is nearest the anchor; none -> the fallback.
* :func:`match_distance` (Algorithm 2): the boxes that contain the anchor; one -> that box;
  several -> the one whose depth distance ``d_j`` (Algorithm 1) is nearest the GNSS
  distance ``D_g``, i.e. the smallest ``|d_j - D_g|`` (the paper writes ``d_j - D_g``; the
  absolute value is meant); none -> the fallback.
* Fallback when no box contains the anchor: ``"none"`` (no match, the default, as in the
  paper) or ``"nearest"`` (the box whose edge is nearest the anchor, within
  ``max_fallback_px``).
* :func:`match_joint`: every connected vehicle in view against every box at once
  (Hungarian assignment, ``scipy.optimize.linear_sum_assignment``) on a cost of
  reprojection error and depth residual, so that two vehicles cannot take the same box and a
  box already explained by one twin vehicle is not given to another.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal, cast

import numpy as np
from scipy.optimize import linear_sum_assignment

from dt_highway._jit import fmax, fmin, kernel

Fallback = Literal["none", "nearest"]

#: why a box was chosen (or not)
RULES = ("single", "depth", "centre", "fallback", "none")


@dataclass(frozen=True)
class Match:
    """The outcome of matching one target.

    :param index: index of the chosen box, ``None`` when there is no match
    :param rule: ``"single"`` (only one box contains the anchor), ``"depth"`` (several:
        Algorithm 2's depth rule), ``"centre"`` (several: nearest centre), ``"fallback"``
        (no box contains the anchor), ``"none"`` (no match)
    :param candidates: indices of the boxes that contain the anchor
    """

    index: int | None
    rule: str
    candidates: tuple[int, ...] = ()


def _valid_anchor(anchor_uv: np.ndarray | tuple[float, float] | None) -> np.ndarray | None:
    if anchor_uv is None:
        return None
    a = np.asarray(anchor_uv, dtype=float).reshape(-1)
    if a.shape != (2,) or not np.all(np.isfinite(a)):
        return None  # e.g. a target behind the camera (NaN pixel)
    return a


def containing(boxes: np.ndarray, anchor_uv: np.ndarray) -> np.ndarray:
    """Indices of the boxes that contain the anchor (edges included).

    :param boxes: ``(N, 4)`` boxes ``x1, y1, x2, y2`` [px]
    :param anchor_uv: the anchor pixel ``(u, v)`` [px]
    :return: the indices into ``boxes``, in order
    """
    b = np.asarray(boxes, dtype=float).reshape(-1, 4)
    u, v = float(anchor_uv[0]), float(anchor_uv[1])
    return np.flatnonzero((b[:, 0] <= u) & (u <= b[:, 2]) & (b[:, 1] <= v) & (v <= b[:, 3]))


def _nearest_centre(boxes: np.ndarray, cand: np.ndarray, anchor: np.ndarray) -> int:
    """The candidate box whose centre is nearest the anchor."""
    centres = (boxes[cand, :2] + boxes[cand, 2:]) / 2
    return int(cand[np.argmin(np.hypot(*(centres - anchor).T))])


def _fallback(boxes: np.ndarray, anchor: np.ndarray, fallback: Fallback, max_px: float) -> Match:
    if fallback == "none" or not len(boxes):
        return Match(None, "none")
    if fallback != "nearest":
        raise ValueError(f"fallback must be 'none' or 'nearest' (got {fallback!r})")
    b = np.asarray(boxes, dtype=float)
    dx = np.maximum(np.maximum(b[:, 0] - anchor[0], anchor[0] - b[:, 2]), 0.0)
    dy = np.maximum(np.maximum(b[:, 1] - anchor[1], anchor[1] - b[:, 3]), 0.0)
    gap = np.hypot(dx, dy)
    best = int(np.argmin(gap))
    if gap[best] > max_px:
        return Match(None, "none")
    return Match(best, "fallback")


def match_baseline(
    anchor_uv: np.ndarray | tuple[float, float] | None,
    boxes: np.ndarray,
    fallback: Fallback = "none",
    max_fallback_px: float = 20.0,
) -> Match:
    """RGB-only matching: the box containing the anchor; among several, the nearest centre.

    :param anchor_uv: the anchor pixel ``(u, v)``; ``None`` or NaN (target behind the
        camera, no twin data) gives no match
    :param boxes: ``(N, 4)`` detected boxes
    :param fallback: what to do when no box contains the anchor
    :param max_fallback_px: farthest box edge the ``"nearest"`` fallback accepts [px]
    :return: the match
    """
    anchor = _valid_anchor(anchor_uv)
    b = np.asarray(boxes, dtype=float).reshape(-1, 4)
    if anchor is None or not len(b):
        return Match(None, "none")
    cand = containing(b, anchor)
    if len(cand) == 1:
        return Match(int(cand[0]), "single", (int(cand[0]),))
    if len(cand) > 1:
        return Match(_nearest_centre(b, cand, anchor), "centre", tuple(int(c) for c in cand))
    return _fallback(b, anchor, fallback, max_fallback_px)


def match_distance(
    anchor_uv: np.ndarray | tuple[float, float] | None,
    boxes: np.ndarray,
    distances_m: np.ndarray,
    gnss_distance_m: float,
    fallback: Fallback = "none",
    max_fallback_px: float = 20.0,
) -> Match:
    """Algorithm 2 (distance matching).

    :param anchor_uv: the anchor pixel ``(u, v)`` (``None``/NaN: no match)
    :param boxes: ``(N, 4)`` detected boxes
    :param distances_m: ``(N,)`` each box's distance from Algorithm 1 [m] (NaN: unknown)
    :param gnss_distance_m: the target's distance from its GNSS position ``D_g`` [m], same
        reference as ``distances_m``; NaN falls back to the nearest-centre rule
    :param fallback: what to do when no box contains the anchor
    :param max_fallback_px: farthest box edge the ``"nearest"`` fallback accepts [px]
    :return: the match
    """
    anchor = _valid_anchor(anchor_uv)
    b = np.asarray(boxes, dtype=float).reshape(-1, 4)
    d = np.asarray(distances_m, dtype=float).reshape(-1)
    if len(d) != len(b):
        raise ValueError(f"one distance per box is needed (got {len(d)} distances for {len(b)} boxes)")
    if anchor is None or not len(b):
        return Match(None, "none")
    cand = containing(b, anchor)
    if len(cand) > 1:
        diff = np.abs(d[cand] - gnss_distance_m)  # Alg. 2 lines 10-14, with |.|
        if math.isfinite(gnss_distance_m) and np.isfinite(diff).any():
            return Match(int(cand[np.nanargmin(diff)]), "depth", tuple(int(c) for c in cand))
    # one box, none, or no usable distance: the baseline's rules
    return match_baseline(anchor, b, fallback, max_fallback_px)


def match_each(
    anchors_uv: np.ndarray,
    boxes: np.ndarray,
    distances_m: np.ndarray | None = None,
    gnss_distances_m: np.ndarray | None = None,
    fallback: Fallback = "none",
    max_fallback_px: float = 20.0,
) -> tuple[np.ndarray, list[str]]:
    """Match each of many targets to a detected box.

    :func:`match_baseline` (without distances) or :func:`match_distance` (with them) for
    many targets at once, each on its own (the same results, as arrays).

    :param anchors_uv: ``(K, 2)`` anchors (NaN rows: no match)
    :param boxes: ``(N, 4)`` detected boxes
    :param distances_m: ``(N,)`` Algorithm 1 distances, or ``None`` for the baseline
    :param gnss_distances_m: ``(K,)`` GNSS distances (with ``distances_m``)
    :param fallback: what to do when no box contains an anchor
    :param max_fallback_px: farthest box edge the ``"nearest"`` fallback accepts [px]
    :return: box index per target (-1: none) and the rule per target
    """
    a = np.asarray(anchors_uv, dtype=float).reshape(-1, 2)
    b = np.asarray(boxes, dtype=float).reshape(-1, 4)
    k_n = len(a)
    idx = np.full(k_n, -1, dtype=np.int64)
    rules = ["none"] * k_n
    if not k_n or not len(b):
        return idx, rules
    if fallback not in ("none", "nearest"):
        raise ValueError(f"fallback must be 'none' or 'nearest' (got {fallback!r})")
    valid = np.isfinite(a).all(axis=1)
    u, v = a[:, 0:1], a[:, 1:2]
    inside = (b[None, :, 0] <= u) & (u <= b[None, :, 2]) & (b[None, :, 1] <= v) & (v <= b[None, :, 3]) & valid[:, None]
    count = inside.sum(axis=1)
    centre = (b[:, :2] + b[:, 2:]) / 2
    centre_key = np.hypot(centre[None, :, 0] - u, centre[None, :, 1] - v)
    key = centre_key
    by_depth = np.zeros(k_n, dtype=bool)
    if distances_m is not None:
        d = np.asarray(distances_m, dtype=float).reshape(-1)
        if len(d) != len(b):
            raise ValueError(f"one distance per box is needed (got {len(d)} distances for {len(b)} boxes)")
        g = np.asarray(gnss_distances_m, dtype=float).reshape(-1)
        diff = np.abs(d[None, :] - g[:, None])  # Alg. 2 lines 10-14, with |.|
        by_depth = cast(np.ndarray, np.isfinite(np.where(inside, diff, np.nan)).any(axis=1))
        key = np.where(by_depth[:, None], np.where(np.isfinite(diff), diff, np.inf), centre_key)
    chosen = np.argmin(np.where(inside, key, np.inf), axis=1)
    for i in np.flatnonzero(count == 1):
        idx[i], rules[i] = chosen[i], "single"
    for i in np.flatnonzero(count > 1):
        idx[i], rules[i] = chosen[i], "depth" if by_depth[i] else "centre"
    if fallback == "nearest":
        dx = np.maximum(np.maximum(b[None, :, 0] - u, u - b[None, :, 2]), 0.0)
        dy = np.maximum(np.maximum(b[None, :, 1] - v, v - b[None, :, 3]), 0.0)
        gap = np.hypot(dx, dy)
        best = np.argmin(gap, axis=1)
        for i in np.flatnonzero((count == 0) & valid):
            if gap[i, best[i]] <= max_fallback_px:
                idx[i], rules[i] = best[i], "fallback"
    return idx, rules


@dataclass(frozen=True)
class JointCost:
    """Weights of :func:`match_joint`'s cost.

    :param depth_scale_m: depth residual that costs 1 [m]
    :param outside_penalty: anchor-only rows: added when the anchor is outside the box [-]
    :param min_fit: expected-box rows: least IoU with the expected box for a pair to be allowed [-]
    :param gate: pairs costlier than this are never assigned [-]
    """

    depth_scale_m: float = 4.0
    outside_penalty: float = 1.0
    min_fit: float = 0.1
    gate: float = 3.0


def match_joint(
    anchors_uv: np.ndarray,
    gnss_distances_m: np.ndarray,
    boxes: np.ndarray,
    distances_m: np.ndarray,
    cost: JointCost = JointCost(),
    extra_cost: np.ndarray | None = None,
    expected_boxes: np.ndarray | None = None,
    anchor_sigma_px: np.ndarray | None = None,
) -> list[int | None]:
    """Assign every connected vehicle in view to at most one box, and each box to at most one vehicle.

    Geometric cost of vehicle ``i`` and box ``j``: the anchor's offset from the box centre,
    per axis in units of (half the box's size + twice the anchor's uncertainty
    ``anchor_sigma_px``), so 1 is "at the edge, give or take the GNSS error", plus
    ``outside_penalty`` beyond that; plus the depth residual ``|d_j - D_g,i| / depth_scale_m``
    (NaN counts as 0). For a vehicle given an expected box instead (its 3-D outline projected,
    used when its anchor is off the image, e.g. beside the ego): ``2 (1 - IoU)`` with the
    expected box, and no depth term (the near face of a car beside the ego is its side). Boxes that no connected vehicle
    explains stay unassigned, so an unconnected car cannot take a twin's label, and one twin
    vehicle cannot take another's box.

    :param anchors_uv: ``(K, 2)`` anchors of the connected vehicles (NaN rows: not in view)
    :param gnss_distances_m: ``(K,)`` their GNSS distances [m]
    :param boxes: ``(N, 4)`` detected boxes
    :param distances_m: ``(N,)`` the boxes' distances from Algorithm 1 [m]
    :param cost: the cost's weights
    :param extra_cost: optional ``(K, N)`` term added to the cost (e.g. a bonus for keeping
        last frame's box); it does not move the gate
    :param expected_boxes: optional ``(K, 4)`` expected boxes (NaN rows: use the anchor)
    :param anchor_sigma_px: optional ``(K,)`` uncertainty of each anchor [px] (default 0)
    :return: for each vehicle, the index of its box or ``None``
    """
    a = np.ascontiguousarray(anchors_uv, dtype=float).reshape(-1, 2)
    g = np.ascontiguousarray(gnss_distances_m, dtype=float).reshape(-1)
    b = np.ascontiguousarray(boxes, dtype=float).reshape(-1, 4)
    d = np.ascontiguousarray(distances_m, dtype=float).reshape(-1)
    out: list[int | None] = [None] * len(a)
    if not len(a) or not len(b):
        return out
    sigma = (np.zeros(len(a)) if anchor_sigma_px is None
             else np.ascontiguousarray(anchor_sigma_px, dtype=float).reshape(-1))
    e = _NONE_2D if expected_boxes is None else np.ascontiguousarray(expected_boxes, dtype=float).reshape(len(a), 4)
    extra = _NONE_2D if extra_cost is None else np.ascontiguousarray(extra_cost, dtype=float).reshape(len(a), len(b))
    total, allowed = _joint_cost(a, g, b, d, sigma, e, extra, float(cost.depth_scale_m), float(cost.outside_penalty),
                                 float(cost.min_fit), float(cost.gate))
    rows, cols = linear_sum_assignment(total)
    for r, c in zip(rows.tolist(), cols.tolist(), strict=True):
        if allowed[r, c]:
            out[r] = c
    return out


_NOT_ALLOWED = 1e6
"""Cost given to forbidden pairs in the assignment (they are dropped afterwards)"""
_NONE_2D = np.zeros((0, 0))
"""An optional ``(K, ...)`` input that was not given"""


@kernel
def _joint_cost(a: np.ndarray, g: np.ndarray, b: np.ndarray, d: np.ndarray, sigma: np.ndarray, e: np.ndarray,
                extra: np.ndarray, depth_scale_m: float, outside_penalty: float, min_fit: float,
                gate: float) -> tuple[np.ndarray, np.ndarray]:
    """The joint matching's cost of each target-box pair (compiled).

    :func:`match_joint`'s cost ``(K, N)`` (forbidden pairs at ``_NOT_ALLOWED``) and which pairs are
    allowed; ``e`` and ``extra`` may have no rows (not given).
    """
    k_n, n_b = a.shape[0], b.shape[0]
    total = np.empty((k_n, n_b))
    allowed = np.empty((k_n, n_b), dtype=np.bool_)
    for i in range(k_n):
        s = sigma[i] if np.isfinite(sigma[i]) else 0.0
        has = (e.shape[0] > 0 and np.isfinite(e[i, 0]) and np.isfinite(e[i, 1]) and np.isfinite(e[i, 2])
               and np.isfinite(e[i, 3]))
        area_e = (e[i, 2] - e[i, 0]) * (e[i, 3] - e[i, 1]) if has else 0.0
        for j in range(n_b):
            ok = True
            if has:
                # expected-box row: how well the box fits the vehicle's projected outline (IoU)
                ix = fmax(fmin(e[i, 2], b[j, 2]) - fmax(e[i, 0], b[j, 0]), 0.0)
                iy = fmax(fmin(e[i, 3], b[j, 3]) - fmax(e[i, 1], b[j, 1]), 0.0)
                inter = ix * iy
                area_b = fmax((b[j, 2] - b[j, 0]) * (b[j, 3] - b[j, 1]), 1e-9)
                fit = inter / fmax(area_e + area_b - inter, 1e-9)
                geo = 2.0 * (1.0 - fit)
                depth = 0.0
                ok = fit >= min_fit
            else:
                # anchor row: offset from the box centre, 1 = at the edge, give or take the error
                ou = (a[i, 0] - (b[j, 0] + b[j, 2]) / 2) / (fmax(b[j, 2] - b[j, 0], 1.0) / 2 + 2.0 * s)
                ov = (a[i, 1] - (b[j, 1] + b[j, 3]) / 2) / (fmax(b[j, 3] - b[j, 1], 1.0) / 2 + 2.0 * s)
                inside = np.abs(ou) <= 1.0 and np.abs(ov) <= 1.0
                geo = np.hypot(ou, ov) + (0.0 if inside else outside_penalty)
                depth = np.abs(d[j] - g[i]) / depth_scale_m
                if np.isnan(depth):
                    depth = 0.0
            t = geo + depth
            if not np.isfinite(t):
                t = np.inf
            ok = ok and t <= gate
            allowed[i, j] = ok
            if extra.shape[0] > 0:
                t = t + extra[i, j]
            total[i, j] = t if ok else _NOT_ALLOWED
    return total, allowed

"""Algorithm 1 of the paper: the distance of each detected box from the depth image.

For each box: shrink it by the resize threshold ``th``, take the lower quarter of the
shrunk box, sample ``n`` random pixels there, and take the mean of their depth (the paper's
``avg``; ``reducer="median"`` is the robust variant, less hurt by road or background
pixels inside a loose box).

Reference: the depth image holds **planar** depth ``Z`` from the camera centre, so the
distances are planar depths too; compare them with the planar depth of the GNSS point
(:attr:`~dt_highway.camera.pinhole.Projection.depth_m`), not with its Euclidean range.
``reference="range"`` turns each sample into Euclidean range first, to compare with
:attr:`~dt_highway.camera.pinhole.Projection.range_m` instead.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

Reducer = Literal["mean", "median"]
Reference = Literal["planar", "range"]


def row_median(values: np.ndarray) -> np.ndarray:
    """Median of each row of a 2-D array: ``np.median(values, axis=1)`` from a partial sort
    (the same numbers, without ``np.median``'s overhead on small arrays)."""
    n = values.shape[1]
    mid = n // 2
    if n % 2:
        return np.partition(values, mid, axis=1)[:, mid]
    part = np.partition(values, [mid - 1, mid], axis=1)
    return (part[:, mid - 1] + part[:, mid]) / 2


def sample_regions(boxes: np.ndarray, th: float, shape: tuple[int, int]) -> np.ndarray:
    """The sampling area of each box: the lower quarter of the box shrunk by ``th``.

    The box keeps its centre and loses ``th`` of its width and of its height (Alg. 1,
    line 2), then the bottom quarter of what is left is the area ``A``; it is clipped to
    the image.

    :param boxes: ``(N, 4)`` boxes ``x1, y1, x2, y2`` [px]
    :param th: resize threshold in ``[0, 1)`` [-]
    :param shape: image ``(height, width)`` [px]
    :return: ``(N, 4)`` areas ``x1, y1, x2, y2`` [px] (may be empty: ``x2 <= x1``)
    """
    if not 0.0 <= th < 1.0:
        raise ValueError(f"the resize threshold th must be in [0, 1) (got {th})")
    b = np.asarray(boxes, dtype=float).reshape(-1, 4)
    cx, cy = (b[:, 0] + b[:, 2]) / 2, (b[:, 1] + b[:, 3]) / 2
    half_w, half_h = (b[:, 2] - b[:, 0]) * (1 - th) / 2, (b[:, 3] - b[:, 1]) * (1 - th) / 2
    x1, x2 = cx - half_w, cx + half_w
    y2 = cy + half_h
    y1 = y2 - half_h / 2  # the lower quarter of the shrunk box's height (2 * half_h)
    h, w = shape
    lo = np.array([-0.5, -0.5, -0.5, -0.5])
    hi = np.array([w - 0.5, h - 0.5, w - 0.5, h - 0.5])
    return np.minimum(np.maximum(np.stack([x1, y1, x2, y2], axis=1), lo), hi)


def box_distances(
    depth_m: np.ndarray,
    boxes: np.ndarray,
    th: float = 0.2,
    n: int = 20,
    rng: np.random.Generator | None = None,
    reducer: Reducer = "mean",
    reference: Reference = "planar",
    ray_norm: np.ndarray | None = None,
) -> np.ndarray:
    """Algorithm 1 (depth evaluation): one distance per box.

    :param depth_m: planar depth image ``(H, W)`` [m]
    :param boxes: ``(N, 4)`` detected boxes ``x1, y1, x2, y2`` [px]
    :param th: box resize threshold [-]
    :param n: sample points per box [-]
    :param rng: random generator for the sample positions
    :param reducer: ``"mean"`` (the paper) or ``"median"`` (robust)
    :param reference: ``"planar"`` (depth along the optical axis) or ``"range"`` (distance
        from the camera centre; needs ``ray_norm``, e.g. ``frame.range_m() / frame.depth_m``)
    :param ray_norm: per-pixel factor range / planar depth ``(H, W)``, for ``reference="range"``
    :return: ``(N,)`` distances [m]; NaN for a box whose sampling area holds no pixel
    """
    if n < 1:
        raise ValueError(f"n (sample points per box) must be >= 1 (got {n})")
    if reducer not in ("mean", "median"):
        raise ValueError(f"reducer must be 'mean' or 'median' (got {reducer!r})")
    if reference not in ("planar", "range"):
        raise ValueError(f"reference must be 'planar' or 'range' (got {reference!r})")
    if reference == "range" and ray_norm is None:
        raise ValueError("reference='range' needs ray_norm (range / planar depth per pixel)")
    rng = rng if rng is not None else np.random.default_rng()
    area = sample_regions(boxes, th, depth_m.shape)
    if not len(area):
        return np.zeros(0)
    # integer pixel columns/rows whose centres lie in the area
    c0, c1 = np.ceil(area[:, 0]), np.floor(area[:, 2])
    r0, r1 = np.ceil(area[:, 1]), np.floor(area[:, 3])
    c1 = np.minimum(c1, depth_m.shape[1] - 1)
    r1 = np.minimum(r1, depth_m.shape[0] - 1)
    empty = (c1 < c0) | (r1 < r0)
    # a degenerate area (thinner than a pixel) falls back to the pixel at its centre
    cc = np.round((area[:, 0] + area[:, 2]) / 2)
    rc = np.round((area[:, 1] + area[:, 3]) / 2)
    c0, c1 = np.where(empty, cc, c0), np.where(empty, cc, c1)
    r0, r1 = np.where(empty, rc, r0), np.where(empty, rc, r1)
    inside = (c0 >= 0) & (c0 < depth_m.shape[1]) & (r0 >= 0) & (r0 < depth_m.shape[0])
    u = (c0[:, None] + np.floor(rng.random((len(area), n)) * (c1 - c0 + 1)[:, None])).astype(np.intp)
    v = (r0[:, None] + np.floor(rng.random((len(area), n)) * (r1 - r0 + 1)[:, None])).astype(np.intp)
    u = np.minimum(np.maximum(u, 0), depth_m.shape[1] - 1)
    v = np.minimum(np.maximum(v, 0), depth_m.shape[0] - 1)
    samples = depth_m[v, u].astype(float)
    if reference == "range":
        samples = samples * ray_norm[v, u]
    out = samples.sum(axis=1) / n if reducer == "mean" else row_median(samples)
    return np.where(inside, out, np.nan)

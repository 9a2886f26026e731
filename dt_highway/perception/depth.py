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

from dt_highway._jit import fmax, fmin, kernel

Reducer = Literal["mean", "median"]
Reference = Literal["planar", "range"]


def row_median(values: np.ndarray) -> np.ndarray:
    """Median of each row of a 2-D array: ``np.median(values, axis=1)`` (the same numbers,
    compiled, without ``np.median``'s overhead on small arrays).

    :param values: a 2-D array ``(N, M)``
    :return: the median of each row ``(N,)``
    """
    return _row_medians(np.ascontiguousarray(values, dtype=float))


@kernel
def _regions(b: np.ndarray, th: float, height: int, width: int) -> np.ndarray:
    """The sampling area of each box (compiled).

    :func:`sample_regions` without the checks (compiled).
    """
    out = np.empty((b.shape[0], 4))
    lo, hi_u, hi_v = -0.5, width - 0.5, height - 0.5
    for i in range(b.shape[0]):
        cx, cy = (b[i, 0] + b[i, 2]) / 2, (b[i, 1] + b[i, 3]) / 2
        half_w, half_h = (b[i, 2] - b[i, 0]) * (1 - th) / 2, (b[i, 3] - b[i, 1]) * (1 - th) / 2
        y2 = cy + half_h
        y1 = y2 - half_h / 2  # the lower quarter of the shrunk box's height (2 * half_h)
        out[i, 0] = fmin(fmax(cx - half_w, lo), hi_u)
        out[i, 1] = fmin(fmax(y1, lo), hi_v)
        out[i, 2] = fmin(fmax(cx + half_w, lo), hi_u)
        out[i, 3] = fmin(fmax(y2, lo), hi_v)
    return out


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
    b = np.ascontiguousarray(boxes, dtype=float).reshape(-1, 4)
    return _regions(b, float(th), int(shape[0]), int(shape[1]))


@kernel
def _row_medians(samples: np.ndarray) -> np.ndarray:
    """The middle value of each row, or the mean of the two middle values."""
    n_box, n = samples.shape
    out = np.empty(n_box)
    mid = n // 2
    row = np.empty(n)
    for i in range(n_box):
        for j in range(n):  # insertion sort: the rows are short (Algorithm 1's n points)
            v = samples[i, j]
            k = j
            while k > 0 and (row[k - 1] > v or row[k - 1] != row[k - 1]):
                row[k] = row[k - 1]
                k -= 1
            row[k] = v
        out[i] = row[mid] if n % 2 else (row[mid - 1] + row[mid]) / 2
    return out


@kernel
def _sample(depth_m: np.ndarray, area: np.ndarray, draw_u: np.ndarray, draw_v: np.ndarray,
            ray_norm: np.ndarray, use_ray_norm: bool) -> tuple[np.ndarray, np.ndarray]:
    """Depth at ``n`` pixels per area, drawn uniformly from ``draw_u``, ``draw_v`` in ``[0, 1)``.

    :return: samples ``(N, n)`` [m] and whether each area lies in the image ``(N,)``
    """
    height, width = depth_m.shape
    n_box, n = draw_u.shape
    samples = np.empty((n_box, n))
    inside = np.empty(n_box, dtype=np.bool_)
    for i in range(n_box):
        # integer pixel columns/rows whose centres lie in the area
        c0, c1 = np.ceil(area[i, 0]), fmin(np.floor(area[i, 2]), width - 1)
        r0, r1 = np.ceil(area[i, 1]), fmin(np.floor(area[i, 3]), height - 1)
        if c1 < c0 or r1 < r0:
            # a degenerate area (thinner than a pixel) falls back to the pixel at its centre
            c0 = c1 = np.round((area[i, 0] + area[i, 2]) / 2)
            r0 = r1 = np.round((area[i, 1] + area[i, 3]) / 2)
        inside[i] = c0 >= 0 and c0 < width and r0 >= 0 and r0 < height
        for j in range(n):
            u = min(max(int(c0 + np.floor(draw_u[i, j] * (c1 - c0 + 1))), 0), width - 1)
            v = min(max(int(r0 + np.floor(draw_v[i, j] * (r1 - r0 + 1))), 0), height - 1)
            samples[i, j] = float(depth_m[v, u]) * float(ray_norm[v, u]) if use_ray_norm else float(depth_m[v, u])
    return samples, inside


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
    draw_u, draw_v = rng.random((len(area), n)), rng.random((len(area), n))
    norm = ray_norm if reference == "range" and ray_norm is not None else depth_m  # (given for "range": checked above)
    samples, inside = _sample(depth_m, area, draw_u, draw_v, norm, reference == "range")
    # the mean stays in numpy: its summation order defines the last bit
    out = samples.sum(axis=1) / n if reducer == "mean" else _row_medians(samples)
    return np.where(inside, out, np.nan)

"""Two-dimensional surrogate safety measures between road users drawn as oriented rectangles.

* **2-D TTC** [s] (:func:`ttc_2d`, :func:`min_ttc_2d`): both road users keep their current
  velocity (translation, no rotation); the TTC is the earliest time ``t >= 0`` at which the
  two rectangles touch, ``math.inf`` when they never do (diverging, or parallel paths that
  never meet). Rectangles are closed sets: touching counts as contact, as in highway-env's
  collision check. Rectangles that already touch or overlap have TTC ``0.0``, and
  ``ttc_2d(a, b) == 0.0`` exactly when :func:`overlapping` ``(a, b)`` is true, so a caller
  can count that state as a collision rather than as a TTC sample.
* **PET** [s] (:func:`post_encroachment_time`): for two sampled trajectories, the time
  between the first road user leaving a spot of the conflict area (where the two swept
  footprints overlap) and the second one reaching it, minimised over the spots;
  ``math.inf`` when the paths never share space.

Algorithm of the TTC: the separating-axis theorem on the relative motion (Eberly, D.,
"Intersection of Convex Objects: The Method of Separating Axes", Geometric Tools, 2001;
Ericson, C., *Real-Time Collision Detection*, 2005, section 5.5 on moving objects). Two rectangles are
disjoint exactly when their projections are disjoint on one of four candidate axes (the
heading and its normal of each). On an axis ``u`` the projections' centres are ``d(t) = d +
s t`` apart, with ``d = u . (p_b - p_a)`` and ``s = u . (v_b - v_a)``, and they overlap while
``|d + s t| <= r_a + r_b``, where ``r = (L / 2) |u . h| + (W / 2) |u . n|`` is a rectangle's
half-extent on ``u``. Each axis gives one time interval (all times, or none, when ``s = 0``);
the rectangles touch on the intersection ``[t_enter, t_exit]`` of the four intervals, and the
TTC is ``max(t_enter, 0)`` when that is not after ``t_exit``. This is exact (no time stepping)
and gives the same number as Jiao's corner-to-edge construction (Jiao, Y., 2023, "A fast
calculation of two-dimensional Time-to-Collision": first contact is a corner of one rectangle
reaching an edge of the other along the relative velocity), which the tests use as the
independent oracle, with brute-force time stepping.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from highway_env.vehicle.kinematics import Vehicle

X, Y, LENGTH, WIDTH, HEADING, VX, VY = range(7)
"""Columns of a footprint array (:func:`footprint_array`)"""


@dataclass(frozen=True)
class Footprint:
    """A road user as an oriented rectangle moving at constant velocity.

    :param x_m: centre x [m]
    :param y_m: centre y [m]
    :param length_m: length along the heading [m]
    :param width_m: width across the heading [m]
    :param heading_rad: heading, counter-clockwise from the x axis [rad]
    :param vx_mps: velocity x [m/s] (need not point along the heading)
    :param vy_mps: velocity y [m/s]
    """

    x_m: float
    y_m: float
    length_m: float
    width_m: float
    heading_rad: float
    vx_mps: float = 0.0
    vy_mps: float = 0.0

    @classmethod
    def from_vehicle(cls, vehicle: Vehicle) -> Footprint:
        """The footprint of a highway-env vehicle (or any object with the same attributes).

        :param vehicle: object with ``position`` [m], ``LENGTH`` [m], ``WIDTH`` [m], ``heading``
            [rad] and ``velocity`` [m/s]
        :return: its footprint
        """
        x_m, y_m = vehicle.position
        vx_mps, vy_mps = vehicle.velocity
        return cls(
            float(x_m), float(y_m), float(vehicle.LENGTH), float(vehicle.WIDTH), float(vehicle.heading), float(vx_mps),
            float(vy_mps),
        )


def footprint_array(footprints: Sequence[Footprint]) -> np.ndarray:
    """Footprints as one array, a row each, columns :data:`X`, :data:`Y`, ... :data:`VY`.

    :param footprints: the footprints
    :return: ``(N, 7)`` array ``x [m], y [m], length [m], width [m], heading [rad], vx [m/s], vy [m/s]``
    """
    rows = [(f.x_m, f.y_m, f.length_m, f.width_m, f.heading_rad, f.vx_mps, f.vy_mps) for f in footprints]
    return np.array(rows, dtype=float).reshape(len(rows), 7)


def corners_m(fp: np.ndarray) -> np.ndarray:
    """The corners of each footprint: front left, front right, rear right, rear left.

    :param fp: ``(N, 7)`` footprint array
    :return: ``(N, 4, 2)`` corners ``x, y`` [m]
    """
    c, s = np.cos(fp[:, HEADING]), np.sin(fp[:, HEADING])
    half_l, half_w = fp[:, LENGTH] / 2, fp[:, WIDTH] / 2
    along = np.array([1.0, 1.0, -1.0, -1.0])[None, :] * half_l[:, None]
    left = np.array([1.0, -1.0, -1.0, 1.0])[None, :] * half_w[:, None]
    xs = fp[:, X, None] + along * c[:, None] - left * s[:, None]
    ys = fp[:, Y, None] + along * s[:, None] + left * c[:, None]
    return np.stack((xs, ys), axis=-1)


def _half_extents_m(fp: np.ndarray, ux: np.ndarray, uy: np.ndarray) -> np.ndarray:
    """Half of each footprint's projection on each axis: ``(L / 2) |u . h| + (W / 2) |u . n|``.

    :param fp: ``(N, 7)`` footprint array
    :param ux: ``(N, K)`` axes' x components (unit axes)
    :param uy: ``(N, K)`` axes' y components
    :return: ``(N, K)`` half-extents [m]
    """
    c, s = np.cos(fp[:, HEADING, None]), np.sin(fp[:, HEADING, None])
    return fp[:, LENGTH, None] / 2 * np.abs(ux * c + uy * s) + fp[:, WIDTH, None] / 2 * np.abs(uy * c - ux * s)


def _separation(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """On the four candidate axes of each pair: centre offset, its rate, and the contact distance.

    :param a: ``(N, 7)`` (or ``(1, 7)``, broadcast) footprint array
    :param b: ``(N, 7)`` footprint array
    :return: ``(N, 4)`` arrays ``d = u . (p_b - p_a)`` [m], ``s = u . (v_b - v_a)`` [m/s] and
        ``r = r_a + r_b`` [m], on the axes: a's heading, a's normal, b's heading, b's normal
    """
    a = np.broadcast_to(a, b.shape)
    ca, sa, cb, sb = np.cos(a[:, HEADING]), np.sin(a[:, HEADING]), np.cos(b[:, HEADING]), np.sin(b[:, HEADING])
    ux, uy = np.stack((ca, -sa, cb, -sb), axis=1), np.stack((sa, ca, sb, cb), axis=1)
    d_m = ux * (b[:, X, None] - a[:, X, None]) + uy * (b[:, Y, None] - a[:, Y, None])
    s_mps = ux * (b[:, VX, None] - a[:, VX, None]) + uy * (b[:, VY, None] - a[:, VY, None])
    r_m = _half_extents_m(a, ux, uy) + _half_extents_m(b, ux, uy)
    return d_m, s_mps, r_m


def _axis_intervals_s(d_m: np.ndarray, s_mps: np.ndarray, r_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per axis, the times ``[lo, hi]`` when the projections touch: ``|d + s t| <= r``.

    Without relative motion on the axis (``s = 0``) that is all times or none.

    :param d_m: centre offsets [m]
    :param s_mps: their rates [m/s]
    :param r_m: contact distances [m]
    :return: ``lo`` and ``hi`` [s] (``lo > hi`` when never)
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        t_a, t_b = (-r_m - d_m) / s_mps, (r_m - d_m) / s_mps
    moving, touching = s_mps != 0.0, np.abs(d_m) <= r_m
    lo = np.where(moving, np.minimum(t_a, t_b), np.where(touching, -math.inf, math.inf))
    hi = np.where(moving, np.maximum(t_a, t_b), np.where(touching, math.inf, -math.inf))
    return lo, hi


def contact_interval_s(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The times ``[t_enter, t_exit]`` when each pair of rectangles touches or overlaps.

    :param a: ``(N, 7)`` (or ``(1, 7)``, broadcast) footprint array
    :param b: ``(N, 7)`` footprint array
    :return: ``t_enter`` and ``t_exit`` [s], ``(N,)`` each; the pair never touches when
        ``t_enter > t_exit``; times before now are negative
    """
    lo, hi = _axis_intervals_s(*_separation(a, b))
    return lo.max(axis=1), hi.min(axis=1)


def ttc_2d_many(a: np.ndarray, b: np.ndarray, horizon_s: float = math.inf) -> np.ndarray:
    """2-D TTC of each pair of rows (see the module's docstring), vectorised.

    :param a: ``(N, 7)`` (or ``(1, 7)``, broadcast) footprint array (:func:`footprint_array`)
    :param b: ``(N, 7)`` footprint array
    :param horizon_s: contacts later than this count as none [s]
    :return: ``(N,)`` TTC [s]: ``0.0`` when already overlapping, ``inf`` when never within the horizon
    """
    if not horizon_s >= 0.0:
        raise ValueError(f"horizon_s must be >= 0, got {horizon_s}")
    t_enter, t_exit = contact_interval_s(a, b)
    start = np.where(t_enter > 0.0, t_enter, 0.0)
    return np.where((start <= t_exit) & (start <= horizon_s), start, math.inf)


def ttc_2d(a: Footprint, b: Footprint, horizon_s: float = math.inf) -> float:
    """2-D TTC [s] of two rectangles moving at constant velocity (see the module's docstring).

    :param a: one road user
    :param b: the other (symmetric: ``ttc_2d(a, b) == ttc_2d(b, a)``)
    :param horizon_s: contacts later than this count as none [s]
    :return: the earliest time ``t >= 0`` at which they touch [s]; ``0.0`` when they already
        overlap (check :func:`overlapping`); ``math.inf`` when never (within the horizon)
    """
    return float(ttc_2d_many(footprint_array([a]), footprint_array([b]), horizon_s)[0])


def overlapping(a: Footprint, b: Footprint) -> bool:
    """Whether two rectangles touch or overlap now (separating-axis test at ``t = 0``).

    :param a: one road user
    :param b: the other
    :return: true when no candidate axis separates them (then :func:`ttc_2d` is ``0.0``)
    """
    d_m, _, r_m = _separation(footprint_array([a]), footprint_array([b]))
    return bool(np.all(np.abs(d_m) <= r_m))


def penetration_depth_m(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """How deep each pair of rectangles overlaps now: the smallest ``r - |d|`` over the four axes.

    :param a: ``(N, 7)`` (or ``(1, 7)``, broadcast) footprint array
    :param b: ``(N, 7)`` footprint array
    :return: ``(N,)`` depth [m]: ``>= 0`` when the pair touches or overlaps, ``< 0`` when apart
    """
    d_m, _, r_m = _separation(a, b)
    return (r_m - np.abs(d_m)).min(axis=1)


CONTACT_AXES = ("a_heading", "a_normal", "b_heading", "b_normal")
"""Names of the candidate axes :func:`contact_axis` returns the index of"""


def contact_axis(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """For pairs that touch now, the axis on which their projections met last, going back in time
    at the current velocities: the faces that made the contact.

    Axis ``0`` (``1``) is ``a``'s heading (normal), ``2`` (``3``) ``b``'s. On a heading axis the
    contact is through a front or rear face (a rear-end); on a normal axis through a side (a
    side-swipe). Without relative motion on any axis the answer is ``0``.

    :param a: ``(N, 7)`` (or ``(1, 7)``, broadcast) footprint array
    :param b: ``(N, 7)`` footprint array
    :return: ``(N,)`` axis index, one of ``0..3`` (:data:`CONTACT_AXES`)
    """
    lo, _ = _axis_intervals_s(*_separation(a, b))
    return np.argmax(lo, axis=1)


def min_ttc_2d(ego: Footprint, others: Sequence[Footprint], horizon_s: float = math.inf) -> tuple[float, int]:
    """The ego's smallest 2-D TTC to any of the others, and which.

    An other that overlaps the ego gives ``0.0``; ``overlapping(ego, others[i])`` tells it apart.

    :param ego: the ego
    :param others: the other road users
    :param horizon_s: contacts later than this count as none [s]
    :return: minimum TTC [s] and its index in ``others`` (the first on ties);
        ``(math.inf, -1)`` when no other is on a collision course (or there are none)
    """
    if not others:
        return math.inf, -1
    ttc_s = ttc_2d_many(footprint_array([ego]), footprint_array(others), horizon_s)
    i = int(np.argmin(ttc_s))
    return (float(ttc_s[i]), i) if ttc_s[i] < math.inf else (math.inf, -1)


# ------------------------------------------------------------------------------------- PET
def _grid_centres_m(lo_m: np.ndarray, hi_m: np.ndarray, cell_m: float) -> np.ndarray:
    """Centres of a grid of equal cells, at most ``cell_m`` on a side, tiling a box.

    :param lo_m: the box's lower corner ``x, y`` [m]
    :param hi_m: its upper corner [m]
    :param cell_m: largest cell side [m]
    :return: ``(C, 2)`` cell centres [m]
    """
    n = np.maximum(np.ceil((hi_m - lo_m) / cell_m), 1.0).astype(int)
    xs = lo_m[0] + (np.arange(n[0]) + 0.5) * (hi_m[0] - lo_m[0]) / n[0]
    ys = lo_m[1] + (np.arange(n[1]) + 0.5) * (hi_m[1] - lo_m[1]) / n[1]
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    return np.stack((gx.ravel(), gy.ravel()), axis=1)


def _inside_margins_m(track: np.ndarray, points_m: np.ndarray) -> np.ndarray:
    """How far each point is inside each footprint, along and across it: ``L / 2 - |u|`` and ``W / 2 - |w|``.

    ``u, w`` are the point's coordinates along and across the footprint; the point is inside
    (or on the boundary) when both margins are ``>= 0``. For a footprint translating at
    constant velocity each margin is linear in time near its zero.

    :param track: ``(T, 7)`` footprint array
    :param points_m: ``(C, 2)`` points [m]
    :return: ``(2, T, C)`` margins [m]
    """
    c, s = np.cos(track[:, HEADING, None]), np.sin(track[:, HEADING, None])
    dx, dy = points_m[None, :, 0] - track[:, X, None], points_m[None, :, 1] - track[:, Y, None]
    u, w = dx * c + dy * s, dy * c - dx * s
    return np.stack((track[:, LENGTH, None] / 2 - np.abs(u), track[:, WIDTH, None] / 2 - np.abs(w)))


def _occupancy_s(t_s: np.ndarray, margins_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """When a track first reaches and last leaves each point.

    Between the last sample outside and the first inside, each margin that was negative is
    interpolated linearly to its zero, and the point is reached when the last of them is
    (leaving: when the first margin turns negative); this is exact for a footprint that
    translates at constant velocity between the two samples. A point occupied at the first
    (last) sample is reached (left) at that sample's time.

    :param t_s: ``(T,)`` sample times [s]
    :param margins_m: ``(2, T, C)`` margins (:func:`_inside_margins_m`) [m]
    :return: ``(C,)`` whether each point is ever occupied, its first entry and last exit [s]
    """
    inside = np.all(margins_m >= 0.0, axis=0)
    last = len(t_s) - 1
    k_in = np.argmax(inside, axis=0)
    k_out = last - np.argmax(inside[::-1], axis=0)
    k0, k1 = np.maximum(k_in - 1, 0), np.minimum(k_out + 1, last)
    cols = np.arange(margins_m.shape[2])
    m_before, m_in = margins_m[:, k0, cols], margins_m[:, k_in, cols]
    m_out, m_after = margins_m[:, k_out, cols], margins_m[:, k1, cols]
    with np.errstate(divide="ignore", invalid="ignore"):
        enter_frac = np.where(m_before < 0.0, m_before / (m_before - m_in), 0.0).max(axis=0)
        exit_frac = np.where(m_after < 0.0, m_out / (m_out - m_after), 1.0).min(axis=0)
        enter_s = np.where(k_in == 0, t_s[0], t_s[k0] + (t_s[k_in] - t_s[k0]) * enter_frac)  # NaN where never inside
        exit_s = np.where(k_out == last, t_s[-1], t_s[k_out] + (t_s[k1] - t_s[k_out]) * exit_frac)
    return inside.any(axis=0), enter_s, exit_s


def _bounding_box_m(track: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The axis-aligned box around all footprints of a track.

    :param track: ``(T, 7)`` footprint array
    :return: lower and upper corners ``x, y`` [m]
    """
    points = corners_m(track).reshape(-1, 2)
    return points.min(axis=0), points.max(axis=0)


def post_encroachment_time(
    t_s: Sequence[float] | np.ndarray,
    ego_track: Sequence[Footprint],
    other_track: Sequence[Footprint],
    cell_m: float = 0.5,
) -> float:
    """Post-encroachment time [s] of two road users' sampled trajectories (e.g. a cut-in).

    Definition (Allen, Shin & Cooper, 1978), at every spot of the conflict area: the time
    from the first road user leaving the spot to the second one reaching it; the PET is its
    minimum over the conflict area. For one crossing point that is the classic PET; for a
    vehicle that ends up ahead in the ego's lane it is the time gap from its rear bumper to
    the ego's front bumper. Spots both occupy at the same time give 0 (a collision there).

    Discretisation: the overlap of the two tracks' bounding boxes is tiled with equal cells
    of at most ``cell_m`` on a side; a cell belongs to a footprint when its centre does (the
    velocities are not used). For each cell and track, the first entry and last exit times
    are interpolated between samples (exact for a footprint that translates at constant
    velocity between them; a track that leaves a cell and comes back counts as occupying it
    throughout). The conflict area is the set of cells both tracks occupy. The minimum over
    cell centres misses the area's extreme spot by less than about one cell, so the result
    is within about ``cell_m * (1 / v_first + 1 / v_second)`` [s] of the exact PET (``v`` the
    road users' speeds [m/s]). Cost: ``O(samples * cells)``.

    :param t_s: ``(T,)`` strictly increasing sample times [s], ``T >= 2``
    :param ego_track: the ego's footprint at each sample time
    :param other_track: the other road user's footprint at each sample time
    :param cell_m: largest cell side [m]
    :return: PET [s], ``>= 0``; ``math.inf`` (not NaN) when the two paths never share space
    """
    times_s = np.asarray(t_s, dtype=float)
    if times_s.ndim != 1 or len(times_s) < 2 or not np.all(np.diff(times_s) > 0):
        raise ValueError("t_s must hold at least two strictly increasing times")
    if len(ego_track) != len(times_s) or len(other_track) != len(times_s):
        got = f"{len(ego_track)} and {len(other_track)}"
        raise ValueError(f"both tracks need one footprint per time ({len(times_s)}), got {got}")
    if not cell_m > 0.0:
        raise ValueError(f"cell_m must be > 0, got {cell_m}")
    ego, other = footprint_array(ego_track), footprint_array(other_track)
    (ego_lo, ego_hi), (other_lo, other_hi) = _bounding_box_m(ego), _bounding_box_m(other)
    lo_m, hi_m = np.maximum(ego_lo, other_lo), np.minimum(ego_hi, other_hi)
    if np.any(lo_m > hi_m):
        return math.inf
    centres_m = _grid_centres_m(lo_m, hi_m, cell_m)
    ego_in, ego_enter_s, ego_exit_s = _occupancy_s(times_s, _inside_margins_m(ego, centres_m))
    other_in, other_enter_s, other_exit_s = _occupancy_s(times_s, _inside_margins_m(other, centres_m))
    conflict = ego_in & other_in
    if not conflict.any():
        return math.inf
    pet_s = np.maximum(np.maximum(other_enter_s - ego_exit_s, ego_enter_s - other_exit_s), 0.0)
    return float(pet_s[conflict].min())

"""The Intelligent Driver Model (Treiber, Hennecke & Helbing 2000, Phys. Rev. E 62, 1805):
car following for the scripted drivers and the assisted action menu."""

from __future__ import annotations

import math

from dt_highway.agent_config import IDMParams

__all__ = ["IDMParams", "idm_accel"]


def idm_accel(speed_mps: float, gap_m: float, closing_mps: float, p: IDMParams,
              desired_speed_mps: float | None = None, time_headway_s: float | None = None) -> float:
    """IDM acceleration [m/s^2]: ``a [1 - (v/v0)^delta - (s*/s)^2]``, ``s* = s0 + vT + v dv / (2 sqrt(ab))``.

    :param speed_mps: own speed ``v`` [m/s]
    :param gap_m: gap to the leader ``s`` [m] (inf: free road)
    :param closing_mps: ``dv = v - v_leader`` [m/s]
    :param p: parameters
    :param desired_speed_mps: overrides ``v0``
    :param time_headway_s: overrides ``T``
    :return: the acceleration [m/s^2]
    """
    v0 = p.desired_speed_mps if desired_speed_mps is None else desired_speed_mps
    t = p.time_headway_s if time_headway_s is None else time_headway_s
    free = 1.0 - (max(speed_mps, 0.0) / v0) ** p.delta
    if not math.isfinite(gap_m):
        return p.max_accel_mps2 * free
    s_star = p.min_gap_m + max(0.0, speed_mps * t
                               + speed_mps * closing_mps / (2.0 * math.sqrt(p.max_accel_mps2 * p.comfort_decel_mps2)))
    return p.max_accel_mps2 * (free - (s_star / max(gap_m, 0.1)) ** 2)

"""A continuum of drivers: every driver's own parameters, correlated through a latent aggressiveness.

Ground truth only (the simulator's; the twin never sees it). With ``traffic.population =
"continuum"`` every driver of the population draws

* a **latent aggressiveness** ``z ~ N(0, 1)``;
* for each parameter ``k`` a standard normal **copula variable**
  ``u_k = rho_k z + sqrt(1 - rho_k^2) e_k`` (``e_k ~ N(0, 1)`` independent), so that
  ``corr(u_k, z) = rho_k`` (``traffic.continuum.<k>.corr_z``), and the parameter is a monotone map of
  ``u_k``: ``mean + sd u_k`` (normal) or ``median exp(log_sd u_k)`` (log-normal), clipped to
  ``[low, high]``. The rank correlation of a parameter with ``z`` is then ``(6/pi) asin(rho_k / 2)``
  (Spearman's, of a bivariate normal; slightly less where clipping ties values);
* **aggressive** ground truth: the top ``traffic.aggressive_fraction`` of the population by ``z``,
  an exact count (``round(fraction * size)``), as the two-class world's exact share.

The defaults (``traffic.continuum``; parameter, distribution, 5-95 % range before clipping,
clipping range, ``corr_z``) and where they come from:

=============================  ==========================  ==============  ============  ======
parameter                      distribution                5-95 %          clipped to    corr_z
=============================  ==========================  ==============  ============  ======
desired_speed_mps              normal 26, sd 2.5           21.9-30.1       20-34          +0.5
time_headway_s                 log-normal 1.3, log-sd 0.3  0.8-2.1         0.5-2.5        -0.6
min_gap_m                      normal 9, sd 1              7.4-10.6        6-12           -0.4
comfort_acc_mps2               log-normal 3.0, 0.2         2.2-4.2         1.5-5          +0.4
comfort_dec_mps2               log-normal 5.0, 0.15        3.9-6.4         3.5-8          +0.4
politeness                     normal 0.35, sd 0.2         0.02-0.68       0-1            -0.6
lane_change_min_gain_mps2      log-normal 0.15, 0.5        0.07-0.34       0.02-0.6       -0.5
max_braking_imposed_mps2       log-normal 3.0, 0.35        1.7-5.3         1.5-7          +0.6
lane_change_delay_s            log-normal 0.8, 0.4         0.41-1.55       0.2-2.5        -0.5
max_lateral_speed_mps          log-normal 0.8, 0.5         0.35-1.8        0.3-3.5        +0.8
cut_in_rate_per_min            log-normal 0.5, 1.0         0.1-2.6         0-10           +0.8
=============================  ==========================  ==============  ============  ======

* **IDM** (desired speed, time headway, jam distance, acceleration, comfortable deceleration):
  Treiber's IDM pages give typical highway values ``v0`` 120 km/h, ``T`` 1.5-1.8 s, ``s0`` 2 m,
  ``a`` 1 m/s^2, ``b`` 1.5-3 m/s^2, and Treiber & Kesting, *Traffic Flow Dynamics* (Springer 2013,
  ch. 11) ranges of roughly ``T`` 0.8-2 s and ``s0`` 0-5 m (from memory, not re-checked against the
  book here). The centres are our two-class world's normal driver (highway-env's IDM: ``s0`` + car
  length 10 m, ``a`` 3 m/s^2, ``b`` 5 m/s^2, speed limit 30 m/s) pulled toward the literature where
  the world allows (``T`` 1.3 s, ``min_gap_m`` 9 m = 4 m + 5 m car): we keep highway-env's scale of
  ``a`` and ``b``, larger than the literature's, so that the continuum drives like the world it
  lives in. The spreads and correlations are **our assumption** (shorter headways, higher speeds and
  harder acceleration with aggressiveness, as the two-class presets).
* **MOBIL** (politeness, gain threshold, max braking imposed): Kesting, Treiber & Helbing (2007),
  "General lane-changing model MOBIL for car-following models", TRR 1999, and Treiber's MOBIL page:
  politeness ``p`` 0-0.5 for realistic drivers (0: selfish), threshold ``a_thr`` 0.1-0.2 m/s^2,
  safe braking ``b_safe`` 4 m/s^2 (below the ~9 m/s^2 possible). Our centres sit between those and
  the normal preset (``p`` 0.5, ``b_safe`` 2 m/s^2); spreads and correlations are **our assumption**.
* **Lane-change decision period**: highway-env's ``LANE_CHANGE_DELAY`` of 1 s; the spread is
  **our assumption**.
* **Lateral speed**: naturalistic highway lane changes take roughly 4-8 s (highD, Krajewski et al.
  2018, as used in this project's design notes), i.e. ~0.5-1 m/s over a 4 m lane; Toledo & Zohar
  (2007), "Modeling duration of lane changes", TRR 1999, report mean durations of 5-6 s. The
  log-normal's quartiles, 0.57-1.12 m/s (3.6-7 s for 4 m), match that; the upper tail (5 % above
  1.8 m/s, the most aggressive reaching the two-class aggressive driver's 3 m/s) stands for the
  sudden lane changes of aggressive drivers: **its width is our assumption**. The lateral controller
  leaves its speed limit ``lateral_settle_m`` (1 m) from the new lane's centre, time constant
  ``lateral_settle_m / max_lateral_speed_mps`` (1 s at 1 m/s, 0.33 s at 3 m/s: the two presets' 1
  and 0.35 s).
* **Cut-in propensity** (attempts per minute; an attempt without a victim ends in a lane hop, as in
  the two-class world): the population mean, ``0.5 exp(1.0^2 / 2)`` = 0.82/min, is the two-class
  world's (20 % aggressive x 4/min = 0.8/min); the spread (a few drivers account for most cut-ins)
  and the correlation are **our assumption**.

The cut-ins' gap, search range, ego preference and chase time are ``traffic.cut_in_*`` in both
worlds; ``traffic.cut_in_rate_per_min``, ``traffic.normal`` and ``traffic.aggressive`` are the
two-class world's only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from dt_highway.config import ContinuumConfig, DriverParams, LogNormalTrait, NormalTrait


@dataclass(frozen=True)
class DriverProfile:
    """One driver's own IDM/MOBIL/lane-change/cut-in parameters (ground truth).

    :param desired_speed_mps: IDM desired speed [m/s]
    :param time_headway_s: IDM desired time gap [s]
    :param min_gap_m: IDM jam distance, bumper to bumper + car length [m]
    :param comfort_acc_mps2: IDM maximum acceleration [m/s^2]
    :param comfort_dec_mps2: IDM comfortable deceleration [m/s^2]
    :param politeness: MOBIL politeness factor [-]
    :param lane_change_min_gain_mps2: MOBIL acceleration gain threshold [m/s^2]
    :param max_braking_imposed_mps2: MOBIL safety criterion [m/s^2]
    :param lane_change_delay_s: time between lane-change decisions [s]
    :param lateral_time_constant_s: lateral position controller time constant [s]
    :param max_lateral_speed_mps: largest lateral speed while changing lane [m/s]
    :param cut_in_rate_per_min: cut-in attempts (or, with no victim, lane hops) [1/min]; 0: never
    """

    desired_speed_mps: float
    time_headway_s: float
    min_gap_m: float
    comfort_acc_mps2: float
    comfort_dec_mps2: float
    politeness: float
    lane_change_min_gain_mps2: float
    max_braking_imposed_mps2: float
    lane_change_delay_s: float
    lateral_time_constant_s: float
    max_lateral_speed_mps: float
    cut_in_rate_per_min: float

    @classmethod
    def from_preset(cls, params: DriverParams, desired_speed_mps: float, cut_in_rate_per_min: float) -> DriverProfile:
        """A two-class driver: the type's preset parameters (the values themselves, unchanged).

        :param params: the driver type's parameters (``traffic.normal`` / ``traffic.aggressive``)
        :param desired_speed_mps: the speed drawn for this driver [m/s]
        :param cut_in_rate_per_min: ``traffic.cut_in_rate_per_min`` for an aggressive driver, else 0 [1/min]
        :return: the driver's profile
        """
        return cls(
            desired_speed_mps=desired_speed_mps,
            time_headway_s=params.time_headway_s,
            min_gap_m=params.min_gap_m,
            comfort_acc_mps2=params.comfort_acc_mps2,
            comfort_dec_mps2=params.comfort_dec_mps2,
            politeness=params.politeness,
            lane_change_min_gain_mps2=params.lane_change_min_gain_mps2,
            max_braking_imposed_mps2=params.max_braking_imposed_mps2,
            lane_change_delay_s=params.lane_change_delay_s,
            lateral_time_constant_s=params.lateral_time_constant_s,
            max_lateral_speed_mps=params.max_lateral_speed_mps,
            cut_in_rate_per_min=cut_in_rate_per_min,
        )


def trait_values(trait: NormalTrait | LogNormalTrait, u: np.ndarray) -> np.ndarray:
    """The monotone map of standard normal copula values to a parameter's values.

    :param trait: the parameter's distribution
    :param u: copula values, standard normal
    :return: ``mean + sd u`` or ``median exp(log_sd u)``, clipped to ``[low, high]``
    """
    if isinstance(trait, NormalTrait):
        values = trait.mean + trait.sd * u
    else:
        values = trait.median * np.exp(trait.log_sd * u)
    return np.clip(values, trait.low, trait.high)


def draw_traits(config: ContinuumConfig, z: np.ndarray, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Every parameter of ``len(z)`` drivers (the copula of the module docstring).

    :param config: the distributions
    :param z: the drivers' latent aggressiveness, standard normal
    :param rng: draws one standard normal vector per parameter, in :meth:`ContinuumConfig.traits` order
    :return: each parameter's values, by name (as in ``traffic.continuum``)
    """
    out: dict[str, np.ndarray] = {}
    for name, trait in config.traits().items():
        noise = rng.standard_normal(len(z))
        rho = trait.corr_z
        out[name] = trait_values(trait, rho * z + math.sqrt(1.0 - rho * rho) * noise)
    return out


def top_share(z: np.ndarray, fraction: float) -> np.ndarray:
    """Which drivers are aggressive: exactly ``round(fraction * len(z))`` of them, those of highest ``z``.

    :param z: latent aggressiveness
    :param fraction: share of aggressive drivers [-]
    :return: boolean mask
    """
    k = int(round(fraction * len(z)))
    mask = np.zeros(len(z), dtype=bool)
    mask[np.argsort(-z, kind="stable")[:k]] = True
    return mask


def profile_of(traits: dict[str, np.ndarray], i: int, lateral_settle_m: float) -> DriverProfile:
    """Driver ``i``'s profile from :func:`draw_traits`' arrays.

    :param traits: the parameters' values by name
    :param i: the driver's index in the arrays
    :param lateral_settle_m: the lateral controller leaves its speed limit this far from the lane centre [m]
    :return: the driver's profile (lateral time constant ``lateral_settle_m / max_lateral_speed_mps``)
    """
    v = {name: float(values[i]) for name, values in traits.items()}
    return DriverProfile(
        desired_speed_mps=v["desired_speed_mps"],
        time_headway_s=v["time_headway_s"],
        min_gap_m=v["min_gap_m"],
        comfort_acc_mps2=v["comfort_acc_mps2"],
        comfort_dec_mps2=v["comfort_dec_mps2"],
        politeness=v["politeness"],
        lane_change_min_gain_mps2=v["lane_change_min_gain_mps2"],
        max_braking_imposed_mps2=v["max_braking_imposed_mps2"],
        lane_change_delay_s=v["lane_change_delay_s"],
        lateral_time_constant_s=lateral_settle_m / v["max_lateral_speed_mps"],
        max_lateral_speed_mps=v["max_lateral_speed_mps"],
        cut_in_rate_per_min=v["cut_in_rate_per_min"],
    )

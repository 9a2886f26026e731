"""Vehicle -> cloud uplink: GNSS fixes with noise, a fixed rate, latency and loss.

Each connected vehicle takes a fix every ``1 / rate_hz`` seconds on its own schedule (a
random phase), so fix times are exact even when the simulation runs at another frequency:
a fix scheduled between two simulation steps is taken at its own time, the vehicle's
position moved back along its velocity from the step's end. Each fix is lost with
probability ``loss_prob``; the others arrive ``max(0, N(latency_mean_s, latency_jitter_s))``
seconds after they were taken. Position, speed and heading all carry measurement noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dt_highway.config import UplinkConfig


@dataclass(frozen=True, slots=True)
class GnssFix:
    """One GNSS fix as the cloud receives it.

    :param vehicle_id: sender's stable id
    :param t_s: time the fix was taken [s] (simulation clock)
    :param x_m: measured position along the road [m]
    :param y_m: measured lateral position [m]
    :param speed_mps: measured speed [m/s]
    :param heading_rad: measured heading (course) [rad]
    :param arrival_s: time the cloud receives it [s]
    """

    vehicle_id: int
    t_s: float
    x_m: float
    y_m: float
    speed_mps: float
    heading_rad: float
    arrival_s: float


@dataclass(frozen=True, slots=True)
class VehicleState:
    """True state of a vehicle at the end of a simulation step (the uplink's input)."""

    vehicle_id: int
    x_m: float
    y_m: float
    vx_mps: float
    vy_mps: float
    speed_mps: float
    heading_rad: float


class Uplink:
    """Turns true vehicle states into the GNSS fixes the cloud receives.

    :param config: uplink configuration (rate, noise, latency, loss)
    :param rng: this component's random generator
    """

    def __init__(self, config: UplinkConfig, rng: np.random.Generator) -> None:
        self.config = config
        self.rng = rng
        self._phase: dict[int, float] = {}

    def forget(self, vehicle_id: int) -> None:
        """Drop a vehicle's schedule (it left the road).

        :param vehicle_id: the vehicle
        """
        self._phase.pop(vehicle_id, None)

    def sample(self, t_prev_s: float, t_now_s: float, states: list[VehicleState]) -> list[GnssFix]:
        """Fixes scheduled in ``(t_prev_s, t_now_s]`` for every given vehicle.

        :param t_prev_s: time of the previous simulation step [s]
        :param t_now_s: time of this simulation step [s]
        :param states: true states at ``t_now_s`` of the connected vehicles
        :return: the fixes that are not lost, each with its arrival time
        """
        cfg = self.config
        period = 1.0 / cfg.rate_hz
        out: list[GnssFix] = []
        for s in states:
            phase = self._phase.get(s.vehicle_id)
            if phase is None:
                phase = self._phase[s.vehicle_id] = float(self.rng.uniform(0.0, period))
            k_first = int(np.floor((t_prev_s - phase) / period)) + 1
            t_fix = phase + k_first * period
            while t_fix <= t_now_s + 1e-12:
                if t_fix > t_prev_s + 1e-12:
                    fix = self._fix(s, t_fix, t_now_s)
                    if fix is not None:
                        out.append(fix)
                t_fix += period
        return out

    def _fix(self, s: VehicleState, t_fix: float, t_now: float) -> GnssFix | None:
        cfg = self.config
        back = t_now - t_fix
        nx, ny, nv, nh = self.rng.normal(0.0, 1.0, size=4)
        lost = self.rng.random() < cfg.loss_prob
        latency = max(0.0, cfg.latency_mean_s + cfg.latency_jitter_s * float(self.rng.normal()))
        if lost:
            return None
        return GnssFix(
            vehicle_id=s.vehicle_id,
            t_s=t_fix,
            x_m=s.x_m - s.vx_mps * back + cfg.noise_sigma_m * nx,
            y_m=s.y_m - s.vy_mps * back + cfg.noise_sigma_m * ny,
            speed_mps=s.speed_mps + cfg.speed_noise_sigma_mps * nv,
            heading_rad=s.heading_rad + cfg.heading_noise_sigma_rad * nh,
            arrival_s=t_fix + latency,
        )

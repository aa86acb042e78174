"""Estimator evaluation on simulated drives: the robustness scenarios and error metrics.

Each scenario drives the two-track plant (the truth) with sensor errors and GPS
faults, and each estimator is designed from a *nominal* parameter set that is
exact or has every cornering stiffness 40 % too high or too low. Manoeuvres begin
after 10 s of straight driving so every filter has converged; errors are taken
from 1 s before the manoeuvre to the end of the run.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from evstab.plants import G, VehicleParams, load_vehicle
from evstab.plants.disturbances import Disturbances, Friction
from evstab.plants.maneuvers import iso3888_1, ramp_steer, sine_lane_change, sine_with_dwell, steer_for_lateral_acceleration
from evstab.plants.sensors import SensorConfig
from ..loop.simulator import simulate

from ..estimation.runner import run_estimator
from ..estimation.spec import NoiseSettings, design_filter

ROBUSTNESS_METHODS = ("dakf", "amrkf", "dakf-paper", "kf", "kf-bias", "lob")

LEAD_IN = 10.0
DEG = np.pi / 180


@dataclass(frozen=True)
class Scenario:
    name: str
    vehicle: str
    log: dict
    window: slice
    stiffness_factor: float


def scaled_stiffness(p: VehicleParams, factor: float) -> VehicleParams:
    return dataclasses.replace(p, cornering_stiffness_front=p.cornering_stiffness_front * factor,
                               cornering_stiffness_rear=p.cornering_stiffness_rear * factor,
                               nominal_cornering_stiffness_front=None, nominal_cornering_stiffness_rear=None)


def _inject_bad_fixes(log: dict, times: tuple[float, float]) -> dict:
    """Fix 1: 3 satellites and course off by 0.1 rad; fix 2: course off by 0.1 rad."""
    log = {k: np.array(v, copy=True) for k, v in log.items()}
    t = log["t"]
    fixes = np.nonzero(np.isfinite(log["gps_course"]))[0]
    for j, tb in enumerate(times):
        k = fixes[np.argmin(np.abs(t[fixes] - tb))]
        log["gps_course"][k] += 0.1
        if j == 0:
            log["gps_sats"][k] = 3
    return log


def robustness_scenarios(seed: int = 0, quick: bool = False) -> list[tuple[str, str, dict, slice]]:
    """The four drives of the robustness table: (name, vehicle, log columns, error window)."""
    sensors = SensorConfig(gyro_bias=0.003, gyro_scale_error=0.01)
    out = []
    compact = load_vehicle("compact-ev")
    micro = load_vehicle("micro-ev")
    a = steer_for_lateral_acceleration(compact, 80 / 3.6, 0.3 * G)
    drives = [
        ("sine-with-dwell 80 km/h (3.5 A)", compact, sine_with_dwell(80 / 3.6, 3.5 * a, start=LEAD_IN), 1.0, sensors),
        ("ramp steer 60 km/h", compact,
         ramp_steer(60 / 3.6, 2 * steer_for_lateral_acceleration(compact, 60 / 3.6, 0.3 * G) / 10.0,
                    start=LEAD_IN, duration=LEAD_IN + 10.0), 1.0, sensors),
        ("ISO 3888-1 60 km/h mu 0.5", compact, iso3888_1(60 / 3.6, compact.width, lead_in=LEAD_IN * 60 / 3.6),
         0.5, sensors),
        ("lane change 25 km/h, 2 s outage, 2 bad fixes", micro,
         sine_lane_change(25 / 3.6, 3 * DEG, start=LEAD_IN, period=4.0, duration=LEAD_IN + 8.0), 1.0,
         dataclasses.replace(sensors, gps_outages=((LEAD_IN + 1.0, LEAD_IN + 3.0),))),
    ]
    if quick:
        drives = drives[:1] + drives[-1:]
    for name, p, man, mu, sens in drives:
        r = simulate(p, "two-track", man, disturbances=Disturbances(friction=Friction(mu=mu)), sensors=sens, seed=seed)
        log = r.log_columns()
        if "bad fixes" in name:
            log = _inject_bad_fixes(log, (LEAD_IN + 4.0, LEAD_IN + 5.4))
        start = int((LEAD_IN - 1.0) / r.meta["dt"])
        out.append((name, p.name, log, slice(start, None)))
    return out


def beta_errors(method: str, vehicle: str, log: dict, window: slice, stiffness_factor: float,
                noise: NoiseSettings | None = None) -> tuple[float, float]:
    """RMS and max |beta error| [deg] of ``method`` designed with scaled nominal stiffness."""
    p = scaled_stiffness(load_vehicle(vehicle), stiffness_factor)
    est = run_estimator(design_filter(method, p, noise, nominal=False), log)
    err = (est["beta"] - log["beta_true"])[window]
    return float(np.degrees(np.sqrt(np.mean(err**2)))), float(np.degrees(np.abs(err).max()))


def robustness_table(methods=ROBUSTNESS_METHODS, seed: int = 0, quick: bool = False, noise: NoiseSettings | None = None):
    """Rows: (scenario, nominal stiffness, method, beta RMS deg, beta max deg)."""
    rows = []
    for name, vehicle, log, window in robustness_scenarios(seed, quick):
        for label, factor in (("exact", 1.0), ("+40 %", 1.4), ("-40 %", 0.6)):
            for m in methods:
                rms, mx = beta_errors(m, vehicle, log, window, factor, noise)
                rows.append({"scenario": name, "nominal_stiffness": label, "method": m,
                             "beta_rms_deg": rms, "beta_max_deg": mx})
    return rows

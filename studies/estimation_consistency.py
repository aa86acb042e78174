"""Is the default filter's noise model consistent on evstab's own logs?

Every bundled vehicle on the two-track plant, three 20 s drives at 60 km/h with 5 s of straight
driving first (a sine lane change, a step steer and a ramp steer, the steer scaled to 3 m/s^2 of
steady lateral acceleration: a lane change's amplitude, the step's hold, the ramp reaching 1.5x at
the end), two seeds each, the sensor model's defaults with a 2 mrad/s gyro bias; ``dakf`` from the
vehicle's own nominal model. Per run, the residual check of ``evstab estimate``
(:func:`toolkit.estimation.diagnostics.course_report`): the mean normalised innovation squared of
the course fixes used after the 5 s warm-up, against its 95 % chi-square interval, and the sideslip
error. Writes ``consistency.csv`` and ``consistency.md`` (the docs' table).

Run: ``python -m evstab.studies.estimation_consistency OUT_DIR [--quick]`` (quick: compact-ev only).
"""

from __future__ import annotations

import numpy as np

from evstab.plants import bundled_vehicles, load_vehicle
from evstab.plants.maneuvers import ramp_steer, sine_lane_change, steer_for_lateral_acceleration, step_steer
from evstab.plants.sensors import SensorConfig
from evstab.studies._common import cli, out_dir, write_markdown, write_table
from evstab.toolkit.estimation import design_filter, run_estimator
from evstab.toolkit.estimation.diagnostics import nis_consistency, used_residuals
from evstab.toolkit.loop.simulator import simulate

SPEED = 60 / 3.6
AY = 3.0
"""[m/s^2] the steady lateral acceleration the steer amplitudes are scaled to."""
SEEDS = (1, 2)


def drives(p):
    d0 = steer_for_lateral_acceleration(p, SPEED, AY)
    return {"lane change": sine_lane_change(SPEED, d0, start=5.0, duration=20.0),
            "step steer": step_steer(SPEED, d0, start=5.0, duration=20.0),
            "ramp steer": ramp_steer(SPEED, d0 / 10.0, start=5.0, duration=20.0)}


def run(vehicle: str, method: str = "dakf") -> list[dict]:
    """The rows of one vehicle: every drive and seed."""
    p = load_vehicle(vehicle)
    d = design_filter(method, p)
    rows = []
    for name, man in drives(p).items():
        for seed in SEEDS:
            log = simulate(p, "two-track", man, sensors=SensorConfig(gyro_bias=0.002), seed=seed).log_columns()
            est = run_estimator(d, log)
            r = used_residuals(est.columns, est.t)
            c = nis_consistency(r[np.isfinite(r)] ** 2)
            err = np.degrees(est["beta"] - log["beta_true"])[log["t"] >= 1.0]
            rows.append({"vehicle": vehicle, "drive": name, "seed": seed, "fixes": c.n, "mean_nis": c.mean,
                         "low": c.low, "high": c.high, "inside": c.consistent,
                         "beta_rms_deg": float(np.sqrt(np.mean(err ** 2))), "beta_max_deg": float(np.abs(err).max())})
    return rows


def main(out, quick: bool = False) -> list[dict]:
    out = out_dir(out)
    vehicles = ["compact-ev"] if quick else sorted(bundled_vehicles())
    rows = [r for v in vehicles for r in run(v)]
    write_table(rows, out / "consistency.csv")
    table = [[r["vehicle"], r["drive"], r["seed"], r["fixes"], f"{r['mean_nis']:.2f}",
              f"[{r['low']:.2f}, {r['high']:.2f}]", "inside" if r["inside"] else "OUTSIDE",
              f"{r['beta_rms_deg']:.3f} / {r['beta_max_deg']:.3f}"] for r in rows]
    write_markdown(out / "consistency.md", ["vehicle", "drive", "seed", "fixes", "mean NIS", "95 % interval",
                                            "verdict", "sideslip error RMS / max [deg]"], table)
    return rows


if __name__ == "__main__":
    cli(main)

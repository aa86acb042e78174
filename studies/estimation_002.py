"""Seed 002: the dual-antenna estimator with road bank, tire slip angles and cornering stiffness.

compact-ev on the two-track plant, two 180-degree turns (57.6 km/h, radius 50 m, 300 m
lead-in, about 5 m/s^2) on a flat road and on a road with a 5 deg side slope (right side
up: banked into the left turns), default sensors plus the dual antenna's heading (0.1 deg)
and roll (0.3 deg). Per road and filter: sideslip error RMS / max from the first turn on;
for ``dual-antenna`` also the total-roll error, the bank estimate (total roll less the roll
model's body roll, 002 eq. 7) and the front/rear slip-angle errors. Then the cornering
stiffness from each filter's sideslip (`toolkit.estimation.identify`) with the lateral
force from ``v r`` alone, ``v r`` plus the estimated bank's gravity, and the accelerometer.

Writes ``dual_antenna.csv/.md`` and ``stiffness_bank.csv/.md``.

Run: ``python -m evstab.studies.estimation_002 OUT_DIR``
"""

from __future__ import annotations

import numpy as np

from evstab.plants import load_vehicle
from evstab.plants.disturbances import Disturbances
from evstab.plants.maneuvers import two_half_turns
from evstab.plants.sensors import SensorConfig
from evstab.studies._common import cli, out_dir, write_table
from evstab.toolkit.estimation import design_filter, run_estimator
from evstab.toolkit.estimation.dual_antenna import bank_estimate
from evstab.toolkit.estimation.identify import cornering_stiffness
from evstab.toolkit.loop.simulator import simulate

SPEED, RADIUS, LEAD_IN = 16.0, 50.0, 300.0
BANKS_DEG = (0.0, -5.0)


def road(p, bank_deg: float, seed: int = 1):
    man = two_half_turns(SPEED, RADIUS, lead_in=LEAD_IN)
    return simulate(p, "two-track", man, disturbances=Disturbances(bank=np.radians(bank_deg)),
                    sensors=SensorConfig(), seed=seed).log_columns()


def slip_angles(p, beta, r, v, steer):
    v = np.maximum(v, 1.0)
    return steer - beta - p.lf * r / v, -beta + p.lr * r / v


def main(out, quick: bool = False) -> list[dict]:
    out = out_dir(out)
    p = load_vehicle("compact-ev")
    rows, st_rows = [], []
    for bank in BANKS_DEG:
        c = road(p, bank)
        m = c["t"] >= LEAD_IN / SPEED - 1.0
        fixes = np.flatnonzero(np.isfinite(c["gps_course"]))
        af_t, ar_t = slip_angles(p, c["beta_true"], c["yaw_rate_true"], c["vx_true"], c["steer_true"])
        for method in ("dual-antenna", "kkf", "dakf"):
            e = run_estimator(design_filter(method, p), c)
            be = np.degrees(e["beta"] - c["beta_true"])[m]
            row = {"bank_deg": bank, "filter": method, "beta_err_rms_deg": float(np.sqrt(np.mean(be ** 2))),
                   "beta_err_max_deg": float(np.abs(be).max())}
            b_est = None
            if method == "dual-antenna":
                rt = np.degrees(e["roll"] - c["roll_true"] - np.radians(bank))[m]
                b_est = bank_estimate(p, e["roll"], c["speed"], e["yaw_rate"])
                af, ar = slip_angles(p, e["beta"], e["yaw_rate"], c["speed"], c["steer"])
                row.update({"total_roll_err_rms_deg": float(np.sqrt(np.mean(rt ** 2))),
                            "bank_estimate_mean_deg": float(np.degrees(np.mean(b_est[m]))),
                            "slip_front_err_rms_deg": float(np.degrees(np.sqrt(np.mean((af - af_t)[m] ** 2)))),
                            "slip_rear_err_rms_deg": float(np.degrees(np.sqrt(np.mean((ar - ar_t)[m] ** 2))))})
            else:
                row.update({k: float("nan") for k in ("total_roll_err_rms_deg", "bank_estimate_mean_deg",
                                                      "slip_front_err_rms_deg", "slip_rear_err_rms_deg")})
            rows.append(row)
            forces = [("v r", {}), ("accelerometer", {"ay": c["ay"], "accel": True})]
            if b_est is not None:
                forces.insert(1, ("v r + estimated bank", {"bank": b_est}))
            for name, kw in forces:
                s = cornering_stiffness(p, c["t"], c["speed"], c["steer"], c["yaw_rate"], e["beta"], rows=fixes,
                                        yaw_moment=c.get("yaw_moment"), **kw)
                st_rows.append({"bank_deg": bank, "sideslip_from": method, "lateral_force_from": name,
                                "front_err_pct": 100 * (s.front / p.cornering_stiffness_front - 1),
                                "rear_err_pct": 100 * (s.rear / p.cornering_stiffness_rear - 1)})
    write_table(rows, out / "dual_antenna.csv", out / "dual_antenna.md")
    write_table(st_rows, out / "stiffness_bank.csv", out / "stiffness_bank.md", floatfmt="{:.1f}")
    return rows + st_rows


if __name__ == "__main__":
    cli(main)

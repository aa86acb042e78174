"""The nominal files of the CommonRoad multi-body cars: the cornering stiffness fitted to each car.

For each parameter set, the output-error fit of ``evstab derive-nominal`` (:mod:`toolkit.design.nominal`:
the linear bicycle's yaw rate and lateral acceleration against the multi-body car's in small-steer
runs at 40, 60, 80, 100 km/h), beside the tyre's own slope times static load, the fit's
residuals and the understeer gradient of the fitted model. Writes ``nominal_fits.csv`` and
``nominal_fits.md`` (the docs' table). ``--quick``: set 1 at 60 km/h only.

Run: ``python -m evstab.studies.nominal_fits OUT_DIR [--quick]``
"""

from __future__ import annotations

import numpy as np

from evstab.plants import commonroad_mb
from evstab.studies._common import cli, out_dir, write_markdown, write_table
from evstab.toolkit.design.nominal import FIT_SPEEDS_KMH, geometry, identify_cornering_stiffness, small_steer_runs


def main(out, quick: bool = False) -> list[dict]:
    out = out_dir(out)
    rows = []
    for n in (1,) if quick else tuple(commonroad_mb.SETS):
        fit = identify_cornering_stiffness(n, small_steer_runs(n, (60.0,) if quick else FIT_SPEEDS_KMH))
        p = geometry(n, fit.front, fit.rear)
        rows.append({"file": f"commonroad-{n}", "front_N_per_rad": fit.front, "rear_N_per_rad": fit.rear,
                     "tire_slope_front_N_per_rad": fit.tire_slope_front, "tire_slope_rear_N_per_rad": fit.tire_slope_rear,
                     "yaw_rate_residual_pct": 100 * fit.yaw_rate_rms_rel, "ay_residual_pct": 100 * fit.ay_rms_rel,
                     "beta_error_pct": 100 * fit.beta_rms_rel,
                     "understeer_gradient_deg_per_mps2": float(np.degrees(p.understeer_gradient))})
    write_table(rows, out / "nominal_fits.csv")
    write_markdown(out / "nominal_fits.md",
                   ["file", "C_f / C_r [N/rad per tyre]", "tyre slope x static load", "fit residual yaw rate / ay",
                    "sideslip (not fitted)", "K_us [deg/(m/s^2)]"],
                   [[r["file"], f"{r['front_N_per_rad']:.0f} / {r['rear_N_per_rad']:.0f}",
                     f"{r['tire_slope_front_N_per_rad']:.0f} / {r['tire_slope_rear_N_per_rad']:.0f}",
                     f"{r['yaw_rate_residual_pct']:.1f} % / {r['ay_residual_pct']:.1f} %", f"{r['beta_error_pct']:.0f} %",
                     f"{r['understeer_gradient_deg_per_mps2']:.3f}"] for r in rows])
    return rows


if __name__ == "__main__":
    cli(main)

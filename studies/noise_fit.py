"""The noise fit of ``evstab estimate --tune`` on a log whose sensors are known.

compact-ev on the two-track plant, 60 s of gentle lane changes (1 deg road-wheel amplitude, 4 s
period) at 60 km/h, the gyro noise 0.006 rad/s and the GPS velocity noise 0.08 m/s per axis (the
filter's defaults are 0.004 and 0.056), gyro bias 2 mrad/s; ``dakf`` from the exact nominal model
starts at its defaults and :func:`toolkit.estimation.noise_fit.fit_noise` fits the sensor noises
and the process noise. Writes ``noise_fit.csv`` and ``noise_fit.md`` (the docs' table). ``--quick``
is the same run (it takes seconds).

Run: ``python -m evstab.studies.noise_fit OUT_DIR [--quick]``
"""

from __future__ import annotations

import time

import numpy as np

from evstab.plants import load_vehicle
from evstab.plants.maneuvers import sine_lane_change
from evstab.plants.sensors import SensorConfig
from evstab.studies._common import cli, out_dir, write_markdown, write_table
from evstab.toolkit.estimation import design_filter
from evstab.toolkit.estimation.noise_fit import fit_noise
from evstab.toolkit.loop.simulator import simulate

TRUE = {"gyro_std": 0.006, "gps_velocity_std": 0.08}
"""The log's sensor noises (the filter's names for them)."""


def main(out, quick: bool = False) -> list[dict]:
    out = out_dir(out)
    p = load_vehicle("compact-ev")
    man = sine_lane_change(60 / 3.6, np.radians(1.0), start=2.0, period=4.0, duration=60.0)
    sens = SensorConfig(gyro_noise=TRUE["gyro_std"], gps_velocity_noise=TRUE["gps_velocity_std"], gyro_bias=0.002)
    log = simulate(p, "two-track", man, sensors=sens, seed=3).log_columns()
    d = design_filter("dakf", p)
    t0 = time.perf_counter()
    fit = fit_noise(d, log)
    wall = time.perf_counter() - t0
    rows = [{"parameter": k, "log": TRUE.get(k, float("nan")), "start": a, "fitted": b,
             "error_pct": 100 * (b / TRUE[k] - 1) if k in TRUE else float("nan"), "at_bound": k in fit.at_bound}
            for k, a, b in zip(fit.parameters, fit.start, fit.values)]
    write_table(rows, out / "noise_fit.csv")
    lo, hi = fit.nis_interval
    table = [[f"`{r['parameter']}`", "-" if np.isnan(r["log"]) else f"{r['log']:.4g}", f"{r['start']:.4g}",
              f"{r['fitted']:.4g}" + (" (bound)" if r["at_bound"] else ""),
              "-" if np.isnan(r["error_pct"]) else f"{r['error_pct']:+.1f} %"] for r in rows]
    table.append(["mean NIS of the course fixes", "1", f"{fit.nis_start:.3f}", f"{fit.nis:.3f}",
                  f"95 % interval [{lo:.3f}, {hi:.3f}]"])
    table.append(["-2 log L per innovation", "", f"{fit.nll_start:.4f}", f"{fit.nll:.4f}",
                  f"{fit.evaluations} filter runs, {wall:.1f} s"])
    write_markdown(out / "noise_fit.md", ["", "the log's sensors", "start (defaults)", "fitted", "fitted vs log"],
                   table)
    return rows


if __name__ == "__main__":
    cli(main)

"""Seed 003 Fig. 6: sideslip estimation on the micro EV, 25 km/h sinusoidal lane change.

True tire stiffness 7000 N/rad, estimator nominal 10000 N/rad; lateral wind 4-8 s;
GPS lost 4-6 s; 1 ms IMU, 200 ms GPS. The estimators run from 10 s of straight
driving before the figure's time zero (as they would in a car); errors are taken
over the figure's 10 s. Writes ``fig6.csv``/``fig6.md`` (RMS and max sideslip
error per method) and ``fig6.png``.

Run: ``python -m evstab.studies.estimation_fig6 OUT_DIR [--quick]``
"""

from __future__ import annotations

import numpy as np

from evstab.plants import load_vehicle
from evstab.plants.disturbances import Disturbances, default_wind
from evstab.plants.maneuvers import sine_lane_change
from evstab.plants.sensors import SensorConfig
from evstab.studies._common import cli, out_dir, save_figure, write_table
from evstab.toolkit.estimation import design_filter, run_estimator
from evstab.toolkit.loop.simulator import simulate

METHODS = ("lob", "kf", "dakf-paper", "dakf", "amrkf")


def main(out, quick: bool = False) -> list[dict]:
    out = out_dir(out)
    p = load_vehicle("micro-ev")
    lead = 3.0 if quick else 10.0
    man = sine_lane_change(25 / 3.6, np.radians(3.0), start=lead + 3.0, period=4.0,
                           duration=lead + (8.0 if quick else 10.0))
    r = simulate(p, "two-track", man, disturbances=Disturbances(wind=default_wind(p, lead + 4.0, lead + 8.0)),
                 sensors=SensorConfig(gps_outages=((lead + 4.0, lead + 6.0),)), seed=0)
    log = r.log_columns()
    t, beta = log["t"] - lead, log["beta_true"]
    window = t >= 0.0
    rows, traces = [], {}
    for m in METHODS:
        est = run_estimator(design_filter(m, p), log)  # nominal: 10000 N/rad per tire
        err = np.degrees(est["beta"] - beta)[window]
        rows.append({"method": m, "beta_rms_deg": float(np.sqrt(np.mean(err**2))),
                     "beta_max_deg": float(np.abs(err).max())})
        traces[m] = est["beta"]
    write_table(rows, out / "fig6.csv", out / "fig6.md")
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(2, 1, figsize=(9, 7), sharex=True, constrained_layout=True)
    keep = window
    t, beta = t[keep], beta[keep]
    log = {k: v[keep] for k, v in log.items()}
    traces = {m: v[keep] for m, v in traces.items()}
    ax[0].plot(t, np.degrees(beta), "k", lw=2, label="true")
    for m in METHODS:
        ax[0].plot(t, np.degrees(traces[m]), lw=1, label=m)
    ax[0].set_ylabel("sideslip [deg]")
    fix = np.isfinite(log["gps_course"])
    ax[1].plot(t, np.degrees(log["yaw_true"] + beta), "k", label="true course")
    ax[1].plot(t[fix], np.degrees(log["gps_course"][fix]), ".", label="GPS course (5 Hz)")
    ax[1].set_ylabel("course [deg]")
    ax[1].set_xlabel("t [s]")
    for a in ax:
        a.axvspan(4, 6, color="0.9", label="GPS lost")
        a.grid(alpha=0.3)
        a.legend(fontsize=8, ncol=3)
    fig.suptitle("micro EV, 25 km/h lane change, Cf = Cr = 7000 (nominal 10000) N/rad, wind 4-8 s")
    save_figure(fig, out / "fig6.png")
    return rows


if __name__ == "__main__":
    cli(main)

"""Seed 004 Fig. 9b: inter-sample sideslip error, conventional multi-rate KF vs the advanced one.

The filters use the same disturbance-accommodating model (evstab's ``dakf``); ``amrkf (paper)``
adds seed 004's inter-sample residual prediction as printed (eq. 28-29, unweighted:
``NoiseSettings.residual_corr_fixes = 0``), ``amrkf`` evstab's, weighted by the fix innovations'
lag-one correlation. Micro EV, 25 km/h lane change, model error as in seed 003. Writes
``intersample.csv`` (RMS sideslip error by time since the last GPS fix) and ``intersample.png``.

Run: ``python -m evstab.studies.estimation_intersample OUT_DIR [--quick]``
"""

from __future__ import annotations

import dataclasses

import numpy as np

from evstab.plants import load_vehicle
from evstab.plants.maneuvers import sine_lane_change
from evstab.studies._common import cli, out_dir, save_figure, write_table
from evstab.toolkit.estimation import design_filter, run_estimator
from evstab.toolkit.loop.simulator import simulate


def main(out, quick: bool = False) -> list[dict]:
    out = out_dir(out)
    p = load_vehicle("micro-ev")
    man = sine_lane_change(25 / 3.6, np.radians(4.0), start=2.0, period=3.0, duration=6.0 if quick else 12.0)
    log = simulate(p, "two-track", man, seed=1).log_columns()
    t = log["t"]
    fix = np.isfinite(log["gps_course"])
    since = np.zeros(len(t))
    last = -np.inf
    for k in range(len(t)):
        if fix[k]:
            last = t[k]
        since[k] = t[k] - last
    amr = design_filter("amrkf", p)
    designs = {"dakf": design_filter("dakf", p), "amrkf": amr,
               "amrkf_paper": dataclasses.replace(amr, noise=dataclasses.replace(amr.noise, residual_corr_fixes=0.0))}
    err = {m: np.degrees(run_estimator(d, log)["beta"] - log["beta_true"]) for m, d in designs.items()}
    rows = []
    use = t >= 1.0
    for lo in np.arange(0.0, 0.2, 0.04):
        sel = use & (since >= lo) & (since < lo + 0.04)
        rows.append({"ms_since_fix": f"{lo * 1000:.0f}-{(lo + 0.04) * 1000:.0f}",
                     "conventional_rms_deg": float(np.sqrt(np.mean(err["dakf"][sel] ** 2))),
                     "amrkf_paper_rms_deg": float(np.sqrt(np.mean(err["amrkf_paper"][sel] ** 2))),
                     "amrkf_rms_deg": float(np.sqrt(np.mean(err["amrkf"][sel] ** 2)))})
    write_table(rows, out / "intersample.csv", out / "intersample.md")
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(9, 4), constrained_layout=True)
    ax.plot(t, err["dakf"], label="conventional multi-rate KF (dakf)")
    ax.plot(t, err["amrkf_paper"], label="advanced multi-rate KF, seed 004 eq. 28-29 (amrkf, unweighted)")
    ax.plot(t, err["amrkf"], label="amrkf, correlation-weighted (evstab's default)")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("sideslip error [deg]")
    ax.grid(alpha=0.3)
    ax.legend()
    save_figure(fig, out / "intersample.png")
    return rows


if __name__ == "__main__":
    cli(main)

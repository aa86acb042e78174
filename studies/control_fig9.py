"""Seed 003 Fig. 9: cornering test with and without the stability controller.

Steer-by-wire with a pre-designed steering command at about 20 km/h (seed 003
sec. VII-B): the road-wheel angle ramps to 8 deg over 1 s, holds 3 s and ramps
back over 1 s (evstab's reading of the paper's programmed cornering command, which
it does not tabulate). Micro EV on the two-track plant, true 7000 vs nominal
10000 N/rad per tire. Writes ``fig9.csv``/``fig9.md`` (RMS tracking errors
against the reference model, with and without control) and ``fig9.png``.

Run: ``python -m evstab.studies.control_fig9 OUT_DIR [--quick]``
"""

from __future__ import annotations

import numpy as np

from evstab.plants import load_vehicle
from evstab.plants.maneuvers import Maneuver
from evstab.studies._common import cli, out_dir, save_figure, write_table
from evstab.studies._common import seed_003_design
from evstab.toolkit.loop.simulator import simulate


def cornering(speed: float, peak: float, start: float = 1.0, ramp: float = 1.0, hold: float = 3.0,
              after: float = 2.0) -> Maneuver:
    def steer(t):
        t = np.asarray(t, float)
        up = np.clip((t - start) / ramp, 0.0, 1.0)
        down = np.clip((t - start - ramp - hold) / ramp, 0.0, 1.0)
        return peak * (up - down)
    return Maneuver("cornering", speed, start + 2 * ramp + hold + after, steer=steer)


def main(out, quick: bool = False) -> list[dict]:
    out = out_dir(out)
    p = load_vehicle("micro-ev")
    man = cornering(20 / 3.6, np.radians(8.0), hold=1.5 if quick else 3.0)
    rows, runs = [], {}
    for ctl in ("none", "two-dof"):
        r = simulate(p, "two-track", man, controller=ctl, design=seed_003_design(p))
        c = r.commands
        sel = r.t >= 1.0
        rows.append({"controller": ctl,
                     "beta_rms_err_deg": float(np.degrees(np.sqrt(np.mean((r.truth["beta"] - c["beta_ref"])[sel] ** 2)))),
                     "yaw_rate_rms_err_deg_s": float(np.degrees(np.sqrt(np.mean(
                         (r.truth["yaw_rate"] - c["yaw_rate_ref"])[sel] ** 2))))})
        runs[ctl] = r
    write_table(rows, out / "fig9.csv", out / "fig9.md")
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(2, 2, figsize=(11, 7), sharex=True, constrained_layout=True)
    for j, ctl in enumerate(("none", "two-dof")):
        r = runs[ctl]
        ax[0, j].plot(r.t, np.degrees(r.truth["beta"]), label="sideslip")
        ax[0, j].plot(r.t, np.degrees(r.commands["beta_ref"]), "--", label="reference")
        ax[1, j].plot(r.t, np.degrees(r.truth["yaw_rate"]), label="yaw rate")
        ax[1, j].plot(r.t, np.degrees(r.commands["yaw_rate_ref"]), "--", label="reference")
        ax[0, j].set_title("without control" if ctl == "none" else "with 2-DOF control (dakf in the loop)")
        ax[0, j].set_ylabel("sideslip [deg]")
        ax[1, j].set_ylabel("yaw rate [deg/s]")
        ax[1, j].set_xlabel("t [s]")
        for a in ax[:, j]:
            a.grid(alpha=0.3)
            a.legend(fontsize=8)
    save_figure(fig, out / "fig9.png")
    return rows


if __name__ == "__main__":
    cli(main)

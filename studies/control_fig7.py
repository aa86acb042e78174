"""Seed 003 Fig. 7: step steer with and without the stability controller.

Micro EV on the two-track plant, 25 km/h, 5 deg road-wheel step at 1 s; true tire
stiffness 7000 N/rad, controller and estimator nominal 10000 N/rad; lateral wind
4-8 s. Controllers: none, yaw-rate PI, the 2-DOF controller with the default
estimator, and the 2-DOF controller fed with true states. Writes ``fig7.csv``/
``fig7.md`` (RMS tracking errors of sideslip and yaw rate against the reference
model, peak commands) and ``fig7.png``.

Run: ``python -m evstab.studies.control_fig7 OUT_DIR [--quick]``
"""

from __future__ import annotations

import numpy as np

from evstab.plants import load_vehicle
from evstab.plants.disturbances import Disturbances, default_wind
from evstab.plants.maneuvers import step_steer
from evstab.studies._common import cli, out_dir, save_figure, write_markdown, write_table
from evstab.studies._common import seed_003_design
from evstab.toolkit.loop.simulator import simulate

CONTROLLERS = ("none", "yaw-pi", "two-dof", "two-dof-true")


def main(out, quick: bool = False) -> list[dict]:
    out = out_dir(out)
    p = load_vehicle("micro-ev")
    man = step_steer(25 / 3.6, np.radians(5.0), start=1.0, duration=5.0 if quick else 10.0)
    rows: list[dict] = []
    runs: dict = {}
    for ctl in CONTROLLERS:
        r = simulate(p, "two-track", man, controller=ctl, design=seed_003_design(p), disturbances=Disturbances(wind=default_wind(p)))
        c = r.commands
        sel = r.t >= 1.0
        eb = np.degrees(r.truth["beta"] - c["beta_ref"])[sel]
        er = np.degrees(r.truth["yaw_rate"] - c["yaw_rate_ref"])[sel]
        rows.append({"controller": ctl, "beta_rms_err_deg": float(np.sqrt(np.mean(eb**2))),
                     "yaw_rate_rms_err_deg_s": float(np.sqrt(np.mean(er**2))),
                     "steer_max_deg": float(np.degrees(np.abs(c["steer"]).max())),
                     "yaw_moment_max_Nm": float(np.abs(c["yaw_moment"]).max())})
        runs[ctl] = r
    write_table(rows, out / "fig7.csv")
    labels = {"none": "none", "yaw-pi": "yaw-rate PI", "two-dof": "2-DOF with `dakf`", "two-dof-true": "2-DOF with true states"}
    write_markdown(out / "fig7.md", ["controller", "sideslip [deg]", "yaw rate [deg/s]", "peak steer [deg]",
                                     "peak yaw moment [N m]"],
                   [[labels[r["controller"]], f"{r['beta_rms_err_deg']:.3f}", f"{r['yaw_rate_rms_err_deg_s']:.3f}",
                     f"{r['steer_max_deg']:.2f}", f"{r['yaw_moment_max_Nm']:.0f}"] for r in rows])
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(2, 2, figsize=(11, 7), constrained_layout=True)
    ref = runs["two-dof"].commands
    t = runs["two-dof"].t
    ax[0, 0].plot(t, np.degrees(ref["beta_ref"]), "k--", label="reference")
    ax[0, 1].plot(t, np.degrees(ref["yaw_rate_ref"]), "k--", label="reference")
    for ctl, r in runs.items():
        ax[0, 0].plot(r.t, np.degrees(r.truth["beta"]), label=ctl)
        ax[0, 1].plot(r.t, np.degrees(r.truth["yaw_rate"]), label=ctl)
        ax[1, 0].plot(r.t, np.degrees(r.commands["steer"]), label=ctl)
        ax[1, 1].plot(r.t, r.commands["yaw_moment"], label=ctl)
    for a, lab in zip(ax.flat, ("sideslip [deg]", "yaw rate [deg/s]", "front steer [deg]", "yaw moment [N m]")):
        a.set_ylabel(lab)
        a.set_xlabel("t [s]")
        a.grid(alpha=0.3)
        a.legend(fontsize=8)
    fig.suptitle("micro EV, 25 km/h step steer, Cf = Cr = 7000 (nominal 10000) N/rad, wind 4-8 s")
    save_figure(fig, out / "fig7.png")
    return rows


if __name__ == "__main__":
    cli(main)

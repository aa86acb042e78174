"""Figures of a simulation run (matplotlib, Agg backend, written atomically)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..logs.drivelog import atomic_write


def plot_run(result, path: str | Path, maneuver=None) -> dict:
    """Six panels: steer, yaw rate, sideslip, lateral acceleration, speed, path (degrees at the edges);
    with a controller in the loop also the ECU's estimates and references, its steer command beside the
    driver's, and a seventh and eighth panel: its yaw-moment command and the law's authority (0 off,
    1 acting) with the friction estimate. Returns each panel's y label and its lines' labels."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t, tr, me, cm = result.t, result.truth, result.measurements, result.commands
    ecu = "steer_driver" in cm
    fig, ax = plt.subplots(4 if ecu else 3, 2, figsize=(11, 12 if ecu else 9), constrained_layout=True)
    if ecu:
        ax[0, 0].plot(t, np.degrees(cm["steer_driver"]), color="0.5", label="driver")
        ax[0, 0].plot(t, np.degrees(cm["steer_cmd"]), label="ECU command")
    else:
        ax[0, 0].plot(t, np.degrees(cm["steer"]), label="steer command")
    ax[0, 0].set_ylabel("front road-wheel angle [deg]")
    ax[0, 1].plot(t, np.degrees(me["yaw_rate"]), color="0.7", lw=0.5, label="gyro")
    ax[0, 1].plot(t, np.degrees(tr["yaw_rate"]), label="true")
    if ecu:
        ax[0, 1].plot(t, np.degrees(cm["yaw_rate_est"]), "--", label="ECU estimate")
        ax[0, 1].plot(t, np.degrees(cm["yaw_rate_ref"]), ":", label="ECU reference")
    ax[0, 1].set_ylabel("yaw rate [deg/s]")
    ax[1, 0].plot(t, np.degrees(tr["beta"]), label="true sideslip at CG")
    if ecu:
        ax[1, 0].plot(t, np.degrees(cm["beta_est"]), "--", label="ECU estimate")
        ax[1, 0].plot(t, np.degrees(cm["beta_ref"]), ":", label="ECU reference")
    ax[1, 0].set_ylabel("sideslip [deg]")
    ax[1, 1].plot(t, me["ay"], color="0.7", lw=0.5, label="accelerometer")
    ax[1, 1].plot(t, tr["ay"], label="true (road plane)")
    ax[1, 1].set_ylabel("lateral acceleration [m/s^2]")
    ax[2, 0].plot(t, tr["vx"] * 3.6, label="vx true")
    fix = np.isfinite(me["gps_speed"])
    ax[2, 0].plot(t[fix], me["gps_speed"][fix] * 3.6, ".", ms=3, label="GPS ground speed")
    ax[2, 0].set_ylabel("speed [km/h]")
    ax[2, 1].plot(tr["x"], tr["y"], label="CG path")
    if maneuver is not None and maneuver.path is not None:
        ax[2, 1].plot(maneuver.path.x, maneuver.path.y, "--", lw=0.8, label="reference path")
    if maneuver is not None and maneuver.cones is not None:
        ax[2, 1].plot(maneuver.cones[:, 0], maneuver.cones[:, 1], "^", color="tab:orange", ms=5, label="cones")
    ax[2, 1].set_xlabel("x [m]")
    ax[2, 1].set_ylabel("y [m]")
    ax[2, 1].set_aspect("equal", adjustable="datalim")
    if ecu:
        ax[3, 0].plot(t, cm["yaw_moment_cmd"], label="ECU command")
        ax[3, 0].plot(t, cm["yaw_moment"], "--", label="applied (actuators)")
        ax[3, 0].set_ylabel("yaw moment [N m]")
        ax[3, 1].plot(t, cm["active"], label="law's authority (0 off, 1 acting)")
        ax[3, 1].plot(t, cm["mu_est"], label="friction estimate")
        ax[3, 1].set_ylabel("authority, friction [-]")
    for a in ax.flat:
        if a is not ax[2, 1]:
            a.set_xlabel("t [s]")
        a.grid(True, alpha=0.3)
        a.legend(fontsize=8)
    m = result.meta
    fig.suptitle(f"{m['vehicle']} - {m['plant']} - {m['maneuver']} at {m['speed_mps'] * 3.6:.0f} km/h (seed {m['seed']})")
    atomic_write(path, lambda fh: fig.savefig(fh, format="png", dpi=110), mode="wb")
    panels = {a.get_ylabel(): [ln.get_label() for ln in a.get_lines()] for a in ax.flat}
    plt.close(fig)
    return panels

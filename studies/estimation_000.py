"""Seed 000: two-stage Kalman filter on the double lane change, lever arm, GPS time synchronisation.

1. **Double lane change** (000 geometry, `plants.maneuvers.dlc_000`, 600 m lead-in so every
   filter has converged) at 120 km/h on mu 0.9 and 0.4, sedan-000 (000 Table 1) on the
   two-track plant, default sensors (dual-antenna heading 0.1 deg, 5 Hz GPS). Sideslip
   error RMS / max over the manoeuvre for ``two-stage`` (000), ``dakf``, ``mbkf``, ``kkf``;
   and the two-stage sideslip moved to the rear axle by the lever arm (000 eq. 28-29)
   against the true rear-axle sideslip.
2. **Time synchronisation** (`toolkit.logs.timesync`): the GPS course and ground speed of the
   mu 0.9 run, sampled at their true instants, stamped with a 100 ms delay (known, taken
   off) and Gaussian jitter of 0 / 10 / 20 / 40 ms, resampled onto the 1 kHz IMU rows by
   linear, cubic Lagrange and 000's fuzzy interpolation (subtractive clustering ra 0.6,
   squash 0.8, accept 0.7, reject 0.2, first-order Sugeno, least squares; 15-sample
   window); RMS error against the true signal over the manoeuvre, averaged over eight
   jitter draws, and in how many of them fuzzy beats linear.

Writes ``dlc.csv/.md``, ``timesync.csv/.md`` and ``timesync.png``.

Run: ``python -m evstab.studies.estimation_000 OUT_DIR``
"""

from __future__ import annotations

import numpy as np

from evstab.plants import load_vehicle
from evstab.plants.disturbances import Disturbances, Friction
from evstab.plants.maneuvers import dlc_000
from evstab.plants.sensors import SensorConfig
from evstab.studies._common import cli, out_dir, save_figure, write_table
from evstab.toolkit.logs import timesync
from evstab.toolkit.estimation import design_filter, run_estimator
from evstab.toolkit.estimation.two_stage import sideslip_at
from evstab.toolkit.loop.simulator import simulate

SPEED = 120 / 3.6
LEAD_IN = 600.0
JITTERS = (0.0, 0.01, 0.02, 0.04)
DELAY = 0.1


def dlc_log(mu: float, seed: int = 2):
    p = load_vehicle("sedan-000")
    man = dlc_000(SPEED, lead_in=LEAD_IN)
    r = simulate(p, "two-track", man, disturbances=Disturbances(friction=Friction(mu=mu)), sensors=SensorConfig(),
                 seed=seed)
    return p, r.log_columns()


def dlc_rows():
    rows = []
    logs = {}
    for mu in (0.9, 0.4):
        p, c = dlc_log(mu)
        logs[mu] = c
        m = c["t"] >= (LEAD_IN - 20.0) / SPEED
        for method in ("two-stage", "dakf", "mbkf", "kkf"):
            e = run_estimator(design_filter(method, p), c)
            be = np.degrees(e["beta"] - c["beta_true"])[m]
            row = {"mu": mu, "filter": method, "beta_err_rms_deg": float(np.sqrt(np.mean(be ** 2))),
                   "beta_err_max_deg": float(np.abs(be).max()),
                   "true_beta_max_deg": float(np.degrees(np.abs(c["beta_true"][m])).max())}
            if method == "two-stage":
                # lever arm: the sideslip at the rear axle from the reference point's velocities
                rear = sideslip_at(e["vx"], e["vy"], e["yaw_rate"], -p.lr)
                true_rear = sideslip_at(c["vx_true"], c["vy_true"], c["yaw_rate_true"], -p.lr)
                ber = np.degrees(rear - true_rear)[m]
                row["rear_axle_beta_err_rms_deg"] = float(np.sqrt(np.mean(ber ** 2)))
            else:
                row["rear_axle_beta_err_rms_deg"] = float("nan")
            rows.append(row)
    return rows, logs


def timesync_rows(c, seeds=range(4, 12)):
    """Resampling error of the GPS course and speed for each jitter and method: the RMS over the
    manoeuvre, its mean over eight jitter draws, and in how many draws fuzzy beats linear."""
    t = c["t"]
    fixes = np.flatnonzero(np.isfinite(c["gps_course"]))
    tau = t[fixes]  # true instants of the fixes
    m = t >= (LEAD_IN - 20.0) / SPEED
    m &= (t > tau[2]) & (t < tau[-3])
    truths = {"course": c["yaw_true"] + c["beta_true"], "speed": np.hypot(c["vx_true"], c["vy_true"])}
    methods = (("linear", timesync.linear), ("lagrange", timesync.lagrange), ("fuzzy", timesync.fuzzy))
    rows, example = [], {}
    for jitter in JITTERS:
        for signal, true in (("course", c["gps_course"]), ("speed", c["gps_speed"])):
            unit = np.degrees if signal == "course" else (lambda x: x)
            rms = {name: [] for name, _ in methods}
            for seed in seeds:
                rng = np.random.default_rng(seed)
                stamp = tau + DELAY + rng.normal(0.0, jitter, len(tau))
                order = np.argsort(stamp)
                ts = stamp[order] - DELAY  # the known delay taken off; the jitter is not known
                ys = true[fixes][order]  # the fix values (with their sensor noise), in stamp order
                for name, f in methods:
                    est = f(ts, ys, t[m])
                    rms[name].append(float(unit(np.sqrt(np.mean((est - truths[signal][m]) ** 2)))))
                    if signal == "course" and jitter == 0.02 and seed == seeds[0]:
                        example[name] = est
            row = {"signal": signal, "unit": "deg" if signal == "course" else "m/s", "jitter_ms": 1000 * jitter}
            row.update({f"{name}_rms": float(np.mean(v)) for name, v in rms.items()})
            row["fuzzy_beats_linear"] = f"{sum(f < li for f, li in zip(rms['fuzzy'], rms['linear']))}/{len(seeds)}"
            rows.append(row)
    return rows, example, t[m], truths["course"][m]


def main(out, quick: bool = False) -> list[dict]:
    out = out_dir(out)
    rows, logs = dlc_rows()
    write_table(rows, out / "dlc.csv", out / "dlc.md")
    ts_rows, example, tt, truth = timesync_rows(logs[0.9])
    write_table(ts_rows, out / "timesync.csv", out / "timesync.md", floatfmt="{:.4f}")
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(8, 3.2))
    for name, est in example.items():
        ax.plot(tt, np.degrees(est - truth), lw=0.8, label=name)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("course error [deg]")
    ax.set_title("GPS course resampled onto the IMU rows, 20 ms timestamp jitter", fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, out / "timesync.png")
    return rows + ts_rows


if __name__ == "__main__":
    cli(main)

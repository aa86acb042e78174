"""Sensor-fault injection: what each fault does to the default estimator, with and without screening.

A 90 s drive of compact-ev on the two-track plant (70 km/h, a 0.2 Hz weave asking
2 m/s^2, GPS at 5 Hz, the default sensor noise, bias and latency-free fixes). At
t = 30 s one fault is injected (the windowed ones last 15 s; :mod:`toolkit.logs.faults`),
and ``dakf`` runs over the log twice: as ``evstab estimate`` runs it (screened,
:mod:`toolkit.estimation.monitor`) and with ``--no-monitor``. The GPS time fault goes
the way a recorded one comes in: the fixes are written as NMEA (pynmea2), one epoch's
time tag is moved 1 s back, and the NMEA is read and merged onto the IMU rows (the
dropped epoch is flagged on the row of the epoch before it: where it arrived, as far
as time tags can tell).

Per fault: rows touched, rows flagged (and how many of them inside the touched rows),
delay from the fault to its first flag, and the sideslip and yaw-rate errors from
t = 30 s to the end, screened and unscreened. The gyro bias step also runs with the
bias CUSUM switched off (``bias_cusum_h = 0``), to show what the alarm buys.
Writes ``faults.csv``/``.md`` and ``faults.png``.

Run: ``python -m evstab.studies.sensor_faults OUT_DIR``
"""

from __future__ import annotations

import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

from evstab.plants import load_vehicle
from evstab.plants.maneuvers import Maneuver, steer_for_lateral_acceleration
from evstab.plants.sensors import SensorConfig
from evstab.studies._common import cli, out_dir, save_figure, write_table
from evstab.toolkit.logs import faults as F
from evstab.toolkit.estimation import design_filter, run_estimator
from evstab.toolkit.estimation.monitor import FLAGS
from evstab.toolkit.logs.nmea import merge_onto_imu, read_nmea, write_nmea
from evstab.toolkit.loop.simulator import simulate

T_FAULT = 30.0
WINDOW = 15.0
SPEED = 70 / 3.6
FAULTS = (
    F.CourseSpikes(T_FAULT, count=3, size=0.3),
    F.FewSatellites(T_FAULT, T_FAULT + WINDOW, sats=3, error=0.2),
    F.FrozenGps(T_FAULT, T_FAULT + WINDOW),
    F.GyroStuck(T_FAULT, T_FAULT + WINDOW),
    F.GyroBiasStep(T_FAULT, step=np.deg2rad(1.0)),
    F.WheelSpeedDropout(T_FAULT, T_FAULT + WINDOW),
)


def drive(seed: int = 3):
    """The clean simulated log (columns, truth included) and the vehicle."""
    p = load_vehicle("compact-ev")
    amp = steer_for_lateral_acceleration(p, SPEED, 2.0)
    man = Maneuver("weave 70 km/h", speed=SPEED, duration=90.0,
                   steer=lambda t: amp * np.sin(2 * np.pi * 0.2 * t) * (t > 2.0))
    return simulate(p, "two-track", man, sensors=SensorConfig(), seed=seed).log_columns(), p


def gps_time_backwards(cols: dict, tmp: Path) -> tuple[dict, np.ndarray]:
    """The log's fixes through NMEA with the epoch at T_FAULT moved 1 s back, merged onto its IMU rows."""
    src = tmp / "gps.nmea"
    write_nmea(src, cols["t"], cols["gps_course"], cols["gps_speed"], hdop=cols["gps_hdop"], sats=cols["gps_sats"])
    lines = src.read_text().splitlines()
    fixes = np.flatnonzero(np.isfinite(cols["gps_course"]))
    epoch = int(np.searchsorted(cols["t"][fixes], T_FAULT))
    bad = tmp / "gps_bad.nmea"
    bad.write_text("\r\n".join(F.nmea_time_backwards(lines, epoch, 1.0)) + "\r\n")
    imu = {k: v for k, v in cols.items() if not k.startswith("gps_")}
    merged, _ = merge_onto_imu(imu, read_nmea(bad), time_offset=12 * 3600.0)
    touched = np.zeros(len(cols["t"]), bool)
    touched[fixes[epoch - 1]] = True  # its time tag claims the past: it is flagged where the epoch before it is
    return merged, touched


def _errors(est, cols, m):
    be = np.degrees(est["beta"] - cols["beta_true"])[m]
    re = np.degrees(est["yaw_rate"] - cols["yaw_rate_true"])[m]
    return float(np.abs(be).max()), float(np.sqrt(np.mean(be ** 2))), float(np.abs(re).max())


def run(seed: int = 3):
    cols, p = drive(seed)
    d = design_filter("dakf", p)
    rng = np.random.default_rng(seed)
    t = cols["t"]
    after = t >= T_FAULT
    cases = [("none", cols, np.zeros(len(t), bool), d)]
    for f in FAULTS:
        c, touched = f.apply(cols, rng)
        cases.append((f.name, c, touched, d))
        if isinstance(f, F.GyroBiasStep):
            off = replace(d, noise=replace(d.noise, bias_cusum_h=0.0))
            cases.append((f.name + " (CUSUM off)", c, touched, off))
    with tempfile.TemporaryDirectory() as tmp:
        merged, touched = gps_time_backwards(cols, Path(tmp))
    merged.update({k: v for k, v in cols.items() if k.endswith("_true")})
    cases.append(("GPS time backwards (NMEA)", merged, touched, d))
    rows, traces = [], {}
    for name, c, touched, dd in cases:
        screened = run_estimator(dd, c, monitor=True)
        raw = run_estimator(dd, c)
        flags = {k: screened[k].astype(bool) for k in FLAGS}
        anyflag = np.any(list(flags.values()), axis=0)
        fired = [k[6:] for k, v in flags.items() if v.any()]
        first = float(t[np.argmax(anyflag)] - T_FAULT) if anyflag.any() else float("nan")
        bs, rs, ys = _errors(screened, c, after)
        bu, ru, yu = _errors(raw, c, after)
        rows.append({"fault": name, "rows touched": int(touched.sum()), "flags": " ".join(fired) or "-",
                     "rows flagged": int(anyflag.sum()), "flagged inside": int((anyflag & touched).sum()),
                     "first flag after [s]": first,
                     "beta err max screened [deg]": bs, "beta err RMS screened [deg]": rs,
                     "yaw-rate err max screened [deg/s]": ys,
                     "beta err max unscreened [deg]": bu, "beta err RMS unscreened [deg]": ru,
                     "yaw-rate err max unscreened [deg/s]": yu})
        traces[name] = (np.degrees(screened["beta"] - c["beta_true"]), np.degrees(raw["beta"] - c["beta_true"]))
    return rows, traces, t


def main(out, quick: bool = False) -> list[dict]:
    out = out_dir(out)
    rows, traces, t = run()
    write_table(rows, out / "faults.csv", out / "faults.md")
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(len(traces), 1, figsize=(8, 1.6 * len(traces)), sharex=True)
    for ax, (name, (scr, raw)) in zip(axes, traces.items()):
        ax.plot(t, raw, lw=0.7, color="0.6", label="unscreened")
        ax.plot(t, scr, lw=0.9, label="screened")
        ax.axvline(T_FAULT, color="r", lw=0.6)
        ax.set_ylabel("beta err\n[deg]", fontsize=7)
        ax.set_title(name, fontsize=8, loc="left")
    axes[0].legend(fontsize=7, loc="upper right")
    axes[-1].set_xlabel("t [s]")
    fig.tight_layout()
    save_figure(fig, out / "faults.png")
    return rows


if __name__ == "__main__":
    cli(main)

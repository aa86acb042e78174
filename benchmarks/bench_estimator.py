"""Estimator speed: evstab's filter core vs filterpy, and ``evstab estimate`` end to end.

1. Core: the ``kf-bias`` design (filterpy needs the same linear model every step)
   over a 10 s, 1 kHz simulated log, run by evstab (casadi-generated C, one call
   per 4000 samples; casadi VM; the numpy reference loop) and by
   ``filterpy.kalman.KalmanFilter`` (predict + gyro update every sample, course
   update at fixes) in the same process, given the model matrices computed once
   outside its timed loop (and, for reference, with the per-step re-discretisation
   included). Also the default ``dakf`` design.
2. End to end: ``evstab estimate`` (read CSV, run dakf, write CSV) on a 10-minute
   1 kHz log of the schema's columns, timed as a subprocess.

Run: ``python benchmarks/bench_estimator.py [--minutes 10]``
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from filterpy.kalman import KalmanFilter

from evstab.plants import load_vehicle
from evstab.plants.backend import NUMPY
from evstab.plants.maneuvers import sine_lane_change
from evstab.plants.sensors import SensorConfig
from evstab.toolkit.estimation import design_filter, run_estimator
from evstab.toolkit.estimation.kalman import INPUTS, discretize, initial_state
from evstab.toolkit.estimation.runner import compiled_filter, inputs_from_columns
from evstab.toolkit.estimation.spec import continuous_model, gyro_row
from evstab.toolkit.logs.drivelog import write_log_table
from evstab.toolkit.loop.simulator import simulate


def filterpy_matrices(d, U):
    """Per sample (F, B, Q) of the ``kf-bias`` model at that sample's speed and period: evstab's
    numpy discretisation, computed once, outside filterpy's timed loop."""
    q = np.diag([d.noise.q_beta, d.noise.q_yaw_rate, d.noise.q_yaw, d.noise.q_bias])
    mats = []
    c = INPUTS.columns(U)
    for dt, v in zip(c["dt"], c["speed"]):
        A, B = continuous_model(d, max(v, d.noise.min_speed), NUMPY)
        F, Gam = discretize(A, dt, NUMPY, d.n)
        mats.append((F, Gam @ B, q * dt))
    return mats


def filterpy_run(d, U, mats=None):
    """``filterpy.kalman.KalmanFilter`` over the log: predict + gyro update every sample, course update at
    fixes. ``mats`` given: the model matrices are ready (only filterpy is timed); None: each step first
    re-discretises at its speed with evstab's numpy code (what a user of filterpy would have to add)."""
    kf = KalmanFilter(dim_x=d.n, dim_z=1, dim_u=2)
    c = INPUTS.columns(U)  # the inputs by name, taken apart before the timed loop
    dts, speeds, fixes = c["dt"], c["speed"], c["fix"]
    uin = np.column_stack([c["steer"], c["yaw_moment"]])
    gyro, course = c["yaw_rate"][:, None], c["course"][:, None]
    kf.x = initial_state(d, 0.0, gyro[0, 0])[:d.n].copy()
    kf.P = d.initial_covariance()
    hg = gyro_row(d)[None, :]
    hc = np.zeros((1, d.n))
    hc[0, d.index("beta")] = hc[0, d.index("yaw")] = 1.0
    q = np.diag([d.noise.q_beta, d.noise.q_yaw_rate, d.noise.q_yaw, d.noise.q_bias])
    out = np.empty(len(U))
    for k in range(len(U)):
        if mats is None:
            A, B = continuous_model(d, max(speeds[k], d.noise.min_speed), NUMPY)
            F, Gam = discretize(A, dts[k], NUMPY, d.n)
            kf.F, kf.B, kf.Q = F, Gam @ B, q * dts[k]
        else:
            kf.F, kf.B, kf.Q = mats[k]
        kf.predict(u=uin[k])
        kf.update(gyro[k], R=d.noise.gyro_std**2, H=hg)
        if fixes[k]:
            kf.update(course[k], R=d.noise.course_std**2, H=hc)
        out[k] = kf.x[0]
    return out


def best(fn, n=3):
    b = np.inf
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        b = min(b, time.perf_counter() - t0)
    return b


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--md", help="also write the docs' table as Markdown to this file")
    args = ap.parse_args(argv)
    table = []
    p = load_vehicle("micro-ev")
    log = simulate(p, "two-track", sine_lane_change(25 / 3.6, np.radians(3.0), duration=10.0),
                   sensors=SensorConfig(gyro_bias=0.002)).log_columns()
    U = inputs_from_columns(log["t"], log["speed"], log["steer"], log["yaw_rate"], log["gps_course"],
                            gps_hdop=log["gps_hdop"], gps_sats=log["gps_sats"])
    n = len(U)
    U_long = np.tile(U, (10, 1))  # 100 s: long enough for stable timings of the compiled path
    kalman_inputs = INPUTS.columns(U_long)
    kalman_inputs["dt"][:] = 1e-3
    print(f"1) filter core, per 1 kHz step (evstab over 100 s of samples, best of 5; filterpy over {n} samples)")
    for method in ("kf-bias", "dakf"):
        d = design_filter(method, p)
        times = {}
        for be in ("c", "vm", "numpy"):
            cf = compiled_filter(d, be)
            z0 = initial_state(d, 0.0, INPUTS.columns(U)["yaw_rate"][0])
            if be == "numpy":
                times[be] = best(lambda: cf.run(U[:2000], z0), 1) / 2000
            else:
                times[be] = best(lambda: cf.run(U_long, z0), 5 if be == "c" else 1) / len(U_long)
        line = f"   {method:8s} evstab C {times['c'] * 1e9:8.0f} ns   VM {times['vm'] * 1e9:8.0f} ns   " \
               f"numpy {times['numpy'] * 1e6:7.1f} us"
        if method == "kf-bias":
            mats = filterpy_matrices(d, U)
            tf = best(lambda: filterpy_run(d, U, mats), 3) / n
            tf_all = best(lambda: filterpy_run(d, U), 1) / n
            ref = filterpy_run(d, U, mats)
            diff = np.abs(run_estimator(d, log, backend="c")["beta"][1:] - ref[1:]).max()
            line += f"   filterpy, matrices given {tf * 1e6:6.1f} us (ratio filterpy/C {tf / times['c']:5.0f}x; " \
                    f"with evstab's numpy re-discretisation per step {tf_all * 1e6:6.1f} us) (beta diff after " \
                    f"the first fix {diff:.1e} rad)"
        print(line)
        table.append([f"`{method}` filter core, per 1 kHz step", f"{times['c'] * 1e9:.0f} ns",
                      f"{times['vm'] * 1e9:.0f} ns", f"{times['numpy'] * 1e6:.0f} us"])
        if method == "kf-bias":
            table.append(["filterpy `KalmanFilter`, same model and data, matrices given", f"{tf * 1e6:.1f} us "
                          f"({tf / times['c']:.0f}x evstab C)", "", f"{tf_all * 1e6:.1f} us with evstab's numpy "
                          f"re-discretisation per step (beta within {diff:.1e} rad)"])
    minutes = args.minutes
    print(f"2) evstab estimate on a {minutes:g}-minute 1 kHz log (schema columns, no truth)")
    rng = np.random.default_rng(0)
    reps = int(np.ceil(minutes * 60 / 10.0))
    cols = {k: v for k, v in log.items() if not k.endswith("_true") and k not in ("x_true", "y_true")}
    big = {}
    for k, v in cols.items():
        if k == "t":
            big[k] = np.arange(reps * n) * 1e-3
        elif k == "yaw_rate":
            big[k] = np.tile(v, reps) + 1e-4 * rng.standard_normal(reps * n)
        else:
            big[k] = np.tile(v, reps)
    with tempfile.TemporaryDirectory() as tmp:
        src, dst = Path(tmp) / "log.csv", Path(tmp) / "est.csv"
        write_log_table(src, big)
        size = src.stat().st_size / 1e6
        cmd = [sys.executable, "-m", "evstab.toolkit.cli", "estimate", str(src), "--vehicle", "micro-ev", "--out", str(dst)]
        subprocess.run(cmd, check=True, capture_output=True)  # warm the compiled cache
        t0 = time.perf_counter()
        res = subprocess.run(cmd, check=True, capture_output=True, text=True)
        wall = time.perf_counter() - t0
        print(f"   {len(big['t'])} rows, {size:.0f} MB: {wall:.2f} s wall (target <= 3 s)  [{res.stdout.strip()}]")
    table.append([f"`evstab estimate` end to end on a {minutes:g}-minute 1 kHz log ({len(big['t'])} rows, "
                  f"{size:.0f} MB CSV)", f"{wall:.2f} s wall", "", ""])
    if args.md:
        from evstab.studies._common import write_markdown
        write_markdown(Path(args.md), ["", "evstab C", "casadi VM", "numpy"], table)


if __name__ == "__main__":
    main()

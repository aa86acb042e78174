"""Sideslip estimators on real measured drives, production sensors emulated on the reference.

The drives are other groups' measurements with a reference sideslip (``--data DIR``, default
``../shared/real``; they are not part of evstab and are read where they lie, through the channel maps
in ``studies/maps/``):

* ``stanford-gti``: Stanford Dynamic Design Lab's VW GTI at the limit, reference-INS body velocities
  (``High_Speed``, ``Low_Speed`` at 200 Hz, ``High_Speed2`` at 1 kHz); no GNSS course in the files;
* ``revsted-thi`` ADMA: ADMA G Pro+ INS at 100 Hz with its RTK receiver's course at 20 Hz (real);
* ``revsted-thi`` OBD: production CAN signals at 50 Hz (a yaw-rate sensor quantised to 1.28 deg/s,
  ABS wheel speeds, a right-positive accelerometer) with the Correvit sideslip; no GNSS.

Where a drive has no course of its own, a single-antenna receiver is emulated from the reference
(:mod:`toolkit.logs.emulate`: course = integrated reference yaw rate + reference sideslip, 5 Hz, noise
0.04 m/s x HDOP 1 over the speed), with the gyro as logged (``reference``) and a production gyro
(``production``: 3 mrad/s bias, +1 % scale, 1.5 mrad/s noise), over :data:`SEEDS` noise seeds. The
OBD sample's gyro is already a production one and stays as logged. Nominal models: the GTI's
publishers' parameters; for ReV-StED, whose car is not named, a generic C-segment car.

Beside the methods, :data:`VARIANTS` (the full run). Per drive, gyro, seed and method: the sideslip error RMS and max [deg] from 5 s after the car first
moves faster than 3 m/s, on samples above 3 m/s; the mean NIS of the course fixes used in that span;
the share of those samples with |error| < 3 ``beta_std``. Beside the methods, ``course - gyro`` is the
model-free line: the course minus the gyro integrated, held between fixes (it is told the heading at the
first fix above 3 m/s by the reference, which no estimator is). Cold starts: each GTI drive
started at :data:`COLD_STARTS` random instants (seeded) with the default method, cold and (High_Speed, High_Speed2) from the gyro
bias learnt over Low_Speed; the time until the error stays below 1 deg for 1 s, the error RMS and the
share of samples inside 3 ``beta_std``.

Outputs: ``real_drives.csv`` (one row per drive, gyro, seed and method), ``real_drives_table.md``
(the docs' table: the worst seed of each cell), ``real_drives_readme.md`` (the README's line),
``real_drives_cold.csv`` / ``real_drives_cold.md``.

Run: ``python -m evstab.studies.real_drives OUT_DIR [--quick] [--data DIR]`` (quick: 30 s of each GTI
drive from 2 s before it first passes 3 m/s, the default method and ``kf-bias``, one seed, two cold starts per drive).
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import numpy as np

from evstab.plants import load_vehicle
from evstab.studies._common import out_dir, pivot, write_markdown, write_table
from evstab.toolkit.logs.channels import load_channel_map, read_mapped
from evstab.toolkit.logs.emulate import PRODUCTION_GYRO, Emulation, emulate
from evstab.toolkit.estimation import METHODS, design_filter, run_estimator
from evstab.toolkit.estimation.spec import METHOD_COLUMNS, estimation_noise

MAPS = Path(__file__).resolve().parent / "maps"
"""The channel maps and vehicle files of the datasets (documented examples of ``evstab convert --map``)."""
SEEDS = (0, 1, 2)
COLD_STARTS = 20
CALIBRATION_SEED = 5
"""The emulation seed of the Low_Speed drive the cold starts' calibration is learnt on (another than theirs)."""
SETTLE_DEG = 1.0
SCORE_SPEED = 3.0
SCORE_AFTER = 5.0
DEFAULT = "dakf"
QUICK_METHODS = ("dakf", "kf-bias")
BIAS_HELD_RATE = 0.25
"""[rad/s] The ``bias_learn_rate`` of the ``dakf, bias held in turns`` row (off by default: on simulated logs, whose
model is right in a turn, a gyro scale error shows there as a bias that must be learnt)."""
VARIANTS = {"dakf, accelerometer read raw": ("dakf", {"kinematic_ay_cutoff": 0.0}),
            "dakf, path thresholds not raised by the noise": ("dakf", {"kinematic_noise_sigmas": 0.0}),
            "dakf, the ECU's kinematic sideslip noise": ("dakf", {"q_beta_kinematic": 0.02}),
            "dakf, yaw row not loosened": ("dakf", {"yaw_model_ay": 0.0}),
            "dakf, yaw row not loosened with the steer": ("dakf", {"yaw_model_steer": 0.0}),
            "dakf, beta_std without the model's error": ("dakf", {"beta_model_std": 0.0, "beta_model_rel": 0.0}),
            "dakf, yaw row released through a 0.1 s lag": ("dakf", {"kinematic_yaw_release": 0.1}),
            "dakf, a quarter less of an under-prediction": ("dakf", {"kinematic_overpredict": 0.25}),
            "dakf, bias held in turns": ("dakf", {"bias_learn_rate": BIAS_HELD_RATE}),
            "dakf, over-prediction only": ("dakf", {"kinematic_overpredict": 1.0})}
"""Rows beside the methods: ``dakf`` with one of its log settings (:func:`toolkit.estimation.spec.estimation_noise`)
undone, each what it does on these drives -- the accelerometer's low-pass (``kinematic_ay_cutoff``), the
kinematic path's thresholds raised by the accelerometer's noise (``kinematic_noise_sigmas``), its sideslip noise
(``q_beta_kinematic``, the ECU's 0.02), the yaw row loosened with the lateral acceleration
(``yaw_model_ay``) and with the steer (``yaw_model_steer``), ``beta_std``'s allowance for the linear model's error (``beta_model_std``,
``beta_model_rel``) -- and settings that are off by default: the yaw row's return to the model through a lag after
the kinematic path lets go (``kinematic_yaw_release`` 0.1 s), the gyro bias held in turns (``bias_learn_rate``
:data:`BIAS_HELD_RATE`), a departure where the car has more lateral acceleration than the model counted a quarter
less (``kinematic_overpredict`` 0.25) or not at all (1)."""
QUICK_SECONDS = 30.0
"""The quick run's excerpt of each GTI drive, from 2 s before the car first passes 3 m/s."""
GTI = (("High_Speed", 200.0), ("Low_Speed", 200.0), ("High_Speed2", 1000.0))


def data_dir(data=None) -> Path | None:
    """The folder of the real drives: ``data``, else ``$EVSTAB_REAL_DATA``, else ``../shared/real`` from the
    working directory or from the repository; None where none exists."""
    cands = [data] if data is not None else [os.environ.get("EVSTAB_REAL_DATA"), Path.cwd().parent / "shared" / "real",
                                             Path(__file__).resolve().parents[2] / "shared" / "real"]
    for c in cands:
        if c and Path(c).is_dir():
            return Path(c)
    return None


def drives(data: Path, quick: bool = False) -> list[dict]:
    """The reference logs: name, columns (with ``beta_true``), whether a course must be emulated, the nominal
    vehicle, and whether the gyro is already a production one."""
    out = []
    gti = load_vehicle(MAPS / "stanford-gti-vehicle.toml")
    generic = load_vehicle(MAPS / "revsted-vehicle.toml")
    for name, rate in GTI:
        cmap = load_channel_map(MAPS / "stanford-gti.toml")
        cmap["sample_rate"] = rate
        cols = dict(read_mapped(data / "stanford-gti" / "raw" / f"{name}.mat", cmap).columns)
        if quick:  # from 2 s before the car first passes 3 m/s
            k0 = max(int(np.argmax(np.abs(cols["speed"]) > SCORE_SPEED)) - int(2 * rate), 0)
            cols = {k: v[k0:k0 + int(QUICK_SECONDS * rate)] for k, v in cols.items()}
            cols["t"] = cols["t"] - cols["t"][0]
        out.append({"drive": f"GTI {name}", "cols": cols, "emulate": True, "vehicle": gti, "gyro_fixed": False})
    adma = read_mapped(data / "revsted-thi" / "raw" / "ADMA_data_sample.csv", MAPS / "revsted-adma.toml").columns
    out.append({"drive": "ReV-StED ADMA (RTK course)", "cols": dict(adma), "emulate": False, "vehicle": generic,
                "gyro_fixed": True})
    obd = dict(read_mapped(data / "revsted-thi" / "raw" / "OBD_Sample.csv", MAPS / "revsted-obd.toml").columns)
    obd["beta_true"] = sideslip_moved(obd["beta_true"], obd["yaw_rate"], obd["speed"],
                                      REVSTED_REFERENCE_AHEAD_OF_REAR_AXLE - generic.lr)
    out.append({"drive": "ReV-StED OBD (CAN)", "cols": obd, "emulate": True, "vehicle": generic,
                "gyro_fixed": True})
    return out


REVSTED_REFERENCE_AHEAD_OF_REAR_AXLE = 0.76
"""[m] Where the OBD sample's Correvit sideslip is: its "CG" lies this far ahead of the rear axle by the sample's
own kinematics (in the walking-pace U-turn, sideslip x speed / yaw rate = 0.76 m; the dataset's README). The
generic vehicle file's CG is ``lr`` = 1.55 m ahead of it; the reference is moved there (:func:`sideslip_moved`)
before the course is emulated from it and the estimates are scored, so that the course, the filters' model and
the reference speak of one point."""


def sideslip_moved(beta, yaw_rate, speed, ahead, min_speed: float = 0.5) -> np.ndarray:
    """The sideslip at the CG from the sideslip ``beta`` at a point ``ahead`` [m] in front of it (behind it:
    negative): the lateral velocity there is the CG's plus ``ahead`` x the yaw rate, so
    ``tan(beta_cg) = tan(beta) - ahead r / v`` (``v`` the speed, at least ``min_speed``)."""
    v = np.maximum(np.abs(np.asarray(speed, float)), min_speed)
    return np.arctan(np.tan(np.asarray(beta, float)) - ahead * np.asarray(yaw_rate, float) / v)


def scored(cols) -> np.ndarray:
    """The samples scored: from 5 s after the speed first passes 3 m/s, above 3 m/s."""
    t, v = cols["t"], np.abs(cols["speed"])
    moving = np.flatnonzero(v > SCORE_SPEED)
    if not len(moving):
        return np.zeros(len(t), bool)
    return (t >= t[moving[0]] + SCORE_AFTER) & (v > SCORE_SPEED)


def floor_estimate(cols) -> np.ndarray:
    """The model-free line: course minus the log's gyro integrated, held between fixes; the integral starts at
    the first fix above 3 m/s from the heading the reference gives there (course less reference sideslip: a
    reference sideslip at walking pace is the INS's noise)."""
    t, r, c = cols["t"], cols["yaw_rate"], cols["gps_course"]
    yaw = np.concatenate([[0.0], np.cumsum(0.5 * (r[1:] + r[:-1]) * np.diff(t))])
    fixes = np.flatnonzero(np.isfinite(c) & (np.abs(cols["speed"]) > SCORE_SPEED))
    if len(fixes):
        k = fixes[0]
        yaw = yaw - yaw[k] + (c[k] - cols["beta_true"][k])
    b = np.where(np.isfinite(c), c - yaw, np.nan)
    idx = np.where(np.isfinite(b), np.arange(len(b)), 0)
    np.maximum.accumulate(idx, out=idx)
    held = b[idx]
    held[: np.argmax(np.isfinite(b))] = np.nan if not np.isfinite(b).any() else b[np.argmax(np.isfinite(b))]
    return held


def errors(cols, beta, beta_std=None, nis=None) -> dict:
    sel = scored(cols)
    e = np.degrees(beta - cols["beta_true"])[sel]
    row = {"rms_deg": float(np.sqrt(np.mean(e ** 2))), "max_deg": float(np.abs(e).max())}
    row["mean_nis"] = float(np.nanmean(nis[sel])) if nis is not None and np.isfinite(nis[sel]).any() else float("nan")
    row["inside_3sd"] = float(np.mean(np.abs(beta - cols["beta_true"])[sel] < 3 * beta_std[sel])) \
        if beta_std is not None and np.isfinite(beta_std[sel]).all() else float("nan")
    return row


def sensor_logs(drive: dict, seeds) -> list[tuple[str, int, dict]]:
    """``(gyro, seed, columns)`` of a drive: emulated where it has no course of its own."""
    if not drive["emulate"]:
        return [("as logged", 0, drive["cols"])]
    gyros = ("as logged",) if drive["gyro_fixed"] else ("reference", "production")
    out = []
    for gyro in gyros:
        for seed in seeds:
            kw = dict(PRODUCTION_GYRO) if gyro == "production" else {}
            out.append((gyro, seed, emulate(drive["cols"], Emulation(seed=seed, **kw))))
    return out


def runnable(method: str, cols) -> str | None:
    """Why ``method`` cannot run on ``cols`` (a column it needs is missing), or None."""
    lacks = [c for c in METHOD_COLUMNS.get(method, ()) if not np.any(np.isfinite(cols.get(c, [np.nan])))]
    return f"needs {', '.join(lacks)}" if lacks else None


def main(out, quick: bool = False, data=None) -> list[dict]:
    out = out_dir(out)
    root = data_dir(data)
    if root is None:
        raise FileNotFoundError("no real-drive data: give --data DIR (the folder with stanford-gti/ and revsted-thi/) "
                                "or set EVSTAB_REAL_DATA")
    methods = tuple(QUICK_METHODS if quick else METHODS)
    seeds = SEEDS[:1] if quick else SEEDS
    rows, skipped = [], {}
    every = drives(root, quick)
    for drive in every:
        for gyro, seed, cols in sensor_logs(drive, seeds):
            log = {k: v for k, v in cols.items() if not k.endswith("_true")}
            base = {"drive": drive["drive"], "gyro": gyro, "seed": seed}
            rows.append({**base, "method": "course - gyro", **errors(cols, floor_estimate(cols))})
            for m in methods + (() if quick else tuple(VARIANTS)):
                method, noise = VARIANTS.get(m, (m, None))
                why = runnable(method, cols)
                if why:
                    skipped[(drive["drive"], gyro, m)] = why
                    continue
                if noise is not None:
                    noise = dataclasses.replace(estimation_noise(), **noise)
                est = run_estimator(design_filter(method, drive["vehicle"], noise), log, monitor=True)
                flags = int(est["fault_gyro_stuck"].sum()) if "fault_gyro_stuck" in est.columns else 0
                rows.append({**base, "method": m, **errors(cols, est["beta"], est["beta_std"], est["nis"]),
                             "gyro_stuck_rows": flags})
    for r in rows:
        r.setdefault("gyro_stuck_rows", 0)
    write_table(rows, out / "real_drives.csv", out / "real_drives.md")
    worst: dict[tuple, dict] = {}
    for r in rows:
        w = worst.setdefault((r["drive"], r["gyro"], r["method"]), dict(r))
        for k in ("rms_deg", "max_deg"):
            w[k] = max(w[k], r[k])
        w["mean_nis_max"] = float(np.fmax(w.get("mean_nis_max", np.nan), r["mean_nis"]))
        w["mean_nis_min"] = float(np.fmin(w.get("mean_nis_min", np.nan), r["mean_nis"]))
        w["inside_min"] = float(np.fmin(w.get("inside_min", np.nan), r["inside_3sd"]))

    def cell(r):
        nis = "-" if not np.isfinite(r["mean_nis_max"]) else (
            f"{r['mean_nis_min']:.2f}" if r["mean_nis_min"] == r["mean_nis_max"] else
            f"{r['mean_nis_min']:.2f}-{r['mean_nis_max']:.2f}")
        inside = "-" if not np.isfinite(r["inside_min"]) else f"{100 * r['inside_min']:.0f} %"
        return f"{r['rms_deg']:.2f} / {r['max_deg']:.2f} / {nis} / {inside}"

    for w in worst.values():
        w["drive_gyro"] = f"{w['drive']}, {w['gyro']} gyro" if w["gyro"] != "as logged" else w["drive"]
    cells = list(worst.values())
    for (drive, gyro, m), why in skipped.items():
        cells.append({"method": m, "drive_gyro": f"{drive}, {gyro} gyro" if gyro != "as logged" else drive,
                      "why": why})
    header, table = pivot(cells, ["method"], "drive_gyro", lambda r: f"not run: {r['why']}" if "why" in r else cell(r))
    write_markdown(out / "real_drives_table.md", header, table)
    line = [w for w in worst.values() if w["method"] == DEFAULT]
    header, table = pivot(line, ["method"], "drive_gyro", lambda r: f"{r['rms_deg']:.2f} / {r['max_deg']:.2f}")
    write_markdown(out / "real_drives_readme.md", header, table)
    cold = cold_starts(every[:len(GTI)], n=2 if quick else COLD_STARTS, quick=quick)
    write_table(cold, out / "real_drives_cold.csv")
    by: dict = {}
    for r in cold:
        by.setdefault(r["drive"], []).append(r)
    write_markdown(out / "real_drives_cold.md", ["drive", "starts", "settled within 3 s", "slowest settle [s]",
                                                 "error RMS, median start [deg]", "inside 3 beta_std (worst start)"],
                   [[d, len(rs), sum(r["settle_s"] <= 3.0 for r in rs), f"{max(r['settle_s'] for r in rs):.2f}",
                     f"{np.median([r['rms_deg'] for r in rs]):.2f}", f"{100 * min(r['inside_3sd'] for r in rs):.0f} %"]
                    for d, rs in by.items()])
    return rows


def cold_starts(gti: list[dict], n: int = COLD_STARTS, seed: int = 0, quick: bool = False) -> list[dict]:
    """The default method started at ``n`` random instants inside each GTI drive (production gyro, emulated
    course of seed 0): the time until the error stays below :data:`SETTLE_DEG` for 1 s (inf: never). High_Speed
    and High_Speed2 are also started from a calibration (:mod:`toolkit.estimation.calibration`): the gyro bias
    the filter learnt over Low_Speed (45 s at rest, then tight turns) with the same production gyro and another
    noise seed, at the same instants; and without the bias held in turns while the heading settles
    (``NoiseSettings.bias_settle_hold`` 0). ``gti``: the GTI drives of :func:`drives`, in their order."""
    rows = []
    rng = np.random.default_rng(seed)
    low = emulate(gti[1]["cols"], Emulation(seed=CALIBRATION_SEED, **PRODUCTION_GYRO))
    cal = run_estimator(design_filter(DEFAULT, gti[1]["vehicle"]), {k: v for k, v in low.items()
                                                                     if not k.endswith("_true")}, monitor=True).final
    calibration = (cal["gyro_bias"], cal["gyro_bias_std"])
    for drive in gti:
        cols = emulate(drive["cols"], Emulation(seed=0, **PRODUCTION_GYRO))
        t = cols["t"]
        moving = t[np.abs(cols["speed"]) > SCORE_SPEED]
        starts = rng.uniform(moving[0], t[-1] - (5.0 if quick else 15.0), n)
        d = design_filter(DEFAULT, drive["vehicle"])
        at_once = design_filter(DEFAULT, drive["vehicle"], dataclasses.replace(estimation_noise(), bias_settle_hold=0.0))
        for label, bias, design in ((drive["drive"], None, d), (f"{drive['drive']}, calibrated on Low_Speed", calibration, d),
                                    (f"{drive['drive']}, bias learnt in turns from the start", None, at_once)):
            if bias is not None and drive is gti[1]:
                continue
            for t0 in starts:
                k0 = int(np.searchsorted(t, t0))
                part = {k: v[k0:] for k, v in cols.items()}
                part["t"] = part["t"] - part["t"][0]
                est = run_estimator(design, {k: v for k, v in part.items() if not k.endswith("_true")},
                                    monitor=True, bias=bias)
                err = np.abs(np.degrees(est["beta"] - part["beta_true"]))
                fast = np.abs(part["speed"]) > SCORE_SPEED
                rows.append({"drive": label, "start_s": float(t[k0]), "settle_s": settle_time(part["t"], err, fast),
                             "rms_deg": float(np.sqrt(np.mean(err[fast] ** 2))),
                             "inside_3sd": float(np.mean((np.abs(est["beta"] - part["beta_true"])
                                                          < 3 * est["beta_std"])[fast]))})
    return rows


def settle_time(t, err_deg, valid) -> float:
    """The first time from which ``err_deg`` stays below :data:`SETTLE_DEG` for 1 s on the ``valid`` samples
    (inf if never)."""
    bad_t = t[(err_deg >= SETTLE_DEG) & valid]
    nxt = np.searchsorted(bad_t, t, side="left")
    next_bad = np.where(nxt < len(bad_t), bad_t[np.minimum(nxt, len(bad_t) - 1)], np.inf) if len(bad_t) else \
        np.full(len(t), np.inf)
    ok = np.flatnonzero((next_bad > t + 1.0) & (t + 1.0 <= t[-1]))
    return float(t[ok[0]]) if len(ok) else float("inf")

if __name__ == "__main__":
    import sys
    args = [a for a in sys.argv[1:] if a != "--quick"]
    data = None
    if "--data" in args:
        i = args.index("--data")
        data = args[i + 1]
        del args[i:i + 2]
    for row in main(args[0] if args else "out/studies", quick="--quick" in sys.argv, data=data):
        print(row)

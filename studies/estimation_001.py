"""Seed 001 (Anderson & Bevly): kinematic vs model-based Kalman filter, residuals, stiffness, Table I.

1. **Two 180-degree turns** (`plants.maneuvers.two_half_turns`: 57.6 km/h, radius 50 m, 300 m
   lead-in, 150 m straights; about 5 m/s^2 in the turns) of compact-ev on the two-track
   plant with a 2 % gyro scale-factor error (001 Figs. 5-7). Filters: the kinematic KF
   (``kkf``), the model-based KF (``mbkf``) with the right parameters and with those of a
   different vehicle (the filter is given sedan-000: 10 % more mass, 30 % more yaw
   inertia, a 38/62 instead of 45/55 weight split, the same tires; 001 Fig. 6), and
   ``dakf`` for reference; plus ``kkf`` without the scale error. Per filter: sideslip
   error RMS / max from the first turn on, the course-residual whiteness (Ljung-Box,
   20 lags, 5 %) and the mean NIS with its 95 % interval.
2. **Cornering stiffness from the kinematic sideslip** (`toolkit.estimation.identify`;
   no scale error: 001 says the KKF serves once the scale error is removed), on the
   bicycle and the two-track plant, three seeds each, against the parameter file.
   Then ``mbkf`` of the wrong vehicle gets the identified stiffness (001 Fig. 12).
3. **Table I**: predicted a-priori errors vs GPS rate at 30 m/s
   (`toolkit.estimation.rate_table`), compact-ev's parameters (stated in the table), the
   steer-noise intensity calibrated on the 5 Hz row.

Writes ``turns.csv/.md``, ``stiffness.csv/.md``, ``table_i.csv/.md`` and ``turns.png``.

Run: ``python -m evstab.studies.estimation_001 OUT_DIR``
"""

from __future__ import annotations

import dataclasses

import numpy as np

from evstab.plants import load_vehicle
from evstab.plants.maneuvers import two_half_turns
from evstab.plants.sensors import SensorConfig
from evstab.studies._common import cli, out_dir, save_figure, write_markdown, write_table
from evstab.toolkit.estimation import design_filter, run_estimator
from evstab.toolkit.estimation.diagnostics import nis_consistency, whiteness
from evstab.toolkit.estimation.identify import cornering_stiffness
from evstab.toolkit.estimation.rate_table import table_i

SPEED, RADIUS, LEAD_IN = 16.0, 50.0, 300.0


def drive(p, plant: str, scale_error: float, seed: int):
    man = two_half_turns(SPEED, RADIUS, lead_in=LEAD_IN)
    return simulate_log(p, plant, man, SensorConfig(gyro_scale_error=scale_error), seed)


def simulate_log(p, plant, man, sensors, seed):
    from evstab.toolkit.loop.simulator import simulate
    return simulate(p, plant, man, sensors=sensors, seed=seed).log_columns()


def _row(name, est, cols, m):
    be = np.degrees(est["beta"] - cols["beta_true"])[m]
    r = np.where(est["gps_used"] > 0.5, est["course_resid"], np.nan)
    w = whiteness(r, lags=20)
    c = nis_consistency(r[np.isfinite(r)] ** 2)
    return {"filter": name, "beta_err_rms_deg": float(np.sqrt(np.mean(be ** 2))),
            "beta_err_max_deg": float(np.abs(be).max()),
            "yaw_rate_err_rms_deg_s": float(np.degrees(np.sqrt(np.mean((est["yaw_rate"] - cols["yaw_rate_true"])[m]
                                                                       ** 2)))),
            "fixes_used": w.n, "ljung_box_q20": w.ljung_box, "whiteness_p": w.p_value,
            "residuals_white": "yes" if w.white else "no", "nis_mean": c.mean,
            "nis_interval": f"[{c.low:.2f}, {c.high:.2f}]"}


def turns(p, wrong):
    cols = drive(p, "two-track", 0.02, seed=1)
    clean = drive(p, "two-track", 0.0, seed=1)
    m = cols["t"] >= LEAD_IN / SPEED - 1.0
    runs = [("kkf, 2 % scale error", design_filter("kkf", p), cols),
            ("kkf, no scale error", design_filter("kkf", p), clean),
            ("mbkf, right parameters", design_filter("mbkf", p), cols),
            ("mbkf, another vehicle's parameters", design_filter("mbkf", wrong), cols),
            ("dakf, right parameters", design_filter("dakf", p), cols)]
    rows, traces = [], {}
    for name, d, c in runs:
        est = run_estimator(d, c)
        rows.append(_row(name, est, c, m))
        traces[name] = est["beta"]
    # the residual check where nothing but the parameters can make residuals coloured: the linear
    # bicycle plant (the filter's own model), no scale error
    lin = drive(p, "bicycle", 0.0, seed=1)
    for name, d in (("mbkf, right parameters, bicycle plant, no scale error", design_filter("mbkf", p)),
                    ("mbkf, another vehicle's, bicycle plant, no scale error", design_filter("mbkf", wrong))):
        rows.append(_row(name, run_estimator(d, lin), lin, m))
    return rows, traces, cols


def stiffness(p, wrong):
    rows = []
    for plant in ("bicycle", "two-track"):
        for seed in (1, 2, 3):
            c = drive(p, plant, 0.0, seed)
            est = run_estimator(design_filter("kkf", p), c)
            fixes = np.flatnonzero(np.isfinite(c["gps_course"]))
            s = cornering_stiffness(p, c["t"], c["speed"], c["steer"], c["yaw_rate"], est["beta"], rows=fixes,
                                    yaw_moment=c.get("yaw_moment"))
            rows.append({"plant": plant, "seed": seed, "front_N_per_rad": s.front, "rear_N_per_rad": s.rear,
                         "front_err_pct": 100 * (s.front / p.cornering_stiffness_front - 1),
                         "rear_err_pct": 100 * (s.rear / p.cornering_stiffness_rear - 1),
                         "fit_r2_front": s.fit_front, "fit_r2_rear": s.fit_rear,
                         "samples": min(s.samples_front, s.samples_rear)})
    # 001 Fig. 12: the wrong vehicle's filter gets the stiffness identified with its own (wrong) mass,
    # inertia and axle positions on the two-track run: the effective stiffness that makes its model
    # reproduce what the car does ("will compensate for errors in other parameters, such as weight split")
    c = drive(p, "two-track", 0.0, 1)
    est = run_estimator(design_filter("kkf", wrong), c)
    fixes = np.flatnonzero(np.isfinite(c["gps_course"]))
    s = cornering_stiffness(wrong, c["t"], c["speed"], c["steer"], c["yaw_rate"], est["beta"], rows=fixes,
                            yaw_moment=c.get("yaw_moment"))
    rows.append({"plant": "two-track, identified with sedan-000's m, Iz, lf, lr", "seed": 1,
                 "front_N_per_rad": s.front, "rear_N_per_rad": s.rear,
                 "front_err_pct": 100 * (s.front / p.cornering_stiffness_front - 1),
                 "rear_err_pct": 100 * (s.rear / p.cornering_stiffness_rear - 1),
                 "fit_r2_front": s.fit_front, "fit_r2_rear": s.fit_rear,
                 "samples": min(s.samples_front, s.samples_rear)})
    fixed = dataclasses.replace(wrong, cornering_stiffness_front=s.front, cornering_stiffness_rear=s.rear,
                                nominal_cornering_stiffness_front=None, nominal_cornering_stiffness_rear=None)
    return rows, fixed


def main(out, quick: bool = False) -> list[dict]:
    out = out_dir(out)
    p = load_vehicle("compact-ev")
    wrong = load_vehicle("sedan-000")
    rows, traces, cols = turns(p, wrong)
    st_rows, fixed = stiffness(p, wrong)
    est = run_estimator(design_filter("mbkf", fixed), cols)
    rows.append(_row("mbkf, another vehicle's parameters + identified stiffness", est, cols,
                     cols["t"] >= LEAD_IN / SPEED - 1.0))
    traces[rows[-1]["filter"]] = est["beta"]
    write_table(rows, out / "turns.csv", out / "turns.md")
    write_table(st_rows, out / "stiffness.csv", out / "stiffness.md")
    t1 = table_i(p)
    for r in t1:
        r["vehicle"] = (f"compact-ev: m {p.mass:g} kg, Iz {p.yaw_inertia:g} kg m^2, lf {p.lf:g} m, lr {p.lr:g} m, "
                        f"C {p.cornering_stiffness_front:g}/{p.cornering_stiffness_rear:g} N/rad per tire")
    write_table(t1, out / "table_i.csv", out / "table_i.md", floatfmt="{:.4g}")
    write_markdown(out / "table_i_table.md", ["GPS rate", "sigma_course, sigma_gyro (paper, input)",
                                              "paper sigma_r, sigma_beta", "evstab a-priori sigma_r, sigma_beta",
                                              "a-posteriori"],
                   [[f"{r['gps_rate_hz']:g} Hz", f"{r['sigma_course_deg']:.4g} deg, {r['sigma_gyro_deg_s']:.4g} deg/s",
                     f"{r['paper_sigma_r_deg_s']:.4g} deg/s, {r['paper_sigma_beta_deg']:.4g} deg",
                     f"{r['sigma_r_deg_s']:.4f} deg/s, {r['sigma_beta_deg']:.4f} deg",
                     f"{r['sigma_r_posterior_deg_s']:.4f}, {r['sigma_beta_posterior_deg']:.4f}"] for r in t1])
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(8, 3.5))
    t = cols["t"]
    ax.plot(t, np.degrees(cols["beta_true"]), "k", lw=1.2, label="truth")
    for name, b in traces.items():
        ax.plot(t, np.degrees(b), lw=0.8, label=name)
    ax.set_xlabel("t [s]")
    ax.set_ylabel("sideslip [deg]")
    ax.set_xlim(LEAD_IN / SPEED - 2, t[-1])
    ax.legend(fontsize=6)
    fig.tight_layout()
    save_figure(fig, out / "turns.png")
    return rows + st_rows + t1


if __name__ == "__main__":
    cli(main)

"""The limit manoeuvres of the design job (:mod:`toolkit.design.limits`) and the straight road, for the
compact EV on the two-track: no control, seed 003's controller as the paper runs it, evstab's
default supervised 2-DOF controller and, with ``--design DIR``, a design folder's ECU as
exported; ``dakf`` in the loop, the ECU not told the friction.

* FMVSS 126 on mu 1.0 and 0.6 (runs passed of the full series);
* ISO 3888-1 at 80 and 100 km/h on mu 1.0, 0.8, 0.5 and the step steer into saturation on mu
  1.0 and 0.5 (peak sideslip [deg]; "no worse" is :func:`toolkit.design.limits.no_worse` against no
  control);
* straight road at 60 and 80 km/h with the default sensor noise: steer and yaw moment the ECU
  adds to the driver's (RMS and peak).

Writes ``limits_summary.md``/``.csv`` and ``straight_summary.md``/``.csv``.

Run: ``python -m evstab.studies.control_limits OUT_DIR [--design DIR]``
"""

from __future__ import annotations

import sys

import numpy as np

from evstab.controllers.two_dof import TwoDofDesign
from evstab.plants import load_vehicle
from evstab.plants.maneuvers import step_steer
from evstab.studies._common import out_dir, seed_003_design, write_table
from evstab.toolkit.design import limits as lm
from evstab.toolkit.loop.simulator import simulate
from evstab.toolkit.design.sweep import SweepConfig


def controllers(p, design_dir=None) -> list[tuple[str, object]]:
    out = [("no control", None), ("2-DOF seed 003", seed_003_design(p)), ("2-DOF default", TwoDofDesign(p.as_nominal()))]
    if design_dir is not None:
        from evstab.toolkit.firmware.export import ecu_from_design
        out.append(("design folder", ecu_from_design(design_dir)[0]))
    return out


def straight_road(p, design, kmh: float) -> dict:
    """Steer and yaw moment the ECU adds on a straight road (10 s, default sensor noise)."""
    r = simulate(p, "two-track", step_steer(kmh / 3.6, 0.0, duration=10.0), seed=0, controller="two-dof",
                 estimator=getattr(getattr(design, "filter", None), "method", "dakf"), design=design)
    added = np.degrees(r.commands["steer"] - r.commands["steer_driver"])
    nz = r.commands["yaw_moment"]
    return {"steer_rms_deg": float(np.sqrt(np.mean(added**2))), "steer_peak_deg": float(np.abs(added).max()),
            "yaw_moment_rms_Nm": float(np.sqrt(np.mean(nz**2))), "yaw_moment_peak_Nm": float(np.abs(nz).max())}


def main(out, design_dir=None) -> list[dict]:
    out = out_dir(out)
    p = load_vehicle("compact-ev")
    cfg = SweepConfig(p)
    a_cache: dict = {}
    ctl = controllers(p, design_dir)
    results = {name: lm.run_limits(cfg, d, a_cache=a_cache, name=name) for name, d in ctl}
    none = results["no control"]
    rows = []
    for i, case in enumerate(none):
        row = {"case": case["case"]}
        for name, _ in ctl:
            r = results[name][i]
            row[name] = (f"{r['runs_passed']}/{r['runs']}" + (" PASS" if r["pass"] else " FAIL")
                         if r["kind"] == "fmvss126" else
                         ("lost" if not np.isfinite(r["peak_beta_deg"]) else f"{r['peak_beta_deg']:.2f}"))
            if name != "no control":
                ok, _ = lm.no_worse(r, case)
                row[name] += "" if ok else " (worse)"
        rows.append(row)
    # the docs' table has the design folder's column whether or not one was given ("-" without)
    write_table([{**r, "design folder": r.get("design folder", "-")} for r in rows], out / "limits_summary.csv",
                out / "limits_summary.md")
    straight = [{"speed_kmh": kmh, "controller": name, **straight_road(p, d, kmh)}
                for kmh in (60.0, 80.0) for name, d in ctl if d is not None]
    write_table(straight, out / "straight_summary.csv", out / "straight_summary.md")
    return rows + straight


if __name__ == "__main__":
    args = sys.argv[1:]
    design = None
    if "--design" in args:
        k = args.index("--design")
        design = args[k + 1]
        del args[k:k + 2]
    for row in main(args[0] if args else "out/studies", design):
        print(row)

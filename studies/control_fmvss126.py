"""FMVSS 126 series for the compact EV on mu 1.0 and 0.6: without control, with seed 003's 2-DOF
controller as the paper runs it (always acting, full steer range) and with evstab's default,
supervised 2-DOF controller (dead bands, friction estimate, steer authority, yaw guard; see
:mod:`controllers.supervisor`); ``dakf`` in the loop, the ECU not told the friction.

A from the slowly increasing steer on each road; sine with dwell at 80 km/h from 1.5 A up to
max(6.5 A, 270 deg), both directions (quick mode: the first two amplitudes at or above 5 A).
Writes ``fmvss126_<controller>_mu<mu>.csv`` per controller and road and ``fmvss126_summary.md``.

Run: ``python -m evstab.studies.control_fmvss126 OUT_DIR [--quick]``
"""

from __future__ import annotations

from evstab.controllers.two_dof import TwoDofDesign
from evstab.plants import load_vehicle
import numpy as np

from evstab.studies._common import cli, out_dir, seed_003_design, write_markdown, write_table
from evstab.toolkit.verdicts.fmvss126 import find_a, run_series

MUS = (1.0, 0.6)


def main(out, quick: bool = False) -> list[dict]:
    out = out_dir(out)
    p = load_vehicle("compact-ev")
    summary, table = [], []
    cases = (("none", "none", None), ("2-DOF seed 003", "two-dof", seed_003_design(p)),
             ("2-DOF supervised", "two-dof", TwoDofDesign(p.as_nominal())))
    for mu in MUS:
        a_deg = find_a(p, mu=mu)
        for label, ctl, design in cases:
            _, rows, verdict = run_series(p, ctl, "dakf", mu=mu, a_deg=a_deg, quick=quick, design=design)
            write_table(rows, out / f"fmvss126_{label.replace(' ', '_').replace('-', '')}_mu{mu:g}.csv")
            summary.append({"mu": mu, "controller": label, "A_deg": a_deg, "runs": len(rows),
                            "runs_passed": sum(r["pass"] for r in rows), "pass": verdict["pass"],
                            "failed_criteria": " ".join(verdict["failed_criteria"]) or "-"})
            big = [r for r in rows if r["amplitude_deg"] >= 5.0 * a_deg - 1e-9]
            passed = sum(r["pass"] for r in rows)
            ok = f"{passed} / {len(rows)}"
            table.append([f"{mu:.1f}", label, f"**{ok}**" if verdict["pass"] else ok,
                          "**PASS**" if verdict["pass"] else "FAIL: " + " ".join(verdict["failed_criteria"]),
                          f"{np.nanmax([r['yaw_ratio_1_0'] for r in rows]):.1f} % / "
                          f"{np.nanmax([r['yaw_ratio_1_75'] for r in rows]):.1f} %",  # the series' ratios are in %
                          f"{min(r['lateral_displacement_m'] for r in big):.2f} m" if big else "-"])
    write_table(summary, out / "fmvss126_summary.csv")
    # the docs' table
    write_markdown(out / "fmvss126_summary.md", ["mu", "controller", "runs passed", "verdict",
                                                 "worst yaw ratio at COS+1.0 / +1.75 s",
                                                 "least displacement at >= 5 A"], table)
    return summary


if __name__ == "__main__":
    cli(main)

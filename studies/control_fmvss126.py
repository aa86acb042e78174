"""FMVSS 126 series for the compact EV, without control and with the 2-DOF controller (estimator in the loop).

A from the slowly increasing steer; sine with dwell at 80 km/h from 1.5 A up to
max(6.5 A, 270 deg), both directions (quick mode: the first two amplitudes at or
above 5 A). Writes ``fmvss126_<controller>.csv`` per controller and
``fmvss126_summary.md``.

Run: ``python -m studies.control_fmvss126 OUT_DIR [--quick]``
"""

from __future__ import annotations

from plants import load_vehicle
from studies._common import cli, out_dir, write_table
from toolkit.fmvss126 import find_a, run_series

CONTROLLERS = ("none", "two-dof")


def main(out, quick: bool = False) -> list[dict]:
    out = out_dir(out)
    p = load_vehicle("compact-ev")
    a_deg = find_a(p)
    summary = []
    for ctl in CONTROLLERS:
        _, rows, verdict = run_series(p, ctl, "dakf", a_deg=a_deg, quick=quick)
        write_table(rows, out / f"fmvss126_{ctl}.csv")
        summary.append({"controller": ctl, "A_deg": a_deg, "runs": len(rows), "runs_passed": sum(r["pass"] for r in rows),
                        "pass": verdict["pass"], "failed_criteria": " ".join(verdict["failed_criteria"]) or "-"})
    write_table(summary, out / "fmvss126_summary.csv", out / "fmvss126_summary.md")
    return summary


if __name__ == "__main__":
    cli(main)

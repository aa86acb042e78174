"""Estimator robustness table on the two-track plant (issue: estimators).

Rows: sine with dwell 80 km/h (3.5 A), ramp steer 60 km/h, ISO 3888-1 60 km/h on
mu 0.5 (compact EV), lane change 25 km/h with a 2 s outage and two bad fixes
(micro EV); each with exact, +40 % and -40 % nominal cornering stiffness; gyro bias
3 mrad/s and 1 % scale error throughout. Writes ``robustness.csv``/``.md`` and
``robustness_table.md`` (sideslip error RMS / max per method, the docs' table).

Run: ``python -m evstab.studies.estimation_robustness OUT_DIR [--quick]``
"""

from __future__ import annotations

from evstab.studies._common import cli, out_dir, pivot, write_markdown, write_table
from evstab.toolkit.verdicts.estimators import robustness_table


def main(out, quick: bool = False) -> list[dict]:
    out = out_dir(out)
    rows = robustness_table(quick=quick)
    write_table(rows, out / "robustness.csv", out / "robustness.md")
    # the docs' table: sideslip error RMS / max [deg], one column per method
    header, table = pivot(rows, ["scenario", "nominal_stiffness"], "method",
                          lambda r: f"{r['beta_rms_deg']:.3f} / {r['beta_max_deg']:.3f}")
    write_markdown(out / "robustness_table.md", header, table)
    return rows


if __name__ == "__main__":
    cli(main)

"""Helpers shared by the study scripts: output folder, tables as CSV and Markdown, figures."""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np

from evstab.toolkit.logs.drivelog import atomic_write


def out_dir(path) -> Path:
    p = Path(path)
    p.mkdir(parents=True, exist_ok=True)
    return p


def write_table(rows: list[dict], path_csv: Path, path_md: Path | None = None, floatfmt: str = "{:.3f}") -> None:
    keys = list(rows[0])

    def w_csv(fh):
        wr = csv.DictWriter(fh, fieldnames=keys)
        wr.writeheader()
        wr.writerows(rows)

    atomic_write(path_csv, w_csv)
    if path_md is not None:
        buf = io.StringIO()
        buf.write("| " + " | ".join(keys) + " |\n|" + "---|" * len(keys) + "\n")
        for r in rows:
            cells = [floatfmt.format(v) if isinstance(v, float) else str(v) for v in r.values()]
            buf.write("| " + " | ".join(cells) + " |\n")
        atomic_write(path_md, lambda fh: fh.write(buf.getvalue()))


def write_markdown(path_md: Path, header: list[str], rows: list[list]) -> None:
    """A Markdown table (``header`` and rows of cells, as text) written atomically: the tables the
    docs pages show (:mod:`evstab.studies.publish`)."""
    lines = ["| " + " | ".join(header) + " |", "| " + " | ".join("---" for _ in header) + " |"]
    lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    atomic_write(path_md, lambda fh: fh.write("\n".join(lines) + "\n"))


def pivot(rows: list[dict], index: list[str], column: str, cell) -> tuple[list[str], list[list]]:
    """``rows`` (long form) as a table: one row per distinct ``index`` values, one column per distinct
    ``column`` value (in order of appearance), ``cell(row)`` the text of each cell."""
    cols = list(dict.fromkeys(r[column] for r in rows))
    keys = list(dict.fromkeys(tuple(r[k] for k in index) for r in rows))
    by = {(tuple(r[k] for k in index), r[column]): r for r in rows}
    table = [list(k) + [cell(by[(k, c)]) if (k, c) in by else "-" for c in cols] for k in keys]
    return list(index) + [str(c) for c in cols], table


def save_figure(fig, path: Path) -> None:
    import matplotlib.pyplot as plt
    atomic_write(path, lambda fh: fig.savefig(fh, format="png", dpi=110), mode="wb")
    plt.close(fig)


def format_row(row: dict) -> str:
    """One console line for a study's result row: ``name value`` pairs, numbers to 4 significant digits."""
    def fmt(v):
        if isinstance(v, (bool, np.bool_)):
            return "yes" if v else "no"
        if isinstance(v, (int, np.integer)):
            return str(int(v))
        if isinstance(v, (float, np.floating)):
            return f"{float(v):.4g}"
        return str(v)
    return "; ".join(f"{k} {fmt(v)}" for k, v in row.items())


def cli(main) -> None:
    """``python -m evstab.studies.NAME OUT_DIR [--quick]``: run a study and print its rows, one line each."""
    import sys
    args = [a for a in sys.argv[1:] if a != "--quick"]
    for row in main(args[0] if args else "out/studies", quick="--quick" in sys.argv):
        print(format_row(row) if isinstance(row, dict) else row)


def seed_003_design(p):
    """Seed 003's controller as the paper runs it: the 2-DOF law always acting above its minimum speed
    (no dead bands), K_beta = K_gamma = 5, its static reference through the lag, with the steer's full range and the motors' torque limit
    only (no superposition limit, no rear-grip limit on the yaw moment, no yaw guard, no rollover
    limit or lateral-acceleration cap on the reference, no slip control, no sideslip phase-plane guard;
    the friction estimate still runs,
    the paper's friction limit uses it)."""
    import numpy as np
    from evstab.controllers.two_dof import TwoDofDesign
    return TwoDofDesign(p.as_nominal(), always_active=True, steer_authority=np.deg2rad(35.0), guard_share=1e6,
                        rear_grip_share=1e6, rollover_share=1e6, ay_headroom=1e6, slip_max=1e6,
                        phase_beta=1e9, reference_model="static")

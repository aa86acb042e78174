"""FMVSS 126 on the CommonRoad multi-body cars with the firmware evstab designs for them.

For ``commonroad-mb:1`` (Ford Escort), ``commonroad-mb:2`` (BMW 320i) and ``commonroad-mb:3`` (VW
Vanagon): the bundled nominal file with every cornering stiffness +40 % (a designer's model that
is wrong), ``evstab design`` on the multi-body car itself (``--plant commonroad-mb:N``, quick
run), and the design folder's ECU (the step ``evstab export`` prints as C) in the loop through the
FMVSS 126 series at 80 km/h on mu 1.0, 0.6 and 0.5, real rear-wheel torques, the friction not
given to the ECU. Beside it the uncontrolled car. Writes ``mb_fmvss126_summary.md``/``.csv`` and the design folders.

Run: ``python -m evstab.studies.control_mb_fmvss126 OUT_DIR [--quick]`` (51 minutes on 2 cores
with four to six other jobs on the machine, most of it the three design jobs; quick, for the test suite: the Escort on mu 1.0 only, with the
default ECU designed from the wrong file instead of a design job's).
"""

from __future__ import annotations

import dataclasses

from evstab.plants import load_vehicle
from evstab.studies._common import cli, out_dir, write_markdown, write_table
from evstab.toolkit.design.design_job import run_design
from evstab.toolkit.firmware.export import ecu_from_design
from evstab.toolkit.verdicts.fmvss126 import find_a, run_series
from evstab.toolkit.logs.drivelog import atomic_write
from evstab.toolkit.loop.loop_ecu import loop_ecu
from evstab.toolkit.design.nominal import to_toml

STIFFNESS_ERROR = 1.4
CARS = (1, 2, 3)
CAR_NAMES = {"commonroad-mb:1": "Escort", "commonroad-mb:2": "BMW 320i", "commonroad-mb:3": "Vanagon"}


def wrong_nominal(n: int):
    """The bundled nominal of set ``n`` with both cornering stiffnesses times :data:`STIFFNESS_ERROR`."""
    p = load_vehicle(f"commonroad-{n}")
    return dataclasses.replace(p, name=f"commonroad-{n}-stiff40",
                               cornering_stiffness_front=STIFFNESS_ERROR * p.cornering_stiffness_front,
                               cornering_stiffness_rear=STIFFNESS_ERROR * p.cornering_stiffness_rear,
                               source=p.source + f" Cornering stiffness x {STIFFNESS_ERROR} (a deliberately wrong model).")


def main(out, quick: bool = False) -> list[dict]:
    out = out_dir(out)
    rows = []
    for n in CARS[:1] if quick else CARS:
        plant = f"commonroad-mb:{n}"
        p = wrong_nominal(n)
        toml = out / f"{p.name}.toml"
        atomic_write(toml, lambda fh: fh.write(to_toml(p, f"commonroad-{n} with +40 % cornering stiffness")))
        if quick:
            ecu = loop_ecu("two-dof", p).ecu
        else:
            design_dir = out / f"design-{n}"
            run_design(str(toml), design_dir, quick=True, plant=plant, progress=False, log=lambda *a: None)
            ecu, _ = ecu_from_design(design_dir)
        for mu in ((1.0,) if quick else (1.0, 0.6, 0.5)):
            a_deg = find_a(p, plant, mu)
            _, none, v_none = run_series(p, "none", plant=plant, mu=mu, a_deg=a_deg)
            _, ctl, v_ctl = run_series(p, "two-dof", ecu.filter.method, plant=plant, mu=mu, a_deg=a_deg, design=ecu)
            harm = sum(1 for a, b in zip(none, ctl) if a["pass"] and not b["pass"])
            for label, rs, v in (("none", none, v_none), ("default ECU" if quick else "designed firmware", ctl, v_ctl)):
                rows.append({"car": plant, "mu": mu, "A_deg": a_deg, "controller": label,
                             "runs_passed": sum(r["pass"] for r in rs), "runs": len(rs), "pass": v["pass"],
                             "failed_criteria": " ".join(v["failed_criteria"]) or "-",
                             "runs_worse_than_none": harm if label != "none" else 0})
    write_table(rows, out / "mb_fmvss126_summary.csv", out / "mb_fmvss126_summary.md")
    write_markdown(out / "mb_fmvss126_table.md", ["car", "mu", "A [deg hand-wheel]", "no control", "designed firmware"],
                   table(rows))
    return rows


def table(rows: list[dict]) -> list[list[str]]:
    """The docs' table: per car and friction, runs passed and verdict without control and with the
    designed firmware (the failed criteria named)."""
    def cell(r):
        verdict = "PASS" if r["pass"] else f"FAIL: {r['failed_criteria']}"
        text = f"{r['runs_passed']} / {r['runs']}, {verdict}"
        return f"**{text}**" if r["pass"] else text

    out = []
    for r in rows:
        if r["controller"] != "none":
            continue
        ctl = next(c for c in rows if c["car"] == r["car"] and c["mu"] == r["mu"] and c["controller"] != "none")
        out.append([f"{r['car']} ({CAR_NAMES.get(r['car'], '')})".replace(" ()", ""), f"{r['mu']:.1f}",
                    f"{r['A_deg']:.1f}", cell(r), cell(ctl)])
    return out


if __name__ == "__main__":
    cli(main)

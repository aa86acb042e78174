"""The limit constraint of the design job: its rules, and the quick design judged through the exported ECU."""

import dataclasses
import json

import numpy as np
import pytest

from evstab.controllers.two_dof import STEER_AUTHORITY, TwoDofDesign
from evstab.plants import load_vehicle
from evstab.toolkit import limits as lm


def _fm(runs, failed):
    return {"kind": "fmvss126", "runs": len(runs), "runs_passed": sum(not f for f in failed), "pass": not any(failed),
            "_runs": [(a, "left", frozenset(f)) for a, f in zip(runs, failed)]}


def test_fmvss_no_worse_is_run_by_run_and_criterion_by_criterion():
    none = _fm([100, 110], [{"yaw_ratio_1_0"}, {"yaw_ratio_1_0", "yaw_ratio_1_75"}])
    # failing a criterion the uncontrolled car fails too is not worse; failing one it meets is
    assert lm.no_worse(_fm([100, 110], [{"yaw_ratio_1_0"}, set()]), none)[0]
    ok, why = lm.no_worse(_fm([100, 110], [set(), {"lateral_displacement"}]), none)
    assert not ok and "lateral_displacement failed in 1 of 2 runs (110-110 deg" in why


def test_sideslip_bound_follows_the_uncontrolled_car():
    row = lambda peak: {"kind": "iso3888-1", "peak_beta_deg": peak, "spun": not peak < lm.SPIN_DEG}
    # uncontrolled 1.0 deg: the bound is the 3 deg floor; uncontrolled 4 deg: 1.5 x 4 = 6 deg
    assert lm.no_worse(row(3.0), row(1.0))[0] and not lm.no_worse(row(3.01), row(1.0))[0]
    assert lm.no_worse(row(6.0), row(4.0))[0] and not lm.no_worse(row(6.01), row(4.0))[0]
    # the uncontrolled car slides: anything that holds the car is no worse, a bigger slide is
    assert lm.no_worse(row(9.0), row(60.0))[0] and not lm.no_worse(row(70.0), row(60.0))[0]
    assert not lm.no_worse(row(float("inf")), row(1.0))[0]  # lost (rolled over / diverged)


def test_compare_needs_the_stated_margin():
    from evstab.toolkit.design_job import BETTER_MARGIN, compare
    rows = [{"design": d, "case_id": 0, "cost": c, "stable": True} for d, c in (("paper", 10.0), ("tuned", 9.6))]
    s = compare(rows)
    assert BETTER_MARGIN == 0.05 and not s["tuned_strictly_better_worst_case"]  # 4 % better: not better
    rows[1]["cost"] = 9.4
    assert compare(rows)["tuned_strictly_better_worst_case"]


def test_steer_authority_comes_from_the_vehicle_file():
    p = load_vehicle("compact-ev")
    assert p.steer_authority is None and TwoDofDesign(p).steer_authority == STEER_AUTHORITY
    q = dataclasses.replace(p, steer_authority=np.deg2rad(5.0), steer_authority_rate=np.deg2rad(40.0))
    d = TwoDofDesign(q)
    assert d.steer_authority == np.deg2rad(5.0) and d.steer_authority_rate == np.deg2rad(40.0)
    from evstab.toolkit.estimation import design_filter
    from evstab.toolkit.firmware.ecu import EcuDesign
    cal = {c.name: c.value for c in EcuDesign.from_designs(design_filter("dakf", q, control=True), d).calibration()}
    assert cal["steer_authority"] == np.deg2rad(5.0) and cal["steer_authority_rate"] == np.deg2rad(40.0)
    with pytest.raises(ValueError, match="steer_authority"):
        dataclasses.replace(p, steer_authority=-0.1)


@pytest.fixture(scope="module")
def design_dir(quick_design_dir):
    return quick_design_dir


def test_quick_design_passes_fmvss_and_is_no_worse_than_no_control(design_dir):
    from evstab.toolkit.design_job import read_csv
    doc = json.loads((design_dir / "design.json").read_text())
    rows = read_csv(design_dir / "limits.csv")
    lim = doc["sweep"]["limits"]
    assert lim["tuned"]["no_worse_than_no_control"] and lim["tuned"]["fmvss126_pass"]
    assert {r["mu"] for r in rows if r["kind"] == "fmvss126" and r["design"] == "tuned" and r["pass"]} == {1.0, 0.6}
    # the tuned design is the candidate, or a point the selection accepted, or the paper design, said so
    sel = doc["tuning"]["limit_selection"]
    if doc["sweep"]["tuned_is_paper"]:
        assert not any(t["accepted"] for t in sel)
    else:
        best = max((t for t in sel if t["accepted"]), key=lambda t: t["step"])
        assert best["k_beta"] == doc["designs"]["tuned"]["k_beta"]


def test_limits_csv_reproduces_through_the_exported_ecu(design_dir):
    # the same FMVSS 126 series on mu 0.6, with the ECU as `evstab export` makes it from the folder
    # (schedule tables, calibration from design.json) instead of the design objects: same verdicts
    from evstab.toolkit.design_job import read_csv
    from evstab.toolkit.firmware.export import ecu_from_design
    from evstab.toolkit.fmvss126 import run_series
    ecu, _ = ecu_from_design(design_dir)
    row = next(r for r in read_csv(design_dir / "limits.csv")
               if r["kind"] == "fmvss126" and r["design"] == "tuned" and r["mu"] == 0.6)
    p = load_vehicle("compact-ev")
    _, runs, verdict = run_series(p, "two-dof", ecu.filter.method, mu=0.6, a_deg=row["A_deg"], design=ecu)
    assert sum(r["pass"] for r in runs) == row["runs_passed"] and verdict["pass"] == row["pass"]

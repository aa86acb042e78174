"""Nominal vehicle files of the CommonRoad multi-body cars (evstab derive-nominal)."""

import json

import numpy as np
import pytest

from evstab.plants import commonroad_mb as mb, load_vehicle
from evstab.plants.maneuvers import step_steer
from evstab.toolkit.cli import main
from evstab.toolkit.loop.simulator import simulate


@pytest.mark.parametrize("set_id", (1, 2, 3))
def test_bundled_geometry_is_the_set(set_id):
    """Masses, inertias and geometry exactly (bit for bit) from the package's set; roll inertia by the
    parallel-axis theorem; the stated assumptions as stated."""
    P = mb.package_parameters(set_id)
    p = load_vehicle(f"commonroad-{set_id}")
    for ours, theirs in (("mass", "m"), ("yaw_inertia", "I_z"), ("lf", "a"), ("lr", "b"), ("sprung_mass", "m_s"),
                         ("cg_height", "h_cg"), ("track_front", "T_f"), ("track_rear", "T_r"), ("width", "w"),
                         ("wheel_radius", "R_w"), ("wheel_inertia", "I_y_w")):
        assert getattr(p, ours) == float(getattr(P, theirs)), ours
    h = P.h_s - (P.h_raf + (P.h_rar - P.h_raf) * P.a / (P.a + P.b))
    assert p.roll_arm == h
    assert p.roll_inertia == pytest.approx(P.I_Phi_s + P.m_s * h * h, rel=1e-15)
    assert p.roll_inertia > p.sprung_mass * p.roll_arm ** 2  # possible by the parallel-axis theorem
    assert p.steering_ratio == 16.0
    assert "derive-nominal" in p.source and "Assumptions" in p.source


def test_derive_nominal_cli_reproduces_the_bundled_file(tmp_path):
    """The command writes what is bundled (the fit is deterministic; 1e-6 allows for a different
    BLAS reordering sums in least_squares)."""
    out = tmp_path / "cr1.toml"
    assert main(["derive-nominal", "commonroad-mb:1", "--out", str(out)]) == 0
    ours, bundled = load_vehicle(str(out)), load_vehicle("commonroad-1")
    assert ours.mass == bundled.mass and ours.roll_inertia == bundled.roll_inertia
    assert ours.cornering_stiffness_front == pytest.approx(bundled.cornering_stiffness_front, rel=1e-6)
    assert ours.cornering_stiffness_rear == pytest.approx(bundled.cornering_stiffness_rear, rel=1e-6)
    assert not list(tmp_path.glob("*.tmp"))
    assert main(["derive-nominal", "two-track", "--out", str(tmp_path / "x.toml")]) == 2
    assert not (tmp_path / "x.toml").exists()


@pytest.mark.parametrize("set_id", (1, 3))
def test_identified_stiffness_predicts_the_steady_yaw_rate(set_id):
    """The bicycle with the identified stiffness reaches the multi-body car's steady yaw rate at 60 km/h
    for 1 m/s^2 within 1.5 % (measured: -0.9 % set 1, -0.1 % set 3), the closed form
    r / delta = v / (L (1 + G v^2)) of seed 003 eq. 24."""
    p = load_vehicle(f"commonroad-{set_id}")
    v = 60 / 3.6
    delta = p.wheelbase / v ** 2
    r = simulate(p, f"commonroad-mb:{set_id}", step_steer(v, delta, start=0.5, duration=4.0))
    mb_r = float(np.mean(r.truth["yaw_rate"][-300:]))
    bic = v / (p.wheelbase * (1 + p.stability_factor * v * v)) * delta
    assert bic == pytest.approx(mb_r, rel=0.015)


def test_fmvss126_on_the_multibody_car(tmp_path):
    """The FMVSS 126 procedure runs on commonroad-mb:1 (A from the slowly increasing steer, the series);
    at mu 1 the uncontrolled Escort rolls over at 5 A and above (its tyres gain grip with camber), and the
    verdict says so."""
    out = tmp_path / "fm"
    assert main(["fmvss126", "--plant", "commonroad-mb:1", "--vehicle", "commonroad-1", "--controller", "none",
                 "--quick", "--out", str(out)]) == 0
    verdict = json.loads((out / "verdict.json").read_text())
    assert verdict["pass"] is False and verdict["failed_criteria"] == ["rollover"]
    assert 14.0 < verdict["A_deg"] < 18.0  # measured 16.0 deg hand-wheel (1.0 deg road wheel)
    rows = (out / "fmvss126.csv").read_text().splitlines()[1:]
    assert len(rows) == 4 and all(r.split(",")[5] == "false" and r.split(",")[6] != "nan" for r in rows)

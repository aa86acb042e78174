"""Loop margins: the frequency response and disk margin against python-control and closed forms, and
the design job's margin constraint at its boundaries."""

import control
import numpy as np
import pytest

from evstab.controllers.two_dof import TwoDofDesign
from evstab.plants import load_vehicle
from evstab.toolkit.design import stability as st

OMEGA = np.logspace(-2, 3, 1500)


def test_frequency_response_equals_python_controls():
    # a 3-state loop with a resonance: python-control's evaluation of the same system, to rounding
    sys = control.ss(control.tf([2.0, 1.0], [1.0, 0.4, 9.0, 0.0]))
    ref = np.squeeze(sys(1j * OMEGA))
    assert np.max(np.abs(st.frequency_response(sys, OMEGA) - ref) / np.abs(ref)) < 1e-10
    assert st.frequency_response(control.ss([], [], [], [[3.0]]), OMEGA[:3]) == pytest.approx([3.0] * 3)


@pytest.mark.parametrize("num, den, expected", [
    ([5.0], [1.0, 0.0], 2.0),           # k / s: S - 1/2 = (s - k) / (2 (s + k)) is all-pass, |.| = 1/2
    ([3.0], [1.0], 4.0),                # k = 3: S = 1/4, 1 / |1/4 - 1/2| = 4 = 2 (1 + k) / |1 - k|
    ([1.0], [1.0, 1.0, 0.0], None),     # 1 / (s (s + 1)): python-control's value
])
def test_disk_margin_closed_forms_and_python_control(num, den, expected):
    L = control.ss(control.tf(num, den))
    dm = st.disk_margin(st.frequency_response(L, OMEGA))
    ref = float(np.min(np.asarray(control.disk_margins(L, OMEGA, skew=0.0)[0]).ravel()))
    assert dm == pytest.approx(ref, rel=1e-9)
    if expected is not None:
        assert dm == pytest.approx(expected, rel=1e-9)


def test_the_paper_design_on_its_own_model_has_integrator_margins():
    # seed 003's law inverts the nominal model exactly: each loop is K / s, so disk margin 2,
    # sensitivity peak 1 and phase margin 90 deg at every speed (to the grid's resolution)
    p = load_vehicle("compact-ev")
    m = st.robust_margins(TwoDofDesign(p), [("nominal", p)], (20.0, 80.0, 140.0))
    assert m.disk_margin == pytest.approx(2.0, abs=1e-6) and m.sensitivity_peak == pytest.approx(1.0, abs=1e-3)
    assert m.pm_delta_deg == pytest.approx(90.0, abs=1e-6) and m.gm_delta_db == float("inf")


def _m(dm=1.0, sp=1.5):
    return st.RobustMargins(dm, sp, 10.0, 60.0, 10.0, 60.0, "here", "here")


@pytest.mark.parametrize("dm, ok", [(0.49, False), (0.5, True), (0.51, True)])
def test_constraint_disk_margin_at_least_one_half(dm, ok):
    assert (not st.margins_admissible(_m(dm=dm))) == ok


@pytest.mark.parametrize("sp, ok", [(1.99, True), (2.0, True), (2.01, False)])
def test_constraint_sensitivity_peak_at_most_two(sp, ok):
    assert (not st.margins_admissible(_m(sp=sp))) == ok


def test_loop_margins_equal_the_python_control_loop():
    # the tuning's numpy margins against channel_margins on python-control's interconnection, on the
    # design's own model and with +-30 % stiffness errors, at low and high speed, for the paper gains
    # and a far point: equal to rounding (1e-14 measured; 1e-9 allows a different BLAS)
    import dataclasses
    p = load_vehicle("compact-ev")
    wrong = dataclasses.replace(p, cornering_stiffness_front=0.7 * p.cornering_stiffness_front,
                                cornering_stiffness_rear=1.3 * p.cornering_stiffness_rear)
    for d in (TwoDofDesign(p), TwoDofDesign(p, k_beta=1.2, k_gamma=6.3)):
        for q in (p, wrong):
            for kmh in (20.0, 140.0):
                loop, _ = st.nominal_loop(d, kmh / 3.6, q)
                ms = st.channel_margins(loop)
                dm, sp = st.loop_margins(d, q, kmh / 3.6)
                assert dm == pytest.approx(min(m.disk_margin for m in ms), rel=1e-9)
                assert sp == pytest.approx(max(m.sensitivity_peak for m in ms), rel=1e-9)


def test_the_tunings_margin_floors():
    # rows: disk margin and -sensitivity peak on the design's own model. A start within the bounds is
    # held to the bounds (0.5, 2); a start beyond them to itself (else its first point is infeasible)
    from evstab.toolkit.design.tuning import margin_floors
    assert margin_floors(np.array([2.0, -1.0])) == pytest.approx([0.5, -2.0], abs=1e-8)
    assert margin_floors(np.array([0.4, -2.5])) == pytest.approx([0.4, -2.5], abs=1e-8)


def test_the_tunings_margin_values_are_the_loop_margins():
    # what IPOPT is given: the least disk margin and the largest peak over the speeds on the nominal model
    from evstab.toolkit.design.sweep import DesignPoint, SweepConfig
    from evstab.toolkit.design.tuning import MarginConstraint, margin_values, phi_of
    p = load_vehicle("compact-ev")
    cfg = SweepConfig(p)
    pt = DesignPoint("x", k_beta=1.2, k_gamma=6.3)
    speeds = (20.0, 80.0, 140.0)
    got = margin_values(cfg, phi_of(pt), MarginConstraint(speeds))
    ms = st.robust_margins(pt.controller(cfg.base_design()), [("own", p)], speeds)
    assert got == pytest.approx([ms.disk_margin, -ms.sensitivity_peak], rel=1e-9)

"""Loop margins: the frequency response and disk margin against python-control and closed forms, and
the design job's margin constraint at its boundaries."""

import control
import numpy as np
import pytest

from evstab.controllers.two_dof import TwoDofDesign
from evstab.plants import load_vehicle
from evstab.toolkit import stability as st

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
    assert (not st.margins_admissible(_m(dm=dm), _m(), _m())) == ok


@pytest.mark.parametrize("sp, ok", [(1.99, True), (2.0, True), (2.01, False)])
def test_constraint_sensitivity_peak_at_most_two(sp, ok):
    assert (not st.margins_admissible(_m(sp=sp), _m(), _m())) == ok


def test_constraint_across_model_errors_is_the_paper_designs_or_the_bounds():
    # where the paper design is worse than the bounds across the model errors, the tuned design may be
    # as bad as it and no worse; where it is better, the bounds apply
    assert not st.margins_admissible(_m(), _m(dm=0.30, sp=4.0), _m(dm=0.30, sp=4.0))
    assert st.margins_admissible(_m(), _m(dm=0.29, sp=4.0), _m(dm=0.30, sp=4.0))
    assert st.margins_admissible(_m(), _m(dm=0.30, sp=4.01), _m(dm=0.30, sp=4.0))
    assert not st.margins_admissible(_m(), _m(dm=0.51, sp=1.99), _m(dm=1.5, sp=1.2))
    assert st.margins_admissible(_m(), _m(dm=0.49, sp=1.99), _m(dm=1.5, sp=1.2))
    assert st.margins_admissible(_m(), _m(dm=0.51, sp=2.01), _m(dm=1.5, sp=1.2))

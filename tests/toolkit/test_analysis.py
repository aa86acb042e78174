"""Speed-grid design analysis: a tidy table whose entries agree with the single analyses."""

import numpy as np
import pytest

from evstab.controllers.two_dof import TwoDofDesign
from evstab.plants import load_vehicle
from evstab.toolkit.design.analysis import estimator_periodic_poles, speed_grid
from evstab.toolkit.estimation import design_filter


def test_speed_grid_rows():
    p = load_vehicle("compact-ev")
    rows = speed_grid(p, design_filter("dakf", p, control=True), TwoDofDesign(p.as_nominal()), speeds_kmh=(20.0, 100.0))
    assert [r["speed_kmh"] for r in rows] == [20.0, 100.0]
    for r in rows:
        assert r["observable"] and r["observability_rank"] == 6 and r["unobservable"] == "-"
        assert r["internally_stable"] and r["multirate_stable"]
        assert r["estimator_slowest_rate_1_s"] < 0
        # equal model-following poles: every channel sees K/s, disk margin 2 (closed form)
        assert r["disk_margin_min"] == pytest.approx(2.0, rel=1e-4)
    paper = speed_grid(p, design_filter("dakf-paper", p), TwoDofDesign(p.as_nominal()), speeds_kmh=(50.0,))[0]
    assert not paper["observable"] and paper["unobservable"].startswith("beta=1 yaw=-1 d1=")
    assert paper["riccati"] == "no stabilising solution" and not paper["multirate_stable"]


def test_estimator_periodic_poles_single_rate_equal_dare_poles():
    # With a fix on every sample (gps_rate = 1 / dt) the monodromy is one sample of the
    # steady-state filter: its poles are those of F (I - K C) with the DARE gain.
    from evstab.toolkit.estimation.analysis import discrete_model, steady_state_gain
    p = load_vehicle("compact-ev")
    d = design_filter("kf-bias", p)
    v, dt = 20.0, 1e-3
    rates = estimator_periodic_poles(d, v, 1.0 / dt, dt)
    K, _ = steady_state_gain(d, v, dt)
    F, _, C, _ = discrete_model(d, v, dt)
    lam = np.linalg.eigvals(F @ (np.eye(d.n) - K @ C))
    # two Riccati solvers (lifted DARE with r = 1 vs plain DARE): 1e-6 relative
    np.testing.assert_allclose(np.sort(np.real(rates)), np.sort(np.real(np.log(lam.astype(complex)) / dt)),
                               rtol=1e-6)

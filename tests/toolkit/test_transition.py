"""The ECU filter's transition table (toolkit.estimation.transition) against scipy's matrix
exponential and against the Taylor step it replaces."""

import numpy as np
import pytest
import scipy.linalg

from evstab.controllers.two_dof import TwoDofDesign
from evstab.plants import G, load_vehicle
from evstab.plants.backend import NUMPY
from evstab.plants.disturbances import Disturbances, Friction, default_wind
from evstab.plants.maneuvers import sine_with_dwell, steer_for_lateral_acceleration
from evstab.toolkit.kernels.compiled import with_fields
from evstab.toolkit.estimation import design_filter
from evstab.toolkit.estimation.kalman import discretize_delta
from evstab.toolkit.estimation.spec import continuous_model
from evstab.toolkit.estimation.transition import exact_discretisation
from evstab.toolkit.ecu.step import INPUTS, OUTPUTS, EcuDesign, ecu_step
from evstab.toolkit.firmware.replay import ecu_inputs
from evstab.toolkit.loop.simulator import simulate


def _ecu(name="compact-ev", method="dakf"):
    p = load_vehicle(name)
    return p, EcuDesign.from_designs(design_filter(method, p, control=True), TwoDofDesign(p.as_nominal()))


def _zoh(A, B, dt):
    """scipy: e^([[A, B], [0, 0]] dt) holds e^(A dt) and int_0^dt e^(A s) ds B."""
    n, m = B.shape
    X = scipy.linalg.expm(np.block([[A, B], [np.zeros((m, n + m))]]) * dt)
    return X[:n, :n] - np.eye(n), X[:n, n:]


@pytest.mark.parametrize("name,method", [("compact-ev", "dakf"), ("micro-ev", "dakf"), ("compact-ev", "kf-bias")])
def test_grid_points_are_the_exact_zero_order_hold(name, method):
    _, d = _ecu(name, method)
    f, tr = d.filter, d.filter.transition
    ne = len(tr.e_entries)
    for k, x in enumerate(tr.table.inv_speed):
        A, B = continuous_model(f, 1.0 / x, NUMPY)
        E, Gm = _zoh(A, B, f.dt_nominal)
        got_e = np.zeros_like(E)
        got_g = np.zeros_like(Gm)
        for r, (i, j) in enumerate(tr.e_entries):
            got_e[i, j] = tr.table.table[r][k]
        for r, (i, c) in enumerate(tr.g_entries):
            got_g[i, c] = tr.table.table[ne + r][k]
        # every entry the table leaves out is zero, and the rest is expm's to rounding (measured 9e-15
        # of the largest entry; the series' remainder after 30 terms is below 1e-40)
        np.testing.assert_allclose(got_e, E, rtol=0, atol=1e-13 * np.abs(E).max())
        np.testing.assert_allclose(got_g, Gm, rtol=0, atol=1e-13 * np.abs(Gm).max())


def test_between_grid_points_the_table_follows_the_taylor_step():
    """Linear interpolation in 1/v of E and G against the Taylor series of the interpolated model:
    measured 1.2e-4 (E) and 6.7e-5 (G) of the largest entry on compact-ev over 2..70 m/s. The
    bound 5e-4 is the schedule's own accuracy class (its coefficients carry up to 4e-3)."""
    _, d = _ecu()
    f, tr = d.filter, d.filter.transition
    for v in np.geomspace(2.0, 70.0, 700):
        E1, G1 = tr.matrices(v, f.dt_nominal, 1.0)
        A, B = continuous_model(f, v, NUMPY)
        E2, Gam = discretize_delta(A, f.dt_nominal, NUMPY, f.n)
        assert np.abs(E1 - E2).max() <= 5e-4 * np.abs(E2).max()
        assert np.abs(G1 - Gam @ B).max() <= 5e-4 * np.abs(Gam @ B).max()


def test_held_model_and_other_periods():
    _, d = _ecu()
    f, tr = d.filter, d.filter.transition
    # below the minimum speed only psi' = r is left: E has the one entry dt, no input acts
    A0, B0 = continuous_model(f, 1.0, NUMPY, dynamic=False)
    E0, G0 = exact_discretisation(A0, B0, 2e-3)
    E, Gm = tr.matrices(1.0, 2e-3, 0.0)
    np.testing.assert_array_equal(E, E0)  # both exactly 2e-3 at (yaw, yaw rate) and 0 elsewhere
    np.testing.assert_array_equal(Gm, G0)
    # another period scales the control period's entries (first order in dt / T - 1): at 1.01 T the
    # difference to the exact discretisation is at most |dt / T - 1| |A T|^2 / 2 of an entry
    v = 25.0
    A, B = continuous_model(f, v, NUMPY)
    T = f.dt_nominal
    E1, _ = tr.matrices(v, 1.01 * T, 1.0)
    Ex, _ = exact_discretisation(A, B, 1.01 * T)
    E_at, _ = tr.matrices(v, T, 1.0)
    bound = 0.01 * np.abs(A * T).sum(axis=1).max() ** 2 / 2 + 2e-4 * np.abs(E_at).max()  # + the interpolation
    assert np.abs(E1 - Ex).max() <= bound


def test_a_closed_loop_log_through_the_tabulated_and_the_taylor_ecu():
    """The ECU step with the table against the same step re-discretising by Taylor series every period,
    over a closed-loop sine with dwell (80 km/h, 5 A, side wind, mu 0.8): measured differences
    2.7e-5 rad in sideslip, 2.3e-5 rad in steer and 3.4 N m in yaw moment (of 1,712 N m). The filters part by
    1e-6 rad 1.05 s into the manoeuvre; the law's own yaw-moment limit flag then switches a period apart
    twice, which moves the commands by more than the estimates' difference alone."""
    p, d = _ecu()
    taylor = with_fields(d, filter=with_fields(d.filter, transition=None))
    a = steer_for_lateral_acceleration(p, 80 / 3.6, 0.3 * G)
    res = simulate(p, "two-track", sine_with_dwell(80 / 3.6, 5 * a, start=1.0), seed=3, controller="two-dof",
                   design=d, disturbances=Disturbances(wind=default_wind(p), friction=Friction(mu=0.8)))
    U = ecu_inputs(res.log_columns(), 0.8, 1e-3, d.wheel_radius)
    fix = U[:, INPUTS.index("gps_valid")] > 0.5
    Ys = []
    for e in (d, taylor):
        z, Y = e.initial_state(), np.empty((len(U), OUTPUTS.size))
        for k in range(len(U)):
            z, Y[k] = ecu_step(e, z, U[k], None, NUMPY, with_course=bool(fix[k]))
        Ys.append(Y)
    diff = {s: np.abs(Ys[0][:, OUTPUTS.index(s)] - Ys[1][:, OUTPUTS.index(s)]).max() for s in OUTPUTS}
    peak_nz = np.abs(Ys[1][:, OUTPUTS.index("yaw_moment_cmd")]).max()
    assert peak_nz > 500.0  # the controller worked
    # the documented bounds (docs/firmware.md): 1e-4 rad (0.006 deg) of sideslip and steer, 5e-3 of the
    # yaw-moment peak: the table's own error (1.2e-4 of E's largest entry, above) through a switching law; measured
    # about 4x and 2.5x below
    assert diff["beta"] <= 1e-4 and diff["steer_cmd"] <= 1e-4
    assert diff["yaw_moment_cmd"] <= 5e-3 * peak_nz


def test_the_kinematic_path_on_the_table_blends_to_first_order():
    """A filter with the kinematic sideslip path on the ECU: the table also holds the model's sideslip
    row (continuous, what the path compares the accelerometer with), and the blend on E and G is the
    exact discretisation of the blended model up to second-order terms in the period."""
    from evstab.toolkit.estimation import kinematic_path
    p = load_vehicle("compact-ev")
    d = EcuDesign.from_designs(design_filter("dakf", p, control=True, kinematic=True), TwoDofDesign(p.as_nominal()))
    f, tr = d.filter, d.filter.transition
    ib, ir = f.index("beta"), f.index("yaw_rate")
    T = f.dt_nominal
    for k, x in enumerate(tr.table.inv_speed[::7]):
        A, B = continuous_model(f, 1.0 / x, NUMPY)
        a, b = tr.continuous(tr.table.values(1.0 / x), 1.0)
        for (i, j), val in a.items():  # the grid point's value to the interpolation's rounding
            assert i == ib and abs(val - A[i, j]) <= 1e-12 * max(1.0, abs(A[i, j]))
        assert set(a) == {(ib, j) for j in np.nonzero(A[ib])[0]} and set(b) == {(ib, c) for c in np.nonzero(B[ib])[0]}
    v = 20.0
    A, B = continuous_model(f, v, NUMPY)
    E, Gu = tr.matrices(v, T, 1.0)
    aT = np.abs(A * T).sum(axis=1).max()  # |A T| (infinity norm), 0.03 here
    for w in (0.0, 0.3, 1.0):
        Eb, Gb = kinematic_path.transition(f, E, Gu, w, T, NUMPY)
        Ab, Bb = A.copy(), B.copy()
        Ab[[ib, ir]] *= 1.0 - w
        Bb[[ib, ir]] *= 1.0 - w
        Ab[ib, ir] -= w
        Ex, Gx = exact_discretisation(Ab, Bb, T)
        if w == 0.0:
            np.testing.assert_array_equal(Eb, E)  # the path off: the table itself
        # E ~ A T: the blend differs by (A T)^2 terms; G ~ B T: by terms of |A T| relative (measured
        # at w 0.3: 3.4e-5 in E against a bound of 9.3e-4, 7.2e-4 of G's largest entry); + the table's
        # interpolation. At w 1 the model's rows are gone and the kinematics are exact (measured 0).
        scale = 1e-12 if w == 1.0 else 1.0
        assert np.abs(Eb - Ex).max() <= scale * aT ** 2 + 1e-4 * np.abs(Ex).max()
        assert np.abs(Gb - Gx).max() <= scale * (aT + 1e-4) * np.abs(Gu).max()

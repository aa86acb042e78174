"""Linear bicycle: closed forms of seed 003, ZOH invariants, python-control cross-checks."""

import casadi as ca
import control
import numpy as np
import pytest
import scipy.linalg
import scipy.signal

from evstab.plants import COMMANDS, DISTURBANCES, ModelError, bicycle, default_disturbance, get_plant, load_vehicle
from evstab.plants.lti import ContinuousLTI

SPEEDS = (5.0, 15.0, 30.0)


@pytest.mark.parametrize("vx", SPEEDS)
def test_steady_state_gains_match_seed_003_eq_23_24(vehicle, vx):
    lti = bicycle.matrices(vehicle, vx)
    A2, B2 = lti.A[:2, :2], lti.B[:2, :1]
    dc = -np.linalg.solve(A2, B2).ravel()  # steady state of (beta, r) per unit steer
    beta, r = bicycle.steady_state_gains(vehicle, vx)
    # Two algebraically identical expressions: agreement to rounding (1e-12 relative).
    assert dc[1] == pytest.approx(r, rel=1e-12)
    assert dc[0] == pytest.approx(beta, rel=1e-10, abs=1e-14)
    # Independent textbook form of the yaw gain: v / (L + K_us v^2).
    assert r == pytest.approx(vx / (vehicle.wheelbase + vehicle.understeer_gradient * vx**2), rel=1e-12)


def test_understeer_gradient_from_steady_state(vehicle):
    # delta = L/R + K_us a_y in steady state (Gillespie); evaluate with the model's own steady state.
    vx, delta = 20.0, 0.01
    _, r = bicycle.steady_state_gains(vehicle, vx)
    yaw_rate = r * delta
    radius, ay = vx / yaw_rate, vx * yaw_rate
    kus = (delta - vehicle.wheelbase / radius) / ay
    assert kus == pytest.approx(vehicle.understeer_gradient, rel=1e-10)  # rounding only


def test_matrix_entries_seed_003_with_004_correction():
    p = load_vehicle("micro-ev").as_nominal()
    vx = 25 / 3.6
    A = bicycle.matrices(p, vx).A
    m, iz, lf, lr, c = p.mass, p.yaw_inertia, p.lf, p.lr, 10000.0
    # a_n11 = -2 (C_f + C_r) / (M v_x)  (seed 004 eq. 38; seed 003 eq. 10 misprints it)
    assert A[0, 0] == pytest.approx(-2 * (c + c) / (m * vx), rel=1e-14)
    assert A[0, 1] == pytest.approx(-1 - 2 * (c * lf - c * lr) / (m * vx**2), rel=1e-14)
    assert A[1, 0] == pytest.approx(-2 * (c * lf - c * lr) / iz, rel=1e-14)
    assert A[1, 1] == pytest.approx(-2 * (c * lf**2 + c * lr**2) / (iz * vx), rel=1e-14)


@pytest.mark.parametrize("vx", SPEEDS)
def test_jacobian_of_f_equals_matrices(vehicle, vx):
    model = get_plant("bicycle")
    lin = model.linearize(vehicle, np.zeros(5), np.array([0.0, 0.0, vx]))
    lti = bicycle.matrices(vehicle, vx)
    # lateral states (beta, r, yaw) -> first three states; inputs steer, N_z, F_d, N_d
    iu = [0, 1, 3 + DISTURBANCES.index("lateral_force"), 3 + DISTURBANCES.index("yaw_moment_dist")]
    np.testing.assert_allclose(lin.A[:3, :3], lti.A, rtol=1e-12, atol=1e-12)  # AD is exact
    np.testing.assert_allclose(lin.B[:3, iu], lti.B, rtol=1e-12, atol=1e-12)


def test_zoh_reproduces_continuous_step_response(compact):
    lti = bicycle.matrices(compact, 20.0).select(inputs=["steer"], outputs=["beta", "yaw_rate"])
    dt = 0.01
    d = lti.discretize(dt)
    assert d.dt == dt and d.method == "zoh"
    n = 300
    # discrete step response by recursion
    x = np.zeros(3)
    yd = []
    for _ in range(n):
        yd.append(d.C @ x)
        x = d.A @ x + d.B[:, 0]
    yd = np.array(yd)
    # continuous step response at the same instants (scipy, independent integrator: expm per sample)
    t = np.arange(n) * dt
    _, yc, _ = scipy.signal.lsim((lti.A, lti.B, lti.C, lti.D), np.ones(n), t, interp=False)
    # ZOH is exact for piecewise-constant inputs: only rounding differs.
    np.testing.assert_allclose(yd, yc, rtol=1e-9, atol=1e-12)


def test_zoh_closed_form_identity():
    # scipy.signal's own test: ZOH of A = I, B = 0 over 0.5 s is e^0.5 I.
    lti = ContinuousLTI(A=np.eye(2), B=np.zeros((2, 1)), C=np.eye(2), D=np.zeros((2, 1)),
                        states=("a", "b"), inputs=("u",), outputs=("a", "b"))
    np.testing.assert_allclose(lti.discretize(0.5).A, np.exp(0.5) * np.eye(2), rtol=1e-14)


def test_discrete_matches_python_control_c2d(compact):
    lti = bicycle.matrices(compact, 25.0)
    ours = lti.discretize(1e-3)
    ref = control.c2d(lti.to_control(), 1e-3, method="zoh")
    np.testing.assert_allclose(ours.A, ref.A, rtol=1e-12, atol=1e-15)  # both expm-based
    np.testing.assert_allclose(ours.B, ref.B, rtol=1e-12, atol=1e-15)


def test_discrete_type_remembers_and_refuses():
    lti = bicycle.matrices(load_vehicle("compact-ev"), 20.0)
    d = lti.discretize(0.001)
    with pytest.raises(ModelError, match="already discrete"):
        d.discretize(0.001)
    with pytest.raises(ModelError, match="I know: 'zoh'"):
        lti.discretize(0.001, method="tustin-typo")
    sys = d.to_control()
    assert sys.dt == 0.001


def test_to_control_keeps_names(compact):
    sys = bicycle.matrices(compact, 20.0).to_control("bike")
    assert sys.input_labels == ["steer", "yaw_moment", "lateral_force", "yaw_moment_dist"]
    assert sys.output_labels == ["beta", "yaw_rate", "yaw", "course", "ay"]
    assert sys.state_labels == ["beta", "yaw_rate", "yaw"]
    # python-control's DC gain of steer -> yaw rate equals the closed form (the yaw
    # integrator is unobservable from yaw rate; minreal removes it first)
    g = control.dcgain(control.tf(sys[1, 0]).minreal())
    assert g == pytest.approx(bicycle.steady_state_gains(compact, 20.0)[1], rel=1e-10)


def test_ay_output_equals_vx_times_course_rate(compact):
    lti = bicycle.matrices(compact, 20.0)
    # ay = vx (beta' + r) = vx * d(course)/dt: rows agree for any x, u
    x, u = np.array([0.01, 0.1, 0.0]), np.array([0.02, 300.0, 50.0, -20.0])
    xdot = lti.A @ x + lti.B @ u
    ay = lti.C[4] @ x + lti.D[4] @ u
    assert ay == pytest.approx(20.0 * (xdot[0] + x[1]), rel=1e-13)


def test_select_unknown_name():
    lti = bicycle.matrices(load_vehicle("compact-ev"), 20.0)
    with pytest.raises(ModelError, match="no input named 'throttle'"):
        lti.select(inputs=["throttle"])


def test_positive_speed_required():
    with pytest.raises(ValueError, match="positive speed"):
        bicycle.matrices(load_vehicle("compact-ev"), 0.0)


@pytest.mark.parametrize("plant", ["bicycle", "bicycle-roll", "two-track", "commonroad-mb:1"])
def test_numpy_and_casadi_agree(vehicle, plant, rng):
    model = get_plant(plant)
    nx, nu = len(model.states), len(model.inputs)
    xs, us, ws = ca.SX.sym("x", nx), ca.SX.sym("u", nu), ca.SX.sym("w", len(DISTURBANCES))
    F = ca.Function("f", [xs, us, ws], [model.f(xs, us, ws, vehicle), model.h(xs, us, ws, vehicle)])
    for _ in range(20):
        x = model.initial_state(vehicle, 15.0) + 0.05 * rng.standard_normal(nx)
        u = model.command_map(COMMANDS.pack(steer=0.05 * rng.standard_normal(), yaw_moment=200 * rng.standard_normal(),
                                            speed_ref=15.0, drive_on=1.0, steer_rate=0.1 * rng.standard_normal(),
                                            brake_fl=300 * rng.random(), brake_rr=300 * rng.random()), x, vehicle)
        w = default_disturbance(0.8) + np.r_[100 * rng.standard_normal(3), 0.02 * rng.standard_normal(), 0, 0, 0, 0]
        fx, hx = F(x, u, w)
        # same expression evaluated two ways: only floating-point rounding differs
        np.testing.assert_allclose(np.array(fx).ravel(), model.f(x, u, w, vehicle), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(np.array(hx).ravel(), model.h(x, u, w, vehicle), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("plant", ["bicycle", "bicycle-roll", "two-track", "commonroad-mb:1"])
def test_batched_numpy_evaluation(compact, plant, rng):
    model = get_plant(plant)
    nx = len(model.states)
    X = model.initial_state(compact, 15.0)[:, None] + 0.01 * rng.standard_normal((nx, 7))
    cmd = COMMANDS.pack(steer=0.02, yaw_moment=0.0, speed_ref=15.0, drive_on=1.0, steer_rate=0.0, brake_fr=200.0)
    cols = [model.f(X[:, j], model.command_map(cmd, X[:, j], compact), default_disturbance(), compact)
            for j in range(7)]
    U = model.command_map(np.repeat(cmd[:, None], 7, axis=1), X, compact)
    batched = model.f(X, U, default_disturbance()[:, None], compact)
    np.testing.assert_allclose(batched, np.column_stack(cols), rtol=1e-14, atol=1e-14)  # same arithmetic

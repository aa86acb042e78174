"""Two-track plant: agreement with the bicycle in the linear range, friction saturation,
combined slip, low speed, signs, and the roll model."""

import numpy as np
import pytest

from evstab.plants import COMMANDS, G, bicycle, default_disturbance, get_plant, load_vehicle, two_track
from evstab.plants.backend import NUMPY
from evstab.plants.disturbances import Disturbances, Friction
from evstab.plants.maneuvers import ramp_steer, step_steer
from evstab.plants.tires import combined_forces, magic_formula_normalised, peak_normalised_slip
from evstab.toolkit.loop.simulator import simulate

DEG = np.pi / 180


@pytest.mark.parametrize("name,kmh", [("compact-ev", 60), ("sedan-000", 60), ("micro-ev", 25)])
def test_agrees_with_bicycle_at_small_steer(name, kmh):
    p = load_vehicle(name)
    man = step_steer(kmh / 3.6, 0.5 * DEG, duration=5.0)
    rb, rt = simulate(p, "bicycle", man), simulate(p, "two-track", man)
    _, r_ss = bicycle.steady_state_gains(p, kmh / 3.6)
    # 2 %: the two-track differs from the linear bicycle by the Magic Formula's cubic
    # term, the speed-hold droop in the turn and the four-wheel kinematics; measured
    # 0.3-1.3 % on the bundled cars.
    assert rt.truth["yaw_rate"][-1] == pytest.approx(r_ss * 0.5 * DEG, rel=0.02)
    err = np.abs(rb.truth["yaw_rate"] - rt.truth["yaw_rate"]).max() / np.abs(rb.truth["yaw_rate"]).max()
    assert err < 0.02
    # sideslip within 0.02 deg over the whole run (0.5 deg steer gives |beta| ~ 0.03 deg)
    assert np.abs(rb.truth["beta"] - rt.truth["beta"]).max() < 0.02 * DEG


@pytest.mark.parametrize("name", ["compact-ev", "sedan-000"])
@pytest.mark.parametrize("mu", [1.0, 0.5])
def test_lateral_acceleration_saturates_near_mu_g(name, mu):
    p = load_vehicle(name)
    man = ramp_steer(80 / 3.6, 1.5 * DEG, duration=12.0)
    r = simulate(p, "two-track", man, disturbances=Disturbances(friction=Friction(mu=mu)))
    ay_max = np.abs(r.truth["ay"]).max()
    # Upper bound: the friction circle caps each tire at mu F_z and sum F_z = M g.
    # Lower bound 0.9: the load transfer and the rear drive force make the axle
    # saturate a little below mu g (measured 0.947 mu g and 0.985 mu g).
    assert 0.90 * mu * G < ay_max < 1.0 * mu * G
    # the steer ramp keeps going, so the car must end beyond the linear range
    assert np.abs(r.truth["beta"]).max() > 1.5 * DEG


def test_magic_formula_peak_and_unit_slope():
    p = load_vehicle("compact-ev")
    c, e = p.tire_shape_factor, p.tire_curvature_factor
    u = 1e-6
    assert magic_formula_normalised(np.array(u), c, e, NUMPY) / u == pytest.approx(1.0, rel=1e-9)
    up = peak_normalised_slip(c, e)
    assert magic_formula_normalised(np.array(up), c, e, NUMPY) == pytest.approx(1.0, abs=1e-9)
    # sliding value sin(C pi / 2)
    assert magic_formula_normalised(np.array(1e9), c, e, NUMPY) == pytest.approx(np.sin(c * np.pi / 2), abs=1e-6)


def test_tyre_shape_table_is_the_formula():
    """The tabulated ``F(u) / u`` (plants.tires.ShapeTable) against the formula it tabulates."""
    from evstab.plants.errors import ModelError
    from evstab.plants.tires import EPS_SLIP, TABLE_CURVATURE, TABLE_SHAPE, ShapeTable, _grid_derivatives, shape_table
    t = shape_table()
    c, e, n = TABLE_SHAPE, TABLE_CURVATURE, t.segments
    # exact at the grid points: each segment starts at the formula's value at w = i / n (its u = (1 - w) / w
    # rounded: 2 units in the last place), and ends where the next starts (5 units: 3 roundings of its sum)
    w = np.arange(1, n) / n
    u = (1.0 - w) / w
    exact = magic_formula_normalised(u, c, e, NUMPY) / u
    assert np.max(np.abs(t.coeffs[1:, 0] - exact) / np.spacing(exact)) <= 2
    ends = t.coeffs[:-1].sum(axis=1)
    assert np.max(np.abs(ends - t.coeffs[1:, 0]) / np.spacing(1.0)) <= 5
    # between them: measured 8.9e-16 in G (at most 1) and 3.0e-15 relative in the force, on 2e5 points in w
    # and 2e5 in u from 1e-9 to 1e9; the formula's own rounding is 2-4 units (4.4e-16)
    err = t.max_error()
    assert err["G_abs"] < 2e-15 and err["F_rel"] < 5e-15
    # the ends in closed form: G(0) = 1 (F' (0) = 1), and G -> sin(C pi/2) / u as u -> infinity
    assert t.ratio(0.0) == pytest.approx(1.0, abs=1e-15)
    assert t.ratio(1e12) * 1e12 == pytest.approx(np.sin(c * np.pi / 2), rel=1e-9)
    # the grid derivatives: the two exact forms (u <= 1 and u >= 1) agree where both hold (to their change
    # over 2e-9 of w), and at u = 0 (w = 1) the series F = u + f3 u^3 gives d2G/dw2 = 2 f3 = F'''(0) / 3,
    # against casadi's third derivative of the formula at 0
    import casadi as ca
    from evstab.plants.backend import CASADI
    w = np.array([0.3, 0.5 - 1e-9, 0.5 + 1e-9, 0.7, 1.0])
    val, dg, ddg = _grid_derivatives(c, e, w)
    assert val[1] == pytest.approx(val[2], rel=1e-8) and dg[1] == pytest.approx(dg[2], rel=1e-7)
    assert ddg[1] == pytest.approx(ddg[2], rel=1e-6)
    us = ca.SX.sym("u")
    d3 = ca.jacobian(ca.jacobian(ca.jacobian(magic_formula_normalised(us, c, e, CASADI), us), us), us)
    assert (val[4], dg[4]) == (1.0, 0.0)
    assert ddg[4] == pytest.approx(float(ca.Function("d3", [us], [d3])(0.0)) / 3.0, rel=1e-12)
    h = 1e-5  # central differences of the formula in w: the first two derivatives at w = 0.3 and 0.7
    for k in (0, 3):  # w 0.3 and 0.7
        g = [magic_formula_normalised(np.array((1 - x) / x), c, e, NUMPY) / ((1 - x) / x)
             for x in (w[k] - h, w[k], w[k] + h)]
        assert dg[k] == pytest.approx((g[2] - g[0]) / (2 * h), rel=1e-8)
        assert ddg[k] == pytest.approx((g[2] - 2 * g[1] + g[0]) / h ** 2, rel=1e-4)
    # the numpy forces read the table for the table's shape and curvature and the formula for others
    k_, ta = np.linspace(-0.2, 0.2, 41), np.linspace(0.3, -0.3, 41)
    args = (4000.0, 3500.0, 0.9, 52000.0, 80000.0)
    ux, uy = args[4] * k_ / (args[2] * args[1]), args[3] * ta / (args[2] * args[1])
    uu = np.sqrt(ux * ux + uy * uy + EPS_SLIP ** 2)
    fx, _ = combined_forces(k_, ta, *args, c, e, NUMPY)
    np.testing.assert_array_equal(fx, args[2] * args[0] * t.ratio(uu) * ux)
    fx, _ = combined_forces(k_, ta, *args, 1.6, 0.5, NUMPY)
    np.testing.assert_array_equal(fx, args[2] * args[0] * magic_formula_normalised(uu, 1.6, 0.5, NUMPY) / uu * ux)
    for bad in ((2.0, -2.0), (1.3, 1.0), (0.9, -2.0)):  # F(inf) = sin(C pi/2) must be > 0; E < 1
        with pytest.raises(ModelError, match="shape table"):
            ShapeTable(*bad)


def test_combined_slip_costs_side_force_and_respects_friction_circle():
    fz, mu, ca_, ck = 4000.0, 1.0, 50000.0, 90000.0
    kappas = np.linspace(0, 0.3, 31)
    fx, fy = combined_forces(kappas, np.full_like(kappas, np.tan(3 * DEG)), fz, fz, mu, ca_, ck, 1.3, -2.0, NUMPY)
    assert np.all(np.diff(-fy) < 0)  # more longitudinal slip, less side force
    assert np.all(np.hypot(fx, fy) <= mu * fz * (1 + 1e-12))  # friction circle (rounding)
    # small-slip limit is the linear tire of the bicycle model (cubic remainder ~1e-7 here)
    fx0, fy0 = combined_forces(np.array(0.0), np.array(1e-4), fz, fz, mu, ca_, ck, 1.3, -2.0, NUMPY)
    assert fy0 == pytest.approx(-ca_ * 1e-4, rel=1e-6)


def test_positive_steer_turns_left(compact):
    r = simulate(compact, "two-track", step_steer(40 / 3.6, 1.0 * DEG, duration=3.0))
    assert r.truth["yaw_rate"][-1] > 0 and r.truth["ay"][-1] > 0 and r.truth["y"][-1] > 0
    assert r.truth["roll"][-1] > 0  # ISO 8855: a left turn rolls the body right-side down = positive roll


def test_rear_torque_difference_makes_positive_yaw_moment(compact):
    # N_z = (T_rr - T_rl) t_r / (2 R_w) > 0 turns the car left.
    model = get_plant("two-track")
    x = model.initial_state(compact, 20.0)
    cmd = dict(steer=0.0, speed_ref=20.0, drive_on=0.0, steer_rate=0.0)
    u0 = model.command_map(COMMANDS.pack(cmd, yaw_moment=0.0), x, compact)
    u1 = model.command_map(COMMANDS.pack(cmd, yaw_moment=500.0), x, compact)
    t_rl, t_rr = u1[3], u1[4]
    assert (t_rr - t_rl) * compact.track_rear / (2 * compact.wheel_radius) == pytest.approx(500.0, rel=1e-12)
    i = model.state_index("omega_rr")
    x_slip = x.copy()
    x_slip[i] += 0.5  # a right-rear wheel driven slightly faster gives forward force on the right
    f = model.f(x_slip, u0, default_disturbance(), compact)
    assert f[model.state_index("yaw_rate")] > 0


def test_standstill_does_not_blow_up(compact):
    man = step_steer(0.0, 10 * DEG, duration=3.0)
    r = simulate(compact, "two-track", man)
    assert np.all(np.isfinite(r.truth["vx"]))
    assert np.abs(r.truth["vx"]).max() < 1e-3 and np.abs(r.truth["yaw_rate"]).max() < 1e-3


def test_vertical_loads_sum_to_weight(compact):
    model = get_plant("two-track")
    x = model.initial_state(compact, 20.0)
    x[model.state_index("ay_f")] = 5.0
    x[model.state_index("ax_f")] = -2.0
    fz = two_track.vertical_loads(x, np.zeros(len(two_track.INPUTS)), default_disturbance(), compact)
    # smoothing adds < 1 N per wheel at these loads (FZ_MIN^2 / (4 F_z))
    assert sum(fz) == pytest.approx(compact.mass * G, abs=1.0)
    assert fz[1] > fz[0] and fz[3] > fz[2]  # left turn loads the right wheels
    assert fz[0] + fz[1] > compact.static_axle_load_front  # braking loads the front


def test_roll_model_steady_state_roll_gain(compact):
    # Bicycle + roll (seed 004 eq. 3) in steady state: K_x phi = M_s h_s a_y.
    man = step_steer(60 / 3.6, 1.0 * DEG, duration=6.0)
    r = simulate(compact, "bicycle-roll", man)
    ay, roll = r.truth["ay"][-1], r.truth["roll"][-1]
    assert roll == pytest.approx(compact.sprung_mass * compact.roll_arm * ay / compact.roll_stiffness, rel=1e-6)
    # lateral dynamics unchanged in steady state: same yaw rate as the plain bicycle
    rb = simulate(compact, "bicycle", man)
    assert r.truth["yaw_rate"][-1] == pytest.approx(rb.truth["yaw_rate"][-1], rel=1e-6)


def test_two_track_steady_roll_equals_the_roll_gradient(compact):
    # The two-track's roll equation carries the rolled body's gravity moment m_s g h_s sin(phi); in a
    # steady turn its roll per lateral acceleration is VehicleParams.roll_gradient, m_s h_s / (K - m_s g h_s)
    # (the quasi-static rollover threshold rests on it). Tolerance 2e-3: sin(phi) ~ phi at the ~1.6 deg of
    # roll here (1.3e-4), and what is left of the roll mode after 6 s (damping ratio 0.34, 1.5 Hz: e^-19).
    r = simulate(compact, "two-track", step_steer(60 / 3.6, 2.0 * DEG, duration=6.0))
    ay, roll = r.truth["ay"][-1], r.truth["roll"][-1]
    assert ay > 2.5  # a real turn
    assert roll / ay == pytest.approx(compact.roll_gradient, rel=2e-3)
    # and the rigid-body gain m_s h_s / K, which leaves the gravity moment out, is measurably different
    assert abs(roll / ay - compact.sprung_mass * compact.roll_arm / compact.roll_stiffness) > 0.03 * roll / ay


def test_bank_pushes_car_right():
    p = load_vehicle("compact-ev")
    r = simulate(p, "two-track", step_steer(60 / 3.6, 0.0, duration=3.0),
                 disturbances=Disturbances(bank=3 * DEG))
    assert r.truth["y"][-1] < -0.1 and r.truth["yaw_rate"][-1] < 0

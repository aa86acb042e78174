"""Actuator allocation (controllers.allocation): which wheel brakes for which moment, the grip each tyre has
left, the slip limiter and the three modes, on hand-worked cases at their boundaries."""

import casadi as ca
import numpy as np
import pytest

from evstab.controllers import allocation as al
from evstab.plants import G, load_vehicle
from evstab.plants.model import brake_yaw_moment

P = load_vehicle("compact-ev")


def _design(**kw):
    base = dict(mass=P.mass, lf=P.lf, lr=P.lr, cg_height=P.cg_height, track_front=P.track_front,
                track_rear=P.track_rear, wheel_radius=P.wheel_radius, brake_gain_front=P.brake_gain_front,
                brake_gain_rear=P.brake_gain_rear, brake_pressure_max=P.brake_pressure_max,
                torque_max=P.max_motor_torque)
    base.update(kw)
    return al.AllocationDesign(**base)


D = _design(mode="brakes")
ROLLING = tuple(20.0 / P.wheel_radius for _ in range(4))  # every wheel rolling free at 20 m/s


@pytest.mark.parametrize("nz, r, wheel", [(1000.0, -0.3, 0), (1000.0, 0.3, 2), (-1000.0, 0.3, 1), (-1000.0, -0.3, 3)])
def test_against_oversteer_the_outer_front_wheel_with_understeer_the_inner_rear(nz, r, wheel):
    """|N_z r| = 300 beyond the 100 N m rad/s blend: a moment against the rotation (oversteer) is made by the front
    wheel of the side it turns towards (for a car turning the other way, the outer wheel), one with the rotation
    (understeer) by the rear wheel of that side (the inner one); the torques make N_z by the plants' own rule
    (plants.model.brake_yaw_moment), to rounding."""
    t = al.brake_moments(D, nz, r)
    assert [i for i in range(4) if t[i] > 0] == [wheel]
    assert brake_yaw_moment(t, P.wheel_radius, P.track_front, P.track_rear) == pytest.approx(nz, rel=1e-12)


def test_going_straight_the_moment_is_shared_by_the_axles():
    """r = 0: half the moment from the front wheel, half from the rear, of the side it turns towards; at N_z r =
    -100 (the blend's edge) all from the front, at +50 three quarters from the rear."""
    t = al.brake_moments(D, 800.0, 0.0)
    r_w, tf, tr = P.wheel_radius, P.track_front, P.track_rear
    assert t[0] == pytest.approx(400.0 * 2 * r_w / tf, rel=1e-12) and t[2] == pytest.approx(400.0 * 2 * r_w / tr,
                                                                                               rel=1e-12)
    assert t[1] == 0.0 and t[3] == 0.0
    t = al.brake_moments(D, 800.0, -0.125)
    assert t[2] == 0.0 and t[0] == pytest.approx(800.0 * 2 * r_w / tf, rel=1e-12)
    t = al.brake_moments(D, 800.0, 0.0625)
    assert t[2] * tr / (2 * r_w) == pytest.approx(600.0, rel=1e-12)


def test_the_grip_left_for_braking():
    """Going straight each tyre has mu F_z R (its static load); at a_y = mu g every tyre's grip goes to the side
    force (the axle's side force m a_y l/L is mu times its load, shared by load): nothing is left."""
    L = P.lf + P.lr
    g0 = al.wheel_grip(D, 0.8, 0.0)
    front = 0.8 * 0.5 * P.mass * G * P.lr / L * P.wheel_radius
    rear = 0.8 * 0.5 * P.mass * G * P.lf / L * P.wheel_radius
    np.testing.assert_allclose(g0, (front, front, rear, rear), rtol=1e-12)
    # 1e-4 N m: the square root of the rounding of (mu F_z)^2 - F_y^2, 2 sqrt(eps) mu F_z R = 1e-5 N m
    assert np.allclose(al.wheel_grip(D, 0.8, 0.8 * G), 0.0, atol=1e-4)
    g = al.wheel_grip(D, 0.8, 3.0)  # a left turn: the right (outer) wheels have more left than the left ones
    assert g[1] > g[0] and g[3] > g[2]


@pytest.mark.parametrize("slip, keep", [(0.0, 1.0), (0.09, 1.0), (0.12, 0.5), (0.15, 0.0), (1.0, 0.0), (-0.2, 1.0)])
def test_the_slip_limiter(slip, keep):
    """Braking slip (v - omega R) / v at 20 m/s: whole pressure up to 0.6 x 0.15 = 0.09, half at 0.12, none from
    0.15 (a locked wheel, slip 1, gets none); a driven wheel (slip below 0) keeps its pressure."""
    omega = 20.0 * (1.0 - slip) / P.wheel_radius
    assert al.slip_limit(D, 1e6, omega, 20.0) == pytest.approx(1e6 * keep, rel=1e-9, abs=1e-6)


def test_the_three_modes():
    """1,500 N m asked going straight on mu 1 at 20 m/s: ``motors`` gives it all to the motors, no pressure;
    ``brakes`` none to the motors and the brakes make all of it; ``blend`` with motor_share 0.2 gives the motors
    0.2 of their capacity (900 N m x 1.52 / 0.31 = 4,413 N m: 883 N m) and the brakes the rest."""
    args = (1500.0, 0.0, 20.0, 0.0, 1.0, ROLLING, 0.0)
    nz_m, p, made = al.allocate(_design(mode="motors"), *args)
    assert nz_m == 1500.0 and all(x == 0.0 for x in p) and made == 0.0
    nz_m, p, made = al.allocate(D, *args)
    assert nz_m == 0.0 and made == pytest.approx(1500.0, rel=1e-12)
    assert p[0] > 0 and p[2] > 0 and p[1] == 0.0 and p[3] == 0.0
    blend = _design(mode="blend", motor_share=0.2)
    assert blend.motor_yaw_capacity == pytest.approx(900.0 * 1.52 / 0.31)
    nz_m, p, made = al.allocate(blend, *args)
    assert nz_m == pytest.approx(0.2 * blend.motor_yaw_capacity, rel=1e-12)
    assert made == pytest.approx(1500.0 - nz_m, rel=1e-12)


def test_what_the_grip_does_not_let_through_is_not_made():
    """20,000 N m asked against oversteer on mu 0.3: the front wheel gets its grip (0.3 x its static load x R)
    and no more; the moment made is that torque's."""
    nz_m, p, made = al.allocate(D, 20000.0, -0.3, 20.0, 0.0, 0.3, ROLLING, 0.0)
    grip = al.wheel_grip(D, 0.3, 0.0)[0]
    assert p[0] * P.brake_gain_front == pytest.approx(grip, rel=1e-12)
    assert made == pytest.approx(grip * P.track_front / (2 * P.wheel_radius), rel=1e-12)


def test_the_drivers_braking_passes_through_and_the_limiter_takes_it_off_a_locking_wheel():
    """50 bar from the driver, no moment asked: every wheel gets 50 bar; the FL wheel at slip 0.15 gets none."""
    omegas = list(ROLLING)
    omegas[0] = 20.0 * 0.85 / P.wheel_radius
    _, p, _ = al.allocate(D, 0.0, 0.0, 20.0, 0.0, 1.0, tuple(omegas), 5e6)
    assert p[0] == pytest.approx(0.0, abs=1e-6) and all(x == pytest.approx(5e6, rel=1e-12) for x in p[1:])


def test_casadi_and_numpy_agree():
    """The same function traced by casadi gives numpy's numbers (1e-12 relative: the same operations)."""
    s = ca.SX.sym("s", 6)
    nz_m, p, made = al.allocate(_design(mode="blend", motor_share=0.3), s[0], s[1], s[2], s[3], s[4],
                                (s[5], s[5], s[5], s[5]), 1e5, ca)
    f = ca.Function("a", [s], [ca.vertcat(nz_m, *p, made)])
    for args in ((3000.0, 0.2, 20.0, 2.0, 0.9, 60.0), (-2500.0, 0.3, 25.0, -4.0, 0.5, 70.0)):
        ref = al.allocate(_design(mode="blend", motor_share=0.3), *args[:5], (args[5],) * 4, 1e5)
        got = np.array(f(np.array(args))).ravel()
        np.testing.assert_allclose(got, [ref[0], *ref[1], ref[2]], rtol=1e-12)

"""Friction brakes: in the plants (signs, the torque against the spin, a wheel held at its grip never turning
backwards) and the hydraulic unit of controllers.brakes (lag, rate limits, range, torque per pascal)."""

import numpy as np
import pytest
import scipy.optimize

from evstab.controllers import brakes as bk
from evstab.plants import COMMANDS, default_disturbance, get_plant, load_vehicle, two_track
from evstab.plants.errors import ParameterError
from evstab.plants.model import brake_yaw_moment
from evstab.toolkit.kernels.compiled import rk4_step

P = load_vehicle("compact-ev")
TT = get_plant("two-track")
V = 20.0


def _inputs(**kw):
    """The two-track's physical inputs (steer, drive torques, brake torques), zero unless given."""
    u = np.zeros(len(two_track.INPUTS))
    for k, v in kw.items():
        u[two_track.INPUTS.index(k)] = v
    return u


def test_at_speed_a_brake_torque_is_a_negative_drive_torque():
    """At 20 m/s (the wheels at 64.5 rad/s, k omega / T_b = 1211 x 64.5 / 800 = 98: tanh is 1 to 1e-80) 800 N m of
    brake at each wheel in turn gives the derivative 800 N m of negative drive torque gives, to rounding."""
    x = two_track.initial(P, V)
    w = default_disturbance()
    for c in ("fl", "fr", "rl", "rr"):
        a = TT.f(x, _inputs(**{f"brake_{c}": 800.0}), w, P)
        b = TT.f(x, _inputs(**{f"torque_{c}": -800.0}), w, P)
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)


def test_the_brake_yaw_moment_is_the_two_tracks_moment_of_the_braking_force():
    """The FL tyre at the slip where its force is -T_b / R (zero slip angle, so no side force): the two-track's
    own sum of moments about the CG (its contact-point geometry) equals brake_yaw_moment's
    T_b t_f / (2 R) = 800 x 1.52 / 0.62 = 1961 N m (left wheel braked: the car turns left, + in ISO 8855)."""
    t_b = 800.0
    x0 = two_track.initial(P, V)
    w = default_disturbance()
    i_w = two_track.STATES.index("omega_fl")

    def force_gap(omega):
        x = x0.copy()
        x[i_w] = omega
        return two_track._forces(x, _inputs(), w, P)[5][0] + t_b / P.wheel_radius

    omega = scipy.optimize.brentq(force_gap, 0.9 * V / P.wheel_radius, V / P.wheel_radius, xtol=1e-13)
    x = x0.copy()
    x[i_w] = omega
    mz = two_track._forces(x, _inputs(), w, P)[8]
    expected = brake_yaw_moment((t_b, 0.0, 0.0, 0.0), P.wheel_radius, P.track_front, P.track_rear)
    assert expected == pytest.approx(t_b * 1.52 / 0.62, rel=1e-12)
    # 1e-6: brentq's force tolerance (xtol 1e-13 rad/s times the tyre's slope, 1e4 N s/rad) over 1961 N m
    assert mz == pytest.approx(expected, rel=1e-6)


def _coast(x, cmd, seconds, dt=1e-3):
    """Roll the two-track out with the commands held (coasting: no drive torque), RK4 as the simulator does."""
    w = default_disturbance()
    n_sub = max(1, int(np.ceil(dt / TT.max_step(P))))
    xs = [x]
    for _ in range(int(round(seconds / dt))):
        x = rk4_step(TT, P, x, cmd, w, dt, n_sub)
        xs.append(x)
    return np.array(xs)


def test_braking_all_four_wheels_decelerates_the_car_by_the_torques():
    """1,000 N m at the front wheels and 400 at the rear, coasting from 20 m/s, mu 1 (below every wheel's
    grip): after 0.3 s the deceleration is the torques' force plus drag and rolling resistance over the car's
    mass and its four wheels' spin inertia, (2 x 1400 / R + F_res) / (m + 4 I_w / R^2) (drag at the
    speed of the moment). 2 %: the tyres' slip grows with the load transfer, and the speed and the drag move
    over the 1 ms the derivative is taken across."""
    cmd = COMMANDS.pack(steer=0.0, yaw_moment=0.0, speed_ref=V, drive_on=0.0, steer_rate=0.0, brake_fl=1000.0,
                        brake_fr=1000.0, brake_rl=400.0, brake_rr=400.0)
    xs = _coast(two_track.initial(P, V), cmd, 0.3)
    iv = two_track.STATES.index("vx")
    v = xs[-1, iv]
    ax = (xs[-1, iv] - xs[-2, iv]) / 1e-3
    r = P.wheel_radius
    f_res = 0.5 * two_track.AIR_DENSITY * P.drag_coefficient * P.frontal_area * v**2 + \
        P.rolling_resistance * P.mass * 9.81
    expected = -(2 * 1400.0 / r + f_res) / (P.mass + 4 * P.wheel_inertia / r**2)
    assert ax == pytest.approx(expected, rel=0.02)
    assert np.all(np.abs(xs[:, two_track.STATES.index("yaw_rate")]) < 1e-9)  # symmetric: no yaw


def test_a_braked_left_wheel_turns_the_car_left():
    """800 N m at the FL brake alone: the yaw rate goes positive (left, ISO 8855) and the car slows."""
    cmd = COMMANDS.pack(steer=0.0, yaw_moment=0.0, speed_ref=V, drive_on=0.0, steer_rate=0.0, brake_fl=800.0)
    xs = _coast(two_track.initial(P, V), cmd, 0.2)
    assert xs[-1, two_track.STATES.index("yaw_rate")] > 0.0
    assert xs[-1, two_track.STATES.index("vx")] < V


def test_a_wheel_braked_beyond_its_grip_locks_and_never_turns_backwards():
    """4,000 N m at every brake from 10 m/s on mu 1 (each tyre's grip is at most mu F_z R = 1.0 x 6,000 N x 0.31
    m = 1,860 N m): while the car moves the wheels creep below (T_b / k) atanh(1860 / 4000) = 1.66 rad/s (k = 1211
    N m s/rad, :func:`two_track.brake_lock_slope`) after 0.2 s, and never turn backwards; the car stops and stays
    stopped. As it stops, the tyres (dampers below 2.5 m/s, the load transfer unwinding) may turn a wheel back by
    less than 0.05 rad/s (15 mm/s at its contact patch; the brake's torque opposes it), and the wheels come to
    rest (below 1e-9 rad/s at the end)."""
    cmd = COMMANDS.pack(steer=0.0, yaw_moment=0.0, speed_ref=0.0, drive_on=0.0, steer_rate=0.0, brake_fl=4000.0,
                        brake_fr=4000.0, brake_rl=4000.0, brake_rr=4000.0)
    xs = _coast(two_track.initial(P, 10.0), cmd, 2.5)
    omegas = xs[:, [two_track.STATES.index(f"omega_{c}") for c in ("fl", "fr", "rl", "rr")]]
    k = two_track.brake_lock_slope(P)
    assert k == pytest.approx(0.35 * 90000.0 * 0.31**2 / 2.5)
    creep = 4000.0 / k * np.arctanh(1860.0 / 4000.0)
    v = xs[:, two_track.STATES.index("vx")]
    moving = v > 0.1
    assert moving[:1000].all() and not moving[-1]  # stops after 1 s or more, from 10 m/s at about 1 g
    assert np.all(omegas[moving] >= 0.0)
    assert np.all(omegas[moving][200:] < creep)
    assert np.all(omegas[~moving] > -0.05) and np.all(np.abs(omegas[-1]) < 1e-9)
    assert abs(v[-1]) < 1e-6 and np.all(v > -1e-3)


def test_a_negative_brake_torque_counts_as_none():
    """A brake asked -5 N m (a command below 0) puts no torque on the wheel: the derivative bit for bit that of no
    brake (unclamped it would drive the wheel with 5 N m)."""
    x = two_track.initial(P, V)
    x[two_track.STATES.index("vy")] = 0.3
    w = default_disturbance()
    a = TT.f(x, _inputs(steer=0.02, torque_rl=200.0, torque_rr=-100.0), w, P)
    b = TT.f(x, _inputs(steer=0.02, torque_rl=200.0, torque_rr=-100.0, brake_fl=-5.0), w, P)
    assert np.array_equal(a, b)


def test_the_bicycle_takes_the_brakes_yaw_moment():
    """The bicycle's command map adds brake_yaw_moment to the yaw moment: 600 N m at RR alone (right rear braked:
    the car turns right) makes -600 x 1.52 / 0.62 = -1471 N m."""
    bic = get_plant("bicycle")
    cmd = COMMANDS.pack(steer=0.0, yaw_moment=100.0, speed_ref=V, drive_on=1.0, steer_rate=0.0, brake_rr=600.0)
    u = bic.command_map(cmd, np.zeros(len(bic.states)), P)
    assert u[1] == pytest.approx(100.0 - 600.0 * 1.52 / 0.62, rel=1e-12)


# ----------------------------------------------------------------------------------------- hydraulics
DT = 1e-3


def _run(cmds, z=None):
    z = bk.initial_state() if z is None else z
    zs, outs = [], []
    for c in cmds:
        z, out = bk.brake_law(P, z, np.asarray(c, float), DT)
        zs.append(z)
        outs.append(out)
    return np.array(zs), np.array(outs)


def test_a_small_pressure_step_follows_the_first_order_lag():
    """10 bar asked at every wheel: 1 - exp(-1/30) of the gap closes each period (0.328 bar the first, inside the
    0.4 bar of build-up a period allows), so p_k = 10 bar (1 - e^(-k dt / tau)); 1e-12 relative: rounding over
    300 periods. The torque is the gain times the pressure."""
    zs, outs = _run([[1e6] * 4] * 300)
    k = np.arange(1, 301)
    np.testing.assert_allclose(zs[:, 0], 1e6 * (1 - np.exp(-k * DT / P.brake_tau)), rtol=1e-12)
    np.testing.assert_allclose(outs[:, bk.OUTPUTS.index("brake_fl")], P.brake_gain_front * zs[:, 0], rtol=1e-15)
    np.testing.assert_allclose(outs[:, bk.OUTPUTS.index("brake_rr")], P.brake_gain_rear * zs[:, 3], rtol=1e-15)
    assert not outs[:, bk.OUTPUTS.index("brake_limited")].any()


def test_a_large_step_builds_at_the_pumps_rate_and_releases_at_the_valves():
    """150 bar asked: the lag would move 4.92 bar the first period, the pump allows 0.4 bar (400 bar/s): the
    pressure ramps by exactly 40,000 Pa a period (float-exact multiples) while the lag's move is the larger, i.e.
    until the gap is below 40,000 / (1 - e^(-1/30)) Pa (12.2 bar); from there the gap shrinks by e^(-1/30) a
    period (1e-9 relative: rounding over the tail). Then back to 0 at the valves' 0.8 bar a period."""
    target = 1.5e7
    zs, outs = _run([[target] * 4] * 600)
    lag = 1 - np.exp(-DT / P.brake_tau)
    n_ramp = int(np.floor((target - 4e4 / lag) / 4e4)) + 1
    assert np.array_equal(zs[:n_ramp, 0], 4e4 * np.arange(1, n_ramp + 1))
    assert outs[:n_ramp, bk.OUTPUTS.index("brake_limited")].all()
    assert not outs[n_ramp:, bk.OUTPUTS.index("brake_limited")].any()
    gap = target - zs[n_ramp - 1, 0]
    tail = target - gap * np.exp(-DT / P.brake_tau) ** np.arange(1, 600 - n_ramp + 1)
    np.testing.assert_allclose(zs[n_ramp:, 0], tail, rtol=1e-9)
    zr, _ = _run([[0.0] * 4] * 50, z=zs[-1])
    assert np.array_equal(zr[:10, 0], zs[-1, 0] - 8e4 * np.arange(1, 11))


def test_the_pressure_stays_in_range():
    """Asked below 0 or above the unit's 180 bar: held at 0 and 180 bar, and flagged."""
    zs, outs = _run([[-1e6, 3e7, 0.0, 0.0]] * 2000)
    assert np.all(zs[:, 0] == 0.0) and zs[-1, 1] == pytest.approx(P.brake_pressure_max, rel=1e-9)
    assert np.all(zs[:, 1] <= P.brake_pressure_max)
    assert outs[:, bk.OUTPUTS.index("brake_limited")].all()


def test_a_vehicle_without_brake_data_is_refused_by_name():
    """The brakes need the six vehicle-file fields; a file without them gets an error naming them."""
    p = load_vehicle("sedan-000")
    with pytest.raises(ParameterError, match="brake_gain_front"):
        bk.brake_law(p, bk.initial_state(), np.zeros(4), DT)


def test_the_multibody_cars_wheel_takes_the_brake_against_its_spin():
    """commonroad-mb:1 running straight at 80 km/h (the wheels at 71 rad/s; k omega / T_b is 1e3 or more, tanh is
    1): 800 N m at one brake changes that wheel's spin derivative by -800 / I_y_w and nothing else in the same
    evaluation (1e-9: the package's wheel equation is a sum of a few terms of 1e3 rad/s^2); a brake on a wheel
    turning backwards pushes it forward (the package's own rule for a backward spin applies as well)."""
    from evstab.plants import commonroad_mb as mb
    pl = mb._Plant(1, mb.STEER_RATE_DEFAULT)
    assert pl.brake_slope == pytest.approx(0.35 * 2.0 / mb.max_stable_step(1) * pl.q.I_y_w)
    x = mb.static_equilibrium(1, mb.STEER_RATE_DEFAULT, 80 / 3.6).copy()
    w = default_disturbance()
    u0 = np.zeros(len(mb.INPUTS))
    for c in ("fl", "fr", "rl", "rr"):
        u = u0.copy()
        u[mb.INPUTS.index(f"brake_{c}")] = 800.0
        d = pl.f(x, u, w) - pl.f(x, u0, w)
        i = mb.STATES.index(f"omega_{c}")
        assert d[i] == pytest.approx(-800.0 / pl.q.I_y_w, rel=1e-9)
        assert np.all(np.delete(d, i) == 0.0)

"""The stability controller's supervision: no harm below the thresholds, friction on board,
the yaw moment the rear tyres can give."""

import dataclasses

import numpy as np
import pytest

from evstab.controllers import supervisor as sup
from evstab.controllers.two_dof import TwoDofDesign
from evstab.plants import G, load_vehicle
from evstab.plants.disturbances import Disturbances, Friction
from evstab.plants.maneuvers import sine_with_dwell, step_steer
from evstab.toolkit.loop.simulator import simulate


def _state(d, **entries):
    """A supervisor state: the initial one with ``entries`` set (by name, per :data:`supervisor.STATE`)."""
    return sup.STATE.pack({**sup.STATE.as_dict(np.asarray(sup.initial_state(d))), **entries})


def test_below_the_thresholds_the_ecu_passes_the_driver_through_exactly():
    # straight road with sensor noise, and a gentle step: commands are the driver's, bit for bit
    p = load_vehicle("compact-ev")
    for man in (step_steer(60 / 3.6, 0.0, duration=4.0), step_steer(60 / 3.6, np.radians(0.5), duration=4.0)):
        r = simulate(p, "two-track", man, controller="two-dof", seed=4)
        c = r.commands
        assert np.array_equal(c["steer_cmd"], c["steer_driver"])
        assert np.all(c["yaw_moment_cmd"] == 0.0) and np.all(c["active"] == 0.0)


def test_the_law_switches_on_at_the_limit_and_off_again():
    # FMVSS 126 sine with dwell at 6 A (compact-ev, mu 1): on in the manoeuvre, off once the car is
    # straight again (measured: on at 1.1 s, off by 5.7 s of 7.6 s)
    p = load_vehicle("compact-ev")
    man = sine_with_dwell(80 / 3.6, np.radians(6 * 22.13) / p.steering_ratio)
    r = simulate(p, "two-track", man, controller="two-dof")
    a = r.commands["active"]
    assert a.max() == 1.0 and np.all(a[-1000:] == 0.0)
    on = np.flatnonzero(a > 0)
    # blending: the authority ramps at 1 / blend_time per second, never jumps
    assert np.max(np.abs(np.diff(a))) <= 1e-3 / TwoDofDesign(p.as_nominal()).blend_time + 1e-12
    assert len(on) < len(a)


@pytest.mark.parametrize("mu", [0.3, 0.5, 0.8])
def test_friction_estimate_in_a_saturated_turn(mu):
    # a 10 deg step steer at 60 km/h: far beyond the grip of each road (the linear demand is 6.6 m/s^2
    # and more), a saturated steady turn. The ECU is not told the road; its estimate settles within 0.1
    # of mu (measured 0.32 / 0.54 / 0.87: the accelerometer also reads the body's roll) and, once it
    # has come down to 1.2 x mu (from mu_max, where it starts without evidence), never exceeds that
    p = load_vehicle("compact-ev")
    r = simulate(p, "two-track", step_steer(60 / 3.6, np.radians(10.0), start=0.5, duration=5.0), controller="none",
                 disturbances=Disturbances(friction=Friction(mu=mu)))
    est = r.commands["mu_est"]
    assert np.all(np.abs(r.truth["ay"][-1000:]) > 0.85 * mu * G)  # saturated (the two-track peaks at 0.947 mu g)
    assert abs(np.mean(est[-1000:]) - mu) < 0.1
    down = np.flatnonzero(est <= 1.2 * mu)
    assert len(down) and np.max(est[down[0]:]) <= 1.2 * mu


def test_rear_grip_limits_the_yaw_moment():
    # the friction circle: no yaw moment from saturated rear tyres, at rest the share of mu W_r / 2 t_r
    d = TwoDofDesign(load_vehicle("compact-ev").as_nominal())
    p = d.params
    full = d.rear_grip_share * 1.0 * 0.5 * p.mass * G * p.lf / p.wheelbase * p.track_rear
    assert sup.yaw_moment_limit(d, 1.0, 0.0) == pytest.approx(min(full, d.nz_max), rel=1e-12)
    assert sup.yaw_moment_limit(d, 0.5, 1.0) == 0.0
    assert sup.yaw_moment_limit(d, 0.5, 0.6) == pytest.approx(min(0.5 * full * 0.8, d.nz_max), rel=1e-12)


def test_yaw_guard_and_steer_authority():
    # while the law acts, a command that would push the yaw rate further from the reference is dropped
    # (b21, b22 > 0: left steer and positive moment turn the car left), and the steer correction
    # stays within the authority and its rate
    d = TwoDofDesign(load_vehicle("compact-ev").as_nominal())
    dt = 1e-3
    z = _state(d, active=1.0, blend=1.0, mu_est=1.0)  # active, fully blended, no correction yet
    # the car yaws too little to the left (error > 0): a right correction and a negative moment are dropped
    zn, steer, nz, _ = sup.supervise(d, z, 20.0, 0.05, 0.0, 0.0, 0.3, 0.02, 0.0, -500.0, 1e4, dt)
    assert steer == 0.02 and nz == 0.0
    # the same error with commands that help: passed, the correction rate-limited to authority_rate dt
    zn, steer, nz, _ = sup.supervise(d, z, 20.0, 0.05, 0.0, 0.0, 0.3, 0.02, 0.5, 500.0, 1e4, dt)
    assert nz == 500.0 and steer == pytest.approx(0.02 + d.steer_authority_rate * dt, rel=1e-12)
    # after long enough the correction sits at the authority, not at the law's 0.48 rad
    for _ in range(2000):
        zn, steer, nz, _ = sup.supervise(d, _state(d, **zn, mu_est=1.0), 20.0, 0.05, 0.0, 0.0, 0.3, 0.02, 0.5,
                                         500.0, 1e4, dt)
    assert steer == pytest.approx(0.02 + d.steer_authority, rel=1e-12)
    assert zn["steer_saturated"] == 1.0  # and the ECU knows its steer is limited (its own flag for the law's anti-windup)


@pytest.mark.parametrize("share,kept", [(0.0, 1.0), (0.25, 0.75), (0.5, 0.5), (1.0, 0.0), (2.0, 0.0)])
def test_yaw_guard_fades_an_opposing_command_over_its_width(share, kept):
    # the guard drops an opposing command in proportion to the error over guard_width of the dead band, so that
    # an error that the gyro's noise moves across 0 does not switch the command between all and nothing. At
    # 20 m/s and friction use 0.3 the dead band is (2 + 0.05 x 20) deg/s x (1 - 0.5 x 0.3) = 2.55 deg/s, its
    # width 0.25 of that 0.6375 deg/s; an error of `share` of the width keeps 1 - share of the command
    d = TwoDofDesign(load_vehicle("compact-ev").as_nominal())
    assert (d.guard_share, d.guard_width) == (0.0, 0.25)
    width = np.radians(2.55) * 0.25
    z = _state(d, active=1.0, blend=1.0, mu_est=1.0)
    e = share * width
    _, steer, nz, _ = sup.supervise(d, z, 20.0, e, 0.0, 0.0, 0.3, 0.02, 0.02 - 1e-4, -500.0, 1e4, 1e-3)
    # 1e-9: the dead band is a product of a few doubles; the command's share follows it to that order
    assert nz == pytest.approx(-500.0 * kept, abs=1e-9)
    assert steer == pytest.approx(0.02 - 1e-4 * kept, abs=1e-12)
    # a command that helps (turns the car towards the reference) passes whole at any error
    _, _, nz, _ = sup.supervise(d, z, 20.0, e, 0.0, 0.0, 0.3, 0.02, 0.02, 500.0, 1e4, 1e-3)
    assert nz == 500.0


@pytest.mark.parametrize("beta_deg,r,expected_deg", [
    # compact-ev's l_r, 10 m/s: l_r r / v of r = 0.5 rad/s; a geometric sideslip the turn explains is left out
    # (4 deg of CG sideslip against more geometry: nothing left), never more than the sideslip itself
    (4.0, 0.5, 0.0), (-4.0, -0.5, 0.0), (0.0, 0.5, 0.0),
    # a sideslip against the turn (a slide to the outside) keeps all of it
    (-4.0, 0.5, -4.0), (4.0, -0.5, 4.0),
    # no yaw rate: nothing to leave out
    (3.0, 0.0, 3.0)])
def test_slide_leaves_out_a_turns_geometric_sideslip(beta_deg, r, expected_deg):
    p = load_vehicle("compact-ev").as_nominal()
    d = TwoDofDesign(p)
    assert sup.slide(d, np.radians(beta_deg), r, 10.0) == pytest.approx(np.radians(expected_deg), abs=1e-15)
    # a sideslip larger than the geometry keeps the difference: 10 deg in a left turn less l_r 0.5 / 10
    geometric = p.lr * 0.5 / 10.0
    assert geometric < np.radians(10.0)
    assert sup.slide(d, np.radians(10.0), 0.5, 10.0) == pytest.approx(np.radians(10.0) - geometric, abs=1e-15)
    assert sup.slide(TwoDofDesign(p, geometric_share=0.0), np.radians(4.0), 0.5, 10.0) == np.radians(4.0)


def test_slip_control_keeps_the_rear_wheels_rolling():
    # mu 0.3, 60 km/h, sine with dwell at 5 A: the law saturates its yaw moment (4,413 N m, above
    # 2,000 N m); with the rear-grip limit switched off, only slip control stands between that demand
    # and the rear tyres. Without it (slip_max huge) a rear wheel spins up (a slip of 113) and the car
    # spins; with it the worse rear wheel stays under the bound (measured 0.081 against slip_max 0.1: the
    # cut starts at half the bound and looks 50 ms ahead, which the motors' 10,000 N m/s torque rate needs)
    # and the sideslip is smaller (2.8 deg against 90)
    p = load_vehicle("compact-ev")
    man = sine_with_dwell(60 / 3.6, np.radians(5 * 22.0) / p.steering_ratio)
    dist = Disturbances(friction=Friction(mu=0.3))

    def run(**kw):
        r = simulate(p, "two-track", man, controller="two-dof", disturbances=dist,
                     design=TwoDofDesign(p.as_nominal(), rear_grip_share=1e6, **kw))
        vx = r.truth["vx"]
        slip = max(np.abs((r.truth[f"wheel_speed_{w}"] * p.wheel_radius - vx) / np.maximum(vx, 3.0)).max()
                   for w in ("rl", "rr"))
        return slip, np.abs(r.commands["yaw_moment_cmd"]).max(), np.degrees(np.abs(r.truth["beta"]).max())

    free, demand, beta_free = run(slip_max=1e6)
    assert demand > 2000.0 and free > 1.0
    held, _, beta_held = run()
    d = TwoDofDesign(p.as_nominal())
    assert held < d.slip_max and beta_held < beta_free


def test_phase_plane_guard_acts_against_the_slide_and_only_outside_its_region():
    d = TwoDofDesign(load_vehicle("compact-ev").as_nominal())
    b, tau = d.phase_beta, d.phase_tau
    # inside the region |beta + tau beta'| <= b: exactly 0; outside: the distance to the boundary
    assert sup.phase_plane_excess(d, 0.5 * b, 0.0, 1.0) == 0.0
    assert sup.phase_plane_excess(d, b, -b / tau, 1.0) == 0.0
    assert sup.phase_plane_excess(d, -b, -0.1, 1.0) == pytest.approx(-tau * 0.1, rel=1e-12)
    # an untrusted sideslip estimate does not count: only the kinematic rate does
    assert sup.phase_plane_excess(d, -10 * b, 0.0, 0.0) == 0.0
    # a car over-rotating to the left (r > a_y / v: beta' = -0.4 rad/s) with an untrusted sideslip
    # estimate and no yaw-rate error: the law is switched on, and the guard's yaw moment and steer
    # turn the car right (negative: b21, b22 > 0), in proportion to the excess
    dt = 1e-3
    z = _state(d, active=1.0, blend=1.0, mu_est=1.0)
    excess = tau * -0.4 + b
    zn, steer, nz, _ = sup.supervise(d, z, 20.0, 0.0, 0.0, 1.0, 0.3, 0.02, 0.02, 0.0, 1e5, dt, beta_rate=-0.4)
    assert zn["active"] == 1.0 and excess < 0
    assert nz == pytest.approx(d.phase_gain_nz * d.params.yaw_inertia * excess, rel=1e-12)
    assert steer == pytest.approx(0.02 - d.steer_authority_rate * dt, rel=1e-12)  # rate-limited, to the right
    # inactive car, inside the region: not switched on by the guard
    z0 = sup.initial_state(d)
    zn, steer, nz, _ = sup.supervise(d, z0, 20.0, 0.0, 0.0, 1.0, 0.0, 0.02, 0.02, 0.0, 1e5, dt, beta_rate=0.05)
    assert zn["active"] == 0.0 and steer == 0.02 and nz == 0.0


@pytest.mark.parametrize("now, lagged, ay, saturated", [
    # a steady demand of 5 m/s^2: saturated below 80 % of it (4 m/s^2), not above
    (5.0, 5.0, 3.99, True), (5.0, 5.0, 4.01, False),
    # the demand now below the lagged one: judged against the smaller, 3 m/s^2 (80 %: 2.4)
    (3.0, 5.0, 2.39, True), (3.0, 5.0, 2.41, False),
    # a reversal (the demand now on the other side): no evidence, however little the car delivers
    (-5.0, 5.0, 0.5, False), (-5.0, 5.0, -0.5, False),
    # the car still turning the other way: no evidence
    (5.0, 5.0, -0.5, False),
    # below saturation_ay_min (2 m/s^2) nothing is judged
    (1.9, 1.9, 0.5, False), (-5.0, -5.0, -3.99, True)])
def test_friction_evidence_only_where_demand_and_car_agree(now, lagged, ay, saturated):
    d = TwoDofDesign(load_vehicle("compact-ev").as_nominal())
    assert (d.saturation_ratio, d.saturation_ay_min) == (0.8, 2.0)
    speed, dt = 20.0, 1e-9  # a period short enough that the lagged demand does not move (by 1e-8 m/s^2)
    mu_next, _, demand_next = sup.friction_estimate(d, 1.0, lagged, speed, ay, ay / speed, now / speed, dt)
    assert demand_next == pytest.approx(lagged, abs=1e-7)
    # saturated: the estimate moves towards what the car delivers (< 1), else it stays at mu_max
    assert (mu_next < 1.0) == saturated


@pytest.mark.parametrize("slide_deg_s, ay, now, tau", [
    # a_y 3 m/s^2 at 20 m/s carries r = 0.15 rad/s; the yaw rate beyond it by more than slide_rate_fast (4 deg/s)
    # is a car sliding out: mu_tau_slide (0.05 s); at or below it mu_tau_down (0.2 s)
    (4.1, 3.0, 10.0, 0.05), (3.9, 3.0, 10.0, 0.2), (0.0, 3.0, 10.0, 0.2),
    # the mirror image in a right turn
    (4.1, -3.0, -10.0, 0.05), (3.9, -3.0, -10.0, 0.2),
    # a yaw rate below what a_y carries (the car drifting wide, the sideslip rate with the turn): the slow fall
    (-10.0, 3.0, 10.0, 0.2),
    # the driver not holding the turn: the lagged demand 10 m/s^2 moves by 1 - exp(-1 ms / 0.15 s) of the way to
    # the demand now; at 12.0 it is 10.0133 and the demand now within 0.2 of it (1.987 <= 2.0027): held; at 12.1
    # it is 10.0139 and 2.086 > 2.0028 from it: a reversal or a turn-in, the slow fall
    (4.1, 3.0, 12.0, 0.05), (4.1, 3.0, 12.1, 0.2), (4.1, -3.0, -12.0, 0.05), (4.1, -3.0, -12.1, 0.2)])
def test_the_friction_estimate_falls_fast_only_while_the_car_slides_out_of_a_held_turn(slide_deg_s, ay, now, tau):
    d = TwoDofDesign(load_vehicle("compact-ev").as_nominal())
    assert (d.mu_tau_down, d.mu_tau_slide, np.degrees(d.slide_rate_fast), d.slide_demand_steady, d.demand_tau) == \
        pytest.approx((0.2, 0.05, 4.0, 0.2, 0.15))
    speed, dt = 20.0, 1e-3
    sign = 1.0 if ay > 0 else -1.0
    r = ay / speed + sign * np.radians(slide_deg_s)
    # saturated (the linear demand lagged 10 m/s^2, now `now`, the car delivering 3): the estimate falls from 1
    # towards |a_y| / (0.95 g) by dt / tau of the way
    target = abs(ay) / (d.peak_ratio * 9.80665)
    mu_next, _, _ = sup.friction_estimate(d, 1.0, sign * 10.0, speed, ay, r, now / speed, dt)
    assert mu_next == pytest.approx(1.0 + (target - 1.0) * dt / tau, rel=1e-12)


@pytest.mark.parametrize("now, lagged, share", [
    # gust_demand 0.15 m/s^2: whole authority up to it, none from twice it, linear between
    (0.14, 0.14, 1.0), (0.15, 0.15, 1.0), (0.225, 0.225, 0.5), (-0.225, -0.225, 0.5), (0.3, 0.3, 0.0),
    # the demand's change counts too: 0.05 now, 0.2 lagged -> 0.05 + 0.15 = 0.2 -> 2 - 0.2 / 0.15
    (0.05, 0.2, 2.0 - 0.2 / 0.15), (0.0, 0.35, 0.0)])
def test_straight_share_of_the_gust_channel(now, lagged, share):
    d = TwoDofDesign(load_vehicle("compact-ev").as_nominal())
    assert d.gust_demand == 0.15
    assert sup.straight_share(d, now, lagged) == pytest.approx(share, abs=1e-12)


def test_gust_channel_acts_where_gyro_and_accelerometer_agree():
    d = TwoDofDesign(load_vehicle("compact-ev").as_nominal())
    assert (d.gust_deadband, d.gust_gain, d.gust_nz_max, d.gust_course_share, d.gust_tau) == (
        np.deg2rad(0.3), 80.0, 2000.0, 0.6, 0.05)
    iz, big, deg = d.params.yaw_inertia, 1e5, np.deg2rad(1.0)

    def nz(r, beta_rate, ref=0.0, straight=1.0, speed=25.0, limit=big, dt=1.0):
        # dt 1 s, long against gust_tau: the lags have settled (their factor min(dt / tau, 1) is 1)
        return sup.gust_moment(d, (0.0, 0.0), ref, r, beta_rate, straight, speed, limit, dt)[0]

    # a push to the right: the car yaws right at 0.5 deg/s (yaw-rate error +0.5) and slides right at 0.5
    # deg/s of sideslip rate (course-rate error 0.5 + 0.5 = 1.0): both beyond half the band, one sign; the
    # error acted on is 0.5 + 0.6 x 0.5 = 0.8 deg/s, 0.5 beyond the band: a left (positive) moment
    assert nz(-0.5 * deg, -0.5 * deg) == pytest.approx(iz * 80.0 * 0.5 * deg, rel=1e-9)
    # the same from the reference (the driver asks 0.5 deg/s of left turn, the car goes straight and
    # slides right): the reference counts like the yaw rate
    assert nz(0.0, -0.5 * deg, ref=0.5 * deg) == pytest.approx(iz * 80.0 * 0.5 * deg, rel=1e-9)
    # how much the two agree: by the smaller error, nothing up to half the band (0.15 deg/s), all from the
    # band (0.3) on, linear between. The yaw-rate error at 0.149, 0.225 and 0.3 deg/s, the course-rate
    # error far beyond the band: 0, half and all of the moment on e_r + 0.6 x 1 deg/s
    assert nz(-0.149 * deg, -1.0 * deg) == 0.0
    assert nz(-0.225 * deg, -1.0 * deg) == pytest.approx(0.5 * iz * 80.0 * 0.525 * deg, rel=1e-9)
    assert nz(-0.3 * deg, -1.0 * deg) == pytest.approx(iz * 80.0 * 0.6 * deg, rel=1e-9)
    # the course-rate error at 0.149 and 0.3 deg/s: r = -1 deg/s with beta' = +0.851 / +0.7
    assert nz(-1.0 * deg, 0.851 * deg) == 0.0
    assert nz(-1.0 * deg, 0.7 * deg) == pytest.approx(iz * 80.0 * (1.0 - 0.6 * 0.7 - 0.3) * deg, rel=1e-9)
    # one sensor alone: an accelerometer reading a sideslip rate with no yaw rate, or a gyro reading a yaw
    # rate the accelerometer does not (beta' = a_y / v - r = +1 deg/s with a_y = 0): nothing
    assert nz(0.0, -1.0 * deg) == 0.0
    assert nz(-1.0 * deg, 1.0 * deg) == 0.0
    # the two of opposite signs: nothing
    assert nz(-0.5 * deg, 1.0 * deg) == 0.0
    # both agree, the error acted on inside the band: 0.2 + 0.6 x 0.1 = 0.26 deg/s
    assert nz(-0.2 * deg, -0.1 * deg) == 0.0
    # the other side: a push to the left, a negative moment
    assert nz(0.5 * deg, 0.5 * deg) == pytest.approx(-iz * 80.0 * 0.5 * deg, rel=1e-9)
    # half straight: half the moment; turning: none; below min_speed: none
    full = nz(-0.5 * deg, -0.5 * deg)
    assert nz(-0.5 * deg, -0.5 * deg, straight=0.5) == pytest.approx(0.5 * full, rel=1e-9)
    assert nz(-0.5 * deg, -0.5 * deg, straight=0.0) == 0.0
    assert nz(-0.5 * deg, -0.5 * deg, speed=0.99 * d.min_speed) == 0.0
    # the limits: gust_nz_max, and the rear tyres' grip where that is less
    assert nz(-0.2, -0.2) == pytest.approx(2000.0)
    assert nz(0.2, 0.2, limit=700.0) == pytest.approx(-700.0)
    # the lags: a step of each input moves its lag by dt / gust_tau of it
    _, (lag_r, lag_b) = sup.gust_moment(d, (0.0, 0.0), 0.0, -deg, 2 * deg, 1.0, 25.0, big, 1e-3)
    assert (lag_r, lag_b) == (pytest.approx(deg * 0.02, rel=1e-12), pytest.approx(2 * deg * 0.02, rel=1e-12))


def test_gust_channel_rejects_a_crosswind():
    # the envelope's gust on the two-track (1.5 kN at 100 km/h, the driver holding the wheel): 2 s after
    # the gust the car alone has drifted 1.54 m and the controlled car 0.62 m (seed 0, measured): below
    # the rule's half. The law itself stays off (its band is 3.4 deg/s; the gust turns the car at 1.9), the
    # steer is the driver's, and the moment holds about 580 N m at the end (the gust's 450 N m of yaw
    # moment plus its side force's) without chatter: no jump above 200 N m per period (measured 136, as the
    # gyro and the accelerometer come to agree at the gust's onset, where the agreement ramps in)
    from evstab.toolkit.verdicts import envelope as ev
    p = load_vehicle("compact-ev")
    case = next(c for c in ev.cases("two-track") if c.kind == "crosswind")
    man, road, _ = ev.run_setup(case, p)
    alone = simulate(p, "two-track", man, disturbances=road, controller=None)
    r = simulate(p, "two-track", man, disturbances=road, seed=0, controller="two-dof", estimator="dakf")
    dev_alone, dev = ev.metrics(alone, man, p).deviation_m, ev.metrics(r, man, p).deviation_m
    assert dev <= ev.GUST_SHARE * dev_alone
    c = r.commands
    assert np.all(c["active"] == 0.0) and np.array_equal(c["steer_cmd"], c["steer_driver"])
    nz = c["yaw_moment_cmd"]
    assert np.all(nz[r.t < man.events["gust"]] == 0.0)  # nothing before the gust
    assert np.max(np.abs(np.diff(nz))) < 200.0


def test_the_drive_is_cut_only_while_the_law_acts_against_oversteer():
    # hand-worked: beta_threshold 3 deg, phase region |beta + 0.3 beta'| <= 4 deg, beta_std_max 2 deg, drive_cut 0.5
    p = load_vehicle("compact-ev")
    d = TwoDofDesign(p.as_nominal())
    assert (np.degrees(d.beta_threshold), np.degrees(d.phase_beta), d.phase_tau) == pytest.approx((3.0, 4.0, 0.3))
    assert d.drive_cut == 0.5
    ok, unsure = np.radians(0.5), np.radians(2.5)  # beta_std: trusted, not trusted
    r = 0.2  # [rad/s] a left turn

    def cut(latch, blend, e, beta=0.0, rate=0.0, std=ok, dd=d):
        return sup.drive_cut(dd, latch, blend, e, r, beta, rate, std)

    # the law off: the drive is the driver's and the latch clears, whatever the car does
    assert cut(1.0, 0.0, -0.05, beta=0.2) == (1.0, 0.0)
    # understeer (the car yaws less than the band: the error has the turn's sign): no cut
    assert cut(0.0, 0.5, +0.05) == (1.0, 0.0)
    # oversteer (beyond the band, the error against the turn): latched, the cut in proportion to the blend
    assert cut(0.0, 0.5, -0.05) == (0.75, 1.0)
    assert cut(0.0, 0.5, -0.05, dd=TwoDofDesign(p.as_nominal(), drive_cut=0.4)) == pytest.approx((0.8, 1.0))
    # inside the band (error 0) the latch holds what it was
    assert cut(1.0, 0.3, 0.0) == pytest.approx((0.85, 1.0)) and cut(0.0, 0.3, 0.0) == (1.0, 0.0)
    # the sideslip beyond 3 deg sets it only while the estimate is trusted (3.5 deg: inside the phase region)
    assert cut(0.0, 1.0, 0.0, beta=np.radians(3.5)) == (0.5, 1.0)
    assert cut(0.0, 1.0, 0.0, beta=np.radians(3.5), std=unsure) == (1.0, 0.0)
    # the phase plane: a sideslip rate of 15 deg/s is 4.5 deg after 0.3 s, beyond the region with no sideslip yet
    assert cut(0.0, 1.0, 0.0, rate=np.radians(15.0), std=unsure) == (0.5, 1.0)
    assert cut(0.0, 1.0, 0.0, rate=np.radians(13.0), std=unsure) == (1.0, 0.0)
    # the paper's law (always active) never cuts
    assert cut(0.0, 1.0, -0.05, dd=TwoDofDesign(p.as_nominal(), always_active=True))[0] == 1.0


def test_the_drive_cut_setting_is_a_share():
    p = load_vehicle("compact-ev")
    for bad in (-0.1, 1.5):
        with pytest.raises(Exception, match="drive_cut"):
            TwoDofDesign(p.as_nominal(), drive_cut=bad)


@pytest.mark.parametrize("limit_time, beyond, fresh, t_next, margin", [
    # turn_in_margin 0.95 for turn_in_time 1 s, then to friction_margin 0.87 over turn_in_fall_time 1 s (1 ms periods)
    (0.0, 1.0, 0.0, 0.001, 0.95), (0.999, 1.0, 0.0, 1.0, 0.95), (1.499, 1.0, 0.0, 1.5, 0.91),
    (1.999, 1.0, 0.0, 2.0, 0.87), (2.0, 1.0, 0.0, 2.0, 0.87),
    # the demand back within the limit: the timer restarts, the next turn-in has the turn-in margin
    (1.5, 0.0, 0.0, 0.0, 0.95),
    # a fresh start in a turn beyond the limit is a held turn; within the limit nothing is held
    (0.0, 1.0, 1.0, 2.0, 0.87), (0.0, 0.0, 1.0, 0.0, 0.95)])
def test_the_reference_margin_falls_once_a_limit_turn_is_held(limit_time, beyond, fresh, t_next, margin):
    d = TwoDofDesign(load_vehicle("compact-ev").as_nominal())
    assert (d.turn_in_margin, d.friction_margin, d.turn_in_time, d.turn_in_fall_time) == (0.95, 0.87, 1.0, 1.0)
    k, t = sup.reference_margin(d, limit_time, beyond, 1e-3, fresh)
    # 1e-12: a sum of a few numbers of order 1
    assert (t, k) == pytest.approx((t_next, margin), abs=1e-12)


def test_the_friction_estimate_does_not_recover_while_the_oversteer_latch_holds():
    # not saturated (no demand): the estimate recovers from 0.5 towards mu_max 1 by dt / mu_tau_up, unless the latch
    # is set; it still falls while saturated (the demand 10 m/s^2, the car delivering 3) and never below what the
    # car uses (3 / (0.95 g) = 0.322)
    d = TwoDofDesign(load_vehicle("compact-ev").as_nominal())
    speed, dt = 20.0, 1e-3
    free = sup.friction_estimate(d, 0.5, 0.0, speed, 3.0, 0.15, 0.0, dt)[0]
    held = sup.friction_estimate(d, 0.5, 0.0, speed, 3.0, 0.15, 0.0, dt, oversteer=1.0)[0]
    assert free == pytest.approx(0.5 + 0.5 * dt / d.mu_tau_up, rel=1e-12)
    assert held == 0.5
    target = 3.0 / (d.peak_ratio * G)
    falling = sup.friction_estimate(d, 0.5, 10.0, speed, 3.0, 0.15, 10.0 / speed, dt, oversteer=1.0)[0]
    assert falling == pytest.approx(0.5 + (target - 0.5) * dt / d.mu_tau_down, rel=1e-12)
    assert sup.friction_estimate(d, 0.3, 0.0, speed, 3.0, 0.15, 0.0, dt, oversteer=1.0)[0] == pytest.approx(target)


@pytest.mark.parametrize("use, released", [(0.0, True), (0.8999, True), (0.9, False), (1.0, False)])
def test_the_law_is_not_released_while_the_car_uses_the_friction(use, released):
    # errors quiet for hold_time (0.5 s): the law ends, unless the car uses release_use (0.9) of the friction or more
    d = TwoDofDesign(load_vehicle("compact-ev").as_nominal())
    assert (d.hold_time, d.release_use) == (0.5, 0.9)
    dt = 1e-3
    z = _state(d, active=1.0, hold=d.hold_time - 0.5 * dt, blend=1.0)
    z_next, *_ = sup.supervise(d, z, 20.0, 0.0, 0.0, 0.0, use, 0.0, 0.0, 0.0, 1000.0, dt)
    assert z_next["active"] == (0.0 if released else 1.0)
    assert z_next["hold"] == pytest.approx(d.hold_time + 0.5 * dt if released else 0.0)


def test_the_supervisor_reads_the_lateral_acceleration_less_the_bodys_roll():
    # sign and units against the two-track's sensor model (a_y cos(phi) + g sin(phi), the body rolling out of the
    # turn): in a steady left turn of about 4 m/s^2 on compact-ev the accelerometer reads g k = 9.5 % more than the
    # car's lateral acceleration, and ay_roll_factor = 1 / (1 + g k) takes it out
    p = load_vehicle("compact-ev")
    d = TwoDofDesign(p.as_nominal())
    k = p.roll_gradient
    assert G * k == pytest.approx(0.095, abs=0.001)
    assert d.ay_roll_factor == pytest.approx(1.0 / (1.0 + G * k), rel=1e-15)
    man = step_steer(60 / 3.6, np.radians(2.6), start=0.5, duration=5.0)
    r = simulate(p, "two-track", man, controller="none", seed=3)
    last = r.t > 4.0
    truth = np.mean(r.truth["ay"][last])
    reading = np.mean(r.measurements["ay"][last])
    assert 3.0 < truth < 5.0
    # 0.5 %: the small-angle form (cos phi 0.9993 at 2.1 deg of roll), the accelerometer's noise over 1000 samples
    # (0.05 m/s^2 / sqrt(1000)) and its bias draw
    assert reading * d.ay_roll_factor == pytest.approx(truth, rel=0.005)
    assert reading / truth == pytest.approx(1.0 + G * k, rel=0.005)
    # a file without roll data: the reading is taken as it is
    bare = dataclasses.replace(p.as_nominal(), sprung_mass=None)
    assert TwoDofDesign(bare).ay_roll_factor == 1.0


def test_the_reference_headroom_lets_a_quick_turn_in_keep_its_lateral_displacement():
    # FMVSS 126 on mu 0.5, the Vanagon from its +40 % stiffness file (the multi-body study's case), the largest
    # amplitude of the series (16.9 deg A: 261.9 deg, right first), the default design: at the turn-in the yaw rate
    # leads the lateral acceleration while the sideslip builds up. With 1.25 m/s^2 of headroom the reference held
    # at the lateral acceleration read that as a slide and the steer was cut to 0.35 deg of the driver's 16.4: 1.818 m
    # sideways against the 1.83 m the standard asks (measured); with the default 2 m/s^2, 1.878 m.
    from evstab.studies.control_mb_fmvss126 import wrong_nominal
    from evstab.toolkit.loop.simulator import simulate_many
    from evstab.toolkit.verdicts import fmvss126 as F

    p = wrong_nominal(3)
    amplitude = F.amplitudes(16.9)[-1]
    assert amplitude == pytest.approx(261.95)
    man = F.series_maneuver(p, -amplitude)
    designs = [TwoDofDesign(p), TwoDofDesign(p, ay_headroom=1.25)]
    assert designs[0].ay_headroom == 2.0
    runs = [simulate_many(p, "commonroad-mb:3", [man], disturbances=Disturbances(friction=Friction(mu=0.5)), seed=0,
                          controller="two-dof", design=d)[0] for d in designs]
    scores = [F.score_swd(r.t, man.steer(r.t) * p.steering_ratio, r.truth["yaw_rate"], r.truth["ay"]) for r in runs]
    ok, failed = scores[0].passes(amplitude, 16.9)
    assert ok, failed
    # 20 mm: the margin the default keeps (1.878 m) less the run-to-run spread of the gyro's noise (the series'
    # neighbouring amplitudes move it by up to 30 mm), still above the standard's 1.83 m
    assert scores[0].lateral_displacement_m > F.LATERAL_DISPLACEMENT_MIN + 0.02
    assert scores[1].lateral_displacement_m < F.LATERAL_DISPLACEMENT_MIN

"""The 2-DOF controller and its stability: closed forms of seed 003 and python-control cross-checks."""

import dataclasses

import control
import numpy as np
import pytest

from evstab.controllers.actuators import SIGNALS as ACT_SIGNALS, ActuatorLimits, actuator_law
from evstab.controllers.two_dof import (OUTPUTS, SIGNALS, STATE, TwoDofDesign, allocate as allocate_commands,
                                        control_law, reference, understeer_share)
from evstab.plants.errors import DesignError
from evstab.plants import G, load_vehicle
from evstab.plants.bicycle import lateral_coefficients, lateral_matrices, steady_state_gains
from evstab.toolkit.design.stability import nominal_loop


@pytest.mark.parametrize("kb,kg", [(5.0, 5.0), (3.0, 8.0)])
@pytest.mark.parametrize("v", [10.0, 25.0])
def test_nominal_closed_loop_poles(vehicle, kb, kg, v):
    d = TwoDofDesign(vehicle.as_nominal(), k_beta=kb, k_gamma=kg)
    loop, st = nominal_loop(d, v)
    A, _ = lateral_matrices(vehicle.as_nominal(), v)
    expected = np.sort_complex(np.concatenate([[-kb, -kg], np.linalg.eigvals(A)]))
    # (sI - A)(sI + Kd): the model-following poles plus the plant's, which the controller cancels
    np.testing.assert_allclose(np.sort_complex(st.poles), expected, atol=1e-9)
    assert st.stable
    # reference -> output is K = diag(Kb/(s+Kb), Kg/(s+Kg)) (seed 003 eq. 31)
    w = np.array([0.1, 1.0, 5.0, 30.0])
    # frequency responses of the 4-state interconnection vs the closed forms: rounding only
    resp = loop(1j * w)
    i_yb, i_yr = loop.output_labels.index("y_beta"), loop.output_labels.index("y_r")
    i_rb, i_rr = loop.input_labels.index("r_beta"), loop.input_labels.index("r_r")
    np.testing.assert_allclose(resp[i_yb, i_rb], kb / (1j * w + kb), rtol=1e-9)
    np.testing.assert_allclose(resp[i_yr, i_rr], kg / (1j * w + kg), rtol=1e-9)
    assert np.abs(resp[i_yb, i_rr]).max() < 1e-9 and np.abs(resp[i_yr, i_rb]).max() < 1e-9  # decoupled


def test_internal_instability_is_found_when_the_design_cancels_an_unstable_plant():
    p = load_vehicle("compact-ev")
    unstable = dataclasses.replace(p, cornering_stiffness_rear=0.3 * p.cornering_stiffness_rear)
    A, _ = lateral_matrices(unstable, 20.0)
    assert np.max(np.linalg.eigvals(A).real) > 0  # an oversteering car above its critical speed
    loop, st = nominal_loop(TwoDofDesign(unstable), 20.0)
    assert not st.stable
    # ... although the reference-to-output map alone is stable: only internal stability shows it
    assert np.all(control.tf(loop["y_beta", "r_beta"]).minreal(1e-6).poles().real < 0)


def test_model_error_cases():
    p = load_vehicle("compact-ev")
    d = TwoDofDesign(p.as_nominal())
    for f in (0.6, 1.0, 1.4):
        true = dataclasses.replace(p, cornering_stiffness_front=f * p.cornering_stiffness_front,
                                   cornering_stiffness_rear=f * p.cornering_stiffness_rear,
                                   mass=p.mass * 1.2)
        assert nominal_loop(d, 25.0, true)[1].stable
    # speed off-nominal: the controller scheduled at a speed 20 % off the true one
    for sched in (20.0, 30.0):
        assert nominal_loop(d, 25.0, controller_speed=sched)[1].stable
    # and the scheduling matters: the exact speed puts the poles back at -K
    _, st = nominal_loop(d, 25.0, controller_speed=25.0)
    assert np.min(np.abs(st.poles + 5.0)) < 1e-9


def test_reference_model_and_friction_limit():
    # seed 003 eq. 23-24 (the bicycle's steady-state gains), then |gamma| <= 0.87 mu g / v (the default
    # friction_margin, controllers.two_dof.FRICTION_MARGIN); the lateral acceleration asked for stays below
    # 0.7 of the rollover threshold too (compact-ev: 0.77 g, above 0.87 x 0.5 g here)
    p = load_vehicle("compact-ev")
    d = TwoDofDesign(p)
    kb, kg = steady_state_gains(p, 20.0)
    beta, gamma, _ = reference(d, 20.0, 0.01, 1.0)
    assert (beta, gamma) == pytest.approx((kb * 0.01, kg * 0.01), rel=1e-12)
    beta, gamma, _ = reference(d, 20.0, 0.2, 0.5)
    assert gamma == pytest.approx(0.87 * 0.5 * G / 20.0, rel=1e-12)
    assert beta / gamma == pytest.approx(kb / kg, rel=1e-12)  # same steady turn
    _, gamma, _ = reference(d, 20.0, 0.2, 2.0)  # friction beyond the rollover limit: that limit holds
    assert gamma * 20.0 == pytest.approx(d.ay_limit, rel=1e-12)


def test_allocation_meets_torque_limits():
    # the motors' allocation in the actuator law: common torque kept (clipped), the difference cut to
    # the room each wheel has left; a 1 s sample so the torque-rate limit (10,000 N m/s) does not act
    p = load_vehicle("compact-ev")
    rng = np.random.default_rng(1)
    lim = ActuatorLimits()
    for _ in range(200):
        nz, tm = rng.uniform(-8000, 8000), rng.uniform(-1200, 1200)
        z, out = actuator_law(p, lim, 900.0, np.zeros(2),
                              ACT_SIGNALS.pack(steer_cmd=0.0, steer_driver=0.0, steer_correction=0.0,
                                               yaw_moment_cmd=nz, t_mean=tm, dt=1.0))
        t_mean = np.clip(tm, -900.0, 900.0)
        t_rl, t_rr = t_mean - z[1], t_mean + z[1]
        assert abs(t_rl) <= 900.0 + 1e-9 and abs(t_rr) <= 900.0 + 1e-9
        ach = (t_rr - t_rl) * p.track_rear / (2 * p.wheel_radius)
        assert ach == pytest.approx(out[1], abs=1e-9)
        assert (out[3] > 0.5) == (abs(ach - nz) > 1e-6)


def _steer_run(lim, driver, cmd, dt=1e-3):
    p = load_vehicle("compact-ev")
    z, applied, states = np.zeros(2), [], []
    for d, c in zip(driver, cmd):
        z, out = actuator_law(p, lim, 900.0, z, ACT_SIGNALS.pack(steer_cmd=c, steer_driver=d, steer_correction=c - d,
                                                                 yaw_moment_cmd=0.0, t_mean=0.0, dt=dt))
        applied.append(out[0])
        states.append(z[0])
    return np.array(applied), np.array(states)


def test_superposition_passes_the_driver_through_the_column():
    # a passive ECU commands the driver's own angle: the superposition gear adds nothing, so the wheels turn
    # exactly as the driver steers, however fast (a 2 Hz, 10 deg sweep is 126 deg/s, twice the servo's rate)
    t = np.arange(0.0, 1.0, 1e-3)
    driver = np.deg2rad(10.0) * np.sin(2 * np.pi * 2.0 * t)
    applied, corr = _steer_run(ActuatorLimits(), driver, driver)
    assert np.array_equal(applied, driver)
    assert not corr.any()
    # the steer-by-wire servo of the whole angle (superposition off) lags and rate-limits the driver's sweep
    whole, _ = _steer_run(ActuatorLimits(superposition=False), driver, driver)
    assert np.abs(whole - driver).max() > np.deg2rad(1.0)


def test_superposition_correction_lags_and_is_rate_limited():
    # a 2 deg correction asked on top of a driver holding 5 deg: the servo's first-order lag asks
    # (2 deg - correction) / 0.03 s, beyond its 60 deg/s while the correction is below 0.2 deg, so the first four
    # 1 ms samples move it 0.06 deg each (0.24 deg; the fourth asks 1.82 / 0.03 = 60.7 deg/s), and the fifth by the
    # lag alone, 1.76 / 0.03 deg/s x 1 ms; the wheels read the driver's angle plus it
    lim = ActuatorLimits()
    n = 200
    driver = np.full(n, np.deg2rad(5.0))
    applied, corr = _steer_run(lim, driver, driver + np.deg2rad(2.0))
    assert np.degrees(corr[:4]) == pytest.approx([0.06, 0.12, 0.18, 0.24], rel=1e-9)
    assert np.degrees(corr[4]) == pytest.approx(0.24 + 1.76 / 30.0, rel=1e-9)
    assert np.array_equal(applied, driver + corr)
    # then 195 samples of the lag alone, each taking 1 ms / 30 ms of what is left
    assert np.degrees(corr[-1]) == pytest.approx(2.0 - (1.76 - 1.76 / 30.0) * (29.0 / 30.0) ** 195, rel=1e-9)


def test_superposition_holds_the_road_wheel_limit():
    # a 3 deg correction on a driver at 30 deg; the driver then jumps to the 35 deg limit with the command still
    # at 33: the rack stops at 35 deg (the gear's angle becomes 35 - 35 = 0), and from there the correction
    # moves towards the -2 deg the command now asks, at the 60 deg/s rate limit (-0.06 deg per 1 ms)
    lim = ActuatorLimits()
    driver = np.deg2rad(np.r_[np.full(300, 30.0), np.full(5, 35.0)])
    applied, corr = _steer_run(lim, driver, np.full(305, np.deg2rad(33.0)))
    assert np.degrees(corr[299]) == pytest.approx(3.0, abs=1e-3)  # 300 samples of the 30 ms lag
    assert np.degrees(applied[300]) == pytest.approx(35.0, rel=1e-15) and corr[300] == 0.0
    assert np.degrees(corr[301]) == pytest.approx(-0.06, rel=1e-9)
    assert np.abs(applied).max() <= np.deg2rad(35.0)


def test_controller_tracks_on_the_nominal_bicycle():
    # discrete controller (seed 003's static reference) on the exact linear plant: the error decays with the
    # model-following pole
    p = load_vehicle("compact-ev")
    # (no understeer band: the car approaches the reference from below, and the law is to pull it all the way)
    d = TwoDofDesign(p, k_beta=5.0, k_gamma=5.0, reference_model="static", understeer_band=0.0)
    A, B = lateral_matrices(p, 20.0)
    x = np.zeros(2)
    st = np.zeros(len(STATE))
    xd = np.array(reference(d, 20.0, 0.02, p.mu)[:2])
    errs = []
    for k in range(3000):
        st, out = control_law(d, st, np.array([20.0, 0.02, x[0], x[1], 0.0, 0.0, p.mu, 0.0, 0.0, 0.0]))
        u = np.array([out[0], out[1]])
        x = x + 1e-3 * (A @ x + B @ u)
        errs.append(np.abs(x - xd).max())
    assert errs[-1] < 1e-4 * np.abs(xd).max() + 1e-9  # exp(-5 * 3 s) ~ 3e-7 of the step


def _law_run(d, p, v, steer, n, mu=1.0, share=0.0):
    """The law on the exact Euler-discretised linear plant from rest, the driver's steer ``steer`` held:
    the commands, the plant's states and the law's states, per period."""
    A, B = lateral_matrices(p, v)
    x, st = np.zeros(2), np.zeros(len(STATE))
    outs, xs, sts = [], [], []
    for _ in range(n):
        sig = SIGNALS.pack(speed=v, steer_driver=steer, beta=x[0], yaw_rate=x[1], d1=0.0, d2=0.0, mu=mu,
                           steer_limited=0.0, yaw_moment_limited=0.0, limit_share=share)
        st, out = control_law(d, st, sig)
        x = x + d.dt * (A @ x + B @ out[:2])
        outs.append(out), xs.append(x.copy()), sts.append(st)
    return np.array(outs), np.array(xs), np.array(sts)


def test_linear_reference_passes_the_driver_through_on_the_nominal_car():
    # The linear car is the reference: on the nominal car (the same Euler step as the law's reference) its
    # feed-forward is exactly the driver's steer and no yaw moment, and the car follows it with no error, so
    # the law adds nothing in a transient the static reference's lag would fight (two-track slalom and
    # ISO 3888-2, docs/controller.md)
    p = load_vehicle("compact-ev")
    d = TwoDofDesign(p)
    assert d.reference_model == "linear"
    steer = 0.01  # 4.3 m/s^2 at 20 m/s in steady state: inside the friction limit
    out, x, st = _law_run(d, p, 20.0, steer, 2000)
    o = OUTPUTS.index("steer"), OUTPUTS.index("yaw_moment"), OUTPUTS.index("yaw_rate_error")
    # rounding of the inverse B^-1 (x_l' - A x_l) against the Euler step: relative 1e-9 of the steer
    np.testing.assert_allclose(out[:, o[0]], steer, rtol=1e-9, atol=0)
    np.testing.assert_allclose(out[:, o[1]], 0.0, atol=1e-6)  # N m, against moments of ~1e3
    np.testing.assert_allclose(out[:, o[2]], 0.0, atol=1e-12)
    # it ends in the linear car's own steady state (seed 003 eq. 23), which the static reference also asks for
    kb, kg = steady_state_gains(p, 20.0)
    assert x[-1, 1] == pytest.approx(kg * steer, rel=1e-6)  # 2 s: the plant's poles (~ -10/s) have settled
    assert st[-1, STATE.index("yaw_rate_ref")] == pytest.approx(kg * steer, rel=1e-6)


def test_linear_reference_holds_the_friction_limit():
    # driver's demand far beyond mu 0.3: the linear car's yaw rate settles at friction_margin mu g / v, as seed
    # 003's limited static reference does
    p = load_vehicle("compact-ev")
    d = TwoDofDesign(p)
    v, mu = 20.0, 0.3
    _, _, st = _law_run(d, p, v, 0.05, 2000, mu=mu)
    limit = d.friction_margin * mu * G / v
    assert abs(st[-1, STATE.index("yaw_rate_linear")]) == pytest.approx(limit, rel=1e-9)
    assert st[-1, STATE.index("yaw_rate_linear")] == pytest.approx(st[-1, STATE.index("yaw_rate_ref")], rel=1e-6)


@pytest.mark.parametrize("r,expected", [(0.15, 0.0), (0.1, 0.0), (0.2, 0.0), (0.25, -0.05), (0.05, 0.05),
                                        (-0.1, 0.2)])
def test_the_supervised_law_acts_on_the_distance_to_the_reference_band(r, expected):
    # linear car 0.2 rad/s, lagged static reference 0.1 rad/s: a yaw rate between them (the edges included) is
    # no error; beyond, the error is to the nearer edge; always active (the paper's law) it is to the reference
    # (without the understeer band, which the next test checks)
    p = load_vehicle("compact-ev")
    d = TwoDofDesign(p, understeer_band=0.0)
    st = STATE.pack(xi_beta=0.0, xi_yaw_rate=0.0, beta_ref=0.0, yaw_rate_ref=0.1, dist_beta=0.0, dist_yaw_rate=0.0,
                    beta_linear=0.0, yaw_rate_linear=0.2)
    sig = SIGNALS.pack(speed=20.0, steer_driver=0.0, beta=0.0, yaw_rate=r, d1=0.0, d2=0.0, mu=1.0, steer_limited=0.0,
                       yaw_moment_limited=0.0, limit_share=0.0)
    i = OUTPUTS.index("yaw_rate_error")
    assert control_law(d, st, sig)[1][i] == pytest.approx(expected, abs=1e-15)
    assert control_law(TwoDofDesign(p, always_active=True), st, sig)[1][i] == pytest.approx(0.2 - r, abs=1e-15)
    # limit_share 1: the reference is the lagged static one and the band has closed on it
    sig1 = SIGNALS.pack(SIGNALS.as_dict(sig) | {"limit_share": 1.0})
    assert control_law(d, st, sig1)[1][i] == pytest.approx(0.1 - r, abs=1e-15)


@pytest.mark.parametrize("linear,static,r,expected", [
    # band 0.1-0.2 rad/s, share 0.2: it reaches down to 0.08; the oversteer side stays at 0.2
    (0.2, 0.1, 0.08, 0.0), (0.2, 0.1, 0.07, 0.01), (0.2, 0.1, 0.0, 0.08), (0.2, 0.1, -0.1, 0.18),
    (0.2, 0.1, 0.21, -0.01),
    # the mirror image in a right turn: up to -0.08, the oversteer side at -0.2
    (-0.2, -0.1, -0.08, 0.0), (-0.2, -0.1, -0.07, -0.01), (-0.2, -0.1, -0.21, 0.01),
    # a band across 0 (a reversal of the steer) already holds 0: unchanged
    (0.1, -0.05, -0.06, 0.01), (0.1, -0.05, 0.11, -0.01), (0.1, -0.05, 0.0, 0.0)])
def test_the_understeer_band_reaches_towards_zero_only(linear, static, r, expected):
    # a car that turns the reference's way at 80 % of the band's smaller yaw rate (understeer_band 0.2) is inside
    # it, as a nominal model with tyres 40 % too stiff asks; yawing more than the band gets no allowance
    p = load_vehicle("compact-ev")
    d = TwoDofDesign(p, understeer_band=0.2)
    st = STATE.pack(xi_beta=0.0, xi_yaw_rate=0.0, beta_ref=0.0, yaw_rate_ref=static, dist_beta=0.0,
                    dist_yaw_rate=0.0, beta_linear=0.0, yaw_rate_linear=linear)
    sig = SIGNALS.pack(speed=20.0, steer_driver=0.0, beta=0.0, yaw_rate=r, d1=0.0, d2=0.0, mu=1.0, steer_limited=0.0,
                       yaw_moment_limited=0.0, limit_share=0.0)
    # 1e-15: the edges are one product and one difference of numbers of order 0.1
    assert control_law(d, st, sig)[1][OUTPUTS.index("yaw_rate_error")] == pytest.approx(expected, abs=1e-15)


@pytest.mark.parametrize("ratio,expected", [(0.0, 0.2), (0.8, 0.2), (0.9, 0.1), (0.95, 0.05), (1.0, 0.0), (2.0, 0.0)])
def test_the_understeer_band_is_whole_below_0_8_of_the_limit_and_gone_at_it(ratio, expected):
    # the driver's linear demand (the nominal car's steady yaw rate for the steer) as `ratio` of the reference's
    # limit min(0.87 mu g, ay_limit) / v: the band's share is 0.2 up to 0.8 of it, falls linearly, 0 from 1 on;
    # either sign of the steer
    p = load_vehicle("compact-ev")
    d = TwoDofDesign(p)
    assert (d.understeer_band, d.understeer_demand) == (0.2, 0.8)
    v, mu = 20.0, 0.6
    limit = min(0.87 * mu * G, d.ay_limit) / v
    steer = ratio * limit / steady_state_gains(p, v)[1]
    for sign in (1.0, -1.0):
        # 1e-12: a ratio and a difference of doubles of order 1
        assert understeer_share(d, v, sign * steer, mu) == pytest.approx(expected, abs=1e-12)


def test_reference_model_settings_are_checked():
    p = load_vehicle("compact-ev")
    with pytest.raises(DesignError, match="reference_model"):
        TwoDofDesign(p, reference_model="dynamic")
    with pytest.raises(DesignError, match="limit_demand_hi > limit_demand_lo"):
        TwoDofDesign(p, limit_demand_lo=1.5, limit_demand_hi=1.5)
    with pytest.raises(DesignError, match="understeer_demand"):
        TwoDofDesign(p, understeer_demand=1.0)


def test_saturation_aware_allocation_prefers_yaw():
    p = load_vehicle("compact-ev")
    d = TwoDofDesign(p.as_nominal(), yaw_priority=50.0)
    v = 20.0
    _, B = lateral_matrices(p.as_nominal(), v)
    _, _, _, _, b11, b21, b22 = lateral_coefficients(p.as_nominal(), v)

    def alloc(u):
        return np.array([float(c) for c in allocate_commands(d, u[0], u[1], b11, b21, b22)])

    u = np.array([0.05, 3.0 * d.nz_max])  # a yaw moment the motors cannot make
    out = alloc(u)
    assert out[1] == pytest.approx(d.nz_max, rel=1e-12)
    # the steer is re-chosen to realise the demanded yaw acceleration as closely as the weights say
    demand = B @ u
    w = np.array([1.0, 50.0])
    col, rest = B[:, 0], demand - B[:, 1] * d.nz_max
    assert out[0] == pytest.approx(np.sum(w * col * rest) / np.sum(w * col * col), rel=1e-12)
    assert out[0] > u[0]  # more steer into the turn makes up for the missing yaw moment
    small = np.array([0.01, 100.0])
    np.testing.assert_array_equal(alloc(small), small)  # no saturation: exact inverse kept


def test_control_law_numpy_and_casadi_agree():
    import casadi as ca
    from evstab.controllers.two_dof import SIGNALS, STATE, control_law
    from evstab.plants.backend import CASADI
    d = TwoDofDesign(load_vehicle("compact-ev").as_nominal())
    z, s = ca.SX.sym("z", len(STATE)), ca.SX.sym("s", len(SIGNALS))
    F = ca.Function("ctl", [z, s], list(control_law(d, z, s, CASADI)))
    rng = np.random.default_rng(0)
    for _ in range(200):
        zz = 0.05 * rng.standard_normal(len(STATE))
        ss = np.array([rng.uniform(0, 30), 0.1 * rng.standard_normal(), 0.05 * rng.standard_normal(),
                       0.3 * rng.standard_normal(), rng.standard_normal(), rng.standard_normal(), 1.0,
                       float(rng.random() < 0.3), float(rng.random() < 0.3), rng.random()])
        zn, y = control_law(d, zz, ss)
        zc, yc = F(zz, ss)
        # one expression evaluated two ways; yaw moments are ~1e4 N m, hence the absolute 1e-9
        np.testing.assert_allclose(np.array(zc).ravel(), zn, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(np.array(yc).ravel(), y, rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize("kb,kg", [(5.0, 5.0), (3.0, 8.0)])
def test_output_channel_margins_closed_form(kb, kg):
    # At the plant outputs the nominal return ratio is P C_fb = K (I - K)^-1 = diag(Kb, Kg) / s:
    # phase margin 90 deg at crossover K_j, no gain margin limit, balanced disk margin
    # 1 / max|S - 1/2| = 2 (|S - 1/2| = |s - K| / (2 |s + K|) = 1/2), |S| < 1 everywhere.
    from evstab.toolkit.design.stability import channel_margins
    p = load_vehicle("compact-ev")
    loop, _ = nominal_loop(TwoDofDesign(p.as_nominal(), k_beta=kb, k_gamma=kg), 20.0)
    m = {c.channel: c for c in channel_margins(loop)}
    for ch, k in (("beta", kb), ("r", kg)):
        assert m[ch].pm_deg == pytest.approx(90.0, abs=1e-6)
        assert m[ch].crossover_rad_s == pytest.approx(k, rel=1e-6)
        assert m[ch].gm_db == float("inf")
        assert m[ch].disk_margin == pytest.approx(2.0, rel=1e-6)
        assert m[ch].sensitivity_peak <= 1.0 + 1e-9
    # with equal poles the input channels see the same K/s (the loop is K at both ends)
    if kb == kg:
        for ch in ("delta", "Nz"):
            assert m[ch].pm_deg == pytest.approx(90.0, abs=1e-6)


@pytest.mark.parametrize("ratio,share", [(0.0, 0.0), (1.19, 0.0), (1.2, 0.0), (1.35, 0.5), (1.5, 1.0), (3.0, 1.0)])
def test_limit_share_moves_to_the_static_reference_beyond_the_rollover_limit(ratio, share):
    # the driver's linear demand as a multiple of the rollover limit (rollover_share of the quasi-static threshold):
    # 0 up to limit_demand_lo (1.2), 1 from limit_demand_hi (1.5), linear between; either sign of the demand
    from evstab.toolkit.ecu.step import limit_share
    d = TwoDofDesign(load_vehicle("compact-ev"))
    p = d.params
    # 0.7 of the quasi-static threshold, which the body's roll puts below the rigid car's g (t_f + t_r) / (4 h)
    assert d.ay_limit == pytest.approx(0.7 * p.rollover_threshold, rel=1e-12)
    assert p.rollover_threshold < G * (p.track_front + p.track_rear) / (4 * p.cg_height)
    for sign in (1.0, -1.0):
        assert limit_share(d, sign * ratio * d.ay_limit) == pytest.approx(share, abs=1e-12)


@pytest.mark.parametrize("steer_limited, moment_limited, integrates", [
    (0.0, 0.0, True), (0.0, 1.0, True), (1.0, 0.0, True), (1.0, 1.0, False)])
def test_the_yaw_rate_integrator_is_held_only_while_both_commands_are_limited(steer_limited, moment_limited,
                                                                               integrates):
    # a car yawing 0.05 rad/s beyond the band: with the yaw moment alone limited the allocation moves the yaw row
    # to the steer, so the integrator runs (xi' = e); the sideslip integrator is held while the steer is limited
    p = load_vehicle("compact-ev")
    d = TwoDofDesign(p, understeer_band=0.0)
    st = STATE.pack(xi_beta=0.0, xi_yaw_rate=0.0, beta_ref=0.0, yaw_rate_ref=0.1, dist_beta=0.0, dist_yaw_rate=0.0,
                    beta_linear=0.0, yaw_rate_linear=0.2)
    sig = SIGNALS.pack(speed=20.0, steer_driver=0.0, beta=0.01, yaw_rate=0.25, d1=0.0, d2=0.0, mu=1.0,
                       steer_limited=steer_limited, yaw_moment_limited=moment_limited, limit_share=0.0)
    z_next, _ = control_law(d, st, sig)
    nxt = STATE.as_dict(z_next)
    # e_r = 0.2 - 0.25 (to the band's upper edge); e_b = 0 - 0.01 (the band 0..0 for beta); one period of 1 ms
    assert nxt["xi_yaw_rate"] == pytest.approx(-0.05 * d.dt if integrates else 0.0, abs=1e-15)
    assert nxt["xi_beta"] == pytest.approx(0.0 if steer_limited else -0.01 * d.dt, abs=1e-15)

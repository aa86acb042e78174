"""What real sensors bring that the simulated ones did not: a vibrating accelerometer (the kinematic path reads it
through a low-pass, a quiet one as it comes) and a quantised CAN yaw rate (held but moving: not a stuck gyro)."""

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest
from scipy import signal

from evstab.plants import load_vehicle
from evstab.plants.maneuvers import make_maneuver
from evstab.toolkit.estimation import design_filter, run_estimator
from evstab.toolkit.estimation.monitor import MonitorSettings, gyro_quantum, gyro_stuck
from evstab.toolkit.estimation.spec import estimation_noise
from evstab.toolkit.loop.simulator import simulate


@pytest.fixture(scope="module")
def runs():
    p = load_vehicle("compact-ev")
    out = {}
    for name, man in (("lane change", make_maneuver("sine-lane-change", p, 80 / 3.6, np.radians(3.0))),
                      ("step", make_maneuver("step-steer", p, 60 / 3.6, np.radians(2.0)))):
        res = simulate(p, "two-track", man, seed=2)
        out[name] = res.log_columns()
    return p, out


def _rms(p, cols, truth, t, **kw):
    d = design_filter("dakf", p, dataclasses.replace(estimation_noise(), **kw))
    beta = run_estimator(d, {k: v for k, v in cols.items() if not k.endswith("_true")})["beta"]
    return beta, float(np.degrees(np.sqrt(np.mean((beta - truth)[t > 1.0] ** 2))))


@pytest.mark.parametrize("name", ["lane change", "step"])
def test_a_quiet_accelerometer_is_read_as_it_comes(runs, name):
    """With the simulated accelerometer (0.05 m/s^2 per sample) the low-pass has no share: the estimate is the
    one without it, bit for bit."""
    p, logs = runs
    log = logs[name]
    with_lp, _ = _rms(p, log, log["beta_true"], log["t"])
    without, _ = _rms(p, log, log["beta_true"], log["t"], kinematic_ay_cutoff=0.0)
    np.testing.assert_array_equal(with_lp, without)


@pytest.mark.parametrize("name", ["lane change", "step"])
def test_a_vibrating_accelerometer_does_not_fake_a_slide(runs, name):
    """4 m/s^2 of 40-100 Hz vibration on the lateral accelerometer (the Stanford GTI's, measured on its logs)
    holds the kinematic path on where it reads the raw signal; through the low-pass the estimate is the quiet
    accelerometer's. Measured: lane change 0.042 deg RMS quiet, 0.158 raw, 0.042 low-passed; step 0.017, 0.250,
    0.017."""
    p, logs = runs
    log = logs[name]
    t, truth = log["t"], log["beta_true"]
    sos = signal.butter(4, [40.0, 100.0], btype="band", fs=1.0 / (t[1] - t[0]), output="sos")
    vib = signal.sosfilt(sos, np.random.default_rng(0).standard_normal(len(t)))
    noisy = dict(log, ay=log["ay"] + vib * (4.0 / vib.std()))
    _, quiet = _rms(p, log, truth, t)
    _, raw = _rms(p, noisy, truth, t, kinematic_ay_cutoff=0.0)
    _, lp = _rms(p, noisy, truth, t)
    assert raw > 3.0 * quiet  # the vibration alone triples the error where the path reads it raw (3.7x, 15x)
    assert lp < quiet + 0.005  # through the low-pass: the quiet accelerometer's error (equal to 1e-3 deg measured)


def test_accelerometer_noise_estimate_and_share():
    """The noise is half the mean squared difference of successive readings: white noise of std s gives s^2;
    the low-passed share is 0 up to accel_noise_on and 1 from accel_noise_full (a smooth ramp between)."""
    from evstab.toolkit.estimation import kalman, kinematic_path
    p = load_vehicle("compact-ev")
    nz = estimation_noise()
    d = design_filter("dakf", p)
    lay = kinematic_path.KINEMATIC_LP
    rng = np.random.default_rng(3)
    for sd, share in ((0.1, 0.0), (nz.accel_noise_on * 0.95, 0.0), (0.45, None), (nz.accel_noise_full * 1.05, 1.0),
                      (4.0, 1.0)):
        ks = lay.as_dict(lay.zeros())
        g = kalman.INPUTS.unpack(kalman.INPUTS.pack({"dt": 1e-3}, fill=0.0))
        for a in sd * rng.standard_normal(20000):
            lp, s, _, _ = kinematic_path.accel_low_pass(d, SimpleNamespace(**ks), g, a, 0.0, 20.0, np.zeros(d.n), np)
            ks.update(lp)
        est = float(np.sqrt(ks["ay_noise"]))
        assert abs(est / sd - 1.0) < 0.1  # a 1 s lag at 1 kHz averages ~2000 squares: 3 % std, 10 % is 3 sigma
        if share is not None:
            assert s == share
        else:  # 0.45 is halfway between 0.3 and 0.6
            assert 0.3 < s < 0.7


@pytest.mark.parametrize("dt", [1e-3, 5e-3, 0.02])
def test_the_low_passed_noise_is_the_two_lags_impulse_energy(dt):
    """``low_passed_noise``: the standard deviation of white noise after the two lags. Cross-checked against
    scipy's impulse response of the same filter (``lfilter`` with ``b = [a]``, ``a = [1, a - 1]``, twice; its
    energy to 1e-12) and against the lags run on 200,000 seeded samples of unit noise (the sample variance of
    correlated samples: about 2 % spread at these lengths, 6 % is 3 sigma)."""
    from evstab.toolkit.estimation import kinematic_path
    d = design_filter("dakf", load_vehicle("compact-ev"))
    a = kinematic_path.low_pass_alpha(d, dt)
    imp = np.zeros(20000)
    imp[0] = 1.0
    h = signal.lfilter([a], [1.0, a - 1.0], signal.lfilter([a], [1.0, a - 1.0], imp))
    sd = kinematic_path.low_passed_noise(d, 4.0, dt)
    assert sd == pytest.approx(2.0 * np.sqrt(np.sum(h * h)), rel=1e-9)
    y = signal.lfilter([a], [1.0, a - 1.0], signal.lfilter([a], [1.0, a - 1.0],
                                                          np.random.default_rng(7).standard_normal(200000)))
    assert np.std(y[5000:]) == pytest.approx(sd / 2.0, rel=0.06)
    # the small-alpha limit a / 4 (1 kHz, 5 Hz: a = 0.030, exact 0.0874 against sqrt(a/4) = 0.0871)
    if dt == 1e-3:
        assert sd / 2.0 == pytest.approx(np.sqrt(a / 4.0), rel=0.01)


def test_the_thresholds_rise_with_the_vibration():
    """``kinematic_noise_sigmas``: with an accelerometer of 4 m/s^2 per sample at 1 kHz (fully low-passed),
    a departure of 1.2 m/s^2 held for 1 s engages the path fully with the thresholds as set (0.4 -> 0.8), and
    not at all with three standard deviations of the low-passed noise added to both (3 x 4 x 0.0874 = 1.05:
    1.45 -> 1.85); at 0.25 m/s^2 of noise (below accel_noise_on, no low-pass) nothing moves."""
    from evstab.toolkit.estimation import kalman, kinematic_path
    p = load_vehicle("compact-ev")

    def weight(sigmas, noise_sd):
        d = design_filter("dakf", p, dataclasses.replace(estimation_noise(), kinematic_noise_sigmas=sigmas))
        lay = kinematic_path.kinematic_layout(d)
        ks = lay.as_dict(lay.zeros())
        ks.update(ay_noise=noise_sd ** 2, dev=1.2, ay_level=10.0, dep_lp=1.2, dep_lp1=1.2, ay_lp=10.0, ay_lp1=10.0,
                  ay_last=10.0)
        g = kalman.INPUTS.unpack(kalman.INPUTS.pack({"dt": 1e-3, "ay": 10.0}, fill=0.0))
        x = np.zeros(d.n)
        a_row = [0.0] * d.n  # a model that asks for no lateral acceleration: the departure is the reading
        w, *_ = kinematic_path.weight(d, a_row, [0.0, 0.0], np.ones((d.n, 1)), x, np.zeros(2), g, 20.0, 1.0,
                                      lay.pack(ks), np)
        return float(w)
    assert weight(0.0, 4.0) == 1.0
    assert weight(3.0, 4.0) == 0.0
    assert weight(3.0, 0.25) == weight(0.0, 0.25)


def test_the_yaw_row_loosens_with_the_lateral_acceleration():
    """``yaw_model_ay``: one predict from a zero covariance at 20 m/s, the gyro gated off (``gyro_ok`` 0) and
    no fix: the yaw rate's variance is its process noise times dt, doubled where the estimated yaw rate makes
    ``v r`` equal to the setting (1 + 1^4) and 17 times at twice it (1 + 2^4), whichever the turn's sign; and
    ``yaw_model_steer`` multiplies by the same law of the road-wheel angle."""
    from evstab.toolkit.estimation import kalman
    p = load_vehicle("compact-ev")
    d = design_filter("dakf", p)
    nz, lay, ir, v = d.noise, kalman.layout(d), d.index("yaw_rate"), 20.0

    def var_r(rate, steer=0.0):
        zs = lay.as_dict(kalman.initial_state(d, yaw_rate0=rate))
        zs["P"] = np.zeros(d.n * d.n)
        u = kalman.INPUTS.pack({"dt": 1e-3, "speed": v, "hdop": 1.0, "gyro_ok": 0.0, "yaw_rate": rate, "steer": steer},
                               fill=0.0)
        z1, _ = kalman.step(d, lay.pack(zs), u)
        return lay.unpack(z1).P.reshape(d.n, d.n, order="F")[ir, ir]
    base = nz.q_yaw_rate * 1e-3
    assert var_r(0.0) == pytest.approx(base, rel=1e-9)
    assert var_r(nz.yaw_model_ay / v) == pytest.approx(2.0 * base, rel=1e-9)
    assert var_r(-2.0 * nz.yaw_model_ay / v) == pytest.approx(17.0 * base, rel=1e-9)
    # yaw_model_steer: the road-wheel angle multiplies it by 1 + (|steer| / yaw_model_steer)^4 on top
    assert var_r(0.0, -nz.yaw_model_steer) == pytest.approx(2.0 * base, rel=1e-9)
    assert var_r(nz.yaw_model_ay / v, 2.0 * nz.yaw_model_steer) == pytest.approx(2.0 * 17.0 * base, rel=1e-9)


def test_beta_std_carries_the_models_error():
    """``beta_model_std`` / ``beta_model_rel``: the output ``beta_std`` is the filter's sideslip variance plus,
    in quadrature, ``beta_model_std (v |r| / beta_model_ay)^2`` and ``beta_model_rel |beta|``; the filter's
    state and covariance are those of the filter without them. Checked on one step from a chosen state:
    20 m/s, 0.35 rad/s (v r = 7 m/s^2 = beta_model_ay: the full 0.5 deg), sideslip 0.05 rad (10 %: 0.005)."""
    from evstab.toolkit.estimation import kalman
    p = load_vehicle("compact-ev")
    d = design_filter("dakf", p)
    plain = design_filter("dakf", p, dataclasses.replace(d.noise, beta_model_std=0.0, beta_model_rel=0.0))
    lay = kalman.layout(d)
    ib, ir = d.index("beta"), d.index("yaw_rate")
    zs = lay.as_dict(kalman.initial_state(d, yaw_rate0=0.35))
    zs["x"] = zs["x"].copy()
    zs["x"][ib] = 0.05
    u = kalman.INPUTS.pack({"dt": 1e-3, "speed": 20.0, "hdop": 1.0, "gyro_ok": 0.0, "yaw_rate": 0.35}, fill=0.0)
    z1, y1 = kalman.step(d, lay.pack(zs), u)
    z0, y0 = kalman.step(plain, lay.pack(zs), u)
    np.testing.assert_array_equal(z1, z0)  # the filter itself is untouched
    x, P = lay.unpack(z1).x, lay.unpack(z1).P.reshape(d.n, d.n, order="F")
    lev = 20.0 * abs(x[ir]) / d.noise.beta_model_ay
    want = np.sqrt(P[ib, ib] + (d.noise.beta_model_std * lev ** 2) ** 2 + (d.noise.beta_model_rel * x[ib]) ** 2)
    out, out0 = kalman.OUTPUTS.as_dict(y1), kalman.OUTPUTS.as_dict(y0)
    assert out["beta_std"] == pytest.approx(want, rel=1e-12)
    assert out0["beta_std"] == pytest.approx(np.sqrt(P[ib, ib]), rel=1e-12)
    assert d.noise.beta_model_std == pytest.approx(np.radians(0.5)) and lev == pytest.approx(1.0, rel=0.01)


def test_the_yaw_row_returns_to_the_model_through_the_release_lag():
    """``kinematic_yaw_release``: the kinematic path off (no lateral acceleration) with the yaw row's weight
    left at 1 by an engagement: one predict from a zero covariance, the gyro gated off, no fix. The weight decays
    by ``dt / kinematic_yaw_release`` per step, and the yaw rate's variance is ``dt ((1 - w) q_yaw_rate +
    w q_yaw_rate_kinematic)`` with the decayed weight (straight ahead, no steer: the yaw row's loosening factors
    are 1). Without the release (the default) the row is the model's at once: ``dt q_yaw_rate``, and no weight
    in the state."""
    from evstab.toolkit.estimation import kalman, kinematic_path
    p = load_vehicle("compact-ev")
    d = design_filter("dakf", p, dataclasses.replace(estimation_noise(), kinematic_yaw_release=0.1))
    nz, ir, dt = d.noise, d.index("yaw_rate"), 1e-3
    lay_k = kinematic_path.kinematic_layout(d)
    assert "w_yaw" in lay_k

    def one(design, w_yaw=None):
        lay_d = kalman.layout(design)
        zs = lay_d.as_dict(kalman.initial_state(design))
        zs["P"] = np.zeros(design.n * design.n)
        if w_yaw is not None:
            ks = lay_k.as_dict(zs["kin"])
            ks["w_yaw"] = w_yaw
            zs["kin"] = lay_k.pack(ks)
        u = kalman.INPUTS.pack({"dt": dt, "speed": 20.0, "hdop": 1.0, "gyro_ok": 0.0}, fill=0.0)
        z1, _ = kalman.step(design, lay_d.pack(zs), u)
        zs1 = lay_d.unpack(z1)
        return zs1.P.reshape(design.n, design.n, order="F")[ir, ir], zs1.kin
    var, kin = one(d, 1.0)
    w = 1.0 - dt / nz.kinematic_yaw_release
    assert lay_k.unpack(kin).w_yaw == pytest.approx(w, rel=1e-12)
    assert var == pytest.approx(dt * ((1.0 - w) * nz.q_yaw_rate + w * nz.q_yaw_rate_kinematic), rel=1e-9)
    at_once = design_filter("dakf", p, dataclasses.replace(nz, kinematic_yaw_release=0.0))
    assert "w_yaw" not in kinematic_path.kinematic_layout(at_once)
    assert one(at_once)[0] == pytest.approx(dt * nz.q_yaw_rate, rel=1e-9)


@pytest.mark.parametrize("rate, init, held", [
    (0.3, 0.0, True),     # v r = 6 m/s^2 before the first fix: the bias held
    (0.3, 1.9, True),     # 0.9 s after it: still settling
    (0.3, 2.1, False),    # 1.1 s after it: learnt
    (0.05, 0.0, False),   # v r = 1 m/s^2, below bias_settle_ay: learnt from the start
    (-0.3, 0.0, True),    # the other way round
])
def test_the_bias_is_held_in_turns_while_the_heading_settles(rate, init, held):
    """``bias_settle_hold``: one step at 20 m/s with the gyro 0.01 rad/s off the yaw rate estimate and no fix.
    The gyro update leaves the bias estimate as it was (to the bit) while the heading settles (``init`` below
    1 + 1 s) in a turn (``v |r|`` above 2 m/s^2), and moves it everywhere else; without the setting it always
    moves it."""
    from evstab.toolkit.estimation import kalman
    p = load_vehicle("compact-ev")
    d = design_filter("dakf", p)
    off = design_filter("dakf", p, dataclasses.replace(d.noise, bias_settle_hold=0.0))
    assert d.noise.bias_settle_hold == 1.0 and d.noise.bias_settle_ay == 2.0
    ig = d.index("gyro_bias")

    def bias_after(design):
        lay = kalman.layout(design)
        zs = lay.as_dict(kalman.initial_state(design, yaw_rate0=rate))
        zs["init"] = init
        u = kalman.INPUTS.pack({"dt": 1e-3, "speed": 20.0, "hdop": 1.0, "gyro_ok": 1.0, "yaw_rate": rate + 0.01},
                               fill=0.0)
        return lay.unpack(kalman.step(design, lay.pack(zs), u)[0]).x[ig]
    assert bool(bias_after(d) == 0.0) is held
    assert abs(bias_after(off)) > 1e-6  # without the hold the gyro update teaches the bias


def test_a_quantised_gyro_adds_its_rounding_to_the_gyro_noise():
    """``runner.quantised_gyro_noise``: a yaw rate in steps of 1.28 deg/s (ReV-StED's CAN signal) is rounded by
    up to half a step, uniformly: the filter's gyro noise becomes ``hypot(gyro_std, q / sqrt(12))``; a MEMS
    gyro's (steps far below the monitor's 1e-3 rad/s) leaves the design as it is, the same object."""
    from evstab.toolkit.estimation.runner import quantised_gyro_noise
    d = design_filter("dakf", load_vehicle("compact-ev"))
    q = np.radians(1.28)
    t = np.arange(500) * 0.02
    r = np.radians(10.0) * np.sin(0.5 * t)
    wide = quantised_gyro_noise(d, {"t": t, "yaw_rate": q * np.round(r / q)})
    assert wide.noise.gyro_std == pytest.approx(np.hypot(d.noise.gyro_std, q / np.sqrt(12.0)), rel=1e-12)
    mems = r + 0.004 * np.random.default_rng(4).standard_normal(len(t))
    assert quantised_gyro_noise(d, {"t": t, "yaw_rate": mems}) is d


Q = np.radians(1.28)  # the ReV-StED CAN yaw rate's resolution


def _turn(n=500, dt=0.02, v=10.0):
    t = np.arange(n) * dt
    r = np.radians(10.0) + np.radians(8.0) * np.sin(2 * np.pi * 0.1 * t)  # a slowly varying turn
    return t, r, v * r, np.full(n, v)


def test_a_quantised_gyro_in_a_turn_is_not_stuck():
    t, r, ay, v = _turn()
    gyro = np.round(r / Q) * Q  # holds each value for several samples while the rate moves inside a step
    assert (np.diff(gyro) == 0).mean() > 0.8
    np.testing.assert_allclose(gyro_quantum(gyro)[-1], Q, rtol=1e-12)
    assert not gyro_stuck(t, gyro, MonitorSettings(), ay, v).any()
    # without a_y the hold limit decides: the longest hold of this turn (at the rate's peak) is the boundary
    same = np.concatenate([[False], np.diff(gyro) == 0])
    runs, k = [], 0
    while k < len(t):
        j = k
        while j + 1 < len(t) and same[j + 1]:
            j += 1
        runs.append(t[j] - t[k])
        k = j + 1
    longest = max(runs)
    assert gyro_stuck(t, gyro, MonitorSettings(quantised_hold_max=longest - 0.01)).any()
    assert not gyro_stuck(t, gyro, MonitorSettings(quantised_hold_max=longest + 0.01)).any()


@pytest.mark.parametrize("excess,flagged", [(-0.01, False), (0.01, True)])
def test_a_held_quantised_value_is_stuck_when_ay_leaves_it(excess, flagged):
    """Held at g from row 100 while a_y says v g + 2 Q v + margin + excess for the rest: flagged from 0.3 s after
    the departure began (and only then) when the excess is positive."""
    s = MonitorSettings()
    t, r, _, v = _turn()
    gyro = np.round(r / Q) * Q
    gyro[100:] = gyro[100]
    ay = v * gyro[100] + 2 * Q * v + s.quantised_margin + excess
    ay = np.where(np.arange(len(t)) >= 150, ay, v * gyro)  # departs from row 150
    flag = gyro_stuck(t, gyro, s, ay, v)
    if not flagged:
        assert not flag.any()
    else:
        first = np.flatnonzero(flag)[0]
        assert t[first] == pytest.approx(t[150] + s.quantised_stuck_time, abs=1e-9)
        assert flag[first:].all()


@pytest.mark.parametrize("ay, model, plain, quarter, overpredict", [
    (4.0, 5.0, 1.0, 1.0, 1.0),     # the model asks 1 m/s^2 more than the car has: a tyre beyond its linear range
    (5.0, 4.0, 1.0, 0.75, 0.0),    # the car has more than the model asks: no tyre gives more than its linear force
    (-4.0, -5.0, 1.0, 1.0, 1.0),   # the same to the right
    (-5.0, -4.0, 1.0, 0.75, 0.0),
    (-1.0, 2.0, 3.0, 3.0, 3.0),    # the two disagree in sign: the whole departure
    (0.0, 0.5, 0.5, 0.5, 0.5),     # straight ahead (0 is of either sign): what the model asks
])
def test_saturation_evidence(ay, model, plain, quarter, overpredict):
    """The departure the kinematic path counts: in full (``kinematic_overpredict`` 0, the default), three
    quarters of what the car has beyond the model (0.25, a row of the real-drives study), over-prediction only
    (1)."""
    from evstab.toolkit.estimation.kinematic_path import saturation_evidence
    p = load_vehicle("compact-ev")
    nz = estimation_noise()
    assert nz.kinematic_overpredict == 0.0
    for k, want in ((0.0, plain), (0.25, quarter), (1.0, overpredict)):
        d = design_filter("dakf", p, dataclasses.replace(nz, kinematic_overpredict=k))
        assert saturation_evidence(d, ay, ay - model) == pytest.approx(want, abs=1e-15), k


def test_overprediction_only_ignores_a_stiffness_set_too_low():
    """With the nominal cornering stiffness 40 % low the linear model asks less lateral acceleration than the car
    has in a 4.8 m/s^2 lane change at 80 km/h: the plain departure engages the kinematic path (the estimate moves
    by up to 0.94 deg from the filter without the path), over-prediction only hardly does (0.0025 deg, in the
    transients where the estimate's model leads). Here the engagement helped: 0.103 deg RMS with the plain
    departure, 0.145 with over-prediction only, 0.145 without the path; what the setting costs a car whose
    model is too soft."""
    p = load_vehicle("compact-ev")
    low = dataclasses.replace(p, cornering_stiffness_front=0.6 * p.cornering_stiffness_front,
                              cornering_stiffness_rear=0.6 * p.cornering_stiffness_rear)
    log = simulate(p, "two-track", make_maneuver("sine-lane-change", p, 80 / 3.6, np.radians(2.2)), seed=1).log_columns()
    cols = {k: v for k, v in log.items() if not k.endswith("_true")}
    nz = estimation_noise()
    beta = {name: run_estimator(design_filter("dakf", low, n, nominal=False, kinematic=kin), cols)["beta"]
            for name, n, kin in (("plain", nz, None), ("over", dataclasses.replace(nz, kinematic_overpredict=1.0), None),
                                 ("none", nz, False))}
    assert np.max(np.abs(log["ay_true"])) > 4.0  # a lane change that asks for it (4.76 m/s^2)
    assert np.degrees(np.abs(beta["plain"] - beta["none"]).max()) > 0.5  # 0.94 deg: the plain departure engaged
    assert np.degrees(np.abs(beta["over"] - beta["none"]).max()) < 0.02  # 0.0025 deg: over-prediction hardly

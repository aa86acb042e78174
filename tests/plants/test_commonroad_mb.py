"""The CommonRoad multi-body plant against the package it was ported from.

The reference is the package's own ``vehiclemodels.vehicle_dynamics_mb`` (pure Python,
``math``), evaluated on the same states; the port is evstab's numpy and casadi code.
"""

import casadi as ca
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from evstab.plants import COMMANDS, TRUTH, commonroad_mb as mb, default_disturbance, get_plant, load_vehicle
from evstab.plants.backend import CASADI, NUMPY
from evstab.plants.errors import ModelError
from evstab.plants.maneuvers import step_steer
from evstab.toolkit.loop.simulator import simulate

SETS = (1, 2, 3)


def _kw(s, rate=None):
    return dict(steer_rate_max=s.steer_rate_stock if rate is None else rate, steer_limits=(s.steer_min, s.steer_max),
                accel_limits=(s.a_max, s.v_switch, s.v_min, s.v_max))


def _random_states(set_id, rng, n):
    """States around the package's own init_mb at random speeds, steer, yaw rates and sideslips, every
    state perturbed by 5 % of its size plus 0.01 (suspension, tyre deflections, lateral velocities all
    away from rest); wheels spinning forwards."""
    from vehiclemodels.init_mb import init_mb
    P = mb.package_parameters(set_id)
    out = []
    for _ in range(n):
        x = np.array(init_mb([0.0, 0.0, rng.uniform(-0.3, 0.3), rng.uniform(3, 40), rng.uniform(-3, 3),
                              rng.uniform(-0.8, 0.8), rng.uniform(-0.2, 0.2)], P))
        x = x + rng.normal(size=29) * (0.05 * np.abs(x) + 0.01)
        x[23:27] = np.abs(x[23:27])
        out.append(x)
    return out


def _close(a, ref, scale):
    # The port evaluates the package's expressions in the same float64 arithmetic; they differ only by
    # the order casadi's SX graph or numpy's ufuncs evaluate them (an ulp per operation). Forces of
    # 1e4 N cancel to ~1 N in the suspension and pin-joint sums, which can lift a relative round-off
    # of 1e-16 to ~1e-12 on a small derivative; 1e-9 of each row's scale keeps three decades of margin
    # and still fails on any wrong term (a wrong coefficient moves a derivative by >= 1e-6 relative).
    return np.abs(a - ref) <= 1e-9 * np.maximum(np.abs(ref), scale)


@pytest.mark.parametrize("set_id", SETS)
def test_port_equals_package(set_id, rng):
    """numpy and casadi (the compiled path) equal vehicle_dynamics_mb on 100 random states and inputs,
    stock steering-rate limit, the package's sign(camber)."""
    s = mb.mb_set(set_id)
    q = s.namespace()
    xs, us = ca.SX.sym("x", 29), ca.SX.sym("u", 2)
    F = ca.Function("f", [xs, us], [ca.vertcat(*mb.rhs_sae(xs, us, q, CASADI, smooth_camber=False, **_kw(s)))])
    states = _random_states(set_id, rng, 100)
    inputs = [np.array([rng.uniform(-1, 1), rng.uniform(-12, 12)]) for _ in states]
    refs = np.array([mb.package_rhs(x, u, set_id) for x, u in zip(states, inputs)])
    scale = 1e-6 * np.max(np.abs(refs), axis=0) + 1e-300
    for x, u, ref in zip(states, inputs, refs):
        a = np.array(F(x, u)).ravel()
        b = np.array(mb.rhs_sae(x, u, q, NUMPY, smooth_camber=False, **_kw(s)), float)
        assert np.all(_close(a, ref, scale)), np.max(np.abs(a - ref) / np.maximum(np.abs(ref), scale))
        assert np.all(_close(b, ref, scale))


def test_smooth_camber_is_the_package_with_a_smooth_sign(rng, monkeypatch):
    """With the package's tire-model sign replaced by evstab's smooth_sign the package's function
    equals the smooth port: the smoothing is the only change."""
    import vehiclemodels.utils.tire_model as tm
    monkeypatch.setattr(tm, "sign", lambda v: float(mb.smooth_sign(v, NUMPY)))
    s = mb.mb_set(2)
    q = s.namespace()
    states = _random_states(2, rng, 100)
    for x in states:
        u = np.array([rng.uniform(-1, 1), rng.uniform(-12, 12)])
        ref = mb.package_rhs(x, u, 2)
        mine = np.array(mb.rhs_sae(x, u, q, NUMPY, **_kw(s)), float)
        assert np.all(_close(mine, ref, 1e-6 * np.abs(ref).max()))


def test_smooth_sign_is_sign_beyond_its_width():
    x = np.concatenate([np.linspace(-0.5, -0.01, 200), np.linspace(0.01, 0.5, 200)])
    assert np.array_equal(mb.smooth_sign(x, NUMPY), np.sign(x))  # exactly: the clip makes s = +-1
    inner = np.linspace(-0.0099, 0.0099, 101)
    v = mb.smooth_sign(inner, NUMPY)
    assert np.all(np.abs(v) < 1.0) and np.all(np.diff(v) > 0)  # monotone, inside (-1, 1)
    assert mb.smooth_sign(0.0, NUMPY) == 0.0


def test_camber_smoothing_changes_nothing_beyond_0_02_rad(rng):
    """On states whose four cambers all exceed 0.02 rad in magnitude the smooth and the stock tyre
    give identical derivatives (bit for bit: smooth_sign is exactly sign there)."""
    s = mb.mb_set(1)
    q = s.namespace()
    checked = 0
    for x in _random_states(1, rng, 100):
        x[6] = rng.choice([-1.0, 1.0]) * rng.uniform(0.03, 0.1)  # body roll: cambers follow it
        _, gam = mb.suspension_sae(x, q, NUMPY)
        if min(abs(g) for g in gam) <= 0.02:
            continue
        u = np.array([0.1, 0.5])
        a = np.array(mb.rhs_sae(x, u, q, NUMPY, **_kw(s)), float)
        b = np.array(mb.rhs_sae(x, u, q, NUMPY, smooth_camber=False, **_kw(s)), float)
        assert np.array_equal(a, b)
        checked += 1
    assert checked >= 20


def _straight_ay(smooth: bool, dt: float, seconds: float = 1.0):
    """Lateral acceleration of set 1 driving straight at 80 km/h, numpy RK4 on the port."""
    pl = mb._Plant(1, mb.STEER_RATE_DEFAULT)
    x = mb.static_equilibrium(1, mb.STEER_RATE_DEFAULT, 80 / 3.6).copy()
    x[mb.STATES.index("roll")] += 1e-4  # a nudge: cambers around zero

    def rhs(xx):
        xs = mb._iso_to_sae(xx)
        fs, (_, sy) = mb.rhs_sae(xs, [0.0, 0.0], pl.q, NUMPY, smooth_camber=smooth, forces=True, **pl.kw)
        return np.append(np.array(fs, float) * mb.SAE_SIGN, 0.0), -sy / pl.q.m_s

    ay = []
    for _ in range(int(round(seconds / dt))):
        k1, a = rhs(x)
        k2, _ = rhs(x + dt / 2 * k1)
        k3, _ = rhs(x + dt / 2 * k2)
        k4, _ = rhs(x + dt * k3)
        x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        ay.append(a)
    return np.array(ay)[int(0.2 / dt):]


def test_straight_driving_does_not_chatter():
    """The stock sign(camber) makes straight driving chatter at the step; the smoothed tyre does not."""
    stock = _straight_ay(False, 5e-4)
    smooth = _straight_ay(True, 5e-4)
    smooth_coarse = _straight_ay(True, 1e-3)
    # the jump of the stock tyre's camber shift is 2 p_vy1 F_z ~ 200 N per tyre: ~0.1 m/s^2 of noise
    assert np.std(stock) > 0.02
    # smoothed: below 1 mm/s^2 and the same at two steps (no step-dependent noise)
    assert np.std(smooth) < 1e-3
    assert abs(np.mean(smooth_coarse) - np.mean(smooth)) < 1e-4


@pytest.mark.parametrize("set_id", (1, 3))
def test_iso_signs(set_id):
    """Left steer: positive yaw rate, lateral acceleration and roll (left side up); positive
    rear-right-minus-left torque on a straight road turns the car left."""
    p = load_vehicle(f"commonroad-{set_id}")
    r = simulate(p, f"commonroad-mb:{set_id}", step_steer(60 / 3.6, np.deg2rad(2.0), start=0.2, duration=3.0))
    end = slice(-500, None)
    assert r.truth["yaw_rate"][end].mean() > 0.1
    assert r.truth["ay"][end].mean() > 1.0
    assert r.truth["roll"][end].mean() > 0.0
    assert r.truth["y"][-1] > 0.0  # and the car went left in the earth frame
    model = get_plant(f"commonroad-mb:{set_id}")
    x = model.initial_state(p, 20.0)
    cmd = COMMANDS.pack(steer=0.0, yaw_moment=500.0, speed_ref=20.0, drive_on=1.0, steer_rate=0.0)  # T_rr > T_rl
    u = model.command_map(cmd, x, p)
    assert u[mb.INPUTS.index("torque_rr")] > 0 > u[mb.INPUTS.index("torque_rl")]
    from evstab.toolkit.kernels.compiled import compiled_plant
    n = 1000
    C = np.repeat(cmd[:, None], n, axis=1)
    assert COMMANDS[1] == "yaw_moment"
    X, Y = compiled_plant(model, p, 1e-3).rollout(x, C, default_disturbance())
    # the torques spin the wheels up, the slip makes the forces: the car yaws left within a second
    assert Y[TRUTH.index("yaw_rate"), -1] > 0.01
    assert X[model.state_index("omega_rr"), -1] > X[model.state_index("omega_rl"), -1]


def _package_steady_yaw_rate(set_id, speed, steer):
    """The package's vehicle_dynamics_mb integrated by scipy (LSODA), road-wheel angle held (state x3,
    SAE sign: + right, so a left steer is negative), speed held by the acceleration input."""
    from vehiclemodels.init_mb import init_mb
    from vehiclemodels.vehicle_dynamics_mb import vehicle_dynamics_mb
    P = mb.package_parameters(set_id)
    x0 = np.array(init_mb([0.0, 0.0, -steer, speed, 0.0, 0.0, 0.0], P))

    def rhs(t, x):
        return vehicle_dynamics_mb(list(x), [0.0, 5.0 * (speed - x[3])], P)

    sol = solve_ivp(rhs, (0.0, 6.0), x0, method="LSODA", rtol=1e-9, atol=1e-9)
    return -sol.y[5, -1]  # ISO yaw rate


@pytest.mark.parametrize("set_id", (1, 3))
def test_cli_step_steer_reaches_the_package_steady_state(set_id, tmp_path):
    """`evstab simulate --plant commonroad-mb:N --maneuver step-steer --speed 60 --amplitude 1.0` ends
    at the package's own steady yaw rate for the same road-wheel angle within 2 % (measured 0.01 %:
    the servo, the smoothed camber sign and RK4 at 1 ms change nothing visible at 1 deg)."""
    from evstab.toolkit.cli import main
    from evstab.toolkit.logs.drivelog import read_log_csv
    out = tmp_path / "run.csv"
    assert main(["simulate", "--plant", f"commonroad-mb:{set_id}", "--vehicle", f"commonroad-{set_id}",
                 "--maneuver", "step-steer", "--speed", "60", "--amplitude", "1.0", "--out", str(out)]) == 0
    log = read_log_csv(out)
    ours = float(np.mean(log["yaw_rate_true"][-200:]))
    ref = _package_steady_yaw_rate(set_id, 60 / 3.6, np.deg2rad(1.0))
    assert ours == pytest.approx(ref, rel=0.02)


def test_sensors_read_the_multibody_truth():
    """The same sensor models on the MB truth: speed from the front wheels with the set's R_w, GPS course
    = yaw + sideslip at the fixes (noise 0.04 m/s per axis at HDOP 0.9: < 0.5 deg at 60 km/h)."""
    p = load_vehicle("compact-ev")  # what a design believes; the truth is the set's
    r = simulate(p, "commonroad-mb:2", step_steer(60 / 3.6, np.deg2rad(2.0), start=0.2, duration=3.0), seed=3)
    tr, m = r.truth, r.measurements
    assert np.max(np.abs(m["speed"] - tr["vx"])) < 0.1  # R_w 0.344 m (compact-ev's 0.31 would read 10 % low)
    fix = np.isfinite(m["gps_course"])
    assert fix.sum() == 15
    err = np.angle(np.exp(1j * (m["gps_course"][fix] - tr["yaw"][fix] - tr["beta"][fix])))
    assert np.max(np.abs(err)) < np.deg2rad(0.5)
    assert r.meta["plant"] == "commonroad-mb:2"


def test_spec_parsing():
    assert mb.parse_spec("commonroad-mb:3") == (3, mb.STEER_RATE_DEFAULT)
    assert mb.parse_spec("commonroad-mb:1:0.4") == (1, 0.4)
    assert get_plant("commonroad-mb:1:0.4").name == "commonroad-mb:1:0.4"
    for bad, words in (("commonroad-mb:7", "unknown parameter set 7"), ("commonroad-mb:x", "not a number"),
                       ("commonroad-mb:1:fast", "steering-rate limit 'fast'"), ("commonroad-mb", "expected")):
        with pytest.raises(ModelError, match=words):
            get_plant(bad)


def test_stock_steering_rate_limits_the_servo():
    """With the stock 0.4 rad/s the road-wheel angle ramps at 0.4 rad/s; with the default it follows."""
    man = step_steer(20.0, np.deg2rad(10.0), start=0.2, rise=0.1, duration=1.0)
    p = load_vehicle("commonroad-1")
    for spec, rate in (("commonroad-mb:1:0.4", 0.4), ("commonroad-mb:1", mb.STEER_RATE_DEFAULT)):
        model = get_plant(spec)
        from evstab.toolkit.kernels.compiled import compiled_plant
        from evstab.plants import COMMANDS
        n = 1000
        t = np.arange(n) * 1e-3
        cmd = np.zeros((len(COMMANDS), n))
        cmd[0] = man.steer(t)
        cmd[4] = np.diff(cmd[0], prepend=0.0) / 1e-3
        cmd[2], cmd[3] = 20.0, 1.0
        X, _ = compiled_plant(model, p, 1e-3).rollout(model.initial_state(p, 20.0), cmd, default_disturbance())
        steer = X[model.state_index("steer"), :n]
        peak_rate = np.max(np.diff(steer)) / 1e-3
        want = min(rate, np.deg2rad(10.0) / 0.1)
        assert peak_rate == pytest.approx(want, rel=0.02)  # RK4 of a clipped rate: exact up to the corners

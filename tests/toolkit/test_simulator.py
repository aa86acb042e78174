"""The simulator: determinism, compiled vs virtual machine vs numpy, closed loop, sign conventions."""

import numpy as np
import pytest

from evstab.plants import COMMANDS, TRUTH, default_disturbance, get_plant, load_vehicle
from evstab.plants.disturbances import Disturbances, Friction, default_wind
from evstab.plants.maneuvers import dlc_000, iso3888_1, make_maneuver, step_steer
from evstab.plants.sensors import SensorConfig, wrap_angle
from evstab.toolkit.kernels.compiled import CompiledPlant
from evstab.toolkit.loop.simulator import simulate

DEG = np.pi / 180


def rk4_numpy(model, p, x0, cmd, w, dt, n_sub):
    """Independent re-implementation of the integrator in plain numpy (reference)."""
    x = x0.copy()
    xs = [x.copy()]
    h = dt / n_sub
    for k in range(cmd.shape[1]):
        def rhs(xx):
            return model.f(xx, model.command_map(cmd[:, k], xx, p), w, p)
        for _ in range(n_sub):
            k1 = rhs(x)
            k2 = rhs(x + h / 2 * k1)
            k3 = rhs(x + h / 2 * k2)
            k4 = rhs(x + h * k3)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        xs.append(x.copy())
    return np.array(xs).T


@pytest.mark.parametrize("plant", ["bicycle", "bicycle-roll", "two-track"])
def test_compiled_vm_and_numpy_agree(plant):
    p = load_vehicle("sedan-000")  # needs 2 RK4 sub-steps on the two-track: exercises them
    model = get_plant(plant)
    n = 300
    cmd = np.zeros((len(COMMANDS), n))
    cmd[0] = 0.03 * np.sin(np.arange(n) * 0.02)
    cmd[1] = 300.0
    cmd[2], cmd[3] = 20.0, 1.0
    w = default_disturbance(0.9)
    x0 = model.initial_state(p, 20.0)
    c = CompiledPlant(model, p, 1e-3, compile=True)
    v = CompiledPlant(model, p, 1e-3, compile=False)
    Xc, Yc = c.rollout(x0, cmd, w)
    Xv, Yv = v.rollout(x0, cmd, w)
    Xn = rk4_numpy(model, p, x0, cmd, w, 1e-3, c.n_sub)
    # C (gcc -O3, no fast-math), casadi VM and numpy evaluate the same arithmetic;
    # only operation order differs: agreement to 1e-12 of each state's scale.
    scale = np.maximum(np.abs(Xn).max(axis=1, keepdims=True), 1.0)
    np.testing.assert_allclose(Xc / scale, Xn / scale, atol=1e-12)
    np.testing.assert_allclose(Xv / scale, Xn / scale, atol=1e-12)
    np.testing.assert_allclose(Yc, Yv, rtol=1e-12, atol=1e-12)
    # stepping one sample at a time gives the rollout
    x = x0
    for k in range(5):
        x, y = c.step(x, cmd[:, k], w)
        np.testing.assert_allclose(y, Yc[:, k], rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(x, Xc[:, 5], rtol=1e-13, atol=1e-13)


def test_rollout_chunk_boundaries():
    # runs that are not a multiple of the compiled chunk length
    p = load_vehicle("compact-ev")
    model = get_plant("bicycle")
    c = CompiledPlant(model, p, 1e-3)
    for n in (1, 1999, 2000, 2001, 4500):
        cmd = np.zeros((len(COMMANDS), n))
        cmd[0], cmd[2] = 0.01, 15.0
        X, Y = c.rollout(np.zeros(5), cmd, default_disturbance())
        assert X.shape == (5, n + 1) and Y.shape == (len(TRUTH), n)
        Xn = rk4_numpy(model, p, np.zeros(5), cmd[:, :min(n, 50)], default_disturbance(), 1e-3, 1)
        np.testing.assert_allclose(X[:, :Xn.shape[1]], Xn, rtol=1e-12, atol=1e-14)  # operation order only


def test_deterministic_for_a_seed(compact):
    man = make_maneuver("sine-lane-change", compact, 25 / 3.6)
    a = simulate(compact, "two-track", man, seed=5)
    b = simulate(compact, "two-track", man, seed=5)
    c = simulate(compact, "two-track", man, seed=6)
    for k in a.measurements:
        np.testing.assert_array_equal(a.measurements[k], b.measurements[k])
    assert not np.array_equal(a.measurements["yaw_rate"], c.measurements["yaw_rate"])
    np.testing.assert_array_equal(a.truth["beta"], c.truth["beta"])  # the seed only drives the sensors


@pytest.mark.parametrize("plant", ["bicycle", "bicycle-roll", "two-track"])
def test_sign_conventions(plant):
    # Low speed: sideslip at the CG is positive in a left turn (l_r / L > 0 at v -> 0),
    # so course - yaw > 0 as well.
    p = load_vehicle("compact-ev")
    man = step_steer(15 / 3.6, 3 * DEG, duration=4.0)
    r = simulate(p, plant, man, sensors=SensorConfig(gps_velocity_noise=0.0))
    tr, me = r.truth, r.measurements
    assert tr["yaw_rate"][-1] > 0 and tr["ay"][-1] > 0 and tr["beta"][-1] > 0
    fix = np.isfinite(me["gps_course"]) & (r.t > 3.0)
    d = wrap_angle(me["gps_course"][fix] - tr["yaw"][fix])
    assert np.all(d > 0)
    np.testing.assert_allclose(d, tr["beta"][fix], atol=1e-9)  # antenna at the CG: course - yaw = beta


def test_path_following_tracks_the_lanes():
    p = load_vehicle("sedan-000")
    man = dlc_000(120 / 3.6)
    r = simulate(p, "two-track", man, disturbances=Disturbances(friction=Friction(mu=0.9)))
    off = man.path.lateral_offset(r.truth["x"][::20], r.truth["y"][::20])
    # the pure-pursuit driver cuts corners by a fraction of a metre at 120 km/h
    assert np.abs(off).max() < 0.5
    assert r.truth["y"].max() > 3.0


def test_iso3888_1_driver_stays_between_cones_at_moderate_speed():
    p = load_vehicle("compact-ev")
    man = iso3888_1(60 / 3.6, p.width)
    r = simulate(p, "two-track", man)
    from evstab.plants.maneuvers import iso3888_1_lanes
    g = iso3888_1_lanes(p.width)
    x, y = r.truth["x"], r.truth["y"]
    half = p.width / 2
    for sec, lane in ((0, "lane1"), (2, "lane3"), (4, "lane5")):
        a, b = g["sections"][sec]
        inside = (x >= a) & (x <= b)
        lo, hi = g[lane]
        # the car's body (CG +- half width, ignoring yaw) stays inside the lane
        assert np.all(y[inside] - half > lo - 0.05) and np.all(y[inside] + half < hi + 0.05)


def test_wind_pushes_left_and_yaws():
    p = load_vehicle("micro-ev")
    man = step_steer(25 / 3.6, 0.0, duration=8.0)
    r = simulate(p, "bicycle", man, disturbances=Disturbances(wind=default_wind(p)))
    assert r.truth["y"][-1] > 0.1  # positive lateral force pushes left
    assert r.disturbances["lateral_force"][int(5 / 1e-3)] == pytest.approx(default_wind(p).force, rel=1e-12)


def test_csv_round_trip(tmp_path, compact):
    from evstab.toolkit.logs.drivelog import read_log_csv
    r = simulate(compact, "two-track", make_maneuver("step-steer", compact, 50 / 3.6),
                 sensors=SensorConfig(gps_outages=((2.0, 3.0),)))
    path = tmp_path / "log.csv"
    r.write_csv(path)
    log = read_log_csv(path)
    cols = r.log_columns()
    for k, v in cols.items():
        # written with 12 significant digits
        np.testing.assert_allclose(log[k], v, rtol=1e-11, atol=1e-12, equal_nan=True, err_msg=k)
    assert np.isnan(log["gps_course"][(r.t >= 2.0) & (r.t < 3.0)]).all()
    assert not any(k.endswith("_true") for k in log.without_truth().columns)
    assert not list(tmp_path.glob("*.part"))  # no temporary left behind


def test_unsupported_plant_params_named():
    from evstab.plants import ParameterError, VehicleParams
    p = VehicleParams(name="bare", mass=1500, yaw_inertia=2500, lf=1.2, lr=1.4,
                      cornering_stiffness_front=40000, cornering_stiffness_rear=45000)
    with pytest.raises(ParameterError, match="two-track.*wheel_radius"):
        simulate(p, "two-track", step_steer(10.0, 0.01))
    simulate(p, "bicycle", step_steer(10.0, 0.01, duration=1.0))  # the bicycle needs nothing more


def test_commands_recorded(compact):
    r = simulate(compact, "two-track", make_maneuver("sine-with-dwell", compact, 80 / 3.6))
    assert set(r.commands) == set(COMMANDS)
    assert r.commands["drive_on"][0] == 1.0 and r.commands["drive_on"][-1] == 0.0


def test_reading_selected_columns(tmp_path, compact):
    from evstab.toolkit.logs.drivelog import REQUIRED, read_log_csv
    r = simulate(compact, "bicycle", make_maneuver("step-steer", compact, 50 / 3.6))
    path = tmp_path / "log.csv"
    r.write_csv(path)
    full = read_log_csv(path)
    part = read_log_csv(path, columns=("ay",))
    assert set(part.columns) == set(REQUIRED) | {"ay"}
    for k in part.columns:
        np.testing.assert_array_equal(part[k], full[k])
    # a damaged column that is not asked for is neither parsed nor reported
    text = path.read_text().splitlines()
    head = text[0].split(",")
    row = text[5].split(",")
    row[head.index("wheel_speed_fl")] = "oops"
    text[5] = ",".join(row)
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(text) + "\n")
    assert len(read_log_csv(bad, columns=("ay",))) == len(full)
    from evstab.toolkit.logs.drivelog import LogFormatError
    with pytest.raises(LogFormatError, match="row 6, column 'wheel_speed_fl'"):
        read_log_csv(bad)


def test_the_run_figure_shows_the_ecu_with_a_controller(tmp_path):
    # with a controller: the driver's steer beside the ECU's command, the ECU's estimates and references,
    # its yaw moment and authority; without one, the six panels of the car alone
    import numpy as np

    from evstab.plants import load_vehicle
    from evstab.plants.maneuvers import step_steer
    from evstab.toolkit.loop.plotting import plot_run
    from evstab.toolkit.loop.simulator import simulate
    p = load_vehicle("compact-ev")
    man = step_steer(60 / 3.6, np.radians(2.0), duration=2.0)
    panels = plot_run(simulate(p, "two-track", man, controller="two-dof"), tmp_path / "ctl.png", man)
    assert (tmp_path / "ctl.png").stat().st_size > 10000 and len(panels) == 8
    assert panels["front road-wheel angle [deg]"] == ["driver", "ECU command"]
    assert {"ECU estimate", "ECU reference"} <= set(panels["yaw rate [deg/s]"]) & set(panels["sideslip [deg]"])
    assert panels["yaw moment [N m]"] == ["ECU command", "applied (actuators)"]
    alone = plot_run(simulate(p, "two-track", man), tmp_path / "alone.png", man)
    assert len(alone) == 6 and alone["front road-wheel angle [deg]"] == ["steer command"]


def test_a_rollover_error_crosses_a_process_boundary():
    """A worker process's run that rolled over (studies run cases in a process pool) reaches the caller as the
    same error with its time: the exception pickles with both of its arguments."""
    import pickle

    from evstab.toolkit.loop.simulator import RolloverError
    e = pickle.loads(pickle.dumps(RolloverError("commonroad-mb:1 rolled over at t = 2.345 s", 2.345)))
    assert isinstance(e, RolloverError) and e.t == 2.345 and str(e) == "commonroad-mb:1 rolled over at t = 2.345 s"


@pytest.mark.parametrize("plant", ["bicycle-roll", "two-track"])
def test_the_integrator_against_an_independent_oracle(plant):
    """The compiled plant's RK4 at 1 kHz against scipy's DOP853 at rtol 1e-11 on the same model (commands held
    over each sample), through 0.6 s of a growing sine steer with drive torque at 72 km/h: an integrator
    written elsewhere, so a wrong stage weight or sub-step in evstab's would show here, which the numpy RK4
    above (the same formula) cannot."""
    from scipy.integrate import solve_ivp
    p = load_vehicle("compact-ev")
    model = get_plant(plant)
    n = 600
    cmd = np.zeros((len(COMMANDS), n))
    cmd[0] = 0.04 * np.sin(np.arange(n) * 0.01) * np.linspace(0.2, 1.0, n)
    cmd[1] = 200.0
    cmd[2], cmd[3] = 20.0, 1.0
    w = default_disturbance(0.9)
    x0 = np.asarray(model.initial_state(p, 20.0), float)
    c = CompiledPlant(model, p, 1e-3, compile=True)
    X, _ = c.rollout(x0, cmd, w)
    x = x0.copy()
    ref = [x.copy()]
    for k in range(n):
        sol = solve_ivp(lambda t, xx: np.asarray(model.f(xx, model.command_map(cmd[:, k], xx, p), w, p), float).ravel(),
                        (0.0, 1e-3), x, method="DOP853", rtol=1e-11, atol=1e-13)
        x = sol.y[:, -1]
        ref.append(x.copy())
    ref = np.array(ref).T
    scale = np.maximum(np.abs(ref).max(axis=1, keepdims=True), 1.0)
    err = np.abs(X - ref) / scale
    # measured: at most 1.3e-7 of a state's scale (the two-track's filtered longitudinal acceleration, whose
    # load-transfer lag and the wheels' spin are the model's fastest modes), 4.7e-9 rad/s of yaw rate; a
    # second-order integrator (Heun) at 1 kHz is off by 3.3e-6 (bicycle-roll) and 8.1e-5 (two-track) of a
    # state's scale against the same oracle (measured), so 1e-6 tells them apart
    assert err.max() < 1e-6, err.max(axis=1)

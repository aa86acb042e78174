"""The loop is closed once (``toolkit.loop.closed_loop.loop_step``): everyone runs that step, and its
compiled form equals its numpy form."""

import dataclasses

import numpy as np
import pytest

from evstab.plants import load_vehicle
from evstab.plants.disturbances import Disturbances, default_wind
from evstab.plants.maneuvers import iso3888_1, step_steer
from evstab.plants.sensors import SensorConfig
from evstab.toolkit.loop import closed_loop, loop_program
from evstab.toolkit.design import stability
from evstab.toolkit.loop.closed_loop import LoopError
from evstab.toolkit.estimation import design_filter
from evstab.toolkit.loop.simulator import simulate


def test_simulator_compiled_loop_and_linearisation_all_run_the_one_loop_step(monkeypatch):
    from evstab.controllers.two_dof import TwoDofDesign
    calls = []
    original = closed_loop.loop_step

    def spy(spec, model, sp, z, u, theta, o=closed_loop.NUMPY):
        calls.append(o)
        return original(spec, model, sp, z, u, theta, o)

    monkeypatch.setattr(closed_loop, "loop_step", spy)
    monkeypatch.setattr(loop_program, "_CACHE", {})
    monkeypatch.setattr(stability, "_JAC", {})
    p = load_vehicle("micro-ev")
    man = step_steer(25 / 3.6, np.radians(3.0), start=0.1, duration=0.05)
    simulate(p, "two-track", man, controller="two-dof", compile=False)  # numpy, sample by sample
    assert len(calls) == 50
    simulate(p, "two-track", man, controller="two-dof")  # traced once (for the lane kernel), compiled
    assert len(calls) == 51
    simulate(p, "two-track", iso3888_1(25 / 3.6, p.width), controller="none")  # path driver: same trace kind
    assert len(calls) == 52
    stability.estimator_loop(TwoDofDesign(p.as_nominal()), design_filter("dakf", p, control=True), 10.0, gps_rate=5.0)
    # the analysis traced the same step (bicycle truth) twice: for the lane kernel that steps it to the
    # start of a GPS period, and for casadi to differentiate (schedule reads inline)
    assert len(calls) == 54


@pytest.mark.parametrize("controller", ["two-dof", "two-dof-true", "yaw-pi", "none"])
def test_compiled_loop_equals_numpy_loop(controller):
    p = load_vehicle("micro-ev")
    # a step of 10 deg at 25 km/h, into the law's band (the 2-DOF law acts: up to 230 N m and 0.8 deg of steer)
    man = step_steer(25 / 3.6, np.radians(10.0), start=0.3, duration=1.5)
    dist = Disturbances(wind=default_wind(p, 0.5, 1.0))
    sens = SensorConfig(gyro_bias=0.002, gps_outages=((0.8, 1.1),))
    r = simulate(p, "two-track", man, controller=controller, disturbances=dist, sensors=sens, seed=3)
    s = simulate(p, "two-track", man, controller=controller, disturbances=dist, sensors=sens, seed=3, compile=False)
    # same equations, same noise; the lane kernel against numpy: evaluation order, its vector math
    # (<= 2 ulp a call) and reciprocal products (<= 1 ulp) only
    for k in ("beta", "yaw_rate", "vx", "yaw", "ay"):
        np.testing.assert_allclose(r.truth[k], s.truth[k], rtol=0, atol=1e-9, err_msg=k)
    for k in ("steer", "beta_est", "yaw_rate_ref"):
        np.testing.assert_allclose(r.commands[k], s.commands[k], rtol=0, atol=1e-9, err_msg=k)
    np.testing.assert_allclose(r.commands["yaw_moment"], s.commands["yaw_moment"], rtol=0, atol=1e-6)  # N m
    np.testing.assert_allclose(r.measurements["gps_course"], s.measurements["gps_course"], rtol=0, atol=1e-12,
                               equal_nan=True)
    if controller == "none":
        np.testing.assert_array_equal(r.commands["yaw_moment_cmd"], 0.0)
        np.testing.assert_allclose(r.commands["steer_cmd"], r.commands["steer_driver"], rtol=0, atol=0)
    else:
        assert np.max(np.abs(r.commands["yaw_moment"])) > 1.0  # the controller acted


def test_path_driver_around_the_loop_compiled_equals_numpy():
    p = load_vehicle("micro-ev")
    full = iso3888_1(25 / 3.6, p.width)
    man = dataclasses.replace(full, duration=1.0)
    r = simulate(p, "two-track", man, controller="two-dof", seed=1)
    s = simulate(p, "two-track", man, controller="two-dof", seed=1, compile=False)
    np.testing.assert_allclose(r.truth["y"], s.truth["y"], rtol=0, atol=1e-9)  # m, rounding only
    np.testing.assert_allclose(r.commands["steer_driver"], s.commands["steer_driver"], rtol=0, atol=1e-9)


def test_loop_with_model_error_and_latency_compiled_equals_numpy():
    p = load_vehicle("compact-ev")
    true = dataclasses.replace(p, cornering_stiffness_front=0.7 * p.cornering_stiffness_front,
                               cornering_stiffness_rear=0.7 * p.cornering_stiffness_rear, mass=1.1 * p.mass)
    man = step_steer(60 / 3.6, np.radians(2.0), start=0.3, duration=1.2)
    sens = SensorConfig(gps_latency=0.05, gyro_bias=0.003, gyro_scale_error=0.01)
    r = simulate(true, "two-track", man, controller="two-dof", sensors=sens, nominal=p, seed=2)
    s = simulate(true, "two-track", man, controller="two-dof", sensors=sens, nominal=p, seed=2, compile=False)
    for k in ("beta", "yaw_rate"):
        np.testing.assert_allclose(r.truth[k], s.truth[k], rtol=0, atol=1e-9, err_msg=k)  # rounding only
    np.testing.assert_allclose(r.commands["beta_est"], s.commands["beta_est"], rtol=0, atol=1e-9)


def test_the_loop_refuses_what_it_cannot_do():
    p = load_vehicle("micro-ev")
    man = step_steer(7.0, 0.05, duration=0.5)
    with pytest.raises(LoopError, match="latency"):
        simulate(p, "two-track", man, controller="two-dof", sensors=SensorConfig(gps_latency=0.0105))
    with pytest.raises(LoopError, match="double-layer"):
        simulate(p, "two-track", man, controller="two-dof", estimator="double-layer")
    with pytest.raises(Exception, match="max_motor_torque"):
        simulate(load_vehicle("sedan-000"), "two-track", man, controller="two-dof")


def test_sensors_sample_the_plant_at_the_start_of_the_period():
    # the ECU's gyro reading at sample k is the plant's yaw rate at t_k (no extra sample of delay),
    # the same instant the logged truth describes
    p = load_vehicle("micro-ev")
    man = step_steer(25 / 3.6, np.radians(5.0), start=0.1, duration=0.6)
    sens = SensorConfig(gyro_noise=0.0)
    r = simulate(p, "two-track", man, controller="two-dof", sensors=sens)
    np.testing.assert_allclose(r.measurements["yaw_rate"], r.truth["yaw_rate"], rtol=0, atol=1e-15)


def test_a_design_folder_ecu_runs_in_the_loop():
    # an EcuDesign (what `evstab export` prints) runs as the loop's ECU, with its own calibration
    from evstab.controllers.two_dof import TwoDofDesign
    from evstab.toolkit.ecu.step import EcuDesign
    # (the law always acting, so that its gains show in a step the supervision would leave to the driver)
    p = load_vehicle("micro-ev")
    law = TwoDofDesign(p.as_nominal(), k_beta=9.0, always_active=True)
    ecu = EcuDesign.from_designs(design_filter("dakf", p, control=True), law)
    man = step_steer(25 / 3.6, np.radians(4.0), start=0.2, duration=1.0)
    a = simulate(p, "two-track", man, controller="two-dof", design=ecu)
    b = simulate(p, "two-track", man, controller="two-dof", design=law)
    np.testing.assert_array_equal(a.truth["beta"], b.truth["beta"])  # the same ECU, built two ways
    c = simulate(p, "two-track", man, controller="two-dof", design=TwoDofDesign(p.as_nominal(), always_active=True))
    assert np.max(np.abs(a.commands["yaw_moment"] - c.commands["yaw_moment"])) > 1.0  # K_beta 9 is not 5
    # a law that always acts leaves the driver's drive torque alone (the paper's controller has no drive cut)
    assert np.all(a["drive_share"] == 1.0) and np.all(a["active"] == 1.0)


def test_a_passive_ecu_leaves_the_car_as_the_driver_drives_it():
    # the steer reaches the wheels through a superposition gear (controllers.actuators): an ECU that corrects
    # nothing (controller "none", the driver passed through) makes the very car the driver makes alone (no ECU,
    # no actuators), through a quick path-following lane change whose steer rate is beyond the servo's
    p = load_vehicle("compact-ev")
    man = iso3888_1(90 / 3.6, p.width)
    alone = simulate(p, "two-track", man, controller=None, seed=0)
    passive = simulate(p, "two-track", man, controller="none", seed=0)
    assert np.abs(np.diff(passive.commands["steer"])).max() / 1e-3 > np.deg2rad(20.0)  # a quick driver
    for k in ("x", "y", "yaw_rate", "beta"):
        assert np.array_equal(alone.truth[k], passive.truth[k]), k
    assert np.array_equal(passive.commands["steer"], passive.commands["steer_driver"])

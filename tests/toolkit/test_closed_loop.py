"""The compiled stability loop equals the loop the simulator steps in Python."""

import numpy as np
import pytest

from plants import load_vehicle
from plants.disturbances import Disturbances, default_wind
from plants.maneuvers import sine_with_dwell, step_steer
from plants.sensors import SensorConfig
from toolkit.closed_loop import compiled_loop_run
from toolkit.simulator import simulate


@pytest.mark.parametrize("controller", ["two-dof", "two-dof-true"])
def test_compiled_loop_matches_python_loop(controller):
    p = load_vehicle("micro-ev")
    man = step_steer(25 / 3.6, np.radians(5.0), start=1.0, duration=4.0)
    dist = Disturbances(wind=default_wind(p, 2.0, 3.0))
    sens = SensorConfig(gyro_bias=0.002, gps_outages=((2.5, 3.0),))
    r = compiled_loop_run(p, man, controller=controller, disturbances=dist, sensors=sens, seed=3)
    s = simulate(p, "two-track", man, controller=controller, disturbances=dist, sensors=sens, seed=3)
    # same equations, same noise, same order: only floating-point evaluation order differs
    for k in ("beta", "yaw_rate", "vx", "yaw"):
        np.testing.assert_allclose(r["truth"][k], s.truth[k], rtol=0, atol=1e-9, err_msg=k)
    for k in ("steer", "beta_est", "yaw_rate_ref"):
        np.testing.assert_allclose(r["commands"][k], s.commands[k], rtol=0, atol=1e-9, err_msg=k)
    np.testing.assert_allclose(r["commands"]["yaw_moment"], s.commands["yaw_moment"], rtol=0, atol=1e-6)  # N m


def test_compiled_loop_at_the_limit_matches_too():
    # the saturating FMVSS case, where every branch (limits, allocation, gating) is exercised
    p = load_vehicle("compact-ev")
    man = sine_with_dwell(80 / 3.6, np.radians(5 * 22.13) / p.steering_ratio)
    r = compiled_loop_run(p, man)
    s = simulate(p, "two-track", man, controller="two-dof")
    # a spinning car amplifies rounding differences; 1e-6 rad over 6 s of a spin
    np.testing.assert_allclose(r["truth"]["yaw_rate"], s.truth["yaw_rate"], rtol=0, atol=1e-6)


def test_compiled_loop_rejects_what_it_cannot_do():
    p = load_vehicle("micro-ev")
    with pytest.raises(ValueError, match="latency"):
        compiled_loop_run(p, step_steer(7.0, 0.05), sensors=SensorConfig(gps_latency=0.0105))


def test_compiled_loop_with_model_error_and_latency_matches_python_loop():
    import dataclasses
    p = load_vehicle("compact-ev")
    true = dataclasses.replace(p, cornering_stiffness_front=0.7 * p.cornering_stiffness_front,
                               cornering_stiffness_rear=0.7 * p.cornering_stiffness_rear, mass=1.1 * p.mass)
    man = step_steer(60 / 3.6, np.radians(2.0), start=1.0, duration=3.0)
    sens = SensorConfig(gps_latency=0.05, gyro_bias=0.003, gyro_scale_error=0.01)
    r = compiled_loop_run(true, man, sensors=sens, nominal=p, seed=2)
    s = simulate(true, "two-track", man, controller="two-dof", sensors=sens, nominal=p, seed=2)
    for k in ("beta", "yaw_rate"):
        np.testing.assert_allclose(r["truth"][k], s.truth[k], rtol=0, atol=1e-9, err_msg=k)  # rounding only
    np.testing.assert_allclose(r["commands"]["beta_est"], s.commands["beta_est"], rtol=0, atol=1e-9)

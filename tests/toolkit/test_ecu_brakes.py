"""The ECU's allocation to the friction brakes (controllers.allocation in toolkit.ecu.step, the hydraulic unit and
the plant's brakes in the loop): compact-ev on the two-track plant."""

import dataclasses

import numpy as np
import pytest

from evstab.controllers.allocation import AllocationDesign, brake_yaw_capacity
from evstab.plants import load_vehicle
from evstab.plants.disturbances import Disturbances, Friction
from evstab.plants.errors import ParameterError
from evstab.plants.maneuvers import make_maneuver
from evstab.plants.model import brake_yaw_moment
from evstab.toolkit.ecu.step import INPUTS, OUTPUTS, ecu_step
from evstab.toolkit.loop.loop_ecu import loop_ecu
from evstab.toolkit.loop.simulator import simulate

WHEELS = ("fl", "fr", "rl", "rr")


@pytest.fixture(scope="module")
def car():
    return load_vehicle("compact-ev")


@pytest.fixture(scope="module")
def lane_change(car):
    """ISO 3888-1 at 100 km/h on mu 0.5, seed 0: the car alone, the motors, the motors through an allocation in
    ``motors`` mode, and the brakes alone."""
    man = make_maneuver("iso3888-1", car, 100 / 3.6)
    road = Disturbances(friction=Friction(mu=0.5))
    runs = {"alone": simulate(car, "two-track", man, disturbances=road, seed=0)}
    for name, alloc in (("motors", None), ("allocated motors", "motors"), ("brakes", "brakes")):
        d = loop_ecu("two-dof", car, allocation=alloc).ecu
        runs[name] = simulate(car, "two-track", man, disturbances=road, seed=0, controller="two-dof", design=d)
    return runs


def test_the_motors_mode_is_the_motors_alone_to_the_bit(lane_change):
    """An allocation in ``motors`` mode changes nothing: every command as without one, no brake torque."""
    a, b = lane_change["motors"].commands, lane_change["allocated motors"].commands
    for k in ("steer_cmd", "yaw_moment_cmd", "beta_est", "active", "fault_word"):
        assert np.array_equal(a[k], b[k]), k
    for c in (a, b):
        assert all(np.all(c[f"brake_{w}"] == 0.0) for w in WHEELS) and np.all(c["yaw_moment_brakes_cmd"] == 0.0)


def test_the_brakes_alone_make_the_laws_moment_and_no_wheel_locks(car, lane_change):
    """A conventional ESC: no motor moment and no steer correction (the steer command is the driver's, exactly).
    The moment the wheel brakes made (their torques through plants.model.brake_yaw_moment) has the sign of the
    ECU's brake moment: weighted by the two, they agree on 99 % (the hydraulic unit lags its command by 30 ms,
    ``brake_tau``, and the moment changes sign four times in the lane change: the disagreement is those lags).
    Every braked wheel's slip stays below the slip limiter's ``slip_max`` (0.15; the wheels spin at 86 rad/s at the
    least), and the car peaks below the car alone's sideslip (2.41 deg)."""
    r = lane_change["brakes"]
    c, tr = r.commands, r.truth
    assert np.all(c["yaw_moment_cmd"] == 0.0) and np.array_equal(c["steer_cmd"], c["steer_driver"])
    torques = [np.asarray(c[f"brake_{w}"]) for w in WHEELS]
    made = brake_yaw_moment(torques, car.wheel_radius, car.track_front, car.track_rear)
    asked = np.asarray(c["yaw_moment_brakes_cmd"])
    assert np.abs(asked).max() > 1000.0  # the law acted through the brakes
    assert np.sum(made * asked) > 0.99 * np.sum(np.abs(made) * np.abs(asked))
    v = np.asarray(tr["vx"])
    slip_max = loop_ecu("two-dof", car, allocation="brakes").ecu.allocation.slip_max
    for w, t in zip(WHEELS, torques):
        omega = np.asarray(tr[f"wheel_speed_{w}"])
        slip = (v - omega * car.wheel_radius) / np.maximum(v, 3.0)
        assert np.all(slip[t > 0.0] < slip_max) and omega.min() > 0.0, w
    peak = lambda run: float(np.degrees(np.abs(run.truth["beta"])).max())  # noqa: E731
    assert peak(r) < peak(lane_change["alone"])


def test_no_brake_in_normal_driving_and_the_drivers_pressure_passes(car):
    """The brakes-mode ECU on a straight road at 100 km/h, settled for 2 s (numpy step, no noise): no pressure of its
    own, exactly; with the driver braking at 20 bar, each wheel's pressure is the driver's (no wheel slips)."""
    d = loop_ecu("two-dof", car, allocation="brakes").ecu
    v = 100 / 3.6
    u = {k: 0.0 for k in INPUTS}
    u.update(dt=d.filter.dt_nominal, speed=v, gps_hdop=1.0, gps_sats=10.0, mu=d.controller.mu_max,
             **{f"wheel_speed_{w}": v / d.wheel_radius for w in WHEELS})
    z = d.initial_state()
    for k in range(2000):
        uk = dict(u, gps_valid=1.0 if k % 200 == 0 else 0.0, brake_pressure_driver=0.0 if k < 1000 else 2e6)
        z, y = ecu_step(d, z, INPUTS.pack(uk))
        out = OUTPUTS.as_dict(y)
        want = 0.0 if k < 1000 else 2e6
        assert all(out[f"brake_pressure_{w}"] == want for w in WHEELS), k
        assert out["yaw_moment_brakes"] == 0.0 and out["yaw_moment_cmd"] == 0.0


def test_the_brakes_capacity_by_hand(car):
    """One wheel's brake at its static load: ``mu F_z t / 2``. compact-ev's front wheel, ``m g l_r / (2 L)`` with
    half the front track, is the larger; at mu 0.5 half of that at mu 1."""
    a = AllocationDesign.from_vehicle(car, "brakes")
    L = car.lf + car.lr
    front = 0.5 * car.mass * 9.80665 * car.lr / L * 0.5 * car.track_front
    rear = 0.5 * car.mass * 9.80665 * car.lf / L * 0.5 * car.track_rear
    assert brake_yaw_capacity(a, 1.0) == pytest.approx(max(front, rear), rel=1e-12)
    assert brake_yaw_capacity(a, 0.5) == pytest.approx(0.5 * max(front, rear), rel=1e-12)


def test_an_allocation_needs_the_brakes_fields(car):
    """A vehicle file without the brakes' fields: the error names them."""
    bare = dataclasses.replace(car, brake_gain_front=None, brake_tau=None)
    with pytest.raises(ParameterError, match="brake_gain_front, brake_tau"):
        AllocationDesign.from_vehicle(bare, "brakes")


def test_a_plant_without_brakes_is_refused_by_name(car):
    """The multi-body car's parameters (the CommonRoad set's) have no brakes: an ECU that brakes is refused, the
    error naming what the plant lacks."""
    d = loop_ecu("two-dof", car, allocation="brakes").ecu
    with pytest.raises(ParameterError, match="brake_gain_front"):
        simulate(car, "commonroad-mb:1", make_maneuver("step-steer", car, 60 / 3.6), controller="two-dof", design=d)

"""The reachable set's search (toolkit/verdicts/reachable.py) on the envelope's friction drop, checked against
integrators it does not share: the simulator's RK4 at 1 ms and scipy's solve_ivp (Radau, variable step).
Windows are short (the drop at 3.0 s, to 4.0 s) to keep the suite fast."""

import dataclasses

import numpy as np
import pytest

from evstab.plants import load_vehicle
from evstab.plants.errors import DesignError
from evstab.controllers.two_dof import STEER_AUTHORITY, STEER_AUTHORITY_RATE
from evstab.toolkit.loop.simulator import simulate
from evstab.toolkit.verdicts import envelope as ev
from evstab.toolkit.verdicts import reachable as rc

CASE = ev.Case("friction-drop", 80, 1.0, 0.3)


@pytest.fixture(scope="module")
def car():
    return load_vehicle("compact-ev")


@pytest.fixture(scope="module")
def ecu_run(car):
    man, road, _ = ev.run_setup(CASE, car)
    return simulate(car, "two-track", man, disturbances=road, controller="two-dof", seed=0)


def test_with_no_command_free_the_search_is_the_car_alone(car, ecu_run):
    """Free from beyond the window's end, the only sequence is the car alone's: the search's peak is the
    simulator's car alone (RK4 at 1 ms, sampled at 1 ms) and the scipy replay's. Tolerances: the collocation
    (Radau IIA, 0.02 s) against scipy at 1e-9 agrees to 1e-5 deg (measured 8.9e-6; 5.9e-7 at 0.01 s, the
    error falling with the step as a high-order method's does); the simulator samples the peak every 1 ms where
    the collocation takes it at its points (3 per 0.02 s): 1e-3 deg covers the sampling of a sideslip that
    moves at 5 deg/s (measured 6e-4)."""
    r = rc.search(CASE, car, start=2.9, react=99.0, end=4.0, guess=ecu_run)
    assert r.status == "Solve_Succeeded"
    assert np.all(np.isnan(r.torques))
    assert np.max(np.abs(r.correction)) < 1e-12  # held by equality constraints IPOPT meets to ~1e-46
    beta = rc.replay(r, CASE, car)
    assert np.max(np.abs(beta - np.arctan2(r.x[1], r.x[0]))) < np.radians(1e-5)
    assert r.peak_beta_deg == pytest.approx(np.degrees(np.max(np.abs(beta))), abs=1e-3)
    assert r.peak_beta_deg == pytest.approx(r.alone_peak_beta_deg, abs=1e-3)
    assert r.alone_peak_beta_deg > 5.0  # the car alone is sliding out by 4 s (it spins by 7 s)


def test_commands_found_hold_the_car_and_stay_inside_the_actuators(car, ecu_run):
    """Free from 0.2 s after the drop, the search holds the car far below the car alone (6.97 deg at 4 s) and
    below the default ECU (4.01 deg by 4 s, seed 0); the scipy replay of the commands found gives the
    search's trajectory (1e-3 deg: the collocation's error at 0.02 s against the replay at 1e-9 where the
    commands switch per step), and the commands are inside the steer authority, its rate and the motors'
    limit (1e-9: IPOPT's bound tolerance relative to the bound)."""
    r = rc.search(CASE, car, start=2.9, react=3.2, end=4.0, guess=ecu_run)
    assert r.status == "Solve_Succeeded"
    beta = rc.replay(r, CASE, car)
    assert np.max(np.abs(beta - np.arctan2(r.x[1], r.x[0]))) < np.radians(1e-3)
    ecu_peak = np.degrees(np.max(np.abs(ecu_run.truth["beta"][(ecu_run.t >= 2.9) & (ecu_run.t <= 4.0)])))
    assert np.degrees(np.max(np.abs(beta))) < 3.0 < ecu_peak
    assert np.max(np.abs(r.correction)) <= STEER_AUTHORITY * (1 + 1e-9)
    assert np.max(np.abs(np.diff(r.correction)) / np.diff(r.t)) <= STEER_AUTHORITY_RATE * (1 + 1e-9)
    free = ~np.isnan(r.torques[0])
    assert np.array_equal(free, r.t[:-1] >= 3.2 - 1e-9)
    assert np.max(np.abs(r.torques[:, free])) <= car.max_motor_torque * (1 + 1e-9)
    # nothing moves before the commands are free
    assert np.all(r.correction[r.t <= 3.2 + 1e-9] == pytest.approx(0.0, abs=1e-12))


def test_a_later_reaction_reaches_no_less(car, ecu_run):
    """A sequence free from 3.2 s may do whatever one free from 3.4 s does: its peak is not above it (1e-4 deg:
    IPOPT's tolerance on the peak), and both lie between the drop's start value and the car alone."""
    early = rc.search(CASE, car, start=2.9, react=3.2, end=4.0, guess=ecu_run)
    late = rc.search(CASE, car, start=2.9, react=3.4, end=4.0, guess=ecu_run)
    start_beta = np.degrees(abs(np.arctan2(early.x[1, 0], early.x[0, 0])))
    assert start_beta <= early.peak_beta_deg <= late.peak_beta_deg + 1e-4 < late.alone_peak_beta_deg


def test_bad_requests_are_refused_with_the_field(car):
    with pytest.raises(DesignError, match="max_motor_torque"):
        rc.search(CASE, dataclasses.replace(car, max_motor_torque=None), start=2.9, react=3.2, end=4.0)
    with pytest.raises(DesignError, match=r"window \[4.0, 3.0\] s is empty"):
        rc.search(CASE, car, start=4.0, react=3.2, end=3.0)
    with pytest.raises(DesignError, match="not an open-loop manoeuvre"):
        rc.search(ev.Case("slalom", 40, 1.0), car, start=1.0, react=2.0, end=3.0)

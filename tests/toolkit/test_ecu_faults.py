"""Faults injected into the ECU's inputs in the closed loop (toolkit.loop.ecu_faults)."""

from __future__ import annotations

import numpy as np
import pytest

from evstab.plants import load_vehicle
from evstab.plants.errors import SettingsError
from evstab.plants.maneuvers import make_maneuver
from evstab.studies.firmware_faults import no_harm, within_bound
from evstab.toolkit.loop.ecu_faults import FAULT_PARAMS
from evstab.toolkit.loop.ecu_faults import OFF, EcuFault, fault_parameters
from evstab.toolkit.ecu.step import INPUTS
from evstab.toolkit.ecu.guard import FAULT_BITS
from evstab.toolkit.loop.simulator import simulate


@pytest.fixture(scope="module")
def straight():
    p = load_vehicle("compact-ev")
    return p, make_maneuver("step-steer", p, 60 / 3.6, 0.0)


def test_an_injector_with_no_fault_changes_nothing(straight):
    """The loop traced with the injector, its window never open, runs the same bits as the loop without it."""
    p, man = straight
    a = simulate(p, "two-track", man, seed=2, controller="two-dof")
    b = simulate(p, "two-track", man, seed=2, controller="two-dof", ecu_fault=EcuFault("ay", "offset", 5.9, 5.9001, 0.0))
    for k in ("steer_cmd", "yaw_moment_cmd", "beta_est"):
        np.testing.assert_array_equal(a.commands[k], b.commands[k])


def test_a_persistent_nan_gyro_is_named_and_the_car_left_alone(straight):
    """NaN yaw rate for 0.5 s from 3 s on a straight road: commands finite and zero, the fault word carries the
    yaw rate's bit from 50 ms in to 0.2 s after the gyro is back."""
    p, man = straight
    r = simulate(p, "two-track", man, seed=2, controller="two-dof", ecu_fault=EcuFault("yaw_rate", "nan", 3.0, 3.5))
    c = r.commands
    assert np.all(c["steer_cmd"] == c["steer_driver"]) and np.all(c["yaw_moment_cmd"] == 0.0)
    word = c["fault_word"].astype(int)
    on = np.flatnonzero(word & (1 << FAULT_BITS["yaw_rate"]))
    # the 50th bad sample is at 3.049 s; the 200th good one after 3.5 s at 3.699 s, where it clears
    assert r.t[on[0]] == pytest.approx(3.049, abs=1e-9) and r.t[on[-1]] == pytest.approx(3.698, abs=1e-9)


def test_fault_parameters_put_the_fault_on_its_input_only():
    f = fault_parameters(EcuFault("speed", "scale", 1.0, 2.0, 1.5))
    assert f[:3] == [1.0, 2.0, 0.0]  # the window, no reset
    per = {name: dict(zip(FAULT_PARAMS, f[3 + 5 * i:8 + 5 * i])) for i, name in enumerate(INPUTS)}
    assert per["speed"] == {"set": 0.0, "value": 0.0, "add": 0.0, "gain": 1.5, "hold": 0.0}
    assert all(v == {"set": 0.0, "value": 0.0, "add": 0.0, "gain": 1.0, "hold": 0.0} for k, v in per.items()
               if k != "speed")
    assert fault_parameters(None)[:3] == [OFF, OFF, 0.0]
    assert fault_parameters(EcuFault("ecu", "reset", 1.0, 1.05))[:3] == [1.0, 1.05, 1.0]
    with pytest.raises(SettingsError, match="not an ECU input"):
        EcuFault("yaw", "nan", 0.0, 1.0)
    with pytest.raises(SettingsError, match="only a reset"):
        EcuFault("speed", "reset", 0.0, 1.0)
    with pytest.raises(SettingsError, match="only a reset"):
        EcuFault("ecu", "nan", 0.0, 1.0)


def test_an_ecu_reset_in_a_turn_at_100_kmh_boots_then_starts_without_a_command():
    """An ECU reset at 5 s in a 4 m/s^2 left turn at 100 km/h, booting 50 ms: through the boot the steer is
    exactly the driver's and the yaw moment 0; from the first step after it the law's references start at
    their targets, so the ECU commands nothing the run without the reset does not (the study's "acting"
    thresholds, 0.01 deg and 10 N m: the run without it commands nothing in this turn)."""
    from evstab.plants.maneuvers import constant_radius
    p = load_vehicle("compact-ev")
    v = 100 / 3.6
    man = constant_radius(v, v * v / 4.0, laps=0.2, lead_in=60.0)
    clean = simulate(p, "two-track", man, seed=1, controller="two-dof")
    r = simulate(p, "two-track", man, seed=1, controller="two-dof", ecu_fault=EcuFault("ecu", "reset", 5.0, 5.05))
    c, c0 = r.commands, clean.commands
    boot = (r.t >= 5.0 - 1e-9) & (r.t < 5.05 - 1e-9)
    assert boot.sum() == 50
    assert np.all(c["steer_cmd"][boot] == c["steer_driver"][boot]) and np.all(c["yaw_moment_cmd"][boot] == 0.0)
    assert np.all(np.isfinite(c["steer_cmd"])) and np.all(np.isfinite(c["yaw_moment_cmd"]))
    assert np.degrees(np.abs(c0["steer_cmd"] - c0["steer_driver"])).max() < 0.01  # the turn needs no control
    after = r.t >= 5.05 - 1e-9
    assert np.degrees(np.abs(c["steer_cmd"] - c["steer_driver"])[after]).max() < 0.01
    assert np.abs(c["yaw_moment_cmd"][after]).max() < 10.0
    # the filter restarted: its sideslip starts from 0 against the turn's (about -0.9 deg) and is back within
    # 1 deg of the truth within 0.2 s (the gyro at once, the course's first fixes at 5 Hz)
    k = after & (r.t >= 5.25)
    assert np.degrees(np.abs(c["beta_est"] - r.truth["beta"])[k]).max() < 1.0


def test_the_study_rules_at_their_boundaries():
    """The straight road's bound (0.5 deg, 300 N m, 100 ms) and the envelope's no-harm rule (1.1 x or
    0.3 deg more: at 1 deg alone the bound is 1.3, at 4 deg 4.4)."""
    ok = {"finite": True, "added_steer_deg": 0.5, "yaw_moment_nm": 300.0, "intervention_s": 0.1}
    assert within_bound(ok)
    for k, v in (("added_steer_deg", 0.5001), ("yaw_moment_nm", 300.1), ("intervention_s", 0.101), ("finite", False)):
        assert not within_bound({**ok, k: v})
    assert no_harm(1.3, 1.0) and not no_harm(1.31, 1.0)
    assert no_harm(4.4, 4.0) and not no_harm(4.41, 4.0) and not no_harm(np.nan, 1.0)

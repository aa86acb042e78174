"""The kinematic sideslip path of the default filter: off in linear driving, in charge in a slide."""

import dataclasses

import numpy as np
import pytest

from evstab.plants import load_vehicle
from evstab.plants.disturbances import Disturbances, Friction
from evstab.plants.maneuvers import sine_lane_change, sine_with_dwell
from evstab.plants.sensors import SensorConfig
from evstab.studies.estimation_mb import SLIDE_HAND_WHEEL_DEG, wrong
from evstab.toolkit.estimation import design_filter, run_estimator
from evstab.toolkit.estimation.kinematic_path import roll_compensation
from evstab.toolkit.loop.simulator import simulate

DEG = np.pi / 180
SENS = SensorConfig(gyro_bias=0.003, gyro_scale_error=0.01)


def test_roll_compensation_is_the_static_roll_of_the_roll_model():
    # a_meas = a_y + g phi with phi = m_s h a_y / (K - m_s g h) (seed 004 eq. 3 in steady state)
    p = load_vehicle("commonroad-3")
    msh = p.sprung_mass * p.roll_arm
    phi_per_ay = msh / (p.roll_stiffness - msh * 9.81)
    assert 1.0 / roll_compensation(p) == pytest.approx(1.0 + 9.81 * phi_per_ay, rel=1e-3)  # g = 9.80665 vs 9.81
    bare = dataclasses.replace(load_vehicle("micro-ev"), sprung_mass=None, roll_arm=None, roll_stiffness=None,
                               roll_inertia=None, roll_damping=None)
    assert roll_compensation(bare) == 1.0


def test_the_roll_gyro_compensates_the_dynamic_roll():
    # the Vanagon's sine with dwell at 80 km/h (13 deg of roll): the lateral accelerometer reads
    # a_y cos(phi) + g sin(phi); the static roll model leaves 0.54 m/s^2 RMS of the body's roll dynamics
    # in the kinematic path's a_y, the roll gyro's complementary filter 0.24 (measured; the truth's
    # a_y is the multi-body car's own). Asserted: better by a third, and within 0.3 m/s^2.
    from evstab.studies.estimation_mb import drives
    from evstab.toolkit.estimation.kalman import INPUTS
    from evstab.toolkit.estimation.kinematic_path import KINEMATIC, lateral_acceleration
    p = load_vehicle("commonroad-3")
    man = drives(p)[1][1]
    log = simulate(p, "commonroad-mb:3", man, sensors=SENS, seed=3).log_columns()
    d = design_filter("dakf", p)
    ks = KINEMATIC.zeros()
    n = len(log["t"])
    ay = np.empty(n)
    for k in range(n):
        g = INPUTS.unpack(INPUTS.pack({"dt": 1e-3, "ay": log["ay"][k], "roll_rate": log["roll_rate"][k],
                                       "roll_rate_ok": 1.0}, fill=0.0))
        ay[k], roll = lateral_acceleration(d, g, KINEMATIC.unpack(ks), np)
        ks = KINEMATIC.pack({"roll": roll}, fill=0.0)
    sel = (log["t"] > 2.0) & (log["t"] < 5.0)
    rms_gyro = np.sqrt(np.mean((ay - log["ay_true"])[sel] ** 2))
    rms_static = np.sqrt(np.mean((log["ay"] * roll_compensation(p) - log["ay_true"])[sel] ** 2))
    assert rms_gyro < 0.67 * rms_static and rms_gyro < 0.3


def test_the_kinematic_path_stays_out_of_linear_driving():
    # a gentle lane change (1.5 m/s^2) with the exact model: the measured lateral acceleration never
    # leaves the model's by the threshold, so the blend weight is 0 throughout and the filter is the
    # linear one (the same arithmetic with the blend's factors exactly 1 and 0: equal to the last bit
    # but for the compiler's freedom with x * 1.0, hence the 1e-15 rad)
    p = load_vehicle("compact-ev")
    log = simulate(p, "two-track", sine_lane_change(60 / 3.6, np.radians(1.0), start=2.0, duration=12.0),
                   sensors=SENS, seed=2).log_columns()
    d = design_filter("dakf", p)
    assert d.kinematic and design_filter("dakf", p, control=True).kinematic  # on logs and in the ECU
    assert not design_filter("dakf", p, control=True, kinematic=False).kinematic
    a = run_estimator(d, log)["beta"]
    b = run_estimator(dataclasses.replace(d, kinematic=False), log)["beta"]
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-15)


@pytest.mark.parametrize("n,peak_min,linear_min", [(3, 15.0, 5.0), (2, 12.0, 3.0)])
def test_a_slide_on_mu_0_5_is_followed_with_a_wrong_model(n, peak_min, linear_min):
    # the Vanagon (set 3) slides to 21 deg on mu 0.5 and recovers, the BMW (set 2) to 14 deg; dakf designed
    # from the +40 % stiffness, +10 % inertia file: within 1 deg RMS (measured 0.44 / 1.00 max on the
    # Vanagon, 0.20 / 0.49 on the BMW) and |error| < 3 beta_std on 99 % of the samples (measured 100 % on
    # both); the same filter without the path is degrees off there (measured 13.3 and 4.2: its model says
    # the tyres give what they do not, and the course fixes are gated)
    p = load_vehicle(f"commonroad-{n}")
    man = sine_with_dwell(80 / 3.6, SLIDE_HAND_WHEEL_DEG[n] * DEG / p.steering_ratio, start=2.0, after=8.0)
    log = simulate(p, f"commonroad-mb:{n}", man, disturbances=Disturbances(friction=Friction(mu=0.5)),
                   sensors=SENS, seed=n).log_columns()
    sel = log["t"] >= 1.0
    assert np.degrees(np.abs(log["beta_true"]).max()) > peak_min
    d = design_filter("dakf", wrong(p), nominal=False)
    est = run_estimator(d, log)
    err = (est["beta"] - log["beta_true"])[sel]
    assert np.degrees(np.sqrt(np.mean(err ** 2))) <= 1.0
    assert np.mean(np.abs(err) < 3 * est["beta_std"][sel]) >= 0.99
    lin = run_estimator(dataclasses.replace(d, kinematic=False), log)
    assert np.degrees(np.sqrt(np.mean(((lin["beta"] - log["beta_true"])[sel]) ** 2))) > linear_min


def test_a_delayed_fix_does_not_engage_the_kinematic_path():
    # the design job's sine lane change at 80 km/h on mu 1 (4 m/s^2) on the multi-body Escort, a GPS
    # latency of 0.15 s the filter does not compensate: a delayed fix moves the estimate, and with it
    # the model's lateral acceleration, for a moment; the lagged departure does not reach the
    # threshold, so dakf is dakf without the path (measured 0.084 deg RMS both; with a lag of 1 ms instead
    # of the 0.1 s the path misfires, 0.38)
    from evstab.studies.control_mb_fmvss126 import wrong_nominal
    from evstab.toolkit.design.sweep import SweepConfig, standard_maneuvers
    p = wrong_nominal(1)
    man = standard_maneuvers(SweepConfig(p, plant="commonroad-mb:1"), 80 / 3.6)[0]
    log = simulate(p, "commonroad-mb:1", man, sensors=SensorConfig(gps_latency=0.15), seed=1).log_columns()
    d = design_filter("dakf", p)
    a = run_estimator(d, log)["beta"]
    b = run_estimator(dataclasses.replace(d, kinematic=False), log)["beta"]
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-15)  # rad: the weight stays 0 (see the linear test)


def test_a_banked_road_does_not_engage_the_kinematic_path():
    # seed 002's two half turns on a 5 deg side slope: the accelerometer reads g sin(bank) = 0.85 m/s^2
    # that is not the tyres. Learnt in the straight lead-in as the accelerometer's offset, it keeps the
    # path out: dakf equals dakf without the path (measured 0.096 deg RMS both); without the offset the
    # path misfires in the turns (measured 0.277 RMS, 0.95 max)
    from evstab.studies.estimation_002 import LEAD_IN, SPEED, road
    p = load_vehicle("compact-ev")
    c = road(p, -5.0)
    m = c["t"] >= LEAD_IN / SPEED - 1.0
    d = design_filter("dakf", p)
    a = run_estimator(d, c)["beta"]
    b = run_estimator(dataclasses.replace(d, kinematic=False), c)["beta"]
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-15)  # rad: the weight stays 0 (see the linear test)
    no_offset = dataclasses.replace(d, noise=dataclasses.replace(d.noise, kinematic_offset_tau=1e9))
    err = (run_estimator(no_offset, c)["beta"] - c["beta_true"])[m]
    assert np.degrees(np.sqrt(np.mean(err ** 2))) > 0.2


def test_the_vanagon_sine_with_dwell_with_a_wrong_model_meets_the_reference_target():
    # FMVSS 126's sine with dwell at 80 km/h (3.5 A, mu 1) on the multi-body Vanagon (13 deg of roll),
    # cold start, dakf from the +40 % stiffness, +10 % inertia file: within the 0.15 deg RMS / 0.5 deg
    # max of a reference instrument (ISO 15037; measured 0.10 / 0.27); the ECU's filter without the
    # kinematic path (the loop's noise) is at 0.56 / 1.77 (measured) on the same log, with it (its
    # default) at 0.15 / 0.40
    from evstab.studies.estimation_mb import drives
    p = load_vehicle("commonroad-3")
    name, man, mu, sens, _ = drives(p)[1]
    log = simulate(p, "commonroad-mb:3", man, sensors=sens, seed=3).log_columns()
    sel = log["t"] >= 1.0
    err = (run_estimator(design_filter("dakf", wrong(p), nominal=False), log)["beta"] - log["beta_true"])[sel]
    assert np.degrees(np.sqrt(np.mean(err ** 2))) <= 0.15 and np.degrees(np.abs(err).max()) <= 0.5
    plain = run_estimator(design_filter("dakf", wrong(p), nominal=False, control=True, kinematic=False), log)
    assert np.degrees(np.sqrt(np.mean((plain["beta"] - log["beta_true"])[sel] ** 2))) > 0.3
    ecu = run_estimator(design_filter("dakf", wrong(p), nominal=False, control=True), log)
    assert np.degrees(np.sqrt(np.mean((ecu["beta"] - log["beta_true"])[sel] ** 2))) < 0.3


def test_the_path_lets_go_after_the_slide():
    # the Vanagon's sine with dwell with the exact model: in kinematic mode a sideslip error is not
    # observable, and the error the manoeuvre leaves keeps the model's lateral acceleration off the
    # measured one; the departure alone holds the path on after the steer. The ECU's filter: 0.47 deg RMS from
    # 5.5 s on without the gate on the peak-held lateral acceleration, 0.09 with it. (The logs' filter, whose
    # yaw row loosens with v r and whose kinematic sideslip noise is lower, leaves little error to hold the
    # path: 0.040 without the gate, 0.024 with it.)
    from evstab.studies.estimation_mb import drives
    p = load_vehicle("commonroad-3")
    name, man, mu, sens, _ = drives(p)[1]
    log = simulate(p, "commonroad-mb:3", man, sensors=sens, seed=3).log_columns()
    after = log["t"] >= 5.5
    d = design_filter("dakf", p, control=True)
    held = dataclasses.replace(d, noise=dataclasses.replace(d.noise, kinematic_ay_quiet=1e-9))
    rms = {k: np.degrees(np.sqrt(np.mean(((run_estimator(x, log)["beta"] - log["beta_true"])[after]) ** 2)))
           for k, x in (("gate", d), ("no gate", held))}
    assert rms["gate"] < 0.2 and rms["no gate"] > 3 * rms["gate"]

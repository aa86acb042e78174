"""Seed 001: kinematic and model-based filters, residual diagnostics, stiffness identification, Table I."""

import dataclasses

import control
import numpy as np
import pytest
import scipy.stats

from evstab.plants import load_vehicle
from evstab.plants.maneuvers import two_half_turns
from evstab.plants.sensors import SensorConfig
from evstab.toolkit.cli import main
from evstab.toolkit.estimation import design_filter, run_estimator
from evstab.toolkit.estimation.diagnostics import autocorrelation, nis_consistency, whiteness
from evstab.toolkit.estimation.identify import cornering_stiffness
from evstab.toolkit.estimation.rate_table import PAPER_TABLE_I, discretise, model, predicted_errors
from evstab.toolkit.logs.drivelog import write_log_csv
from evstab.toolkit.loop.simulator import simulate

SPEED, RADIUS = 16.0, 50.0


@pytest.fixture(scope="module")
def vehicle():
    return load_vehicle("compact-ev")


def _turns(p, plant, scale=0.0, seed=1, lead_in=300.0):
    man = two_half_turns(SPEED, RADIUS, lead_in=lead_in)
    return simulate(p, plant, man, sensors=SensorConfig(gyro_scale_error=scale), seed=seed).log_columns()


@pytest.fixture(scope="module")
def bicycle_turns(vehicle):
    return _turns(vehicle, "bicycle")


def _used_resid(est):
    return np.where(est["gps_used"] > 0.5, est["course_resid"], np.nan)


def test_autocorrelation_and_ljung_box_are_the_textbook_ones():
    """rho_k from numpy.correlate; on white Gaussian sequences (N = 300, 20 lags) the 5 % test rejects
    in 5 % of 400 seeded runs (binomial: 20 +- 4.4; the band is +-3.3 sigma, p ~ 1e-3 of a false
    failure), on an AR(1) sequence with phi = 0.5 (expected Q ~ 100 against the 31.4 threshold) in all."""
    rng = np.random.default_rng(11)
    e = rng.normal(size=500)
    c = np.correlate(e - e.mean(), e - e.mean(), mode="full")[499:]
    np.testing.assert_allclose(autocorrelation(e, 10), c[1:11] / c[0], rtol=1e-12)
    rejects = sum(not whiteness(rng.normal(size=300), lags=20).white for _ in range(400))
    assert 6 <= rejects <= 34
    ar = []
    for _ in range(20):
        w = rng.normal(size=300)
        x = np.empty(300)
        x[0] = w[0]
        for k in range(1, 300):
            x[k] = 0.5 * x[k - 1] + w[k]
        ar.append(whiteness(x, lags=20).white)
    assert not any(ar)


def test_nis_interval_is_the_chi_square_one():
    c = nis_consistency(np.ones(100))
    assert c.low == pytest.approx(scipy.stats.chi2.ppf(0.025, 100) / 100)
    assert c.high == pytest.approx(scipy.stats.chi2.ppf(0.975, 100) / 100)
    assert c.consistent


def test_whiteness_passes_the_right_model_and_flags_a_wrong_one(vehicle, bicycle_turns):
    """mbkf on its own plant (the linear bicycle, no scale error): course residuals white (measured
    p = 0.25); with another vehicle's parameters (sedan-000) they are not (measured p = 2e-4, Q = 50 on
    20 lags; asserted below 1e-3)."""
    right = run_estimator(design_filter("mbkf", vehicle), bicycle_turns)
    wrong = run_estimator(design_filter("mbkf", load_vehicle("sedan-000")), bicycle_turns)
    assert whiteness(_used_resid(right), lags=20).white
    assert whiteness(_used_resid(wrong), lags=20).p_value < 1e-3


def test_nis_consistent_when_the_filter_knows_the_noise(vehicle, bicycle_turns):
    """The simulated course noise is 0.04 m/s per axis x HDOP 0.9 over the speed (16 m/s: 0.129 deg);
    mbkf (constant course noise) assuming exactly that has a mean NIS inside its 95 % interval
    (measured 1.13 in [0.84, 1.17]), assuming twice that it sits below it (measured 0.29: too cautious)."""
    d = design_filter("mbkf", vehicle)
    sd = 0.04 * 0.9 / SPEED
    matched = dataclasses.replace(d, noise=dataclasses.replace(d.noise, course_std=sd))
    cautious = dataclasses.replace(d, noise=dataclasses.replace(d.noise, course_std=2 * sd))
    r = _used_resid(run_estimator(matched, bicycle_turns))
    assert nis_consistency(r[np.isfinite(r)] ** 2).consistent
    r = _used_resid(run_estimator(cautious, bicycle_turns))
    c = nis_consistency(r[np.isfinite(r)] ** 2)
    assert c.mean < c.low


def _identify(p, cols):
    est = run_estimator(design_filter("kkf", p), cols)
    fixes = np.flatnonzero(np.isfinite(cols["gps_course"]))
    return cornering_stiffness(p, cols["t"], cols["speed"], cols["steer"], cols["yaw_rate"], est["beta"],
                               rows=fixes, yaw_moment=cols.get("yaw_moment"))


def test_stiffness_from_the_kinematic_sideslip(vehicle, bicycle_turns):
    """Two 180-degree turns at 57.6 km/h, radius 50 m: on the bicycle plant within 5 % of the known
    stiffness (measured -0.6 / -1.0 %, seeds 2-3 up to -4.2 %), on the two-track plant within 10 % of
    the parameter file's (measured -3.5 / -1.8 %, seeds 2-3 up to -5.9 %: load transfer and the
    tires' curvature at 5 m/s^2)."""
    s = _identify(vehicle, bicycle_turns)
    assert s.front == pytest.approx(vehicle.cornering_stiffness_front, rel=0.05)
    assert s.rear == pytest.approx(vehicle.cornering_stiffness_rear, rel=0.05)
    s = _identify(vehicle, _turns(vehicle, "two-track"))
    assert s.front == pytest.approx(vehicle.cornering_stiffness_front, rel=0.10)
    assert s.rear == pytest.approx(vehicle.cornering_stiffness_rear, rel=0.10)


def test_stiffness_identification_is_exact_with_the_true_sideslip(vehicle, bicycle_turns):
    """With the simulator's sideslip and yaw rate the force balance is the plant's own: within 0.5 %
    (measured 0.2 %; the smoothed yaw acceleration is the only approximation)."""
    c = bicycle_turns
    s = cornering_stiffness(vehicle, c["t"], c["speed"], c["steer"], c["yaw_rate_true"], c["beta_true"])
    assert s.front == pytest.approx(vehicle.cornering_stiffness_front, rel=0.005)
    assert s.rear == pytest.approx(vehicle.cornering_stiffness_rear, rel=0.005)


def test_kkf_turns_a_gyro_scale_error_into_sideslip(vehicle):
    """A 2 % scale error integrates into a heading error of 2 % of the angle turned, which the kinematic
    filter (update off while turning) reports as sideslip: at the last fix of the first 180-degree
    turn the error is -0.02 pi rad = -3.6 deg within 0.3 deg (course noise 0.15 deg per fix plus the
    bias learned on the lead-in); the model-based filter stays within 0.1 deg there."""
    c = _turns(vehicle, "bicycle", scale=0.02, lead_in=200.0)
    kkf = run_estimator(design_filter("kkf", vehicle), c)
    mbkf = run_estimator(design_filter("mbkf", vehicle), c)
    turning = np.abs(c["yaw_rate_true"]) > 0.5 * SPEED / RADIUS
    start = int(np.argmax(turning))
    end = start + int(np.argmax(~turning[start:]))
    k = np.flatnonzero(np.isfinite(c["gps_course"][:end]))[-1]
    turned = c["yaw_true"][k] - c["yaw_true"][start]
    assert turned == pytest.approx(np.pi, abs=0.1)
    assert kkf["beta"][k] - c["beta_true"][k] == pytest.approx(-0.02 * turned, abs=np.radians(0.3))
    assert abs(mbkf["beta"][k] - c["beta_true"][k]) < np.radians(0.1)


def test_table_i_riccati_matches_python_control(vehicle):
    """The a-priori steady-state covariance equals python-control's dlqe on the same discrete model
    (3 states: the constant bias is known exactly in the steady state) to 1e-9 relative."""
    rate, sc, sg, _, _ = PAPER_TABLE_I[1]
    q = 1e-6
    pr = predicted_errors(vehicle, 30.0, rate, np.radians(sc), np.radians(sg), q)
    A, b, H = model(vehicle, 30.0)
    F, Q = discretise(A[:3, :3], b[:3, None], np.array([[q]]), 1.0 / rate)
    _, P, _ = control.dlqe(F, np.eye(3), H[:, :3], Q, np.diag([np.radians(sg) ** 2, np.radians(sc) ** 2]))
    np.testing.assert_allclose(pr.prior[:3, :3], P, rtol=1e-9, atol=1e-18)
    assert pr.posterior[0, 0] < pr.prior[0, 0]


def test_estimate_runs_kkf_and_names_what_lob_lacks(vehicle, tmp_path, capsys):
    c = _turns(vehicle, "bicycle", lead_in=50.0)
    c = {k: v for k, v in c.items() if k != "ay"}
    write_log_csv(tmp_path / "log.csv", c)
    assert main(["estimate", str(tmp_path / "log.csv"), "--vehicle", "compact-ev", "--method", "kkf",
                 "--out", str(tmp_path / "est.csv")]) == 0
    assert "course residuals over" in capsys.readouterr().out
    assert main(["estimate", str(tmp_path / "log.csv"), "--vehicle", "compact-ev", "--method", "lob",
                 "--out", str(tmp_path / "lob.csv")]) == 2
    err = capsys.readouterr().err
    assert "method 'lob' needs column(s) ay" in err and not (tmp_path / "lob.csv").exists()


def test_online_stiffness_ends_at_the_batch_estimate(vehicle, bicycle_turns):
    """Recursive least squares without forgetting is the batch fit sample by sample: its last value
    equals cornering_stiffness's to rounding; with forgetting 0.99 (about 100 fixes' memory) it ends
    within 10 % (measured -4.5 / -4.1 %: the exit of the last turn, where the smoothed yaw acceleration
    is least exact, weighs most)."""
    from evstab.toolkit.estimation.identify import cornering_stiffness_online
    c = bicycle_turns
    args = (vehicle, c["t"], c["speed"], c["steer"], c["yaw_rate_true"], c["beta_true"])
    batch = cornering_stiffness(*args)
    front, rear = cornering_stiffness_online(*args)
    assert front[-1] == pytest.approx(batch.front, rel=1e-9) and rear[-1] == pytest.approx(batch.rear, rel=1e-9)
    assert np.isnan(front[0])
    front, rear = cornering_stiffness_online(*args, forgetting=0.99)
    assert front[-1] == pytest.approx(vehicle.cornering_stiffness_front, rel=0.10)
    assert rear[-1] == pytest.approx(vehicle.cornering_stiffness_rear, rel=0.10)

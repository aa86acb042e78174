"""Noise intensities fitted to a log by innovation maximum likelihood (``evstab estimate --tune``)."""

import dataclasses

import numpy as np
import pytest

from evstab.plants import load_vehicle
from evstab.plants.errors import DataError
from evstab.plants.maneuvers import sine_lane_change
from evstab.plants.sensors import SensorConfig
from evstab.toolkit.estimation import design_filter, kalman
from evstab.toolkit.estimation.noise_fit import fit_noise, load_noise, nis_interval, write_noise
from evstab.toolkit.estimation.runner import compiled_filter, initial_state, log_inputs
from evstab.toolkit.estimation.spec import NoiseSettings
from evstab.toolkit.logs.drivelog import write_log_csv
from evstab.toolkit.loop.simulator import simulate

# the log's sensors differ from the filter's defaults (gyro 0.004 rad/s, GPS velocity 0.056 m/s)
GYRO, GPS = 0.006, 0.08


@pytest.fixture(scope="module")
def log():
    p = load_vehicle("compact-ev")
    man = sine_lane_change(60 / 3.6, np.radians(1.0), start=2.0, period=4.0, duration=60.0)
    sens = SensorConfig(gyro_noise=GYRO, gps_velocity_noise=GPS, gyro_bias=0.002)
    return simulate(p, "two-track", man, sensors=sens, seed=3).log_columns()


def test_run_time_noise_equals_the_noise_built_in(log):
    # the filter compiled with the intensities as a run-time input gives what the filter with those
    # values built in gives (the same arithmetic, the values arriving later: equal to rounding)
    p = load_vehicle("compact-ev")
    d = design_filter("dakf", p)
    noise = dataclasses.replace(d.noise, gyro_std=0.005, gps_velocity_std=0.07, q_d1=0.01)
    built = dataclasses.replace(d, noise=noise)
    U = log_inputs(log, d.dt_nominal)
    z0 = initial_state(d)
    names = ("gyro_std", "gps_velocity_std", "q_d1")
    Y = compiled_filter(d, "auto", names).run(U, z0, theta=[0.005, 0.07, 0.01])
    Y0 = compiled_filter(built).run(U, z0)
    a, b = kalman.OUTPUTS.columns(Y), kalman.OUTPUTS.columns(Y0)
    np.testing.assert_allclose(a["beta"], b["beta"], rtol=0, atol=1e-12)  # rad; rounding of reordered sums
    np.testing.assert_allclose(a["gyro_var"], b["gyro_var"], rtol=1e-12)


def test_fit_recovers_the_sensor_noise_of_a_simulated_log(log):
    d = design_filter("dakf", load_vehicle("compact-ev"))
    fit = fit_noise(d, log)
    got = dict(zip(fit.parameters, fit.values))
    # measured: 0.00592 and 0.0824 (1.3 % and 3 % off); the bound is 20 %
    assert got["gyro_std"] == pytest.approx(GYRO, rel=0.2)
    assert got["gps_velocity_std"] == pytest.approx(GPS, rel=0.2)
    assert fit.nll < fit.nll_start and fit.converged
    lo, hi = fit.nis_interval
    assert lo < fit.nis < hi  # the fitted filter's course innovations are consistent
    # the process noise the gentle log cannot pin ends on a bound, and the fit says so
    assert set(fit.at_bound) <= {"q_beta", "q_yaw_rate", "q_d1", "q_d2"}


def test_nis_interval_is_the_chi_square_interval_of_the_mean():
    import scipy.stats
    lo, hi = nis_interval(300)
    assert lo == pytest.approx(scipy.stats.chi2.ppf(0.025, 300) / 300) and hi == pytest.approx(
        scipy.stats.chi2.ppf(0.975, 300) / 300)
    assert lo < 1 < hi


def test_the_cli_writes_a_noise_file_that_estimate_and_design_read(log, tmp_path, capsys, monkeypatch):
    from evstab.toolkit import cli
    path = tmp_path / "log.csv"
    write_log_csv(path, log)
    noise = tmp_path / "noise.toml"
    assert cli.main(["estimate", str(path), "--vehicle", "compact-ev", "--tune", "--out", str(noise)]) == 0
    out = capsys.readouterr().out
    assert "gyro_std" in out and "mean NIS" in out
    n = load_noise(noise)
    assert n.gyro_std == pytest.approx(GYRO, rel=0.2) and n.gps_velocity_std == pytest.approx(GPS, rel=0.2)
    est = tmp_path / "est.csv"
    assert cli.main(["estimate", str(path), "--vehicle", "compact-ev", "--noise", str(noise), "--out", str(est)]) == 0
    # evstab design --noise hands the file's settings to the design job
    seen = {}

    def fake_run_design(vehicle, out, **kw):
        seen.update(kw)
        raise SystemExit(0)

    monkeypatch.setattr("evstab.toolkit.design.design_job.run_design", fake_run_design)
    with pytest.raises(SystemExit):
        cli.main(["design", "--vehicle", "compact-ev", "--out", str(tmp_path / "d"), "--noise", str(noise)])
    assert seen["noise"] == n


def test_a_noise_file_sets_the_design_jobs_filter_and_start():
    from evstab.toolkit.design import sweep as sw
    n = NoiseSettings(gyro_std=0.005, q_d1=0.03)
    cfg = sw.SweepConfig(load_vehicle("compact-ev"), noise=n)
    assert cfg.paper.q_d1 == 0.03 and cfg.paper.k_beta == sw.PAPER.k_beta
    assert cfg.filter_design(cfg.paper).noise == n
    assert sw.SweepConfig(load_vehicle("compact-ev")).paper == sw.PAPER


def test_bad_noise_files_are_refused_with_the_file_and_field(tmp_path):
    p = tmp_path / "n.toml"
    p.write_text("[noise]\ngyro_sdt = 0.004\n")
    with pytest.raises(DataError, match=r"n\.toml.*gyro_sdt"):
        load_noise(p)
    p.write_text("[noise]\ngyro_std = -1.0\n")
    with pytest.raises(DataError, match=r"n\.toml.*gyro_std"):
        load_noise(p)
    p.write_text("[meta]\nsource = 'x'\n")
    with pytest.raises(DataError, match=r"\[noise\] is missing"):
        load_noise(p)
    with pytest.raises(DataError, match="no such noise file"):
        load_noise(tmp_path / "absent.toml")


def test_write_noise_round_trips(tmp_path, log):
    d = design_filter("dakf", load_vehicle("compact-ev"))
    fit = fit_noise(d, log, ("gyro_std",), max_iter=10)
    write_noise(tmp_path / "n.toml", fit, d.noise, "test")
    assert load_noise(tmp_path / "n.toml") == fit.noise(d.noise)

"""Production sensors emulated on a reference log: hand-worked cases for the course, the fixes' timing and the
production gyro, and the command end to end."""

import json

import numpy as np
import pytest

from evstab.plants.errors import EvstabError
from evstab.toolkit.cli import main
from evstab.toolkit.logs.emulate import PRODUCTION_GYRO, Emulation, emulate, metadata_path, read_metadata
from evstab.toolkit.logs.drivelog import LogFormatError, read_log_csv, write_log_csv


def _circle(n=2001, dt=0.005, r=0.2, beta=0.03, v=20.0):
    """A steady turn: constant yaw rate and sideslip at 200 Hz, from t = 0."""
    t = np.arange(n) * dt
    return {"t": t, "speed": np.full(n, v * np.cos(beta)), "steer": np.full(n, 0.02), "yaw_rate": np.full(n, r),
            "gps_course": np.full(n, np.nan), "beta_true": np.full(n, beta), "vx_true": np.full(n, v * np.cos(beta)),
            "vy_true": np.full(n, v * np.sin(beta))}


def test_course_is_the_integrated_reference_yaw_rate_plus_sideslip():
    cols = _circle()
    out = emulate(cols, Emulation(gps_velocity_noise=0.0))
    fix = np.flatnonzero(np.isfinite(out["gps_course"]))
    # a fix every 0.2 s from the first row (40 rows at 200 Hz), none invented between
    np.testing.assert_array_equal(fix, np.arange(0, 2001, 40))
    # constant rate: the trapezoidal integral is exact, course = r t + beta
    np.testing.assert_allclose(out["gps_course"][fix], 0.2 * cols["t"][fix] + 0.03, rtol=0, atol=1e-12)
    np.testing.assert_allclose(out["gps_speed"][fix], 20.0, rtol=1e-12)  # ground speed from vx, vy
    assert (out["gps_sats"][fix] == 12).all() and (out["gps_hdop"][fix] == 1).all()
    np.testing.assert_array_equal(out["yaw_rate"], cols["yaw_rate"])  # the reference gyro as logged
    np.testing.assert_array_equal(out["yaw_rate_true"], cols["yaw_rate"])


def test_course_noise_is_the_velocity_noise_over_the_speed():
    cols = _circle(n=200001)
    out = emulate(cols, Emulation(gps_velocity_noise=0.04, seed=4))
    fix = np.isfinite(out["gps_course"])
    e = out["gps_course"][fix] - (0.2 * cols["t"][fix] + 0.03)
    # 0.04 m/s at HDOP 1 over 20 m/s: 2 mrad; 5001 fixes put the sample std within 3 % (1 / sqrt(2 n) = 1 %, 3 sigma)
    assert abs(np.std(e) / 0.002 - 1.0) < 0.03
    # the same seed draws the same noise, another seed other noise
    again = emulate(cols, Emulation(gps_velocity_noise=0.04, seed=4))
    np.testing.assert_array_equal(again["gps_course"], out["gps_course"])
    assert not np.array_equal(emulate(cols, Emulation(gps_velocity_noise=0.04, seed=5))["gps_course"], out["gps_course"])


def test_offset_latency_and_no_fix_at_rest():
    cols = _circle()
    cols["vx_true"][:400] = 0.5  # below the 1 m/s a single antenna needs for a course
    cols["vy_true"][:400] = 0.0
    out = emulate(cols, Emulation(gps_velocity_noise=0.0, gps_offset=0.05, gps_latency=0.1))
    fix = np.flatnonzero(np.isfinite(out["gps_course"]))
    # instants 0.05 + 0.2 k s (rows 10 + 40 k), none while slower than 1 m/s (rows < 400), each logged 0.1 s
    # (20 rows) later and describing its instant
    described = np.arange(10, 2001, 40)
    described = described[described >= 400]
    np.testing.assert_array_equal(fix, described + 20)
    np.testing.assert_allclose(out["gps_course"][fix], 0.2 * cols["t"][described] + 0.03, atol=1e-12)


def test_production_gyro_bias_scale_and_quantum():
    cols = _circle()
    out = emulate(cols, Emulation(gyro="production", gyro_bias=3e-3, gyro_scale=0.01, gyro_noise=0.0))
    np.testing.assert_allclose(out["yaw_rate"], 1.01 * 0.2 + 3e-3, rtol=1e-15)
    q = np.radians(1.28)
    out = emulate(cols, Emulation(gyro="production", gyro_bias=3e-3, gyro_scale=0.01, gyro_quantum=q))
    np.testing.assert_allclose(out["yaw_rate"], np.round((1.01 * 0.2 + 3e-3) / q) * q, rtol=1e-15)  # 9 steps
    noisy = emulate(_circle(n=100001), Emulation(seed=1, **PRODUCTION_GYRO))
    e = noisy["yaw_rate"] - (1.01 * 0.2 + 3e-3)
    assert abs(np.std(e) / 1.5e-3 - 1.0) < 0.015  # 1e5 samples: the std within 1.5 % (3 sigma = 0.7 %)


@pytest.mark.parametrize("kw,needle", [({"gps_rate": 0.0}, "'gps_rate' must be above 0"),
                                       ({"gyro": "mems"}, "gyro must be 'reference' or 'production'"),
                                       ({"gyro_scale": 0.5}, "'gyro_scale' must be within"),
                                       ({"gps_latency": -0.1}, "'gps_latency' must be >= 0")])
def test_bad_settings(kw, needle):
    with pytest.raises(EvstabError, match=needle):
        Emulation(**kw)


def test_a_log_without_reference_sideslip_is_refused():
    cols = _circle()
    del cols["beta_true"], cols["vx_true"], cols["vy_true"]
    with pytest.raises(LogFormatError, match="no reference sideslip"):
        emulate(cols, Emulation())


def test_emulate_command_records_what_it_emulated(tmp_path, capsys):
    cols = _circle()
    write_log_csv(tmp_path / "ref.csv", cols)
    out = tmp_path / "log.csv"
    assert main(["emulate", str(tmp_path / "ref.csv"), "--gyro", "production", "--gyro-quantum", "0.1", "--seed", "7",
                 "--out", str(out)]) == 0
    assert "production gyro: bias 3 mrad/s, scale +1 %" in capsys.readouterr().out
    meta = read_metadata(out)
    assert meta["settings"]["seed"] == 7 and meta["settings"]["gyro_scale"] == 0.01
    assert meta["settings"]["gyro_quantum"] == pytest.approx(np.radians(0.1), rel=1e-15)
    assert json.loads(open(metadata_path(out)).read())["format"] == "evstab-emulation/1"
    log = read_log_csv(out)
    assert np.isfinite(log["gps_course"]).sum() == 51
    # the estimator reads it like any drive log
    assert main(["estimate", str(out), "--vehicle", "compact-ev", "--out", str(tmp_path / "est.csv")]) == 0
    assert main(["emulate", str(tmp_path / "ref.csv"), "--gyro-bias", "0.01", "--out", str(tmp_path / "x.csv")]) == 2
    assert "--gyro-bias goes with --gyro production" in capsys.readouterr().err

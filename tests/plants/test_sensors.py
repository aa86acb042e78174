"""Sensor models: noise statistics, GPS timing, course geometry, latency, outages, seeding."""

import numpy as np
import pytest

from evstab.plants import ModelError
from evstab.plants.sensors import SensorConfig, gps_fix_mask, measure, wrap_angle

N = 200_000


def truth_const(n=N, **over):
    z = np.zeros(n)
    base = {k: z.copy() for k in ("vx", "vy", "beta", "yaw_rate", "yaw", "x", "y", "ax", "ay", "roll", "roll_rate",
                                  "wheel_speed_fl", "wheel_speed_fr", "wheel_speed_rl", "wheel_speed_rr")}
    base["vx"][:] = 20.0
    for w in ("wheel_speed_fl", "wheel_speed_fr", "wheel_speed_rl", "wheel_speed_rr"):
        base[w][:] = 20.0 / 0.3
    base.update(over)
    return base


def inputs(n=N):
    return {"steer": np.zeros(n), "yaw_moment": np.zeros(n), "bank": np.zeros(n)}


def test_gyro_noise_bias_and_scale_statistics():
    cfg = SensorConfig(gyro_noise=0.004, gyro_bias=0.003, gyro_scale_error=0.01)
    t = np.arange(N) * 1e-3
    tr = truth_const(yaw_rate=np.full(N, 0.2))
    m = measure(t, tr, inputs(), cfg, seed=1, wheel_radius=0.3)
    err = m["yaw_rate"] - (1.01 * 0.2 + 0.003)
    # sample mean of N iid N(0, s^2): std s/sqrt(N) = 9e-6; 5 sigma
    assert abs(err.mean()) < 5 * 0.004 / np.sqrt(N)
    # sample std: relative std of the estimate ~ 1/sqrt(2N) = 0.16 %; 5 sigma = 0.8 %
    assert err.std() == pytest.approx(0.004, rel=0.008)
    # white: lag-1 autocorrelation ~ N(0, 1/N); 5 sigma
    e = err - err.mean()
    assert abs(np.dot(e[:-1], e[1:]) / np.dot(e, e)) < 5 / np.sqrt(N)


def test_accelerometer_sees_gravity_through_roll_and_bank():
    cfg = SensorConfig(accel_noise=0.0)
    n = 10
    roll, bank = 0.03, 0.02
    tr = truth_const(n, roll=np.full(n, roll), ay=np.full(n, 2.0))
    inp = inputs(n)
    inp["bank"] = np.full(n, bank)
    m = measure(np.arange(n) * 1e-3, tr, inp, cfg, 0, 0.3)
    np.testing.assert_allclose(m["ay"], 2.0 * np.cos(roll) + 9.80665 * np.sin(roll + bank), rtol=1e-14)


def test_gps_fix_times_rate_and_outage():
    t = np.arange(0, 10, 1e-3)
    cfg = SensorConfig(gps_rate=5.0, gps_outages=((4.0, 6.0),))
    mask = gps_fix_mask(t, cfg)
    ft = t[mask]
    assert len(ft) == 50 - 10  # 5 Hz for 10 s, minus 2 s of outage
    np.testing.assert_allclose(np.diff(ft[ft < 4.0]), 0.2, atol=1e-9)
    assert not np.any((ft >= 4.0) & (ft < 6.0))
    # irregular sampling still gives one fix per period, on the first sample at/after each fix time
    rng = np.random.default_rng(0)
    ti = np.cumsum(rng.uniform(0.5e-3, 1.5e-3, 20000))
    fi = ti[gps_fix_mask(ti, SensorConfig(gps_rate=5.0, gps_start=ti[0]))]
    assert np.all(np.abs(np.diff(fi) - 0.2) < 1.5e-3)


def test_course_is_yaw_plus_sideslip_at_antenna():
    n = 1000
    yaw, vx, vy, r = 3.1, 15.0, 0.6, 0.2
    xa, ya = 1.0, 0.3
    tr = truth_const(n, vx=np.full(n, vx), vy=np.full(n, vy), yaw=np.full(n, yaw), yaw_rate=np.full(n, r))
    cfg = SensorConfig(gps_velocity_noise=0.0, gps_antenna_x=xa, gps_antenna_y=ya)
    m = measure(np.arange(n) * 1e-3, tr, inputs(n), cfg, 0, 0.3)
    fix = np.isfinite(m["gps_course"])
    expected = wrap_angle(yaw + np.arctan2(vy + r * xa, vx - r * ya))  # wraps past +pi here
    np.testing.assert_allclose(m["gps_course"][fix], expected, atol=1e-12)
    assert np.all(m["gps_course"][fix] <= np.pi) and np.all(m["gps_course"][fix] > -np.pi)
    np.testing.assert_allclose(m["gps_speed"][fix], np.hypot(vy + r * xa, vx - r * ya), rtol=1e-12)


def test_course_noise_scales_with_hdop_over_speed():
    n = 400_000
    for v, hdop in ((10.0, 1.0), (20.0, 2.0)):
        tr = truth_const(n, vx=np.full(n, v))
        cfg = SensorConfig(gps_rate=1000.0, gps_hdop=hdop, gps_velocity_noise=0.04)
        m = measure(np.arange(n) * 1e-3, tr, inputs(n), cfg, 3, 0.3)
        c = m["gps_course"][np.isfinite(m["gps_course"])]
        # sigma_course = sigma_v * hdop / v for small noise; 400k samples: std estimate
        # within 0.5 % (5 sigma ~ 0.56 %), 2 % allows the small-angle approximation
        assert c.std() == pytest.approx(0.04 * hdop / v, rel=0.02)


def test_latency_delays_the_fix():
    n = 3000
    t = np.arange(n) * 1e-3
    yaw = 0.5 * t
    tr = truth_const(n, yaw=yaw)
    cfg = SensorConfig(gps_velocity_noise=0.0, gps_latency=0.1)
    m = measure(t, tr, inputs(n), cfg, 0, 0.3)
    fix = np.isfinite(m["gps_course"]) & (t > 0.2)
    np.testing.assert_allclose(m["gps_course"][fix], 0.5 * (t[fix] - 0.1), atol=1e-12)


def test_same_seed_same_noise_and_independent_streams():
    n = 1000
    t = np.arange(n) * 1e-3
    a = measure(t, truth_const(n), inputs(n), SensorConfig(), 7, 0.3)
    b = measure(t, truth_const(n), inputs(n), SensorConfig(), 7, 0.3)
    c = measure(t, truth_const(n), inputs(n), SensorConfig(accel_noise=0.5), 7, 0.3)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])
    np.testing.assert_array_equal(a["yaw_rate"], c["yaw_rate"])  # other sensors' streams untouched


def test_noise_rows_are_draw_noises_streams_stacked():
    from evstab.plants.sensors import draw_noise, noise_rows
    full = draw_noise(SensorConfig(), 11, 300)
    rows = noise_rows(11, 300, ("wheel", "gyro", "gps"))  # any subset, any order: each stream's own draws
    np.testing.assert_array_equal(rows, np.vstack([full["wheel"], full["gyro"], full["gps"]]))
    with pytest.raises(ModelError, match="unknown noise stream.*'?compass"):
        noise_rows(11, 300, ("gyro", "compass"))


def test_low_speed_course_is_nan():
    n = 1000
    m = measure(np.arange(n) * 1e-3, truth_const(n, vx=np.full(n, 0.1)), inputs(n), SensorConfig(), 0, 0.3)
    assert np.all(np.isnan(m["gps_course"]))
    assert np.any(np.isfinite(m["gps_speed"]))


def test_bad_config():
    with pytest.raises(ModelError, match="gps_rate"):
        SensorConfig(gps_rate=0.0)
    with pytest.raises(ModelError, match="outage"):
        SensorConfig(gps_outages=((5.0, 4.0),))


def test_per_sample_form_reads_the_same_noise():
    n = 3000
    t = np.arange(n) * 1e-3
    tr = truth_const(n, yaw=0.3 * t, yaw_rate=np.full(n, 0.3))
    cfg = SensorConfig(gps_latency=0.05, gyro_bias=0.001)
    whole = measure(t, tr, inputs(n), cfg, 9, 0.3)
    for k in (0, 1, 200, 1000, 2999):
        one = measure(t, tr, inputs(n), cfg, 9, 0.3, index=k)
        for name, v in whole.items():
            np.testing.assert_array_equal(one[name], v[k:k + 1], err_msg=f"{name} at {k}")

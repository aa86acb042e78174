"""FMVSS 126's numbers, each checked at its boundary on a hand-worked case, so that a wrong
threshold, instant, filter or series constant in :mod:`toolkit.verdicts.fmvss126` fails a test.

The regulation's numbers are written here as the regulation states them (49 CFR 571.126, S5.2,
S7.6, S7.9, S7.11), never read from the module under test."""

import numpy as np
import pytest
import scipy.signal

from evstab.plants import G, load_vehicle
from evstab.plants.maneuvers import sine_with_dwell
from evstab.toolkit.verdicts import fmvss126 as fm

A = 20.0  # [deg hand-wheel] the series' A in the decisions below


def score(r1=10.0, r2=5.0, lat=2.5):
    return fm.SwdScore(bos=1.0, cos=2.9, yaw_peak=0.5, yaw_ratio_1_0=r1, yaw_ratio_1_75=r2, lateral_displacement_m=lat)


@pytest.mark.parametrize("r1, ok", [(34.9, True), (35.0, True), (35.1, False)])
def test_yaw_rate_at_one_second_is_at_most_35_percent(r1, ok):
    passed, failed = score(r1=r1).passes(5 * A, A)
    assert passed == ok and (("yaw_ratio_1_0" in failed) != ok)


@pytest.mark.parametrize("r2, ok", [(19.9, True), (20.0, True), (20.1, False)])
def test_yaw_rate_at_one_and_three_quarter_seconds_is_at_most_20_percent(r2, ok):
    passed, failed = score(r2=r2).passes(5 * A, A)
    assert passed == ok and (("yaw_ratio_1_75" in failed) != ok)


@pytest.mark.parametrize("lat, ok", [(1.82, False), (1.83, True), (1.84, True)])
def test_lateral_displacement_is_at_least_1_83_m(lat, ok):
    passed, failed = score(lat=lat).passes(5 * A, A)
    assert passed == ok and (("lateral_displacement" in failed) != ok)


@pytest.mark.parametrize("multiple, applies", [(4.9, False), (5.0, True), (5.5, True)])
def test_the_displacement_applies_from_5_a(multiple, applies):
    # 4.5 A is a run of the series (1.5 A in steps of 0.5 A) the displacement does not judge
    passed, failed = score(lat=0.5).passes(multiple * A, A)
    assert passed == (not applies) and ("lateral_displacement" in failed) == applies


def _yaw_run(offset_1_0=1.0, sigma=0.5, e=0.0, n_periods=2):
    """A sine-with-dwell run (100 deg, left first) whose yaw rate (in the dwell's direction, so
    negative) is a Gaussian bump of 0.5 rad/s plus a 6 Hz cosine of ``e`` rad/s that peaks with it:
    the bump's centre ``n_periods`` periods of 6 Hz before ``offset_1_0`` s after COS."""
    t = np.arange(0.0, 9.0, 1e-3)
    hw = sine_with_dwell(20.0, np.deg2rad(100.0), start=1.0).steer(t)
    b, a = scipy.signal.butter(6, 10.0 / 500.0)  # the regulation's 10 Hz hand-wheel filter, fs 1 kHz
    f = scipy.signal.filtfilt(b, a, hw)
    kmin = np.argmin(f)
    j = kmin + np.argmax(f[kmin:] >= 0.0)
    cos = float(np.interp(0.0, f[j - 1:j + 1], t[j - 1:j + 1]))
    t1 = cos + offset_1_0
    t_p = t1 - n_periods / 6.0
    r = -(0.5 * np.exp(-(((t - t_p) / sigma) ** 2)) + e * np.cos(2 * np.pi * 6.0 * (t - t_p)))
    return t, hw, r, np.zeros_like(t), cos, t_p


def test_yaw_criteria_are_read_1_0_and_1_75_s_after_cos():
    # a wide bump (sigma 1 s) 0.5 s after COS: 100 exp(-(0.5)^2) = 77.88 % at COS + 1.0 s and
    # 100 exp(-(1.25)^2) = 20.96 % at COS + 1.75 s; at 1.1 or 1.925 s they would be 69.8 and 13.3 %
    t, hw, r, ay, cos, t_p = _yaw_run(offset_1_0=0.5 + 3 / 6.0, sigma=1.0, n_periods=3)
    assert t_p == pytest.approx(cos + 0.5, abs=1e-12)
    sc = fm.score_swd(t, hw, r, ay)
    assert sc.cos == pytest.approx(cos, abs=1e-5)  # the scorer's COS is the independent one
    # the 6 Hz filter passes a 1 s Gaussian to 1e-6 relative; interpolation between 1 ms samples
    # of a bump this wide is good to 1e-5 %
    # and zeroing by the pre-steer mean subtracts the bump's tail (0.5 exp(-2.9^2) = 1e-4 rad/s, 0.02 %)
    assert sc.yaw_ratio_1_0 == pytest.approx(100 * np.exp(-0.25), abs=0.05)
    assert sc.yaw_ratio_1_75 == pytest.approx(100 * np.exp(-1.5625), abs=0.05)


def test_yaw_rate_is_filtered_at_6_hz():
    # (the lateral acceleration goes through the same filter; its double integral to BOS + 1.07 s
    # is checked in test_fmvss126)
    # the 12-pole phaseless Butterworth at 6 Hz halves a 6 Hz component (|H|^2 = 1 / (1 + 1^12)),
    # where a 5.4 Hz filter would leave 0.21 of it and a 6.6 Hz one 0.76. The cosine peaks with the
    # bump and again at COS + 1.0 s (two of its periods later): peak 0.5 + e / 2 and, at COS + 1.0 s,
    # 0.5 exp(-(1/3 / 0.5)^2) + e / 2
    e = 0.1
    t, hw, r, ay, cos, t_p = _yaw_run(e=e)
    sc = fm.score_swd(t, hw, r, ay)
    assert sc.yaw_peak == pytest.approx(0.5 + e / 2, abs=2e-4)  # the bump's 6 Hz content: < 1e-4 rad/s
    expected = 100 * (0.5 * np.exp(-((1 / 3 / 0.5) ** 2)) + e / 2) / (0.5 + e / 2)
    assert sc.yaw_ratio_1_0 == pytest.approx(expected, abs=0.1)  # 0.1 %: the bump's own filtering
    # and the pre-steer mean of the cosine (three whole periods in 0.5 s, to a sample); a 10 % wrong
    # cut-off moves the ratio by >= 1.3 %


def test_the_amplitude_series():
    # A = 44 deg: 1.5 A = 66, steps of 22 deg up to 6.5 A = 286 deg (above 270, below the 300 cap)
    amps = fm.amplitudes(44.0)
    assert amps[0] == pytest.approx(66.0) and amps[-1] == pytest.approx(286.0)
    assert np.allclose(np.diff(amps), 22.0)
    # A = 20: 6.5 A = 130 < 270: the series goes on in steps of A/2 to 270 deg
    assert fm.amplitudes(20.0)[-1] == pytest.approx(270.0) and len(fm.amplitudes(20.0)) == 25
    # A = 50: 6.5 A = 325: every amplitude capped at 300 deg
    assert fm.amplitudes(50.0)[-1] == pytest.approx(300.0) and fm.amplitudes(50.0)[-2] == pytest.approx(275.0)


def _ramp(a1=7.66, a2=-3.0, n=40001, top=0.9):
    h = np.linspace(0.0, top, n)
    return h, a1 * h + a2 * h ** 2


def test_a_from_the_regression_between_0_1_and_0_375_g():
    # a curved response, a_y = a1 h + a2 h^2 (h [rad hand-wheel]). The least-squares line through
    # equally spaced h on [h0, h1] has slope a1 + a2 (h0 + h1) and intercept
    # -a2 (h0^2 + 4 h0 h1 + h1^2) / 6 (the best line to h^2 on an interval), with h0, h1 where a_y
    # is 0.1 g and 0.375 g; A is where the line reaches 0.3 g
    a1, a2 = 7.66, -3.0
    h, ay = _ramp(a1, a2)
    h0, h1 = ((-a1 + np.sqrt(a1 ** 2 + 4 * a2 * g * G)) / (2 * a2) for g in (0.1, 0.375))
    slope, icpt = a1 + a2 * (h0 + h1), -a2 * (h0 ** 2 + 4 * h0 * h1 + h1 ** 2) / 6
    expected = np.degrees((0.3 * G - icpt) / slope)
    # 1e-3 deg: the samples at the window's ends (2.25e-5 rad apart) and the discrete sum's
    # departure from the integral; a 10 % move of either end of the window moves A by >= 0.03 deg,
    # of the 0.3 g target by 2.4 deg
    assert fm.a_from_ramp(h, ay) == pytest.approx(expected, abs=1e-3)
    assert abs(expected - np.degrees(0.3 * G / a1)) > 0.5  # the curvature matters here


def test_a_stops_where_the_acceleration_first_reaches_0_375_g():
    # past the window's top the response falls back into the window (a car sliding out): those
    # samples are not regressed; A is as without them
    h, ay = _ramp()
    k = np.argmax(ay >= 0.375 * G)
    tail = ay[k] - np.linspace(0.0, 0.2 * G, 5000)
    h2, ay2 = np.concatenate([h[:k + 1], h[k] + np.linspace(1e-5, 0.05, 5000)]), np.concatenate([ay[:k + 1], tail])
    assert fm.a_from_ramp(h2, ay2) == pytest.approx(fm.a_from_ramp(h, ay), abs=1e-9)


def test_the_slowly_increasing_steer():
    # 80 km/h, the hand-wheel at 13.5 deg/s from 1 s; it ends at 1.5 x the linear model's hand-wheel
    # angle for 0.55 g (compact-ev: L = 2.6 m, K = understeer gradient), at most 270 deg
    p = load_vehicle("compact-ev")
    man = fm.sis_maneuver(p, -1.0)
    assert man.speed == pytest.approx(80 / 3.6, rel=1e-12)
    rate = (man.steer(np.array([3.0])) - man.steer(np.array([2.0])))[0] * p.steering_ratio
    assert rate == pytest.approx(-np.deg2rad(13.5), rel=1e-12)
    end = 1.5 * (p.wheelbase / (80 / 3.6) ** 2 + p.understeer_gradient) * 0.55 * G * p.steering_ratio
    assert man.duration == pytest.approx(1.0 + end / np.deg2rad(13.5), rel=1e-12)
    assert np.degrees(end) < 270.0  # not capped: the factor and the 0.55 g decide
    import dataclasses
    slow = dataclasses.replace(p, steering_ratio=30.0, cornering_stiffness_front=0.4 * p.cornering_stiffness_front)
    assert 1.5 * (slow.wheelbase / (80 / 3.6) ** 2 + slow.understeer_gradient) * 0.55 * G * 30.0 > np.deg2rad(270.0)
    assert fm.sis_end_handwheel(slow) == pytest.approx(np.deg2rad(270.0), rel=1e-12)

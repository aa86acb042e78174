"""Seed 000: time synchronisation (subtractive clustering, Sugeno, Lagrange) and the two-stage filter."""

import numpy as np
import pytest

from evstab.plants import load_vehicle
from evstab.plants.disturbances import Disturbances, Friction
from evstab.plants.maneuvers import dlc_000
from evstab.plants.sensors import SensorConfig
from evstab.toolkit.logs import timesync
from evstab.toolkit.estimation import design_filter, run_estimator
from evstab.toolkit.estimation.two_stage import sideslip_at
from evstab.toolkit.loop.simulator import simulate


def test_subtractive_clustering_finds_two_blobs():
    """Two tight blobs in the unit square: two centres, each within 0.05 of its blob's mean (the
    centres are data points; the blobs' spread is 0.02)."""
    rng = np.random.default_rng(0)
    a = rng.normal([0.2, 0.3], 0.02, (40, 2))
    b = rng.normal([0.8, 0.7], 0.02, (40, 2))
    c = timesync.subtractive_clustering(np.vstack([a, b]))
    assert len(c) == 2
    found = sorted(map(tuple, c))
    assert np.allclose(found[0], a.mean(axis=0), atol=0.05) and np.allclose(found[1], b.mean(axis=0), atol=0.05)


def test_sugeno_fit_is_exact_on_a_line_and_lagrange_on_a_cubic():
    """Normalised memberships sum to one, so equal linear consequents reproduce a line: least squares
    finds it to rounding; cubic Lagrange through four points is exact on a cubic."""
    x = np.linspace(0, 2, 30)
    m = timesync.fit_sugeno(x, 3.0 - 2.0 * x)
    np.testing.assert_allclose(m(np.array([0.1, 0.77, 1.9])), 3.0 - 2.0 * np.array([0.1, 0.77, 1.9]), atol=1e-9)
    ts = np.sort(np.random.default_rng(1).uniform(0, 5, 12))
    f = lambda t: 0.5 * t ** 3 - t ** 2 + 2.0  # noqa: E731
    t = np.linspace(0.5, 4.5, 50)
    np.testing.assert_allclose(timesync.lagrange(ts, f(ts), t), f(t), rtol=1e-9, atol=1e-9)


def test_fuzzy_beats_linear_under_timestamp_jitter_not_without():
    """A 5 Hz signal (0.25 and 0.6 Hz sines) resampled onto 1 kHz, eight seeded jitter draws each:
    with 20 ms Gaussian timestamp jitter fuzzy interpolation beats linear in every draw (mean RMS
    0.085 vs 0.096), with 40 ms too (0.132 vs 0.165); with exact stamps linear wins every draw
    (0.0569 vs 0.0575: the regression does not pass through exact samples). The study repeats it
    on the GPS course and speed of the double lane change (studies.estimation_000)."""
    def sig(t):
        return 3 * np.sin(2 * np.pi * 0.25 * t) + 1.5 * np.sin(2 * np.pi * 0.6 * t + 1)

    tau = np.arange(0, 20, 0.2)
    t = np.arange(1, 19, 0.001)
    for jitter, fuzzy_wins in ((0.0, 0), (0.02, 8), (0.04, 8)):
        wins = 0
        for seed in range(8):
            ts = np.sort(tau + np.random.default_rng(seed).normal(0, jitter, len(tau)))
            lin = np.sqrt(np.mean((timesync.linear(ts, sig(tau), t) - sig(t)) ** 2))
            fz = np.sqrt(np.mean((timesync.fuzzy(ts, sig(tau), t) - sig(t)) ** 2))
            wins += fz < lin
        assert wins == fuzzy_wins, jitter


def test_lever_arm_moves_sideslip_like_the_rigid_body():
    """A body at vx = 20, vy = 0.5 m/s turning at 0.3 rad/s: at 1.5 m behind the reference the
    lateral velocity is 0.5 - 0.45 = 0.05 m/s, and 1 m to the left the longitudinal one is
    20 - 0.3 = 19.7 m/s (000 eq. 28: V_P = V_A + gamma x R_AP)."""
    assert sideslip_at(20.0, 0.5, 0.3, -1.5) == pytest.approx(np.arctan2(0.05, 20.0))
    assert sideslip_at(20.0, 0.5, 0.3, 0.0, 1.0) == pytest.approx(np.arctan2(0.5, 19.7))


@pytest.mark.parametrize("mu", [0.9, 0.4])
def test_two_stage_on_the_double_lane_change(mu):
    """000's double lane change at 120 km/h, sedan-000 on the two-track plant: the two-stage filter's
    sideslip error stays below 0.1 deg RMS on either road (measured 0.034 on both; it uses no tire
    model, so the friction does not matter), and beats the kinematic filter."""
    p = load_vehicle("sedan-000")
    man = dlc_000(120 / 3.6, lead_in=600.0)
    c = simulate(p, "two-track", man, disturbances=Disturbances(friction=Friction(mu=mu)), sensors=SensorConfig(),
                 seed=2).log_columns()
    m = c["t"] >= 580.0 / (120 / 3.6)
    two = run_estimator(design_filter("two-stage", p), c)
    kkf = run_estimator(design_filter("kkf", p), c)
    rms = lambda e: float(np.sqrt(np.mean((e["beta"] - c["beta_true"])[m] ** 2)))  # noqa: E731
    assert rms(two) < np.radians(0.1)
    assert rms(two) < rms(kkf)

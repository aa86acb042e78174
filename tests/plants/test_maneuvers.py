"""Manoeuvre timing and geometry."""

import numpy as np
import pytest

from evstab.plants import ManeuverError, load_vehicle
from evstab.plants.maneuvers import (dlc_000, iso3888_1_cones, iso3888_1_lanes, make_maneuver, sine_lane_change,
                              sine_with_dwell, steer_for_lateral_acceleration)
from evstab.plants.params import G


def test_sine_with_dwell_timing():
    start, a = 1.0, 0.1
    m = sine_with_dwell(80 / 3.6, a, start=start)
    T = 1 / 0.7
    # FMVSS 126: peaks at T/4 = 0.357 s and 3T/4 = 1.071 s, dwell 0.5 s, back to zero at 1.929 s
    assert m.events["first_peak"] - start == pytest.approx(0.357, abs=5e-4)   # printed to 3 decimals
    assert m.events["second_peak"] - start == pytest.approx(1.071, abs=5e-4)
    assert m.events["steer_end"] - start == pytest.approx(1.929, abs=5e-4)
    assert m.steer(np.array([start + T / 4]))[0] == pytest.approx(a, rel=1e-12)
    dwell = np.linspace(start + 0.75 * T, start + 0.75 * T + 0.5, 50)
    np.testing.assert_allclose(m.steer(dwell), -a, rtol=1e-12)
    assert m.steer(np.array([start + 0.75 * T + 0.5 + T / 4]))[0] == pytest.approx(0.0, abs=1e-12)
    t = np.arange(0, m.duration, 1e-4)
    s = m.steer(t)
    assert np.all(np.abs(np.diff(s)) < 2 * np.pi * 0.7 * a * 1e-4 * 1.0001)  # continuous: no jumps
    assert s[t < start].max() == 0 and np.abs(s[t > m.events["steer_end"] + 1e-3]).max() == 0
    assert m.drive_on(np.array([0.5, 1.5])).tolist() == [1.0, 0.0]  # throttle released at steer start


def test_sine_lane_change_one_period():
    m = sine_lane_change(25 / 3.6, 0.05, start=3.0, period=4.0)
    t = np.array([2.9, 4.0, 5.0, 6.0, 7.0, 7.1])
    np.testing.assert_allclose(m.steer(t), [0, 0.05, 0, -0.05, 0, 0], atol=1e-15)


def test_iso3888_1_cone_positions():
    w = 1.8
    g = iso3888_1_lanes(w)
    assert [b - a for a, b in g["sections"]] == [15, 30, 25, 25, 15]
    np.testing.assert_allclose(g["widths"], [1.1 * w + 0.25, 1.2 * w + 0.25, 1.3 * w + 0.25], rtol=1e-15)
    assert g["lane3"][0] - g["lane1"][0] == pytest.approx(3.5, abs=1e-12)  # offset between right boundaries
    cones = iso3888_1_cones(w)
    # lane 1 at x = 0: cones at +-(1.1 w + 0.25)/2
    at0 = sorted(cones[cones[:, 0] == 0.0][:, 1])
    np.testing.assert_allclose(at0, [-(1.1 * w + 0.25) / 2, (1.1 * w + 0.25) / 2], rtol=1e-14)
    # lane 3 from x = 45 to 70, lane 5 from x = 95 to 110
    at45 = sorted(cones[cones[:, 0] == 45.0][:, 1])
    np.testing.assert_allclose(np.diff(at45), [1.2 * w + 0.25], rtol=1e-14)
    at110 = sorted(cones[cones[:, 0] == 110.0][:, 1])
    np.testing.assert_allclose(np.diff(at110), [1.3 * w + 0.25], rtol=1e-14)
    assert len(cones) == 18


def test_dlc_000_geometry():
    m = dlc_000(120 / 3.6)
    y = np.interp([0.0, 60.0, 80.0, 100.0, 160.0, 180.0], m.path.x, m.path.y)
    np.testing.assert_allclose(y, [0, 3.5, 3.5, 3.5, 0, 0], atol=1e-12)


def test_amplitude_for_0_3_g():
    p = load_vehicle("compact-ev")
    v = 80 / 3.6
    a = steer_for_lateral_acceleration(p, v, 0.3 * G)
    _, r = __import__("plants").bicycle.steady_state_gains(p, v)
    assert v * r * a == pytest.approx(0.3 * G, rel=1e-12)


def test_errors():
    with pytest.raises(ManeuverError, match="unknown manoeuvre"):
        make_maneuver("slalom", load_vehicle("compact-ev"), 10.0)
    with pytest.raises(ManeuverError, match="speed"):
        sine_lane_change(-1.0, 0.1)

"""NMEA 0183 reader and ``evstab convert --nmea``: conventions in closed form, a simulated log
round-tripped through NMEA written with pynmea2, and the errors."""

import math

import numpy as np
import pynmea2
import pytest

from evstab.plants import load_vehicle
from evstab.plants.maneuvers import make_maneuver
from evstab.plants.sensors import SensorConfig
from evstab.toolkit.cli import main
from evstab.toolkit.logs.drivelog import LogFormatError, read_log_csv, write_log_csv
from evstab.toolkit.logs.nmea import KNOT, NmeaFormatError, merge_onto_imu, read_nmea
from evstab.toolkit.loop.simulator import simulate

T0 = 12 * 3600.0  # the drive starts at 12:00:00 UTC


def _s(kind, fields):
    return str(getattr(pynmea2, kind)("GP", kind, tuple(fields)))


def _hms(t):
    t = round(t, 2)
    h, rem = divmod(t, 3600)
    m, s = divmod(rem, 60)
    return f"{int(h):02d}{int(m):02d}{s:05.2f}"


def _epoch(t, cog, knots, hdop, sats, heading=None, date="230394", status="A", quality="1"):
    out = [_s("RMC", (_hms(t), status, "4807.038", "N", "01131.000", "E", f"{knots:.3f}", f"{cog:.2f}", date, "", "")),
           _s("VTG", (f"{cog:.2f}", "T", "", "M", f"{knots:.3f}", "N", f"{knots * KNOT * 3.6:.3f}", "K")),
           _s("GGA", (_hms(t), "4807.038", "N", "01131.000", "E", quality, f"{sats:02d}", f"{hdop:.1f}", "545.4", "M",
                      "46.9", "M", "", "")),
           _s("GSA", ("A", "3", "04", "05", "", "", "", "", "", "", "", "", "", "", "2.5", f"{hdop:.1f}", "2.1"))]
    if heading is not None:
        out.append(_s("HDT", (f"{heading:.2f}", "T")))
    return out


def test_receiver_angles_and_speeds_become_the_schemas(tmp_path):
    """COG is clockwise from north in degrees; the schema's course is the yaw sense (counter-clockwise
    from east) in radians: north -> pi/2, east -> 0, west -> pi (continuous), 10 knots = 5.144 m/s."""
    lines = _epoch(10.0, 0.0, 10.0, 0.9, 9, heading=0.0) + _epoch(10.2, 90.0, 10.0, 0.9, 9, heading=90.0) + \
        _epoch(10.4, 180.0, 10.0, 0.9, 9) + _epoch(10.6, 270.0, 10.0, 0.9, 9)
    f = tmp_path / "a.nmea"
    f.write_text("\r\n".join(lines) + "\r\n")  # CRLF, as receivers write
    g = read_nmea(f)
    np.testing.assert_allclose(g.t, [10.0, 10.2, 10.4, 10.6], atol=1e-9)
    np.testing.assert_allclose(g.course, [np.pi / 2, 0.0, -np.pi / 2, -np.pi], atol=1e-12)
    np.testing.assert_allclose(g.speed, 10 * 1852 / 3600, rtol=1e-12)
    np.testing.assert_allclose(g.heading[:2], [np.pi / 2, 0.0], atol=1e-12)
    assert np.isnan(g.heading[2:]).all() and list(g.sats) == [9] * 4 and np.allclose(g.hdop, 0.9)


def test_course_is_continuous_across_north(tmp_path):
    cogs = [350.0, 355.0, 0.0, 5.0, 10.0]
    lines = sum((_epoch(1.0 + 0.2 * i, c, 20.0, 1.0, 8) for i, c in enumerate(cogs)), [])
    (tmp_path / "n.nmea").write_text("\n".join(lines))
    c = read_nmea(tmp_path / "n.nmea").course
    np.testing.assert_allclose(np.diff(c), -np.radians(5.0), atol=1e-12)  # turning right: yaw falls by 5 deg


def test_invalid_epochs_have_no_course_and_midnight_keeps_counting(tmp_path):
    lines = (_epoch(86399.6, 10.0, 20.0, 1.0, 8) + _epoch(86399.8, 10.0, 20.0, 1.0, 8, status="V") +
             _epoch(0.0, 10.0, 20.0, 1.0, 8, date="240394") + _epoch(0.2, 10.0, 20.0, 1.0, 8, date="240394",
                                                                        quality="0"))
    (tmp_path / "m.nmea").write_text("\n".join(lines))
    g = read_nmea(tmp_path / "m.nmea")
    np.testing.assert_allclose(g.t, [86399.6, 86399.8, 86400.0, 86400.2], atol=1e-6)
    assert np.isfinite(g.course[[0, 2]]).all() and np.isnan(g.course[[1, 3]]).all()


@pytest.mark.parametrize("text,expect", [
    ("", "no RMC or GGA"),
    ("GPRMC,123519.00,A,4807.038,N,01131.000,E,022.4,084.4,230394,003.1,W*44\n", "line 1: expected a sentence"),
    ("$GPRMC,123519.00,A,4807.038,N,01131.000,E,022.4,084.4,230394,003.1,W*45\n", "line 1: checksum"),
    ("$GPRMC,123519.00,A,4807.038,N,01131.000,E,022.4,084.4,230394,003.1,W\n", "line 1"),
    ("$GPHDT,274.07,T*03\n", "no RMC or GGA"),
])
def test_bad_nmea_names_the_line(tmp_path, text, expect):
    f = tmp_path / "bad.nmea"
    f.write_text(text)
    with pytest.raises(NmeaFormatError, match=expect):
        read_nmea(f)


def test_an_epoch_whose_time_goes_backwards_is_dropped_and_flagged(tmp_path):
    """Epochs at 10.0, 10.4, then one tagged 10.2 (with its VTG/GSA), then 10.6: the 10.2 epoch has no
    course, sits at 10.4 (where it arrived), is marked; after merging, 3 fixes and one flag on the
    10.4 fix's row; ``evstab estimate`` carries the flag as fault_gps_time."""
    f = tmp_path / "b.nmea"
    f.write_text("\n".join(_epoch(10.0, 10.0, 20.0, 1.0, 8) + _epoch(10.4, 10.0, 20.0, 1.0, 8) +
                           _epoch(10.2, 50.0, 20.0, 1.0, 8) + _epoch(10.6, 10.0, 20.0, 1.0, 8)))
    g = read_nmea(f)
    assert list(g.time_fault) == [False, False, True, False]
    np.testing.assert_allclose(g.t, [10.0, 10.4, 10.4, 10.6], atol=1e-9)
    assert np.isnan(g.course[2]) and np.isfinite(g.course[[0, 1, 3]]).all()
    imu = {"t": np.arange(9.9, 10.8, 0.01)}
    merged, counts = merge_onto_imu(imu, g)
    assert counts["time_backwards"] == 1 and counts["placed"] == 3
    assert np.isfinite(merged["gps_course"]).sum() == 3
    flagged = np.flatnonzero(merged["gps_time_fault"])
    np.testing.assert_allclose(imu["t"][flagged], [10.4], atol=1e-9)
    assert np.isfinite(merged["gps_course"][flagged]).all()  # the good 10.4 fix stays on its row


def test_absurd_values_are_refused(tmp_path):
    f = tmp_path / "b.nmea"
    f.write_text("\n".join(_epoch(10.0, 10.0, 2000.0, 1.0, 8)))
    with pytest.raises(NmeaFormatError, match=r"line 1: speed .* outside"):
        read_nmea(f)
    f.write_bytes(b"$GPHDT,274.07,T*03\n\xff\n")
    with pytest.raises(NmeaFormatError, match="not ASCII"):
        read_nmea(f)


def test_merge_places_each_epoch_on_one_imu_row_and_invents_none():
    imu = {"t": np.arange(0.0, 1.0, 0.01)}

    class G:  # the reader's shape, built by hand
        t = np.array([-0.5, 0.1, 0.3049, 0.5, 2.0])
        course = speed = hdop = sats = heading = np.arange(5.0)
        source = "g.nmea"

    out, counts = merge_onto_imu(imu, G)
    assert counts == {"placed": 3, "before": 1, "after": 1, "time_backwards": 0}
    assert np.flatnonzero(np.isfinite(out["gps_course"])).tolist() == [10, 31, 50]  # first row at or after
    G.t = np.array([0.101, 0.105])
    with pytest.raises(LogFormatError, match=r"two samples fall on row 13 \(t = 0.11\)"):
        merge_onto_imu(imu, G)


def test_a_simulated_log_round_trips_through_nmea(tmp_path, capsys):
    """Write a simulated drive's GPS columns as NMEA (pynmea2) and its IMU columns as CSV; `evstab convert`
    gives back the schema columns, fixes on the same rows, values within the sentences' resolution."""
    p = load_vehicle("compact-ev")
    man = make_maneuver("sine-lane-change", p, 60 / 3.6, np.radians(3.0))
    res = simulate(p, "two-track", man, sensors=SensorConfig(gps_outages=((2.0, 3.0),)), seed=4)
    cols = {k: v for k, v in res.log_columns().items() if not k.endswith("_true")}
    t = cols["t"]
    fix = np.flatnonzero(np.isfinite(cols["gps_course"]))
    lines = []
    for k in fix:
        cog = (90.0 - np.degrees(cols["gps_course"][k])) % 360.0
        hdg = (90.0 - np.degrees(cols["gps_heading"][k])) % 360.0
        lines += _epoch(T0 + t[k], cog, cols["gps_speed"][k] / KNOT, cols["gps_hdop"][k], int(cols["gps_sats"][k]),
                        heading=hdg)
    (tmp_path / "gps.nmea").write_text("\n".join(lines) + "\n")
    imu = {k: v for k, v in cols.items() if not k.startswith("gps_")}
    imu["t"] = t + T0
    write_log_csv(tmp_path / "imu.csv", {**imu, "gps_course": np.full(len(t), np.nan)})
    assert main(["convert", "--nmea", str(tmp_path / "gps.nmea"), "--imu", str(tmp_path / "imu.csv"),
                 "--out", str(tmp_path / "log.csv")]) == 0
    log = read_log_csv(tmp_path / "log.csv")
    got = np.flatnonzero(np.isfinite(log["gps_course"]))
    assert got.tolist() == fix.tolist()  # the fixes on their rows, none invented, the outage kept
    d = log["gps_course"][fix] - cols["gps_course"][fix]
    # course and heading are written with 0.01 deg: half of that is the rounding; the reader unwraps
    assert np.abs(np.angle(np.exp(1j * d))).max() <= np.radians(0.005) + 1e-12
    dh = log["gps_heading"][fix] - cols["gps_heading"][fix]
    assert np.abs(np.angle(np.exp(1j * dh))).max() <= np.radians(0.005) + 1e-12
    assert np.all(np.abs(np.diff(log["gps_course"][fix])) < 1.0)  # continuous: no 2 pi jumps
    # speed written with 0.001 knot, HDOP with 0.1: half a digit
    assert np.abs(log["gps_speed"][fix] - cols["gps_speed"][fix]).max() <= 0.0005 * KNOT + 1e-12
    assert np.abs(log["gps_hdop"][fix] - cols["gps_hdop"][fix]).max() <= 0.05 + 1e-12
    np.testing.assert_array_equal(log["gps_sats"][fix], cols["gps_sats"][fix])
    np.testing.assert_array_equal(log["yaw_rate"], cols["yaw_rate"])
    # the same IMU log on its own clock (t from 0, the GPS on time of day): no fix would land on it;
    # convert says so and names the offset that puts the first fix on the first row, writes nothing
    write_log_csv(tmp_path / "imu0.csv", {**imu, "t": t, "gps_course": np.full(len(t), np.nan)})
    out = tmp_path / "log0.csv"
    assert main(["convert", "--nmea", str(tmp_path / "gps.nmea"), "--imu", str(tmp_path / "imu0.csv"),
                 "--out", str(out)]) == 2
    err = capsys.readouterr().err
    offset = T0 + t[fix[0]] - t[0]
    assert f"--time-offset {offset:.3f} puts the first fix" in err and not out.exists()


def test_convert_refuses_a_bad_nmea_log_and_writes_nothing(tmp_path, capsys):
    (tmp_path / "g.nmea").write_text("$GPRMC,123519.00,A,4807.038,N,01131.000,E,022.4,084.4,230394,003.1,W*45\n")
    write_log_csv(tmp_path / "imu.csv", {"t": [0.0, 0.01], "speed": [1.0, 1.0], "steer": [0.0, 0.0],
                                         "yaw_rate": [0.0, 0.0], "gps_course": [math.nan, math.nan]})
    out = tmp_path / "log.csv"
    assert main(["convert", "--nmea", str(tmp_path / "g.nmea"), "--imu", str(tmp_path / "imu.csv"), "--out",
                 str(out)]) == 2
    assert "g.nmea: line 1: checksum" in capsys.readouterr().err and not out.exists()

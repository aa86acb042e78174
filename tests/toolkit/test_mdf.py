"""MDF4 logs through asammdf and a channel map, and gzip-compressed CSV: a simulated log written
with asammdf in a logger's units and rates comes back as the schema's columns."""

import gzip

import numpy as np
import pytest
from asammdf import MDF, Signal

from evstab.plants import load_vehicle
from evstab.plants.maneuvers import make_maneuver
from evstab.plants.sensors import SensorConfig
from evstab.toolkit.cli import main
from evstab.toolkit.logs.channels import read_log
from evstab.toolkit.logs.drivelog import LogFormatError, read_log_csv
from evstab.toolkit.logs.mdf import load_channel_map
from evstab.toolkit.loop.simulator import simulate

MAP = """
[options]
time_base = "yaw_rate"

[yaw_rate]
channel = "GyroZ"
unit = "deg/s"
scale = 0.017453292519943295

[speed]
channel = "VehSpd"
unit = "km/h"
scale = 0.2777777777777778

[steer]
channel = "SteerRW"
unit = "deg"
scale = 0.017453292519943295

[ay]
channel = "AccY_100Hz"
unit = "m/s^2"

[gps_course]
channel = "GNSS_COG"
unit = "deg"
angle = "cw-from-north-deg"

[gps_speed]
channel = "GNSS_Speed"
unit = "m/s"

[gps_sats]
channel = "GNSS_NumSV"

[gps_hdop]
channel = "GNSS_HDOP"
"""


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    """A simulated lane change with a GPS outage, written as CSV and as MDF4 the way a data logger
    would: gyro and steer in deg, speed in km/h at 1 kHz, lateral acceleration at 100 Hz, GNSS at 5 Hz
    in its own channel group with its own time stamps and course clockwise from north in degrees."""
    p = load_vehicle("compact-ev")
    man = make_maneuver("sine-lane-change", p, 60 / 3.6, np.radians(3.0))
    res = simulate(p, "two-track", man, sensors=SensorConfig(gps_outages=((2.0, 3.0),)), seed=5)
    cols = {k: v for k, v in res.log_columns().items() if not k.endswith("_true")}
    d = tmp_path_factory.mktemp("mdf")
    from evstab.toolkit.logs.drivelog import write_log_csv
    write_log_csv(d / "log.csv", cols)
    t = cols["t"]
    fix = np.isfinite(cols["gps_course"])
    t100 = t[::10]
    mdf = MDF(version="4.10")
    mdf.append([Signal(np.degrees(cols["yaw_rate"]), t, name="GyroZ", unit="deg/s"),
                Signal(cols["speed"] * 3.6, t, name="VehSpd", unit="km/h"),
                Signal(np.degrees(cols["steer"]), t, name="SteerRW", unit="deg")], comment="imu 1 kHz")
    mdf.append([Signal(cols["ay"][::10], t100, name="AccY_100Hz", unit="m/s^2")], comment="acc 100 Hz")
    mdf.append([Signal((90.0 - np.degrees(cols["gps_course"][fix])) % 360.0, t[fix], name="GNSS_COG", unit="deg"),
                Signal(cols["gps_speed"][fix], t[fix], name="GNSS_Speed", unit="m/s"),
                Signal(cols["gps_sats"][fix], t[fix], name="GNSS_NumSV", unit=""),
                Signal(cols["gps_hdop"][fix], t[fix], name="GNSS_HDOP", unit="")], comment="gnss 5 Hz")
    mdf.save(d / "log.mf4", overwrite=True)
    (d / "map.toml").write_text(MAP)
    return cols, d


def test_mdf_converts_to_the_schema(logs, tmp_path):
    cols, d = logs
    assert main(["convert", str(d / "log.mf4"), "--channel-map", str(d / "map.toml"), "--out",
                 str(tmp_path / "log.csv")]) == 0
    log = read_log_csv(tmp_path / "log.csv")
    t = cols["t"]
    np.testing.assert_array_equal(log["t"], t)
    for c in ("yaw_rate", "speed", "steer"):  # logged in deg or km/h, scaled back: rounding only
        np.testing.assert_allclose(log[c], cols[c], rtol=1e-12, atol=1e-15)
    # 100 Hz channel: linear interpolation onto the 1 kHz rows, none beyond its last sample
    inside = t <= t[::10][-1]
    np.testing.assert_allclose(log["ay"][inside], np.interp(t[inside], t[::10], cols["ay"][::10]), rtol=1e-12)
    assert np.isnan(log["ay"][~inside]).all()
    # GNSS: every fix on its own row, none invented (the outage stays empty), course back in the yaw sense
    fix = np.isfinite(cols["gps_course"])
    np.testing.assert_array_equal(np.isfinite(log["gps_course"]), fix)
    dc = log["gps_course"][fix] - cols["gps_course"][fix]
    assert np.abs(np.angle(np.exp(1j * dc))).max() < 1e-12
    assert np.all(np.abs(np.diff(log["gps_course"][fix])) < 1.0)  # continuous
    np.testing.assert_array_equal(log["gps_sats"][fix], cols["gps_sats"][fix])


def test_estimate_reads_mdf_and_gzip_like_csv(logs, tmp_path):
    cols, d = logs
    gz = tmp_path / "log.csv.gz"
    gz.write_bytes(gzip.compress((d / "log.csv").read_bytes()))
    outs = {}
    for name, args in (("csv", [str(d / "log.csv")]), ("gz", [str(gz)]),
                       ("mf4", [str(d / "log.mf4"), "--channel-map", str(d / "map.toml")])):
        out = tmp_path / f"{name}.out.csv"
        assert main(["estimate", *args, "--vehicle", "compact-ev", "--out", str(out)]) == 0
        outs[name] = read_log_csv(out, required=("t",))
    np.testing.assert_array_equal(outs["gz"]["beta"], outs["csv"]["beta"])
    # the MDF carries the same signals through deg and km/h and back (1e-15 relative; the 100 Hz
    # lateral acceleration is not used by dakf): measured 1.6e-16 rad apart; 1e-12 leaves that
    # rounding room to grow through 10 s of filtering
    np.testing.assert_allclose(outs["mf4"]["beta"], outs["csv"]["beta"], rtol=0, atol=1e-12)


@pytest.mark.parametrize("edit,needle", [
    (lambda m: m.replace("[ay]", "[lateral_acc]"), "[lateral_acc]: unknown schema column"),
    (lambda m: m.replace('unit = "m/s^2"', 'units = "m/s^2"'), "[ay]: unknown key 'units'"),
    (lambda m: m.replace('channel = "VehSpd"\n', ""), "[speed]: missing key 'channel'"),
    (lambda m: m.replace("[steer]", "[steer_x]"), "unknown schema column"),
    (lambda m: m.replace("scale = 0.2777777777777778", "scale = 0"), "'scale' must be a finite number other than 0"),
    (lambda m: m.replace('[gps_speed]\nchannel = "GNSS_Speed"', '[gps_speed]\nangle = "cw-from-north-deg"\nchannel = '
                                                                '"GNSS_Speed"'), "[gps_speed]: 'angle'"),
    (lambda m: m.replace('time_base = "yaw_rate"', 'time_base = "gps_speed"'), "time_base = 'gps_speed'"),
    (lambda m: m.replace('channel = "GyroZ"', 'channel = "GyroZZ"'), "no channel 'GyroZZ'"),
    (lambda m: m.replace('unit = "km/h"', 'unit = "m/s"'), "channel 'VehSpd' is in 'km/h', the channel map"),
    (lambda m: m + "\n[ax\n", "not a TOML file"),
])
def test_bad_channel_maps_are_named(logs, tmp_path, capsys, edit, needle):
    _, d = logs
    cmap = tmp_path / "map.toml"
    cmap.write_text(edit(MAP))
    out = tmp_path / "log.csv"
    assert main(["convert", str(d / "log.mf4"), "--channel-map", str(cmap), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert needle in err and ("map.toml" in err or "log.mf4" in err), err
    assert not out.exists()


def test_mdf_needs_a_map_and_a_real_file(tmp_path, logs):
    _, d = logs
    with pytest.raises(LogFormatError, match="needs a channel map"):
        read_log(d / "log.mf4")
    fake = tmp_path / "fake.mf4"
    fake.write_bytes(b"not an mdf file at all" * 10)
    with pytest.raises(LogFormatError, match="fake.mf4: not a readable MDF file"):
        read_log(fake, channel_map=d / "map.toml")
    assert load_channel_map(d / "map.toml")["time_base"] == "yaw_rate"

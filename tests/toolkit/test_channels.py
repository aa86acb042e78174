"""Logs with their own channels through a channel map: MATLAB files (v5 through scipy.io, v7.3 through h5py) and
CSV tables, written here in a logger's units and conventions from a simulated log, come back as the schema's
columns; every bad map or file is refused with the file and the key named."""

import numpy as np
import pytest
import scipy.io

from evstab.plants import load_vehicle
from evstab.plants.maneuvers import make_maneuver
from evstab.toolkit.logs.channels import load_channel_map, read_mapped, table_header
from evstab.toolkit.cli import main
from evstab.toolkit.logs.drivelog import LogFormatError, read_log_csv
from evstab.toolkit.loop.simulator import simulate

RATIO = 15.0
G = 9.80665

MAT_MAP = f"""
[meta]
source = "a test logger"

[options]
time_base = "yaw_rate"
sample_rate = 200.0

[yaw_rate]
channel = "GyroZ"
unit = "deg/s"

[speed]
channels = ["WheelRL", "WheelRR"]
unit = "km/h"

[steer]
channel = "HandWheel"
unit = "deg"
ratio = {RATIO}

[ay]
channel = "AccY"
unit = "g"
sign = -1

[vx_true]
channel = "Vx"
unit = "m/s"

[vy_true]
channel = "Vy"
unit = "m/s"
"""


@pytest.fixture(scope="module")
def reference():
    """A simulated lane change at 200 Hz (every fifth 1 kHz sample) and what a logger would record of it:
    gyro in deg/s, two rear wheel speeds in km/h (0.3 km/h apart, the mean is the speed), a hand-wheel angle
    in deg, a right-positive accelerometer in g, the reference velocities in m/s; no time vector."""
    p = load_vehicle("compact-ev")
    res = simulate(p, "two-track", make_maneuver("sine-lane-change", p, 60 / 3.6, np.radians(3.0)), seed=3)
    cols = {k: np.asarray(v)[::5] for k, v in res.log_columns().items()}
    chans = {"GyroZ": np.degrees(cols["yaw_rate"]), "WheelRL": cols["speed"] * 3.6 - 0.15,
             "WheelRR": cols["speed"] * 3.6 + 0.15, "HandWheel": np.degrees(cols["steer"]) * RATIO,
             "AccY": -cols["ay"] / G, "Vx": cols["vx_true"], "Vy": cols["vy_true"]}
    return cols, chans


def _check(log, cols):
    t = cols["t"] - cols["t"][0]
    np.testing.assert_allclose(log["t"], t, rtol=0, atol=1e-12)  # rows at 1 / 200 Hz from 0
    # each channel back through its unit's factor, sign and ratio: rounding only (1e-12 relative)
    for c in ("yaw_rate", "speed", "steer", "ay", "vx_true", "vy_true"):
        np.testing.assert_allclose(log[c], cols[c], rtol=1e-12, atol=1e-12, err_msg=c)
    np.testing.assert_allclose(log["beta_true"], np.arctan2(cols["vy_true"], cols["vx_true"]), rtol=1e-12, atol=1e-15)
    assert np.isnan(log["gps_course"]).all()  # a reference log: no course of its own


def test_matlab_v5_file_through_a_map(tmp_path, reference):
    cols, chans = reference
    scipy.io.savemat(tmp_path / "run.mat", {k: v.reshape(-1, 1) for k, v in chans.items()})  # column vectors
    (tmp_path / "map.toml").write_text(MAT_MAP)
    _check(read_mapped(tmp_path / "run.mat", tmp_path / "map.toml").columns, cols)


def test_matlab_v73_file_through_h5py(tmp_path, reference):
    """A v7.3 MAT-file is HDF5 behind a 512-byte MATLAB header: scipy.io refuses it, h5py reads it."""
    h5py = pytest.importorskip("h5py")
    cols, chans = reference
    path = tmp_path / "run73.mat"
    with h5py.File(path, "w", userblock_size=512) as fh:
        for k, v in chans.items():
            fh.create_dataset(k, data=v.reshape(1, -1))  # MATLAB stores a column vector as 1 x N in HDF5
    header = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Thu Dec  3 2026 HDF5 schema 1.00 ."
    with open(path, "r+b") as fh:
        fh.write(header.ljust(116, b" ") + b"\0" * 8 + b"\x00\x02" + b"IM")
    with pytest.raises(NotImplementedError):
        scipy.io.loadmat(path)
    (tmp_path / "map.toml").write_text(MAT_MAP)
    _check(read_mapped(path, tmp_path / "map.toml").columns, cols)


def test_convert_command_writes_the_reference_log(tmp_path, reference, capsys):
    cols, chans = reference
    scipy.io.savemat(tmp_path / "run.mat", chans)
    (tmp_path / "map.toml").write_text(MAT_MAP)
    out = tmp_path / "ref.csv"
    assert main(["convert", str(tmp_path / "run.mat"), "--map", str(tmp_path / "map.toml"), "--out", str(out)]) == 0
    assert "a reference log" in capsys.readouterr().out
    log = read_log_csv(out)
    np.testing.assert_allclose(log["beta_true"], np.arctan2(cols["vy_true"], cols["vx_true"]), rtol=1e-12, atol=1e-15)


def test_csv_table_with_groups_quoted_rows_and_held_epochs(tmp_path):
    """A ROS-bag dump: ';'-separated, every row one quoted string, x/y/z named by the group before them,
    a 20 Hz course repeated on 100 Hz rows (one fix per change), time in ms."""
    n = 60
    t_ms = 1000.0 + 10.0 * np.arange(n)
    rate = np.full(n, 5.0)  # deg/s
    cog = np.repeat(90.0 - 0.05 * np.arange(n // 5), 5)  # deg from north, new every 5th row
    lines = ["stamp;acc;x;y;z;rate;x;y;z;cog;speed"]
    for k in range(n):
        row = f"{t_ms[k]:.1f};;0.01;{0.1:.3f};1.0;;0.0;0.0;{rate[k]};{cog[k]};12.5"
        lines.append('"' + row + '"')
    (tmp_path / "dump.csv").write_text("\n".join(lines) + "\n")
    (tmp_path / "map.toml").write_text("""
[options]
time = "stamp"
time_scale = 1e-3
[yaw_rate]
channel = "rate.z"
unit = "deg/s"
[ay]
channel = "acc.y"
unit = "g"
[speed]
channel = "speed"
unit = "m/s"
[steer]
value = 0.0
[gps_course]
channel = "cog"
unit = "deg"
angle = "cw-from-north-deg"
held = true
""")
    log = read_mapped(tmp_path / "dump.csv", tmp_path / "map.toml")
    np.testing.assert_allclose(log["t"], (t_ms - t_ms[0]) / 1e3, atol=1e-12)
    np.testing.assert_allclose(log["yaw_rate"], np.radians(5.0), rtol=1e-15)
    np.testing.assert_allclose(log["ay"], 0.1 * G, rtol=1e-15)
    assert (log["steer"] == 0).all()
    fix = np.isfinite(log["gps_course"])
    np.testing.assert_array_equal(np.flatnonzero(fix), np.arange(0, n, 5))  # one fix per epoch, at its first row
    # 90 deg from north is the yaw sense's 0, and the bearing growing clockwise turns the course negative
    np.testing.assert_allclose(log["gps_course"][fix], np.radians(0.05 * np.arange(n // 5)), atol=1e-12)


def test_table_header_names():
    names = ["t", "acc_body_hr", "x", "y", "z", "rate", "x", "y", "z", "ins_vel_hor", "x", "y", "z", "ins_vel_hor", "x"]
    first = ["1", "", "0", "0", "1", "", "0", "0", "0", "", "1", "2", "3", "", "4"]
    assert table_header(names, first) == ["t", "acc_body_hr", "acc_body_hr.x", "acc_body_hr.y", "acc_body_hr.z",
                                          "rate", "rate.x", "rate.y", "rate.z", "ins_vel_hor", "ins_vel_hor.x",
                                          "ins_vel_hor.y", "ins_vel_hor.z", "ins_vel_hor#2", "ins_vel_hor.x#2"]


@pytest.mark.parametrize("edit,needle", [
    (lambda m: m.replace('unit = "km/h"', 'unit = "deg"'), "[speed]: unit 'deg' is rad, column 'speed' is in m/s"),
    (lambda m: m.replace('unit = "km/h"', 'unit = "kph"'), "[speed]: unit 'kph' is not one evstab converts"),
    (lambda m: m.replace("sign = -1", "sign = 2"), "[ay]: 'sign' must be 1 or -1"),
    (lambda m: m.replace("sign = -1", "ratio = 15.0"), "'ratio' (hand-wheel to road-wheel angle) is for 'steer' only"),
    (lambda m: m.replace(f"ratio = {RATIO}", "ratio = 0.5"), "'ratio' = 0.5: a steering ratio is between 1 and 100"),
    (lambda m: m.replace("sample_rate = 200.0", ""), "has no time stamps: give [options] sample_rate"),
    (lambda m: m.replace("sample_rate = 200.0", "sample_rate = -1"), "sample_rate = -1: expected a rate in Hz"),
    (lambda m: m.replace('channel = "GyroZ"', 'channel = "GyroX"'), "no channel 'GyroX' (mapped to 'yaw_rate'"),
    (lambda m: m.replace('channels = ["WheelRL", "WheelRR"]', 'channels = []'), "'channels' a list of names"),
    (lambda m: m.replace("[vx_true]", "[vx_ref]"), "[vx_ref]: unknown schema column"),
    (lambda m: m.replace('channel = "HandWheel"', 'value = 0.1\nchannel = "HandWheel"'), "'value'"),
    (lambda m: m.replace("[steer]", "[steer]\nheld = true"), "'held' is for GPS columns"),
])
def test_bad_maps_are_named(tmp_path, reference, edit, needle, capsys):
    cols, chans = reference
    scipy.io.savemat(tmp_path / "run.mat", chans)
    (tmp_path / "map.toml").write_text(edit(MAT_MAP))
    out = tmp_path / "ref.csv"
    assert main(["convert", str(tmp_path / "run.mat"), "--map", str(tmp_path / "map.toml"), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert needle in err and ("map.toml" in err or "run.mat" in err), err
    assert not out.exists()


def test_matlab_file_needs_a_map_and_a_real_file(tmp_path, reference):
    from evstab.toolkit.logs.channels import read_log
    _, chans = reference
    scipy.io.savemat(tmp_path / "run.mat", chans)
    with pytest.raises(LogFormatError, match="a MATLAB log needs a channel map"):
        read_log(tmp_path / "run.mat")
    (tmp_path / "fake.mat").write_bytes(b"not a mat file" * 20)
    (tmp_path / "map.toml").write_text(MAT_MAP)
    with pytest.raises(LogFormatError, match="fake.mat: not a readable MATLAB file"):
        read_mapped(tmp_path / "fake.mat", tmp_path / "map.toml")
    assert load_channel_map(tmp_path / "map.toml")["sample_rate"] == 200.0

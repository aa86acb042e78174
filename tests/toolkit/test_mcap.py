"""ROS 2 bags (MCAP) to drive logs (toolkit.logs.mcaplog through toolkit.logs.channels.read_mapped): a bag that
mcap-ros2-support writes with the standard message definitions (sensor_msgs/Imu, nav_msgs/Odometry,
geometry_msgs/TwistStamped, sensor_msgs/NavSatFix, std_msgs/Float64 for the hand-wheel angle) converts to the
drive log the same samples give as a CSV table, and to the simulated log it was drawn from; `evstab estimate`
runs on it; frames (FRD, NED) convert to ISO 8855; damaged bags and maps exit 2 with a message naming the file,
topic or field, and write nothing (a fuzz test mutates the bag and the map)."""

from __future__ import annotations

import csv
import io

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap_ros2.writer import Writer

from evstab.plants import load_vehicle
from evstab.plants.maneuvers import make_maneuver
from evstab.toolkit.logs.channels import horizontal_velocity, read_mapped
from evstab.toolkit.cli import main
from evstab.toolkit.logs.drivelog import LogFormatError, read_log_csv
from evstab.toolkit.logs.mcaplog import split_channel
from evstab.toolkit.logs.nmea import yaw_sense
from evstab.toolkit.loop.simulator import simulate

# The standard ROS 2 message definitions (common_interfaces), with their dependencies, as `ros2 bag record`
# stores them in an MCAP schema record.
SEP = "\n" + "=" * 80 + "\n"
TIME = "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec"
HEADER = "MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id"
VECTOR3 = "MSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z"
QUATERNION = "MSG: geometry_msgs/Quaternion\nfloat64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1"
POINT = "MSG: geometry_msgs/Point\nfloat64 x\nfloat64 y\nfloat64 z"
TWIST = "MSG: geometry_msgs/Twist\nVector3 linear\nVector3 angular"
MSGDEFS = {
    "sensor_msgs/msg/Imu": SEP.join([
        "std_msgs/Header header\ngeometry_msgs/Quaternion orientation\nfloat64[9] orientation_covariance\n"
        "geometry_msgs/Vector3 angular_velocity\nfloat64[9] angular_velocity_covariance\n"
        "geometry_msgs/Vector3 linear_acceleration\nfloat64[9] linear_acceleration_covariance",
        QUATERNION, VECTOR3, HEADER, TIME]),
    "nav_msgs/msg/Odometry": SEP.join([
        "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/PoseWithCovariance pose\n"
        "geometry_msgs/TwistWithCovariance twist",
        "MSG: geometry_msgs/PoseWithCovariance\nPose pose\nfloat64[36] covariance",
        "MSG: geometry_msgs/Pose\nPoint position\nQuaternion orientation", POINT, QUATERNION,
        "MSG: geometry_msgs/TwistWithCovariance\nTwist twist\nfloat64[36] covariance", TWIST, VECTOR3, HEADER, TIME]),
    "geometry_msgs/msg/TwistStamped": SEP.join(["std_msgs/Header header\nTwist twist", TWIST, VECTOR3, HEADER, TIME]),
    "sensor_msgs/msg/NavSatFix": SEP.join([
        "std_msgs/Header header\nsensor_msgs/NavSatStatus status\nfloat64 latitude\nfloat64 longitude\n"
        "float64 altitude\nfloat64[9] position_covariance\nuint8 COVARIANCE_TYPE_UNKNOWN = 0\n"
        "uint8 COVARIANCE_TYPE_APPROXIMATED = 1\nuint8 COVARIANCE_TYPE_DIAGONAL_KNOWN = 2\n"
        "uint8 COVARIANCE_TYPE_KNOWN = 3\nuint8 position_covariance_type",
        "MSG: sensor_msgs/NavSatStatus\nint8 STATUS_NO_FIX = -1\nint8 STATUS_FIX = 0\nint8 STATUS_SBAS_FIX = 1\n"
        "int8 STATUS_GBAS_FIX = 2\nint8 status\nuint16 SERVICE_GPS = 1\nuint16 SERVICE_GLONASS = 2\n"
        "uint16 SERVICE_COMPASS = 4\nuint16 SERVICE_GALILEO = 8\nuint16 service", HEADER, TIME]),
    "std_msgs/msg/Float64": "float64 data",
}

MAP = """[meta]
source = "test: a ROS 2 bag with the standard messages"

[options]
time_base = "yaw_rate"
{options}

[yaw_rate]
channel = "{imu}.angular_velocity.z"
unit = "rad/s"
{frame}

[ay]
channel = "{imu}.linear_acceleration.y"
unit = "m/s^2"
{frame}

[ax]
channel = "{imu}.linear_acceleration.x"
unit = "m/s^2"
{frame}

[speed]
channel = "{odom}.twist.twist.linear.x"
unit = "m/s"

[vx_true]
channel = "{odom}.twist.twist.linear.x"

[vy_true]
channel = "{odom}.twist.twist.linear.y"

[steer]
channel = "{steer}.data"
unit = "deg"
ratio = {ratio}

[gps_course]
velocity = ["{vel}.twist.linear.x", "{vel}.twist.linear.y"]
frame = "{earth}"
fix_status = "{fix}.status.status"

[gps_speed]
velocity = ["{vel}.twist.linear.x", "{vel}.twist.linear.y"]
frame = "{earth}"
fix_status = "{fix}.status.status"
"""
BAG_NAMES = dict(imu="/imu/data", odom="/odom", steer="/steering_wheel_angle", vel="/gnss/vel", fix="/gnss/fix")
CSV_NAMES = dict(imu="imu", odom="odom", steer="steer", vel="vel", fix="fix")
T0_NS = 1_733_000_000_000_000_000  # the bag's clock: UNIX time in ns, as a recorder's
LATENCY_NS = 3_000_000  # [ns] the recorder receives each stamped message 3 ms after its header stamp
NO_FIX = (3, 17)
"""The GNSS epochs (of 50) whose NavSatFix says STATUS_NO_FIX: their velocities are no fixes."""


def _header(ns):
    return {"stamp": {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}, "frame_id": "base_link"}


def _write_bag(path, log, ratio, *, imu_frd=False, ned=False, zero_stamps=False, chunked=True):
    """The log's sensors as a ROS 2 bag: IMU at 200 Hz, odometry at 100 Hz, the hand-wheel angle at 50 Hz (a
    Float64, no header: its log time is its time), the GNSS velocity and fix at the log's 5 Hz fixes. Every
    sample sits on a 5 ms instant of the simulated log. Returns the table of the same samples, one row per
    instant (empty where a topic has none)."""
    buf = io.BytesIO()
    w = Writer(buf, chunk_size=1 << 20 if chunked else 64)
    schema = {name: w.register_msgdef(name, text) for name, text in MSGDEFS.items()}
    t = log["t"]
    fixes = np.flatnonzero(np.isfinite(log["gps_course"]))
    rows = []
    zy = -1.0 if imu_frd else 1.0
    for k in range(0, len(t), 5):
        ns = T0_NS + int(round(t[k] * 1e9))
        stamp = 0 if zero_stamps else ns
        row = {"time": (ns - T0_NS) / 1e9}
        imu = {"header": _header(stamp), "angular_velocity": {"x": 0.0, "y": 0.0, "z": zy * log["yaw_rate"][k]},
               "linear_acceleration": {"x": log["ax"][k], "y": zy * log["ay"][k], "z": zy * 9.81}}
        w.write_message(BAG_NAMES["imu"], schema["sensor_msgs/msg/Imu"], imu, log_time=ns + LATENCY_NS)
        row.update({"imu.angular_velocity.z": log["yaw_rate"][k], "imu.linear_acceleration.y": log["ay"][k],
                    "imu.linear_acceleration.x": log["ax"][k]})
        if k % 10 == 0:
            vx = log["speed"][k]
            vy = vx * np.tan(log["beta_true"][k])
            odom = {"header": _header(stamp), "child_frame_id": "base_link",
                    "twist": {"twist": {"linear": {"x": vx, "y": vy, "z": 0.0}}}}
            w.write_message(BAG_NAMES["odom"], schema["nav_msgs/msg/Odometry"], odom, log_time=ns + LATENCY_NS)
            row.update({"odom.twist.twist.linear.x": vx, "odom.twist.twist.linear.y": vy})
        if k % 20 == 0:
            hw = float(np.degrees(log["steer"][k]) * ratio)
            w.write_message(BAG_NAMES["steer"], schema["std_msgs/msg/Float64"], {"data": hw}, log_time=ns)
            row["steer.data"] = hw
        near = fixes[(fixes >= k) & (fixes < k + 5)]
        if len(near):
            e = int(np.searchsorted(fixes, near[0]))
            c, gs = log["gps_course"][near[0]], log["gps_speed"][near[0]]
            east, north = gs * np.cos(c), gs * np.sin(c)
            x, y = (north, east) if ned else (east, north)
            w.write_message(BAG_NAMES["vel"], schema["geometry_msgs/msg/TwistStamped"],
                            {"header": _header(stamp), "twist": {"linear": {"x": x, "y": y, "z": 0.0}}},
                            log_time=ns + LATENCY_NS)
            status = -1 if e in NO_FIX else 0
            w.write_message(BAG_NAMES["fix"], schema["sensor_msgs/msg/NavSatFix"],
                            {"header": _header(stamp), "status": {"status": status, "service": 1},
                             "latitude": 48.1, "longitude": 11.5, "altitude": 520.0}, log_time=ns + LATENCY_NS)
            row.update({"vel.twist.linear.x": x, "vel.twist.linear.y": y, "fix.status.status": float(status)})
        rows.append(row)
    w.finish()
    path.write_bytes(buf.getvalue())
    return rows


def _map(ratio, names, options, frame="", earth="ENU"):
    return MAP.format(options=options, ratio=ratio, frame=frame, earth=earth, **names)


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    """A closed-loop lane change's sensors (compact-ev, 60 km/h, 10 s) as a ROS 2 bag, the channel map, and the
    same samples as a CSV table with its map; and the simulated log."""
    root = tmp_path_factory.mktemp("mcap")
    p = load_vehicle("compact-ev")
    log = simulate(p, "two-track", make_maneuver("sine-lane-change", p, 60 / 3.6, np.radians(3.0)), seed=2,
                   controller="two-dof").log_columns()
    rows = _write_bag(root / "drive.mcap", log, p.steering_ratio)
    names = ["time"] + sorted({k for r in rows for k in r} - {"time"})
    with open(root / "drive.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(names)
        for r in rows:
            w.writerow([repr(float(r[n])) if n in r else "" for n in names])
    (root / "bag.toml").write_text(_map(p.steering_ratio, BAG_NAMES, ""))
    (root / "csv.toml").write_text(_map(p.steering_ratio, CSV_NAMES, 'time = "time"'))
    return root, log, p


def test_a_bag_converts_to_the_log_its_samples_give_as_csv(bag):
    """Every column equal to the CSV table's, bit for bit: the same numbers (CDR stores float64), on the same
    times (both whole nanoseconds from the first sample divided by 1e9), through the same interpolation; the
    header stamps are the times, not the log times 3 ms later."""
    root, _, _ = bag
    got = read_mapped(root / "drive.mcap", root / "bag.toml").columns
    ref = read_mapped(root / "drive.csv", root / "csv.toml").columns
    assert set(got) == set(ref) and {"gps_course", "gps_speed", "beta_true", "steer"} <= set(got)
    for c in ref:
        np.testing.assert_array_equal(got[c], ref[c], err_msg=c)


def test_a_bag_converts_to_the_simulated_log_it_was_drawn_from(bag):
    """Against the simulation, not the reader: on the IMU's 200 Hz rows the yaw rate and accelerations are the
    simulated ones exactly; the steer is the hand-wheel angle over the ratio, interpolated between 50 Hz samples
    (within the steer's change over 20 ms); the sideslip from the odometry's body velocity is the simulated one
    on its 100 Hz rows (atan(tan(beta)), 1e-12 rad of rounding), interpolated between them; the course from the ENU velocity is the simulated course (1e-12
    rad) at every fix but the two the NavSatFix says are no fixes."""
    root, log, _ = bag
    read = read_mapped(root / "drive.mcap", root / "bag.toml")
    got = read.columns
    # The IMU's last sample is at 9.995 s, the hand-wheel angle's (50 Hz) at 9.980 s: a required column is not
    # extrapolated, so the IMU rows after 9.980 s, three, are dropped, and the reader says so.
    k = np.arange(0, len(log["t"]), 5)[:-3]
    assert read.notes == ("rows: the last 3 (after t = 9.98 s) dropped, after the last sample of "
                          "'/steering_wheel_angle.data' (steer)",)
    np.testing.assert_allclose(got["t"], log["t"][k], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(got["yaw_rate"], log["yaw_rate"][k])
    np.testing.assert_array_equal(got["ay"], log["ay"][k])
    np.testing.assert_allclose(got["beta_true"][::2], log["beta_true"][k][::2], rtol=0, atol=1e-12)  # odometry rows
    between = np.abs(np.diff(log["beta_true"])).max() * 10  # the sideslip's largest change over 10 ms
    np.testing.assert_allclose(got["beta_true"], log["beta_true"][k], rtol=0, atol=between)
    step = np.abs(np.diff(log["steer"])).max() * 20
    np.testing.assert_allclose(got["steer"], log["steer"][k], rtol=0, atol=step)
    fixes = np.flatnonzero(np.isfinite(log["gps_course"]))
    placed = np.flatnonzero(np.isfinite(got["gps_course"]))
    assert len(placed) == len(fixes) - len(NO_FIX)
    want = np.delete(fixes, NO_FIX)
    np.testing.assert_allclose(got["gps_course"][placed], log["gps_course"][want], rtol=0, atol=1e-12)
    np.testing.assert_allclose(got["gps_speed"][placed], log["gps_speed"][want], rtol=0, atol=1e-12)


@pytest.mark.parametrize("how", ["frd", "ned", "log-stamps"])
def test_other_frames_and_stamps_give_the_same_log(bag, tmp_path, how):
    """An IMU in forward-right-down (its yaw rate and lateral acceleration of the other sign) with frame =
    "FRD", a GNSS velocity in north-east-down with frame = "NED", and a bag whose drivers leave the stamps at
    zero read by their log times (stamps = "log"; the recorder's 3 ms latency then shifts every stamped topic,
    the steering's own times stay) give the log the FLU/ENU bag gives, bit for bit where only signs or the
    axis order changed."""
    root, log, p = bag
    ref = read_mapped(root / "drive.mcap", root / "bag.toml").columns
    if how == "frd":
        _write_bag(tmp_path / "b.mcap", log, p.steering_ratio, imu_frd=True)
        text = _map(p.steering_ratio, BAG_NAMES, "", frame='frame = "FRD"')
    elif how == "ned":
        _write_bag(tmp_path / "b.mcap", log, p.steering_ratio, ned=True)
        text = _map(p.steering_ratio, BAG_NAMES, "", earth="NED")
    else:
        _write_bag(tmp_path / "b.mcap", log, p.steering_ratio, zero_stamps=True)
        (tmp_path / "m.toml").write_text(_map(p.steering_ratio, BAG_NAMES, ""))
        with pytest.raises(LogFormatError, match="every header stamp is zero.*stamps = \"log\""):
            read_mapped(tmp_path / "b.mcap", tmp_path / "m.toml")
        text = _map(p.steering_ratio, BAG_NAMES, 'stamps = "log"')
    (tmp_path / "m.toml").write_text(text)
    got = read_mapped(tmp_path / "b.mcap", tmp_path / "m.toml").columns
    if how == "log-stamps":
        # The time base (IMU) starts 3 ms after the steering's first sample: its rows are 3 ms later, and one
        # more of them (9.983 s) falls after the steering's last sample (9.980 s).
        np.testing.assert_allclose(got["t"], ref["t"][:-1] + LATENCY_NS / 1e9, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(got["yaw_rate"], ref["yaw_rate"][:-1])
        return
    for c in ref:
        # NED swaps x and y: atan2 of the same two numbers in the other order, the same angle to 1 ulp
        tol = 1e-15 if how == "ned" and c == "gps_course" else 0.0
        np.testing.assert_allclose(got[c], ref[c], rtol=0, atol=tol, err_msg=c)


def test_evstab_estimate_runs_on_the_converted_bag(bag, tmp_path, capsys):
    root, _, _ = bag
    out = tmp_path / "drive.csv"
    assert main(["convert", "--mcap", str(root / "drive.mcap"), "--map", str(root / "bag.toml"),
                 "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "48 GPS fixes" in printed and "rows: the last 3" in printed  # 50 epochs, 2 without a fix
    assert main(["estimate", str(out), "--vehicle", "compact-ev", "--out", str(tmp_path / "est.csv")]) == 0
    est = np.genfromtxt(tmp_path / "est.csv", delimiter=",", names=True)
    assert np.all(np.isfinite(est["beta"]))


def test_the_mcap_and_can_options_take_only_their_kind(bag, tmp_path, capsys):
    root, _, _ = bag
    out = tmp_path / "o.csv"
    assert main(["convert", "--mcap", str(root / "drive.csv"), "--map", str(root / "bag.toml"), "--out",
                 str(out)]) == 2
    assert "expected an MCAP file (.mcap)" in capsys.readouterr().err and not out.exists()
    assert main(["convert", "--can", str(root / "drive.mcap"), "--map", str(root / "bag.toml"), "--out",
                 str(out)]) == 2
    assert "expected a CAN trace" in capsys.readouterr().err and not out.exists()
    assert main(["convert", str(root / "drive.mcap"), "--mcap", str(root / "drive.mcap"), "--map",
                 str(root / "bag.toml"), "--out", str(out)]) == 2
    assert "give one log" in capsys.readouterr().err and not out.exists()


def test_json_messages_read_like_cdr(tmp_path):
    """An MCAP whose messages are JSON (what Foxglove bridges and many loggers write): the same field paths and
    header stamps; hand-worked values: a steady 0.2 rad/s turn at 20 m/s, 100 Hz, the hand-wheel at 30 deg over a
    ratio of 15 (2 deg of road-wheel angle), the stamps 1 ms before the log times."""
    import json

    from mcap.writer import Writer as McapWriter
    path = tmp_path / "j.mcap"
    with open(path, "wb") as fh:
        w = McapWriter(fh)
        w.start(profile="", library="test")
        sid = w.register_schema("vehicle", "jsonschema", b"{}")
        ch = {n: w.register_channel(topic=n, message_encoding="json", schema_id=sid) for n in ("/imu", "/car")}
        for k in range(100):
            ns = 5_000_000_000 + k * 10_000_000
            stamp = {"sec": ns // 10**9, "nanosec": ns % 10**9}
            w.add_message(ch["/imu"], log_time=ns + 1_000_000, publish_time=ns, data=json.dumps(
                {"header": {"stamp": stamp}, "angular_velocity": {"z": 0.2}}).encode())
            w.add_message(ch["/car"], log_time=ns + 1_000_000, publish_time=ns, data=json.dumps(
                {"header": {"stamp": stamp}, "speed": 20, "wheel": [30.0, 0.0]}).encode())
        w.finish()
    (tmp_path / "j.toml").write_text('[yaw_rate]\nchannel = "/imu.angular_velocity.z"\n[speed]\nchannel = "/car.speed"\n'
                                     '[steer]\nchannel = "/car.wheel[0]"\nunit = "deg"\nratio = 15\n')
    got = read_mapped(path, tmp_path / "j.toml").columns
    np.testing.assert_allclose(got["t"], np.arange(100) * 0.01, rtol=0, atol=1e-12)  # the stamps, from 0
    assert np.all(got["yaw_rate"] == 0.2) and np.all(got["speed"] == 20.0)
    np.testing.assert_allclose(got["steer"], np.radians(2.0), rtol=1e-15)


def test_horizontal_velocity_by_hand():
    """Course 0 east, counter-clockwise (the yaw sense of docs/models.md): north is +90 deg in ENU (0, 1) and NED (1, 0),
    west 180 deg; crossing south-west to west the angle is unwrapped, not folded to -180; no velocity has no
    course; the ground speed is the norm. Cross-checked against the receiver-bearing conversion nmea.yaw_sense
    (bearing clockwise from north)."""
    e = np.array([1.0, 0.0, -1.0, -1.0, -1.0, 0.0, 3.0])
    n = np.array([0.0, 1.0, 0.0, -1e-9, 1e-9, 0.0, 4.0])
    got = horizontal_velocity("gps_course", "ENU", e.copy(), n.copy())
    np.testing.assert_array_equal(horizontal_velocity("gps_course", "NED", n.copy(), e.copy()), got)
    np.testing.assert_allclose(got[:3], [0.0, np.pi / 2, np.pi], rtol=0, atol=1e-15)
    assert got[3] > np.pi and np.isnan(got[5])  # -180 deg - 1e-9 read as 180 deg + 1e-9 after 180 deg
    bearing = np.degrees(np.arctan2(e, n))
    ok = np.isfinite(got)
    np.testing.assert_allclose(got[ok], yaw_sense(bearing)[ok] + 0.0, rtol=0, atol=1e-12)
    np.testing.assert_allclose(horizontal_velocity("gps_speed", "ENU", e, n)[-1], 5.0, rtol=0, atol=0)


def test_channel_names_split_at_the_first_dot():
    assert split_channel("/imu/data.angular_velocity.z") == ("/imu/data", ["angular_velocity", "z"])
    assert split_channel("/gnss/fix.position_covariance[4]") == ("/gnss/fix", ["position_covariance", 4])
    for bad in ("/imu/data", "/imu/data.", "/imu.angular velocity", "/imu.x[a]"):
        with pytest.raises(LogFormatError, match="channel"):
            split_channel(bad)


def _convert(bag_path, map_path, tmp_path):
    out = tmp_path / "out.csv"
    return main(["convert", str(bag_path), "--map", str(map_path), "--out", str(out)]), out


@pytest.mark.parametrize("what, edit, message", [
    ("an unknown topic", lambda m: m.replace('"/odom.', '"/odometry.'), "no topic '/odometry'"),
    ("the wrong message type", lambda m: m.replace('"/steering_wheel_angle.data"', '"/gnss/fix.data"'),
     "sensor_msgs/msg/NavSatFix.*has no field 'data'"),
    ("a field that is a string", lambda m: m.replace('"/imu/data.angular_velocity.z"', '"/imu/data.header.frame_id"'),
     "'header.frame_id' is a string"),
    ("an array not indexed", lambda m: m.replace('"/imu/data.linear_acceleration.x"',
                                                 '"/imu/data.orientation_covariance"'),
     "is an array of 9"),
    ("an index past the end", lambda m: m.replace('"/imu/data.linear_acceleration.x"',
                                                  '"/imu/data.orientation_covariance[9]"'), "has 9 elements"),
    ("a nested message", lambda m: m.replace('"/imu/data.linear_acceleration.x"', '"/imu/data.orientation"'),
     "is a message"),
    ("a frame on a speed", lambda m: m.replace('[speed]\n', '[speed]\nframe = "FRD"\n'), "'frame'"),
    ("a velocity without a frame", lambda m: m.replace('frame = "ENU"\n', '', 1), "needs 'frame'"),
])
def test_malformed_maps_exit_2_naming_what_and_write_nothing(bag, tmp_path, capsys, what, edit, message):
    root, _, _ = bag
    text = edit((root / "bag.toml").read_text())
    assert text != (root / "bag.toml").read_text(), what
    (tmp_path / "m.toml").write_text(text)
    code, out = _convert(root / "drive.mcap", tmp_path / "m.toml", tmp_path)
    err = capsys.readouterr().err
    assert code == 2 and not out.exists(), (what, err)
    import re
    assert re.search(message, err), (what, err)


def test_damaged_bags_exit_2_naming_the_file_and_write_nothing(bag, tmp_path, capsys):
    root, _, _ = bag
    data = (root / "drive.mcap").read_bytes()
    cases = {"cut.mcap": (data[: len(data) // 2], "cannot be read past its message"),
             "csv.mcap": ((root / "drive.csv").read_bytes(), "not an MCAP file")}
    for name, (content, message) in cases.items():
        (tmp_path / name).write_bytes(content)
        code, out = _convert(tmp_path / name, root / "bag.toml", tmp_path)
        err = capsys.readouterr().err
        assert code == 2 and name in err and message in err and not out.exists(), err


N_BAG, N_MAP = 120, 80
SETTINGS = dict(derandomize=True, deadline=None, database=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


def _exits_cleanly(root, tmp_path, bag_bytes, map_text, capsys):
    (tmp_path / "f.mcap").write_bytes(bag_bytes)
    (tmp_path / "f.toml").write_text(map_text)
    out = tmp_path / "out.csv"
    if out.exists():
        out.unlink()
    code = main(["convert", str(tmp_path / "f.mcap"), "--map", str(tmp_path / "f.toml"), "--out", str(out)])
    err = capsys.readouterr().err
    assert code in (0, 2), err
    if code == 2:
        assert err.strip() and not out.exists(), err
    else:
        assert np.isfinite(read_log_csv(out).columns["yaw_rate"]).all()


@pytest.fixture(scope="module")
def small_bag(bag, tmp_path_factory):
    """The first 2 s of the bag, unchunked (records in the clear, so that a mutation reaches the records
    themselves and not only a compressed chunk's CRC)."""
    root, log, p = bag
    short = {k: v[:2000] for k, v in log.items()}
    path = tmp_path_factory.mktemp("small") / "s.mcap"
    _write_bag(path, short, p.steering_ratio, chunked=False)
    return root, path.read_bytes()


@settings(max_examples=N_BAG, **SETTINGS)
@given(st.data())
def test_fuzz_damaged_bags(small_bag, tmp_path, capsys, data):
    """Bytes flipped, dropped or the file cut: status 0 and a complete log, or status 2 and one message."""
    root, raw = small_bag
    b = bytearray(raw)
    kind = data.draw(st.sampled_from(["flip", "drop", "cut"]))
    at = data.draw(st.integers(0, len(b) - 1))
    if kind == "flip":
        b[at] ^= data.draw(st.integers(1, 255))
    elif kind == "drop":
        del b[at: at + data.draw(st.integers(1, 64))]
    else:
        del b[at:]
    _exits_cleanly(root, tmp_path, bytes(b), (root / "bag.toml").read_text(), capsys)


@settings(max_examples=N_MAP, **SETTINGS)
@given(st.data())
def test_fuzz_damaged_maps(small_bag, tmp_path, capsys, data):
    """A channel map's tokens replaced, lines dropped or duplicated, on the valid bag."""
    root, raw = small_bag
    lines = (root / "bag.toml").read_text().splitlines()
    k = data.draw(st.integers(0, len(lines) - 1))
    kind = data.draw(st.sampled_from(["drop", "dup", "token"]))
    if kind == "drop":
        del lines[k]
    elif kind == "dup":
        lines.insert(k, lines[k])
    else:
        tokens = lines[k].split(" ")
        j = data.draw(st.integers(0, len(tokens) - 1))
        tokens[j] = data.draw(st.sampled_from(['"FRD"', '"NED"', "1e9", '"/imu/data.header.stamp.sec"', "[", "",
                                               '["/odom.twist.twist.linear.x"]', '"/x.y"', "-1", "true"]))
        lines[k] = " ".join(tokens)
    _exits_cleanly(root, tmp_path, raw, "\n".join(lines) + "\n", capsys)

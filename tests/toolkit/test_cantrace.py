"""CAN traces to drive logs (toolkit.logs.cantrace through toolkit.logs.channels.read_mapped): a BLF and an ASC trace that
python-can writes, with a DBC the test writes (a multiplexed steering message among them), decode with cantools
to the drive log the same samples give as a CSV table; `evstab estimate` runs on it; damaged inputs exit 2 with a
message naming the file, message or signal, and write nothing; a late message is named."""

from __future__ import annotations

import csv

import can
import cantools
import numpy as np
import pytest

from evstab.plants import load_vehicle
from evstab.plants.maneuvers import make_maneuver
from evstab.toolkit.logs.channels import read_mapped
from evstab.toolkit.cli import main
from evstab.toolkit.loop.simulator import simulate

DBC = """VERSION ""

NS_ :

BS_:

BU_: ESC

BO_ 257 ESP_21: 8 ESC
 SG_ YawRate : 0|16@1- (0.01,0) [-300|300] "deg/s" Vector__XXX
 SG_ LatAcc : 16|16@1- (0.001,0) [-30|30] "m/s^2" Vector__XXX

BO_ 258 Wheels: 8 ESC
 SG_ WheelSpeedRL : 0|16@1+ (0.01,0) [0|655] "km/h" Vector__XXX
 SG_ WheelSpeedRR : 16|16@1+ (0.01,0) [0|655] "km/h" Vector__XXX

BO_ 259 Steering: 8 ESC
 SG_ Mux M : 0|8@1+ (1,0) [0|1] "" Vector__XXX
 SG_ SteerAngle m0 : 8|16@1- (0.1,0) [-800|800] "deg" Vector__XXX
 SG_ SteerRate m1 : 8|16@1- (1,0) [-2000|2000] "deg/s" Vector__XXX

BO_ 260 GNSS: 8 ESC
 SG_ Course : 0|32@1- (1e-06,0) [-100|100] "rad" Vector__XXX
 SG_ Hdop : 32|8@1+ (0.1,0) [0|25] "" Vector__XXX
 SG_ Sats : 40|8@1+ (1,0) [0|255] "" Vector__XXX
"""

MAP = """[meta]
source = "test: a CAN trace with the test's DBC"

[options]
time_base = "yaw_rate"
{options}

[yaw_rate]
channel = "YawRate"
unit = "deg/s"

[ay]
channel = "LatAcc"
unit = "m/s^2"

[speed]
channels = ["WheelSpeedRL", "WheelSpeedRR"]
unit = "km/h"

[steer]
channel = "SteerAngle"
unit = "deg"
ratio = {ratio}

[gps_course]
channel = "Course"
unit = "rad"

[gps_hdop]
channel = "Hdop"
unit = "-"

[gps_sats]
channel = "Sats"
unit = "-"
"""
PERIOD = 0.01
"""[s] Every message but the GNSS one at 100 Hz, on the same instants (the steering message alternates its
multiplexer: the steer angle at 50 Hz); the GNSS one every 20th instant (5 Hz)."""


@pytest.fixture(scope="module")
def trace(tmp_path_factory):
    """A closed-loop lane change's sensors (compact-ev, 60 km/h, 10 s) as CAN frames: the BLF and ASC traces, the
    DBC, the channel maps, and a CSV table of the same decoded samples (empty where a frame carries none)."""
    root = tmp_path_factory.mktemp("can")
    p = load_vehicle("compact-ev")
    log = simulate(p, "two-track", make_maneuver("sine-lane-change", p, 60 / 3.6, np.radians(3.0)), seed=2,
                   controller="two-dof").log_columns()
    (root / "car.dbc").write_text(DBC)
    db = cantools.database.load_file(str(root / "car.dbc"))
    t = log["t"]
    step = int(round(PERIOD / (t[1] - t[0])))
    fix = np.flatnonzero(np.isfinite(log["gps_course"]))
    msgs, rows = [], []
    instants = list(range(0, len(t), step))
    instants = instants[:len(instants) - 1 + len(instants) % 2]  # an odd number: the last carries the steer angle
    for j, k in enumerate(instants):
        ts = 1000.0 + j * PERIOD  # an absolute clock, as a logger's
        vals = {"YawRate": np.degrees(log["yaw_rate"][k]), "LatAcc": log["ay"][k],
                "WheelSpeedRL": 3.6 * log["speed"][k], "WheelSpeedRR": 3.6 * log["speed"][k]}
        frames = [("ESP_21", {"YawRate": vals["YawRate"], "LatAcc": vals["LatAcc"]}),
                  ("Wheels", {"WheelSpeedRL": vals["WheelSpeedRL"], "WheelSpeedRR": vals["WheelSpeedRR"]})]
        if j % 2 == 0:
            frames.append(("Steering", {"Mux": 0, "SteerAngle": np.degrees(log["steer"][k]) * p.steering_ratio}))
        else:
            frames.append(("Steering", {"Mux": 1, "SteerRate": 0.0}))
        near = fix[(fix >= k) & (fix < k + step)]
        if j % 20 == 0 and len(near):
            f = near[0]
            frames.append(("GNSS", {"Course": log["gps_course"][f], "Hdop": 1.0, "Sats": 10}))
        row = {"time": ts}
        for name, sig in frames:
            m = db.get_message_by_name(name)
            data = m.encode(sig)
            msgs.append(can.Message(timestamp=ts, arbitration_id=m.frame_id, data=data, is_extended_id=False))
            row.update({k_: v for k_, v in m.decode(data, decode_choices=False).items() if k_ != "Mux"})
        rows.append(row)
    for suffix, writer in ((".blf", can.BLFWriter), (".asc", can.ASCWriter)):
        with writer(str(root / f"drive{suffix}")) as w:
            for m in msgs:
                w.on_message_received(m)
    names = ["time", "YawRate", "LatAcc", "WheelSpeedRL", "WheelSpeedRR", "SteerAngle", "SteerRate", "Course", "Hdop",
             "Sats"]
    with open(root / "drive.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(names)
        for r in rows:
            w.writerow([repr(float(r[n])) if n in r else "" for n in names])
    (root / "can.toml").write_text(MAP.format(options='dbc = "car.dbc"', ratio=p.steering_ratio))
    (root / "csv.toml").write_text(MAP.format(options='time = "time"', ratio=p.steering_ratio))
    return root, msgs


@pytest.mark.parametrize("suffix", [".blf", ".asc"])
def test_a_can_trace_converts_to_the_log_its_samples_give_as_csv(trace, suffix):
    """Every column equal to the CSV table's: times to 1e-9 s (the trace's clock is stored in whole nanoseconds
    in BLF, microseconds in ASC, then the first frame's time is taken off), values to 1e-9 of their scale (the
    same raw numbers times the DBC's scale, interpolated alike)."""
    root, _ = trace
    got = read_mapped(root / f"drive{suffix}", root / "can.toml").columns
    ref = read_mapped(root / "drive.csv", root / "csv.toml").columns
    assert set(got) == set(ref)
    np.testing.assert_allclose(got["t"], ref["t"], rtol=0, atol=1e-5 if suffix == ".asc" else 1e-9)
    for c in ref:
        if c == "t":
            continue
        scale = max(1.0, float(np.nanmax(np.abs(ref[c]))))
        np.testing.assert_allclose(got[c], ref[c], rtol=0, atol=1e-6 * scale, equal_nan=True, err_msg=c)
    assert np.isfinite(got["gps_course"]).sum() >= 20  # 5 Hz fixes over 10 s: placed, not interpolated


def test_evstab_estimate_runs_on_the_converted_trace(trace, tmp_path, capsys):
    root, _ = trace
    out = tmp_path / "drive.csv"
    assert main(["convert", str(root / "drive.blf"), "--dbc", str(root / "car.dbc"), "--map", str(root / "can.toml"),
                 "--out", str(out)]) == 0
    assert "late frames" not in capsys.readouterr().out
    assert main(["estimate", str(out), "--vehicle", "compact-ev", "--out", str(tmp_path / "est.csv")]) == 0
    est = np.genfromtxt(tmp_path / "est.csv", delimiter=",", names=True)
    assert np.all(np.isfinite(est["beta"]))


def _convert(root, tmp_path, trace_name, dbc_name="car.dbc", map_name="can.toml"):
    out = tmp_path / "out.csv"
    code = main(["convert", str(root / trace_name), "--dbc", str(root / dbc_name), "--map", str(root / map_name),
                 "--out", str(out)])
    return code, out


def test_damaged_inputs_exit_2_naming_what_and_write_nothing(trace, tmp_path, capsys):
    root, msgs = trace
    # a map naming a signal the DBC does not have
    (tmp_path / "bad.toml").write_text((root / "can.toml").read_text().replace('"LatAcc"', '"LatAccel"'))
    code, out = _convert(root, tmp_path, "drive.blf", map_name=str(tmp_path / "bad.toml"))
    assert code == 2 and "LatAccel" in capsys.readouterr().err and not out.exists()
    # a DBC that is not one
    (tmp_path / "bad.dbc").write_text("BO_ this is not a DBC")
    code, out = _convert(root, tmp_path, "drive.blf", dbc_name=str(tmp_path / "bad.dbc"))
    assert code == 2 and "bad.dbc" in capsys.readouterr().err and not out.exists()
    # a truncated BLF
    data = (root / "drive.blf").read_bytes()
    (tmp_path / "cut.blf").write_bytes(data[: len(data) // 2])
    code, out = _convert(root, tmp_path, str(tmp_path / "cut.blf"))
    err = capsys.readouterr().err
    assert code == 2 and "cut.blf" in err and not out.exists(), err
    # an ASC cut at a line boundary (every line it keeps is whole: only its missing last line tells)
    lines = (root / "drive.asc").read_text().splitlines(keepends=True)
    (tmp_path / "cut.asc").write_text("".join(lines[: len(lines) // 2]))
    code, out = _convert(root, tmp_path, str(tmp_path / "cut.asc"))
    err = capsys.readouterr().err
    assert code == 2 and "cut.asc" in err and "End TriggerBlock" in err and not out.exists(), err
    # a trace without the steering message
    with can.BLFWriter(str(tmp_path / "nosteer.blf")) as w:
        for m in msgs:
            if m.arbitration_id != 259:
                w.on_message_received(m)
    code, out = _convert(root, tmp_path, str(tmp_path / "nosteer.blf"))
    err = capsys.readouterr().err
    assert code == 2 and "Steering" in err and "0x103" in err and not out.exists(), err


def test_a_late_message_is_named(trace, tmp_path, capsys):
    """Ten ESP_21 frames dropped in a row: one interval of 110 ms against the message's 10 ms."""
    root, msgs = trace
    esp = [m for m in msgs if m.arbitration_id == 257]
    drop = {id(m) for m in esp[200:210]}
    with can.BLFWriter(str(tmp_path / "late.blf")) as w:
        for m in msgs:
            if id(m) not in drop:
                w.on_message_received(m)
    code, out = _convert(root, tmp_path, str(tmp_path / "late.blf"))
    printed = capsys.readouterr().out
    assert code == 0 and out.exists()
    assert "late frames: message 'ESP_21' (id 0x101): 1 of 988 intervals longer than 3 x its median 10.0 ms, the " \
           "longest 110.0 ms" in printed, printed  # 999 instants, 10 frames dropped

"""Fuzzing `evstab convert` with damaged CAN traces and DBC files (toolkit.logs.cantrace).

Each example is a mutation of a valid BLF trace (bytes flipped, dropped, truncated), of a valid ASC trace
(tokens and lines replaced, dropped, duplicated) or of the valid DBC (tokens and lines). Whatever comes in,
the command must end with status 0 and a complete drive log, or status 2, one message and nothing written:
never an uncaught exception. Hypothesis runs derandomized (the same examples every run).
"""

from pathlib import Path

import can
import cantools
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from evstab.toolkit.cli import main
from evstab.toolkit.logs.drivelog import read_log_csv

N_BLF, N_ASC, N_DBC = 150, 150, 150
SETTINGS = dict(derandomize=True, deadline=None, database=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
DBC = """VERSION ""

NS_ :

BS_:

BU_: ESC

BO_ 257 ESP_21: 8 ESC
 SG_ YawRate : 0|16@1- (0.01,0) [-300|300] "deg/s" Vector__XXX
 SG_ LatAcc : 16|16@1- (0.001,0) [-30|30] "m/s^2" Vector__XXX
 SG_ Speed : 32|16@1+ (0.01,0) [0|655] "km/h" Vector__XXX
 SG_ Steer : 48|16@1- (0.001,0) [-30|30] "deg" Vector__XXX

BO_ 260 GNSS: 8 ESC
 SG_ Mux M : 0|8@1+ (1,0) [0|1] "" Vector__XXX
 SG_ Course m0 : 8|32@1- (1e-06,0) [-100|100] "rad" Vector__XXX
 SG_ Hdop m1 : 8|8@1+ (0.1,0) [0|25] "" Vector__XXX
"""
MAP = """[options]
time_base = "yaw_rate"
dbc = "car.dbc"

[yaw_rate]
channel = "YawRate"
unit = "deg/s"

[ay]
channel = "LatAcc"
unit = "m/s^2"

[speed]
channel = "Speed"
unit = "km/h"

[steer]
channel = "Steer"
unit = "deg"

[gps_course]
channel = "Course"
unit = "rad"
"""
TOKENS = ["", "0", "-1", "999999999", "nan", "x", " ", ":", "|", "@", "(", ")", "\"", "BO_", "SG_", "m0", "M",
          "Rx", "Tx", "d", "1e308", "\x00", "é"]
OUTCOMES: dict = {}


def _frames():
    db = cantools.database.load_string(DBC, database_format="dbc")
    esp, gnss = db.get_message_by_name("ESP_21"), db.get_message_by_name("GNSS")
    out = []
    for k in range(60):
        t = 0.01 * k
        out.append(can.Message(timestamp=t, arbitration_id=257, is_extended_id=False, data=esp.encode(
            {"YawRate": 5 * np.sin(t), "LatAcc": 2 * np.sin(t), "Speed": 60.0, "Steer": 0.5 * np.sin(t)})))
        if k % 20 == 0:
            out.append(can.Message(timestamp=t, arbitration_id=260, is_extended_id=False,
                                   data=gnss.encode({"Mux": 0, "Course": 0.1 * t})))
    return out


@pytest.fixture(scope="module")
def valid(tmp_path_factory):
    root = tmp_path_factory.mktemp("can_fuzz")
    for suffix, writer in ((".blf", can.BLFWriter), (".asc", can.ASCWriter)):
        with writer(str(root / f"valid{suffix}")) as w:
            for m in _frames():
                w.on_message_received(m)
    return (root / "valid.blf").read_bytes(), (root / "valid.asc").read_text()


def _check(tmp: Path, trace: Path, capsys, dbc: str = DBC) -> None:
    (tmp / "car.dbc").write_text(dbc, encoding="utf-8", errors="surrogatepass")
    (tmp / "map.toml").write_text(MAP)
    out = tmp / "log.csv"
    if out.exists():
        out.unlink()
    rc = main(["convert", str(trace), "--map", str(tmp / "map.toml"), "--out", str(out)])
    err = capsys.readouterr().err
    assert not [p.name for p in tmp.iterdir() if p.name.startswith(".log.csv")]  # no half-written file
    OUTCOMES[rc] = OUTCOMES.get(rc, 0) + 1
    if rc == 2:
        assert not out.exists() and err.count("\n") == 1 and "error:" in err, err  # one message
    else:
        assert rc == 0 and out.exists()
        log = read_log_csv(out)
        assert len(log) > 0 and np.all(np.isfinite(log["yaw_rate"]))


def _mutate_text(text: str, data) -> str:
    lines = text.split("\n")
    for _ in range(data.draw(st.integers(1, 3))):
        op = data.draw(st.sampled_from(["token", "drop_line", "dup_line", "truncate", "char"]))
        i = data.draw(st.integers(0, len(lines) - 1))
        if op == "token":
            words = lines[i].split(" ")
            j = data.draw(st.integers(0, len(words) - 1))
            words[j] = data.draw(st.sampled_from(TOKENS))
            lines[i] = " ".join(words)
        elif op == "drop_line" and len(lines) > 1:
            del lines[i]
        elif op == "dup_line":
            lines.insert(i, lines[i])
        elif op == "truncate":
            lines = lines[: i + 1]
            lines[-1] = lines[-1][: data.draw(st.integers(0, len(lines[-1])))]
        elif op == "char" and lines[i]:
            j = data.draw(st.integers(0, len(lines[i]) - 1))
            lines[i] = lines[i][:j] + data.draw(st.sampled_from(TOKENS)) + lines[i][j + 1:]
    return "\n".join(lines)


@settings(max_examples=N_BLF, **SETTINGS)
@given(data=st.data())
def test_mutated_blf_traces(valid, tmp_path, capsys, data):
    raw = bytearray(valid[0])
    for _ in range(data.draw(st.integers(1, 4))):
        op = data.draw(st.sampled_from(["flip", "drop", "truncate", "zero"]))
        i = data.draw(st.integers(0, len(raw) - 1))
        if op == "flip":
            raw[i] ^= data.draw(st.integers(1, 255))
        elif op == "drop":
            del raw[i: i + data.draw(st.integers(1, 64))]
        elif op == "truncate":
            del raw[i:]
        else:
            raw[i: i + 16] = bytes(min(16, len(raw) - i))
        if not raw:
            break
    trace = tmp_path / "trace.blf"
    trace.write_bytes(bytes(raw))
    _check(tmp_path, trace, capsys)


@settings(max_examples=N_ASC, **SETTINGS)
@given(data=st.data())
def test_mutated_asc_traces(valid, tmp_path, capsys, data):
    trace = tmp_path / "trace.asc"
    trace.write_text(_mutate_text(valid[1], data), encoding="utf-8", errors="surrogatepass")
    _check(tmp_path, trace, capsys)


@settings(max_examples=N_DBC, **SETTINGS)
@given(data=st.data())
def test_mutated_dbc_files(valid, tmp_path, capsys, data):
    trace = tmp_path / "trace.blf"
    trace.write_bytes(valid[0])
    _check(tmp_path, trace, capsys, _mutate_text(DBC, data))


def test_the_can_fuzz_ran_both_ways():
    """Runs after the three above (file order): every example ended in 0 or 2, both outcomes occurred."""
    if sum(OUTCOMES.values()) < N_BLF + N_ASC + N_DBC:  # run alone (-k), or the file split over workers
        return
    assert set(OUTCOMES) == {0, 2}, OUTCOMES

"""The drive-log reader on bad input, case by case: each one exits 2 from `evstab estimate` with one
message naming the file, row and column, and leaves no output (not even a temporary file)."""

import numpy as np
import pytest

from evstab.toolkit.cli import main
from evstab.toolkit.logs.drivelog import read_log_csv

H = "t,speed,steer,yaw_rate,gps_course\n"
GOOD = "0,10,0.01,0.02,0.5\n0.001,10,0.01,0.02,\n0.002,10,0.01,0.02,\n"

BAD = {
    "empty_file": ("", "empty file"),
    "header_only": (H, "header only"),
    "missing_required_column": ("t,speed,steer,gps_course\n0,10,0,0.5\n", "row 1: missing required column 'yaw_rate'"),
    "duplicate_column": ("t,speed,steer,yaw_rate,yaw_rate,gps_course\n0,10,0,0,0,0.5\n",
                         "row 1: duplicate column 'yaw_rate'"),
    "text_in_numeric_column": (H + "0,10,abc,0,0.5\n", "row 2, column 'steer': 'abc' is not a number"),
    "nan_in_required_column": (H + "0,nan,0,0,0.5\n", "row 2, column 'speed': empty or NaN"),
    "inf_in_required_column": (H + "0,inf,0,0,0.5\n", "row 2, column 'speed': inf is not finite"),
    "duplicate_t": (H + "0,10,0,0,0.5\n0,10,0,0,\n", "row 3, column 't': 0.0 is not after the previous time 0.0"),
    "decreasing_t": (H + "0.1,10,0,0,0.5\n0.05,10,0,0,\n", "row 3, column 't': 0.05 is not after"),
    "truncated_last_line": (H + GOOD + "0.003,10,0.0", "row 5: 3 fields, expected 5"),
    "absurd_speed": (H + "0,1e6,0,0,0.5\n0.001,10,0,0,\n", "row 2, column 'speed': 1000000.0 is outside"),
    "absurd_steer": (H + "0,10,10,0,0.5\n0.001,10,0,0,\n", "row 2, column 'steer': 10.0 is outside"),
    "absurd_yaw_rate_in_deg": (H + "0,10,0,0,0.5\n0.001,10,0,45.0,\n", "row 3, column 'yaw_rate': 45.0 is outside"),
    "not_utf8": (b"t,speed,steer,yaw_rate,gps_course\n0,10,0,0,\xff\n", "not UTF-8"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_log_exits_2_names_the_place_and_writes_nothing(case, tmp_path, capsys):
    text, needle = BAD[case]
    log = tmp_path / f"{case}.csv"
    if isinstance(text, bytes):
        log.write_bytes(text)
    else:
        log.write_text(text, newline="")
    out = tmp_path / "est.csv"
    assert main(["estimate", str(log), "--vehicle", "compact-ev", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{case}.csv" in err[0] and needle in err[0], err
    assert list(tmp_path.iterdir()) == [log]  # no output, no temporary file


@pytest.mark.parametrize("variant", ["bom", "crlf", "bom_and_crlf"])
def test_bom_and_crlf_logs_read_like_plain_ones(variant, tmp_path):
    text = H + GOOD
    if "crlf" in variant:
        text = text.replace("\n", "\r\n")
    if "bom" in variant:
        text = "\ufeff" + text
    (tmp_path / "plain.csv").write_text(H + GOOD, newline="")
    (tmp_path / "v.csv").write_text(text, newline="")
    a, b = read_log_csv(tmp_path / "plain.csv"), read_log_csv(tmp_path / "v.csv")
    assert list(a.columns) == list(b.columns)
    for c in a.columns:
        np.testing.assert_array_equal(a[c], b[c])

"""Fuzzing the readers and ``evstab estimate`` with malformed drive logs and vehicle files.

Each example is a mutation of a valid file (characters, tokens, lines and columns replaced,
dropped, duplicated; BOM, CRLF, truncation, binary bytes) or a table of random columns and
values. Whatever comes in, the command must end with status 0 and a complete output, or with
status 2, one message and nothing written: never an uncaught exception. Hypothesis runs
derandomized (the same examples every run); the counts add up to 1,200 files per run.
"""

import tomllib
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from plants import bundled_vehicles
from toolkit.cli import main
from toolkit.logio import read_log_csv

N_LOGS, N_RANDOM_TABLES, N_VEHICLES = 600, 300, 300
SETTINGS = dict(derandomize=True, deadline=None, database=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])

HEADER = "t,speed,steer,yaw_rate,ay,gps_course,gps_hdop,gps_sats"


def _valid_log() -> str:
    rng = np.random.default_rng(3)
    rows = [HEADER]
    for k in range(40):
        course = f"{0.3 + 0.01 * k:.4f}" if k % 10 == 0 else ""
        rows.append(f"{k * 0.001:.3f},{15 + rng.normal(0, 0.1):.4f},{0.02 * np.sin(k / 5):.5f},"
                    f"{0.05 * np.sin(k / 5):.5f},{rng.normal(0, 0.5):.4f},{course},{'0.9' if course else ''},"
                    f"{'9' if course else ''}")
    return "\n".join(rows) + "\n"


VALID = _valid_log()
TOKENS = ["", "nan", "NaN", "inf", "-inf", "1e308", "-1e308", "1e6", "10", "-0", "abc", "0x10", " ", ",", "\"",
          "\x00", "1,2", "é", "\r", "t", "speed", "1e-320", "+", "."]
BUNDLED = (Path(__file__).resolve().parents[2] / "plants" / "data" / "compact-ev.toml").read_text()


def _mutate(text: str, data) -> str | bytes:
    lines = text.split("\n")
    for _ in range(data.draw(st.integers(1, 4))):
        op = data.draw(st.sampled_from(["token", "drop_line", "dup_line", "swap_lines", "drop_field", "dup_header",
                                        "truncate", "crlf", "bom", "char", "reverse_t", "empty_lines"]))
        i = data.draw(st.integers(0, len(lines) - 1))
        fields = lines[i].split(",")
        if op == "token":
            j = data.draw(st.integers(0, len(fields) - 1))
            fields[j] = data.draw(st.sampled_from(TOKENS))
            lines[i] = ",".join(fields)
        elif op == "drop_line" and len(lines) > 1:
            del lines[i]
        elif op == "dup_line":
            lines.insert(i, lines[i])
        elif op == "swap_lines":
            j = data.draw(st.integers(0, len(lines) - 1))
            lines[i], lines[j] = lines[j], lines[i]
        elif op == "drop_field" and len(fields) > 1:
            del fields[data.draw(st.integers(0, len(fields) - 1))]
            lines[i] = ",".join(fields)
        elif op == "dup_header":
            head = lines[0].split(",")
            lines[0] = ",".join(head + [data.draw(st.sampled_from(head))])
        elif op == "truncate":
            text2 = "\n".join(lines)
            return text2[:data.draw(st.integers(0, len(text2)))]
        elif op == "crlf":
            lines = [ln + "\r" for ln in lines]
        elif op == "bom":
            lines[0] = "\ufeff" + lines[0]
        elif op == "char":
            if lines[i]:
                j = data.draw(st.integers(0, len(lines[i]) - 1))
                lines[i] = lines[i][:j] + data.draw(st.characters(codec="utf-8")) + lines[i][j + 1:]
        elif op == "reverse_t":
            lines = [lines[0]] + lines[:0:-1]
        elif op == "empty_lines":
            lines.insert(i, "")
    out = "\n".join(lines)
    if data.draw(st.integers(0, 30)) == 0:
        return out.encode("utf-8", "surrogatepass")[:50] + bytes(data.draw(st.lists(st.integers(0, 255), max_size=20)))
    return out


OUTCOMES = {0: 0, 2: 0}


def _check_command(tmp: Path, log: Path, vehicle: str, capsys) -> None:
    out = tmp / "est.csv"
    if out.exists():
        out.unlink()
    rc = main(["estimate", str(log), "--vehicle", vehicle, "--out", str(out)])
    err = capsys.readouterr().err
    leftovers = [p.name for p in tmp.iterdir() if p.name.startswith(".est.csv")]
    assert not leftovers, leftovers  # never a half-written temporary file
    OUTCOMES[rc] = OUTCOMES.get(rc, 0) + 1
    if rc == 2:
        assert not out.exists() and err.count("\n") == 1 and "error:" in err  # one message, no output
    else:
        assert rc == 0 and out.exists()
        est = np.genfromtxt(out, delimiter=",", names=True)  # complete: one row per log row, finite estimates
        assert len(np.atleast_1d(est)) == len(read_log_csv(log)) and np.all(np.isfinite(est["beta"]))


@settings(max_examples=N_LOGS, **SETTINGS)
@given(data=st.data())
def test_mutated_logs(tmp_path, capsys, data):
    log = tmp_path / "log.csv"
    content = _mutate(VALID, data)
    (log.write_bytes if isinstance(content, bytes) else lambda c: log.write_text(c, newline=""))(content)
    _check_command(tmp_path, log, "compact-ev", capsys)


COLUMNS = ["t", "speed", "steer", "yaw_rate", "gps_course", "ay", "yaw_moment", "gps_hdop", "gps_sats", "extra"]
VALUES = st.one_of(st.floats(allow_nan=True, allow_infinity=True, width=64), st.integers(-10**6, 10**6),
                   st.sampled_from(TOKENS))


@settings(max_examples=N_RANDOM_TABLES, **SETTINGS)
@given(cols=st.lists(st.sampled_from(COLUMNS), min_size=1, max_size=8),
       rows=st.lists(st.lists(VALUES, min_size=1, max_size=9), min_size=0, max_size=6))
def test_random_tables(tmp_path, capsys, cols, rows):
    log = tmp_path / "log.csv"
    text = ",".join(cols) + "\n" + "".join(",".join(str(v) for v in r) + "\n" for r in rows)
    log.write_text(text, encoding="utf-8", errors="surrogatepass", newline="")
    _check_command(tmp_path, log, "compact-ev", capsys)


@settings(max_examples=N_VEHICLES, **SETTINGS)
@given(data=st.data())
def test_mutated_vehicle_files(tmp_path, capsys, data):
    lines = BUNDLED.split("\n")
    for _ in range(data.draw(st.integers(1, 3))):
        i = data.draw(st.integers(0, len(lines) - 1))
        op = data.draw(st.sampled_from(["value", "drop", "dup", "key", "char"]))
        if op == "value" and "=" in lines[i]:
            key = lines[i].split("=")[0]
            lines[i] = key + "= " + data.draw(st.sampled_from(["-1500.0", "0", "nan", "inf", "\"x\"", "[1, 2]",
                                                               "1e309", "true", "-0.5", "1e-30", ""]))
        elif op == "drop":
            del lines[i]
        elif op == "dup":
            lines.insert(i, lines[i])
        elif op == "key" and "=" in lines[i]:
            lines[i] = data.draw(st.sampled_from(["mass_kg", "yaw_inertia", "lf", "unknown"])) + " =" + \
                lines[i].split("=", 1)[1]
        elif op == "char" and lines[i]:
            j = data.draw(st.integers(0, len(lines[i]) - 1))
            lines[i] = lines[i][:j] + data.draw(st.sampled_from(list("[]=\"#\\x0 "))) + lines[i][j + 1:]
    vehicle = tmp_path / "car.toml"
    vehicle.write_text("\n".join(lines))
    log = tmp_path / "log.csv"
    if not log.exists():
        log.write_text(VALID)
    _check_command(tmp_path, log, str(vehicle), capsys)


def test_the_fuzz_ran_a_thousand_files_both_ways():
    """Runs after the three above (file order): every example ended in 0 or 2, both outcomes occurred."""
    assert set(OUTCOMES) == {0, 2}
    if sum(OUTCOMES.values()) == 0:  # run alone (-k): nothing to count
        return
    assert sum(OUTCOMES.values()) >= 1000 and OUTCOMES[0] > 0 and OUTCOMES[2] > 0, OUTCOMES


def test_a_vehicle_that_makes_the_filter_diverge_is_refused(tmp_path, capsys):
    vehicle = tmp_path / "feather.toml"
    vehicle.write_text(BUNDLED.replace("yaw_inertia = 2350.0", "yaw_inertia = 1e-30"))
    assert tomllib.loads(vehicle.read_text())["vehicle"]["yaw_inertia"] == 1e-30
    log = tmp_path / "log.csv"
    log.write_text(VALID)
    out = tmp_path / "est.csv"
    assert main(["estimate", str(log), "--vehicle", str(vehicle), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "log.csv: row" in err and "diverged" in err and not out.exists()
    assert "compact-ev" in bundled_vehicles()

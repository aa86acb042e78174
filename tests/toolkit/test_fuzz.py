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

from evstab.plants import bundled_vehicles
from evstab.toolkit.cli import main
from evstab.toolkit.logs.drivelog import read_log_csv

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
                                        "truncate", "crlf", "bom", "char", "reverse_t", "empty_lines", "handwheel",
                                        "semicolons"]))
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
        elif op == "handwheel":  # the steer column logged as the hand-wheel angle (ratio 15)
            head = lines[0].split(",")
            if "steer" in head:
                j = head.index("steer")
                for k in range(1, len(lines)):
                    f = lines[k].split(",")
                    try:
                        f[j] = repr(15.0 * float(f[j]))
                    except (ValueError, IndexError):
                        continue
                    lines[k] = ",".join(f)
        elif op == "semicolons":  # a spreadsheet's export
            lines = [ln.replace(",", ";") for ln in lines]
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
    # the same file through the simulator (bicycle plant, 2 s): 0 with a complete log, or 2 with one
    # message naming the file and nothing written
    sim = tmp_path / "sim.csv"
    if sim.exists():
        sim.unlink()
    rc = main(["simulate", "--vehicle", str(vehicle), "--plant", "bicycle", "--maneuver", "step-steer",
               "--speed", "60", "--out", str(sim)])
    err = capsys.readouterr().err
    if rc == 2:
        assert not sim.exists() and err.count("\n") == 1 and "error:" in err, err
    else:
        assert rc == 0 and len(read_log_csv(sim)) > 1000


NUMBERS = ["0", "-1", "1e308", "nan", "inf", "abc", "", "1,5", "0x10"]
ARGS = {
    "simulate": {"--vehicle": ["compact-ev", "micro-ev", "no-such-car", "/dev/null", ""],
                 "--plant": ["bicycle", "xyz", "commonroad-mb:9", "two-track:3", ""],
                 "--maneuver": ["step-steer", "sine-lane-change", "iso3888-1", "warp", ""],
                 "--speed": ["60", "20", "301", "800", "-5"] + NUMBERS,
                 "--amplitude": ["2", "-3", "90", "1e6"] + NUMBERS, "--mu": ["0.5", "1.0", "-0.2", "5"] + NUMBERS,
                 "--controller": ["two-dof", "none", "bogus"], "--estimator": ["dakf", "kf", "bogus"],
                 "--dt": ["1e-3", "0", "-1", "abc", "nan"], "--gps-outage": ["2:4", "4:2", "x:y", "-1:1", "1"],
                 "--seed": ["0", "7", "-3", "1.5", "abc"], "--design": ["/nonexistent", ""]},
    "estimate": {"--vehicle": ["compact-ev", "no-such-car", ""], "--method": ["dakf", "kf-bias", "bogus"],
                 "--gps-latency": ["0", "0.1", "-1", "10"] + NUMBERS, "--channel-map": ["/nonexistent.toml"],
                 "--design": ["/nonexistent"]},
    "export": {"--format": ["c", "json", "bogus"], "--precision": ["float32", "float16"]},
    "report": {},
    "score-swd": {"--vehicle": ["compact-ev", "micro-ev", "nope"]},
    "vehicles": {},
    "convert": {"--nmea": ["/nonexistent.nmea"], "--imu": ["/nonexistent.csv"], "--time-offset": ["0", "5"] + NUMBERS,
                "--channel-map": ["/nonexistent.toml"]},
}
"""Per command, options and values to draw from: valid ones, out-of-range numbers, unit mistakes
(800 km/h), garbage, options that do not fit together. The plant is the bicycle (or refused), so
that a valid draw runs in a fraction of a second."""
REQUIRED = {"simulate": ("--vehicle", "--maneuver", "--speed"), "estimate": ("--vehicle",),
            "score-swd": ("--vehicle",)}
N_ARGS = 150


@settings(max_examples=N_ARGS, **SETTINGS)
@given(data=st.data())
def test_fuzzed_command_lines(tmp_path, capsys, data):
    """Random command lines: status 0 with an output, or 2 with an error message and nothing written."""
    import shutil
    log = tmp_path / "log.csv"
    log.write_text(VALID)
    out = tmp_path / "out.csv"
    if out.exists():  # tmp_path is shared by the examples of one test
        out.unlink() if out.is_file() else shutil.rmtree(out)
    cmd = data.draw(st.sampled_from(sorted(ARGS) + ["nonsense"]))
    argv = [cmd]
    if cmd in ("estimate", "score-swd", "convert"):
        argv.append(str(log) if data.draw(st.integers(0, 9)) < 7 else
                    data.draw(st.sampled_from([str(tmp_path / "missing.csv"), "-", ""])))
    elif cmd in ("export", "report"):
        argv.append(data.draw(st.sampled_from([str(tmp_path), str(tmp_path / "missing"), ""])))
    for opt, values in ARGS.get(cmd, {}).items():
        # the options a command needs are there most of the time, the others now and then; most values
        # are the valid first entry, so that whole valid command lines occur too
        if data.draw(st.integers(0, 9)) < (9 if opt in REQUIRED.get(cmd, ()) else 3):
            argv += [opt, values[0] if data.draw(st.integers(0, 9)) < 7 else data.draw(st.sampled_from(values))]
    if data.draw(st.integers(0, 9)) > 0:
        argv += ["--out", str(out)]
    if data.draw(st.integers(0, 9)) == 0:
        argv.insert(data.draw(st.integers(1, len(argv))), data.draw(st.sampled_from(["--bogus", "-x", "--", "%s"])))
    try:
        rc = main(argv)
    except SystemExit as e:  # argparse: 2 for a bad command line, 0 for --help
        rc = e.code
    cap = capsys.readouterr()
    assert rc in (0, 2), (argv, rc, cap.err[-500:])
    assert "Traceback" not in cap.err, (argv, cap.err[-2000:])
    if rc == 2:
        assert "error" in cap.err and not out.exists(), (argv, cap.err[-500:])
    OUTCOMES_ARGS[rc] = OUTCOMES_ARGS.get(rc, 0) + 1
    OUTCOMES_ARGS[(cmd, rc)] = OUTCOMES_ARGS.get((cmd, rc), 0) + 1


OUTCOMES_ARGS: dict = {}


def test_the_command_line_fuzz_ran_both_ways():
    if not OUTCOMES_ARGS:  # run alone (-k): nothing to count
        return
    assert OUTCOMES_ARGS.get(0, 0) > 0 and OUTCOMES_ARGS.get(2, 0) > 50, OUTCOMES_ARGS


def test_the_fuzz_ran_a_thousand_files_both_ways():
    """Runs after the three above (file order): every example ended in 0 or 2, both outcomes occurred."""
    assert set(OUTCOMES) == {0, 2}
    if sum(OUTCOMES.values()) == 0:  # run alone (-k): nothing to count
        return
    assert sum(OUTCOMES.values()) >= 1000 and OUTCOMES[0] > 0 and OUTCOMES[2] > 0, OUTCOMES


def test_a_vehicle_that_would_make_the_filter_diverge_is_refused(tmp_path, capsys):
    # a yaw inertia of 1e-30 kg m^2 (once: a filter that diverged on the log) is refused by the
    # parameter check before anything runs: dynamic index I_z / (m l_f l_r) = 4e-34
    vehicle = tmp_path / "feather.toml"
    vehicle.write_text(BUNDLED.replace("yaw_inertia = 2350.0", "yaw_inertia = 1e-30"))
    assert tomllib.loads(vehicle.read_text())["vehicle"]["yaw_inertia"] == 1e-30
    log = tmp_path / "log.csv"
    log.write_text(VALID)
    out = tmp_path / "est.csv"
    assert main(["estimate", str(log), "--vehicle", str(vehicle), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "'yaw_inertia' = 1e-30 kg m^2 gives a dynamic index" in err and not out.exists()
    assert "compact-ev" in bundled_vehicles()


def test_estimates_that_stop_being_numbers_are_refused_naming_the_row():
    import pytest
    from evstab.plants.errors import EvstabError
    from evstab.toolkit.cli_logs import _require_finite
    t = np.arange(5) * 1e-3
    with pytest.raises(EvstabError, match=r"log.csv: row 5 \(t = 0.003 s\): the beta estimate is not finite"):
        _require_finite("log.csv", t, {"beta": np.array([0.0, 0.1, 0.2, np.nan, np.inf])})

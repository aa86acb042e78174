"""Mistakes users make get a clear answer: physics checks on vehicle files, unit mistakes in logs found
by consistency, command-line limits, the compile cache command. Every case exits 2 naming the field or
column, writes nothing, and shows no traceback."""

import csv
import dataclasses
import os

import numpy as np
import pytest

from evstab.plants import load_vehicle
from evstab.plants.errors import ParameterError
from evstab.toolkit.cli import main

P = load_vehicle("compact-ev")


@pytest.mark.parametrize("change, message", [
    # compact-ev: m_s h^2 = 1380 * 0.48^2 = 318 kg m^2; a user who copies the sprung mass's own inertia
    (dict(roll_inertia=300.0), r"'roll_inertia' = 300.0 kg m\^2 is below sprung_mass \* roll_arm\^2"),
    (dict(sprung_mass=1600.0), r"'sprung_mass' = 1600.0 kg exceeds 'mass' = 1550.0 kg"),
    (dict(width=1.5), r"'track_front' = 1.52 m exceeds the overall 'width' = 1.5 m"),
    (dict(lf=0.3, lr=0.4), r"wheelbase lf \+ lr = 0.3 \+ 0.4 = 0.7 m is outside \[1.0, 6.0\] m"),
    (dict(wheel_radius=0.8), r"'wheel_radius' = 0.8 m is outside \[0.15, 0.6\] m"),
    (dict(steering_ratio=3.0), r"'steering_ratio' = 3.0 is outside \[5.0, 30.0\]"),
    # 2350 / (1550 * 1.17 * 1.43) = 0.906; the inertia in kg m^2 typed as t m^2 gives 0.000906
    (dict(yaw_inertia=2.35), r"'yaw_inertia' = 2.35 kg m\^2 gives a dynamic index I_z / \(m l_f l_r\) = 0.000906"),
    (dict(mass=1.55, sprung_mass=1.2), r"'mass' = 1.55 kg is below 50 kg"),
])
def test_physically_impossible_parameters_are_refused_naming_field_and_bound(change, message):
    with pytest.raises(ParameterError, match=message):
        dataclasses.replace(P, **change)


def test_every_bundled_vehicle_meets_the_physics_checks():
    from evstab.plants import bundled_vehicles
    for name in bundled_vehicles():
        load_vehicle(name)  # raises if not


def test_an_impossible_vehicle_file_exits_2_and_writes_nothing(tmp_path, capsys):
    from evstab.toolkit.design.nominal import to_toml
    f = tmp_path / "v.toml"
    f.write_text(to_toml(P, "test").replace("roll_inertia = 800.0", "roll_inertia = 200.0"))
    assert "roll_inertia = 200.0" in f.read_text()
    out = tmp_path / "log.csv"
    assert main(["simulate", "--vehicle", str(f), "--maneuver", "step-steer", "--speed", "60", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "roll_inertia" in err and "parallel-axis" in err and "Traceback" not in err and not out.exists()


def test_a_speed_beyond_300_kmh_is_refused(tmp_path, capsys):
    out = tmp_path / "log.csv"
    with pytest.raises(SystemExit) as e:
        main(["simulate", "--vehicle", "compact-ev", "--maneuver", "step-steer", "--speed", "800", "--out", str(out)])
    assert e.value.code == 2 and "800 km/h is beyond 300 km/h" in capsys.readouterr().err and not out.exists()


@pytest.fixture(scope="module")
def log_rows(tmp_path_factory):
    """A gentle drive (1 deg sine lane change at 40 km/h: the gyro never leaves +-10 rad/s even in deg/s)."""
    d = tmp_path_factory.mktemp("units")
    assert main(["simulate", "--vehicle", "compact-ev", "--maneuver", "sine-lane-change", "--speed", "40",
                 "--amplitude", "1", "--out", str(d / "log.csv")]) == 0
    with open(d / "log.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    return rows


def _write(path, rows, col, f):
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        for r in rows:
            r = dict(r)
            if r[col] != "":
                r[col] = repr(float(f(float(r[col]))))
            w.writerow(r)


@pytest.mark.parametrize("col, f, message", [
    ("yaw_rate", np.degrees, r"column 'yaw_rate'.*looks like deg/s"),
    ("speed", lambda v: 3.6 * v, r"column 'speed'.*looks like km/h"),
    ("gps_course", lambda c: np.pi / 2 - c, r"column 'gps_course'.*compass bearing \(clockwise from north\)"),
    ("gps_course", lambda c: 90.0 - np.degrees(c), r"column 'gps_course'.*degrees clockwise from north"),
    ("gps_course", np.degrees, r"column 'gps_course'.*looks like degrees, expected rad"),
    ("steer", lambda d: 15.0 * d, r"column 'steer'.*15.* times the road-wheel angle.*looks like the hand-wheel angle"),
])
def test_unit_mistakes_are_found_by_consistency(tmp_path, capsys, log_rows, col, f, message):
    import re
    bad, out = tmp_path / "bad.csv", tmp_path / "est.csv"
    _write(bad, log_rows, col, f)
    assert main(["estimate", str(bad), "--vehicle", "compact-ev", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert re.search(message, err) and "Traceback" not in err and not out.exists()
    # the user who knows better overrides the check
    assert main(["estimate", str(bad), "--vehicle", "compact-ev", "--out", str(out), "--trust-units"]) == 0


def test_the_correct_log_passes_the_unit_checks(tmp_path, log_rows):
    good, out = tmp_path / "good.csv", tmp_path / "est.csv"
    _write(good, log_rows, "speed", lambda v: v)
    assert main(["estimate", str(good), "--vehicle", "compact-ev", "--out", str(out)]) == 0


def test_a_log_without_a_fix_is_refused(tmp_path, capsys, log_rows):
    bad, out = tmp_path / "nofix.csv", tmp_path / "est.csv"
    rows = [dict(r, gps_course="") for r in log_rows]
    _write(bad, rows, "speed", lambda v: v)
    assert main(["estimate", str(bad), "--vehicle", "compact-ev", "--out", str(out)]) == 2
    assert "no GPS fix" in capsys.readouterr().err and not out.exists()


def test_help_states_the_defaults(capsys):
    with pytest.raises(SystemExit):
        main(["simulate", "--help"])
    text = capsys.readouterr().out
    assert "(default: 0.001)" in text and "(default: 0)" in text


def test_cache_command_shows_and_clears(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("EVSTAB_CACHE", str(tmp_path))
    (tmp_path / "evstab_abc.so").write_bytes(b"x" * 2048)
    (tmp_path / "not_ours.txt").write_text("keep")
    assert main(["cache"]) == 0
    assert f"{tmp_path}: 1 files" in capsys.readouterr().out
    assert main(["cache", "--clear"]) == 0
    assert "removed 1 files" in capsys.readouterr().out
    assert not (tmp_path / "evstab_abc.so").exists() and (tmp_path / "not_ours.txt").exists()


def test_export_of_a_missing_folder_is_a_sentence(tmp_path, capsys):
    assert main(["export", str(tmp_path / "nothing"), "--out", str(tmp_path / "fw")]) == 2
    err = capsys.readouterr().err
    assert "no such file; expected an 'evstab design' folder" in err and "Errno" not in err


_RACE = r"""
import sys, time
from pathlib import Path
from evstab.toolkit.kernels.compiled import compile_source
tmp = Path(sys.argv[1])
(tmp / f"ready{sys.argv[2]}").touch()
while not (tmp / "go").exists():
    time.sleep(0.01)
def write(path):
    with open(tmp / "writes.log", "a") as fh:
        fh.write(sys.argv[2] + "\n")
    time.sleep(1.0)  # a slow build: the other process asks for the library meanwhile
    path.write_text("double answer(void) { return 42.0; }\n")
print(compile_source(write, "race_test", ("-O1",), "nothing"))
"""


def test_two_processes_asking_for_one_library_build_it_once(tmp_path):
    # two processes (as a sweep's workers at start) ask for the same library at the same moment:
    # one builds it, the other waits and loads it (without the lock both wrote and compiled it)
    import subprocess
    import sys
    import time
    from evstab.toolkit.kernels.compiled import compiler
    if compiler() is None:
        pytest.skip("no C compiler")
    cache = tmp_path / "cache"
    env = {**os.environ, "EVSTAB_CACHE": str(cache)}
    procs = [subprocess.Popen([sys.executable, "-c", _RACE, str(tmp_path), str(i)], env=env, stdout=subprocess.PIPE,
                              text=True) for i in (1, 2)]
    t0 = time.monotonic()
    while not all((tmp_path / f"ready{i}").exists() for i in (1, 2)):
        assert time.monotonic() - t0 < 120, "the processes did not start"
        time.sleep(0.01)
    (tmp_path / "go").touch()
    outs = [p.communicate(timeout=120)[0].strip() for p in procs]
    assert all(p.returncode == 0 for p in procs)
    assert outs[0] == outs[1] == str(cache / "evstab_race_test.so")
    assert (tmp_path / "writes.log").read_text().split() in (["1"], ["2"])
    assert sorted(f.name for f in cache.iterdir()) == ["evstab_race_test.so"]  # no lock or temporary left


@pytest.mark.parametrize("k, refused", [(1.0, False), (4.9, False), (5.1, True), (39.0, True), (41.0, False)])
def test_the_steer_check_at_its_bounds(k, refused):
    """A steady turn whose steer is k times the steady-state road-wheel angle (l / v + K v) r: a hand-wheel
    angle from k = 5 to 40 (steering ratios are 10-20); outside, no verdict."""
    from evstab.toolkit.logs.drivelog import DriveLog, LogFormatError, check_steer
    p = load_vehicle("compact-ev")
    n, v, r = 1000, 15.0, 0.1  # |a_y| = 1.5 m/s^2: inside the tyres' linear range
    noise = 1e-5 * np.random.default_rng(0).standard_normal(n)  # a steer sensor's (the fit needs a spread)
    steer = k * (p.wheelbase / v + p.understeer_gradient * v) * r + noise
    log = DriveLog({"t": np.arange(n) * 1e-3, "speed": np.full(n, v), "yaw_rate": np.full(n, r), "steer": steer},
                   "turn.csv")
    if refused:
        with pytest.raises(LogFormatError, match="turn.csv: column 'steer'"):
            check_steer(log, p.wheelbase, p.understeer_gradient)
    else:
        check_steer(log, p.wheelbase, p.understeer_gradient)


@pytest.mark.parametrize("delim, name", [(";", "semicolons"), ("\t", "tabs")])
def test_a_csv_with_another_delimiter_is_named(tmp_path, capsys, log_rows, delim, name):
    bad, out = tmp_path / "semi.csv", tmp_path / "est.csv"
    with open(bad, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(log_rows[0]), delimiter=delim)
        w.writeheader()
        w.writerows(log_rows)
    assert main(["estimate", str(bad), "--vehicle", "compact-ev", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert f"row 1: the header is separated by {name}" in err and "missing required column" not in err
    assert not out.exists()


@pytest.mark.parametrize("command", [["export", "no-such-design"], ["design", "--vehicle", "compact-ev", "--quick"]])
def test_an_output_folder_that_is_a_file_is_refused_as_such(tmp_path, capsys, command):
    target = tmp_path / "out"
    target.write_text("a file the user wanted kept\n")
    assert main([*command, "--out", str(target)]) == 2
    assert f"--out {target}: is a file; expected a folder" in capsys.readouterr().err
    assert target.read_text() == "a file the user wanted kept\n"


def test_a_road_wheel_angle_no_car_has_is_refused_before_the_run(tmp_path, capsys):
    out = tmp_path / "run.csv"
    assert main(["simulate", "--vehicle", "compact-ev", "--maneuver", "step-steer", "--speed", "60", "--amplitude", "90",
                 "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "asks 90.0 deg of road-wheel angle, beyond the 68.8 deg" in err and "not the hand-wheel angle" in err
    assert "steering ratio: 15.5" in err and "vehicle parameters" not in err and not out.exists()
    # 68 deg is a road-wheel angle a car has: no verdict before the run
    assert main(["simulate", "--vehicle", "compact-ev", "--maneuver", "step-steer", "--speed", "10", "--amplitude", "30",
                 "--out", str(out)]) == 0


def test_a_run_that_spins_is_named_as_a_spin(tmp_path, capsys):
    """At 250 km/h a 2 deg step is beyond the tyres: the car spins and ends up sliding backwards faster than a
    drive log holds. The message says so, not that the vehicle file is wrong."""
    out = tmp_path / "run.csv"
    assert main(["simulate", "--vehicle", "compact-ev", "--maneuver", "step-steer", "--speed", "250",
                 "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "step-steer at 250 km/h: the car spins (sideslip" in err and "lower --speed or --amplitude" in err
    assert "vehicle parameters" not in err and "unit or scaling" not in err and not out.exists()

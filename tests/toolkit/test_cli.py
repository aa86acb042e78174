"""The evstab command line: the README's main command, listing, and clear errors (exit status 2)."""

import subprocess
import sys

import numpy as np
import pytest

from evstab.toolkit.cli import main
from evstab.toolkit.logs.drivelog import read_log_csv


def test_vehicles_lists_bundled(capsys):
    assert main(["vehicles"]) == 0
    out = capsys.readouterr().out
    for name in ("micro-ev", "sedan-000", "compact-ev"):
        assert name in out


def test_simulate_writes_log_and_plot(tmp_path, capsys):
    out, png = tmp_path / "log.csv", tmp_path / "log.png"
    rc = main(["simulate", "--vehicle", "micro-ev", "--plant", "two-track", "--maneuver", "sine-lane-change",
               "--speed", "25", "--wind", "--gps-outage", "4:6", "--seed", "3", "--out", str(out), "--plot", str(png)])
    assert rc == 0
    log = read_log_csv(out)
    assert len(log) == 10000
    t = log["t"]
    assert np.isnan(log["gps_course"][(t >= 4) & (t < 6)]).all()
    assert np.isfinite(log["gps_course"][(t >= 6)]).sum() == 20
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_simulate_accepts_toml_path(tmp_path):
    from importlib import resources
    src = resources.files("evstab.plants").joinpath("data", "compact-ev.toml").read_text()
    f = tmp_path / "mycar.toml"
    f.write_text(src)
    assert main(["simulate", "--vehicle", str(f), "--plant", "bicycle", "--maneuver", "step-steer",
                 "--speed", "60", "--out", str(tmp_path / "a.csv")]) == 0


def test_bad_vehicle_file_exit_2_and_no_output(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text('[meta]\nname="x"\nsource="y"\n[vehicle]\nmass=-1\n')
    out = tmp_path / "never.csv"
    rc = main(["simulate", "--vehicle", str(bad), "--maneuver", "step-steer", "--speed", "50", "--out", str(out)])
    assert rc == 2
    err = capsys.readouterr().err
    assert str(bad) in err and "yaw_inertia" in err
    assert not out.exists()


def test_bad_option_exit_2(capsys):
    with pytest.raises(SystemExit) as e:
        main(["simulate", "--vehicle", "micro-ev", "--maneuver", "step-steer", "--speed", "50",
              "--gps-outage", "6:4", "--out", "x.csv"])
    assert e.value.code == 2
    assert "--gps-outage 6:4: END must be after START" in capsys.readouterr().err


def test_console_script_runs(tmp_path):
    # the installed entry point (what the README's first command uses)
    r = subprocess.run([sys.executable, "-m", "evstab.toolkit.cli", "simulate", "--vehicle", "compact-ev", "--maneuver",
                        "step-steer", "--speed", "80", "--plant", "bicycle", "--out", str(tmp_path / "x.csv")],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "compact-ev on bicycle, step-steer" in r.stdout


def test_estimate_writes_method_columns(tmp_path):
    log, est = tmp_path / "log.csv", tmp_path / "est.csv"
    assert main(["simulate", "--vehicle", "micro-ev", "--maneuver", "sine-lane-change", "--speed", "25",
                 "--out", str(log)]) == 0
    assert main(["estimate", str(log), "--vehicle", "micro-ev", "--out", str(est)]) == 0
    header = est.read_text().splitlines()[0].split(",")
    flags = ["fault_gps_spike", "fault_gps_sats", "fault_gps_frozen", "fault_gps_time", "fault_gyro_stuck",
             "fault_gyro_bias", "fault_speed_dropout"]
    assert header == ["t", "beta", "yaw_rate", "yaw", "beta_std", "d1", "d2", "gyro_bias", "gps_used", "nis",
                      "course_resid", "noise_scale"] + flags
    assert main(["estimate", str(log), "--vehicle", "micro-ev", "--method", "kf", "--out", str(est)]) == 0
    assert est.read_text().splitlines()[0] == ",".join(["t", "beta", "yaw_rate", "yaw", "beta_std", "gps_used",
                                                        "nis", "course_resid"] + flags)


def test_estimate_bias_learn_rate(tmp_path, capsys):
    """``--bias-learn-rate``: the filter's gyro bias held where the yaw rate is above it. A sine lane change at
    25 km/h on micro-ev peaks near 0.5 rad/s: with 0.05 rad/s the bias is held through the turns and the
    estimate differs from the default's; a method without a bias state is refused, naming the flag, and
    nothing is written."""
    log, est, held = tmp_path / "log.csv", tmp_path / "est.csv", tmp_path / "held.csv"
    assert main(["simulate", "--vehicle", "micro-ev", "--maneuver", "sine-lane-change", "--speed", "25",
                 "--out", str(log)]) == 0
    assert main(["estimate", str(log), "--vehicle", "micro-ev", "--out", str(est)]) == 0
    assert main(["estimate", str(log), "--vehicle", "micro-ev", "--bias-learn-rate", "0.05", "--out", str(held)]) == 0
    a, b = (np.genfromtxt(f, delimiter=",", names=True) for f in (est, held))
    assert np.max(np.abs(a["gyro_bias"] - b["gyro_bias"])) > 1e-6  # the bias moved differently
    out = tmp_path / "kf.csv"
    assert main(["estimate", str(log), "--vehicle", "micro-ev", "--method", "kf", "--bias-learn-rate", "0.2",
                 "--out", str(out)]) == 2
    assert "--bias-learn-rate" in capsys.readouterr().err and not out.exists()


def test_estimate_bad_log_exit_2_names_row_and_column(tmp_path, capsys):
    bad = tmp_path / "bad.csv"
    bad.write_text("t,speed,steer,yaw_rate,gps_course\n0,10,0,0,\n0.001,10,abc,0,\n")
    out = tmp_path / "est.csv"
    assert main(["estimate", str(bad), "--vehicle", "micro-ev", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "row 3" in err and "'steer'" in err and "'abc' is not a number" in err
    assert not out.exists() and not list(tmp_path.glob("*.part"))


def test_fmvss126_and_score_swd(tmp_path, capsys):
    import json
    out = tmp_path / "fm"
    assert main(["fmvss126", "--vehicle", "compact-ev", "--controller", "none", "--quick", "--out", str(out)]) == 0
    rows = (out / "fmvss126.csv").read_text().splitlines()
    assert rows[0] == "amplitude_deg,direction,yaw_ratio_1_0,yaw_ratio_1_75,lateral_displacement_m,pass,failed,rollover_s"
    assert len(rows) == 5
    verdict = json.loads((out / "verdict.json").read_text())
    assert verdict["pass"] is False and "yaw_ratio_1_0" in verdict["failed_criteria"]  # it spins
    log = tmp_path / "swd.csv"
    assert main(["simulate", "--vehicle", "compact-ev", "--maneuver", "sine-with-dwell", "--speed", "80",
                 "--out", str(log)]) == 0
    capsys.readouterr()
    assert main(["score-swd", str(log), "--vehicle", "compact-ev", "--a-deg", "22.13"]) == 0
    assert "FAIL yaw_ratio_1_0" in capsys.readouterr().out


def test_simulate_with_the_stability_loop(tmp_path):
    out = tmp_path / "cl.csv"
    assert main(["simulate", "--vehicle", "micro-ev", "--maneuver", "step-steer", "--speed", "25",
                 "--controller", "two-dof", "--out", str(out)]) == 0
    log = read_log_csv(out)
    assert "steer_driver" in log and "yaw_moment_cmd" in log
    assert np.all(log["yaw_moment_cmd"] == 0)  # a gentle step: the ECU passes the driver through
    assert main(["simulate", "--vehicle", "compact-ev", "--maneuver", "sine-with-dwell", "--speed", "80",
                 "--controller", "two-dof", "--out", str(out)]) == 0
    assert np.abs(read_log_csv(out)["yaw_moment"]).max() > 100  # at the limit the motors act [N m]
    with pytest.raises(SystemExit):
        main(["simulate", "--vehicle", "micro-ev", "--maneuver", "step-steer", "--speed", "25",
              "--controller", "magic", "--out", str(out)])


@pytest.mark.parametrize("start, fitted, warned", [
    (1.04, 1.32, True),    # the 10 s log: further from 1 (and out of [0.7, 1.3])
    (1.04, 1.02, False),   # closer to 1
    (0.60, 0.69, False),   # closer to 1, still outside: no worse than it started
    (1.10, 0.92, False),   # as far from 1 on the other side is closer (0.08 < 0.10)
    (1.25, 1.31, True),    # inside -> outside
])
def test_tune_warns_when_the_fit_is_less_consistent(start, fitted, warned):
    from types import SimpleNamespace

    from evstab.toolkit.cli_logs import tune_warning
    fit = SimpleNamespace(nis_start=start, nis=fitted, nis_interval=(0.7, 1.3), course_fixes=49)
    msg = tune_warning(fit)
    assert bool(msg) == warned
    if warned:
        assert f"{start:.3f} -> {fitted:.3f}" in msg and "49 course fixes" in msg

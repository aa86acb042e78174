"""A gyro bias learnt on one drive starts the next: written by ``estimate --save-calibration``, read by
``--calibration``; a cold start at speed then needs no time to learn it."""

import numpy as np
import pytest

from evstab.plants import load_vehicle
from evstab.plants.errors import DataError
from evstab.plants.maneuvers import make_maneuver
from evstab.plants.sensors import SensorConfig
from evstab.toolkit.cli import main
from evstab.toolkit.estimation.calibration import load_calibration, write_calibration
from evstab.toolkit.logs.drivelog import read_log_csv, write_log_csv
from evstab.toolkit.loop.simulator import simulate

BIAS = 3e-3  # rad/s, the gyro's on both drives


@pytest.fixture(scope="module")
def drives(tmp_path_factory):
    d = tmp_path_factory.mktemp("cal")
    p = load_vehicle("compact-ev")
    sens = SensorConfig(gyro_bias=BIAS)
    first = simulate(p, "two-track", make_maneuver("sine-lane-change", p, 60 / 3.6, np.radians(2.0)), sensors=sens,
                     seed=1).log_columns()
    # the second drive: a ramp steer from the first row, the bias unknown to a filter started cold
    second = simulate(p, "two-track", make_maneuver("ramp-steer", p, 60 / 3.6), sensors=sens, seed=2).log_columns()
    write_log_csv(d / "first.csv", first)
    write_log_csv(d / "second.csv", second)
    return d, second


def test_a_learnt_bias_starts_the_next_drive(drives):
    d, second = drives
    assert main(["estimate", str(d / "first.csv"), "--vehicle", "compact-ev", "--out", str(d / "e1.csv"),
                 "--save-calibration", str(d / "cal.toml")]) == 0
    bias, sd = load_calibration(d / "cal.toml")
    assert abs(bias - BIAS) < 3 * sd and sd < 5e-4  # learnt over the first drive, within its own 3 sigma
    for name, extra in (("cold", []), ("calibrated", ["--calibration", str(d / "cal.toml")])):
        assert main(["estimate", str(d / "second.csv"), "--vehicle", "compact-ev", "--out", str(d / f"{name}.csv"),
                     *extra]) == 0
    cold, cal = (read_log_csv(d / f"{n}.csv", required=("t",)) for n in ("cold", "calibrated"))
    assert cal["gyro_bias"][0] == pytest.approx(bias, abs=1e-5)  # starts where the first drive ended
    assert cold["gyro_bias"][0] == pytest.approx(0.0, abs=1e-3)
    # the first 3 s of the second drive: the bias error with the calibration a tenth of the cold start's
    first3 = cold["t"] < 3.0
    assert np.abs(cal["gyro_bias"][first3] - BIAS).max() < 0.1 * np.abs(cold["gyro_bias"][first3] - BIAS).max()


@pytest.mark.parametrize("text, needle", [("[gyro]\nbias = 0.2\nbias_std = 1e-3\n", "bias = 0.2"),
                                          ("[gyro]\nbias = 0.001\nbias_std = 0\n", "bias_std = 0"),
                                          ("[gyro]\nbias = 0.001\n", "bias_std = None"),
                                          ("bias = 0.001\n", "no [gyro] table"),
                                          ("[gyro\n", "not a TOML file")])
def test_bad_calibration_files(tmp_path, text, needle):
    (tmp_path / "cal.toml").write_text(text)
    with pytest.raises(DataError, match=needle.replace("[", r"\[")):
        load_calibration(tmp_path / "cal.toml")


def test_round_trip(tmp_path):
    write_calibration(tmp_path / "c.toml", 0.0021, 3.5e-5, "evstab estimate 'x.csv'")
    assert load_calibration(tmp_path / "c.toml") == (0.0021, 3.5e-5)

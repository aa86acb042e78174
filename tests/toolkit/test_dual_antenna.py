"""Seed 002's dual-antenna estimator on a banked road: total roll, bank, sideslip, slip angles, stiffness."""

import numpy as np
import pytest

from evstab.plants import load_vehicle
from evstab.plants.disturbances import Disturbances
from evstab.plants.maneuvers import two_half_turns
from evstab.plants.sensors import SensorConfig
from evstab.toolkit.cli import main
from evstab.toolkit.estimation import design_filter, run_estimator
from evstab.toolkit.estimation.dual_antenna import bank_estimate
from evstab.toolkit.estimation.identify import cornering_stiffness
from evstab.toolkit.logs.drivelog import write_log_csv
from evstab.toolkit.loop.simulator import simulate

BANK = np.radians(-5.0)  # right side up: banked into the left turns


@pytest.fixture(scope="module")
def banked():
    p = load_vehicle("compact-ev")
    c = simulate(p, "two-track", two_half_turns(16.0, 50.0, lead_in=300.0), disturbances=Disturbances(bank=BANK),
                 sensors=SensorConfig(), seed=1).log_columns()
    return p, c, c["t"] >= 300.0 / 16.0 - 1.0


def test_total_roll_bank_and_sideslip_on_a_banked_road(banked):
    """Measured: total-roll error 0.057 deg RMS (the antenna's 0.3 deg per fix, filtered with the roll
    gyro), bank estimate -4.87 deg for -5, sideslip 0.068 deg RMS against the kinematic filter's 0.311
    (the bank tilts nothing the dual antenna needs; the sideslip is read from GPS velocity, not a
    model). Bounds: 0.15 deg, 0.5 deg, 0.15 deg and better than kkf."""
    p, c, m = banked
    e = run_estimator(design_filter("dual-antenna", p), c)
    k = run_estimator(design_filter("kkf", p), c)
    assert np.degrees(np.sqrt(np.mean((e["roll"] - c["roll_true"] - BANK)[m] ** 2))) < 0.15
    b = bank_estimate(p, e["roll"], c["speed"], e["yaw_rate"])
    assert np.degrees(np.mean(b[m])) == pytest.approx(-5.0, abs=0.5)
    rms = lambda est: float(np.sqrt(np.mean((est["beta"] - c["beta_true"])[m] ** 2)))  # noqa: E731
    assert rms(e) < np.radians(0.15) and rms(e) < rms(k)


def test_stiffness_on_a_banked_road_needs_the_bank(banked):
    """With the lateral force from v r alone the 5 deg slope's gravity is missed (measured +8.1 / +12.2 %);
    adding g sin(estimated bank) brings both axles within 10 % of the parameter file (measured -3.2 /
    -2.5 %; 002 reports within 10 %)."""
    p, c, _ = banked
    e = run_estimator(design_filter("dual-antenna", p), c)
    fixes = np.flatnonzero(np.isfinite(c["gps_course"]))
    b = bank_estimate(p, e["roll"], c["speed"], e["yaw_rate"])
    args = (p, c["t"], c["speed"], c["steer"], c["yaw_rate"], e["beta"])
    naive = cornering_stiffness(*args, rows=fixes)
    fixed = cornering_stiffness(*args, rows=fixes, bank=b)
    for got, bad, true in ((fixed.front, naive.front, p.cornering_stiffness_front),
                           (fixed.rear, naive.rear, p.cornering_stiffness_rear)):
        assert got == pytest.approx(true, rel=0.10)
        assert abs(got - true) < abs(bad - true)


def test_estimate_names_the_dual_antenna_columns_a_log_lacks(banked, tmp_path, capsys):
    _, c, _ = banked
    # the heading is what the dual antenna is for (the third antenna's roll is optional, below)
    cols = {k: v[:20000] for k, v in c.items() if k != "gps_heading"}
    write_log_csv(tmp_path / "log.csv", cols)
    assert main(["estimate", str(tmp_path / "log.csv"), "--vehicle", "compact-ev", "--method", "dual-antenna",
                 "--out", str(tmp_path / "est.csv")]) == 2
    assert "needs column(s) gps_heading" in capsys.readouterr().err


def test_runs_on_the_heading_alone_without_a_third_antenna(tmp_path, capsys):
    # the common installation: two antennas give heading, no roll; the filter skips the roll update
    # and the sideslip stays close to the three-antenna figure (measured 0.071 vs 0.069 deg RMS on
    # this lane change: the roll update is about the bank, which a flat road does not have)
    import numpy as np
    from evstab.plants import load_vehicle
    from evstab.plants.maneuvers import sine_lane_change
    from evstab.plants.sensors import SensorConfig
    from evstab.toolkit.cli import main
    from evstab.toolkit.estimation import design_filter, run_estimator
    from evstab.toolkit.logs.drivelog import write_log_table
    from evstab.toolkit.loop.simulator import simulate
    p = load_vehicle("compact-ev")
    r = simulate(p, "two-track", sine_lane_change(60 / 3.6, np.radians(3), start=3.0, duration=12.0),
                 sensors=SensorConfig(gyro_bias=0.003), seed=2)
    log = r.log_columns()
    alone = {k: v for k, v in log.items() if k != "gps_roll"}
    d = design_filter("dual-antenna", p)
    rms = {}
    for label, lg in (("roll", log), ("alone", alone)):
        err = run_estimator(d, lg)["beta"][2000:] - log["beta_true"][2000:]
        rms[label] = float(np.sqrt(np.mean(err ** 2)))
    assert rms["alone"] < 1.25 * rms["roll"] and np.degrees(rms["alone"]) < 0.15
    f = tmp_path / "two_antennas.csv"
    write_log_table(f, {k: v for k, v in alone.items() if not k.endswith("_true")})
    assert main(["estimate", str(f), "--vehicle", "compact-ev", "--method", "dual-antenna",
                 "--out", str(tmp_path / "est.csv")]) == 0

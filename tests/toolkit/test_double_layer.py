"""Seed 004's double-layer estimator (layer 2) against the two-state roll KF and the kinematic velocity KF."""

import numpy as np

from evstab.plants import load_vehicle
from evstab.plants.maneuvers import steer_for_lateral_acceleration, step_steer
from evstab.plants.sensors import SensorConfig
from evstab.toolkit.estimation import design_filter, run_estimator
from evstab.toolkit.estimation.double_layer import layer2, roll_kf, roll_model_error, velocity_kf
from evstab.toolkit.loop.simulator import simulate


def test_layer2_under_30_percent_roll_model_error():
    """micro-ev, two-track plant, 25 km/h, 20 s step steer asking 3 m/s^2 (1.46 deg of roll), both
    filters with I_x, C_x, K_x 30 % high (004 eq. 43). The roll KF follows its model's static gain
    (measured 0.316 deg RMS). Layer 2 ties the roll to the lateral kinematics through the pseudo
    velocities from layer 1's sideslip, and micro-ev's nominal stiffness is 43 % high: layer 1's
    sideslip error (0.39 deg RMS) carries into it, and it ties the roll KF here (measured 0.316;
    0.081 with the ECU's noise in layer 1, whose beta_std several times its error made layer 2 lean on
    the kinematics; on the bicycle-roll plant 0.17 against 0.22, docs/estimators.md): asserted no more
    than 5 % worse. Its lateral velocity beats the kinematic velocity KF's, which has no roll term and
    only v_x measured (0.040 vs 0.604 m/s): asserted below a fifth."""
    p = load_vehicle("micro-ev")
    v = 25 / 3.6
    man = step_steer(v, steer_for_lateral_acceleration(p, v, 3.0), duration=20.0)
    c = simulate(p, "two-track", man, sensors=SensorConfig(), seed=3).log_columns()
    l1 = run_estimator(design_filter("dakf", p), c)
    pn = roll_model_error(p.as_nominal(), 0.3)
    assert pn.roll_stiffness == 1.3 * p.roll_stiffness
    l2 = layer2(pn, c["t"], c["ax"], c["ay"], l1["yaw_rate"], c["roll_rate"], c["gps_speed"], l1["beta"],
                l1["beta_std"])
    rk = roll_kf(pn, c["t"], c["ay"], c["roll_rate"])
    _, vy = velocity_kf(c["t"], c["ax"], c["ay"], c["yaw_rate"], c["speed"])
    m = c["t"] >= 1.0

    def rms(a):
        return float(np.sqrt(np.mean(a[m] ** 2)))

    assert rms(l2["roll"] - c["roll_true"]) < 1.05 * rms(rk - c["roll_true"])
    assert rms(l2["vy"] - c["vy_true"]) < 0.2 * rms(vy - c["vy_true"])
    # positive roll in a left turn (ISO 8855, docs/models.md): the estimate has the truth's sign at the end
    assert np.sign(l2["roll"][-1]) == np.sign(c["roll_true"][-1]) == 1.0


def test_double_layer_runs_through_estimate(tmp_path, capsys):
    """`evstab estimate --method double-layer` writes layer 2's vx, vy and roll next to layer 1's
    sideslip; a log without a roll gyro is refused, naming the column."""
    from evstab.toolkit.cli import main
    from evstab.toolkit.logs.drivelog import read_log_csv, write_log_csv

    p = load_vehicle("micro-ev")
    v = 25 / 3.6
    c = simulate(p, "two-track", step_steer(v, steer_for_lateral_acceleration(p, v, 2.0), duration=6.0),
                 sensors=SensorConfig(), seed=1).log_columns()
    write_log_csv(tmp_path / "log.csv", c)
    assert main(["estimate", str(tmp_path / "log.csv"), "--vehicle", "micro-ev", "--method", "double-layer",
                 "--out", str(tmp_path / "est.csv")]) == 0
    est = read_log_csv(tmp_path / "est.csv", required=("t",)).columns
    assert {"beta", "vx", "vy", "roll"} <= set(est)
    m = est["t"] > 1.0
    assert np.abs(est["vx"] - c["vx_true"])[m].max() < 0.2  # m/s; measured 0.046 (pseudo-velocities at 5 Hz)
    write_log_csv(tmp_path / "noroll.csv", {k: x for k, x in c.items() if k != "roll_rate"})
    assert main(["estimate", str(tmp_path / "noroll.csv"), "--vehicle", "micro-ev", "--method", "double-layer",
                 "--out", str(tmp_path / "x.csv")]) == 2
    assert "needs column(s) roll_rate" in capsys.readouterr().err

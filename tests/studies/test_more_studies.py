"""The studies the other tests do not run, each in its quick form, each held to what its table is
for (the claims the docs make from it). About 80 s in all."""

import csv

import numpy as np
import pytest


def _rows(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def _run(name, out):
    import importlib
    mod = importlib.import_module(f"evstab.studies.{name}")
    import inspect
    kw = {"quick": True} if "quick" in inspect.signature(mod.main).parameters else {}
    mod.main(out, **kw)
    # the tables its docs blocks show: written, with the blocks' columns
    from evstab.studies.publish import check_study
    assert not check_study(name, out)
    return out


def test_sensor_faults_every_injected_fault_is_flagged(tmp_path):
    rows = _rows(_run("sensor_faults", tmp_path) / "faults.csv")
    assert rows[0]["fault"] == "none" and int(rows[0]["rows flagged"]) == 0  # no false alarm on a clean log
    for r in rows[1:]:
        if r["flags"] == "-":  # the same fault with its detector switched off (the study's contrast row)
            assert int(r["rows flagged"]) == 0, r["fault"]
        else:
            assert int(r["rows touched"]) > 0 and int(r["flagged inside"]) > 0, r["fault"]


def test_robustness_the_paper_filter_is_the_one_with_the_flaw(tmp_path):
    # seed 003's DAKF (dakf-paper) has an unobservable direction (docs/estimators.md); evstab's dakf
    # does not: on the exact model the paper filter's sideslip error is several times dakf's
    rows = _rows(_run("estimation_robustness", tmp_path) / "robustness.csv")
    by = {(r["scenario"], r["nominal_stiffness"], r["method"]): float(r["beta_rms_deg"]) for r in rows}
    exact = [k for k in by if k[1] == "exact" and k[2] == "dakf"]
    assert exact
    for scen, nom, _ in exact:
        assert by[(scen, nom, "dakf-paper")] > 3.0 * by[(scen, nom, "dakf")], scen


def test_dual_antenna_estimates_the_bank(tmp_path):
    rows = _rows(_run("estimation_002", tmp_path) / "dual_antenna.csv")
    da = [r for r in rows if r["filter"] == "dual-antenna"]
    assert len(da) >= 2
    for r in da:
        # the bank is observable with a third antenna's roll: mean estimate within 0.25 deg of the
        # road's (measured 0.13 deg off at -5 deg; the body's roll noise is 0.3 deg per fix)
        assert abs(float(r["bank_estimate_mean_deg"]) - float(r["bank_deg"])) < 0.25, r


def test_seed_001_table_i_is_reproduced_at_5_hz(tmp_path):
    rows = _rows(_run("estimation_001", tmp_path) / "table_i.csv")
    r5 = next(r for r in rows if float(r["gps_rate_hz"]) == 5.0)
    # the paper's sideslip standard deviation at 5 Hz, from its own noise figures: 5 % (its table
    # prints 2-3 significant digits)
    assert float(r5["sigma_beta_deg"]) == pytest.approx(float(r5["paper_sigma_beta_deg"]), rel=0.05)


def test_two_stage_and_double_layer_tables(tmp_path):
    rows = _rows(_run("estimation_000", tmp_path / "000") / "dlc.csv")
    for r in rows:  # every filter tracks the double lane change's sideslip to a fraction of it
        assert float(r["beta_err_rms_deg"]) < 0.5 * float(r["true_beta_max_deg"]), r
    rows = _rows(_run("estimation_004", tmp_path / "004") / "double_layer.csv")
    for r in rows:
        if r["manoeuvre"] == "sine lane change":  # seed 004 Fig. 9's manoeuvre: within 0.15 deg (its ~0.1),
            # and better than the roll KF (measured 0.029-0.031 against 0.031-0.044)
            assert float(r["roll_err_layer2_deg"]) < min(0.15, float(r["roll_err_roll_kf_deg"])), r
        else:  # sustained cornering with micro-ev's 43 % stiffness error in layer 1: within 0.35 deg
            # (measured 0.17 and 0.32 against the roll KF's 0.22 and 0.32)
            assert float(r["roll_err_layer2_deg"]) < 0.35, r


def test_intersample_errors_are_finite_and_small(tmp_path):
    rows = _rows(_run("estimation_intersample", tmp_path) / "intersample.csv")
    vals = np.array([[float(r["conventional_rms_deg"]), float(r["amrkf_rms_deg"])] for r in rows])
    assert len(rows) >= 4 and np.all(np.isfinite(vals)) and vals.max() < 0.5


def test_control_limits_default_controller_does_no_harm(tmp_path):
    rows = _rows(_run("control_limits", tmp_path) / "limits_summary.csv")
    for r in rows:
        assert "(worse)" not in r["2-DOF default"], r
        if r["case"].startswith("fmvss126"):
            assert r["2-DOF default"].endswith("PASS"), r


def test_estimation_on_the_multibody_car_meets_the_targets(tmp_path):
    # what docs/estimators.md states for dakf with the wrong model (+40 % stiffness, +10 % inertias)
    # on the Escort (quick: this car), against the targets of a good inertial reference: <= 0.15 deg
    # RMS and 0.5 deg max on the lane changes and the sine with dwell, 0.25 RMS on the mu 0.5 double
    # lane change, 0.4 RMS on the ramp; the slide to 8 deg within 1 deg RMS (the Vanagon's drives:
    # tests/toolkit/test_kinematic.py). Measured: lane changes and sine with dwell 0.09 / 0.08 / 0.09
    # RMS (max 0.21 / 0.21 / 0.26), double lane change 0.03, slide 0.10, ramp 0.09. Quick is the first
    # noise seed; on the full study's other two the sine with dwell is 0.12 and 0.08 (docs/estimators.md)
    rows = _rows(_run("estimation_mb", tmp_path) / "estimation_mb.csv")
    got = {r["drive"]: r for r in rows if r["car"] == "commonroad-mb:1" and r["nominal"] == "off"
           and r["method"] == "dakf"}
    for drive in ("lane change 25 km/h", "lane change, 2 s outage, 2 bad fixes", "sine with dwell 80 km/h (3.5 A)"):
        assert float(got[drive]["rms_deg"]) <= 0.15 and float(got[drive]["max_deg"]) <= 0.5, drive
    assert float(got["double lane change 60 km/h mu 0.5"]["rms_deg"]) <= 0.25
    assert float(got["slide 80 km/h mu 0.5"]["rms_deg"]) <= 1.0
    assert float(got["ramp 0-4 deg 60 km/h"]["rms_deg"]) <= 0.4
    # amrkf (its residual prediction weighted by the fixes' innovation correlation) is not worse than
    # dakf on any drive, either nominal: 0.005 deg RMS of slack (the full study, 48 logs, measures
    # equal but for 0.003 on one Vanagon ramp)
    by = {(r["drive"], r["nominal"], r["method"]): float(r["rms_deg"]) for r in rows}
    for (drive, nominal, method), v in by.items():
        if method == "amrkf":
            assert v <= by[(drive, nominal, "dakf")] + 0.005, (drive, nominal)
    # nor is dakf worse than the plain bias-aware KF (kf-bias, no disturbance states): where the model
    # holds its sideslip output is the estimate conditioned on zero disturbances (kalman.significant_sideslip),
    # which keeps what the filter learnt with the disturbances present; 0.005 deg RMS of slack (the full
    # study's 64 log-and-nominal pairs: at most 0.0036 above kf-bias, on the Escort's double lane change;
    # these drives 0.0016; without the conditioning 0.029)
    # the rule holds evstab's own methods, not the references as published (spec.AS_PUBLISHED)
    from evstab.toolkit.estimation.spec import AS_PUBLISHED
    own = {m for (_, _, m) in by} - set(AS_PUBLISHED) - {"kf-bias"}
    assert {"dakf", "amrkf"} <= own, own
    for (drive, nominal, method), v in by.items():
        if method in own:
            assert v <= by[(drive, nominal, "kf-bias")] + 0.005, (drive, nominal, method)


def test_nominal_fits_reproduce_the_bundled_files(tmp_path):
    # quick: set 1 at 60 km/h only; the bundled commonroad-1 file's stiffness came from 40-100 km/h,
    # so the one-speed fit is within 10 % of it (the fit residual itself is 5-7 %, docs/models.md)
    from evstab.plants import load_vehicle
    rows = _rows(_run("nominal_fits", tmp_path) / "nominal_fits.csv")
    p = load_vehicle("commonroad-1")
    assert float(rows[0]["front_N_per_rad"]) == pytest.approx(p.cornering_stiffness_front, rel=0.10)
    assert float(rows[0]["rear_N_per_rad"]) == pytest.approx(p.cornering_stiffness_rear, rel=0.10)


def test_multibody_fmvss126_the_ecu_does_no_harm(tmp_path):
    # quick: the Escort on mu 1.0 with the default ECU designed from the +40 % stiffness file (the
    # full study runs the design job on each car); without control the car rolls over from 4 A on
    # (docs/controller.md), with the ECU it passes, and no run the car passes alone fails with it
    rows = _rows(_run("control_mb_fmvss126", tmp_path) / "mb_fmvss126_summary.csv")
    none = next(r for r in rows if r["controller"] == "none")
    ecu = next(r for r in rows if r["controller"] != "none")
    assert none["pass"] == "False" and ecu["pass"] == "True"
    assert int(ecu["runs_worse_than_none"]) == 0 and int(ecu["runs_passed"]) == int(ecu["runs"])


def test_noise_fit_recovers_the_logs_sensor_noise(tmp_path):
    # the log's gyro and GPS velocity noise (0.006 rad/s, 0.08 m/s) from the filter's defaults
    # (0.004, 0.056): within 20 % (docs/estimators.md has the measured errors)
    rows = {r["parameter"]: r for r in _rows(_run("noise_fit", tmp_path) / "noise_fit.csv")}
    for k in ("gyro_std", "gps_velocity_std"):
        assert abs(float(rows[k]["error_pct"])) < 20.0, rows[k]


def test_estimation_consistency_table(tmp_path):
    # quick: compact-ev only. What docs/estimators.md says of the default noise: on evstab's own logs
    # the course innovations are as large as the filter predicts (mean NIS inside its 95 % interval:
    # measured 0.74-0.91 on compact-ev, 0.74-1.10 on all six cars), and the sideslip error is small
    # (0.15 deg: eight times the largest measured RMS on compact-ev, 0.019)
    rows = _rows(_run("estimation_consistency", tmp_path) / "consistency.csv")
    assert len(rows) == 6
    for r in rows:
        assert int(r["fixes"]) >= 60  # 15 s of 5 Hz fixes after the warm-up (a few fall to the gate)
        assert float(r["low"]) <= float(r["mean_nis"]) <= float(r["high"]), r
        assert float(r["beta_rms_deg"]) < 0.15, r


def test_envelope_keeps_what_the_controller_does_well(tmp_path):
    # the quick envelope (compact-ev, two seeds). What docs/controller.md says the default ECU does
    # well, held on every seed: where the car alone spins in the steps at 80 km/h on mu 1 (78.8 deg)
    # and 100 km/h on mu 0.3 (70.4 deg) it holds the car below 5 deg (measured 1.56 / 1.85 and 2.31 /
    # 2.34 deg); in smooth random steering below 4 m/s^2 and in a lift-off at 0.7 g it stays off (the
    # quiet rule: 0.25 deg, 300 N m; measured 0 deg, 0 N m: the driver passed through)
    from evstab.toolkit.verdicts import envelope as ev
    rows = _rows(_run("control_envelope", tmp_path) / "envelope.csv")
    by = {}
    for r in rows:
        by.setdefault(r["case"], []).append(r)
    assert len(by) == 6 and all(len(v) == 2 for v in by.values())
    for case in ("step 80 km/h mu 1", "step 100 km/h mu 0.3"):
        assert all(float(r["alone_beta_deg"]) > ev.SLIDE_DEG and float(r["beta_deg"]) < ev.HELD_DEG
                   for r in by[case]), case
    for case in ("random-steer 80 km/h mu 1", "lift-off 80 km/h mu 1"):
        for r in by[case]:
            assert float(r["added_steer_deg"]) <= 0.25 and float(r["yaw_moment_Nm"]) <= 300.0, r
            assert r["rules_broken"] == "-", r


def test_control_reachable_holds_the_friction_drop_below_the_ecu(tmp_path):
    # the quick run (one reaction, 0.2 s after the drop; the window to 4 s): the commands found, replayed
    # through the plant by scipy, keep the peak below the default ECU's (seed 0), which holds the stabilise
    # rule's 5 deg, where the car alone passes it by 4 s (measured 2.33, 4.01 and 6.97 deg)
    from evstab.toolkit.verdicts import envelope as ev
    rows = _rows(_run("control_reachable", tmp_path) / "reachable.csv")
    assert len(rows) == 1 and float(rows[0]["reaction_s"]) == 0.2
    r = rows[0]
    assert float(r["reachable_peak_beta_deg"]) < float(r["ecu_worst_deg"]) < ev.HELD_DEG < float(r["alone_peak_beta_deg"])
    assert float(r["largest_torque_nm"]) <= 900.0 and float(r["largest_correction_deg"]) <= 20.0

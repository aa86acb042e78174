"""Every study runs in quick mode and writes what it promises; headline claims hold."""

import csv


from evstab.studies import estimation_fig6, estimation_intersample, estimation_robustness
from evstab.studies.publish import check_study


def test_fig6(tmp_path):
    rows = {r["method"]: r for r in estimation_fig6.main(tmp_path, quick=True)}
    assert (tmp_path / "fig6.png").stat().st_size > 10000 and (tmp_path / "fig6.md").exists()
    # seed 003's ordering: the disturbance-accommodating filter beats LOB and KF under model error
    assert rows["dakf"]["beta_rms_deg"] < rows["lob"]["beta_rms_deg"]
    assert rows["dakf"]["beta_rms_deg"] < rows["kf"]["beta_rms_deg"]


def test_intersample(tmp_path):
    rows = estimation_intersample.main(tmp_path, quick=True)
    assert len(rows) == 5 and (tmp_path / "intersample.png").exists()


def test_robustness_quick(tmp_path):
    rows = estimation_robustness.main(tmp_path, quick=True)
    assert not check_study("estimation_robustness", tmp_path)
    with open(tmp_path / "robustness.csv") as fh:
        assert len(list(csv.DictReader(fh))) == len(rows) == 2 * 3 * 6
    plus40 = [r for r in rows if r["nominal_stiffness"] in ("+40 %", "-40 %")]
    for scen in {(r["scenario"], r["nominal_stiffness"]) for r in plus40}:
        by = {r["method"]: r["beta_rms_deg"] for r in plus40 if (r["scenario"], r["nominal_stiffness"]) == scen}
        assert by["dakf"] < by["lob"] and by["dakf"] < by["kf"], scen


def test_control_fig7(tmp_path):
    from evstab.studies import control_fig7
    rows = {r["controller"]: r for r in control_fig7.main(tmp_path, quick=True)}
    assert (tmp_path / "fig7.png").exists() and not check_study("control_fig7", tmp_path)
    # seed 003's claim (its controller: always acting, full steer range): with the 2-DOF controller both
    # states track the reference model. Against the ECU's lagged reference, measured: yaw rate 0.59 vs
    # 1.21 deg/s (quick), 0.40 vs 1.10 (full run); sideslip with true states 0.09 vs 0.60 deg (quick), with
    # dakf estimates 0.65 (full: no better than none, the estimate's error is the tracking error)
    assert rows["two-dof"]["yaw_rate_rms_err_deg_s"] < 0.6 * rows["none"]["yaw_rate_rms_err_deg_s"]
    assert rows["two-dof-true"]["beta_rms_err_deg"] < 0.3 * rows["none"]["beta_rms_err_deg"]


def test_control_fmvss126_quick(tmp_path):
    from evstab.studies import control_fmvss126
    rows = {(r["mu"], r["controller"]): r for r in control_fmvss126.main(tmp_path, quick=True)}
    assert not check_study("control_fmvss126", tmp_path)
    assert rows[(1.0, "none")]["pass"] is False  # the uncontrolled compact EV spins from 5 A
    assert rows[(1.0, "2-DOF supervised")]["pass"] is True
    assert rows[(0.6, "2-DOF supervised")]["pass"] is True
    assert (tmp_path / "fmvss126_2DOF_supervised_mu0.6.csv").exists() and (tmp_path / "fmvss126_summary.md").exists()


def test_control_fig9(tmp_path):
    from evstab.studies import control_fig9
    rows = {r["controller"]: r for r in control_fig9.main(tmp_path, quick=True)}
    assert (tmp_path / "fig9.png").exists()
    # measured against the ECU's lagged reference: yaw-rate error 0.275 vs 0.359 deg/s (quick), 0.18 vs
    # 0.42 (full run), sideslip 0.33 vs 0.55 deg (full run); the quick run's hold is half as long, so its
    # error is mostly the turn-in's -> at least 15 % less yaw-rate error with the law
    assert rows["two-dof"]["yaw_rate_rms_err_deg_s"] < 0.85 * rows["none"]["yaw_rate_rms_err_deg_s"]
    assert rows["two-dof"]["beta_rms_err_deg"] < rows["none"]["beta_rms_err_deg"]


def test_a_study_prints_a_row_as_one_readable_line():
    # not a Python dict: name and value pairs, numbers to 4 significant digits, flags as yes / no
    import numpy as np

    from evstab.studies._common import format_row
    row = {"case": "step 80 km/h mu 1", "seed": np.int64(3), "beta_deg": 1.73612, "nis": float("nan"),
           "pass": np.bool_(True), "cones": 0}
    assert format_row(row) == "case step 80 km/h mu 1; seed 3; beta_deg 1.736; nis nan; pass yes; cones 0"

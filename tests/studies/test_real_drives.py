"""The real-drives study on excerpts of the measured logs in ``../shared/real`` (skipped, with the reason,
where the folder is absent: a user's clone; CI has it)."""

import numpy as np
import pytest

from evstab.studies import real_drives

DATA = real_drives.data_dir()
pytestmark = pytest.mark.skipif(DATA is None, reason="no real-drive data: ../shared/real (or $EVSTAB_REAL_DATA) is "
                                                     "absent; the datasets are other groups' and not in the repository")


@pytest.fixture(scope="module")
def rows(tmp_path_factory):
    out = tmp_path_factory.mktemp("real")
    return out, {(r["drive"], r["gyro"], r["method"]): r for r in real_drives.main(out, quick=True, data=DATA)}


def test_tables_are_written(rows):
    out, _ = rows
    for name in ("real_drives.csv", "real_drives_table.md", "real_drives_readme.md"):
        assert (out / name).stat().st_size > 0
    table = (out / "real_drives_table.md").read_text()
    assert "course - gyro" in table and "GTI High_Speed, production gyro" in table
    from evstab.studies.publish import check_study
    assert not check_study("real_drives", out)  # the docs' blocks: the same files, the same columns


def test_the_default_filter_holds_on_the_gti_excerpt(rows):
    """The first 30 s of High_Speed (a race track at 13.6-32 m/s, the car moving from the first row): 0.44 deg
    RMS with the reference gyro and 0.30 with the production gyro, 1.37 / 1.28 max, mean NIS 1.33 and 1.32.
    Read raw, the GTI's vibrating accelerometer held the kinematic path on (1.21 deg, NIS 0.005)."""
    _, r = rows
    for gyro in ("reference", "production"):
        row = r[("GTI High_Speed", gyro, "dakf")]
        assert row["rms_deg"] < 0.5, row  # 0.44 / 0.30 measured; the real-drives issue's bound
        assert 0.5 <= row["mean_nis"] <= 2.0, row  # 1.33 / 1.32: the real-drives issue's interval
        assert row["max_deg"] < 2.0, row  # 1.37 / 1.28: the bound on the maximum


def test_revsted_samples(rows):
    """The ADMA sample's real RTK course (20 Hz, repeated on its 100 Hz rows: one fix per epoch) and the OBD
    sample's CAN yaw rate, quantised in 1.28 deg/s steps: held between steps while the car turns, which the
    monitor no longer calls a stuck gyro (650 of 999 rows were flagged)."""
    _, r = rows
    assert r[("ReV-StED ADMA (RTK course)", "as logged", "dakf")]["rms_deg"] < 0.35  # 0.26 measured
    assert r[("ReV-StED OBD (CAN)", "as logged", "dakf")]["gyro_stuck_rows"] == 0
    # with the Correvit's reference moved to the vehicle file's CG (real_drives.sideslip_moved): 0.79 deg RMS
    # on the first seed, mean NIS 1.81 (the quantised yaw rate's q^2 / 12 in the gyro noise: 0.84 without); the bound is the real-drives issue's target, the NIS its interval
    obd = r[("ReV-StED OBD (CAN)", "as logged", "dakf")]
    assert obd["rms_deg"] <= 1.0 and 0.5 <= obd["mean_nis"] <= 2.0, obd


def test_a_sideslip_moved_along_the_car_in_a_kinematic_turn():
    """A car turning about a point level with its rear axle (no tyre slip at the rear, radius 5 m at the rear
    axle): a point x ahead of the rear axle has tan(beta) = x / R, whatever the speed. Moving the sideslip from
    0.76 m to 1.55 m ahead of the rear axle gives atan(1.55 / 5); a point on the axle itself has none."""
    R, v = 5.0, np.array([2.0, 3.5, 8.0])
    r = -v / R  # a right turn: yaw rate and sideslip negative (ISO 8855)
    beta_076 = np.arctan(-0.76 / R) * np.ones(3)
    np.testing.assert_allclose(real_drives.sideslip_moved(beta_076, r, v, 0.76 - 1.55), np.arctan(-1.55 / R) * np.ones(3),
                               rtol=1e-12)
    np.testing.assert_allclose(real_drives.sideslip_moved(beta_076, r, v, 0.76), 0.0, atol=1e-15)


@pytest.fixture(scope="module")
def gti_ablations():
    """Whole GTI drives, reference gyro, the first emulation seed: ``dakf`` as it estimates on logs, and with two
    of its log settings undone (``real_drives.VARIANTS``). RMS [deg] per drive."""
    import dataclasses

    from evstab.toolkit.logs.emulate import Emulation, emulate
    from evstab.toolkit.estimation import design_filter, run_estimator
    from evstab.toolkit.estimation.spec import estimation_noise
    undone = {"default": {}, "noise": {"kinematic_noise_sigmas": 0.0}, "steer": {"yaw_model_steer": 0.0}}
    out = {}
    for drive in real_drives.drives(DATA)[:len(real_drives.GTI)]:
        cols = emulate(drive["cols"], Emulation(seed=0))
        log = {k: v for k, v in cols.items() if not k.endswith("_true")}
        for label, kw in undone.items():
            est = run_estimator(design_filter("dakf", drive["vehicle"], dataclasses.replace(estimation_noise(), **kw)),
                                log)
            out[(drive["drive"], label)] = real_drives.errors(cols, est["beta"])["rms_deg"]
    return out


def test_what_each_log_setting_does_on_the_gti_drives(gti_ablations):
    """Measured (High_Speed, Low_Speed, High_Speed2; deg RMS): the default 0.38, 0.39, 0.78. The kinematic
    path's thresholds not raised by the accelerometer's noise (``kinematic_noise_sigmas`` 0): the vibration
    half-engages the path, 0.50 on High_Speed and 1.63 on High_Speed2. The yaw row not loosened with the road-wheel
    angle (``yaw_model_steer`` 0): Low_Speed's tight turns at 5 m/s, 10 deg of steer, at 0.75. The bounds sit
    between the measured pairs."""
    r = gti_ablations
    for name, default in (("GTI High_Speed", 0.38), ("GTI Low_Speed", 0.39), ("GTI High_Speed2", 0.78)):
        assert r[(name, "default")] < default + 0.05, (name, r)  # the default as measured, 0.05 for the compiler
    assert r[("GTI High_Speed", "noise")] > 1.2 * r[("GTI High_Speed", "default")], r  # 0.50 against 0.38
    assert r[("GTI High_Speed2", "noise")] > 1.5 * r[("GTI High_Speed2", "default")], r  # 1.63 against 0.78
    assert r[("GTI Low_Speed", "steer")] > 1.5 * r[("GTI Low_Speed", "default")], r  # 0.75 against 0.39

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
    # with the Correvit's reference moved to the vehicle file's CG (real_drives.sideslip_moved): 0.53 deg RMS
    # on the first seed, mean NIS 1.31; the bound is the real-drives issue's target, the NIS its interval
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
    """Whole GTI drives, reference gyro, the first emulation seed: ``dakf`` as it estimates on logs, and with some
    of its log settings undone or one of its options set (``real_drives.VARIANTS``). RMS and max [deg] per drive."""
    import dataclasses

    from evstab.toolkit.logs.emulate import Emulation, emulate
    from evstab.toolkit.estimation import design_filter, run_estimator
    from evstab.toolkit.estimation.spec import estimation_noise
    undone = {"default": {}, "noise": {"kinematic_noise_sigmas": 0.0}, "steer": {"yaw_model_steer": 0.0},
              "release": {"kinematic_yaw_release": 0.1}}
    out = {}
    for drive in real_drives.drives(DATA)[:len(real_drives.GTI)]:
        cols = emulate(drive["cols"], Emulation(seed=0))
        log = {k: v for k, v in cols.items() if not k.endswith("_true")}
        for label, kw in undone.items():
            est = run_estimator(design_filter("dakf", drive["vehicle"], dataclasses.replace(estimation_noise(), **kw)),
                                log)
            e = real_drives.errors(cols, est["beta"])
            out[(drive["drive"], label)] = e["rms_deg"], e["max_deg"]
    return out


def test_what_each_log_setting_does_on_the_gti_drives(gti_ablations):
    """Measured (High_Speed, Low_Speed, High_Speed2; deg RMS / max): the default 0.376 / 1.31, 0.391 / 1.03,
    0.782 / 7.88. The kinematic path's thresholds not raised by the accelerometer's noise
    (``kinematic_noise_sigmas`` 0): the vibration half-engages the path, 0.496 on High_Speed and 1.626 on
    High_Speed2. The yaw row not loosened with the road-wheel angle (``yaw_model_steer`` 0): Low_Speed's tight
    turns at 5 m/s, 10 deg of steer, at 0.745. The yaw row returned to the model through a 0.1 s lag when the
    kinematic path lets go (``kinematic_yaw_release``, off by default): High_Speed2's 7.88 deg peak, a
    millisecond's throw of the sideslip by the INS yaw rate (read at 200 Hz, held at 1 kHz) through the model's
    yaw row, becomes 2.39. The bounds sit between the measured pairs."""
    r = {k: v[0] for k, v in gti_ablations.items()}
    peak = {k: v[1] for k, v in gti_ablations.items()}
    for name, default in (("GTI High_Speed", 0.376), ("GTI Low_Speed", 0.391), ("GTI High_Speed2", 0.782)):
        assert r[(name, "default")] < default + 0.05, (name, r)  # the default as measured, 0.05 for the compiler
    assert r[("GTI High_Speed", "noise")] > 1.2 * r[("GTI High_Speed", "default")], r  # 0.496 against 0.376
    assert r[("GTI High_Speed2", "noise")] > 1.5 * r[("GTI High_Speed2", "default")], r  # 1.626 against 0.782
    assert r[("GTI Low_Speed", "steer")] > 1.5 * r[("GTI Low_Speed", "default")], r  # 0.745 against 0.391
    assert peak[("GTI High_Speed2", "release")] < 0.5 * peak[("GTI High_Speed2", "default")], peak  # 2.39 against 7.88


@pytest.mark.parametrize("start", [11.9, 41.9])
def test_a_cold_start_in_a_hard_turn_settles(start):
    """High_Speed2 (production gyro, the first seed's course) started at 11.9 s and at 41.9 s, each in a
    12 m/s^2 turn: the error comes below 1 deg, and stays there for 1 s, within 3 s (1.7 s and 2.3 s measured). With the bias learnt
    from the gyro from the first sample (``bias_settle_hold`` 0), the yaw model's error in the turn goes to the
    bias (1-3 deg/s within the first second), the following fixes are gated, and the error stays above 1 deg
    for 22 s and 35 s."""
    import dataclasses

    from evstab.toolkit.logs.emulate import PRODUCTION_GYRO, Emulation, emulate
    from evstab.toolkit.estimation import design_filter, run_estimator
    from evstab.toolkit.estimation.spec import estimation_noise
    drive = real_drives.drives(DATA)[2]
    assert drive["drive"] == "GTI High_Speed2"
    cols = emulate(drive["cols"], Emulation(seed=0, **PRODUCTION_GYRO))
    k0 = int(np.searchsorted(cols["t"], start))
    part = {k: v[k0:] for k, v in cols.items()}
    part["t"] = part["t"] - part["t"][0]
    log = {k: v for k, v in part.items() if not k.endswith("_true")}
    fast = np.abs(part["speed"]) > real_drives.SCORE_SPEED
    settle = {}
    for label, kw in (("default", {}), ("learnt at once", {"bias_settle_hold": 0.0})):
        est = run_estimator(design_filter("dakf", drive["vehicle"], dataclasses.replace(estimation_noise(), **kw)),
                            log, monitor=True)
        err = np.abs(np.degrees(est["beta"] - part["beta_true"]))
        settle[label] = real_drives.settle_time(part["t"], err, fast)
    assert settle["default"] <= 3.0, settle  # the real-drives issue's bound
    assert settle["learnt at once"] > 10.0, settle  # 22 s and 35 s

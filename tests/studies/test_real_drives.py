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
    """The first 30 s of High_Speed (a race track at 13.6-32 m/s, the car moving from the first row). Read raw,
    the GTI's vibrating accelerometer held the kinematic path on: 1.21 deg RMS with the reference gyro and a mean
    NIS of 0.005 (the course innovations 14x smaller than predicted). Through the low-pass: 0.49 deg, NIS 0.54;
    0.41 deg, NIS 0.83 with the production gyro."""
    _, r = rows
    for gyro in ("reference", "production"):
        row = r[("GTI High_Speed", gyro, "dakf")]
        assert row["rms_deg"] < 0.8, row  # 0.49 / 0.41 measured; the raw accelerometer's 1.21 fails it
        assert 0.3 < row["mean_nis"] < 3.0, row  # 0.54 / 0.83; raw 0.005
        assert np.isfinite(row["max_deg"])


def test_revsted_samples(rows):
    """The ADMA sample's real RTK course (20 Hz, repeated on its 100 Hz rows: one fix per epoch) and the OBD
    sample's CAN yaw rate, quantised in 1.28 deg/s steps: held between steps while the car turns, which the
    monitor no longer calls a stuck gyro (650 of 999 rows were flagged)."""
    _, r = rows
    assert r[("ReV-StED ADMA (RTK course)", "as logged", "dakf")]["rms_deg"] < 0.35  # 0.26 measured
    assert r[("ReV-StED OBD (CAN)", "as logged", "dakf")]["gyro_stuck_rows"] == 0
    # with the Correvit's reference moved to the vehicle file's CG (real_drives.sideslip_moved): 0.94 deg RMS
    # on the first seed, mean NIS 1.65; the bound is the real-drives issue's target, the NIS its interval
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


def test_the_bias_held_in_turns_on_the_gti_drives():
    """Whole GTI drives, reference gyro, the first emulation seed: ``dakf`` with its gyro bias learnt in full only
    below 0.2 rad/s (``NoiseSettings.bias_learn_rate``, the study's ``dakf, bias held in turns`` row) against
    the default, which learns it at every yaw rate. Learnt in the turns the bias takes up the nominal model's
    sideslip error: 1.17, 0.70 and 2.16 deg RMS; held there, 0.55, 0.49 and 0.63 (docs/estimators.md)."""
    import dataclasses

    from evstab.toolkit.logs.emulate import Emulation, emulate
    from evstab.toolkit.estimation import design_filter, run_estimator
    from evstab.toolkit.estimation.spec import estimation_noise
    for drive in real_drives.drives(DATA)[:len(real_drives.GTI)]:
        cols = emulate(drive["cols"], Emulation(seed=0))
        log = {k: v for k, v in cols.items() if not k.endswith("_true")}
        rms = {}
        for rate in (0.0, real_drives.BIAS_HELD_RATE):
            est = run_estimator(design_filter("dakf", drive["vehicle"],
                                              dataclasses.replace(estimation_noise(), bias_learn_rate=rate)), log)
            rms[rate] = real_drives.errors(cols, est["beta"])["rms_deg"]
        held, everywhere = rms[real_drives.BIAS_HELD_RATE], rms[0.0]
        # the smallest gain measured, Low_Speed's 0.70 -> 0.49, is 30 %; the bound asks for 15 %
        assert held < 0.85 * everywhere, (drive["drive"], rms)
        assert held < 0.7, (drive["drive"], rms)  # 0.55 / 0.49 / 0.63 measured

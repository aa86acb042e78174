"""The firmware-faults study's quick run: single NaN and spike faults on every ECU input, on the straight road at
60 km/h and in the ISO 3888-1 lane change at 80 km/h (seed 0)."""

import pytest

from evstab.studies import firmware_faults


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("ff")
    return out, firmware_faults.main(out, quick=True)


def test_tables_are_written(run):
    out, rows = run
    from evstab.studies.publish import check_study
    assert not check_study("firmware_faults", out)  # the docs' blocks: the same files, the same columns
    assert len(rows) == 2 * 11 * 3  # two cases, eleven inputs, three NaN/spike faults each


def test_no_fault_makes_a_command_non_finite(run):
    _, rows = run
    assert all(r["finite"] for r in rows)


def test_one_bad_sample_on_the_straight_road_does_nothing(run):
    """A single NaN, infinity or out-of-the-rate spike is replaced by the last good value: no steer added and
    no yaw moment at all (0 exactly), on every input."""
    _, rows = run
    single = [r for r in rows if r["case"].startswith("straight") and r["fault"].endswith(", 1 ms")]
    assert len(single) == 11 * 2
    for r in single:
        assert r["added_steer_deg"] == 0.0 and r["yaw_moment_nm"] == 0.0, r


def test_a_persistent_nan_is_named(run):
    """NaN for 0.5 s on any input the guard checks: its bit in the fault word (the course's: the GPS bit)."""
    _, rows = run
    for r in rows:
        if r["case"].startswith("straight") and r["fault"].endswith("NaN, 500 ms"):
            assert r["named"], r


def _straight(within, finite=True):
    return {"signal": "yaw_rate", "fault": "x offset 0.1, 1000 ms", "finite": finite, "added_steer_deg": 0.6,
            "yaw_moment_nm": 0.0, "intervention_s": 0.0, "named": False, "within_bound": within}


def _lane(no_harm, as_without, finite=True):
    return {"signal": "yaw_rate", "fault": "x offset 0.1, 1000 ms", "finite": finite, "peak_beta_deg": 2.5,
            "alone_peak_beta_deg": 2.0, "no_fault_peak_beta_deg": 2.4, "no_harm": no_harm,
            "as_without_fault": as_without}


@pytest.mark.parametrize("straight, lane, verdict", [
    ([True, True], [(True, True)], "pass"),
    # the lane change breaks the rule against the car alone, not against the run without the fault
    ([True, True], [(False, True)], "as without the fault"),
    ([True, True], [(False, False)], "FAIL"),
    # a straight road beyond its bound: the run without the fault commands nothing there, nothing excuses it
    ([True, False], [(True, True)], "FAIL"),
    ([False, True], [(False, True)], "FAIL"),
    # a non-finite command fails whatever the peaks say
    ([True, True], [(True, True, False)], "FAIL"),
])
def test_the_fault_tables_verdict(straight, lane, verdict):
    from evstab.studies.firmware_faults import fault_table
    rows = [_straight(w) for w in straight] + [_lane(*x) for x in lane]
    (t,) = fault_table(rows).values()
    assert t["verdict"] == verdict
    # the worst over the runs: 2.5 - 2.0 and 2.5 - 2.4
    assert (t["excess"], t["by_fault"]) == pytest.approx((0.5, 0.1))


def test_command_steps_by_hand():
    """Periods 0-3 (1 ms), from 0.002 s on: corrections 2 and -1 deg of steer, yaw moments 300 and -500 N m; the
    largest change of each from one period to the next within the span (3 deg, 800 N m); over all four periods
    (8 -> 2 deg: 6; 5000 -> 300 N m: 4700)."""
    import numpy as np
    from evstab.studies.firmware_faults import command_steps
    t = np.array([0.0, 0.001, 0.002, 0.003])
    driver = np.radians([1.0, 1.0, 1.0, 1.0])
    steer = np.radians([9.0, 9.0, 3.0, 0.0])
    nz = np.array([5000.0, 5000.0, 300.0, -500.0])
    assert command_steps(t, steer, driver, nz, 0.002) == pytest.approx([3.0, 800.0], rel=1e-12)
    assert command_steps(t, steer, driver, nz) == pytest.approx([6.0, 4700.0], rel=1e-12)


@pytest.mark.parametrize("reset, spike", [((3.0, 800.0), False), ((3.0, 800.0 * (1 + 1e-6)), True),
                                          ((3.0 * (1 + 1e-6), 800.0), True), ((3.0, float("nan")), True)])
def test_no_spike_at_its_boundary(reset, spike):
    """Each of a reset's steps at most the never-reset ECU's (3 deg, 800 N m): equal is no spike; 1e-6 above
    (beyond the 1e-9 rounding margin) on either is; a NaN is."""
    from evstab.studies.firmware_faults import no_spike
    assert no_spike(reset, (3.0, 800.0)) == (not spike)


@pytest.mark.parametrize("steady, back, harm, spike, finite, verdict", [
    (True, True, False, False, True, "pass"),
    (True, False, False, False, True, "FAIL: late"),
    # at the limit the time is reported, not judged
    (False, False, False, False, True, "pass (at the limit: no harm, no spike)"),
    (False, False, True, False, True, "FAIL: harm"),
    (False, False, False, True, True, "FAIL: spike"),
    (True, True, False, False, False, "FAIL: not finite"),
])
def test_the_reset_verdict(steady, back, harm, spike, finite, verdict):
    from evstab.studies.firmware_faults import reset_verdict
    r = {"steady": steady, "back_in_time": back, "no_harm": not harm, "no_spike": not spike, "finite": finite}
    assert reset_verdict(r) == verdict

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

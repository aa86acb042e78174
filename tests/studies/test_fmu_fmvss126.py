"""The FMU in a closed loop with the two-track plant (studies/fmu_fmvss126.py, quick: the largest amplitude of
the FMVSS 126 series at 80 km/h on mu 1, steered left): the exported ECU, run by FMPy one period at a time, keeps
the car within the standard where the car alone spins."""

import pytest

from evstab.toolkit.kernels.compiled import compiler

pytest.importorskip("fmpy", reason="FMPy (test extra) is not installed")
if compiler() is None:
    pytest.skip("no C compiler on this machine (the FMU's binary is built at export)", allow_module_level=True)

from evstab.studies import fmu_fmvss126  # noqa: E402
from evstab.toolkit.verdicts.fmvss126 import LATERAL_DISPLACEMENT_MIN, YAW_RATIO_1_0_MAX, YAW_RATIO_1_75_MAX  # noqa: E402


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("fmu_swd")
    return out, fmu_fmvss126.main(out, quick=True)


def test_tables_are_written(run):
    out, rows = run
    from evstab.studies.publish import check_study
    assert not check_study("fmu_fmvss126", out)  # the docs' block: the same file, the same columns
    assert [r["controller"] for r in rows] == ["the FMU", "none (the car alone)"]


def test_the_fmu_in_the_loop_passes_where_the_car_alone_spins(run):
    """The standard's limits (yaw rate at most 35 % / 20 % of its peak 1.0 / 1.75 s after the steer ends, at
    least 1.83 m of lateral displacement) with the FMU in the loop; the car alone breaks both yaw-rate limits and
    slides past 10 deg of sideslip (it spins)."""
    _, (fmu, alone) = run
    assert fmu["verdict"] == "pass"
    assert fmu["yaw_ratio_1_0_pct"] <= YAW_RATIO_1_0_MAX and fmu["yaw_ratio_1_75_pct"] <= YAW_RATIO_1_75_MAX
    assert fmu["lateral_displacement_m"] >= LATERAL_DISPLACEMENT_MIN and fmu["peak_beta_deg"] < 5.0
    assert alone["verdict"].startswith("FAIL") and alone["peak_beta_deg"] > 10.0

"""The random fault campaign: its draws (every kind and input reachable, windows inside the manoeuvre) and its
quick run (four two-track runs, tables as the docs show them)."""

import numpy as np
import pytest

from evstab.studies import firmware_campaign as fc
from evstab.toolkit.loop.ecu_faults import ECU, OFFSETS


def test_the_draws_reach_every_kind_and_input_within_their_bounds():
    rng = np.random.default_rng(0)
    faults = [fc.draw_fault(rng) for _ in range(2000)]
    assert {f.kind for f in faults} == set(fc.KINDS)
    assert {f.signal for f in faults} == set(OFFSETS) | {ECU}
    for f in faults:
        assert 0.5 <= f.start <= 4.0
        if f.kind == "reset":
            # boots of 1-100 ms, plus the one sample that keeps a 1 ms boot a window of its own
            assert 0.001 <= f.end - f.start <= 0.102
        else:
            assert 0.001 - 1e-12 <= f.end - f.start <= 2.0 + 1e-9
        if f.kind == "value":
            lo, hi = fc.SPAN[f.signal]
            assert lo <= f.value <= hi
        if f.kind == "offset":
            assert abs(f.value) <= 2.0 * abs(OFFSETS[f.signal])  # mu's offset is negative
        if f.kind == "scale":
            assert 0.5 <= f.value <= 1.5
    # the same seed draws the same campaign
    a, b = np.random.default_rng(5), np.random.default_rng(5)
    assert [fc.draw_fault(a) for _ in range(20)] == [fc.draw_fault(b) for _ in range(20)]


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("campaign")
    return out, fc.main(out, quick=True)


def test_quick_campaign_tables_match_the_docs_and_every_command_is_finite(run):
    out, rows = run
    from evstab.studies.publish import check_study
    assert not check_study("firmware_campaign", out)  # the docs' blocks: the same files, the same columns
    assert len(rows) == sum(fc.QUICK_RUNS.values())
    assert all(r["finite"] for r in rows)
    # the summary's counts are the rows' (the last line: all cars)
    last = (out / "firmware_campaign_summary.md").read_text().strip().splitlines()[-1]
    assert last == (f"| all | {len(rows)} | {sum(r['finite'] for r in rows)} | {sum(r['no_harm'] for r in rows)} | "
                    f"{sum(r['as_without_fault'] for r in rows)} |")

"""Mutation check of the rules' thresholds: each named constant of a scorer, moved by +10 % and by
-10 %, must fail at least one test.

Run: ``python tests/mutants.py [NAME ...]`` from the repository's root (the design job's limit rules
are judged by the fast tests of ``tests/toolkit/test_limits.py`` only; a mutant the fast tests do not
kill runs into ``tests/toolkit/test_fmvss126.py``'s series on the simulated car, minutes each). It edits
one constant at a time in place, runs the tests that judge it, and restores the file (also on
Ctrl-C); it refuses to start while a file it edits has uncommitted changes. Prints one row per
mutant, ``killed`` (a test failed) or ``SURVIVED``, and exits 1 if any survived.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

FMVSS_TESTS = ("tests/toolkit/test_fmvss126_criteria.py", "tests/toolkit/test_fmvss126.py")
ENVELOPE_TESTS = ("tests/toolkit/test_envelope.py",)
MARGIN_TESTS = ("tests/toolkit/test_margins.py",)

CONSTANTS = {
    "toolkit/verdicts/fmvss126.py": (FMVSS_TESTS, (
        "SPEED", "YAW_RATIO_1_0_MAX", "YAW_RATIO_1_75_MAX", "T_YAW_1_0", "T_YAW_1_75", "LATERAL_DISPLACEMENT_MIN",
        "T_DISPLACEMENT", "DISPLACEMENT_FROM_A", "BOS_DEG", "HANDWHEEL_FILTER_HZ", "MOTION_FILTER_HZ",
        "HANDWHEEL_RATE", "A_G", "REGRESSION_FROM_G", "REGRESSION_TO_G", "SIS_END_G", "SIS_END_FACTOR",
        "SIS_END_MAX_DEG", "AMPLITUDE_FIRST_A", "AMPLITUDE_STEP_A", "AMPLITUDE_LAST_A", "AMPLITUDE_LAST_DEG",
        "AMPLITUDE_CAP_DEG")),
    "toolkit/verdicts/envelope.py": (ENVELOPE_TESTS, (
        "HARM_FACTOR", "HARM_MARGIN_DEG", "SLIDE_DEG", "HELD_DEG", "NORMAL_USE", "QUIET_STEER_DEG",
        "QUIET_YAW_MOMENT", "GUST_SHARE", "GUST_AFTER", "OVERHANG")),
    "toolkit/design/stability.py": (MARGIN_TESTS, ("DISK_MARGIN_MIN", "SENSITIVITY_PEAK_MAX")),
    "toolkit/design/limits.py": (tuple(f"tests/toolkit/test_limits.py::{t}" for t in (
        "test_sideslip_bound_follows_the_uncontrolled_car", "test_a_car_past_10_deg_of_sideslip_has_spun",
        "test_the_uncontrolled_slide_is_judged_against_10_deg", "test_the_step_case_asks_one_and_a_half_times_the_friction")),
        ("SPIN_DEG", "SIDESLIP_FACTOR", "SIDESLIP_FLOOR_DEG", "STEP_SATURATION")),
}


def mutate(text: str, name: str, factor: float) -> str:
    """``text`` with the module-level assignment ``NAME = <expression>`` scaled by ``factor``."""
    pat = re.compile(rf"^({name}\s*=\s*)(.+)$", re.M)
    m = pat.search(text)
    if m is None:
        raise SystemExit(f"{name}: no module-level assignment found")
    return text[:m.start()] + f"{m.group(1)}({m.group(2)}) * {factor!r}" + text[m.end():]


def main(only: list[str]) -> int:
    dirty = subprocess.run(["git", "status", "--porcelain", "--", *CONSTANTS], cwd=ROOT, capture_output=True,
                           text=True).stdout.strip()
    if dirty:
        raise SystemExit(f"uncommitted changes in the files this script edits:\n{dirty}")
    survived = 0
    for rel, (tests, names) in CONSTANTS.items():
        path = ROOT / rel
        names = [n for n in names if not only or n in only]
        original = path.read_text() if names else ""
        for name in names:
            for factor in (1.1, 0.9):
                try:
                    path.write_text(mutate(original, name, factor))
                    res = subprocess.run([sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider",
                                          *tests], cwd=ROOT, capture_output=True, text=True)
                finally:
                    path.write_text(original)
                killed = res.returncode != 0
                survived += not killed
                print(f"{rel}  {name} x {factor}: {'killed' if killed else 'SURVIVED'}", flush=True)
    return 1 if survived else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

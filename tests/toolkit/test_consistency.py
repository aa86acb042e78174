"""The residual check of ``evstab estimate``: which fixes it counts."""

import numpy as np

from evstab.toolkit.estimation.diagnostics import WARMUP, course_report, used_residuals


def test_the_residual_check_skips_the_warm_up():
    t = np.arange(0.0, 20.0, 0.2)
    cols = {"course_resid": np.random.default_rng(0).standard_normal(len(t)), "gps_used": np.ones(len(t))}
    assert np.isfinite(used_residuals(cols, t)).sum() == np.sum(t >= WARMUP)
    assert np.isfinite(used_residuals(cols)).sum() == len(t)  # no times: every used fix
    assert f"after the first {WARMUP:g} s" in course_report(cols, t=t)


def test_too_few_fixes_says_how_many_and_why():
    # 49 used fixes at 5 Hz over 9.6 s: 24 of them after the 5 s warm-up, more than 15, tested; over
    # 4.8 s none is after the warm-up; a method without course residuals (two-stage) says so
    from evstab.toolkit.estimation.diagnostics import MIN_FIXES
    t = np.arange(49) * 0.2
    cols = {"course_resid": np.random.default_rng(0).standard_normal(49), "gps_used": np.ones(49)}
    assert "Ljung-Box" in course_report(cols, t=t)
    short = {k: v[:25] for k, v in cols.items()}
    assert course_report(short, t=t[:25]) == (f"course residuals: 0 of the 25 used fixes have one after the first "
                                              f"{WARMUP:g} s, fewer than {MIN_FIXES}: no whiteness or NIS test")
    none = {"course_resid": np.full(49, np.nan), "gps_used": np.ones(49)}
    assert course_report(none, t=t) == ("course residuals: the method reports none for its 49 used fixes, no "
                                        "whiteness or NIS test")

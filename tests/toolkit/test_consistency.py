"""The residual check of ``evstab estimate``: which fixes it counts."""

import numpy as np

from evstab.toolkit.estimation.diagnostics import WARMUP, course_report, used_residuals


def test_the_residual_check_skips_the_warm_up():
    t = np.arange(0.0, 20.0, 0.2)
    cols = {"course_resid": np.random.default_rng(0).standard_normal(len(t)), "gps_used": np.ones(len(t))}
    assert np.isfinite(used_residuals(cols, t)).sum() == np.sum(t >= WARMUP)
    assert np.isfinite(used_residuals(cols)).sum() == len(t)  # no times: every used fix
    assert f"after the first {WARMUP:g} s" in course_report(cols, t=t)

"""Residual diagnostics for any filter run: whiteness of the innovations and NIS consistency.

Seed 001 checks the model with the filter's residuals: with the right model and noise
the innovation sequence is white, and each normalised innovation squared (NIS) is
chi-square distributed with one degree of freedom. Both tests are reported per run by
``evstab estimate`` for the course residual (the filter's ``course_resid`` output:
innovation over its predicted standard deviation, at the fixes the filter used).

* :func:`whiteness`: normalised autocorrelation ``rho_k`` for lags 1..m with the
  approximate 95 % bounds ``+-1.96 / sqrt(N)``, and the Ljung-Box portmanteau statistic
  ``Q = N (N + 2) sum rho_k^2 / (N - k)``, chi-square with m degrees of freedom under
  whiteness; the sequence is called white when Q's p-value is above ``alpha``.
* :func:`nis_consistency`: the mean NIS over N fixes against the two-sided chi-square
  interval ``[chi2(alpha/2, N), chi2(1 - alpha/2, N)] / N`` (mean 1 for a consistent
  filter; above: the filter is overconfident, below: too cautious).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.special  # not scipy.stats: importing it costs a second on every `evstab estimate`
from evstab.plants.errors import DataError


def _chi2_sf(x, k):
    """Chi-square survival function: the regularised upper incomplete gamma Q(k/2, x/2)."""
    return scipy.special.gammaincc(k / 2.0, x / 2.0)


def _chi2_ppf(p, k):
    """Chi-square quantile: 2 P^-1(k/2, p)."""
    return 2.0 * scipy.special.gammaincinv(k / 2.0, p)


@dataclass(frozen=True)
class Whiteness:
    n: int
    lags: int
    autocorrelation: np.ndarray
    """rho_1 .. rho_m."""
    bound: float
    """The approximate per-lag bound ``z_(1 - alpha/2) / sqrt(N)``."""
    outside: int
    """Lags whose |rho| exceeds the bound."""
    ljung_box: float
    p_value: float
    alpha: float

    @property
    def white(self) -> bool:
        return self.p_value > self.alpha


def autocorrelation(e: np.ndarray, lags: int) -> np.ndarray:
    """Normalised sample autocorrelation rho_1..rho_lags of ``e`` (mean removed; biased estimator,
    the one the Ljung-Box statistic and the 1/sqrt(N) bounds assume)."""
    e = np.asarray(e, float) - np.mean(e)
    c0 = float(np.dot(e, e))
    return np.array([float(np.dot(e[:-k], e[k:])) / c0 for k in range(1, lags + 1)])


def whiteness(residuals, lags: int | None = None, alpha: float = 0.05) -> Whiteness:
    """Whiteness test of a residual sequence (NaN entries, i.e. samples without a residual, dropped)."""
    e = np.asarray(residuals, float)
    e = e[np.isfinite(e)]
    n = len(e)
    m = int(lags) if lags is not None else min(20, n // 5)
    if m < 1 or n < 3 * m:
        raise DataError(f"whiteness: {n} residuals are too few for {m} lags (at least 3 per lag)")
    rho = autocorrelation(e, m)
    k = np.arange(1, m + 1)
    q = float(n * (n + 2) * np.sum(rho ** 2 / (n - k)))
    bound = float(scipy.special.ndtri(1 - alpha / 2) / np.sqrt(n))
    return Whiteness(n, m, rho, bound, int(np.sum(np.abs(rho) > bound)), q, float(_chi2_sf(q, m)), alpha)


@dataclass(frozen=True)
class NisConsistency:
    n: int
    mean: float
    low: float
    high: float

    @property
    def consistent(self) -> bool:
        return self.low <= self.mean <= self.high


def nis_consistency(nis, alpha: float = 0.05) -> NisConsistency:
    """Mean NIS of one-dimensional innovations against its chi-square interval."""
    v = np.asarray(nis, float)
    v = v[np.isfinite(v)]
    n = len(v)
    if n < 1:
        raise DataError("nis_consistency: no innovations")
    return NisConsistency(n, float(np.mean(v)), float(_chi2_ppf(alpha / 2, n) / n),
                          float(_chi2_ppf(1 - alpha / 2, n) / n))


WARMUP = 5.0
"""[s] The residual tests count the fixes from this long after the log's start: the filter's initial
covariance is a prior for a cold start, not its steady state (the noise fit skips the same)."""


MIN_FIXES = 15
"""Fewest used fixes with a residual for :func:`course_report`'s whiteness and NIS tests."""


def used_residuals(est_columns: dict, t=None, warmup: float = WARMUP) -> np.ndarray:
    """The normalised course residuals of the fixes a run used, NaN elsewhere and in the first ``warmup``
    seconds (``t``: the run's times; None: no warm-up)."""
    r = np.asarray(est_columns.get("course_resid", []), float)
    used = np.asarray(est_columns.get("gps_used", np.zeros(len(r))), float) > 0.5
    if t is not None and len(r):
        t = np.asarray(t, float)
        used &= t >= t[0] + warmup
    return np.where(used, r, np.nan)


def course_report(est_columns: dict, alpha: float = 0.05, t=None, warmup: float = WARMUP) -> str:
    """One line on the course residuals of a run (the fixes the filter used after ``warmup`` seconds of
    ``t``), for the console."""
    r = used_residuals(est_columns, t, warmup)
    n = int(np.sum(np.isfinite(r)))
    if n < MIN_FIXES:
        total = int(np.sum(np.asarray(est_columns.get("gps_used", []), float) > 0.5))
        resid = np.asarray(est_columns.get("course_resid", []), float)
        if not np.any(np.isfinite(resid)):
            return (f"course residuals: the method reports none for its {total} used fixes, no whiteness or NIS "
                    f"test")
        after = "" if t is None else f" after the first {warmup:g} s"
        return (f"course residuals: {n} of the {total} used fixes have one{after}, fewer than {MIN_FIXES}: no "
                f"whiteness or NIS test")
    w = whiteness(r, alpha=alpha)
    c = nis_consistency(r[np.isfinite(r)] ** 2, alpha)
    after = "" if t is None else f" after the first {warmup:g} s"
    return (f"course residuals over {w.n} fixes{after}: Ljung-Box Q({w.lags}) = {w.ljung_box:.1f}, p = {w.p_value:.3g} "
            f"({'white' if w.white else 'NOT white'} at {alpha:g}; {w.outside} of {w.lags} lags outside "
            f"+-{w.bound:.3f}); mean NIS {c.mean:.2f} ({'inside' if c.consistent else 'OUTSIDE'} "
            f"[{c.low:.2f}, {c.high:.2f}])")

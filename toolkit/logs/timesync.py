"""GPS-to-IMU time synchronisation: seed 000's objective fuzzy interpolation next to linear and Lagrange.

GPS samples arrive at their own instants (a receiver's epochs, with latency and jitter
once stamped by the logger); a filter running on the IMU clock wants them at its own
instants. Three ways to resample a slow signal ``y(t_k)`` onto times ``t``:

* :func:`linear`: piecewise linear through the samples (``numpy.interp``);
* :func:`lagrange`: the cubic Lagrange polynomial through the four samples around each
  time (seed 000 [9]'s classic method);
* :func:`fuzzy`: seed 000 section 3: within a sliding window of samples, Chiu's
  subtractive clustering (radius ``ra`` 0.6, squash factor ``eta`` 0.8, accept ratio 0.7,
  reject ratio 0.2) finds the rules in the joint (time, value) space; each rule has a
  Gaussian membership in time (width ``ra * range / sqrt(8)``) and a first-order Sugeno
  consequent ``w_i = p_i0 + p_i1 t``; all consequents are fitted at once by least squares
  (000 eq. 2-3, ``X = (A^T A)^-1 A^T B``), and the output is the membership-weighted mean.

Unlike the two interpolators, the fuzzy model is a regression: it does not pass through
each sample, so it averages a sample's noise (or its timestamp's jitter) with its
neighbours'.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from evstab.plants.errors import DataError


@dataclass(frozen=True)
class ClusterSettings:
    radius: float = 0.6
    squash: float = 0.8
    accept: float = 0.7
    reject: float = 0.2


def subtractive_clustering(X: np.ndarray, s: ClusterSettings = ClusterSettings()) -> np.ndarray:
    """Cluster centres (rows) of the data ``X`` (n x d, already scaled to the unit hypercube), Chiu 1994."""
    X = np.asarray(X, float)
    ra, rb = s.radius, s.radius * s.squash
    alpha, beta = 4.0 / ra ** 2, 4.0 / rb ** 2
    d2 = np.sum((X[:, None, :] - X[None, :, :]) ** 2, axis=-1)
    pot = np.exp(-alpha * d2).sum(axis=1)
    first = float(pot.max())
    centres: list[np.ndarray] = []
    while True:
        k = int(np.argmax(pot))
        pk = float(pot[k])
        if pk <= 0:
            break
        if pk > s.accept * first:
            ok = True
        elif pk < s.reject * first:
            break
        else:
            dmin = min(np.sqrt(np.sum((X[k] - c) ** 2)) for c in centres) if centres else np.inf
            ok = dmin / ra + pk / first >= 1.0
            if not ok:
                pot[k] = 0.0  # reject this point and try the next highest potential
                continue
        centres.append(X[k].copy())
        pot = pot - pk * np.exp(-beta * np.sum((X - X[k]) ** 2, axis=1))
        pot[k] = 0.0
    return np.array(centres)


@dataclass(frozen=True)
class Sugeno:
    """A first-order Sugeno model of one input: Gaussian memberships, linear consequents."""

    centres: np.ndarray
    sigma: float
    coef: np.ndarray
    """(rules, 2): p_i0, p_i1."""

    def weights(self, x):
        w = np.exp(-0.5 * ((np.asarray(x, float)[:, None] - self.centres[None, :]) / self.sigma) ** 2)
        return w / np.maximum(w.sum(axis=1, keepdims=True), 1e-300)

    def __call__(self, x):
        x = np.asarray(x, float)
        b = self.weights(x)
        return np.sum(b * (self.coef[:, 0][None, :] + self.coef[:, 1][None, :] * x[:, None]), axis=1)


def fit_sugeno(x, y, s: ClusterSettings = ClusterSettings()) -> Sugeno:
    """Subtractive clustering in the scaled (x, y) space, rules on x, consequents by least squares."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    lo, hi = np.array([x.min(), y.min()]), np.array([x.max(), y.max()])
    span = np.where(hi > lo, hi - lo, 1.0)
    Xs = (np.column_stack([x, y]) - lo) / span
    c = subtractive_clustering(Xs, s)
    centres = c[:, 0] * span[0] + lo[0]
    sigma = s.radius * span[0] / np.sqrt(8.0)
    proto = Sugeno(centres, sigma, np.zeros((len(centres), 2)))
    b = proto.weights(x)
    A = np.hstack([b, b * x[:, None]])  # columns: beta_i, beta_i x (000 eq. 3)
    sol, *_ = np.linalg.lstsq(A, y, rcond=None)
    r = len(centres)
    return Sugeno(centres, sigma, np.column_stack([sol[:r], sol[r:]]))


def linear(t_samples, y_samples, t):
    return np.interp(t, t_samples, y_samples)


def lagrange(t_samples, y_samples, t):
    """Cubic Lagrange interpolation through the four samples around each time (ends: the first/last four)."""
    ts, ys, t = (np.asarray(a, float) for a in (t_samples, y_samples, t))
    k = np.clip(np.searchsorted(ts, t) - 2, 0, len(ts) - 4)
    idx = k[:, None] + np.arange(4)[None, :]
    tk, yk = ts[idx], ys[idx]
    out = np.zeros(len(t))
    for i in range(4):
        li = np.ones(len(t))
        for j in range(4):
            if j != i:
                li *= (t - tk[:, j]) / (tk[:, i] - tk[:, j])
        out += li * yk[:, i]
    return out


def fuzzy(t_samples, y_samples, t, window: int = 15, s: ClusterSettings = ClusterSettings()):
    """Seed 000's objective fuzzy interpolation: a Sugeno model fitted on the ``window`` samples
    centred on each stretch between two samples, evaluated at the times inside it."""
    ts, ys, t = (np.asarray(a, float) for a in (t_samples, y_samples, t))
    n = len(ts)
    if n < 4:
        raise DataError(f"fuzzy interpolation needs at least 4 samples, got {n}")
    out = np.empty(len(t))
    seg = np.clip(np.searchsorted(ts, t) - 1, 0, n - 2)  # sample stretch [ts[seg], ts[seg + 1])
    half = window // 2
    for k in np.unique(seg):
        a = int(np.clip(k - half + 1, 0, max(n - window, 0)))
        b = min(n, a + window)
        m = fit_sugeno(ts[a:b] - ts[k], ys[a:b], s)
        sel = seg == k
        out[sel] = m(t[sel] - ts[k])
    return out

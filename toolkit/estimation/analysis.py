"""Estimator analysis as data: observability, steady-state and periodic Kalman gains.

* :func:`observability` — rank and smallest singular value of the observability
  matrix of ``(A, C)`` with both measurements (gyro, course), and the unobservable
  directions named by state.
* :func:`discrete_model` — the exact matrices the filter step uses at one speed
  (same Taylor discretisation, ``Q_d = Q dt``).
* :func:`steady_state_gain` — single rate (course every sample): the DARE solution
  (scipy), in measurement-update form ``K = P C^T (C P C^T + R)^-1``.
* :func:`periodic_gains` — multi-rate (gyro every sample, course every ``r``
  samples): the periodic Riccati solution over one GPS period, found by iterating
  the joint-update Riccati map to its fixed point.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from evstab.plants.backend import NUMPY
from .core import posterior
from .kalman import transition_matrix
from .spec import FilterDesign, continuous_model, gyro_row, process_noise_diag


@dataclass(frozen=True)
class Observability:
    """Observability of a filter design at one speed."""

    states: tuple[str, ...]
    rank: int
    smallest_singular_value: float
    """Smallest over largest singular value of the column-normalised observability matrix."""
    unobservable: tuple[dict, ...]
    """Unobservable directions in state units, each {state name: component}, first component 1."""

    @property
    def observable(self) -> bool:
        return self.rank == len(self.states)


def measurement_rows(d: FilterDesign, v: float) -> np.ndarray:
    """Rows of the measurement matrix: gyro and course (for ``lob``: gyro and lateral acceleration)."""
    if d.method == "lob":
        from .spec import lateral_coefficients
        a11, a12, *_ = lateral_coefficients(d.params, v)
        return np.array([[0.0, 1.0], [v * a11, v * (a12 + 1.0)]])
    hc = np.zeros(d.n)
    hc[d.index("beta")] = 1.0
    hc[d.index("yaw")] = 1.0
    if d.antenna_x:
        hc[d.index("yaw_rate")] = d.antenna_x / v
    return np.vstack([gyro_row(d), hc])


def observability(d: FilterDesign, v: float, rtol: float = 1e-9) -> Observability:
    """Observability of ``d`` at speed ``v`` with gyro and course (continuous model).

    Uses the Popov-Belevitch-Hautus test: the pair is observable iff
    ``[lambda I - A; C]`` has full column rank at every eigenvalue ``lambda`` of ``A``.
    Columns are normalised first (the states' units do not matter). The rank is
    ``n`` minus the total null-space dimension found; the smallest singular value
    reported is the smallest, over the eigenvalues, of ``sigma_min / sigma_max``.
    Unlike powers of ``A`` this stays well conditioned for slow modes (a 10 s
    correlation time).
    """
    A, _ = continuous_model(d, v, NUMPY)
    C = measurement_rows(d, v)
    n = d.n
    eig = np.linalg.eigvals(A)
    distinct: list = []
    for lam in eig:
        if not any(abs(lam - mu) <= 1e-9 * max(1.0, abs(mu)) for mu in distinct):
            distinct.append(lam)
    worst, dirs = np.inf, []
    for lam in distinct:
        M = np.vstack([lam * np.eye(n) - A, C])
        norms = np.linalg.norm(M, axis=0)
        norms[norms == 0] = 1.0
        _, s, vt = np.linalg.svd(M / norms)
        worst = min(worst, s[-1] / s[0])
        for k in np.nonzero(s < rtol * s[0])[0]:
            vec = np.real_if_close(vt[k].conj() / norms)
            vec = np.real(vec)
            vec = vec / vec[np.argmax(np.abs(vec) > 1e-9 * np.abs(vec).max())]  # first component = 1
            dirs.append({name: float(c) for name, c in zip(d.states, vec) if abs(c) > 1e-9 * np.abs(vec).max()})
    return Observability(d.states, n - len(dirs), float(worst), tuple(dirs))


def discrete_model(d: FilterDesign, v: float, dt: float):
    """(F, Qd, C, R) the filter uses at speed ``v`` (:func:`kalman.transition_matrix`: its transition
    table, or the Taylor-4 discretisation), Qd = Q dt."""
    F = transition_matrix(d, v, dt)
    Q = np.diag(process_noise_diag(d) * dt)
    C = measurement_rows(d, v)
    if d.hdop_noise:
        sc = max(d.noise.gps_velocity_std / max(v, d.noise.gps_min_speed), d.noise.course_std_min)
    else:
        sc = d.noise.course_std
    R = np.diag([d.noise.gyro_std**2, sc**2])
    return F, Q, C, R


def steady_state_gain(d: FilterDesign, v: float, dt: float = 1e-3):
    """Single-rate steady state: a-priori covariance from the DARE, gain ``K`` (update form)."""
    F, Q, C, R = discrete_model(d, v, dt)
    P = scipy.linalg.solve_discrete_are(F.T, C.T, Q, R)
    K = P @ C.T @ np.linalg.inv(C @ P @ C.T + R)
    return K, P


def _update(P, C, R):
    P_post, K = posterior(P, C, R)
    return K, P_post


def _compose(m1, m2):
    """Composition ``m2 o m1`` of two Riccati maps ``P -> A (P^-1 + G)^-1 A^T + H``, as (A, G, H).

    The structure-preserving doubling algorithm's product (Chu, Fan & Lin, 2005): with
    ``W = (I + H1 G2)^-1``, ``A = A2 W A1``, ``G = G1 + A1^T G2 W A1``, ``H = H2 + A2 W H1 A2^T``.
    Checked against applying the maps one after the other in the tests.
    """
    A1, G1, H1 = m1
    A2, G2, H2 = m2
    W = np.eye(A1.shape[0]) + H1 @ G2
    A = A2 @ np.linalg.solve(W, A1)
    G = G1 + A1.T @ G2 @ np.linalg.solve(W, A1)
    H = H2 + A2 @ np.linalg.solve(W, H1) @ A2.T
    return A, 0.5 * (G + G.T), 0.5 * (H + H.T)


def _power(m, k: int):
    """``m`` composed with itself ``k >= 1`` times, by repeated doubling (O(log k) products)."""
    out, base = None, m
    while k:
        if k & 1:
            out = base if out is None else _compose(out, base)
        k >>= 1
        if k:
            base = _compose(base, base)
    return out


def riccati_map(F, C, R, Q):
    """One filter sample (update with ``C``, ``R``, then predict) as a Riccati map (A, G, H)."""
    return F, C.T @ np.linalg.solve(R, C), Q


def periodic_gains(d: FilterDesign, v: float, gps_rate: float = 5.0, dt: float = 1e-3):
    """Periodic steady state over one GPS period of ``r = round(1 / (gps_rate dt))`` samples.

    Sample 0 of the period has gyro and course, samples 1..r-1 the gyro only. The
    a-priori covariance at the start of a period evolves by the period's Riccati map,
    the composition of the per-sample maps ``P -> F (P^-1 + C^T R^-1 C)^-1 F^T + Q``; the
    r - 1 gyro-only samples are composed by doubling (log2 r products, numerically
    stable: no symplectic matrix powers). The periodic solution is the fixed point of
    the period map ``P = A (P^-1 + G)^-1 A^T + H``, a standard DARE (``G = b b^T``);
    one pass through the period gives the gains. Returns (gains, posteriors), lists
    of length r. (Equal to the lifted-system DARE to 1e-11, 100x faster at 1 Hz GPS.)
    """
    F, Q, C, R = discrete_model(d, v, dt)
    n = d.n
    r = int(round(1.0 / (gps_rate * dt)))
    first = riccati_map(F, C, R, Q)
    per = first if r == 1 else _compose(first, _power(riccati_map(F, C[:1], R[:1, :1], Q), r - 1))
    A, G, H = per
    w, V = np.linalg.eigh(G)
    b = V * np.sqrt(np.clip(w, 0.0, None))
    P = scipy.linalg.solve_discrete_are(A.T, b, H, np.eye(n))
    P = 0.5 * (P + P.T)
    # a stabilising solution makes the period's error map a contraction; scipy may return a
    # solution of an undetectable pair (a marginal mode, here 1 - 1.6e-9 by round-off) without complaint
    closed = A.T - b @ np.linalg.solve(np.eye(b.shape[1]) + b.T @ P @ b, b.T @ P @ A.T)
    rho = np.max(np.abs(np.linalg.eigvals(closed)))
    if rho >= 1.0 - 1e-6:  # a mode decaying by < 1e-6 per period (time constant > 1e5 s at 5 Hz) is marginal
        raise np.linalg.LinAlgError("the periodic Riccati equation has no stabilising solution "
                                    "(the design is not detectable)")
    rows = [(C, R)] + [(C[:1], R[:1, :1])] * (r - 1)
    gains, posts = [], []
    for k in range(r):
        K, P_post = _update(P, *rows[k])
        gains.append(K)
        posts.append(P_post)
        P = F @ P_post @ F.T + Q
    return gains, posts

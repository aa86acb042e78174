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

from plants.backend import NUMPY
from .kalman import discretize
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
    distinct = []
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
    """(F, Qd, C, R) the filter uses at speed ``v``: Taylor-4 discretisation, Qd = Q dt."""
    A, _ = continuous_model(d, v, NUMPY)
    F, _ = discretize(A, dt, NUMPY, d.n)
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
    S = C @ P @ C.T + R
    K = P @ C.T @ np.linalg.inv(S)
    return K, P - K @ S @ K.T


def periodic_gains(d: FilterDesign, v: float, gps_rate: float = 5.0, dt: float = 1e-3):
    """Periodic steady state over one GPS period of ``r = round(1 / (gps_rate dt))`` samples.

    Sample 0 of the period has gyro and course, samples 1..r-1 the gyro only. The
    period is lifted: with ``x_j`` the state at the start of period ``j``,
    ``x_{j+1} = F^r x_j + sum_i F^(r-1-i) w_i`` and the period's measurements stack to
    ``Y_j = H_L x_j + G_L w + v``, whose noise is correlated with the lifted process
    noise. The lifted periodic Riccati equation is then one DARE with a cross term
    (scipy ``solve_discrete_are`` with ``s``); its solution is the a-priori
    covariance at the start of the period, and one pass through the period gives
    the gains. Returns (gains, posteriors), lists of length r.
    """
    F, Q, C, R = discrete_model(d, v, dt)
    n = d.n
    r = int(round(1.0 / (gps_rate * dt)))
    Fp = [np.eye(n)]
    for _ in range(r):
        Fp.append(F @ Fp[-1])
    rows = [(C, R)] + [(C[:1], R[:1, :1])] * (r - 1)
    m_tot = sum(h.shape[0] for h, _ in rows)
    H_L = np.zeros((m_tot, n))
    G_meas = np.zeros((m_tot, n * r))
    R_L = np.zeros((m_tot, m_tot))
    row = 0
    for k, (h, rk) in enumerate(rows):
        m = h.shape[0]
        H_L[row:row + m] = h @ Fp[k]
        for i in range(k):
            G_meas[row:row + m, i * n:(i + 1) * n] = h @ Fp[k - 1 - i]
        R_L[row:row + m, row:row + m] = rk
        row += m
    G_state = np.hstack([Fp[r - 1 - i] for i in range(r)])
    Qw = np.kron(np.eye(r), Q)
    Q_L = G_state @ Qw @ G_state.T
    R_L = R_L + G_meas @ Qw @ G_meas.T
    S_L = G_state @ Qw @ G_meas.T
    P = scipy.linalg.solve_discrete_are(Fp[r].T, H_L.T, Q_L, R_L, s=S_L)
    P = 0.5 * (P + P.T)
    gains, posts = [], []
    for k in range(r):
        K, P_post = _update(P, *rows[k])
        gains.append(K)
        posts.append(P_post)
        P = F @ P_post @ F.T + Q
    return gains, posts

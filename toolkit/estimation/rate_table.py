"""Seed 001's Table I: the predicted steady-state estimation error of the model-based filter vs GPS rate.

Anderson & Bevly's model-based Kalman filter has states (beta, r, psi, b_gyro)
(001 eq. 5): the linear bicycle for (beta, r), ``psi' = r``, a constant gyro bias;
measurements yaw rate (``r + b``) and GPS course (``beta + psi``), both at the rate
of the row; process noise enters through the steer input (``Q_d ~ B Q_c B^T T_s``,
001 eq. 3), so the filter's trust in the model is one number, the steer-noise
intensity. Table I lists, at 30 m/s, the measurement noises (growing with the square
root of the rate) and the predicted standard deviations of the yaw-rate and sideslip
estimates; "predicted" is read as the a-priori steady-state covariance (the DARE
solution): the table's yaw-rate error is larger than the gyro noise, which the
a-posteriori covariance can never be.

:func:`predicted_errors` solves the DARE (scipy) of that model discretised exactly
(Van Loan's method for ``Q_d``); :func:`calibrate_steer_noise` finds the one unknown
the paper does not print (the steer-noise intensity, with the vehicle's parameters)
from one row, so the other rows become predictions to compare with the paper's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.optimize

from evstab.plants import VehicleParams
from evstab.plants.bicycle import lateral_coefficients

from .core import posterior

PAPER_TABLE_I = (
    # rate [Hz], sigma_course [deg], sigma_gyro [deg/s], predicted sigma_r [deg/s], predicted sigma_beta [deg]
    (5.0, 0.0348, 0.0636, 0.0671, 0.0086),
    (20.0, 0.0697, 0.1272, 0.1342, 0.0171),
    (50.0, 0.1101, 0.2012, 0.2121, 0.0270),
    (100.0, 0.1558, 0.2845, 0.3, 0.0382),
)
"""001 Table I at 30 m/s, as printed."""

STATES = ("beta", "yaw_rate", "yaw", "gyro_bias")


def model(p: VehicleParams, speed: float):
    """Continuous ``A`` (4 x 4), steer column ``b`` (4,), measurement matrix ``H`` (gyro; course)."""
    a11, a12, a21, a22, b11, b21, _ = lateral_coefficients(p, speed)
    A = np.zeros((4, 4))
    A[0, :2] = a11, a12
    A[1, :2] = a21, a22
    A[2, 1] = 1.0
    b = np.array([b11, b21, 0.0, 0.0])
    H = np.array([[0.0, 1.0, 0.0, 1.0], [1.0, 0.0, 1.0, 0.0]])
    return A, b, H


def discretise(A, G, Qc, T):
    """Van Loan: ``F = e^(A T)``, ``Q_d = int_0^T e^(A s) G Qc G^T e^(A^T s) ds``."""
    n = A.shape[0]
    M = np.zeros((2 * n, 2 * n))
    M[:n, :n] = -A
    M[:n, n:] = G @ Qc @ G.T
    M[n:, n:] = A.T
    E = scipy.linalg.expm(M * T)
    F = E[n:, n:].T
    return F, F @ E[:n, n:]


@dataclass(frozen=True)
class Predicted:
    rate: float
    prior: np.ndarray
    """Steady-state a-priori covariance (before each update), states per :data:`STATES`."""
    posterior: np.ndarray

    def std(self, state: str, which: str = "prior") -> float:
        i = STATES.index(state)
        return float(np.sqrt(getattr(self, which)[i, i]))


def predicted_errors(p: VehicleParams, speed: float, rate: float, sigma_course: float, sigma_gyro: float,
                     q_steer: float, q_bias: float = 0.0) -> Predicted:
    """Steady-state covariances of 001's model-based filter with both measurements at ``rate`` [Hz].

    ``sigma_course`` [rad] and ``sigma_gyro`` [rad/s] per sample; ``q_steer`` [rad^2/s] the
    intensity of white noise on the steer input; ``q_bias`` [rad^2/s^3] an optional bias walk
    (0: a constant bias, which the steady state then knows exactly)."""
    A, b, H = model(p, speed)
    G = np.column_stack([b, np.eye(4)[3]])
    # a constant bias (q_bias = 0) is known exactly in the steady state, and its mode on the unit
    # circle, driven by no noise, has no DARE solution: solve without it (the limit), variance 0
    k = 4 if q_bias > 0 else 3
    F, Q = discretise(A[:k, :k], G[:k], np.diag([q_steer, q_bias]), 1.0 / rate)
    R = np.diag([sigma_gyro ** 2, sigma_course ** 2])
    Hk = H[:, :k]
    P = scipy.linalg.solve_discrete_are(F.T, Hk.T, Q, R)
    P = 0.5 * (P + P.T)
    post, _ = posterior(P, Hk, R)
    full = [np.zeros((4, 4)), np.zeros((4, 4))]
    full[0][:k, :k], full[1][:k, :k] = P, post
    return Predicted(rate, full[0], full[1])


def calibrate_steer_noise(p: VehicleParams, speed: float = 30.0, row=PAPER_TABLE_I[0]) -> float:
    """The steer-noise intensity at which the predicted (a-priori) sideslip std equals ``row``'s."""
    rate, sc, sg, _, sb = row

    def gap(log_q):
        pr = predicted_errors(p, speed, rate, np.radians(sc), np.radians(sg), float(np.exp(log_q)))
        return np.log(pr.std("beta")) - np.log(np.radians(sb))

    return float(np.exp(scipy.optimize.brentq(gap, np.log(1e-16), np.log(1e2), xtol=1e-12)))


def table_i(p: VehicleParams, speed: float = 30.0, q_steer: float | None = None) -> list[dict]:
    """Table I for vehicle ``p``: per paper row, the paper's figures and this model's predictions
    (a-priori and a-posteriori) with ``q_steer`` (default: calibrated on the 5 Hz row)."""
    q = calibrate_steer_noise(p, speed) if q_steer is None else q_steer
    rows = []
    for rate, sc, sg, sr, sb in PAPER_TABLE_I:
        pr = predicted_errors(p, speed, rate, np.radians(sc), np.radians(sg), q)
        rows.append({"gps_rate_hz": rate, "sigma_course_deg": sc, "sigma_gyro_deg_s": sg,
                     "paper_sigma_r_deg_s": sr, "paper_sigma_beta_deg": sb,
                     "sigma_r_deg_s": float(np.degrees(pr.std("yaw_rate"))),
                     "sigma_beta_deg": float(np.degrees(pr.std("beta"))),
                     "sigma_r_posterior_deg_s": float(np.degrees(pr.std("yaw_rate", "posterior"))),
                     "sigma_beta_posterior_deg": float(np.degrees(pr.std("beta", "posterior"))),
                     "q_steer": q})
    return rows
